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
from ._common import (MM_PER_UM, UM_PER_MM, check_inputs, command_axes, field_error_um, field_jacobian_um,
                      forward_jacobian, make_result, project_to_ball, wrap180)

MAX_STEP = np.array([1.0, 1.0, 90.0])
"""Largest Newton step (x_mm, z_mm, a_deg) before the line search."""
ARMIJO = 1e-4
MAX_HALVINGS = 20
SLOW = 0.99
"""An accepted step that leaves more than SLOW·|F| counts as no progress (stagnation)."""


def solve3(J, b) -> np.ndarray:
    """Solve ``J x = b`` for a batch of 3×3 systems by Cramer's rule; (n,3,3),(n,3) -> (n,3).

    A (numerically) singular system gives a zero step (the point then stagnates).
    """
    c0, c1, c2 = J[:, :, 0], J[:, :, 1], J[:, :, 2]
    c12 = np.cross(c1, c2)
    det = np.einsum("ij,ij->i", c0, c12)
    scale = np.linalg.norm(c0, axis=1) * np.linalg.norm(c1, axis=1) * np.linalg.norm(c2, axis=1)
    ok = np.abs(det) > 1e-13 * scale
    safe = np.where(ok, det, 1.0)
    x = np.stack([np.einsum("ij,ij->i", b, c12),
                  np.einsum("ij,ij->i", c0, np.cross(b, c2)),
                  np.einsum("ij,ij->i", c0, np.cross(c1, b))], axis=1) / safe[:, None]
    x[~ok] = 0.0
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


def _newton(field, machine, targets, q0, xtol_um, max_iter):
    """Newton–chord iterations with line search on one chunk; returns (q, E(q) μm, iterations, jacobians, nfev)."""
    n = len(targets)
    q = q0.copy()
    iters = np.zeros(n, dtype=np.int32)
    n_jac = np.zeros(n, dtype=np.int32)
    E = field_error_um(field, q, machine)  # μm at the current iterate
    F = forward(machine, q) + MM_PER_UM * E - targets
    fn = np.linalg.norm(F, axis=1)
    nfev = n
    JE = np.empty((n, 3, 3))  # field part of the Jacobian, μm per (mm, mm, deg)
    stale = np.ones(n, dtype=bool)  # Jacobian needs (re)computing
    active = np.flatnonzero(fn * UM_PER_MM > xtol_um)
    for _ in range(max_iter):
        if active.size == 0:
            break
        refresh = active[stale[active]]
        if refresh.size:
            JE[refresh], fe = field_jacobian_um(field, q[refresh], machine, e0_um=E[refresh])
            n_jac[refresh] += 1
            stale[refresh] = False
            nfev += fe
        # kinematic part always fresh (analytic, cheap); field part reused while it works
        J = forward_jacobian(machine, q[active]) + MM_PER_UM * JE[active]
        step = solve3(J, -F[active])
        big = np.max(np.abs(step) / MAX_STEP, axis=1)
        step /= np.maximum(big, 1.0)[:, None]
        # backtracking line search on the points still searching
        alpha = np.ones(active.size)
        crawl = np.zeros(n, dtype=bool)
        accepted = np.zeros(active.size, dtype=bool)
        pending = np.arange(active.size)
        for _h in range(MAX_HALVINGS):
            idx = active[pending]
            qt = q[idx] + alpha[pending, None] * step[pending]
            Et = field_error_um(field, qt, machine)
            Ft = forward(machine, qt) + MM_PER_UM * Et - targets[idx]
            nfev += idx.size
            ft = np.linalg.norm(Ft, axis=1)
            ok = ft <= (1.0 - ARMIJO * alpha[pending]) * fn[idx]
            if ok.any():
                good = idx[ok]
                crawl[good] = ft[ok] > SLOW * fn[good]
                # Broyden (secant) update of the field part, free: dE = JE·dq along the step
                dq, dE = qt[ok] - q[good], Et[ok] - E[good]
                miss = dE - np.einsum("nij,nj->ni", JE[good], dq)
                JE[good] += miss[:, :, None] * dq[:, None, :] / np.maximum(
                    np.einsum("ni,ni->n", dq, dq), 1e-300)[:, None, None]
                q[good], E[good], F[good], fn[good] = qt[ok], Et[ok], Ft[ok], ft[ok]
                accepted[pending[ok]] = True
            pending = pending[~ok]
            if pending.size == 0:
                break
            alpha[pending] *= 0.5
        iters[active] += 1
        # no step decreased |F| (or only crawled): retry once with a fresh Jacobian;
        # with a fresh one, stop (a root cannot be reached, e.g. a field discontinuity)
        failed_mask = ~accepted | crawl[active]
        stale[active[failed_mask]] = True
        # a failure right after a fresh Jacobian stops the point (boolean masks, no sorting)
        fresh = np.zeros(n, dtype=bool)
        fresh[refresh] = True
        stop_mask = failed_mask & fresh[active]
        done_mask = fn[active] * UM_PER_MM <= xtol_um
        active = active[~(stop_mask | done_mask)]
    return q, E, iters, n_jac, nfev
