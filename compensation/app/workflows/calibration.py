"""PKM kinematic calibration (``volcomp calibrate``): split, identify, validate, compare, document.

The poses are split into fit and held-out poses (or a separate check file is used);
:func:`errormap.pkm.pipeline.validated_calibration` identifies, runs the loop on leg residuals and
fits the plain baseline; the *measured residual* on the held-out poses decides what is returned
(never a model that loses to the baseline). :func:`run_calibration` writes ``model.json``,
``report.html`` and the PNGs (:mod:`compensation.app.reports.calibration`).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.io import InputError, write_json
from errormap.pkm.calibration import PKMCalibrator
from errormap.pkm.calibration_file import calibration_to_dict
from errormap.pkm.poses import check_pose_set, read_poses
from errormap.pkm.hexapod import KinematicsError
from errormap.pkm.pipeline import rms_um, validated_calibration

from compensation.app.validate import UsageError

from ...calibration_models import calibration_model_document

from ..families import family_of

from ..reports.calibration import write_html, write_plots


@dataclass
class CalibrationSettings:
    """One calibration. ``check``: a separate held-out pose file (else ``holdout`` of ``poses``
    is held out, split by ``seed``); ``noise_um`` / ``lever_mm``: None = estimated."""

    poses: str
    check: str | None = None
    holdout: float = 0.2
    noise_um: float | None = None
    scales: bool = True
    register: bool = True
    loop: bool = True
    lever_mm: float | None = None
    seed: int = 0
    lambda_rule: str = "gcv"
    compare_rules: bool = False


@dataclass
class CalibrationRun:
    """What :func:`run_calibration` did: the ``model.json`` document, the PNGs written and
    the held-out measured residual (RMS, max; μm) before, of volcomp's model and of the baseline."""

    doc: dict
    pngs: list
    before_um: tuple
    volcomp_um: tuple
    baseline_um: tuple

    @property
    def success(self) -> bool:
        return bool(self.doc["success"])


def holdout_split(data, holdout: float, seed: int):
    """(fit, held-out) of a pose set (anything with ``len`` and ``subset(idx)``): a random
    ``holdout`` share held out, drawn from ``seed``; at least one pose held out."""
    if not 0 < holdout < 1:
        raise UsageError(f"--holdout must be in (0, 1), got {holdout}")
    idx = np.random.default_rng(seed).permutation(len(data))
    n_check = max(1, int(round(holdout * len(data))))
    return data.subset(idx[n_check:]), data.subset(idx[:n_check])


def split_poses(machine, s, data, read=read_poses):
    """(fit, held-out) pose sets: ``--check`` poses (``s.check`` read with ``read``), else a random hold-out
    (``s.holdout``, ``s.seed``); a parallel machine's and an arm's settings alike."""
    if s.check:
        return data, read(s.check, machine)
    return holdout_split(data, s.holdout, s.seed)


def compare_rules(machine, s: CalibrationSettings, fit, check, res, after, log=None) -> dict:
    """Fit with each lambda rule; chosen lambda, delta, fit and held-out measured residual per rule."""
    log = sys.stderr if log is None else log
    rows = []
    for rule in PKMCalibrator.RULES:
        if rule == s.lambda_rule:
            r, e = res, after
        else:
            r = PKMCalibrator(machine, estimate_scales=s.scales, register=s.register,
                              noise_um=s.noise_um, lever_mm=res.lever_mm, lambda_rule=rule).fit(fit)
            e = r.pose_errors_um(check)
        pos = e["position_um"]
        rows.append({"rule": rule, "lambda": r.lam, "delta_um": r.delta_mm * 1e3,
                     "delta_estimated": r.delta_estimated, "success": r.success,
                     "fit_rms_um": float(1e3 * np.sqrt(np.mean(np.sum(r.residuals[:, :3] ** 2, axis=1)))),
                     "heldout_rms_um": float(np.sqrt(np.mean(pos ** 2))), "heldout_max_um": float(pos.max())})
        print(f"calibrate: lambda rule {rule}: lambda {r.lam:.3g}, held-out RMS {rows[-1]['heldout_rms_um']:.2f} um",
              file=log)
    return {"residual_kind": "measured residual (measurement minus model) on the held-out poses, position norm; "
                             "fit_rms_um on the fit poses",
            "delta": "morozov uses --noise-um when given, else delta estimated from the GCV fit "
                     "(delta^2 = RSS / (m - trace H))",
            "rules": rows}


def calibration_document(v, s: CalibrationSettings, check, comparison) -> dict:
    """The ``model.json`` document of a :func:`validated_calibration` result ``v``."""
    res, base, before, after = v.result, v.baseline, v.before, v.after
    b_rms, b_max = rms_um(before)
    a_rms, a_max = rms_um(after)
    p_rms, p_max = rms_um(v.baseline_e)
    returned = v.returned
    doc = calibration_to_dict(res)
    if returned != "volcomp":
        doc["identified_machine"] = {"base_joints_mm": base.machine.base_joints_mm,
                                     "platform_joints_mm": base.machine.platform_joints_mm,
                                     "leg_offset_mm": base.machine.leg_offset_mm, "leg_scale": base.machine.leg_scale,
                                     "tool_in_platform_mm": base.machine.tool_in_platform_mm}
        from scipy.spatial.transform import Rotation
        rot = Rotation.from_matrix(base.frame_rotation)
        doc["frame"].update({"translation_mm": base.frame_translation_mm, "rotation_qx_qy_qz_qw": rot.as_quat(),
                             "rotation_deg_fixed_xyz": rot.as_euler("xyz", degrees=True)})
        doc["leg_terms"] = []
    else:
        doc["leg_terms"] = res.leg_terms.to_list() if res.leg_terms else []
    doc.update({"residual_kind": "measured residual (measurement minus model) on held-out poses, position norm",
                "rms_before_um": b_rms, "rms_after_um": min(a_rms, p_rms) if returned != "volcomp" else a_rms,
                "max_before_um": b_max, "max_after_um": p_max if returned != "volcomp" else a_max,
                "n_check_poses": len(check), "poses_file": str(s.poses), "check_file": s.check,
                "scales_estimated": s.scales, "lever_mm": res.lever_mm, "lever_estimated": res.lever_estimated,
                "returned_model": returned,
                "volcomp": {"rms_um": a_rms, "max_um": a_max, "rigid_rms_um": rms_um(v.rigid_e)[0]},
                "baseline": {"what": f"plain least squares in {base.objective} space (scipy least_squares, LM, no "
                                     "regularisation) of the same parameters and the frame",
                             "objective": base.objective, "rms_um": p_rms, "max_um": p_max,
                             "fit_rms_mm": base.fit_rms_mm, "converged": base.success},
                "loop": v.loop, "noise": v.noise_source, "success": v.success, "success_reasons": v.reasons,
                "notes": v.notes, "message": res.message if v.success else "; ".join(v.reasons)})
    if "angle_urad" in after:
        doc.update({"rms_angle_before_urad": float(np.sqrt(np.mean(before["angle_urad"] ** 2))),
                    "rms_angle_after_urad": float(np.sqrt(np.mean(after["angle_urad"] ** 2)))})
    if comparison is not None:
        doc["lambda_comparison"] = comparison
    return doc


def run_calibration(machine, s: CalibrationSettings, out, log=None) -> CalibrationRun:
    """Calibrate ``machine`` (hexapod or tripod) from ``s.poses``; write ``out/model.json``,
    ``out/report.html`` and the PNGs. Progress goes to ``log`` (stderr)."""
    log = sys.stderr if log is None else log
    data = read_poses(s.poses, machine)
    k = machine.n_legs
    d = 6 if (family_of(machine).facts.platform_orientation and data.rotation is not None) else 3
    check_pose_set(data.source, machine, data.q, (8 if s.scales else 7) * k + 6 * s.register, d)
    fit, check = split_poses(machine, s, data)
    print(f"calibrate: {len(fit)} fit poses, {len(check)} held-out poses, machine {machine.name}", file=log)
    try:
        v = validated_calibration(machine, fit, check, scales=s.scales, register=s.register,
                                  noise_um=s.noise_um, lever_mm=s.lever_mm, lambda_rule=s.lambda_rule,
                                  loop=s.loop, progress=lambda msg: print(f"calibrate: {msg}", file=log))
        if v.loop.get("run"):
            print(f"calibrate: loop on leg residuals: {len(v.loop['accepted_terms'])} term(s) accepted"
                  + "".join(f"; {t['family']} leg {t['leg']}" for t in v.loop["accepted_terms"])
                  + ("" if v.loop.get("kept", True) else " (rejected on the held-out poses)"), file=log)
        comparison = (compare_rules(machine, s, fit, check, v.rigid, v.rigid_e, log=log)
                      if s.compare_rules or s.noise_um is None else None)
    except KinematicsError as exc:
        raise InputError(f"{s.poses}: {exc}") from None
    except ValueError as exc:
        raise InputError(str(exc)) from None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = calibration_document(v, s, check, comparison)
    write_json(out / "model.json", calibration_model_document(
        "parallel", machine, doc, {"written_by": "volcomp calibrate", "poses": str(s.poses), "check": s.check}))
    pngs = write_plots(v.result, v.before["position_um"], v.after["position_um"], out)
    write_html(doc, pngs, out)
    return CalibrationRun(doc, pngs, rms_um(v.before), rms_um(v.after), rms_um(v.baseline_e))
