"""``volcomp predict --machine hexapod|tripod --model model.json``: the calibrated parallel machine's
tool-tip error at commanded poses.

A pose (``x_mm, y_mm, z_mm`` in the machine frame; on a hexapod optionally ``rx_deg, ry_deg, rz_deg``, the
fixed-axis X-Y-Z angles of the platform, else level) is commanded with the nominal inverse kinematics (what the
controller does without compensation); the calibrated machine's forward kinematics gives where the tool tip
lands. Written: the input columns and ``dx_mm, dy_mm, dz_mm`` = landed − commanded (the negative of what
``interpolate --calibration`` corrects), as an arm's ``predict`` writes them.
"""
from __future__ import annotations

import sys

import numpy as np

from errormap.io import InputError, read_table, write_csv
from compensation.app.validate import UsageError

from ..families import family_of

ANGLES = ("rx_deg", "ry_deg", "rz_deg")


def run_pkm_predict(machine, points, model, out) -> int:
    """``volcomp predict`` of the commanded poses in the CSV ``points`` on a parallel machine, with its
    ``model.json`` ``model`` (``volcomp calibrate``); the CSV ``out`` written whole."""
    from ...model_file import read_model
    from errormap.pkm.hexapod import KinematicsError, angles_to_rotation, forward_kinematics, inverse_kinematics
    m = read_model(model, machine, family="parallel")
    calibrated = m.calibration
    if calibrated.extra.get("leg_terms"):
        key = "calibration.leg_terms" if m.source.kind == "pkm-model" else "leg_terms"
        raise UsageError(f"{m.source.path}: key '{key}': the loop's leg terms are applied to commands "
                         "(interpolate --calibration), not yet predicted at poses; predict takes a calibration "
                         "without them (calibrate --no-loop)")
    t = read_table(points, "points")
    t.require("x_mm", "y_mm", "z_mm")
    tips = np.stack([t.float(c) for c in ("x_mm", "y_mm", "z_mm")], axis=1)
    has = [c for c in ANGLES if c in t.names]
    oriented = family_of(machine).facts.platform_orientation
    if has and (not oriented or len(has) != 3):
        raise InputError(f"{t.path}: columns {', '.join(has)}: a hexapod's platform angles are the three "
                         f"{', '.join(ANGLES)}" + ("" if oriented else f"; a {machine.kind} takes positions only"))
    R = angles_to_rotation(np.stack([t.float(c) for c in ANGLES], axis=1)) if has else np.tile(np.eye(3), (len(tips), 1, 1))
    try:
        legs = inverse_kinematics(machine, tips, R, check_limits=True)   # the nominal commands
        q = machine.legs_to_drive(legs)
        fk = forward_kinematics(calibrated, calibrated.drive_to_legs(q), guess_tip_mm=tips, guess_platform2base=R,
                                check_limits=False)
    except KinematicsError as exc:
        raise InputError(f"{t.path}: {exc}") from None
    d = fk.x - tips
    cols = {c: np.array(t.raw(c)) for c in t.names if c not in ("dx_mm", "dy_mm", "dz_mm")}
    cols.update({"dx_mm": d[:, 0], "dy_mm": d[:, 1], "dz_mm": d[:, 2]})
    print(f"predicting {len(tips)} poses with {model} ...", file=sys.stderr)
    path = write_csv(out, cols, header_comments=[f"machine: {machine.name}", f"model: {model}",
                                                      "dx_mm..dz_mm: the calibrated machine's tool tip at the nominal "
                                                      "commands minus the commanded pose (machine frame)"])
    print(f"wrote {len(tips)} predictions to {path}")
    return 0
