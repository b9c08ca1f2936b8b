"""The grinder's user's path on an out-of-catalogue bump (the session-shared run of tests/shared_runs.py):
the learned stage kept and compensated with, and `volcomp diagnose`'s files are the in-memory core's result.
One unit with tests/test_tracking_learned_residual.py under the slow tier's ``--dist loadscope``
(``SAME_WORKER``, tests/conftest.py), split from tests/test_hybrid.py so that its other slow tests can run on
the other worker."""
import json

import numpy as np
import pytest

from compensation.diagnosed_model import load_diagnosed_model
from errormap.machine import load_machine
from errormap.simulator import random_axes
from shared_runs import private_copy
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
    assert s["rms_final_um"] <= HELD_OUT_FLOOR_FACTOR * np.sqrt(3) * s["update"]["check_noise_sigma_um"]
    cover = s["learned_residual"]["held_out_band95_cover_total"]   # the hybrid's total band ⊕ noise
    assert BAND95_COVER_LO <= cover <= BAND95_COVER_HI
    assert "band95_total_um" in s["learned_residual"]["map"]
    model = json.loads((d / "model.json").read_text())
    assert model["format"] == "volcomp-diagnosed-model/1" and model["stage"] == "learned_residual"
    P = random_axes(load_machine(), 100, np.random.default_rng(0))
    lo, hi = np.array(model["learned_residual"]["box_lo"]), np.array(model["learned_residual"]["box_hi"])
    P[:, :2] = lo + (P[:, :2] - P[:, :2].min(0)) / np.ptp(P[:, :2], axis=0) * (hi - lo) * 0.99 + 0.005 * (hi - lo)
    write_csv(tmp_path / "pts.csv", dict(zip(("x_mm", "z_mm", "a_deg"), P.T)), float_fmt="%.12g")
    assert main(["compensate", str(tmp_path / "pts.csv"), "--model", str(d / "model.json"),
                 "--method", "exact", "--out", str(tmp_path / "c"), "--temp-c", "20", "--time-s", "0",
                 "--dir-x", "1", "--dir-z", "1", "--dir-a", "1"]) == 0
    summ = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert summ["model_max_um"] <= EXACT_MODEL_TOL_UM
    assert read_table(tmp_path / "c" / "pts.csv").float("x_mm").shape == (100,)


CORE_FIELD_TOL_UM = 1e-9
"""The core's in-memory fields against those loaded from the files it wrote: the same doubles (JSON and npz
round-trip a double exactly) evaluated by the same code, so only round-off could differ (VALUE_TOL_UM)."""

ANY_CONDITIONS = {"temp_c": 24.0, "time_s": 7200.0, "dir_x": 1.0, "dir_z": -1.0, "dir_a": 1.0}
"""Conditions at which the diagnosed fields are compared (any values; those of the benchmark's flute path)."""


@pytest.mark.slow
def test_run_closed_loop_writes_what_the_in_memory_core_decides(bump_user_path, tmp_path):
    """`volcomp diagnose`'s closed loop is closed_loop_model (in memory) plus writing: diagnosis.json, model.json
    and the element sets are its result byte for byte (with the MLflow run id of the tracked learned residual
    added, as --track adds it), and its kept and loop-alone fields are those `volcomp compensate` builds from
    model.json and from model.json with loop_alone in place of elements and terms and without the learned part.
    The shared run (tests/shared_runs.py) recorded closed_loop_model's result as diagnose ran."""
    from compensation.diagnosed_model import loop_alone_model
    from errormap.io import write_json
    res = bump_user_path.extra["core"]
    d, mine = private_copy(bump_user_path.root / "d", tmp_path / "d"), tmp_path / "mine"
    assert res.learned is not None and res.loop_alone is not None   # the branch that writes every file
    mine.mkdir()
    shared_d = bump_user_path.root / "d"
    rid = json.loads((d / "model.json").read_text())["mlflow_run_id"]
    write_json(mine / "diagnosis.json", dict(res.summary, updated_elements_file=str(shared_d / "updated_elements.json"),
                                             learned_residual=dict(res.summary["learned_residual"], mlflow_run_id=rid)))
    write_json(mine / "model.json", dict(res.model, mlflow_run_id=rid))
    res.ship_cov.elements.save(mine / "updated_elements.json")
    res.loop_alone[0].elements.save(mine / "loop_elements.json")
    for name in ("diagnosis.json", "model.json", "updated_elements.json", "loop_elements.json"):
        assert (mine / name).read_bytes() == (d / name).read_bytes(), name
    model = json.loads((d / "model.json").read_text())
    alone = {k: v for k, v in model.items() if k not in ("learned_residual", "loop_alone", "base_terms_replaced")}
    alone.update(elements=model["loop_alone"]["elements"], stage=model["base_stage"],
                 terms=model["loop_alone"]["terms"] + model.get("base_terms_replaced", []))
    (d / "alone.json").write_text(json.dumps(alone))
    assert loop_alone_model(model)["terms"] == alone["terms"] and loop_alone_model(model)["stage"] == alone["stage"]
    m = load_machine()
    P = random_axes(m, 500, np.random.default_rng(3))
    cond = {k: np.full(len(P), v) for k, v in ANY_CONDITIONS.items()}
    for in_memory, name in ((res.kept_field(m), "model.json"), (res.loop_alone_field(m), "alone.json")):
        from_file = load_diagnosed_model(d / name, m)
        np.testing.assert_allclose(in_memory.predict(P, **cond), from_file.predict(P, **cond), rtol=0,
                                   atol=CORE_FIELD_TOL_UM, err_msg=name)
