"""``volcomp register poses.csv --machine ur5 --model DIR/model.json --out DIR2``: a calibrated arm in a new
measurement session. Only the tracker → base frame (``--tool``: and the tool point) is fitted on the session's
poses (:func:`errormap.arm_register.register_frame`); every link parameter, joint slot and learned stage of the
calibration is kept. With ``--fit-poses N`` the first N poses (file order) register and the rest are held out:
their measured residual (measured − model, position norm) is reported for the registered model and, beside it,
for the calibration as it was. Writes ``DIR2/model.json``: the calibration with the registered frame and a
``registration`` key (the frame's slots with standard errors, the poses that would pin it best, the figures)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from errormap.arm_poses import read_arm_poses, temperature_summary
from errormap.arm_register import MIN_POSES, choose_candidate, fit_frame, register_frame, registered_point
from errormap.io import InputError, write_json
from training.arm_residual import RotatedResidual

from compensation.app.validate import UsageError, allowed_verdict

from ...calibration_models import calibration_model_document
from ...model_file import read_model
from .arm_calibration import errors_mm, stage_name


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
"""Name of the plain calibration (``model.json`` key ``plain_geometric``) among the candidates register weighs."""


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


def candidates_of(geo, learner, plain, kept_stage) -> list:
    """(name, GeometricResult, learner or None) of the models register weighs, plainest first: the plain calibration;
    the kept geometric stage alone (where it is not the plain one); the kept stage with its learned residual (where
    one is carried). A stacked stage (a blend of two pipelines with their own base frames) is not registered as a
    blend: each of its pipelines is a candidate."""
    from training.arm_residual import StackedResidual
    pipes = ([(n, g, l) for n, (g, l) in zip(learner.names, learner.pipelines)] if isinstance(learner, StackedResidual)
             else [(kept_stage, geo, learner)])
    out = {PLAIN: (PLAIN, plain, None)}
    for _, g, _ in pipes:
        n = PLAIN if g.method == "plain least squares" else stage_name(g.model)
        out.setdefault(n, (n, g, None))
    for n, g, l in pipes:
        if l is not None:
            out.setdefault(n, (n, g, l))
    return list(out.values())


def session_candidates(cands, geo, carried: dict, term, data) -> list:
    """``cands`` (:func:`candidates_of`) as the calibration's blocked CV over sessions left them (``carried``, its
    ``across_sessions.carried``): the geometric stage alone dropped where it did not carry; where the temperature term
    carried and the session logs ``temp_c``, the kept geometric stage expanded to the session's mean temperature
    (``term``: ``alpha_per_k``, ``t_ref_c``) added as the richest candidate."""
    from errormap.arm_sessions import expanded_params
    out = [c for c in cands if not (carried.get("geometric") is False and c[0] != PLAIN and c[2] is None)]
    if carried.get("temperature") and isinstance(term, dict) and data.temp_c is not None:
        ds = float(term["alpha_per_k"]) * (float(np.mean(data.temp_c)) - float(term["t_ref_c"]))
        name = (PLAIN if geo.method == "plain least squares" else stage_name(geo.model)) + " + temperature"
        out.append((name, dataclasses.replace(geo, params=expanded_params(geo.chain, geo.params, ds)), None))
    return out


def run_arm_register(chain, poses, model, out, tool: bool = False, fit_poses: int | None = None, seed: int = 0,
                     log=None, allow_failed_verdict: bool = False) -> dict:
    """Register the calibration ``model`` on the poses file ``poses``; write ``out/model.json``; returns its
    ``registration`` dict. The model kept for the session is weighed against the plain calibration inside the
    registration poses (:func:`errormap.arm_register.choose_candidate`, :func:`candidates_of`). A calibration whose
    verdict failed is refused (InputError naming it and the reasons) unless ``allow_failed_verdict``
    (``--allow failed-verdict``): then ``registration.allowed`` records it, and the calibration's own failed verdict
    stays in the output (every later use refuses it again unless allowed)."""
    from ...fields import check_verdict
    m = read_model(model, chain, family="arm")          # refuses what is not an arm calibration of this chain
    geo, learner, doc = m.calibration.geometric, m.calibration.learner, m.doc
    verdict = check_verdict(model, allow_failed_verdict)
    plain = plain_of(chain, doc, model)
    across = doc.get("across_blocks") if isinstance(doc.get("across_blocks"), dict) else {}
    sessions = doc.get("across_sessions") if isinstance(doc.get("across_sessions"), dict) else None
    carried = (sessions or {}).get("carried") or {}
    had_learner = learner is not None
    dropped = had_learner and (carried["learned"] is False if "learned" in carried else
                               across.get("learned_carried") is False)
    if dropped:                          # helps inside the calibration's session only: not carried to this one
        learner = None
    data = read_arm_poses(poses, chain)
    n_fit = len(data) if fit_poses is None else int(fit_poses)
    if not MIN_POSES <= n_fit <= len(data):
        raise UsageError(f"--fit-poses: {n_fit} of {len(data)} poses in {poses}; a registration takes "
                         f"{MIN_POSES} to all of them")
    fit, rest = data.subset(np.arange(n_fit)), data.subset(np.arange(n_fit, len(data)))
    cands = session_candidates(candidates_of(geo, learner, plain, doc["kept_stage"]), geo, carried,
                               (sessions or {}).get("temperature_term"), data)
    choice = choose_candidate([(n, g.chain, g.params, l) for n, g, l in cands], fit, tool=tool)
    regs = {n: fit_frame(g.chain, g.params, fit, l, tool=tool) for n, g, l in cands}     # (slots, …, rotation, …)
    kept = choice["kept"]
    _, k_geo, k_learner = next(c for c in cands if c[0] == kept)
    reg = register_frame(k_geo.chain, k_geo.params, fit, k_learner, tool=tool, seed=seed)   # with its uncertainty
    turned = isinstance(k_learner, RotatedResidual)       # a session's model registered again
    R_total = reg.learned_rotation @ (k_learner.R if turned else np.eye(3))
    heldout = {n: _row(errors_mm(rest, registered_point(g.chain, regs[n][0], l, regs[n][3], rest.q)))
               for n, g, l in cands} if len(rest) else {}
    e_before = None if not len(rest) else errors_mm(
        rest, geo.predict(rest.q) + (0.0 if learner is None else learner.predict(rest.q)))
    out_doc = {k: v for k, v in doc.items() if k != "stacked"}
    new = dataclasses.replace(k_geo, params=reg.params)
    out_doc["geometric"] = {**new.to_dict(), "cv_table": doc["geometric"].get("cv_table", [])}
    out_doc["plain_geometric"] = dataclasses.replace(plain, params=regs[PLAIN][0]).to_dict()
    out_doc["kept_stage"] = kept
    out_doc["learned"] = None if k_learner is None else (k_learner.learner if turned else k_learner).to_dict()
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
        "learned_why": ((sessions or {}).get("why", {}).get("learned") or across.get("why")) if dropped else
                       (choice["why"] if had_learner else None),
        "across_sessions": None if sessions is None else {"carried": carried, "why": sessions.get("why")},
        "allowed": allowed_verdict(verdict),
        "temperature_c": temperature_summary(data), "temperature_change_c": _temperature_change(doc, data),
        "residual_kind": "measured residual (measured − model) on the session's poses after the first n_fit_poses, "
                         "position norm, mm"}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "model.json", calibration_model_document(
        "arm", chain, out_doc, {"written_by": "volcomp register", "poses": str(poses), "model": str(model)}))
    return out_doc["registration"]
