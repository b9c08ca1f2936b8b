"""Exact compensation on a machine-tool chain (``kind = "machine-tool"``): Newton in axis space.

For each target ``p_d`` (WCS mm, the nominal tool point of the program's axes ``q_d``) find the axis command
``q`` with ``F(q) = fwd(q) + 1e-3·E(q) − p_d = 0`` (mm); ``p_r = fwd(q)`` and the model residual is
``F(q)·1e3``. The iteration is :func:`compensation.solvers.exact.newton`; which axes move:
:func:`solved_and_kept`. The 250 μm ball is a hard limit (a root outside is projected onto it, ``success``
False); a solved rotary command beyond :func:`rotary_guard`'s ``Δθ_max`` is refused with the programmed axes
kept (``info["rotary_refused"]``, ``info["rotary_reasons"]``). Shapes: targets (n, 3) mm, axes (n, k) in
``machine.axis_columns`` order. Derivations and measurements: docs/explanation/solvers.md ("The exact solver
on a chain")."""
from __future__ import annotations

import time

import numpy as np

from errormap.field import FLOAT32, JACOBIAN, PREDICT_AND_JACOBIAN, PREDICT_COLUMNS, check_field
from errormap.chain_kernel import NominalChain
from errormap.progress import Progress
from errormap.transforms import check_points

from ._common import MM_PER_UM, UM_PER_MM, make_result, project_to_ball
from .base import BALL_RADIUS_UM
from .exact import ROUNDOFF_ULPS, check_roundoff_ulps, keep_turn, newton, solve3, solved_axes

KEPT_NOTE = ("tool-tip position compensated with the linear axes {lin}; the rotary axes {rot} (tool orientation) "
             "are kept as commanded")
SOLVED_NOTE = ("tool-tip position compensated with {sol} (every axis of the machine; the rotary axes {rot} solved, "
               "on the commanded turn)")


def nominal_and_jacobian(machine, axes, compiled=None) -> tuple[np.ndarray, np.ndarray]:
    """Nominal tool point (n, 3) mm and ``d(tool point)/d(axes)`` (n, 3, k) of ``machine`` at
    ``axes`` (n, k), compiled (equal to :meth:`MachineTool.nominal` / ``axis_jacobian``, tested).
    ``compiled``: the machine's :class:`errormap.chain_kernel.NominalChain` (packed here when None)."""
    if compiled is None:
        compiled = NominalChain(machine)
    return compiled.forward_and_jacobian(axes)


def linear_axes(machine) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into ``machine.axes``) of the linear axes and of the rotary axes; ValueError
    unless there are exactly three linear axes (what needs a slide per coordinate: the GA's linear
    offsets, per-joint tables, body diagonals; the exact solver uses :func:`solved_and_kept`)."""
    lin = np.array([j for j, a in enumerate(machine.axes) if a.kind == "linear"], dtype=np.intp)
    rot = np.array([j for j, a in enumerate(machine.axes) if a.kind != "linear"], dtype=np.intp)
    if len(lin) != 3:
        raise ValueError(f"this needs three linear axes (one slide per coordinate of the tool point); "
                         f"{machine.name!r} has {len(lin)} ({', '.join(machine.axis_columns[j] for j in lin)})")
    return lin, rot


def solved_and_kept(machine, compiled=None) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into ``machine.axes``) of the axes the exact chain solver moves (3,) and of those it
    keeps as commanded (k - 3,): :func:`compensation.solvers.exact.solved_axes` on the machine's chain
    (``compiled``, packed here when None). ValueError for a machine it cannot solve."""
    if compiled is None:
        compiled = NominalChain(machine)
    sol = np.asarray(solved_axes(compiled), dtype=np.intp)
    kept = np.array([j for j in range(compiled.k) if j not in set(sol.tolist())], dtype=np.intp)
    return sol, kept


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
    if target_axes is None:  # the closed-form inverse where the chain has one (rotary axis unwrapped along the path)
        try:
            return machine.inverse_closed(targets, unwrap=True)
        except ValueError:
            return chain_inverse(machine, targets, compiled)
    k = len(machine.axes)
    axes_d = np.array(target_axes, dtype=float)
    if axes_d.shape != (len(targets), k) or not np.all(np.isfinite(axes_d)):
        raise ValueError(f"Expected finite target_axes of shape ({len(targets)}, {k}) "
                         f"({', '.join(machine.axis_columns)}), got {axes_d.shape}")
    return axes_d


def check_rotary_limit(rotary_limit_deg):
    """``rotary_limit_deg`` as a float (None: no limit beyond the ball's, returned as inf); ValueError
    unless a positive number of degrees (at most 180)."""
    if rotary_limit_deg is None:
        return np.inf
    v = float(rotary_limit_deg)
    if not (np.isfinite(v) and 0.0 < v <= 180.0):
        raise ValueError(f"Expected a rotary correction limit in (0, 180] degrees, got {rotary_limit_deg!r}")
    return v


def rotary_bound_deg(radius_mm, ball_um: float = BALL_RADIUS_UM, rotary_limit_deg=None) -> np.ndarray:
    """Largest compensated change of a solved rotary axis (n,) deg at targets ``radius_mm`` (n,) mm from
    its line: ``min(degrees(asin(min(1, b/r))), rotary_limit_deg)`` with ``b = ball_um·1e-3`` mm
    (module docstring)."""
    r = np.asarray(radius_mm, dtype=float)
    with np.errstate(divide="ignore"):
        ratio = np.where(r > 0.0, (ball_um * MM_PER_UM) / np.where(r > 0.0, r, 1.0), np.inf)
    return np.minimum(np.degrees(np.arcsin(np.minimum(1.0, ratio))), check_rotary_limit(rotary_limit_deg))


def rotary_radius_mm(J_deg) -> np.ndarray:
    """Distance (n,) mm of the tool point from a rotary axis' line: ``|∂p/∂θ|·180/π`` from that axis'
    column (n, 3) of the nominal axis Jacobian (mm per degree)."""
    return np.linalg.norm(J_deg, axis=1) * (180.0 / np.pi)


def rotary_guard(compiled, machine, axes_d, q, sol, ball_um, rotary_limit_deg):
    """Points whose solved rotary command leaves its bound; returns (refused (n,) bool, reasons
    {index: text}). Only solved rotary axes are checked (kept ones are not moved)."""
    n = len(axes_d)
    refused = np.zeros(n, dtype=bool)
    reasons: dict = {}
    rot = [int(j) for j in sol if compiled.kinds[j] != "linear"]
    if not rot or n == 0:
        return refused, reasons
    _, J_d = nominal_and_jacobian(machine, axes_d, compiled)
    names = machine.axis_columns
    limit = check_rotary_limit(rotary_limit_deg)
    for j in rot:
        r = rotary_radius_mm(J_d[:, :, j])
        bound = rotary_bound_deg(r, ball_um, rotary_limit_deg)
        swing = np.abs(q[:, j] - axes_d[:, j])
        bad = ~(swing <= bound * (1.0 + 1e-12))
        for i in np.flatnonzero(bad).tolist():
            by = ("the --max-rotary-correction-deg limit" if limit <= bound[i]
                  else f"asin(ball {ball_um:g} um / r {r[i]:.4g} mm)")
            text = (f"rotary continuity: {names[j]} would turn by {swing[i]:.4g} deg from the programmed "
                    f"{axes_d[i, j]:.6g} deg, more than {bound[i]:.4g} deg ({by}); refused, programmed axes kept")
            reasons[i] = f"{reasons[i]}; {text}" if i in reasons else text
        refused |= bad
    return refused, reasons


def check_chain_call(field, targets_mm, machine, ball_um):
    """The chain solvers' shared checks (ValueError): the field over ``machine.axis_columns``, a machine
    the chain solvers can place the tool point on, the targets, the ball. Returns ``(compiled, solved (3,),
    kept, targets (n, 3) mm)``."""
    check_field(field, machine.axis_columns)
    compiled = NominalChain(machine)
    sol, kept = solved_and_kept(machine, compiled)
    targets = check_points(targets_mm, "WCS targets (px_mm, py_mm, pz_mm)")
    if not (np.isfinite(ball_um) and ball_um > 0):
        raise ValueError(f"Expected a positive ball radius in μm, got {ball_um!r}")
    return compiled, sol, kept, targets


def axes_info(info, compiled, machine, sol, kept, refused, reasons, rotary_limit_deg) -> dict:
    """``info`` with the exact and traditional chain solvers' common keys: ``compensated_axes``, ``kept_axes``,
    the rotary guard's ``rotary_refused`` / ``rotary_reasons`` / ``rotary_limit_deg`` where a rotary axis is
    solved, ``note``."""
    names = machine.axis_columns
    info.update(compensated_axes=[names[j] for j in sol], kept_axes=[names[j] for j in kept])
    rot_sol = [names[j] for j in sol if compiled.kinds[j] != "linear"]
    if rot_sol:
        info["rotary_refused"] = np.flatnonzero(refused)
        info["rotary_reasons"] = [reasons[i] for i in np.flatnonzero(refused).tolist()]
        info["rotary_limit_deg"] = None if rotary_limit_deg is None else float(rotary_limit_deg)
    if len(kept):
        info["note"] = KEPT_NOTE.format(lin=", ".join(info["compensated_axes"]), rot=", ".join(info["kept_axes"]))
    elif rot_sol:
        info["note"] = SOLVED_NOTE.format(sol=", ".join(info["compensated_axes"]), rot=", ".join(rot_sol))
    return info


def solve_exact_chain(field, targets_mm, machine, *, target_axes=None, ball_um: float = BALL_RADIUS_UM,
                      tol_um: float = 1e-4, xtol_um: float = 1e-9, max_iter: int = 50, chunk: int = 250_000,
                      rotary_limit_deg=None, progress: bool = True, roundoff_ulps: float = ROUNDOFF_ULPS):
    """Exact compensation of WCS targets (n, 3) mm on a machine-tool chain (module docstring).

    ``target_axes`` (n, k): the program's axes of each target (required when the machine has
    rotary axes: they are kept). ``field``: an error field over ``machine.axis_columns`` that
    declares ``predict_and_jacobian`` (:class:`errormap.chain_field.ChainField`). ``rotary_limit_deg``:
    a limit on a solved rotary axis' correction below the ball's bound (module docstring).
    ``roundoff_ulps`` (0 … 1e6, default :data:`~compensation.solvers.exact.ROUNDOFF_ULPS`): iteration also
    stops where ``|F|`` is within this many ulps of the target's largest coordinate; a smaller value iterates
    on to ``xtol_um`` or stagnation (to compare two solvers below their round-off); it does not change
    ``success`` (``tol_um``). Works in chunks of ``chunk`` points to bound peak memory. Returns a
    :class:`~compensation.solvers.base.SolveResult` with ``axes`` (n, k); ``info``: iterations per
    point, ``compensated_axes``, ``kept_axes``, ``note``, ``outside_ball``, ``rotary_refused``
    (indices), ``rotary_reasons`` (one text per refused index).
    """
    t0 = time.perf_counter()
    compiled, sol, kept, targets = check_chain_call(field, targets_mm, machine, ball_um)
    if not (tol_um > 0 and xtol_um > 0 and max_iter >= 1 and chunk >= 1):
        raise ValueError(f"Expected tol_um > 0, xtol_um > 0, max_iter ≥ 1, chunk ≥ 1, got "
                         f"{tol_um}, {xtol_um}, {max_iter}, {chunk}")
    check_rotary_limit(rotary_limit_deg)
    roundoff_ulps = check_roundoff_ulps(roundoff_ulps)
    axes_d = target_axes_of(machine, targets, target_axes, compiled)
    n = len(targets)
    q = axes_d.copy()
    commands = np.empty_like(targets)
    E = np.empty((n, 3))
    iters = np.zeros(n, dtype=np.int32)
    n_jac = np.zeros(n, dtype=np.int32)
    nfev = 0
    bar = Progress(n, "exact (chain)", enabled=progress)
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        q[sl], commands[sl], E[sl], iters[sl], n_jac[sl], fe = _newton(field, compiled, targets[sl], axes_d[sl], sol,
                                                                       xtol_um, max_iter, roundoff_ulps)
        nfev += fe
        bar.update(sl.stop - sl.start)
    d_um = (commands - targets) * UM_PER_MM
    outside = np.linalg.norm(d_um, axis=1) > ball_um
    if outside.any():  # the ball as a hard limit: roots outside it are projected onto its surface
        P0, J0 = nominal_and_jacobian(machine, axes_d[outside], compiled)
        commands[outside] = targets[outside] + MM_PER_UM * project_to_ball(d_um[outside], ball_um)
        qo = axes_d[outside].copy()
        qo[:, sol] += solve3(J0[:, :, sol], commands[outside] - P0)
        q[outside] = qo
        E[outside] = field.predict(qo)
        nfev += int(outside.sum())
    refused, reasons = rotary_guard(compiled, machine, axes_d, q, sol, ball_um, rotary_limit_deg)
    if refused.any():  # never silently swung: the programmed axes are kept, the point is unsolved
        q[refused] = axes_d[refused]
        commands[refused] = compiled.forward(axes_d[refused])
        E[refused] = field.predict(axes_d[refused])
        nfev += int(refused.sum())
    res = (commands - targets) * UM_PER_MM + E
    converged = (np.linalg.norm(res, axis=1) <= tol_um) & ~outside & ~refused
    info = axes_info({"iterations": iters, "jacobians": n_jac, "tol_um": tol_um, "outside_ball": np.flatnonzero(outside)},
                     compiled, machine, sol, kept, refused, reasons, rotary_limit_deg)
    return make_result("exact", targets, commands, q, res, converged, nfev, t0, ball_um, info=info)


class _ChainFieldEval:
    """A field for the exact solver's Newton core (:func:`compensation.solvers.exact.newton`), evaluated as
    every solver evaluates a field: full-turn axes folded into the calibrated turn of their stroke, its
    float32 path for the start where it declares one (only the first step's direction depends on it), its
    ``predict_columns`` for values where declared, its own Jacobian where declared, else forward differences
    (:data:`FD_STEP`). Shapes: axes (m, k), values (m, 3) μm, Jacobians (m, 3, k)."""

    def __init__(self, field, machine):
        self.field = field
        self.full = [(j, float(machine.axes[j].stroke[0])) for j, a in enumerate(machine.axes) if a.full_turn]
        self.own = PREDICT_AND_JACOBIAN in field.capabilities and JACOBIAN in field.capabilities

    def fold(self, q):
        if not self.full:
            return q
        q = np.array(q, dtype=float, copy=True)
        for j, lo in self.full:
            q[:, j] = lo + np.mod(q[:, j] - lo, 360.0)
        return q

    def start(self, q):
        if not self.own:
            E = self.value(q)
            J, fe = self.jacobian(q, E)
            return E, J, len(q) + fe
        kw = {"dtype": np.float32} if FLOAT32 in self.field.capabilities else {}
        E, JE = self.field.predict_and_jacobian(self.fold(q), **kw)
        return np.asarray(E, dtype=float), np.asarray(JE, dtype=float), 2 * len(q)

    def value(self, q):
        a = self.fold(q)
        if PREDICT_COLUMNS in self.field.capabilities:
            return np.ascontiguousarray(self.field.predict_columns(np.ascontiguousarray(a.T)).T, dtype=float)
        return np.asarray(self.field.predict(a), dtype=float)

    def jacobian(self, q, e0):
        if self.own:
            return np.asarray(self.field.jacobian(self.fold(q)), dtype=float), len(q)
        k = q.shape[1]
        J = np.empty((len(q), 3, k))
        for j in range(k):
            d = np.zeros(k)
            d[j] = FD_STEP
            J[:, :, j] = (self.value(q + d) - e0) / FD_STEP
        return J, k * len(q)


FD_STEP = 1e-3
"""Forward-difference step of a field without its own Jacobian, per axis (mm or deg)."""


def _newton(field, compiled, targets, axes_d, sol, xtol_um, max_iter, roundoff_ulps: float = ROUNDOFF_ULPS, q0=None):
    """The exact solver's Newton core on the solved axes ``sol`` (3,) of one chunk (the others kept
    at ``axes_d``; a solved full-turn axis put on the turn of ``axes_d``), started from ``q0`` (m, k) (default
    ``axes_d``: a GA's polish starts from its best); returns
    ``(q (m, k), p_r (m, 3) mm, E (m, 3) μm at q, iterations (m,), Jacobians (m,), field evaluations)``."""
    start = axes_d if q0 is None else q0
    q, E, iters, n_jac, nfev = newton(_ChainFieldEval(field, compiled.machine_tool), compiled, sol, targets, start,
                                      xtol_um, max_iter, roundoff_ulps=roundoff_ulps)
    keep_turn(compiled, q, axes_d)
    return q, compiled.forward(q), E, iters, n_jac, nfev
