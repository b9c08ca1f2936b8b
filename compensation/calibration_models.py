"""A calibrated arm's or parallel machine's ``model.json``: written by :func:`calibration_model_document`, read
through :func:`compensation.model_file.read_model` (its readers :func:`read_arm_model` and :func:`read_pkm_model`).

``model.json`` (``format: volcomp-model/1``) of a serial arm or a parallel machine names its family (key
``family``: ``arm`` or ``parallel``) and holds the calibration (key ``calibration``: what ``volcomp calibrate``
identified, in the section's own versioned format, ``volcomp-arm-calibration/4`` or ``volcomp-pkm-calibration/1``);
the calibration's verdict is the file's ``verdict``. The older files, a bare arm ``calibration.json``
(``volcomp-arm-calibration/2`` … ``/4``) or PKM ``calibration.json`` (``volcomp-pkm-calibration/1``, or earlier
without a ``format`` key), are read by the same readers as the section alone. Schema:
docs/reference/file-formats.md.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from dataclasses import replace as dc_replace
from pathlib import Path

import numpy as np

from errormap.io import InputError, read_document_text

from .fields import ARM_FORMAT, ARM_READ_FORMATS, MODEL_FORMAT, PKM_FORMAT

BASE_FRAME_FORMATS = (ARM_FORMAT,)
"""Arm formats whose base slots are the instrument → robot base transform: the only ones a joint program is compensated
or predicted with in the robot's base frame (before /4 a link slot could carry the instrument's placement)."""
SECTION_FORMATS = {"arm": ARM_READ_FORMATS, "parallel": (PKM_FORMAT,)}
"""The ``calibration`` section's formats of each family a calibration model holds (``calibrate`` writes the first;
``register`` keeps an older arm calibration's)."""
STACKED = "stacked"
"""Stage name of the blend of volcomp's pipeline and the plain GP (:class:`training.arm_residual.StackedResidual`)."""
KEPT_WITH_LEARNER = ("learned", "plain GP on plain LSQ residual")
"""Kept stages that carry a learned residual (arm section key ``learned``)."""
ROTATION_ATOL = 1e-9
"""A registered arm section's ``learned_rotation`` must be orthonormal to this (written from an exact rotation)."""


def calibration_model_document(family: str, machine, calibration: dict, provenance: dict | None = None) -> dict:
    """``model.json``'s content for the calibration document ``calibration`` (its ``format`` the family's section
    format) of ``machine`` (``name``, ``sha256``); its ``verdict`` becomes the file's."""
    if calibration.get("format") not in SECTION_FORMATS.get(family, ()):
        raise ValueError(f"a {family!r} model holds a calibration of format {SECTION_FORMATS.get(family)}, got "
                         f"{calibration.get('format')!r}")
    section = {k: v for k, v in calibration.items() if k != "verdict"}
    return {"format": MODEL_FORMAT, "family": family, "machine": machine.name, "machine_sha256": machine.sha256,
            "calibration": section, "provenance": dict(provenance or {"written_by": "volcomp calibrate"}),
            "verdict": calibration.get("verdict")}


def calibration_section(path, family: str) -> tuple[dict, str]:
    """(the calibration document, its format) of the ``model.json`` or older calibration file ``path`` of
    ``family``: a model.json's ``calibration`` section with its ``verdict``, or an older file whole. InputError
    naming the file and key for anything else."""
    path = Path(path)
    try:
        doc = json.loads(read_document_text(path, "a model file"))
    except (OSError, ValueError, RecursionError) as exc:
        raise InputError(f"{path}: not a readable model file ({exc})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: not a model file (JSON {type(doc).__name__}, no key 'format')")
    if doc.get("format") == MODEL_FORMAT:
        if doc.get("family") != family:
            raise InputError(f"{path}: key 'family': a {doc.get('family') or 'machine tool'!r} model, not a "
                             f"{family!r} one (--machine)")
        sec = doc.get("calibration")
        if not isinstance(sec, dict):
            raise InputError(f"{path}: key 'calibration': expected the {family}'s calibration (an object), got "
                             f"{type(sec).__name__}")
        if sec.get("format") not in SECTION_FORMATS[family]:
            raise InputError(f"{path}: key 'calibration.format': expected {SECTION_FORMATS[family][0]!r}, got "
                             f"{sec.get('format')!r}")
        return {**sec, "verdict": doc.get("verdict")}, sec["format"]
    return doc, doc.get("format")


@dataclass(frozen=True)
class ArmCalibration:
    """An arm calibration read: ``geometric`` (:class:`errormap.arm_calibration.GeometricResult`), ``learner`` (its
    learned residual, None: none kept), ``band_scale`` (the kept stage's band factor), ``format`` (the section's)."""

    geometric: object
    learner: object
    band_scale: float
    format: str

    @property
    def stages(self) -> tuple:
        """(geometric, learner or None)."""
        return self.geometric, self.learner

    def require_base_frame(self, path) -> ArmCalibration:
        """Itself, or InputError when its format was written before the robot's base frame was kept apart."""
        if self.format not in BASE_FRAME_FORMATS:
            raise InputError(f"{path}: key 'format': {self.format!r} predates the robot's base frame kept apart from "
                             "the link parameters, so points in the base frame cannot be told; calibrate again")
        return self


def read_arm_model(src, chain) -> tuple[ArmCalibration, dict]:
    """(:class:`ArmCalibration`, the calibration section) of an arm's ``model.json`` or older ``calibration.json``
    (``src``, a :class:`compensation.fields.ModelSource`) for ``chain``."""
    path = Path(src.path)
    d, fmt = calibration_section(path, "arm")
    where = "calibration." if src.kind == "arm-model" else ""
    if fmt not in ARM_READ_FORMATS:
        raise InputError(f"{path}: key '{where}format': expected {ARM_FORMAT!r} (an arm calibration)")
    m = d.get("machine")
    if not isinstance(m, dict) or m.get("name") != chain.name or m.get("joints") != getattr(chain, "joint_columns", None):
        raise InputError(f"{path}: key '{where}machine': calibrated for "
                         f"{m.get('name') if isinstance(m, dict) else None!r}, not {chain.name!r}")
    geo, learner = _arm_stages(chain, d, path, where)
    return ArmCalibration(geo, learner, band_scale_of(d, path, where), fmt), d


def _arm_stages(chain, d: dict, path, where: str = ""):
    """(GeometricResult, learner or None) of the arm calibration section ``d``."""
    from errormap.arm_calibration import GeometricResult
    if d.get("kept_stage") == STACKED:
        from training.arm_residual import StackedResidual
        if not isinstance(d.get("stacked"), dict):
            raise InputError(f"{path}: key '{where}stacked': missing (the kept stage is {STACKED!r})")
        try:
            st = StackedResidual.from_dict(chain, d["stacked"])
        except (ValueError, KeyError, TypeError, InputError) as exc:
            raise InputError(f"{path}: key '{where}stacked': {exc}") from None
        return st.geometric, st
    try:
        geo = GeometricResult.from_dict(chain, d["geometric"])
    except (KeyError, TypeError, InputError) as exc:
        raise InputError(f"{path}: key '{where}geometric': {exc}") from None
    learner = None
    if d.get("kept_stage") in KEPT_WITH_LEARNER and d.get("learned"):
        from training.arm_residual import ArmResidualRegressor
        try:
            learner = ArmResidualRegressor.from_dict(chain, d["learned"])
        except (ValueError, KeyError) as exc:
            raise InputError(f"{path}: key '{where}learned': {exc}") from None
        learner = registered_learner(learner, d, path, where)
    return geo, learner


def band_scale_of(d: dict, path, where: str = "") -> float:
    """The kept stage's band factor of an arm calibration section ``d`` (``band_calibration.factor``; 1 for one
    written before the blocked band rule, or calibrated without it); InputError on anything but a finite factor ≥ 1."""
    bc = d.get("band_calibration")
    if bc is None:
        return 1.0
    c = bc.get("factor") if isinstance(bc, dict) else None
    if isinstance(c, bool) or not isinstance(c, (int, float)) or not np.isfinite(c) or c < 1.0:
        raise InputError(f"{path}: key '{where}band_calibration.factor': expected a finite factor ≥ 1, got {c!r}")
    return float(c)


def registered_learner(learner, d: dict, path, where: str = ""):
    """The learner of an arm section written by ``volcomp register``, turned into the session's frame
    (:class:`training.arm_residual.RotatedResidual` by ``registration.learned_rotation``); as read otherwise."""
    reg = d.get("registration")
    if not isinstance(reg, dict):
        return learner
    from training.arm_residual import RotatedResidual
    R = np.asarray(reg.get("learned_rotation", np.nan), float)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=ROTATION_ATOL, rtol=0):
        raise InputError(f"{path}: key '{where}registration.learned_rotation': expected a 3 × 3 rotation matrix")
    return RotatedResidual(learner, R)


def read_pkm_model(src, machine) -> tuple[object, dict]:
    """(the identified machine, :class:`errormap.pkm.machine_file.PKM` with the loop's leg terms in ``extra``; the
    calibration section) of a parallel machine's ``model.json`` or older ``calibration.json`` (``src``) for
    ``machine``."""
    path = Path(src.path)
    d, fmt = calibration_section(path, "parallel")
    where = "calibration." if src.kind == "pkm-model" else ""
    if fmt is not None and fmt != PKM_FORMAT:
        raise InputError(f"{path}: key '{where}format': {str(fmt)!r}; not a PKM calibration (expected "
                         f"{PKM_FORMAT!r}, written by `volcomp calibrate`)")
    try:
        im, kind = d["identified_machine"], d["kind"]
    except KeyError as exc:
        raise InputError(f"{path}: not a PKM calibration (no key '{where}{exc.args[0]}'; expected format "
                         f"{PKM_FORMAT!r})") from None
    if kind != getattr(machine, "kind", None) or not hasattr(machine, "n_legs"):
        raise InputError(f"{path}: key '{where}kind': calibration is for a {kind}, the machine file is a "
                         f"{getattr(machine, 'kind', None)}")
    k = machine.n_legs
    from errormap.pkm.legspace import LegTerms
    try:
        terms = LegTerms.from_list(d.get("leg_terms", []), k, path)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    extra = dict(machine.extra)
    if terms:   # leg terms of the loop: applied when commands are converted to drive units (with the nominal)
        extra.update({"leg_terms": terms, "leg_terms_nominal": machine})
    try:
        calibrated = dc_replace(machine, base_joints_mm=np.asarray(im["base_joints_mm"], float).reshape(k, 3),
                                platform_joints_mm=np.asarray(im["platform_joints_mm"], float).reshape(k, 3),
                                leg_offset_mm=np.asarray(im["leg_offset_mm"], float).reshape(k),
                                leg_scale=np.asarray(im["leg_scale"], float).reshape(k), extra=extra)
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{path}: key '{where}identified_machine': {exc}") from None
    return calibrated, d
