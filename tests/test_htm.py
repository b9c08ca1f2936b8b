"""The 23-element HTM model: zero errors, each element alone against its hand-derived
first-order effect, exact vs first-order, the error-transfer Jacobian vs finite differences."""
import numpy as np

from errormap.grinder_file import rho0_mm
import pytest

from errormap.chain_elements import ChainElementSet
from errormap.elements import ELEMENT_NAMES
from errormap.chain_field import ChainField
from errormap.chain_kernel import error_jacobian, spatial_error
from errormap.chain_truth import make_chain_truth

TOL_ZERO_UM = 1e-9
TOL_FIRST_ORDER_UM = 1e-6      # for 1 μm / 1 μrad elements, second-order terms are ~1e-9 μm
TOL_JAC_ABS = 1e-7          # round-off of differencing 200 mm positions
ANGLE_COLUMNS = [i for i, n in enumerate(ELEMENT_NAMES) if n.startswith('e') or n == 's_xz']
TOL_JAC_AT_STATE_FACTOR = 2.0  # safety factor on the derived second-order bound


def hand_first_order(m, axes, name, v):
    """First-order spatial error (μm) of element ``name`` = v alone, derived by hand.

    p = (px, ρ sin a, ρ cos a); q0 = tool point on the X carriage = (-l5-x, 0, ρ + l8);
    q2 = on the A-axis end = (px, 0, ρ); b = tool point on the Z carriage = (l3, 0, l4 - R);
    Ra = RotX(-a): (wx, wy, wz) -> (wx, c wy + s wz, -s wy + c wz). Angles in μrad give μm·1e-3 per mm.
    """
    x, z, a = axes[:, 0], axes[:, 1], np.deg2rad(axes[:, 2])
    c, s = np.cos(a), np.sin(a)
    th = np.deg2rad(m.geometry["theta1_deg"])
    ct, st = np.cos(th), np.sin(th)
    rho = rho0_mm(m) + z
    px, py, pz = -(m.geometry["l5"] + m.geometry["l7"] + x), rho * s, rho * c
    qx, h0 = -m.geometry["l5"] - x, rho + m.geometry["l8"]
    bx, bz = m.geometry["l3"], m.geometry["l4"] - m.geometry["R"]
    w = v * 1e-3  # μrad -> μm per mm
    zero = np.zeros_like(x)
    f = {
        "dx_x": (-v + zero, zero, zero), "dy_x": (zero, -c * v, s * v), "dz_x": (zero, -s * v, -c * v),
        "ex_x": (zero, c * w * h0, -s * w * h0), "ey_x": (-w * h0, s * w * qx, c * w * qx),
        "ez_x": (zero, -c * w * qx, s * w * qx),
        "dx_z": (v * ct + zero, c * v * st, -s * v * st), "dy_z": (-v * st + zero, c * v * ct, -s * v * ct),
        "dz_z": (zero, s * v, c * v),
        "ex_z": (w * bz * st + zero, -c * w * bz * ct, s * w * bz * ct),
        "ey_z": (w * bz * ct + zero, c * w * bz * st - s * w * bx, -s * w * bz * st - c * w * bx),
        "ez_z": (-w * bx * st + zero, c * w * bx * ct, -s * w * bx * ct),
        "dx_a": (-v + zero, zero, zero), "dy_a": (zero, -v + zero, zero), "dz_a": (zero, zero, -v + zero),
        "ex_a": (zero, w * pz, -w * py), "ey_a": (-w * pz, zero, w * px), "ez_a": (w * py, -w * px, zero),
        "dy_oa": (zero, -c * v, s * v), "dz_oa": (zero, -s * v, -c * v),
        "ey_oa": (-w * rho, s * w * px, c * w * px), "ez_oa": (zero, -c * w * px, s * w * px),
        "s_xz": (w * z, zero, zero),
    }[name]
    return np.stack(f, axis=1)


@pytest.fixture
def axes(rng):
    return np.c_[rng.uniform(0, 200, 64), rng.uniform(0, 60, 64), rng.uniform(0, 360, 64)]


def test_zero_elements_give_zero_error(grinder, axes):
    field = ChainField(grinder, ChainElementSet.zeros(grinder))
    assert np.abs(field.predict(axes)).max() < TOL_ZERO_UM


@pytest.mark.parametrize("name", ELEMENT_NAMES)
def test_each_element_alone_matches_hand_derivation(grinder, axes, name):
    j = ELEMENT_NAMES.index(name)
    values = np.zeros((len(axes), 23))
    values[:, j] = 1.0
    expected = hand_first_order(grinder, axes, name, 1.0)
    assert np.abs(expected).max() > 1e-3  # the element does something here
    np.testing.assert_allclose(spatial_error(grinder, axes, values), expected, atol=TOL_FIRST_ORDER_UM)
    np.testing.assert_allclose(_first_order(grinder, axes, values), expected, atol=1e-12)


def test_exact_and_first_order_agree_to_second_order(grinder, axes, rng):
    v = rng.normal(0.0, 100.0, (len(axes), 23))
    gaps = []
    for scale in (1.0, 0.1, 0.01):
        gaps.append(np.abs(spatial_error(grinder, axes, v * scale)
                           - _first_order(grinder, axes, v * scale)).max())
    # halving... a tenth of the element size gives a hundredth of the gap (second order)
    assert gaps[0] > 1e-4
    for g_big, g_small in zip(gaps, gaps[1:]):
        assert g_small / g_big == pytest.approx(0.01, rel=0.05)


def test_jacobian_matches_finite_differences(grinder, axes, rng):
    """At zero error the Jacobian is the exact derivative (to round-off); at a realistic
    error state (50 μm / 50 μrad) it stays the derivative to first order."""
    J = error_jacobian(grinder, axes)
    h = 1e-2
    v0 = rng.normal(0.0, 50.0, (len(axes), 23))
    for j in range(23):
        dv = np.zeros((len(axes), 23))
        dv[:, j] = h
        fd0 = (spatial_error(grinder, axes, dv) - spatial_error(grinder, axes, -dv)) / (2 * h)
        np.testing.assert_allclose(fd0, J[:, :, j], atol=TOL_JAC_ABS)
        fd = (spatial_error(grinder, axes, v0 + dv) - spatial_error(grinder, axes, v0 - dv)) / (2 * h)
        # second-order terms: the error state turns each column by ~Σ|ε| rad and shifts the
        # lever arms of the angle columns by the spatial error itself (mm) · 1e-3 μm/μrad
        turn_rad = np.abs(v0[:, ANGLE_COLUMNS]).sum(1).max() * 1e-6
        shift_mm = np.abs(spatial_error(grinder, axes, v0)).max() * 1e-3
        bound = turn_rad * np.abs(J[:, :, j]).max() + (shift_mm * 1e-3 if j in ANGLE_COLUMNS else 0.0)
        assert np.abs(fd - J[:, :, j]).max() <= TOL_JAC_AT_STATE_FACTOR * bound + TOL_JAC_ABS


def test_element_set_round_trip(tmp_path, grinder, axes):
    el = make_chain_truth(grinder, 7).elements
    path = el.save(tmp_path / "el.json")
    back = ChainElementSet.load(path, grinder)
    np.testing.assert_array_equal(back.values(axes), el.values(axes))


def test_element_splines_interpolate_and_are_periodic_in_a(grinder):
    el = make_chain_truth(grinder, 3).elements
    st = el.stations
    at_stations = el.values(np.c_[st["x_mm"], st["z_mm"], st["a_deg"]])
    np.testing.assert_allclose(at_stations[:, ELEMENT_NAMES.index("dy_x")], el.functions["dy_x"], atol=1e-12)
    a = np.linspace(0, 360, 7)
    v1 = el.values(np.c_[np.full(7, 50.0), np.full(7, 20.0), a])
    v2 = el.values(np.c_[np.full(7, 50.0), np.full(7, 20.0), a + 720.0])
    np.testing.assert_allclose(v1, v2, atol=1e-9)


def test_element_set_file_errors(tmp_path, grinder):
    from errormap.io import InputError
    p = tmp_path / "bad.json"
    p.write_text('{"format": "other"}')
    with pytest.raises(InputError, match="format"):
        ChainElementSet.load(p, grinder)


def _first_order(machine, axes, values):
    """The first-order spatial error ``J · v`` (μm), (n, 3)."""
    return np.einsum("nij,nj->ni", error_jacobian(machine, axes), np.asarray(values, dtype=float))
