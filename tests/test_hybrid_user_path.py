"""The grinder's user's path on an out-of-catalogue bump (the session-shared run of tests/shared_runs.py):
the learned stage kept and compensated with, and `volcomp diagnose`'s files are the in-memory core's result.
One unit with tests/test_tracking_learned_residual.py under the slow tier's ``--dist loadscope``
(``SAME_WORKER``, tests/conftest.py), split from tests/test_hybrid.py so that its other slow tests can run on
the other worker."""
import json

import numpy as np
import pytest

from errormap.machine import load_machine
from errormap.chain_truth import random_axes
from test_hybrid import EXACT_MODEL_TOL_UM


HELD_OUT_FLOOR_FACTOR = 1.25
"""Issue 28: the kept stage's held-out MEASURED RMS within 1.25 × the noise floor √3·σ̂."""


BAND95_COVER_LO, BAND95_COVER_HI = 0.90, 0.98
"""The issue's target for the 95 % band's coverage on held-out checks (960 components here: the
binomial SE at 95 % is 0.7 %, so the range is not met by chance alone)."""

@pytest.mark.slow
def test_user_path_learns_an_out_of_catalogue_bump_and_compensates_with_it(bump_user_path, tmp_path):
    """sweeps → simulate (bump) → identify → diagnose (the shared run, tests/shared_runs.py): the learned
    stage is kept and beats the loop on the held-out checks; compensate --model DIR/model.json solves the
    hybrid (exact)."""
    from compensation.app.cli import main
    from errormap.io import read_table, write_csv
    d = bump_user_path.root / "d"
    s = json.loads((d / "diagnosis.json").read_text())
    assert s["kept_stage"] == "learned_residual" and s["learned_residual"]["kept"]
    st = s["stages"]
    assert st["learned_residual"]["held_out"]["rms_um"] < st[s["base_stage"]]["held_out"]["rms_um"]
    assert s["held_out_rms_um"] <= HELD_OUT_FLOOR_FACTOR * np.sqrt(3) * s["noise_sigma_um"]
    cover = s["learned_residual"]["held_out_band95_cover"]   # the learned band ⊕ the fitted noise
    assert BAND95_COVER_LO <= cover <= BAND95_COVER_HI
    assert "band95_um" in s["learned_residual"]["map"]
    assert s["learned_residual"]["mlflow_run_id"]   # --track: the kept learned residual is an MLflow run
    model = json.loads((d / "model.json").read_text())
    assert model["format"] == "volcomp-model/1" and model["kept_stage"] == "learned_residual"
    P = random_axes(load_machine(), 100, np.random.default_rng(0))
    lo, hi = np.array(model["learned_residual"]["box_lo"]), np.array(model["learned_residual"]["box_hi"])
    P[:, :2] = lo + (P[:, :2] - P[:, :2].min(0)) / np.ptp(P[:, :2], axis=0) * (hi - lo) * 0.99 + 0.005 * (hi - lo)
    write_csv(tmp_path / "pts.csv", dict(zip(("x_mm", "z_mm", "a_deg"), P.T)), float_fmt="%.12g")
    from compensation.model_file import read_model
    needs = read_model(d / "model.json", load_machine()).field.needs   # the reference conditions of what it needs
    conds = [x for c in needs for x in (f"--{c.replace('_', '-')}", "20" if c == "temp_c" else "1")]
    assert main(["compensate", str(tmp_path / "pts.csv"), "--model", str(d / "model.json"),
                 "--method", "exact", "--out", str(tmp_path / "c"), *conds]) == 0
    summ = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert summ["model_max_um"] <= EXACT_MODEL_TOL_UM
    assert read_table(tmp_path / "c" / "pts.csv").float("x_mm").shape == (100,)
