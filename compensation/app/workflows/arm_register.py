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
from errormap.arm_register import MIN_POSES, choose_candidate, register_frame, registered_point
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


PLAIN = "plain geometric LSQ"
"""Name of the plain calibration (``calibration.json`` key ``plain_geometric``) among the candidates register weighs."""


def plain_of(chain, doc, model):
    """The plain least-squares calibration kept beside the model (key ``plain_geometric``); InputError without it."""
    from errormap.arm_calibration import GeometricResult
    d = doc.get("plain_geometric")
    if not isinstance(d, dict):
        raise InputError(f"{model}: key 'plain_geometric': missing (written before register weighed the model "
                         "against the plain calibration); calibrate again")
    try:
        return GeometricResult.from_dict(chain, d)
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise InputError(f"{model}: key 'plain_geometric': {exc}") from None


def candidates_of(doc, geo, learner, plain) -> list:
    """(name, chain, params, learner) of the models register weighs, plainest first: the plain calibration, the
    kept geometric stage alone (where it is not the plain one), the kept stage with its learned residual (where one
    is carried)."""
    out = [(PLAIN, plain.chain, plain.params, None)]
    geo_name = PLAIN if geo.method == "plain least squares" else stage_name(geo.model)
    if geo_name != PLAIN:
        out.append((geo_name, geo.chain, geo.params, None))
    if learner is not None:
        out.append((doc["kept_stage"], geo.chain, geo.params, learner))
    return out


def run_arm_register(chain, poses, model, out, tool: bool = False, fit_poses: int | None = None, seed: int = 0,
                     log=None) -> dict:
    """Register the calibration ``model`` on the poses file ``poses``; write ``out/calibration.json``; returns its
    ``registration`` dict. The model kept for the session is weighed against the plain calibration inside the
    registration poses (:func:`errormap.arm_register.choose_candidate`)."""
    geo, learner = load_arm_model(chain, model)          # refuses what is not an arm calibration of this chain
    doc = json.loads(read_document_text(model, "an arm calibration"))
    if doc.get("kept_stage") == STACKED:
        raise InputError(f"{model}: key 'kept_stage': a stacked stage (two pipelines) is not re-registered; "
                         "calibrate with a single kept pipeline")
    plain = plain_of(chain, doc, model)
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
    cands = candidates_of(doc, geo, learner, plain)
    choice = choose_candidate(cands, fit, tool=tool)
    regs = {}
    for name, ch, params, lrn in cands:
        regs[name] = register_frame(ch, params, fit, lrn, tool=tool, seed=seed)
    kept = choice["kept"]
    k_chain, _, _, k_learner = next(c for c in cands if c[0] == kept)
    reg = regs[kept]
    turned = isinstance(k_learner, RotatedResidual)       # a session's model registered again
    R_total = reg.learned_rotation @ (k_learner.R if turned else np.eye(3))
    heldout = {}
    if len(rest):
        for name, ch, _, lrn in cands:
            heldout[name] = _row(errors_mm(rest, registered_point(ch, regs[name].params, lrn,
                                                                  regs[name].learned_rotation, rest.q)))
    e_before = None if not len(rest) else errors_mm(
        rest, geo.predict(rest.q) + (0.0 if learner is None else learner.predict(rest.q)))
    out_doc = dict(doc)
    kept_geo = plain if kept == PLAIN else geo
    new = dataclasses.replace(kept_geo, params=reg.params)
    out_doc["geometric"] = {**new.to_dict(), "cv_table": doc["geometric"].get("cv_table", [])}
    out_doc["plain_geometric"] = dataclasses.replace(plain, params=regs[PLAIN].params).to_dict()
    if k_learner is None and (had_learner or kept == PLAIN):
        out_doc["kept_stage"] = PLAIN if kept == PLAIN else stage_name(geo.model)
        out_doc["learned"] = None
    reg_doc = {**reg.to_dict(chain.joint_columns), "learned_rotation": R_total.tolist()}
    out_doc["registration"] = {
        "poses_file": str(poses), "n_fit_poses": n_fit, "n_heldout_poses": len(rest), "fitted": "base" + "+tool" * tool,
        "kept": kept, "kept_is_plain_fallback": kept == PLAIN, "kept_why": choice["why"], "decision_cv": choice["cv"],
        "frames": {"base.*": "tracker (world) → robot base of this session", "tool.*": "tool point in the flange frame",
                   "link*, compliance.*, harmonic.*, table.*, learned": "kept from the calibration",
                   "plain_geometric": "the plain calibration, its base frame registered on the same poses",
                   "learned_rotation": "turns the learned residual from the calibration's instrument frame into "
                                       "this session's"},
        **reg_doc,
        "heldout_registered": heldout.get(kept), "heldout_by_candidate": heldout or None,
        "heldout_as_calibrated": _row(e_before),
        "learned_carried": (not dropped and k_learner is not None) if had_learner else None,
        "learned_why": across.get("why") if dropped else (choice["why"] if had_learner else None),
        "temperature_c": temperature_summary(data), "temperature_change_c": _temperature_change(doc, data),
        "residual_kind": "measured residual (measured − model) on the session's poses after the first n_fit_poses, "
                         "position norm, mm"}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "calibration.json", out_doc)
    return out_doc["registration"]
