"""The ISO 230-1 map, checked element by element against hand-derived values.

Set-up for every hand value (default grinder, axes x = 50 mm, z = 30 mm, a = 0°):
tool point (MCS) = RotZ(30°)·(l2 + l3, 0, l1 + z + l4 − R) = (0, 0, 330) mm;
X carriage origin (−190, 0, 180) → tool offset r_X = (190, 0, 150) mm;
Z carriage origin RotZ(30°)·(160, 0, 450) = (138.564, 80, 450) → r_Z = (−138.564, −80, −120) mm;
A-axis end (−150, 0, 299.9) → r_A = (150, 0, 30.1) mm. At a = 0 the WCS axes are the MCS axes.
An angle ε (μrad) moves a point at offset r by 1e-3·ε × r (μm). X and A carry the workpiece,
so the tool moves relative to the work by MINUS their error motion; Z carries the wheel (PLUS).
"""
import numpy as np
import pytest

from errormap.elements import ELEMENT_NAMES
from errormap.chain_kernel import spatial_error
from errormap.elements import A_ELEMENTS, X_ELEMENTS, Z_ELEMENTS
from errormap.iso230 import ISO_NAME, ISO_NAMES, axis_from_mcs, axis_to_mcs, label

# exact transforms carry second-order terms: ε²·|r| ≤ (1e-4)²·330 mm ≈ 3e-6 μm, and the
# hand values below are written to 3 decimals (≤ 5e-4 μm rounding): 2e-3 μm covers both.
HAND_TOL_UM = 2e-3
# float round trip of a linear map and its inverse on values up to ~300
ROUND_TRIP_TOL = 1e-9

AXES = np.array([[50.0, 30.0, 0.0]])
R_X = np.array([190.0, 0.0, 150.0])
R_Z = np.array([-138.564, -80.0, -120.0])
R_A = np.array([150.0, 0.0, 30.1])
C30, S30 = np.cos(np.deg2rad(30.0)), 0.5

# element: (injected value, hand ISO values {name: value}, hand spatial error in WCS μm at a = 0)
HAND = {
    "dx_x": (1.0, {"EXX": 1.0}, (-1.0, 0.0, 0.0)),
    "dy_x": (1.0, {"EYX": 1.0}, (0.0, -1.0, 0.0)),
    "dz_x": (1.0, {"EZX": 1.0}, (0.0, 0.0, -1.0)),
    "ex_x": (100.0, {"EAX": 100.0}, (0.0, 15.0, 0.0)),          # -(ε × r_X) = -(0, -15, 0)
    "ey_x": (100.0, {"EBX": 100.0}, (-15.0, 0.0, 19.0)),        # ε × r_X = (15, 0, -19)
    "ez_x": (100.0, {"ECX": 100.0}, (0.0, -19.0, 0.0)),         # ε × r_X = (0, 19, 0)
    "dx_z": (1.0, {"EXZ": C30, "EYZ": S30}, (C30, S30, 0.0)),   # column frame turned by θ1 = 30°
    "dy_z": (1.0, {"EXZ": -S30, "EYZ": C30}, (-S30, C30, 0.0)),
    "dz_z": (1.0, {"EZZ": 1.0}, (0.0, 0.0, 1.0)),
    "ex_z": (100.0, {"EAZ": 100 * C30, "EBZ": 50.0}, (-6.0, 10.392, 0.0)),     # ε_MCS × r_Z
    "ey_z": (100.0, {"EAZ": -50.0, "EBZ": 100 * C30}, (-10.392, -6.0, 16.0)),
    "ez_z": (100.0, {"ECZ": 100.0}, (8.0, -13.856, 0.0)),
    "dx_a": (1.0, {"EXA": 1.0}, (-1.0, 0.0, 0.0)),
    "dy_a": (1.0, {"EYA": 1.0}, (0.0, -1.0, 0.0)),
    "dz_a": (1.0, {"EZA": 1.0}, (0.0, 0.0, -1.0)),
    "ex_a": (100.0, {"EAA": 100.0}, (0.0, 3.01, 0.0)),          # ε × r_A = (0, -3.01, 0)
    "ey_a": (100.0, {"EBA": 100.0}, (-3.01, 0.0, 15.0)),        # ε × r_A = (3.01, 0, -15)
    "ez_a": (100.0, {"ECA": 100.0}, (0.0, -15.0, 0.0)),         # ε × r_A = (0, 15, 0)
    "dy_oa": (1.0, {"EY0A": 1.0}, (0.0, -1.0, 0.0)),
    "dz_oa": (1.0, {"EZ0A": 1.0}, (0.0, 0.0, -1.0)),
    "ey_oa": (100.0, {"EB0A": 100.0}, (-3.01, 0.0, 15.0)),      # the A line tilts about its end
    "ez_oa": (100.0, {"EC0A": 100.0}, (0.0, -15.0, 0.0)),
    "s_xz": (100.0, {"EB0Z": 100.0}, (3.0, 0.0, 0.0)),          # 1e-3 · 100 μrad · z = 30 mm along +X
}
SIDE = {"X": -1.0, "Z": 1.0, "A": -1.0}


_TRIPLES = {"X": X_ELEMENTS, "Z": Z_ELEMENTS, "A": A_ELEMENTS}


def reference_points_mm(machine, axes):
    """The X, Z and A bodies' reference points (MCS mm, (n, 3) each): their frames' origins in the chain."""
    return {b: machine.body_frames(b, axes)[1] for b in _TRIPLES}


def _convert(v, axes, machine, offsets, per_axis):
    """The 23 values (n, 23) with each body's six components converted by the library's ``per_axis``."""
    out = np.array(v, dtype=float, copy=True)
    for b, names in _TRIPLES.items():
        cols = [ELEMENT_NAMES.index(k) for k in names]
        r = None if not offsets or b not in offsets else np.broadcast_to(offsets[b], (len(axes), 3))
        out[:, cols] = per_axis(machine, b, axes, out[:, cols], r)
    return out


def to_iso(v, axes, machine, offsets=None):
    """Element values -> ISO 230-1 values (ELEMENT_NAMES order) through :func:`errormap.iso230.axis_to_mcs`."""
    return _convert(v, axes, machine, offsets, axis_to_mcs)


def from_iso(iso, axes, machine, offsets=None):
    return _convert(iso, axes, machine, offsets, axis_from_mcs)


def one(name, value, n=1):
    v = np.zeros((n, 23))
    v[:, ELEMENT_NAMES.index(name)] = value
    return v


def test_map_is_one_to_one_and_covers_23():
    assert len(set(ISO_NAMES)) == 23 and set(ISO_NAME) == set(ELEMENT_NAMES)
    assert label("s_xz") == "s_xz (EB0Z)"


@pytest.mark.parametrize("name", ELEMENT_NAMES)
def test_hand_derived_iso_value_and_effect(grinder, name):
    value, iso_hand, err_hand = HAND[name]
    v = one(name, value)
    iso = to_iso(v, AXES, grinder)[0]
    want = np.zeros(23)
    for k, x in iso_hand.items():
        want[ISO_NAMES.index(k)] = x
    np.testing.assert_allclose(iso, want, atol=HAND_TOL_UM)
    # the element, injected alone into the exact HTM chain, moves the tool by the hand value
    e = spatial_error(grinder, AXES, v)[0]
    np.testing.assert_allclose(e, err_hand, atol=HAND_TOL_UM)


@pytest.mark.parametrize("name", [k for k in ELEMENT_NAMES if not k.endswith("oa") and k != "s_xz"])
def test_iso_translation_at_tool_point_is_the_tool_displacement(grinder, name):
    """Moving the reference point to the tool point (offset r per body) gives, with the side's
    sign, exactly the displacement of the tool relative to the workpiece (MCS, a = 0 and 90°)."""
    for a in (0.0, 90.0):
        axes = np.array([[50.0, 30.0, a]])
        ref = reference_points_mm(grinder, axes)
        tool = np.array([[0.0, 0.0, 330.0]])
        off = {b: tool - ref[b] for b in ("X", "Z", "A")}
        value = HAND[name][0]
        iso = to_iso(one(name, value), axes, grinder, off)[0]
        body = {"x": "X", "z": "Z", "a": "A"}[name[-1]]
        cols = [ISO_NAMES.index(f"E{c}{body}") for c in "XYZ"]
        e_wcs = spatial_error(grinder, axes, one(name, value))[0]
        ca, sa = np.cos(np.deg2rad(a)), np.sin(np.deg2rad(a))
        e_mcs = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]) @ e_wcs   # WCS = MCS turned by RotX(a)
        np.testing.assert_allclose(e_mcs, SIDE[body] * iso[cols], atol=HAND_TOL_UM)


def test_a_axis_radial_pair_turns_with_a(grinder):
    """dy_a = 1 μm in the rotating frame at a = 90° is +1 μm along the fixed Z: EZA = 1, EYA = 0."""
    iso = to_iso(one("dy_a", 1.0), np.array([[50.0, 30.0, 90.0]]), grinder)[0]
    assert iso[ISO_NAMES.index("EYA")] == pytest.approx(0.0, abs=1e-12)
    assert iso[ISO_NAMES.index("EZA")] == pytest.approx(1.0, abs=1e-12)


def test_round_trip(grinder):
    rng = np.random.default_rng(19)
    axes = np.column_stack([rng.uniform(0, 200, 50), rng.uniform(0, 60, 50), rng.uniform(0, 360, 50)])
    v = rng.normal(0, 50, (50, 23))
    off = {"X": rng.normal(0, 100, 3), "Z": rng.normal(0, 100, (50, 3)), "A": rng.normal(0, 100, 3)}
    back = from_iso(to_iso(v, axes, grinder, off), axes, grinder, off)
    np.testing.assert_allclose(back, v, atol=ROUND_TRIP_TOL)


def test_identify_summary_shows_iso_names(grinder):
    from compensation.app.reports.identification import iso_summary_lines
    from errormap.chain_truth import make_chain_truth
    el = make_chain_truth(grinder, 4).elements
    lines = iso_summary_lines(el)
    assert len(lines) == 24
    assert lines[1].split()[:2] == ["dx_x", "(EXX)"]
    assert float(lines[1].split()[2]) == pytest.approx(np.abs(el.functions["dx_x"]).max(), abs=5e-4)
    assert lines[-1].split()[:2] == ["s_xz", "(EB0Z)"] and lines[-1].endswith("(constant)")
