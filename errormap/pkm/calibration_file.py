"""The PKM calibration file, ``calibration.json`` (docs/explanation/parallel-kinematics.md): written from a
:class:`errormap.pkm.calibration.CalibrationResult` (:func:`calibration_to_dict`) and read back as the identified
machine (:func:`load_calibrated_machine`), recognised by its ``format`` key."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from ..io import InputError, read_document_text
from .machine_file import PKM

if TYPE_CHECKING:
    from .calibration import CalibrationResult


def calibration_to_dict(result: CalibrationResult) -> dict:
    """The machine-readable part of ``calibration.json`` (see docs/explanation/parallel-kinematics.md)."""
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
"""The ``format`` key of ``calibration.json``: the file is recognised by it, whatever its name (files
written before the key existed are recognised by their ``kind`` and ``identified_machine`` keys)."""


def load_calibrated_machine(path, machine: PKM) -> PKM:
    """The identified machine from ``calibration.json`` (a file, whatever its name, or its folder),
    recognised by its ``format`` key and checked against ``machine``."""
    import json
    p = Path(path)
    if p.is_dir():
        p = p / "calibration.json"
    if not p.is_file():
        raise InputError(f"{p}: no such calibration file")
    try:
        doc = json.loads(read_document_text(p, "a calibration file"))
    except ValueError as exc:
        raise InputError(f"{p}: not a PKM calibration file (not JSON: {exc})") from None
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt is not None and fmt != CALIBRATION_FORMAT:
        raise InputError(f"{p}: key 'format': {str(fmt)!r}; not a PKM calibration file (expected "
                         f"{CALIBRATION_FORMAT!r}, written by `volcomp calibrate`)")
    try:
        im = doc["identified_machine"]
        kind = doc["kind"]
    except (KeyError, TypeError) as exc:
        raise InputError(f"{p}: not a PKM calibration file (no key {exc}; expected format "
                         f"{CALIBRATION_FORMAT!r})") from None
    if kind != machine.kind:
        raise InputError(f"{p}: key 'kind': calibration is for a {kind}, the machine file is a {machine.kind}")
    k = machine.n_legs
    from .legspace import LegTerms
    try:
        terms = LegTerms.from_list(doc.get("leg_terms", []), k, p)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    extra = dict(machine.extra)
    if terms:   # leg terms of the loop: applied when commands are converted to drive units (with the nominal)
        extra.update({"leg_terms": terms, "leg_terms_nominal": machine})
    try:
        return replace(machine, base_joints_mm=np.asarray(im["base_joints_mm"], float).reshape(k, 3),
                       platform_joints_mm=np.asarray(im["platform_joints_mm"], float).reshape(k, 3),
                       leg_offset_mm=np.asarray(im["leg_offset_mm"], float).reshape(k),
                       leg_scale=np.asarray(im["leg_scale"], float).reshape(k), extra=extra)
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{p}: key 'identified_machine': {exc}") from None
