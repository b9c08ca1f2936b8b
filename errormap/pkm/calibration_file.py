"""The PKM calibration document (docs/explanation/parallel-kinematics.md), written from a
:class:`errormap.pkm.calibration.CalibrationResult` (:func:`calibration_to_dict`) as the ``calibration`` section of
``model.json``; read back as the identified machine by ``compensation.model_file.read_model``."""
from __future__ import annotations


def calibration_to_dict(result) -> dict:
    """The machine-readable part of ``model.json``'s ``calibration`` section (see
    docs/explanation/parallel-kinematics.md) of ``result``, a :class:`errormap.pkm.calibration.CalibrationResult`
    (not imported here: the calibrator imports this module)."""
    from scipy.spatial.transform import Rotation  # here: every model reader imports this module's format name
    rot = Rotation.from_matrix(result.frame_rotation)
    m = result.machine
    return {
        "format": CALIBRATION_FORMAT,
        "kind": m.kind,
        "machine": {"name": m.name, "path": m.path, "sha256": m.sha256},
        "parameters": result.parameter_table(),
        "identified_machine": {
            "base_joints_mm": m.base_joints_mm, "platform_joints_mm": m.platform_joints_mm,
            "leg_offset_mm": m.leg_offset_mm, "leg_scale": m.leg_scale,
            "tool_in_platform_mm": m.tool_in_platform_mm},
        "frame": {"meaning": "instrument <- machine: p_instrument = R p_machine + t",
                  "translation_mm": result.frame_translation_mm, "rotation_qx_qy_qz_qw": rot.as_quat(),
                  "rotation_deg_fixed_xyz": rot.as_euler("xyz", degrees=True)},
        "condition_number": result.condition_number,
        "condition_number_raw": result.condition_number_raw,
        "condition_number_meaning": (
            "condition_number: s_max / s_min of the scaled, frame-eliminated parameter Jacobian on the "
            "identifiable subspace (the gauge directions fixed, structural null directions with "
            "s < rcond * s_max removed); condition_number_raw: the same Jacobian over all estimated "
            "parameters, null directions included (~1e16, or null = infinite, when a gauge exists)"),
        "singular_values": result.singular_values,
        "singular_values_raw": result.singular_values_raw,
        "n_gauge": result.n_gauge,
        "unidentifiable": result.unidentifiable,
        "lambda_rule": result.lambda_rule,
        "lambda": result.lam, "lambda_gcv": result.lambda_gcv, "lambda_lcurve": result.lambda_lcurve,
        "lambda_morozov": result.lambda_morozov, "discrepancy_reached": result.discrepancy_reached,
        "delta_um": result.delta_mm * 1e3, "delta_estimated": result.delta_estimated,
        "lever_mm": result.lever_mm, "n_fit_poses": result.n_poses, "success": result.success,
        "message": result.message, "iterations": result.iterations, "residual_evaluations": result.nfev,
        "fit_time_s": result.fit_time_s,
    }


CALIBRATION_FORMAT = "volcomp-pkm-calibration/1"
"""The ``format`` key of the calibration document (the section of ``model.json``, or an older bare
``calibration.json``, recognised by it whatever its name; files written before the key existed are recognised by
their ``kind`` and ``identified_machine`` keys)."""
LAMBDA_RULES = ("morozov", "gcv", "lcurve")
"""The rules that choose the Tikhonov λ (:class:`errormap.pkm.calibration.PKMCalibrator`), as the document's
``lambda_rule`` names them (here, with the format, so that ``volcomp calibrate`` lists them without the solver)."""
