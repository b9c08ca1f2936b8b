"""``volcomp predict program.csv --machine ur5 --model DIR/calibration.json --out pred.csv``: an arm's
calibrated tool-point error at joint configurations.

Input: a CSV with the chain's joint columns (``q1_deg …``; other columns are ignored), checked for
radians and the joint limits like every arm file. Output: the joint columns, the calibrated model's
tool point ``x_mm, y_mm, z_mm`` (kept stage: geometric slots [+ joint slots] [+ the learned residual])
and its error against the nominal chain, ``dx_mm, dy_mm, dz_mm`` — what the arm does where the program
meant the nominal point (the negative of what ``compensate`` corrects). With ``--band 95`` (or ``1sigma``) also
``dx_band95_mm, dy_band95_mm, dz_band95_mm``: the half-width per component of the band of a new measurement about
the kept stage (:data:`BAND_RULES`; its 95 % coverage is checked by CV and on the held-out poses in
``calibration.json``). Written whole.
"""
from __future__ import annotations

import numpy as np

from errormap.io import write_csv

from compensation.app.validate import UsageError

from ...arm_compensation import model_point
from .arm_calibration import load_arm_model
from .arm_compensate import read_program


Z95 = 1.959963984540054
BAND_RULES = {"geometric": "geometric stage: J Σ Jᵀ with the fit's covariance, and its residual σ",
              "learned": "learned stage: the GP's latent std calibrated on its CV, and its noise",
              "stacked": "stacked stage: w·s_a + (1 − w)·s_b of its two pipelines' stds, conservative"}
"""The band rule per kind of kept stage (:func:`training.arm_residual.pipeline_std_mm`)."""


def stage_kind(learner) -> str:
    if learner is None or learner.chosen_ == "none":
        return "geometric"
    return "stacked" if learner.chosen_ == "stacked" else "learned"


def run_arm_predict(chain, args) -> int:
    if getattr(args, "allow", None):
        raise UsageError("--allow: an arm's joint values are checked against the machine's joint limits; nothing "
                         "to allow")
    geo, learner = load_arm_model(chain, args.model)
    q, _ = read_program(args.points, chain)
    band = getattr(args, "band", None)
    if band and (learner is None or learner.chosen_ == "none") and not geo.full_covariance:
        raise UsageError(f"--band: {args.model} holds the geometric stage's standard errors but not its covariance "
                         "(written before the covariance was saved); calibrate again for a band")
    p = model_point(geo.chain, geo.params, learner, q)
    d = p - chain.tool_point(q)
    cols = {c: q[:, i] for i, c in enumerate(chain.joint_columns)}
    cols.update({c: p[:, i] for i, c in enumerate(("x_mm", "y_mm", "z_mm"))})
    cols.update({c: d[:, i] for i, c in enumerate(("dx_mm", "dy_mm", "dz_mm"))})
    meta = [f"machine: {chain.name}", f"model: {args.model}",
            "x_mm..z_mm: calibrated tool point; dx_mm..dz_mm: calibrated minus nominal"]
    if band:
        from training.arm_residual import pipeline_std_mm
        k, tag = (1.0, "1sigma") if band == "1sigma" else (Z95, "95")
        sd = pipeline_std_mm(geo, learner, q)
        cols.update({f"{c}_band{tag}_mm": k * sd[:, j] for j, c in enumerate(("dx", "dy", "dz"))})
        meta.append(f"band: {'1-sigma' if band == '1sigma' else '95 %'} half-width per component of a new measurement "
                    f"about the kept stage ({BAND_RULES[stage_kind(learner)]})")
    path = write_csv(args.out, cols, header_comments=meta, float_fmt="%.10g")
    n = np.linalg.norm(d, axis=1)
    print(f"wrote {len(q)} predictions to {path} (calibrated − nominal: RMS {np.sqrt(np.mean(n ** 2)):.4f} mm, "
          f"max {n.max():.4f} mm)")
    return 0
