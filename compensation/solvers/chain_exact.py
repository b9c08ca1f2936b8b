"""Exact compensation on a machine-tool chain (``kind = "machine-tool"``): Newton in axis space.

For each target ``p_d`` (WCS mm, the nominal tool point of the program's axes ``q_d``) find the
axis command ``q`` such that the machine, driven to ``q``, puts the tool point on ``p_d``::

    F(q) = fwd(q) + 1e-3·E(q) − p_d = 0          (mm)
    J(q) = dfwd/dq_lin + 1e-3·dE/dq_lin           (mm per mm)

with ``fwd`` the machine's nominal forward kinematics (:meth:`errormap.mt_chain.MachineTool.nominal`)
and ``E`` the field (``predict_and_jacobian``, μm). Then ``p_r = fwd(q)`` and the model residual
``(p_r − p_d)·1e3 + E(q)`` equals ``F(q)·1e3``.

**Which axes move.** The tool-tip POSITION is compensated with the machine's three linear axes;
rotary axes (the tool's orientation relative to the workpiece on a 5-axis machine) are kept as
the program commands them, and the result says so (``info["kept_axes"]``). A machine with other
than three linear axes is refused (a lathe's X, Z cannot place a point in 3-D; not solved here).

**Why it is exact and fast.** With the rotary axes fixed, the nominal tool point is an affine
function of the linear axes (a product of translations along frame axes and fixed rotations), so
``fwd(q) = fwd(q_d) + A·(q_lin − q_lin,d)`` holds exactly with ``A = dfwd/dq_lin`` at ``q_d``:
the chain is walked once per point (a compiled pass over the chain's op arrays, the field kernel's
own :func:`errormap.mt_kernel._chain_point`), the Newton loop only calls the field's compiled
``predict_and_jacobian`` and a 3×3 Cramer solve (:func:`compensation.solvers.exact.solve3`).

Robustness: a step is halved (up to :data:`MAX_HALVINGS` times) until ``|F|`` decreases
(Armijo, :data:`ARMIJO`); iteration stops at ``|F| ≤ xtol_um`` or at round-off
(:data:`ROUNDOFF_ULPS` ulps of the target's largest coordinate), at stagnation or ``max_iter``.
The 250 μm ball is a hard limit: a root outside it is projected onto the ball's surface and
reported with its residual and ``success = False`` (the guards then refuse it unless overridden).
``success``: ``|residual| ≤ tol_um`` and inside the ball. Shapes: targets (n, 3) mm, axes (n, k)
in ``machine.axis_columns`` order.
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from errormap.field import PREDICT_AND_JACOBIAN, check_field
from errormap.mt_kernel import _chain_point, _jacobian_columns
from errormap.progress import Progress
from errormap.transforms import check_points

from ._common import MM_PER_UM, UM_PER_MM, make_result, project_to_ball
from .base import BALL_RADIUS_UM
from .exact import ARMIJO, MAX_HALVINGS, ROUNDOFF_ULPS, SLOW, solve3

KEPT_NOTE = ("tool-tip position compensated with the linear axes {lin}; the rotary axes {rot} (tool orientation) "
             "are kept as commanded")


@njit(cache=True, nogil=True, error_model="numpy")
def _nominal_kernel(axes, prog, own, P, J):  # pragma: no cover - compiled
    """Nominal tool point ``P`` (n, 3) mm and its axis Jacobian ``J`` (n, 3, k) mm per mm / per deg
    of a chain program without errors (:meth:`errormap.mt_kernel.CompiledChain._program`)."""
    kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt = prog
    k = axes.shape[1]
    m = kind.shape[0]
    W = np.empty((max(m, 1), 3))
    O = np.empty((max(m, 1), 3))
    R = np.empty((3, 3))
    t = np.empty(3)
    ev = np.zeros(max(own.shape[0], 1))
    Jp = np.empty((3, k))
    for n in range(axes.shape[0]):
        _chain_point(axes[n], ev, kind, eaxis, value, joint, jscale, slot, coef, block, BR, Bt, R, t, W, O, True)
        for i in range(3):
            for j in range(k):
                Jp[i, j] = 0.0
        _jacobian_columns(ev, kind, joint, jscale, slot, coef, own, t, W, O, Jp, 1.0)
        for i in range(3):
            P[n, i] = t[i]
            for j in range(k):
                J[n, i, j] = Jp[i, j]


def _nominal_program(machine):
    """The machine's chain packed for the kernels (its nominal program does not depend on the
    element values: a zero element set packs it)."""
    from errormap.mt_elements import ChainElementSet
    from errormap.mt_kernel import CompiledChain
    return CompiledChain(machine, ChainElementSet.zeros(machine))


def nominal_and_jacobian(machine, axes, compiled=None) -> tuple[np.ndarray, np.ndarray]:
    """Nominal tool point (n, 3) mm and ``d(tool point)/d(axes)`` (n, 3, k) of ``machine`` at
    ``axes`` (n, k), compiled (equal to :meth:`MachineTool.nominal` / ``axis_jacobian``, tested).
    ``compiled``: a :class:`errormap.mt_kernel.CompiledChain` of the machine (any element set;
    packed here when None)."""
    if compiled is None:
        compiled = _nominal_program(machine)
    axes = np.ascontiguousarray(axes, dtype=float)
    P = np.empty((axes.shape[0], 3))
    J = np.empty((axes.shape[0], 3, axes.shape[1]))
    _nominal_kernel(axes, compiled.prog_nom, compiled.own, P, J)
    return P, J


def linear_axes(machine) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into ``machine.axes``) of the linear axes and of the rotary axes; ValueError
    unless there are exactly three linear axes (the tool-tip position has three coordinates)."""
    lin = np.array([j for j, a in enumerate(machine.axes) if a.kind == "linear"], dtype=np.intp)
    rot = np.array([j for j, a in enumerate(machine.axes) if a.kind != "linear"], dtype=np.intp)
    if len(lin) != 3:
        raise ValueError(f"the exact chain solver compensates the tool-tip position with three linear axes; "
                         f"{machine.name!r} has {len(lin)} ({', '.join(machine.axis_columns[j] for j in lin)})")
    return lin, rot


def chain_inverse(machine, targets_mm, compiled=None) -> np.ndarray:
    """Nominal inverse kinematics of a machine whose axes are all linear: axis values (n, 3) whose
    nominal tool point is ``targets_mm`` (n, 3). Exact (the map is affine), solved from the stroke
    middle; ValueError for a machine with rotary axes (their values must come with the targets)."""
    lin, rot = linear_axes(machine)
    if len(rot):
        raise ValueError(f"{machine.name!r} has rotary axes; pass the targets' axes (target_axes)")
    p = np.asarray(targets_mm, dtype=float)
    mid = 0.5 * (machine.stroke_lo + machine.stroke_hi)[None]
    P0, J0 = nominal_and_jacobian(machine, mid, compiled)
    return mid + solve3(np.repeat(J0, len(p), axis=0), p - P0)


def target_axes_of(machine, targets, target_axes, compiled) -> np.ndarray:
    """The programmed axes of each target, shape (n, k): ``target_axes`` as given (checked: finite, one
    row per target, one column per axis of the machine) or the nominal inverse of the targets."""
    if target_axes is None:
        return chain_inverse(machine, targets, compiled)
    k = len(machine.axes)
    axes_d = np.array(target_axes, dtype=float)
    if axes_d.shape != (len(targets), k) or not np.all(np.isfinite(axes_d)):
        raise ValueError(f"Expected finite target_axes of shape ({len(targets)}, {k}) "
                         f"({', '.join(machine.axis_columns)}), got {axes_d.shape}")
    return axes_d


def solve_exact_chain(field, targets_mm, machine, *, target_axes=None, ball_um: float = BALL_RADIUS_UM,
                      tol_um: float = 1e-4, xtol_um: float = 1e-9, max_iter: int = 50, chunk: int = 250_000,
                      progress: bool = True):
    """Exact compensation of WCS targets (n, 3) mm on a machine-tool chain (module docstring).

    ``target_axes`` (n, k): the program's axes of each target (required when the machine has
    rotary axes: they are kept). ``field``: an error field over ``machine.axis_columns`` that
    declares ``predict_and_jacobian`` (:class:`errormap.mt_field.ChainField`). Returns a
    :class:`~compensation.solvers.base.SolveResult` with ``axes`` (n, k); ``info``: iterations per
    point, ``compensated_axes``, ``kept_axes``, ``note``, ``outside_ball``.
    """
    t0 = time.perf_counter()
    check_field(field, machine.axis_columns)
    if PREDICT_AND_JACOBIAN not in field.capabilities:
        raise TypeError(f"{type(field).__name__} declares no predict_and_jacobian; the exact chain solver needs it")
    lin, rot = linear_axes(machine)
    targets = check_points(targets_mm, "WCS targets (px_mm, py_mm, pz_mm)")
    if not (np.isfinite(ball_um) and ball_um > 0):
        raise ValueError(f"Expected a positive ball radius in μm, got {ball_um!r}")
    if not (tol_um > 0 and xtol_um > 0 and max_iter >= 1 and chunk >= 1):
        raise ValueError(f"Expected tol_um > 0, xtol_um > 0, max_iter ≥ 1, chunk ≥ 1, got "
                         f"{tol_um}, {xtol_um}, {max_iter}, {chunk}")
    compiled = _nominal_program(machine)
    axes_d = target_axes_of(machine, targets, target_axes, compiled)
    n = len(targets)
    q = axes_d.copy()
    commands = np.empty_like(targets)
    E = np.empty((n, 3))
    iters = np.zeros(n, dtype=np.int32)
    nfev = 0
    bar = Progress(n, "exact (chain)", enabled=progress)
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        q[sl], commands[sl], E[sl], iters[sl], fe = _newton(field, machine, compiled, targets[sl], axes_d[sl], lin,
                                                            xtol_um, max_iter)
        nfev += fe
        bar.update(sl.stop - sl.start)
    d_um = (commands - targets) * UM_PER_MM
    outside = np.linalg.norm(d_um, axis=1) > ball_um
    if outside.any():  # the ball as a hard limit: roots outside it are projected onto its surface
        P0, J0 = nominal_and_jacobian(machine, axes_d[outside], compiled)
        commands[outside] = targets[outside] + MM_PER_UM * project_to_ball(d_um[outside], ball_um)
        qo = axes_d[outside].copy()
        qo[:, lin] += solve3(J0[:, :, lin], commands[outside] - P0)
        q[outside] = qo
        E[outside] = field.predict(qo)
        nfev += int(outside.sum())
    res = (commands - targets) * UM_PER_MM + E
    converged = (np.linalg.norm(res, axis=1) <= tol_um) & ~outside
    names = machine.axis_columns
    info = {"iterations": iters, "tol_um": tol_um, "outside_ball": np.flatnonzero(outside),
            "compensated_axes": [names[j] for j in lin], "kept_axes": [names[j] for j in rot]}
    if len(rot):
        info["note"] = KEPT_NOTE.format(lin=", ".join(info["compensated_axes"]), rot=", ".join(info["kept_axes"]))
    return make_result("exact", targets, commands, q, res, converged, nfev, t0, ball_um, info=info)


def _newton(field, machine, compiled, targets, axes_d, lin, xtol_um, max_iter):
    """Newton on the linear axes of one chunk; returns ``(q (m, k), p_r (m, 3) mm, E (m, 3) μm at q,
    iterations (m,), field evaluations)``."""
    m = len(targets)
    P0, J0 = nominal_and_jacobian(machine, axes_d, compiled)
    A = np.ascontiguousarray(J0[:, :, lin])                       # (m, 3, 3) mm per mm, constant per point
    q = axes_d.copy()
    dq = np.zeros((m, 3))                                        # linear-axis offsets from axes_d
    E, JE = field.predict_and_jacobian(q)
    nfev = 2 * m
    F = P0 + 1e-3 * E - targets
    fn = np.linalg.norm(F, axis=1)
    scale = np.abs(targets).max(axis=1)
    stop = np.maximum(xtol_um * MM_PER_UM, ROUNDOFF_ULPS * np.spacing(np.maximum(scale, 1.0)))
    iters = np.zeros(m, dtype=np.int32)
    idx = np.flatnonzero(fn > stop)
    for _ in range(max_iter):
        if not idx.size:
            break
        step = solve3(A[idx] + 1e-3 * JE[idx][:, :, lin], -F[idx])
        alpha = np.ones(idx.size)
        pend = np.arange(idx.size)
        accepted = np.zeros(idx.size, bool)
        for _h in range(MAX_HALVINGS + 1):
            if not pend.size:
                break
            ii = idx[pend]
            dqt = dq[ii] + alpha[pend, None] * step[pend]
            qt = axes_d[ii].copy()
            qt[:, lin] += dqt
            Et, JEt = field.predict_and_jacobian(qt)
            nfev += 2 * ii.size
            Ft = P0[ii] + np.einsum("nij,nj->ni", A[ii], dqt) + 1e-3 * Et - targets[ii]
            ft = np.linalg.norm(Ft, axis=1)
            ok = ft <= (1.0 - ARMIJO * alpha[pend]) * fn[ii]
            good = pend[ok]
            gi = ii[ok]
            dq[gi], q[gi], E[gi], JE[gi], F[gi] = dqt[ok], qt[ok], Et[ok], JEt[ok], Ft[ok]
            slow = ft[ok] > SLOW * fn[gi]
            fn[gi] = ft[ok]
            accepted[good] = ~slow
            alpha[pend[~ok]] *= 0.5
            pend = pend[~ok]
        iters[idx] += 1
        idx = idx[accepted & (fn[idx] > stop[idx])]
    commands = P0 + np.einsum("nij,nj->ni", A, dq)
    return q, commands, E, iters, nfev
