"""``volcomp predict program.csv --machine ur5 --model DIR/calibration.json --out pred.csv``: an arm's
calibrated tool-point error at joint configurations.

Input: a CSV with the chain's joint columns (``q1_deg …``; other columns are ignored), checked for
radians and the joint limits like every arm file. Output: the joint columns, the calibrated model's
tool point ``x_mm, y_mm, z_mm`` (kept stage: geometric slots [+ joint slots] [+ the learned residual])
and its error against the nominal chain, ``dx_mm, dy_mm, dz_mm`` — what the arm does where the program
meant the nominal point (the negative of what ``compensate`` corrects). Written whole.
"""
from __future__ import annotations

import numpy as np

from errormap.io import write_csv

from compensation.app.validate import UsageError

from ...arm_compensation import model_point
from .arm_calibration import load_arm_model
from .arm_compensate import read_program


def run_arm_predict(chain, args) -> int:
    if getattr(args, "band", None):
        raise UsageError("--band: an arm's calibration.json carries its held-out band in its report, not a per-point "
                         "covariance; predict without --band")
    if getattr(args, "allow", None):
        raise UsageError("--allow: an arm's joint values are checked against the machine's joint limits; nothing "
                         "to allow")
    geo, learner = load_arm_model(chain, args.model)
    q, _ = read_program(args.points, chain)
    p = model_point(geo.chain, geo.params, learner, q)
    d = p - chain.tool_point(q)
    cols = {c: q[:, i] for i, c in enumerate(chain.joint_columns)}
    cols.update({c: p[:, i] for i, c in enumerate(("x_mm", "y_mm", "z_mm"))})
    cols.update({c: d[:, i] for i, c in enumerate(("dx_mm", "dy_mm", "dz_mm"))})
    path = write_csv(args.out, cols, header_comments=[f"machine: {chain.name}", f"model: {args.model}",
                                                      "x_mm..z_mm: calibrated tool point; dx_mm..dz_mm: calibrated "
                                                      "minus nominal"], float_fmt="%.10g")
    n = np.linalg.norm(d, axis=1)
    print(f"wrote {len(q)} predictions to {path} (calibrated − nominal: RMS {np.sqrt(np.mean(n ** 2)):.4f} mm, "
          f"max {n.max():.4f} mm)")
    return 0
