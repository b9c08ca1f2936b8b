"""``volcomp calibrate POSES --machine ur5``: the arm calibration run end to end — the poses read (several sessions
in one file moved into one frame, :func:`errormap.arm_sessions.align_sessions`), split into fit and held-out poses,
calibrated (:func:`compensation.app.workflows.arm_calibration.calibrate_arm`), what carries across sessions decided
(:func:`compensation.app.workflows.arm_sessions.session_document`), the verdict; writes ``model.json`` and
``report.html``."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from errormap.arm_calibration import check_pose_set
from errormap.arm_poses import read_arm_poses
from errormap.arm_sessions import align_sessions, apply_alignment
from errormap.io import write_json

from ...calibration_models import calibration_model_document

from ..reports.arm_calibration import write_report
from .arm_calibration import ArmCalibrationSettings, calibrate_arm, held_out_verdict, model_document, stated_sigma_mm
from .calibration import split_poses
from .arm_sessions import session_document


def run_arm_calibration(chain, s: ArmCalibrationSettings, out, log=None) -> dict:
    """Calibrate ``chain`` from ``s.poses``; write ``out/model.json`` and ``out/report.html``."""
    log = sys.stderr if log is None else log
    data = read_arm_poses(s.poses, chain)
    moves, frames = None, None
    if data.session is not None and len(set(data.session)) > 1:       # several sessions: one frame, the reference's
        data, moves, frames = align_sessions(chain, data)
    check_pose_set(chain, data)
    fit, check = split_poses(chain, s, data, read_arm_poses)
    if moves is not None:
        fit = fit.subset(np.argsort(fit.rows, kind="stable"))     # file order: a session's first poses register
        if s.check:
            check = apply_alignment(check, moves, "held-out poses")
    check_pose_set(chain, fit)
    print(f"calibrate: {len(fit)} fit poses, {len(check)} held-out poses, machine {chain.name}"
          + (f", {len(moves)} sessions" if moves else "")
          + (", 6-DoF: orientation rows in the fit" if fit.rot is not None else ", position only"), file=log)
    core = calibrate_arm(chain, fit, check, learned=s.learned, k_folds=s.k_folds, n_restarts=s.n_restarts,
                         seed=s.seed, log=log)
    doc = model_document(chain, core, s, len(fit), len(check))
    doc["measured"] = "position and orientation (6-DoF)" if fit.rot is not None else "position"
    if moves is not None:
        doc["across_sessions"] = session_document(
            chain, fit, core, frames, s, lambda m: print(f"calibrate: {m}", file=log, flush=True))
    doc["verdict"] = held_out_verdict(core, check, stated_sigma_mm(s, check))   # failed: calibrate exits 1
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "model.json", calibration_model_document(
        "arm", chain, doc, {"written_by": "volcomp calibrate", "poses": str(s.poses), "check": s.check}))
    write_report(doc, chain, core, check, out)
    return doc
