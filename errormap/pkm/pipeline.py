"""The whole PKM calibration as ``volcomp calibrate`` runs it, validated on held-out poses.

:func:`validated_calibration`: the rigid-model identification (:class:`~.calibration.PKMCalibrator`), the
loop on leg residuals (:func:`~.legspace.fit_leg_terms`), the plain baseline
(:func:`~.legspace.plain_leg_fit`), the returned model (never one that loses to the baseline on the held-out
poses) and the success verdict with one reason per failed check (``NOISE_FACTOR``, ``GAP_FACTOR``;
``docs/explanation/parallel-kinematics.md``, "No false success"). Benchmarks and the CLI both call it, so a
benchmark measures the user's path."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..stats import residual_stats
from .calibration import CalibrationResult, PKMCalibrator
from .poses import PoseData
from .legspace import PlainFit, fit_leg_terms, plain_leg_fit
from .machine_file import PKM

NOISE_FACTOR = 3.0      # held-out RMS per component above 3x the given noise: "far above the noise"
GAP_FACTOR = 2.0        # ... above 2x the estimated noise (repeats, else the fit's delta): does not generalise


def rms_um(e: dict) -> tuple[float, float]:
    """(RMS, max) of a ``pose_errors_um`` position norm (um)."""
    st = residual_stats(e["position_um"])
    return st["rms_um"], st["max_um"]


def repeat_noise_um(data: PoseData) -> tuple[float, int] | None:
    """Noise per position component (um) from poses with identical commands (pooled within-group
    scatter), and its degrees of freedom; None without repeats."""
    _, inv, counts = np.unique(np.round(data.q, 9), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    groups = np.flatnonzero(counts > 1)
    if groups.size == 0:
        return None
    ss, dof = 0.0, 0
    for g in groups:
        t = data.tip_mm[inv == g]
        ss += float(np.sum((t - t.mean(0)) ** 2))
        dof += 3 * (len(t) - 1)
    return 1e3 * np.sqrt(ss / dof), dof


def loop_table(rounds) -> list:
    """Per round, the candidates that passed plus the best three that did not (report size)."""
    out = []
    for i, rows in enumerate(rounds):
        rows = sorted(rows, key=lambda r: -r["cv_gain"])
        keep = [r for r in rows if r["passes"]] + [r for r in rows if not r["passes"]][:3]
        out.append([{"round": i + 1, "family": r["family"], "leg": r["leg"] + 1,
                     "cv_rss_before_mm2": r["cv_rss_before_mm2"], "cv_rss_after_mm2": r["cv_rss_after_mm2"],
                     "cv_gain": r["cv_gain"], "F": r["F"], "p_value": r["p_value"], "passes": r["passes"]}
                    for r in keep])
    return out


@dataclass
class ValidatedCalibration:
    """Result of :func:`validated_calibration`. Errors are ``pose_errors_um`` dicts on the check poses
    (measured residual): ``before`` (nominal, initial registration), ``rigid_e``, ``after`` (volcomp's
    final model), ``baseline_e``. ``returned``: ``"volcomp"`` or ``"plain baseline"``."""

    rigid: CalibrationResult
    result: CalibrationResult
    baseline: PlainFit
    before: dict
    rigid_e: dict
    after: dict
    baseline_e: dict
    returned: str
    success: bool
    reasons: list
    notes: list
    loop: dict = field(default_factory=dict)
    noise_source: str = ""


def validated_calibration(machine: PKM, fit: PoseData, check: PoseData, *, scales: bool = True,
                          register: bool = True, noise_um: float | None = None, lever_mm: float | None = None,
                          lambda_rule: str = "gcv", loop: bool = True, progress=None) -> ValidatedCalibration:
    """Calibrate on ``fit`` and validate on ``check`` (see the module docstring)."""
    cal = PKMCalibrator(machine, estimate_scales=scales, register=register, noise_um=noise_um, lever_mm=lever_mm,
                        lambda_rule=lambda_rule, progress=progress)
    rigid = cal.fit(fit)
    before = rigid.pose_errors_um(check, nominal=True, frame=rigid.lcurve["initial_frame"])
    rigid_e = rigid.pose_errors_um(check)
    res, after = rigid, rigid_e
    full_pose = machine.kind == "tripod" or fit.rotation is not None
    loop_doc = {"run": False}
    if loop and full_pose:
        cal_fixed = PKMCalibrator(machine, estimate_scales=scales, register=register, noise_um=noise_um,
                                  lever_mm=rigid.lever_mm, lambda_rule=lambda_rule)
        terms, rounds, with_terms = fit_leg_terms(cal_fixed, fit, rigid)
        loop_doc = {"run": True, "accepted_terms": terms.to_list(), "rounds": loop_table(rounds),
                    "heldout_rms_um_rigid": rms_um(rigid_e)[0]}
        if terms:
            e_t = with_terms.pose_errors_um(check)
            loop_doc["heldout_rms_um_with_terms"] = rms_um(e_t)[0]
            loop_doc["kept"] = rms_um(e_t)[0] < rms_um(rigid_e)[0]
            if loop_doc["kept"]:
                res, after = with_terms, e_t
            else:
                loop_doc["note"] = "terms rejected: the held-out residual did not improve"
    elif loop:
        loop_doc["note"] = "needs measured orientations (leg lengths from full poses)"
    base = plain_leg_fit(machine, fit, scales=scales, register=register)
    base_e = base.pose_errors_um(check, machine)
    b_rms = rms_um(before)[0]
    a_rms, p_rms = rms_um(after)[0], rms_um(base_e)[0]
    returned, notes, reasons = "volcomp", [], []
    if p_rms < a_rms:
        returned = "plain baseline"
        notes.append(f"the plain {base.objective}-space least-squares fit has the lower held-out residual "
                     f"({p_rms:.2f} vs {a_rms:.2f} um): its parameters are returned")
    if not res.success:
        reasons.append(f"the fit did not converge ({res.message})")
    final_rms = min(a_rms, p_rms)
    per_comp = final_rms / np.sqrt(3.0)
    if final_rms >= b_rms:
        reasons.append(f"held-out residual not better than the nominal model ({b_rms:.2f} -> {final_rms:.2f} um RMS)")
    rep = repeat_noise_um(fit)
    if noise_um is not None:
        noise_source = f"given: {noise_um:g} um"
        if per_comp > NOISE_FACTOR * noise_um:
            reasons.append(f"held-out residual {per_comp:.3g} um per component is {per_comp / noise_um:.1f}x the "
                           f"noise you gave ({noise_um:g} um): the model lacks something, or the noise is larger")
    else:
        est, what = ((rep[0], f"repeated poses ({rep[1]} degrees of freedom)") if rep is not None
                     else (res.delta_mm * 1e3, "the fit's residual (GCV)"))
        noise_source = f"estimated from {what}: {est:.3g} um"
        if per_comp > GAP_FACTOR * est:
            reasons.append(f"held-out residual {per_comp:.3g} um per component is {per_comp / est:.1f}x the noise "
                           f"estimated from {what} ({est:.3g} um): the model does not generalise or lacks something")
    return ValidatedCalibration(rigid, res, base, before, rigid_e, after, base_e, returned, not reasons, reasons,
                                notes, loop_doc, noise_source)
