"""The Newton core of exact compensation: Newton's method with a backtracking line search, in axis space.

The solver itself is :func:`compensation.solvers.chain_exact.solve_exact_chain`. For each target ``p_d`` it
solves ``F(q) = fwd(q) + 1e-3·E(q) - p_d = 0`` (mm) for the axis command ``q`` with ``J(q) = dfwd/dq +
1e-3·dE/dq``, then ``p_r = fwd(q)``: ``fwd`` and ``dfwd/dq`` from the machine's chain
(:class:`errormap.chain_kernel.NominalChain`), ``dE/dq`` from the field once per point, then Broyden
updates; steps limited to 1 mm / 90° and halved (Armijo) until ``|F|`` decreases; stops at ``xtol_um``,
round-off (:data:`ROUNDOFF_ULPS`) or stagnation. Which axes move: :func:`solved_axes`. Compiled kernels over
the chain's op arrays; the field is called once per line-search round on all trial points. Why axis space,
and the measurements: docs/explanation/solvers.md ("exact")."""
from __future__ import annotations

import numpy as np
from numba import njit

from errormap.chain_kernel import NominalChain, nominal_columns, nominal_point

from ._common import MM_PER_UM, wrap180

MAX_STEP_MM = 1.0
MAX_STEP_DEG = 90.0
"""Largest Newton step of a linear (mm) and of a rotary (deg) axis before the line search."""
ARMIJO = 1e-4
MAX_HALVINGS = 20
SLOW = 0.99
"""An accepted step that leaves more than SLOW·|F| counts as no progress (stagnation)."""
ROUNDOFF_ULPS = 1024.0
"""``|F|`` within this many ulps of the target's largest coordinate is round-off: iteration stops there (as
at ``xtol_um``), about 4.5e-8 μm for a 200 mm coordinate, where more halvings only spent field evaluations.
A tighter stop is a setting (``solve("exact", …, roundoff_ulps=…)``); its cost and the measurements:
docs/decisions/020-benchmark-notebook.md."""


MAX_ROUNDOFF_ULPS = 1e6
"""Largest ``roundoff_ulps`` (1e6 ulps of a 200 mm coordinate is 4.4e-5 μm, below the default
success threshold ``tol_um`` = 1e-4 μm)."""


def check_roundoff_ulps(roundoff_ulps) -> float:
    """``roundoff_ulps`` as a float in ``[0, MAX_ROUNDOFF_ULPS]``; ValueError otherwise."""
    if isinstance(roundoff_ulps, bool) or not isinstance(roundoff_ulps, (int, float, np.integer, np.floating)) \
            or not 0.0 <= float(roundoff_ulps) <= MAX_ROUNDOFF_ULPS:
        raise ValueError(f"Expected roundoff_ulps in [0, {MAX_ROUNDOFF_ULPS:g}], got {roundoff_ulps!r}")
    return float(roundoff_ulps)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _solve3_point(a00, a01, a02, a10, a11, a12, a20, a21, a22, b0, b1, b2):  # pragma: no cover - compiled
    """``J x = b`` for one 3×3 system by Cramer's rule (a zero step when numerically singular)."""
    m0 = a11 * a22 - a12 * a21  # cofactors of the first row
    m1 = a12 * a20 - a10 * a22
    m2 = a10 * a21 - a11 * a20
    det = a00 * m0 + a01 * m1 + a02 * m2
    col = np.sqrt(a00**2 + a10**2 + a20**2) * np.sqrt(a01**2 + a11**2 + a21**2) * np.sqrt(a02**2 + a12**2 + a22**2)
    if not abs(det) > 1e-13 * col:
        return 0.0, 0.0, 0.0
    inv = 1.0 / det
    return ((m0 * b0 + (a02 * a21 - a01 * a22) * b1 + (a01 * a12 - a02 * a11) * b2) * inv,
            (m1 * b0 + (a00 * a22 - a02 * a20) * b1 + (a02 * a10 - a00 * a12) * b2) * inv,
            (m2 * b0 + (a01 * a20 - a00 * a21) * b1 + (a00 * a11 - a01 * a10) * b2) * inv)


@njit(cache=True, nogil=True, error_model="numpy")
def _solve3_kernel(J, b, x):  # pragma: no cover - compiled
    for k in range(J.shape[0]):
        x[k, 0], x[k, 1], x[k, 2] = _solve3_point(J[k, 0, 0], J[k, 0, 1], J[k, 0, 2], J[k, 1, 0], J[k, 1, 1],
                                                  J[k, 1, 2], J[k, 2, 0], J[k, 2, 1], J[k, 2, 2],
                                                  b[k, 0], b[k, 1], b[k, 2])


def solve3(J, b) -> np.ndarray:
    """Solve ``J x = b`` for a batch of 3×3 systems by Cramer's rule; (n,3,3),(n,3) -> (n,3).

    Compiled, point by point (the Newton loop's own step, :func:`_solve3_point`). A
    (numerically) singular system gives a zero step (the point then stagnates).
    """
    J = np.ascontiguousarray(J, dtype=float)
    b = np.ascontiguousarray(b, dtype=float)
    x = np.empty_like(b)
    _solve3_kernel(J, b, x)
    return x


# ---------------------------------------------------------------------------- the generic Newton core

def solved_axes(chain: NominalChain) -> np.ndarray:
    """Indices (3,) of the axes the exact solvers move to place the tool point, read from the
    machine's chain: its linear axes when it has three (rotary axes, the tool's orientation, are
    kept as commanded), else every axis of a three-axis machine (e.g. two linear axes and a
    rotary one, as the X-Z-A grinder: the rotary axis is solved). ValueError otherwise."""
    lin = [j for j, kd in enumerate(chain.kinds) if kd == "linear"]
    if len(lin) == 3:
        return np.array(lin, dtype=np.int64)
    if chain.k == 3:
        return np.arange(3, dtype=np.int64)
    raise ValueError(f"the exact solver places the tool point with three axes: the three linear axes, or the "
                     f"three axes of a three-axis machine; {chain.machine_tool.name!r} has {len(lin)} linear of "
                     f"{chain.k} ({', '.join(chain.columns)})")


def max_step(chain: NominalChain, sol) -> np.ndarray:
    """Largest Newton step of each solved axis (3,): :data:`MAX_STEP_MM` or :data:`MAX_STEP_DEG` by
    the axis' kind."""
    return np.array([MAX_STEP_MM if chain.kinds[j] == "linear" else MAX_STEP_DEG for j in sol])


def keep_turn(chain: NominalChain, q, axes_d) -> None:
    """Full-turn axes of ``q`` (n, k) moved by whole turns onto the turn of ``axes_d`` (in place):
    ``q = q_d + wrap180(q - q_d)``, so a path whose targets are continuous gets continuous axes."""
    for j in np.flatnonzero(chain.full_turn):
        q[:, j] = axes_d[:, j] + wrap180(q[:, j] - axes_d[:, j])


@njit(cache=True, nogil=True, error_model="numpy")
def _residual_kernel(q, E, targets, prog, F, fn):  # pragma: no cover - compiled
    """``F = fwd(q) + 1e-3·E - p_d`` (n, 3) mm and ``|F|`` (n,), in place; ``fwd`` the chain's
    nominal tool point (:func:`errormap.chain_kernel.nominal_point`)."""
    m = max(prog[0].shape[0], 1)
    R = np.empty((3, 3))
    t = np.empty(3)
    W = np.empty((m, 3))
    ev = np.zeros(1)
    for i in range(q.shape[0]):
        nominal_point(q[i], prog, R, t, W, W, ev, False)
        f0 = t[0] + 1e-3 * E[i, 0] - targets[i, 0]
        f1 = t[1] + 1e-3 * E[i, 1] - targets[i, 1]
        f2 = t[2] + 1e-3 * E[i, 2] - targets[i, 2]
        F[i, 0], F[i, 1], F[i, 2] = f0, f1, f2
        fn[i] = np.sqrt(f0 * f0 + f1 * f1 + f2 * f2)


@njit(cache=True, nogil=True, error_model="numpy")
def _step_kernel(idx, q, JE, F, prog, own, sol, max_step, step):  # pragma: no cover - compiled
    """The Newton step of the points ``idx`` on the solved axes ``sol`` (3,):
    ``(dfwd/dq + 1e-3·JE) step = -F`` with the chain's nominal axis Jacobian at ``q``
    (:func:`errormap.chain_kernel.nominal_columns`), scaled down to ``max_step`` (per solved axis)
    where it exceeds it."""
    m = max(prog[0].shape[0], 1)
    R = np.empty((3, 3))
    t = np.empty(3)
    W = np.empty((m, 3))
    O = np.empty((m, 3))
    ev = np.zeros(1)
    Jp = np.empty((3, q.shape[1]))
    a, b, c = sol[0], sol[1], sol[2]
    for j in range(idx.shape[0]):
        i = idx[j]
        nominal_point(q[i], prog, R, t, W, O, ev, True)
        nominal_columns(prog, own, t, W, O, ev, Jp)
        J = JE[i]
        s0, s1, s2 = _solve3_point(Jp[0, a] + 1e-3 * J[0, a], Jp[0, b] + 1e-3 * J[0, b], Jp[0, c] + 1e-3 * J[0, c],
                                   Jp[1, a] + 1e-3 * J[1, a], Jp[1, b] + 1e-3 * J[1, b], Jp[1, c] + 1e-3 * J[1, c],
                                   Jp[2, a] + 1e-3 * J[2, a], Jp[2, b] + 1e-3 * J[2, b], Jp[2, c] + 1e-3 * J[2, c],
                                   -F[i, 0], -F[i, 1], -F[i, 2])
        big = max(abs(s0) / max_step[0], abs(s1) / max_step[1], abs(s2) / max_step[2])
        if big > 1.0:
            s0, s1, s2 = s0 / big, s1 / big, s2 / big
        step[j, 0], step[j, 1], step[j, 2] = s0, s1, s2


@njit(cache=True, nogil=True, error_model="numpy")
def _trial_kernel(idx, pend, alpha, step, q, sol, qt):  # pragma: no cover - compiled
    """Trial axes ``q + α·step`` (step on the solved axes ``sol``) of the pending positions ``pend``
    (into ``idx``), into ``qt`` (m, k)."""
    for j in range(pend.shape[0]):
        p = pend[j]
        i = idx[p]
        for k in range(q.shape[1]):
            qt[j, k] = q[i, k]
        for c in range(3):
            qt[j, sol[c]] = q[i, sol[c]] + alpha[p] * step[p, c]


@njit(cache=True, nogil=True, error_model="numpy")
def _accept_kernel(idx, pend, alpha, qt, Et, targets, prog, sol, armijo, slow, q, E, F, fn, JE,
                   accepted, crawl, left):  # pragma: no cover - compiled
    """The Armijo test of the trial points (``qt``, their field ``Et``); accepted points take the
    trial's ``q, E, F, |F|`` and a Broyden (secant) update of ``JE``'s solved columns in place. The
    positions still searching go to ``left`` (their ``α`` halved); returns how many."""
    m = max(prog[0].shape[0], 1)
    R = np.empty((3, 3))
    t = np.empty(3)
    W = np.empty((m, 3))
    ev = np.zeros(1)
    a, b, c = sol[0], sol[1], sol[2]
    nleft = 0
    for j in range(pend.shape[0]):
        p = pend[j]
        i = idx[p]
        nominal_point(qt[j], prog, R, t, W, W, ev, False)
        f0 = t[0] + 1e-3 * Et[j, 0] - targets[i, 0]
        f1 = t[1] + 1e-3 * Et[j, 1] - targets[i, 1]
        f2 = t[2] + 1e-3 * Et[j, 2] - targets[i, 2]
        ft = np.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        f_old = fn[i]
        if ft <= (1.0 - armijo * alpha[p]) * f_old:
            # Broyden (secant) update of the field part, free: dE = JE·dq along the step
            d0, d1, d2 = qt[j, a] - q[i, a], qt[j, b] - q[i, b], qt[j, c] - q[i, c]
            dd = max(d0 * d0 + d1 * d1 + d2 * d2, 1e-300)
            w0, w1, w2 = d0 / dd, d1 / dd, d2 / dd
            for r in range(3):
                miss = (Et[j, r] - E[i, r]) - (JE[i, r, a] * d0 + JE[i, r, b] * d1 + JE[i, r, c] * d2)
                JE[i, r, a] += miss * w0
                JE[i, r, b] += miss * w1
                JE[i, r, c] += miss * w2
            for k in range(q.shape[1]):
                q[i, k] = qt[j, k]
            for k in range(3):
                E[i, k] = Et[j, k]
            F[i, 0], F[i, 1], F[i, 2] = f0, f1, f2
            fn[i] = ft
            accepted[p] = True
            crawl[p] = ft > slow * f_old
        else:
            alpha[p] *= 0.5
            left[nleft] = p
            nleft += 1
    return nleft


def _line_search(ev, chain, sol, targets, idx, step, q, E, F, fn, JE):
    """Backtracking (Armijo) along ``step`` for the points ``idx`` (int64 indices). Accepted points
    get their new ``q, E, F, fn`` and a Broyden (secant) update of ``JE``, in place. Returns
    ``(accepted, crawl, nfev)``, the first two per position in ``idx``: a step was taken / it
    decreased ``|F|`` by less than ``SLOW``.
    """
    m = step.shape[0]
    nfev = 0
    alpha = np.ones(m)
    accepted = np.zeros(m, dtype=bool)
    crawl = np.zeros(m, dtype=bool)
    pend = np.arange(m)
    left = np.empty(m, dtype=np.int64)
    for _h in range(MAX_HALVINGS):
        qt = np.empty((pend.size, q.shape[1]))
        _trial_kernel(idx, pend, alpha, step, q, sol, qt)
        Et = np.ascontiguousarray(ev.value(qt))
        nfev += pend.size
        k = _accept_kernel(idx, pend, alpha, qt, Et, targets, chain.prog, sol, ARMIJO, SLOW, q, E, F, fn, JE,
                           accepted, crawl, left)
        if k == 0:
            break
        pend = left[:k].copy()
    return accepted, crawl, nfev


def newton(ev, chain: NominalChain, sol, targets, q0, xtol_um, max_iter, roundoff_ulps: float = ROUNDOFF_ULPS):
    """Newton–Broyden iterations with line search on one chunk; returns (q (m, k), E(q) (m, 3) μm,
    iterations, jacobians, nfev). A point stops at ``|F| ≤ max(xtol_um, roundoff_ulps ulps of its
    target's largest coordinate)``, at stagnation or after ``max_iter`` iterations.

    ``ev``: the field (``start(q) -> (E, JE, nfev)``, ``value(q) -> E``, ``jacobian(q, E) ->
    (JE, nfev)``; JE (m, 3, k)); ``chain`` the machine's nominal chain; ``sol`` (3,) the solved axes
    (:func:`solved_axes`; the others stay at ``q0``). Arrays stay full length; ``idx`` (int64)
    holds the points still iterating. The per-point arithmetic (residual, kinematic Jacobian, step,
    Armijo test, Broyden update) runs in compiled kernels over the chain's op arrays; the field is
    called on the whole set of trial points at once.
    """
    n = len(targets)
    targets = np.ascontiguousarray(targets, dtype=float)
    sol = np.ascontiguousarray(sol, dtype=np.int64)
    steps = max_step(chain, sol)
    q = np.array(q0, dtype=float)
    iters = np.zeros(n, dtype=np.int32)
    n_jac = np.ones(n, dtype=np.int32)
    E, JE, nfev = ev.start(q)
    E, JE = np.ascontiguousarray(E, dtype=float), np.ascontiguousarray(JE, dtype=float)
    F, fn = np.empty((n, 3)), np.empty(n)
    _residual_kernel(q, E, targets, chain.prog, F, fn)
    stale = np.zeros(n, dtype=bool)  # the field Jacobian needs recomputing
    tol = xtol_um * MM_PER_UM
    floor = roundoff_ulps * np.finfo(float).eps * np.maximum(np.abs(targets).max(axis=1), 1.0)  # mm
    stop = np.maximum(tol, floor)  # float precision: xtol, or round-off where that is larger
    idx = np.flatnonzero(fn > stop)
    for _ in range(max_iter):
        if idx.size == 0:
            break
        refresh = stale[idx]
        if refresh.any():
            ri = idx[refresh]
            JE[ri], fe = ev.jacobian(q[ri], E[ri])
            n_jac[ri] += 1
            stale[ri] = False
            nfev += fe
        step = np.empty((idx.size, 3))
        _step_kernel(idx, q, JE, F, chain.prog, chain.own, sol, steps, step)
        accepted, crawl, fe = _line_search(ev, chain, sol, targets, idx, step, q, E, F, fn, JE)
        nfev += fe
        iters[idx] += 1
        # no step decreased |F| (or only crawled): retry once with a fresh field Jacobian;
        # a failure right after a fresh Jacobian stops the point (stagnation)
        failed = ~accepted | crawl
        keep = fn[idx] > stop[idx]
        if failed.any():
            keep &= ~(failed & refresh)
            stale[idx[failed]] = True
        idx = idx[keep]
    return q, E, iters, n_jac, nfev
