"""Exact compensation: Newton's method with a backtracking line search, in axis space.

Solve for the axis command ``q`` (x_mm, z_mm, a_deg) of each target ``p_d``::

    F(q) = fwd(q) + 1e-3·E(q) - p_d = 0          (mm)
    J(q) = dfwd/dq + 1e-3·dE/dq                   (mm per mm, mm, deg)

then ``p_r = fwd(q)``. Why axis space and not WCS: in the WCS the field ``E(IK(p))`` is
steep near the A axis (its tangential slope grows like ``|E|/ρ``, and ρ is 0.1 mm at
z = 0 on the default grinder), so the WCS map ``p ↦ p + E(IK(p))`` can fold and a WCS
fixed-point or Newton iteration diverges there. In axis space both ``fwd`` and ``E`` are
smooth; the solution is the same point (``IK(fwd(q)) = q``, A modulo 360°), and the model
residual ``p_r + 1e-3·E(axes(p_r)) - p_d`` equals ``F(q)``.

Robustness:

* Backtracking (Armijo) line search on ``|F|``: a step is halved (up to 20 times) until
  ``|F|`` decreases by at least ``1e-4·α``; a point where no step decreases ``|F|`` by
  more than 1 %, even with a fresh Jacobian, stops (stagnation).
* Steps are limited to ``max_step`` (1 mm, 1 mm, 90°) before the line search.
* Jacobian: the kinematic part ``dfwd/dq`` is analytic and recomputed every iteration;
  the field part ``dE/dq`` comes from ``field.jacobian(axes)`` when the field has it, else
  from forward differences in axis space, once per point, then is updated along every
  accepted step by Broyden's secant rule (no extra evaluations); it is recomputed only
  where the line search fails or stalls. (The first step's modest reduction near the A
  axis is the kinematics' curvature — a 130 μm correction on a 0.4 mm radius turns A by
  ~20° — which the fresh analytic kinematic Jacobian handles in the next steps.)
* The ball is a hard limit: a root outside the 250 μm ball is projected onto the ball
  surface, reported with its (non-zero) residual and ``success = False``.
* ``success``: ``|residual| ≤ tol_um`` (default 1e-4 μm) and inside the ball. Iteration
  goes on to float precision (``|F| ≤ xtol_um``, default 1e-9 μm) or until stagnation.
"""
from __future__ import annotations

import time

import numpy as np

from errormap.kinematics import forward
from errormap.progress import Progress

from .base import BALL_RADIUS_UM, SolveResult
from ._common import (MM_PER_UM, UM_PER_MM, check_inputs, command_axes, field_error_and_jacobian_um, field_error_um,
                      field_jacobian_um, forward_and_jacobian, make_result, project_to_ball, wrap180)

MAX_STEP = np.array([1.0, 1.0, 90.0])
"""Largest Newton step (x_mm, z_mm, a_deg) before the line search."""
ARMIJO = 1e-4
MAX_HALVINGS = 20
SLOW = 0.99
"""An accepted step that leaves more than SLOW·|F| counts as no progress (stagnation)."""


def solve3(J, b) -> np.ndarray:
    """Solve ``J x = b`` for a batch of 3×3 systems by Cramer's rule; (n,3,3),(n,3) -> (n,3).

    Written out component by component (no temporaries of shape (n, 3, 3)). A
    (numerically) singular system gives a zero step (the point then stagnates).
    """
    J = np.asarray(J, dtype=float)
    b = np.asarray(b, dtype=float)
    a00, a01, a02 = J[:, 0, 0], J[:, 0, 1], J[:, 0, 2]
    a10, a11, a12 = J[:, 1, 0], J[:, 1, 1], J[:, 1, 2]
    a20, a21, a22 = J[:, 2, 0], J[:, 2, 1], J[:, 2, 2]
    m0 = a11 * a22 - a12 * a21  # cofactors of the first row
    m1 = a12 * a20 - a10 * a22
    m2 = a10 * a21 - a11 * a20
    det = a00 * m0 + a01 * m1 + a02 * m2
    col = np.sqrt(a00**2 + a10**2 + a20**2) * np.sqrt(a01**2 + a11**2 + a21**2) * np.sqrt(a02**2 + a12**2 + a22**2)
    ok = np.abs(det) > 1e-13 * col
    inv = np.where(ok, 1.0, 0.0) / np.where(ok, det, 1.0)
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    x = np.empty_like(b)
    x[:, 0] = (m0 * b0 + (a02 * a21 - a01 * a22) * b1 + (a01 * a12 - a02 * a11) * b2) * inv
    x[:, 1] = (m1 * b0 + (a00 * a22 - a02 * a20) * b1 + (a02 * a10 - a00 * a12) * b2) * inv
    x[:, 2] = (m2 * b0 + (a01 * a20 - a00 * a21) * b1 + (a00 * a11 - a01 * a10) * b2) * inv
    return x


def solve_exact(field, targets_mm, machine, *, target_axes=None, a_start_deg=None,
                ball_um: float = BALL_RADIUS_UM, tol_um: float = 1e-4, xtol_um: float = 1e-9,
                max_iter: int = 50, chunk: int = 250_000, progress: bool = True) -> SolveResult:
    """Exact compensation of WCS targets, shape (n, 3) mm (see the module docstring).

    Works in chunks of ``chunk`` points to bound peak memory. ``info`` holds the iteration
    count per point (``iterations``) and Jacobian evaluations (``jacobians``).
    """
    t0 = time.perf_counter()
    targets, axes_d = check_inputs(field, targets_mm, machine, target_axes, a_start_deg, ball_um)
    if not (tol_um > 0 and xtol_um > 0 and max_iter >= 1 and chunk >= 1):
        raise ValueError(f"Expected tol_um > 0, xtol_um > 0, max_iter ≥ 1, chunk ≥ 1, got "
                         f"{tol_um}, {xtol_um}, {max_iter}, {chunk}")
    n = len(targets)
    q = axes_d.copy()
    E = np.empty_like(q)
    iters = np.zeros(n, dtype=np.int32)
    n_jac = np.zeros(n, dtype=np.int32)
    nfev = 0
    bar = Progress(n, "exact", enabled=progress)
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        q[sl], E[sl], it, nj, fe = _newton(field, machine, targets[sl], axes_d[sl], xtol_um, max_iter)
        iters[sl], n_jac[sl] = it, nj
        nfev += fe
        bar.update(sl.stop - sl.start)
    q[:, 2] = axes_d[:, 2] + wrap180(q[:, 2] - axes_d[:, 2])
    commands = forward(machine, q)
    # the ball as a hard limit: roots outside it are projected onto its surface
    d_um = (commands - targets) * UM_PER_MM
    outside = np.linalg.norm(d_um, axis=1) > ball_um
    if outside.any():
        commands[outside] = targets[outside] + MM_PER_UM * project_to_ball(d_um[outside], ball_um)
        q[outside] = command_axes(machine, commands[outside], axes_d[outside])
        E[outside] = field_error_um(field, q[outside], machine)
        nfev += int(outside.sum())
    # E is the field at the final iterate (A moved by whole turns at most: E is periodic)
    res = (commands - targets) * UM_PER_MM + E
    converged = (np.linalg.norm(res, axis=1) <= tol_um) & ~outside
    return make_result("exact", targets, commands, q, res, converged, nfev, t0, ball_um,
                       info={"iterations": iters, "jacobians": n_jac, "tol_um": tol_um,
                             "outside_ball": np.flatnonzero(outside)})


def _index(idx, pos):
    """Point indices at positions ``pos`` of ``idx`` (a slice over all points or an index array)."""
    return pos if isinstance(idx, slice) else idx[pos]


def _take(idx, mask):
    """The entries of ``idx`` where ``mask`` holds; ``idx`` itself when the mask is all true
    (so the common path, all points iterating, indexes with a slice: views, not copies)."""
    return idx if mask.all() else _index(idx, np.flatnonzero(mask))


def _line_search(field, machine, targets, idx, step, q, E, F, fn, JE, JK):
    """Backtracking (Armijo) along ``step`` for the points ``idx``; ``pend`` are the positions (into
    ``idx``) still searching. Accepted points get their new ``q, E, F, fn, JK`` and a Broyden
    (secant) update of ``JE``, in place. Returns ``(accepted, crawl, nfev)``, the first two per
    position in ``idx``: a step was taken / it decreased ``|F|`` by less than ``SLOW``.
    """
    m = step.shape[0]
    nfev = 0
    alpha = np.ones(m)
    accepted = np.zeros(m, dtype=bool)
    crawl = np.zeros(m, dtype=bool)
    pend = None  # all of them
    for _h in range(MAX_HALVINGS):
        ii = idx if pend is None else _index(idx, pend)
        al = alpha if pend is None else alpha[pend]
        qt = q[ii] + al[:, None] * (step if pend is None else step[pend])
        Et = field_error_um(field, qt, machine)
        Pt, JKt = forward_and_jacobian(machine, qt)
        Ft = Pt + MM_PER_UM * Et - targets[ii]
        ft = np.sqrt(np.einsum("ij,ij->i", Ft, Ft))
        nfev += ft.size
        f_old = fn[ii].copy()  # fn[ii] may be a view, and fn is updated below
        ok = ft <= (1.0 - ARMIJO * al) * f_old
        if ok.any():
            if ok.all():
                good, sel, pos = ii, slice(None), (slice(None) if pend is None else pend)
            else:
                sel = ok
                pos = np.flatnonzero(ok) if pend is None else pend[ok]
                good = _index(idx, pos)
            # Broyden (secant) update of the field part, free: dE = JE·dq along the step
            dq, dE = qt[sel] - q[good], Et[sel] - E[good]
            JEg = JE[good]
            miss = dE - np.einsum("nij,nj->ni", JEg, dq)
            w = dq / np.maximum(np.einsum("ni,ni->n", dq, dq), 1e-300)[:, None]
            JE[good] = JEg + miss[:, :, None] * w[:, None, :]
            q[good], E[good], F[good], fn[good], JK[good] = qt[sel], Et[sel], Ft[sel], ft[sel], JKt[sel]
            accepted[pos] = True
            crawl[pos] = ft[sel] > SLOW * f_old[sel]
            if ok.all():
                break
        pend = np.flatnonzero(~ok) if pend is None else pend[~ok]
        alpha[pend] *= 0.5
    return accepted, crawl, nfev


def _newton(field, machine, targets, q0, xtol_um, max_iter):
    """Newton–Broyden iterations with line search on one chunk; returns (q, E(q) μm, iterations, jacobians, nfev).

    Arrays stay full length; ``idx`` selects the points still iterating (a slice while all
    of them are, the usual case on a path).
    """
    n = len(targets)
    q = q0.copy()
    iters = np.zeros(n, dtype=np.int32)
    n_jac = np.ones(n, dtype=np.int32)
    # value and field Jacobian at the start in one pass, in float32 where the field has it
    # (only the first step's direction depends on them: every later value is float64); the
    # kinematic Jacobian alongside
    E, JE, nfev = field_error_and_jacobian_um(field, q, machine, fast=True)
    P, JK = forward_and_jacobian(machine, q)
    F = P + MM_PER_UM * E - targets
    fn = np.sqrt(np.einsum("ij,ij->i", F, F))
    stale = np.zeros(n, dtype=bool)  # the field Jacobian needs recomputing
    tol = xtol_um * MM_PER_UM
    idx = _take(slice(None), fn > tol)
    for _ in range(max_iter):
        if not isinstance(idx, slice) and idx.size == 0:
            break
        refresh = None
        if stale[idx].any():
            refresh = _take(idx, stale[idx])
            JE[refresh], fe = field_jacobian_um(field, q[refresh], machine, e0_um=E[refresh])
            n_jac[refresh] += 1
            stale[refresh] = False
            nfev += fe
        step = solve3(JK[idx] + MM_PER_UM * JE[idx], -F[idx])
        big = np.max(np.abs(step) / MAX_STEP, axis=1)
        if np.any(big > 1.0):
            step /= np.maximum(big, 1.0)[:, None]
        m = step.shape[0]
        accepted, crawl, fe = _line_search(field, machine, targets, idx, step, q, E, F, fn, JE, JK)
        nfev += fe
        iters[idx] += 1
        # no step decreased |F| (or only crawled): retry once with a fresh field Jacobian;
        # a failure right after a fresh Jacobian stops the point (stagnation)
        failed = ~accepted | crawl
        keep = fn[idx] > tol
        if failed.any():
            idx_arr = _index(idx, np.arange(m))
            if refresh is not None:
                was_fresh = np.zeros(n, dtype=bool)
                was_fresh[refresh] = True
                keep &= ~(failed & was_fresh[idx_arr])
            stale[idx_arr[failed]] = True
        idx = _take(idx, keep)
    return q, E, iters, n_jac, nfev
