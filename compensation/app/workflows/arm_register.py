"""``volcomp register poses.csv --machine ur5 --model DIR/calibration.json --out DIR2``: a calibrated arm in a new
measurement session. Only the tracker → base frame (``--tool``: and the tool point) is fitted on the session's
poses (:func:`errormap.arm_register.register_frame`); every link parameter, joint slot and learned stage of the
calibration is kept. With ``--fit-poses N`` the first N poses (file order) register and the rest are held out:
their measured residual (measured − model, position norm) is reported for the registered model and, beside it,
for the calibration as it was. Writes ``DIR2/calibration.json``: the calibration with the registered frame and a
``registration`` key (the frame's slots with standard errors, the poses that would pin it best, the figures)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from errormap.arm_poses import read_arm_poses, temperature_summary
from errormap.arm_register import MIN_POSES, register_frame
from errormap.io import InputError, read_document_text, write_json
from training.arm_residual import RotatedResidual

from compensation.app.validate import UsageError

from .arm_calibration import STACKED, errors_mm, load_arm_model, stage_name


def _row(e) -> dict | None:
    return None if e is None else {"mean_mm": float(e.mean()), "rms_mm": float(np.sqrt(np.mean(e ** 2))),
                                   "max_mm": float(e.max()), "n": int(len(e))}


def _temperature_change(doc, data) -> float | None:
    """The session's mean logged temperature minus the calibration's (°C), where both files carry ``temp_c``."""
    cal = doc.get("temperature_c")
    now = temperature_summary(data)
    if not isinstance(cal, dict) or now is None or not isinstance(cal.get("mean"), (int, float)):
        return None
    return now["mean"] - float(cal["mean"])


def run_arm_register(chain, poses, model, out, tool: bool = False, fit_poses: int | None = None, seed: int = 0,
                     log=None, allow_failed_verdict: bool = False) -> dict:
    """Register the calibration ``model`` on the poses file ``poses``; write ``out/calibration.json``; returns its
    ``registration`` dict. A calibration whose verdict failed is refused (InputError naming it and the reasons)
    unless ``allow_failed_verdict`` (``--allow failed-verdict``): then ``registration.allowed`` records it, and the
    calibration's own failed verdict stays in the output (every later use refuses it again unless allowed)."""
    from ...fields import FAILED_VERDICT, check_verdict
    geo, learner = load_arm_model(chain, model)          # refuses what is not an arm calibration of this chain
    verdict = check_verdict(model, allow_failed_verdict)
    doc = json.loads(read_document_text(model, "an arm calibration"))
    if doc.get("kept_stage") == STACKED:
        raise InputError(f"{model}: key 'kept_stage': a stacked stage (two pipelines) is not re-registered; "
                         "calibrate with a single kept pipeline")
    across = doc.get("across_blocks") if isinstance(doc.get("across_blocks"), dict) else {}
    had_learner = learner is not None
    dropped = had_learner and across.get("learned_carried") is False
    if dropped:                          # helps inside the calibration's session only: not carried to this one
        learner = None
    data = read_arm_poses(poses, chain)
    n_fit = len(data) if fit_poses is None else int(fit_poses)
    if not MIN_POSES <= n_fit <= len(data):
        raise UsageError(f"--fit-poses: {n_fit} of {len(data)} poses in {poses}; a registration takes "
                         f"{MIN_POSES} to all of them")
    fit, rest = data.subset(np.arange(n_fit)), data.subset(np.arange(n_fit, len(data)))
    reg = register_frame(geo.chain, geo.params, fit, learner, tool=tool, seed=seed)
    new = dataclasses.replace(geo, params=reg.params)
    turned = isinstance(learner, RotatedResidual)       # a session's model registered again
    R_total = reg.learned_rotation @ (learner.R if turned else np.eye(3))
    new_learner = None if learner is None else RotatedResidual(learner.learner if turned else learner, R_total)
    e_after = e_before = None
    if len(rest):
        e_after = errors_mm(rest, new.predict(rest.q) + (0.0 if learner is None else new_learner.predict(rest.q)))
        e_before = errors_mm(rest, geo.predict(rest.q) + (0.0 if learner is None else learner.predict(rest.q)))
    out_doc = dict(doc)
    out_doc["geometric"] = {**new.to_dict(), "cv_table": doc["geometric"].get("cv_table", [])}
    if dropped:
        out_doc["kept_stage"] = ("plain geometric LSQ" if geo.method == "plain least squares"
                                 else stage_name(geo.model))
        out_doc["learned"] = None
    reg_doc = {**reg.to_dict(chain.joint_columns), "learned_rotation": R_total.tolist()}
    out_doc["registration"] = {
        "poses_file": str(poses), "n_fit_poses": n_fit, "n_heldout_poses": len(rest), "fitted": "base" + "+tool" * tool,
        "frames": {"base.*": "tracker (world) → robot base of this session", "tool.*": "tool point in the flange frame",
                   "link*, compliance.*, harmonic.*, table.*, learned": "kept from the calibration",
                   "learned_rotation": "turns the learned residual from the calibration's instrument frame into "
                                       "this session's"},
        **reg_doc,
        "heldout_registered": _row(e_after), "heldout_as_calibrated": _row(e_before),
        "allowed": (f"{FAILED_VERDICT} ({verdict['file']}: verdict failed: "
                    f"{'; '.join(verdict['reasons']) or 'no reasons recorded'})"
                    if verdict and verdict.get("overridden_by") else None),
        "learned_carried": not dropped if had_learner else None,
        "learned_why": across.get("why"),
        "temperature_c": temperature_summary(data), "temperature_change_c": _temperature_change(doc, data),
        "residual_kind": "measured residual (measured − model) on the session's poses after the first n_fit_poses, "
                         "position norm, mm"}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "calibration.json", out_doc)
    return out_doc["registration"]
