"""ISO 230-1: one axis' components to and from the MCS (the names: each slot's ``iso`` in the machine file).

ISO 230-1 names a *component error* ``E<direction><axis>`` (``EXX`` positioning of X, ``EAX`` its
roll) and a *location error* ``E<direction>0<axis>`` (``EB0Z`` squareness of Z to X about Y). An ISO
value is the error motion of the moving body itself in the fixed machine frame (MCS): translations μm
along +X/+Y/+Z, angles μrad right-handed, translations at the body's reference point (the origin of its
frame in the chain, :meth:`errormap.machine_tool.MachineTool.body_frames`); at ``P = O + r`` (mm)
``δ_P = δ_O + 1e-3·ε × r``. The map, the signs, the grinder's reference points and where the project's
frames differ (Z turned by θ1, A rotating): ``docs/how-to/export-to-controller.md`` (ISO 230-1 names).
"""
from __future__ import annotations

import numpy as np


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
