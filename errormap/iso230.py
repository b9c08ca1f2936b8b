"""ISO 230-1 names for the grinder's 23 error elements, with signs and reference points.

ISO 230-1 names a *component error* ``E<direction><axis>`` (``EXX`` positioning of X,
``EYX``/``EZX`` straightness of X in Y/Z, ``EAX``/``EBX``/``ECX`` its roll/pitch/yaw about
X/Y/Z) and a *location error* ``E<direction>0<axis>`` (``EB0Z``: squareness of Z to X
about Y; ``EY0A``/``EZ0A``: offsets of the A axis line in Y/Z; ``EB0A``/``EC0A``: its tilts
about Y/Z). Conventions used here (and in every file volcomp exports):

* **what is measured** — the error motion of the moving body itself (the X carriage and
  the A spindle carry the workpiece; the Z carriage carries the wheel), relative to its
  nominal pose, expressed in the **fixed machine frame (MCS)**: translations in μm along
  +X/+Y/+Z, angles in μrad, right-handed about +X/+Y/+Z. Positive ``EXX`` = the X carriage
  is further along +X than commanded. Because X and A carry the workpiece, their errors
  move the tool *relative to the workpiece* with the opposite sign; the Z carriage's
  errors move it with the same sign.
* **reference point** — the translational components are given at the body's reference
  point (below); at another point ``P`` they are ``δ_P = δ_O + ε × (P − O)`` (μm, with
  ε in μrad and ``P − O`` in mm: ``δ_P = δ_O + 1e-3·ε × r``). :func:`axis_to_mcs` and
  :func:`axis_from_mcs` take an offset ``r`` to move the reference point.

The one-to-one map (``ELEMENT_NAMES`` order ↔ ``ISO_NAMES`` order):

=======================  ===============================  ===================================================
project elements         ISO 230-1                        conversion (project → ISO)
=======================  ===============================  ===================================================
``dx_x dy_x dz_x``       ``EXX EYX EZX``                  identical (the X carriage frame is MCS-aligned)
``ex_x ey_x ez_x``       ``EAX EBX ECX``                  identical
``dx_z dy_z dz_z``       ``EXZ EYZ EZZ``                  ``RotZ(θ1)·(dx_z, dy_z, dz_z)``: the project gives Z's
                                                          errors in the column frame turned by θ1 about Z
``ex_z ey_z ez_z``       ``EAZ EBZ ECZ``                  ``RotZ(θ1)·(ex_z, ey_z, ez_z)``
``dx_a dy_a dz_a``       ``EXA EYA EZA``                  ``RotX(a)·(dx_a, dy_a, dz_a)``: the project gives A's
                                                          errors in the rotating frame, ISO in the fixed one
``ex_a ey_a ez_a``       ``EAA EBA ECA``                  ``RotX(a)·(ex_a, ey_a, ez_a)``
``dy_oa dz_oa``          ``EY0A EZ0A``                    identical
``ey_oa ez_oa``          ``EB0A EC0A``                    identical
``s_xz``                 ``EB0Z``                         identical (Z tilted towards +X is a positive
                                                          rotation of the Z line about +Y)
=======================  ===============================  ===================================================

``EXX EYX EZX EXA EAA`` and the location errors are plain renames; the Z-axis pairs are
mixed by the fixed angle θ1 (30° on the default grinder) and the A-axis radial and tilt
pairs by the A position. Angles compose as ``RotX·RotY·RotZ`` in the project and as a
small rotation vector in ISO: the two agree to second order (~1e-10 relative at 100 μrad).

Reference points (nominal, MCS, mm): the origins of the bodies' frames in the grinder's chain
(:meth:`errormap.machine_tool.MachineTool.body_frames`):
X — the X carriage origin ``(l5 + x, 0, l6)``; Z — the Z carriage origin
``RotZ(θ1)·(l2, 0, l1 + z)``; A and the A-axis line — the A-axis end on the carriage
``(l5 + x + l7, 0, l6 + l8)``; squareness — the Z stroke origin (z = 0), so the tool is
displaced by ``1e-3·EB0Z·z`` μm along +X.
"""
from __future__ import annotations

import numpy as np

from .elements import A_ELEMENTS, CONSTANT_ELEMENTS, ELEMENT_NAMES, X_ELEMENTS, Z_ELEMENTS
from .grinder_file import ELEMENT_SLOTS

ISO_NAME = dict(ELEMENT_SLOTS)
"""Project element name -> ISO 230-1 name (one-to-one): the grinder chain's slots and their ISO names."""
ISO_NAMES = tuple(ISO_NAME[k] for k in ELEMENT_NAMES)
"""The 23 ISO names, in ELEMENT_NAMES order."""

ISO_MEANING = {
    "EXX": "positioning error of X", "EYX": "straightness of X in Y", "EZX": "straightness of X in Z",
    "EAX": "roll of X (about X)", "EBX": "pitch of X (about Y)", "ECX": "yaw of X (about Z)",
    "EXZ": "straightness of Z in X", "EYZ": "straightness of Z in Y", "EZZ": "positioning error of Z",
    "EAZ": "angular error of Z about X", "EBZ": "angular error of Z about Y", "ECZ": "roll of Z (about Z)",
    "EXA": "axial error motion of A", "EYA": "radial error motion of A in Y", "EZA": "radial error motion of A in Z",
    "EAA": "angular positioning error of A", "EBA": "tilt error motion of A about Y",
    "ECA": "tilt error motion of A about Z",
    "EY0A": "offset of the A axis line in Y", "EZ0A": "offset of the A axis line in Z",
    "EB0A": "tilt of the A axis line about Y", "EC0A": "tilt of the A axis line about Z",
    "EB0Z": "squareness of Z to X (about Y)",
}
BODY_OF = {**{k: "X" for k in X_ELEMENTS}, **{k: "Z" for k in Z_ELEMENTS}, **{k: "A" for k in A_ELEMENTS},
           "dy_oa": "A", "dz_oa": "A", "ey_oa": "A", "ez_oa": "A", "s_xz": "Z"}
CARRIES = {"X": "workpiece", "Z": "wheel (tool)", "A": "workpiece"}


def label(name: str) -> str:
    """``"dx_x (EXX)"``: the project name with its ISO 230-1 name beside it."""
    if name not in ISO_NAME:
        raise KeyError(f"Expected one of the 23 element names {ELEMENT_NAMES}, got {name!r}")
    return f"{name} ({ISO_NAME[name]})"


def axis_to_mcs(mt, word: str, axes, comp, offset_mm=None) -> np.ndarray:
    """One axis' six components (n, 6) (δx δy δz μm, εx εy εz μrad) in the frame its chain applies them in ->
    ISO 230-1 in the MCS at ``axes`` (n, k) of the chain ``mt`` (:class:`errormap.machine_tool.MachineTool`): turned
    by the body's nominal rotation, the translations moved to the reference point offset by ``offset_mm``
    (n, 3) (None: the body's own), ``δ + 1e-3·ε × r``. The same transform for every machine tool."""
    R, _ = mt.body_frames(word, axes)
    comp = np.asarray(comp, dtype=float)
    r = np.zeros((comp.shape[0], 3)) if offset_mm is None else offset_mm
    d = np.einsum("nij,nj->ni", R, comp[:, :3])
    e = np.einsum("nij,nj->ni", R, comp[:, 3:])
    return np.concatenate([d + 1e-3 * np.cross(e, r), e], axis=1)


def axis_from_mcs(mt, word: str, axes, iso, offset_mm=None) -> np.ndarray:
    """The inverse of :func:`axis_to_mcs`: ISO components (n, 6) -> the chain frame's (n, 6)."""
    R, _ = mt.body_frames(word, axes)
    iso = np.asarray(iso, dtype=float)
    r = np.zeros((iso.shape[0], 3)) if offset_mm is None else offset_mm
    e = iso[:, 3:]
    d = iso[:, :3] - 1e-3 * np.cross(e, r)
    return np.concatenate([np.einsum("nji,nj->ni", R, d), np.einsum("nji,nj->ni", R, e)], axis=1)


def map_rows() -> list[dict]:
    """The documented map as rows (element, iso, meaning, body, carries, unit) for tables and reports."""
    rows = []
    for k in ELEMENT_NAMES:
        b = BODY_OF[k]
        rows.append({"element": k, "iso": ISO_NAME[k], "meaning": ISO_MEANING[ISO_NAME[k]],
                     "body": b, "carries": CARRIES[b], "constant": k in CONSTANT_ELEMENTS,
                     "unit": "um" if k.startswith("d") else "urad"})
    return rows
