"""Turning mode on lathe-xzc (compensation/turning.py): while the spindle turns, X and Z compensate the
tool point against the surface of revolution and C is never written; C is solved only in C-axis mode.

The truth is a seeded element set of the lathe's chain (±10 μm / μrad, tests/test_chain_compensate.py); the
model is the truth with seeded noise (``ESTIMATE_NOISE_UM``, as the mill's test) and, for the oracle, the
truth itself. TRUE residual: the truth machine's tool tip at the written axes, radial and axial deviation
from the programmed surface of revolution, mean over one spindle turn."""
import json
import re

import numpy as np
import pytest
from compensation.app.cli import main
from compensation.turning import TOL_UM, solve_turning, spindle_turning, surface_residual_um
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField

from test_chain_compensate import chain_elements

LATHE = "lathe-xzc"
ESTIMATE_NOISE_UM = 0.3
"""The model's element values differ from the truth's by this (1 σ), as in the mill's test."""
TRUE_AFTER_MAX_UM = 1.5
"""TRUE residual after with that model: the noise's effect on r and z (a few 0.3 μm elements summed over the
chain, with the levers of the tool point; observed 1.12 μm max, rms 0.61 μm)."""
ORACLE_TRUE_UM = 2 * TOL_UM
"""With the truth as the model the TRUE residual is the solver's tolerance (|g| ≤ TOL_UM), twice for the
finite-difference re-evaluation."""
UNCOMPENSATED_MIN_UM = 10.0
"""The uncompensated error of the ±10 μm truth along the program is tens of μm (observed 33 μm max)."""

TURNING = ("%\nO2000 (TURNING: FACE, TURN, ARC, SHOULDER)\nG18 G90 G21\nT1 M6\nG0 X90. Z360.\nG96 S180 M3\n"
           "G1 X60. Z350. F0.2\nG1 Z280.\nG2 X80. Z260. I20. K0.\nG1 X120. (SHOULDER)\nG1 Z200.\nG0 X150.\n"
           "M5\nM30\n%\n")
MOVES = {7, 8, 9, 10, 11}
"""1-based lines of the compensated cutting moves (G1/G2; the G0 rapids are kept as written)."""
MIXED = ("%\nG18 G90 G21\nG0 X80. Z350. C0.\nS1000 M3\nG1 X60. Z320. F0.2\nG1 Z260.\nM5\n"
         "G1 X60. Z260. C90. F100.\nG1 Z250. C180.\nM30\n%\n")


def _noisy(v, rng):
    """Element values with noise; a closed profile (C: value at 360° = value at 0°) stays closed."""
    out = v + rng.normal(0.0, ESTIMATE_NOISE_UM, v.shape)
    if abs(v[-1] - v[0]) < 1e-12:
        out[-1] = out[0]
    return out


@pytest.fixture(scope="module")
def lathe_models(tmp_path_factory):
    d = tmp_path_factory.mktemp("lathe")
    mt = load_machine(LATHE)
    truth = chain_elements(mt, 301, scale=10.0)
    rng = np.random.default_rng(302)
    est = ChainElementSet(mt, truth.stations, {k: _noisy(v, rng) for k, v in truth.functions.items()},
                          {k: v + rng.normal(0.0, ESTIMATE_NOISE_UM) for k, v in truth.constants.items()})
    return truth.save(d / "truth.json"), est.save(d / "est.json")


def test_the_spindle_state_follows_the_machine_files_codes():
    spindle = load_machine(LATHE).spindle
    # x_words unset: no manual settles the built-in's control
    assert spindle == {"axis": "C", "turning_on": (3, 4), "turning_off": (5,), "x_words": None}
    lines = TURNING.splitlines(keepends=True)
    on = spindle_turning(lines, spindle)
    assert [i + 1 for i in np.flatnonzero(on)] == list(range(6, 13))  # from 'G96 S180 M3' to before 'M5'


def test_solver_hits_the_surface_and_leaves_c_alone():
    mt = load_machine(LATHE)
    f = ChainField(mt, chain_elements(mt, 303, scale=10.0))
    rng = np.random.default_rng(304)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (300, 3))
    ax[:, 0] = rng.uniform(5.0, 200.0, 300)
    q, res, conv, spread, _ = solve_turning(f, mt, ax, ball_um=250.0)
    assert conv.all() and np.array_equal(q[:, 2], ax[:, 2])
    mean, _ = surface_residual_um(f, mt, q, ax)  # independently re-evaluated at the returned axes
    assert np.abs(mean).max() <= ORACLE_TRUE_UM and np.abs(res[:, [0, 2]] - mean).max() < 1e-9
    before, _ = surface_residual_um(f, mt, ax, ax)
    assert np.abs(before).max() > UNCOMPENSATED_MIN_UM


def _compensate(tmp_path, text, model, truth, name):
    prog = tmp_path / f"{name}.nc"
    prog.write_text(text)
    out = tmp_path / f"o_{name}"
    assert main(["compensate", "--work-offsets", "machine",
                 str(prog), "--machine", LATHE, "--model", str(model), "--method", "exact",
                 "--truth", str(truth), "--out", str(out)]) == 0
    entry = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    return entry, (out / prog.name).read_text().splitlines(keepends=True)


def test_turning_program_no_c_on_any_cutting_move_and_true_residual(tmp_path, lathe_models):
    truth, est = lathe_models
    entry, out = _compensate(tmp_path, TURNING, est, truth, "turn")
    src = TURNING.splitlines(keepends=True)
    assert not any(re.search(r"C[-+.\d]", re.sub(r"\([^)]*\)", "", ln)) for ln in out)  # C never written
    kept = [ln for i, ln in enumerate(src, 1) if i not in MOVES]
    it = iter(out)
    assert all(any(o == ln for o in it) for ln in kept)  # every other line byte for byte, in order
    t = entry["turning"]
    assert t["points"] == entry["points"] and entry["failures"] == 0
    assert t["true"]["max_um"] < TRUE_AFTER_MAX_UM < UNCOMPENSATED_MIN_UM < t["true_uncompensated"]["max_um"]
    assert "turning mode" in entry["note"] and entry["kept_axes"] == ["c_deg"]
    oracle, _ = _compensate(tmp_path, TURNING, truth, truth, "turn_oracle")
    assert oracle["turning"]["true"]["max_um"] <= ORACLE_TRUE_UM


def test_mixed_program_c_solved_only_in_c_axis_mode(tmp_path, lathe_models):
    truth, est = lathe_models
    entry, out = _compensate(tmp_path, MIXED, truth, truth, "mixed")
    body = [re.sub(r"\([^)]*\)", "", ln) for ln in out]
    i_on, i_off = next(i for i, ln in enumerate(body) if "M3" in ln), next(i for i, ln in enumerate(body) if "M5" in ln)
    assert not any("C" in ln for ln in body[i_on:i_off])  # turning: C untouched
    c_words = [float(m) for ln in body[i_off:] for m in re.findall(r"C(-?\d+\.\d+)", ln)]
    assert c_words and any(abs(c - round(c)) > 1e-6 for c in c_words)  # C-axis mode: C solved (corrected)
    assert 2 <= entry["turning"]["points"] < entry["points"] and entry["failures"] == 0
    assert entry["true"]["max_um"] <= ORACLE_TRUE_UM


def test_a_c_word_while_the_spindle_turns_is_refused(tmp_path, lathe_models, capsys):
    truth, _ = lathe_models
    prog = tmp_path / "bad.nc"
    prog.write_text("G18 G90 G21\nG0 X80. Z350. C0.\nS800 M4\nG1 X60. Z320. C45. F0.2\nM30\n")
    assert main(["compensate", "--work-offsets", "machine",
                 str(prog), "--machine", LATHE, "--model", str(truth), "--method", "exact",
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{prog}: line 4, column 15: 'C45.' while the spindle turns" in err and "M5" in err


NEAREST_UM = 0.05
"""The tip crossing the slide's plane at the axis is the least mean radius up to second order in the tip's wobble
over the turn (observed 0.003 μm above the scan's least)."""
AXIS_SCAN_UM = np.arange(-150.0, 150.01, 0.5)
"""X offsets (μm) scanned about a programmed point on the spindle axis: wider than the chain's error there (the
±10 μm truth leaves tens of μm)."""


def test_points_across_the_spindle_axis_converge_the_axis_itself_is_written_at_the_closest_approach():
    """A turning program crossing X = 0 (X < 0 is inside lathe-xzc's stroke, -20..200 mm): on both sides of the axis
    every point reaches its surface of revolution; on the axis (radius 0) no X and Z bring the tip nearer than its
    centre-height error (checked by a scan of X): written where the tip passes nearest the axis, listed apart, not a
    convergence violation."""
    from compensation.turning import height_um, unreachable_radius
    mt = load_machine(LATHE)
    f = ChainField(mt, chain_elements(mt, 303, scale=10.0))
    xs = np.array([-5.0, -1.0, -0.2, 0.2, 1.0, 5.0, 0.0])
    ax = np.stack([xs, np.full(len(xs), 230.0), np.zeros(len(xs))], axis=1)
    q, res, conv, _, _ = solve_turning(f, mt, ax, ball_um=250.0)
    mean, _ = surface_residual_um(f, mt, q, ax)
    assert conv[:-1].all() and np.abs(mean[:-1]).max() <= ORACLE_TRUE_UM
    assert np.all(np.sign(q[:-1, 0]) == np.sign(xs[:-1]))  # each side of the axis stays on its side
    hit, heights, nearest = unreachable_radius(f, mt, q, ax, np.flatnonzero(~conv))
    h = float(height_um(f, mt, q[6:])[0])
    assert hit.tolist() == [6] and heights.tolist() == height_um(f, mt, nearest).tolist()  # where it is written
    scan = np.repeat(ax[6:], len(AXIS_SCAN_UM), axis=0)
    scan[:, 0] += AXIS_SCAN_UM * 1e-3
    radius = surface_residual_um(f, mt, scan, np.repeat(ax[6:], len(AXIS_SCAN_UM), axis=0))[0][:, 0]
    assert h > 1.0 and radius.min() >= h - 1e-6  # no X reaches nearer the axis than the height error
    at_nearest = surface_residual_um(f, mt, nearest, ax[6:])[0][0]  # where it is written
    assert at_nearest[0] <= radius.min() + NEAREST_UM and abs(at_nearest[1]) <= ORACLE_TRUE_UM
    from compensation.guards import convergence_violations
    from compensation.turning import nominal_by_tool, solve_with_turning
    res = solve_with_turning(None, f, mt, nominal_by_tool(mt, ax, None), ax, np.ones(len(ax), bool), 250.0)
    assert res.success.tolist() == [True] * 6 + [False] and res.info["spindle_axis"] == {6: heights[0]}
    assert np.array_equal(res.axes[6:], nearest) and res.residual_um[6, 0] == at_nearest[0]  # written there
    bad, _ = convergence_violations(res)
    assert bad.tolist() == []  # not a solver failure: the guard does not count it
    res.success[2] = False  # a real non-convergence elsewhere still is one
    assert convergence_violations(res)[0].tolist() == [2]
