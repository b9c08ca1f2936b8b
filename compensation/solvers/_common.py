"""Helpers shared by the solvers: results, the ball, rotary continuity.

Conventions (all solvers): the field is an :class:`errormap.field.ErrorField`, checked once per solve, its
optional methods used where its ``capabilities`` declare them; targets ``p_d`` and commands ``p_r`` are WCS
points (n, 3) mm; the field is evaluated with a full-turn rotary axis folded into its calibrated turn; the
command of ``p_r`` takes the turn of its own target's rotary axis (``a_r = a_d + wrap180(a_r - a_d)``), so a
continuous path gets continuous rotary commands; the model residual is ``(p_r - p_d)·1e3 + E(axes(p_r))`` μm
(docs/explanation/kinematics.md)."""
from __future__ import annotations

import time

import numpy as np

from .base import SolveResult

UM_PER_MM = 1e3
MM_PER_UM = 1e-3


def wrap180(angle_deg) -> np.ndarray:
    """Angles folded into ``[-180, 180)``."""
    return np.mod(np.asarray(angle_deg, dtype=float) + 180.0, 360.0) - 180.0


def project_to_ball(d_um, radius_um) -> np.ndarray:
    """Offsets (..., 3) μm radially projected onto the ball ``|d| ≤ radius_um`` (inside: unchanged)."""
    nrm = np.linalg.norm(d_um, axis=-1, keepdims=True)
    return d_um * np.minimum(1.0, radius_um / np.maximum(nrm, 1e-300))


def make_result(method, targets, commands, axes, residual, converged, nfev, t0, ball_um, message="", info=None):
    """Assemble a :class:`SolveResult`; ``success`` = converged, finite and inside the ball."""
    correction = np.linalg.norm(commands - targets, axis=1) * UM_PER_MM
    finite = np.all(np.isfinite(commands), axis=1) & np.all(np.isfinite(residual), axis=1)
    success = np.asarray(converged, dtype=bool) & finite & (correction <= ball_um * (1 + 1e-12))
    n_fail = int((~success).sum())
    msg = message or (f"{len(success) - n_fail}/{len(success)} points solved" + (f"; {n_fail} failed" if n_fail else ""))
    info = dict(info or {})
    info.setdefault("ball_um", float(ball_um))
    return SolveResult(method=method, targets_mm=targets, commands_mm=commands, axes=axes,
                       residual_um=residual, correction_um=correction, success=success,
                       nfev=int(nfev), seconds=time.perf_counter() - t0, message=msg, info=info)
