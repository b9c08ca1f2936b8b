"""Helpers shared by the solvers: input validation, field evaluation, Jacobians, A continuity.

Conventions (all solvers):

* The field is an :class:`errormap.field.ErrorField`, checked once per solve
  (:func:`errormap.field.check_field`); its optional methods are used where its
  ``capabilities`` declare them, never probed.

* Targets ``p_d`` and commands ``p_r`` are WCS points, shape (n, 3), mm.
* Axes are ``(x_mm, z_mm, a_deg)``, shape (n, 3). The field is always evaluated with A
  folded into the calibrated turn ``[a_lo, a_lo + 360)`` of the A stroke when that stroke
  spans a full turn (errors are periodic in A, docs/kinematics.md), so multi-turn commands never
  reach a field outside its training range.
* A continuity: the axis command of ``p_r`` takes the A turn of its own target, i.e.
  ``a_r = a_d + wrap180(a_r - a_d)``, where the targets' A is unwrapped along the path
  (``kinematics.inverse(unwrap=True)``) or given by the caller (``target_axes``). A path
  whose targets are continuous therefore gets continuous compensated A, never a 360° jump.
* The model residual is ``(p_r - p_d)·1e3 + E(axes(p_r))`` μm (residual 1 of docs/kinematics.md).
"""
from __future__ import annotations

import contextlib
import time

import numpy as np

from errormap.field import FLOAT32, JACOBIAN, PREDICT_AND_JACOBIAN, PREDICT_COLUMNS, check_field
from errormap.kinematics import inverse
from errormap.machine import Grinder
from errormap.mt_kernel import NominalChain
from errormap.threads import limit_threads
from errormap.transforms import check_points

from .base import BALL_RADIUS_UM, SolveResult

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
FD_STEPS = np.array([1e-3, 1e-3, 1e-3])
"""Central-difference steps in axis space (mm, mm, deg) for fields without ``jacobian``."""


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


def check_inputs(field, targets_mm, machine, target_axes=None, a_start_deg=None, ball_um=BALL_RADIUS_UM):
    """Validate solver input before any expensive work.

    Returns ``(targets (n, 3) mm, target_axes (n, 3))``; the targets' A is unwrapped along
    the path (or taken from ``target_axes``, which must be the nominal axes of the targets).
    """
    check_field(field)
    if not isinstance(machine, Grinder):
        raise TypeError(f"Expected a grinder machine (errormap.machine.Grinder), got {type(machine).__name__}")
    targets = check_points(targets_mm, "WCS targets (px_mm, py_mm, pz_mm)")
    if not (np.isfinite(ball_um) and ball_um > 0):
        raise ValueError(f"Expected a positive ball radius in μm, got {ball_um!r}")
    if target_axes is None:
        axes_d = inverse(machine, targets, unwrap=True, a_start_deg=a_start_deg)
    else:
        axes_d = check_points(target_axes, "target axes (x_mm, z_mm, a_deg)")
        if axes_d.shape != targets.shape:
            raise ValueError(f"Expected target_axes of shape {targets.shape}, got {axes_d.shape}")
    return targets, axes_d


@contextlib.contextmanager
def field_threads(field):
    """Run the block with :data:`FIELD_TORCH_THREADS` torch threads if ``field`` is a torch field."""
    if PREDICT_COLUMNS not in field.capabilities:
        yield
        return
    with limit_threads(FIELD_TORCH_THREADS):
        yield


def field_error_um(field, axes, machine, chunk: int = FIELD_CHUNK, fast: bool = False) -> np.ndarray:
    """:func:`_field_error_um` on :func:`field_threads`."""
    with field_threads(field):
        return _field_error_um(field, axes, machine, chunk, fast)


def _field_error_um(field, axes, machine, chunk: int = FIELD_CHUNK, fast: bool = False) -> np.ndarray:
    """``E(axes)`` μm with A folded into the calibrated turn, in chunks; (n, 3) -> (n, 3).

    Fields declaring ``predict_columns`` (the learned MLP) are evaluated through it, in
    float64: the same field without ``predict``'s validation and conversions (the solvers
    validate their input once). ``fast=True`` (GA fitness only) uses the field's float32 path
    when it declares ``float32`` (a few nm from float64, below the GA's ~0.01 μm resolution);
    the result is float64 either way. Capabilities: :mod:`errormap.field`.
    """
    axes = fold_a(axes, machine)
    n = axes.shape[0]
    caps = field.capabilities
    if PREDICT_COLUMNS in caps and not fast:
        out = np.empty((n, 3))
        for s in range(0, n, chunk):
            out[s:s + chunk] = field.predict_columns(np.ascontiguousarray(axes[s:s + chunk].T)).T
        return out
    kw = {"dtype": np.float32} if fast and FLOAT32 in caps else {}
    if n <= chunk:
        return np.asarray(field.predict(axes, **kw), dtype=float).reshape(n, 3)
    out = np.empty((n, 3))
    for s in range(0, n, chunk):
        out[s:s + chunk] = np.asarray(field.predict(axes[s:s + chunk], **kw), dtype=float).reshape(-1, 3)
    return out


def field_jacobian_um(field, axes, machine, e0_um=None, chunk: int = FIELD_CHUNK) -> tuple[np.ndarray, int]:
    """``dE/d(axes)`` μm per (mm, mm, deg), shape (n, 3, 3) (rows: error components).

    Uses ``field.jacobian(axes)`` when the field declares ``jacobian``. Otherwise finite differences in
    axis space with steps :data:`FD_STEPS`: forward differences from ``e0_um = E(axes)``
    when given (3 evaluations per point), else central differences (6 per point).
    Returns ``(J, evaluations)``.
    """
    axes = np.asarray(axes, dtype=float)
    n = axes.shape[0]
    J = np.empty((n, 3, 3))
    if JACOBIAN in field.capabilities:
        a = fold_a(axes, machine)
        for s in range(0, n, chunk):
            J[s:s + chunk] = np.asarray(field.jacobian(a[s:s + chunk]), dtype=float).reshape(-1, 3, 3)
        return J, n
    signs = (1.0,) if e0_um is not None else (1.0, -1.0)
    m_shift = 3 * len(signs)
    step = max(1, chunk // m_shift)
    for s in range(0, n, step):
        a = axes[s:s + step]
        m = a.shape[0]
        shifted = np.repeat(a[None], m_shift, axis=0)  # (k, m, 3): +x[, -x], +z[, -z], +a[, -a]
        for k in range(3):
            for j, sg in enumerate(signs):
                shifted[len(signs) * k + j, :, k] += sg * FD_STEPS[k]
        e = field_error_um(field, shifted.reshape(-1, 3), machine, chunk=chunk).reshape(m_shift, m, 3)
        if e0_um is None:
            cols = [(e[2 * k] - e[2 * k + 1]) / (2 * FD_STEPS[k]) for k in range(3)]
        else:
            cols = [(e[k] - e0_um[s:s + step]) / FD_STEPS[k] for k in range(3)]
        J[s:s + step] = np.stack(cols, axis=2)
    return J, m_shift * n


def field_error_and_jacobian_um(field, axes, machine, chunk: int = FIELD_CHUNK, fast: bool = False):
    """``(E (n, 3) μm, dE/d(axes) (n, 3, 3), evaluations)`` at axes (n, 3), A folded.

    One pass through ``field.predict_and_jacobian`` when the field declares it (counted as two
    evaluations per point, a value and a Jacobian), else :func:`field_error_um` then
    :func:`field_jacobian_um` (forward differences from it). ``fast=True`` runs a field with a
    declared float32 path in float32 (e.g. a Newton start, where only the step direction matters).
    """
    n = np.asarray(axes).shape[0]
    caps = field.capabilities
    if PREDICT_AND_JACOBIAN not in caps:
        E = field_error_um(field, axes, machine, chunk=chunk)
        J, fe = field_jacobian_um(field, axes, machine, e0_um=E, chunk=chunk)
        return E, J, n + fe
    kw = {"dtype": np.float32} if fast and FLOAT32 in caps else {}
    a = fold_a(axes, machine)
    E, J = np.empty((n, 3)), np.empty((n, 3, 3))
    with field_threads(field):
        for s in range(0, n, chunk):
            e, j = field.predict_and_jacobian(a[s:s + chunk], **kw)
            E[s:s + chunk] = np.asarray(e, dtype=float).reshape(-1, 3)
            J[s:s + chunk] = np.asarray(j, dtype=float).reshape(-1, 3, 3)
    return E, J, 2 * n


def forward_and_jacobian(machine, axes, jac: bool = True):
    """Nominal tool point ``p`` (n, 3) mm and ``dp/d(axes)`` (n, 3, k) mm per mm / per deg of the
    machine's chain (:class:`errormap.mt_kernel.NominalChain`: for the grinder its chain file, the
    same one source as every chain), at ``axes`` (n, k). ``jac=False`` returns ``(p, None)``."""
    return NominalChain(machine).forward_and_jacobian(axes, jac)


def forward_jacobian(machine, axes) -> np.ndarray:
    """``d p / d(axes)`` of the nominal forward kinematics, mm per mm / per deg, (n, 3, k)."""
    return forward_and_jacobian(machine, axes)[1]


def command_axes(machine, commands_mm, axes_d) -> np.ndarray:
    """Axis commands of WCS commands, A on the turn of each target's A; (n, 3) -> (n, 3)."""
    q = inverse(machine, commands_mm, unwrap=False)
    q[:, 2] = axes_d[:, 2] + wrap180(q[:, 2] - axes_d[:, 2])
    return q


def project_to_ball(d_um, radius_um) -> np.ndarray:
    """Offsets (..., 3) μm radially projected onto the ball ``|d| ≤ radius_um`` (inside: unchanged)."""
    nrm = np.linalg.norm(d_um, axis=-1, keepdims=True)
    return d_um * np.minimum(1.0, radius_um / np.maximum(nrm, 1e-300))


def residual_um(field, machine, commands_mm, axes, targets_mm) -> np.ndarray:
    """Model residual ``(p_r - p_d)·1e3 + E(axes)`` μm, shape (n, 3)."""
    return (commands_mm - targets_mm) * UM_PER_MM + field_error_um(field, axes, machine)


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


def ga_result(method, field, machine, targets, offsets_um, axes_d, nfev, t0, ball_um, tol_um, seed, **info):
    """The result of a GA solver from its best offsets ``p_r - p_d`` (μm), shape (n, 3):
    commands, their axes, the float64 model residual, and ``converged`` = |residual| ≤ ``tol_um``."""
    commands = targets + MM_PER_UM * offsets_um
    axes = command_axes(machine, commands, axes_d)
    res = residual_um(field, machine, commands, axes, targets)
    converged = np.linalg.norm(res, axis=1) <= tol_um
    return make_result(method, targets, commands, axes, res, converged, nfev, t0, ball_um,
                       info={"tol_um": tol_um, "seed": seed if isinstance(seed, (int, np.integer)) else None, **info})
