"""Built-in machine-tool chain files (issue 26 points 4 and 7): the five-axis machine against the
ISO 230-7 first-order formulas, the lathe's Jacobians, and bad machine files refused through the
CLI with exit 2 and one line naming the file, the table and the key."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField

ISO_SCALES = (100.0, 10.0)
"""Location errors of ±100 and ±10 μm / μrad: the exact model minus the first-order formula is a
second-order remainder, so it shrinks 100× when the errors shrink 10×."""
ISO_REMAINDER_FACTOR = 8.0
"""Bound on the remainder, in units of ε·(δ + ε·L) (ε rad, δ mm, L the largest lever arm in mm):
the eight location slots each contribute at most one such product (a tilt times an offset or a
tilt times a lever arm, and tilt products of two axes), so 8 is the sum's worst case."""
QUADRATIC_RATIO_MIN = 50.0
"""The remainder at 10× smaller errors is 100× smaller for a second-order term; 50 allows for the
mix of ε·δ and ε² terms without accepting a first-order (10×) discrepancy."""
FD_STEP = 1e-3
FD_TOL_REL = 1e-5
"""Central differences (step 1e-3 mm / deg) on cubic splines and trig terms: truncation ~1e-7 of the
scale; 1e-5 relative to the largest entry leaves a margin of 100."""


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0] = 1.0
    R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2] = c, -s, s, c
    return R


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 2, 2] = 1.0
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1] = c, -s, s, c
    return R


def _iso230_7_first_order(geo, axes, v):
    """ISO 230-7 location errors of a work-side A/C trunnion, first order, written out: an axis
    line offset δ and tilted by ε moves the workpiece by ``δ + ε × r`` at a point ``r`` from the
    line's reference point, so the tool relative to the workpiece by the opposite, seen in the
    workpiece frame. A: reference point the A pivot (0, 0, a_height), δ = (0, EY0A, EZ0A), ε = (0,
    EB0A, EC0A) in the machine frame; C: reference point the table centre after A's rotation, δ =
    (EX0C, EY0C, 0), ε = (EA0C, EB0C, 0) in the trunnion frame. Returns (n, 3) μm."""
    x, y, z, a, c = axes.T
    a, c = np.radians(a), np.radians(c)
    n = len(x)
    t = np.stack([x, y, np.full(n, geo["spindle_home"]) + z - geo["tool_length"]], 1)   # tool point, machine frame
    r_a = t - np.array([0.0, 0.0, geo["a_height"]])                                    # from the A pivot
    d_a = np.stack([np.zeros(n), v["dy_oa"] * 1e-3, v["dz_oa"] * 1e-3], 1)
    e_a = np.stack([np.zeros(n), v["ey_oa"] * 1e-6, v["ez_oa"] * 1e-6], 1)
    RaT = np.swapaxes(_rx(a), 1, 2)
    r_c = np.einsum("nij,nj->ni", RaT, r_a) + np.array([0.0, 0.0, geo["c_below_a"]])    # in the trunnion frame
    d_c = np.stack([v["dx_oc"] * 1e-3, v["dy_oc"] * 1e-3, np.zeros(n)], 1)
    e_c = np.stack([v["ex_oc"] * 1e-6, v["ey_oc"] * 1e-6, np.zeros(n)], 1)
    RcT = np.swapaxes(_rz(c), 1, 2)
    dev_a = np.einsum("nij,nj->ni", RcT, np.einsum("nij,nj->ni", RaT, d_a + np.cross(e_a, r_a)))
    dev_c = np.einsum("nij,nj->ni", RcT, d_c + np.cross(e_c, r_c))
    return -(dev_a + dev_c) * 1e3


def test_five_axis_location_errors_equal_iso_230_7_first_order():
    mt = load_machine("five-axis-ac")
    loc = ("dy_oa", "dz_oa", "ey_oa", "ez_oa", "dx_oc", "dy_oc", "ex_oc", "ey_oc")
    assert tuple(s.name for s in mt.slots if s.kind == "location") == loc
    assert tuple(s.iso for s in mt.slots if s.kind == "location") == (
        "EY0A", "EZ0A", "EB0A", "EC0A", "EX0C", "EY0C", "EA0C", "EB0C")
    rng = np.random.default_rng(71)
    n = 5000
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (n, 5))
    unit = rng.uniform(-1.0, 1.0, (n, len(loc)))
    lever_mm = np.linalg.norm(mt.nominal(ax), axis=1).max() + mt.geometry["a_height"]
    remainders = []
    for scale in ISO_SCALES:
        vals = np.zeros((n, len(mt.slots)))
        for j, k in enumerate(loc):
            vals[:, mt.slot_names.index(k)] = scale * unit[:, j]
        v = {k: vals[:, mt.slot_names.index(k)] for k in loc}
        exact = mt.spatial_error(ax, vals)
        first = _iso230_7_first_order(mt.geometry, ax, v)
        rem = np.abs(exact - first).max()
        eps, delta = scale * 1e-6, scale * 1e-3
        assert rem < ISO_REMAINDER_FACTOR * eps * (delta + eps * lever_mm) * 1e3
        assert np.abs(first).max() > 1e3 * rem   # the formula carries the effect, the remainder is tiny
        remainders.append(rem)
    assert remainders[0] / remainders[1] > QUADRATIC_RATIO_MIN


@pytest.mark.parametrize("name", ["five-axis-ac", "lathe-xzc"])
def test_builtin_field_jacobian_matches_finite_differences(name):
    mt = load_machine(name)
    f = ChainField(mt, ChainElementSet.random(mt, 5, 25.0, 9))
    rng = np.random.default_rng(6)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (100, len(mt.axes)))
    _, J = f.predict_and_jacobian(ax)
    for j in range(len(mt.axes)):
        d = np.zeros(len(mt.axes))
        d[j] = FD_STEP
        fd = (f.predict(ax + d) - f.predict(ax - d)) / (2 * FD_STEP)
        assert np.abs(J[:, :, j] - fd).max() < FD_TOL_REL * max(1.0, np.abs(J).max())


def test_full_turn_axis_is_periodic():
    mt = load_machine("lathe-xzc")
    f = ChainField(mt, ChainElementSet.random(mt, 8, 25.0, 9))
    rng = np.random.default_rng(9)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (200, 3))
    turned = ax.copy()
    turned[:, 2] += 720.0
    np.testing.assert_allclose(f.predict(turned), f.predict(ax), rtol=0, atol=1e-9)


# -- bad machine files (point 7) ----------------------------------------------------------------
MILL = Path(load_machine("mill-xyz").path).read_text()
FIVE = Path(load_machine("five-axis-ac").path).read_text()

BAD = {
    "unknown joint type": (MILL, 'joint = "linear"\naxis = "Y"', 'joint = "helical"\naxis = "Y"',
                           ["work[0].joint", "unknown joint type"]),
    "duplicate axis word": (MILL, 'axis = "X"', 'axis = "Y"', ["work[1].axis", "duplicate axis word"]),
    "non-orthonormal rotation": (MILL, "[targets]", "[[tool]]\nrotation = [[1, 0, 0], [0, 1, 0.1], [0, 0, 1]]\n\n"
                                 "[targets]", ["tool[3].rotation", "orthonormal"]),
    "zero stroke": (MILL, "stroke = [0.0, 600.0]", "stroke = [600.0, 600.0]", ["work[1].stroke", "zero or inverted"]),
    "inverted stroke": (MILL, "stroke = [0.0, 600.0]", "stroke = [600.0, 0.0]", ["work[1].stroke", "zero or inverted"]),
    "error slot on a fixed transform": (MILL, 'tz = "table_height"', 'tz = "table_height"\nerror = "dz"',
                                        ["work[2].error", "fixed transform"]),
    "degrees where mm are expected": (MILL, "stroke = [0.0, 600.0]", 'stroke = [0.0, 600.0]\nunit = "deg"',
                                      ["work[1].unit", "degrees where mm"]),
    "unknown slot name": (MILL, "stroke = [0.0, 600.0]", 'stroke = [0.0, 600.0]\nerrors = ["dx", "exx"]',
                          ["work[1].errors", "unknown component error 'exx'"]),
    "rotary stroke in radians": (FIVE, "stroke = [-120.0, 30.0]", "stroke = [-2.1, 0.5]",
                                 ["work[1].stroke", "radians"]),
    "linear word on a rotary joint": (FIVE, 'axis = "A"', 'axis = "U"', ["work[1].axis", "linear"]),
    "unknown key": (MILL, "stroke = [0.0, 600.0]", "strok = [0.0, 600.0]", ["work[1]", "strok"]),
    "unknown geometry name": (MILL, 'tz = "table_height"', 'tz = "table_hieght"', ["work[2].tz", "table_hieght"]),
    "target on a missing axis": (MILL, "Y = [[-250.0", "B = [[-250.0", ["targets.B"]),
    "schema": (MILL, "schema = 1", "schema = 2", ["machine.schema"]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_machine_file_exit_2_one_line(case, tmp_path, capsys):
    text, old, new, words = BAD[case]
    assert old in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(old, new, 1))
    rc = main(["simulate", "--machine", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1, err
    assert str(bad) in err
    for w in words:
        assert w in err, (w, err)


def test_bad_machine_file_through_the_command(tmp_path):
    """The installed command path (a fresh process), not only main()."""
    bad = tmp_path / "bad.toml"
    bad.write_text(MILL.replace('axis = "X"', 'axis = "Y"', 1))
    r = subprocess.run([sys.executable, "-m", "compensation.app.cli", "simulate", "--machine", str(bad), "--out",
                        str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "work[1].axis" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("name", ["mill-xyz", "five-axis-ac", "lathe-xzc", "grinder-chain"])
def test_builtin_machine_tool_loads_by_name(name):
    mt = load_machine(name)
    assert mt.kind == "machine-tool" and set(mt.targets) == set(mt.axis_words)
    assert len(set(mt.slot_names)) == len(mt.slot_names)


def test_machines_page_example_loads(tmp_path):
    """The machine files of the how-to and of the reference page load (a block may carry a title)."""
    import re
    docs = Path(__file__).resolve().parents[1] / "docs"
    text = "".join((docs / page).read_text(encoding="utf-8")
                   for page in ("how-to/machine-file.md", "reference/machine-tool-chains.md"))
    blocks = re.findall(r"```toml(?:[ \t]+title=\"[^\"]*\")?\n(.*?)```", text, flags=re.S)
    assert len(blocks) >= 2
    for i, b in enumerate(blocks):
        p = tmp_path / f"m{i}.toml"
        p.write_text(b, encoding="utf-8")
        assert load_machine(p).kind == "machine-tool"


@pytest.mark.slow  # 60 examples per file: up to ~5 s each on the shared cores
@pytest.mark.parametrize("name", ["mill-xyz", "five-axis-ac", "grinder-chain"])
def test_fuzz_machine_tool_files(name):
    """Mangled chain files (values, dropped and extra lines, stray bytes): loaded or refused with
    the project's error naming the file, never another exception (the fuzz of test_fuzz_inputs)."""
    from hypothesis import given
    from hypothesis import strategies as st
    from test_fuzz_inputs import FUZZ, mangled_toml, reads_or_refuses

    text = Path(load_machine(name).path).read_text(encoding="utf-8")

    @FUZZ
    @given(data=st.data())
    def fuzz(data):
        reads_or_refuses(load_machine, data.draw(mangled_toml(text)), ".toml")

    fuzz()


def test_grinder_command_refuses_a_valid_chain_file_by_kind(tmp_path, capsys):
    """Commands not yet generic over chains refuse a machine-tool file in one line naming its kind
    (never run it as a grinder)."""
    rc = main(["demo", "--machine", "mill-xyz", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert "mill-xyz.toml" in err and "(machine-tool 'mill-xyz')" in err and "not yet:" in err
    assert not (tmp_path / "o").exists()
