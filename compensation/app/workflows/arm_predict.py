"""``volcomp predict program.csv --machine ur5 --model DIR/model.json --out pred.csv``: an arm's
calibrated tool-point error at joint configurations.

Input: a CSV with the chain's joint columns (``q1_deg …``), or a measured-pose file in the tracker grid layout
(then the output also holds the MEASURED residual per pose, ``ex_mm, ey_mm, ez_mm``, in the calibration's
instrument frame, and its mean / RMS / max are printed). Output: the joint columns, the kept stage's tool point
``x_mm, y_mm, z_mm`` in the ROBOT'S BASE FRAME (:mod:`errormap.arm_frames`) and its error against the nominal
chain there, ``dx_mm, dy_mm, dz_mm``; with ``--band`` (:data:`BAND_RULES`) the half-widths
``dx_band95_mm …``. Written whole. docs/reference/arm-calibration.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from errormap.arm_frames import base_rotation, to_base_frame
from errormap.arm_poses import tracker_grid_columns, tracker_grid_points
from errormap.io import read_table, write_csv

from compensation.app.validate import UsageError, allowed_verdict

from ...arm_compensation import model_point
from ...model_file import read_model
from .arm_compensate import joint_values, nominal_base_points, read_program


Z95 = 1.959963984540054
BAND_RULES = {"geometric": "geometric stage: J Σ Jᵀ with the fit's covariance, and its residual σ",
              "learned": "learned stage: the GP's latent std calibrated on its CV, and its noise",
              "stacked": "stacked stage: w·s_a + (1 − w)·s_b of its two pipelines' stds, conservative"}
"""The band rule per kind of kept stage (:func:`training.arm_residual.pipeline_std_mm`)."""


def stage_kind(learner) -> str:
    if learner is None or learner.chosen_ == "none":
        return "geometric"
    return "stacked" if learner.chosen_ == "stacked" else "learned"


def read_points(path, chain):
    """(q (n, nq) joint values, measured tool points (n, 3) mm or None) of ``predict``'s input: a joint program
    (:func:`read_program`; its ``x_mm…`` are targets, not measurements, and are ignored here) or a tracker-grid
    measured-pose file (its joints ``joint_k`` and its measured points)."""
    t = read_table(path, "points")
    grid = None if all(c in t for c in chain.joint_columns) else tracker_grid_columns(t, chain, path)
    if grid is None:
        return read_program(path, chain, t)[0], None
    return joint_values(path, t, chain, grid), tracker_grid_points(t)


@dataclass(frozen=True)
class ArmPredictSettings:
    """How ``volcomp predict`` runs on a serial arm: ``model`` (its ``model.json``), ``out`` (the CSV
    written), ``band`` (None, ``"95"`` or ``"1sigma"``: the band columns), ``allow_failed_verdict`` (use a
    calibration whose verdict failed; recorded in the header)."""
    model: str
    out: str
    band: str | None = None
    allow_failed_verdict: bool = False


def arm_predict_settings_of(model, out, band, allow) -> ArmPredictSettings:
    """``predict``'s options on an arm as :class:`ArmPredictSettings` (``--allow`` takes failed-verdict only)."""
    from ...fields import FAILED_VERDICT
    other = [a for a in allow or [] if a != FAILED_VERDICT]
    if other:
        raise UsageError(f"--allow {other[0]}: an arm's joint values are checked against the machine's joint limits; "
                         f"only --allow {FAILED_VERDICT} applies")
    return ArmPredictSettings(model=model, out=out, band=band, allow_failed_verdict=FAILED_VERDICT in (allow or []))


def run_arm_predict(chain, points, settings: ArmPredictSettings) -> int:
    """``volcomp predict`` of the joint configurations (or tracker-grid poses) in ``points`` on a serial arm."""
    from ...fields import check_verdict
    model, band = settings.model, settings.band
    cal = read_model(model, chain, family="arm").calibration.require_base_frame(model)
    geo, learner, band_c = cal.geometric, cal.learner, cal.band_scale
    verdict = check_verdict(model, settings.allow_failed_verdict)   # a failed calibration: refused
    q, measured = read_points(points, chain)
    if band and (learner is None or learner.chosen_ == "none") and not geo.full_covariance:
        raise UsageError(f"--band: {model} holds the geometric stage's standard errors but not its covariance "
                         "(written before the covariance was saved); calibrate again for a band")
    p = model_point(geo.chain, geo.params, learner, q)          # instrument frame
    R_base = base_rotation(chain, geo.params)
    pb = to_base_frame(chain, geo.params, p)
    d = pb - nominal_base_points(chain, q)
    cols = {c: q[:, i] for i, c in enumerate(chain.joint_columns)}
    cols.update({c: pb[:, i] for i, c in enumerate(("x_mm", "y_mm", "z_mm"))})
    cols.update({c: d[:, i] for i, c in enumerate(("dx_mm", "dy_mm", "dz_mm"))})
    meta = [f"machine: {chain.name}", f"model: {model}",
            "x_mm..z_mm: calibrated tool point, dx_mm..dz_mm: calibrated minus nominal, both in the robot's base frame"]
    if allowed_verdict(verdict):
        meta.insert(0, f"allowed: {allowed_verdict(verdict)}")
    if measured is not None:
        e = measured - p
        cols.update({c: e[:, i] for i, c in enumerate(("ex_mm", "ey_mm", "ez_mm"))})
        meta.append("ex_mm..ez_mm: MEASURED residual, measured (tracker-grid target + difference) minus calibrated, in "
                    "the calibration's instrument frame")
    if band:
        from training.arm_residual import pipeline_std_mm
        k, tag = (1.0, "1sigma") if band == "1sigma" else (Z95, "95")
        sd = band_c * np.sqrt((pipeline_std_mm(geo, learner, q) ** 2) @ (R_base ** 2))   # turned into the base frame
        cols.update({f"{c}_band{tag}_mm": k * sd[:, j] for j, c in enumerate(("dx", "dy", "dz"))})
        meta.append(f"band: {'1-sigma' if band == '1sigma' else '95 %'} half-width per component of a new measurement "
                    f"about the kept stage ({BAND_RULES[stage_kind(learner)]}), times {band_c:.4g}: the blocked band "
                    "factor (model.json band_calibration: 95 % on blocked inner CVs of the fit poses, at most 98 % "
                    "on the interleaved one; 1 for a file without it)")
    path = write_csv(settings.out, cols, header_comments=meta, float_fmt="%.10g")
    n = np.linalg.norm(d, axis=1)
    print(f"wrote {len(q)} predictions to {path} (calibrated − nominal: RMS {np.sqrt(np.mean(n ** 2)):.4f} mm, "
          f"max {n.max():.4f} mm)")
    if measured is not None:
        m = np.linalg.norm(measured - p, axis=1)
        print(f"measured − calibrated at these {len(q)} poses: mean {m.mean():.4f} mm, RMS {np.sqrt(np.mean(m ** 2)):.4f} mm, "
              f"max {m.max():.4f} mm")
    return 0
