"""Helpers shared by the solvers: results, the ball, rotary folding and continuity, field evaluation in
chunks.

Conventions (all solvers): the field is an :class:`errormap.field.ErrorField`, checked once per solve, its
optional methods used where its ``capabilities`` declare them; targets ``p_d`` and commands ``p_r`` are WCS
points (n, 3) mm; the field is evaluated with a full-turn rotary axis folded into its calibrated turn; the
command of ``p_r`` takes the turn of its own target's rotary axis (``a_r = a_d + wrap180(a_r - a_d)``), so a
continuous path gets continuous rotary commands; the model residual is ``(p_r - p_d)·1e3 + E(axes(p_r))`` μm
(docs/explanation/kinematics.md)."""
from __future__ import annotations

import contextlib
import time

import numpy as np

from errormap.field import PREDICT_COLUMNS
from errormap.threads import limit_threads

from .base import SolveResult

UM_PER_MM = 1e3
MM_PER_UM = 1e-3
FIELD_CHUNK = 262_144
"""Rows per ``field.predict`` call: bounds the peak memory of any field."""
FIELD_TORCH_THREADS = 1
"""torch threads while a torch field (the learned MLP: it has ``predict_columns``) is evaluated
here. Its layers are narrow (at most 25 wide), so intra-op threads gain little, and on busy
cores they spin. Measured on the shared 2-core machine at load ~15, 200,000 points in chunks
of 65,536: 7.9 μs a point wall (0.94 μs CPU) on one thread, 59 μs wall (10.7 μs CPU) on two.
One thread also makes the result independent of the machine's thread count."""


def full_turn_a(machine) -> bool:
    """True when the A stroke spans at least one full turn (A is a continuous rotary axis)."""
    lo, hi = machine.strokes["a_deg"]
    return hi - lo >= 360.0 - 1e-9


def fold_a(axes, machine) -> np.ndarray:
    """Axes with A folded into ``[a_lo, a_lo + 360)`` when the stroke spans a full turn, (n, 3)."""
    out = np.array(axes, dtype=float, copy=True)
    if full_turn_a(machine):
        a_lo = machine.strokes["a_deg"][0]
        out[:, 2] = a_lo + np.mod(out[:, 2] - a_lo, 360.0)
    return out


def wrap180(angle_deg) -> np.ndarray:
    """Angles folded into ``[-180, 180)``."""
    return np.mod(np.asarray(angle_deg, dtype=float) + 180.0, 360.0) - 180.0


@contextlib.contextmanager
def field_threads(field):
    """Run the block with :data:`FIELD_TORCH_THREADS` torch threads if ``field`` is a torch field."""
    if PREDICT_COLUMNS not in field.capabilities:
        yield
        return
    with limit_threads(FIELD_TORCH_THREADS):
        yield


def field_error_um(field, axes, machine, chunk: int = FIELD_CHUNK) -> np.ndarray:
    """``E(axes)`` μm with A folded into the calibrated turn, in chunks, on :func:`field_threads`; (n, 3) -> (n, 3).

    Fields declaring ``predict_columns`` (the learned MLP) are evaluated through it, in float64: the same field
    without ``predict``'s validation and conversions. Capabilities: :mod:`errormap.field`.
    """
    axes = fold_a(axes, machine)
    n = axes.shape[0]
    out = np.empty((n, 3))
    with field_threads(field):
        for s in range(0, n, chunk):
            a = axes[s:s + chunk]
            out[s:s + chunk] = (field.predict_columns(np.ascontiguousarray(a.T)).T
                                if PREDICT_COLUMNS in field.capabilities
                                else np.asarray(field.predict(a), dtype=float).reshape(-1, 3))
    return out


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
