"""Issue 26, the lathe: the rotary continuity guard of the exact chain solver.

A solved rotary axis (the lathe's C) may differ from its programmed value by at most
``min(degrees(asin(min(1, b/r))), limit)``: ``b`` the 250 μm ball, ``r`` the target's distance from
the axis (from the chain's axis Jacobian), ``limit`` the ``--max-rotary-correction-deg`` option.
Beyond it the point is refused (unsolved, programmed axes kept, a reason naming the line), never
silently swung."""
import json

import numpy as np
import pytest
from compensation.app.cli import main
from compensation.solvers.chain_exact import rotary_bound_deg, rotary_radius_mm, solve_exact_chain
from errormap.machine import load_machine
from errormap.chain_field import ChainField
from errormap.chain_kernel import NominalChain

from test_chain_compensate import TOL_MODEL_RESIDUAL_UM, chain_elements

LATHE = "lathe-xzc"
BOUND_TOL_DEG = 1e-12
"""The formula's values are closed form (asin of an exact ratio): equal to round-off."""
RADIUS_TOL_MM = 1e-9
"""|∂p/∂C|·180/π against |X| on the lathe (the tool tip on the spindle centre height): round-off."""
FAR_MM = 5.0
"""'Far' from the spindle axis: |X| ≥ 5 mm. There a ±20 μm error needs ≲ 1° of C, the bound is
asin(0.25/5) = 2.9°: no point may be refused."""
NEAR_MM = 0.5
"""'Near' the spindle axis: |X| < 0.5 mm (2 ball radii), where Newton may swing C by up to ~130°."""
LIMIT_DEG = 10.0
"""A user limit tighter than the ball's 90° near the axis (refuses more points, every kept one within it)."""


def test_bound_formula():
    b = 250.0
    r = np.array([0.0, 0.1, 0.25, 0.5, 1.0, 5.0, 100.0])
    want = np.degrees(np.arcsin(np.minimum(1.0, 0.25 / np.where(r > 0, r, 1e-300))))
    assert np.abs(rotary_bound_deg(r, b) - want).max() < BOUND_TOL_DEG
    assert rotary_bound_deg(np.array([0.1]), b)[0] == 90.0  # the ball holds the axis: 90° reach every ball point
    assert abs(rotary_bound_deg(np.array([1.0]), b)[0] - np.degrees(np.arcsin(0.25))) < BOUND_TOL_DEG  # 14.48°
    assert np.all(rotary_bound_deg(r, b, LIMIT_DEG) <= LIMIT_DEG)
    for bad in (0.0, -1.0, 181.0, float("nan")):
        with pytest.raises(ValueError, match="rotary correction limit"):
            rotary_bound_deg(r, b, bad)


def test_radius_from_the_chain_is_the_distance_from_the_spindle_axis():
    mt = load_machine(LATHE)
    ax = np.random.default_rng(31).uniform(mt.stroke_lo, mt.stroke_hi, (200, 3))
    _, J = NominalChain(mt).forward_and_jacobian(ax)
    assert np.abs(rotary_radius_mm(J[:, :, 2]) - np.abs(ax[:, 0])).max() < RADIUS_TOL_MM


def _points(rng, mt, n, near):
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (n, 3))
    if near:
        ax[:, 0] = rng.uniform(-NEAR_MM, NEAR_MM, n)
    else:
        ax[:, 0] = np.where(np.abs(ax[:, 0]) < FAR_MM, np.sign(ax[:, 0] + 1e-12) * FAR_MM, ax[:, 0])
    return ax


@pytest.mark.parametrize("limit", [None, LIMIT_DEG])
def test_guard_near_and_far_from_the_spindle_axis(limit):
    mt = load_machine(LATHE)
    f = ChainField(mt, chain_elements(mt, 23))
    rng = np.random.default_rng(24)
    counts = {}
    for near in (False, True):
        ax = _points(rng, mt, 400, near)
        targets = mt.nominal(ax)
        r = solve_exact_chain(f, targets, mt, target_axes=ax, progress=False, rotary_limit_deg=limit)
        ref = r.info["rotary_refused"]
        counts[near] = len(ref)
        _, J = NominalChain(mt).forward_and_jacobian(ax)
        bound = rotary_bound_deg(rotary_radius_mm(J[:, :, 2]), 250.0, limit)
        swing = np.abs(r.axes[:, 2] - ax[:, 2])
        ok = np.setdiff1d(np.arange(len(ax)), ref)
        assert np.all(swing[ok] <= bound[ok] * (1 + BOUND_TOL_DEG))       # every kept point within its bound
        assert np.array_equal(r.axes[ref], ax[ref]) and not r.success[ref].any()  # refused: programmed, unsolved
        assert len(r.info["rotary_reasons"]) == len(ref)
        assert all(t.startswith("rotary continuity: c_deg would turn by") for t in r.info["rotary_reasons"])
        model = np.linalg.norm((mt.nominal(r.axes) - targets) * 1e3 + f.predict(r.axes), axis=1)
        assert np.all(model[r.success] < TOL_MODEL_RESIDUAL_UM)
        assert np.array_equal(r.success, (model <= r.info["tol_um"]) & ~np.isin(np.arange(len(ax)), ref))
    assert counts[False] == 0  # far from the axis nothing is refused
    assert counts[True] > 0    # near it some swings are caught (observed 2 of 400 by the ball, 95 with 10°)
    if limit is not None:
        assert counts[True] > 2


def test_mill_and_five_axis_have_no_rotary_guard():
    for name in ("mill-xyz", "five-axis-ac"):
        mt = load_machine(name)
        f = ChainField(mt, chain_elements(mt, 5))
        ax = np.random.default_rng(6).uniform(mt.stroke_lo, mt.stroke_hi, (20, len(mt.axes)))
        r = solve_exact_chain(f, mt.nominal(ax), mt, target_axes=ax, progress=False)
        assert "rotary_refused" not in r.info and r.success.all()


NEAR_PROGRAM_ROWS = 40


def test_compensate_refuses_a_swung_point_naming_its_line(tmp_path, capsys):
    """A CSV of lathe points near the spindle axis: the swung points refuse the file (exit 3) with a
    reason naming the row; the summary counts them; ``--allow convergence`` writes the programmed
    axes for them (never the swing)."""
    mt = load_machine(LATHE)
    el = chain_elements(mt, 23).save(tmp_path / "el.json")
    rng = np.random.default_rng(41)
    ax = _points(rng, mt, NEAR_PROGRAM_ROWS, near=True)
    path = tmp_path / "near.csv"
    np.savetxt(path, ax, delimiter=",", header="x_mm,z_mm,c_deg", comments="", fmt="%.6f")
    args = ["compensate", str(path), "--machine", LATHE, "--model", str(el), "--method", "exact",
            "--max-rotary-correction-deg", str(LIMIT_DEG)]
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "o1")]) == 3
    cap = capsys.readouterr()
    assert "rotary continuity: c_deg would turn by" in cap.err and "(line " in cap.err
    doc = json.loads((tmp_path / "o1" / "compensate_summary.json").read_text())
    n_ref = doc["files"][0]["rotary_refused"]
    assert n_ref > 0 and doc["files"][0]["rotary_limit_deg"] == LIMIT_DEG
    assert f"rotary continuity: {n_ref} point(s) refused" in cap.out
    assert main(args + ["--out", str(tmp_path / "o2"), "--allow", "convergence"]) == 0
    from errormap.io import read_table
    t = read_table(tmp_path / "o2" / "near.csv")
    c = t.float("c_deg")
    assert np.all(np.abs(c - np.round(ax[:, 2], 6)) <= LIMIT_DEG)  # no swing written beyond the limit


def test_rotary_limit_option_refused_where_nothing_turns(tmp_path, capsys):
    mt = load_machine("mill-xyz")
    el = chain_elements(mt, 7).save(tmp_path / "el.json")
    path = tmp_path / "p.csv"
    np.savetxt(path, np.array([[10.0, 20.0, -30.0]]), delimiter=",", header="x_mm,y_mm,z_mm", comments="",
               fmt="%.6f")
    capsys.readouterr()
    assert main(["compensate", str(path), "--machine", "mill-xyz", "--model", str(el), "--method", "exact",
                 "--max-rotary-correction-deg", "5", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--max-rotary-correction-deg: the solver moves no rotary axis" in err and len(err.strip().splitlines()) == 1
    assert main(["compensate", str(path), "--machine", LATHE, "--model", str(el), "--method", "exact",
                 "--max-rotary-correction-deg", "0", "--out", str(tmp_path / "o")]) == 2
    assert "--max-rotary-correction-deg: expected a number in (0, 180] deg" in capsys.readouterr().err
    # the grinder (the default machine) compensates on its chain, where the exact solver moves A: the bound applies
    from errormap.chain_truth import make_chain_truth
    g = load_machine()
    gel = make_chain_truth(g, 7).elements.save(tmp_path / "grinder_el.json")
    gpath = tmp_path / "g.csv"
    np.savetxt(gpath, np.array([[90.0, 5.0, 10.0], [91.0, 5.0, 20.0]]), delimiter=",", header="x_mm,z_mm,a_deg",
               comments="", fmt="%.6f")
    assert main(["compensate", str(gpath), "--model", str(gel), "--method", "exact", "--max-rotary-correction-deg",
                 "5", "--out", str(tmp_path / "g")]) == 0
    entry = json.loads((tmp_path / "g" / "compensate_summary.json").read_text())["files"][0]
    assert entry["rotary_limit_deg"] == 5.0
