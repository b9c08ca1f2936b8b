"""Turning mode on a lathe: while the spindle turns, C is the spindle, not a positioning axis.

A lathe's machine file names its work spindle and the M codes that start and end turning (``[spindle]``;
docs/how-to/machine-file.md). While the spindle turns, a move is compensated with X and Z alone (C is never
written) so that the tool tip's radius and axial position, averaged over one turn, are the programmed ones::

g(X, Z) = mean over one turn of [ r(X, Z, c) − r_d ,  z(X, Z, c) − z_d ]  = 0   (μm)

with the tip ``fwd(q) + 1e-3·E(q)`` at :data:`TURN_SAMPLES` spindle angles, solved by Newton
(finite-difference 2×2 Jacobian, step :data:`FD_STEP_MM`); the spread over the turn (out-of-roundness) is
reported (``roundness_um``). In C-axis mode C is solved with X and Z as on every three-axis machine. The
program rules (C words, turning codes): docs/reference/tool-paths.md ("Turning mode")."""
from __future__ import annotations

import dataclasses
from functools import partial

import numpy as np

from errormap.io import InputError

from .evaluate import gradient_norm
from .gcode import AxisWords, GProgram, parse_program, tokenize
from .nc_contour import expand_finishing, refuse_open
from .nc_expand import source_line
from .nc_g7x import expand_g7x, refuse_kept as refuse_kept_g7x
from .nc_groove import expand_grooves, refuse_kept as refuse_kept_groove
from .nc_thread import expand_threading, refuse_kept as refuse_kept_thread

TURN_SAMPLES = 24
"""Spindle angles (every 15°) at which the error is averaged over one turn: the chain's errors are smooth
in C (splines over a few stations and low harmonics), so 24 samples average their first harmonics exactly
(a harmonic of order < 24 averages to zero on 24 evenly spaced samples)."""
FD_STEP_MM = 1e-3
"""Finite-difference step for the 2×2 Jacobian of ``g`` (the error changes by ~1e-5 μm over it)."""
TOL_UM = 1e-4
"""A turning point converges when ``|g| ≤`` this (the exact chain solver's tolerance)."""
MAX_ITER = 30
AXIS_INVARIANCE_MM = 1e-9
"""The spindle must turn about the workpiece frame's z axis: the nominal r and z of a point may change by
at most this over the turn (checked; otherwise turning mode is refused for that machine file)."""


def spindle_turning(lines, spindle: dict) -> np.ndarray:
    """Per line (bool, shape (n,)): the spindle turns after the line's M codes (a ``turning_on`` code starts
    it, a ``turning_off`` code or ``M2``/``M30`` ends it; M codes act before the line's motion, RS274 order)."""
    on, off = set(spindle["turning_on"]), set(spindle["turning_off"]) | {2, 30}
    out = np.zeros(len(lines), dtype=bool)
    state = False
    for i, line in enumerate(lines):
        if "M" in line or "m" in line:
            for w in tokenize(line.rstrip("\r\n"))[1]:
                if w.letter == "M" and w.value == int(w.value):
                    code = int(w.value)
                    state = True if code in on else False if code in off else state
        out[i] = state
    return out


def _refuse_lathe_x(prog, lathe_x) -> None:
    """``lathe_x`` (``--lathe-x``) on a program whose dialect says it in the program (LinuxCNC G7/G8; the reader
    refuses a Fanuc, Haas or Siemens ISO lathe program's X without it, naming the option)."""
    from .dialects import DIALECTS
    if lathe_x is not None and not getattr(DIALECTS.get(prog.dialect), "lathe_x_by_parameter", False):
        raise InputError(f"{prog.path}: --lathe-x {lathe_x}: this {prog.dialect} program's X is not set by a control "
                         "parameter (LinuxCNC's G7/G8 say it in the program): leave --lathe-x out")


LATHE_X_KEY = "[spindle] x_words"
"""The machine file's key that says what a Fanuc, Haas or Siemens ISO lathe's X words are (its control's
parameter: Fanuc 1006 bit 3); ``--lathe-x`` overrides it for one run."""


def lathe_x_words(machine, option) -> tuple:
    """``(value, source)``: what a Fanuc, Haas or Siemens ISO lathe's X words are (``"diameter"``, ``"radius"``)
    and who said it: the option ``--lathe-x`` (``option``) over the machine file's :data:`LATHE_X_KEY`;
    ``(None, None)`` where neither does (such a program's X is refused, naming both)."""
    if option is not None:
        return option, "--lathe-x"
    value = (getattr(machine, "spindle", None) or {}).get("x_words")
    return (value, f"machine file {LATHE_X_KEY}") if value is not None else (None, None)


def lathe_x_entry(machine, option, dialect) -> dict:
    """The summary's ``lathe_x`` and ``lathe_x_source`` of a program whose dialect reads X by a control parameter
    (:func:`lathe_x_words`); empty otherwise."""
    from .dialects import DIALECTS
    value, source = lathe_x_words(machine, option)
    if value is None or not getattr(DIALECTS.get(dialect), "lathe_x_by_parameter", False):
        return {}
    return {"lathe_x": value, "lathe_x_source": source}


def parse_lathe_program(path, machine, rapids, block_delete, dialect=None, lathe_x=None,
                        subprograms=None, cycles="keep") -> tuple[GProgram, np.ndarray]:
    """A program for a machine with a ``[spindle]``: ``(program, turning)`` with ``turning`` (n_moves,) per
    move of ``program.moves`` (module docstring). ``lathe_x``: ``"diameter"`` or ``"radius"``, what a Fanuc, Haas
    or Siemens ISO lathe's X words are (``--lathe-x``; None: the machine file's :data:`LATHE_X_KEY`, and without
    it such a program's X is refused). ``cycles``: ``"expand"`` writes a contour cycle's ``G70`` as its moves
    (:func:`compensation.nc_contour.expand_finishing`); ``"keep"`` reads the contour in place."""
    option = lathe_x
    lathe_x = lathe_x_words(machine, lathe_x)[0]
    c = machine.spindle["axis"]
    full = AxisWords.of(machine)
    xz = dataclasses.replace(full, words=tuple(w for w in full.words if w != c),  # the file's harmless M codes kept
                             rotary=tuple(r for r in full.rotary if r != c))
    try:
        prog = _read(path, cycles, rapids=rapids, block_delete=block_delete, axis_words=xz, dialect=dialect,
                     lathe_x=lathe_x, subprograms=subprograms)
        _refuse_lathe_x(prog, option)
        refuse_open(path, prog.events)
        return prog, np.ones(len(prog.moves), dtype=bool)
    except InputError as exc:
        if f"no {c} axis" not in str(exc):
            raise  # a program without C words: the reading that applies to it names the refusal
    prog = parse_program(path, rapids=rapids, block_delete=block_delete, axis_words=full, dialect=dialect,
                         lathe_x=lathe_x, subprograms=subprograms)
    _refuse_lathe_x(prog, option)
    flags = spindle_turning(prog.lines, machine.spindle)
    turning = np.array([flags[m.index] for m in prog.moves], dtype=bool)
    stopped = next((m for m in prog.moves if m.lead is not None and not flags[m.index]), None)
    if stopped is not None:  # a thread with the spindle stopped (C-axis mode)
        on = ", ".join(f"M{k}" for k in machine.spindle["turning_on"])
        exc = InputError(f"{path}: line {stopped.index + 1}: '{stopped.synced}' while the spindle is stopped (C-axis "
                         f"mode): a thread is cut while it turns; start it ({on}) before the thread")
        raise exc if prog.expanded is None else prog.expanded.relocate(exc)
    if not turning.any():
        return prog, turning
    for m in prog.moves:
        if flags[m.index] and c in m.words:
            w = m.words[c]
            exc = InputError(f"{path}: line {m.index + 1}, column {w.start + 1}: '{c}{w.text}' while the spindle "
                             f"turns (turning mode): {c} is the spindle, not an axis; stop it (one of "
                             f"{', '.join(f'M{k}' for k in machine.spindle['turning_off'])}) before positioning {c}")
            raise exc if prog.expanded is None else prog.expanded.relocate(exc)
    kept = dataclasses.replace(full, kept=(c,))  # C written only where C-axis mode moves it
    prog = _read(path, cycles, rapids=rapids, block_delete=block_delete, axis_words=kept, dialect=dialect,
                 lathe_x=lathe_x, subprograms=subprograms)
    refuse_open(path, prog.events)
    flags = spindle_turning(prog.lines, machine.spindle)  # the lines read (an expanded G70 moves those after it)
    return prog, np.array([flags[m.index] for m in prog.moves], dtype=bool)


def _read(path, cycles, **kw) -> GProgram:
    """:func:`compensation.gcode.parse_program` of a lathe program (``kw``), its G70 lines, G92 passes and G74/G75
    cycles and LinuxCNC G70-G72 expanded where ``cycles`` is ``"expand"`` (:func:`compensation.nc_g7x.expand_g7x`,
    :func:`compensation.nc_contour.expand_finishing`,
    :func:`compensation.nc_thread.expand_threading`, :func:`compensation.nc_groove.expand_grooves`); kept, a G92
    refused (:func:`compensation.nc_thread.refuse_kept`) and a G74/G75 of several columns refused
    (:func:`compensation.nc_groove.refuse_kept`)."""
    prog = parse_program(path, **kw)
    if cycles != "expand":
        try:  # refused on the program's flat lines, named at the source line
            refuse_kept_thread(path, prog.events)  # a G92 kept as a cycle (compensation.nc_thread)
            refuse_kept_groove(path, prog.events)  # a G74/G75 of several columns: only as its moves
            refuse_kept_g7x(path, prog.events)  # a LinuxCNC G70-G72: only as its moves (compensation.nc_g7x)
        except InputError as exc:
            raise (prog.expanded.relocate(exc) if prog.expanded is not None else exc) from None
        return prog
    refuse_open(path, prog.events)
    kw.pop("subprograms", None)  # the flat text: its calls are expanded already
    reparse = lambda text: parse_program(path, data=text.encode("latin-1"), **kw)  # noqa: E731
    prog = expand_g7x(prog, path, reparse)  # first: the flat text read again holds no contour for them
    return expand_grooves(expand_threading(expand_finishing(prog, path, reparse), path, reparse), path, reparse)


class ColumnsField:
    """A chain field read at a program's columns (X, Z), the spindle's angle set to 0: for planning moves."""

    def __init__(self, field, columns, k):
        self.field, self.columns, self.k = field, np.asarray(columns), k

    def full(self, q):
        out = np.zeros((len(q), self.k))
        out[:, self.columns] = q
        return out

    def predict(self, q):
        return self.field.predict(self.full(np.asarray(q, dtype=float)))


# ---------------------------------------------------------------------------- the solver
def _indices(machine):
    c = machine.axis_words.index(machine.spindle["axis"])
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    return c, lin


def _over_turn(machine, q):
    n = len(q)
    c, _ = _indices(machine)
    Q = np.repeat(q, TURN_SAMPLES, axis=0)
    Q[:, c] = np.tile(np.arange(TURN_SAMPLES) * (360.0 / TURN_SAMPLES), n)
    return Q


def surface_residual_um(field, machine, axes, axes_d, compiled=None):
    """``(mean (n, 2), spread (n,))``: the tool tip's deviation (radial, axial; μm) from the surface of
    revolution of the programmed axes ``axes_d`` (n, k) when the machine (nominal + ``field``) is driven to
    ``axes`` (n, k), averaged over one turn of the spindle; ``spread`` the largest departure from that mean
    over the turn (what X and Z cannot correct)."""
    from .solvers.chain_exact import nominal_and_jacobian
    n = len(axes)
    P0, _ = nominal_and_jacobian(machine, _over_turn(machine, axes_d), compiled)
    P0 = P0.reshape(n, TURN_SAMPLES, 3)
    r0, z0 = np.hypot(P0[..., 0], P0[..., 1]), P0[..., 2]
    if n and max(np.ptp(r0, axis=1).max(), np.ptp(z0, axis=1).max()) > AXIS_INVARIANCE_MM:
        raise ValueError(f"machine {machine.name!r}: its spindle does not turn about the workpiece frame's z axis; "
                         "turning mode needs that")
    Q = _over_turn(machine, axes)
    P, _ = nominal_and_jacobian(machine, Q, compiled)
    P = (P + 1e-3 * np.asarray(field.predict(Q))).reshape(n, TURN_SAMPLES, 3)
    d = np.stack([np.hypot(P[..., 0], P[..., 1]) - r0[:, :1], P[..., 2] - z0[:, :1]], axis=-1) * 1e3
    mean = d.mean(axis=1)
    spread = np.linalg.norm(d - mean[:, None, :], axis=2).max(axis=1) if n else np.zeros(0)
    return mean, spread


def _tip_over_turn(field, machine, axes, compiled=None) -> tuple:
    """``(P (n, T, 3) mm, u (n, T, 2))``: the tool tip (nominal + ``field``; ``field`` None: nominal) over one turn
    of the spindle (:data:`TURN_SAMPLES` = T) at ``axes`` (n, k), and the unit xy direction in which the linear axis
    that moves the tip radially (X) moves it there."""
    from .solvers.chain_exact import nominal_and_jacobian
    Q = _over_turn(machine, axes)
    P, J = nominal_and_jacobian(machine, Q, compiled)
    if field is not None:
        P = P + 1e-3 * np.asarray(field.predict(Q))
    _, lin = _indices(machine)
    slide = J[:, :2, lin]  # (n·T, 2, 2): the xy motion of each linear axis
    j = np.argmax(np.linalg.norm(slide, axis=1), axis=1)
    u = slide[np.arange(len(Q)), :, j]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return P.reshape(len(axes), TURN_SAMPLES, 3), u.reshape(len(axes), TURN_SAMPLES, 2)


def height_um(field, machine, axes, compiled=None) -> np.ndarray:
    """(n,) the tool tip's distance (μm) from the plane through the spindle axis in which the linear axes move it
    (its centre-height error), averaged over one turn, the machine (nominal + ``field``) driven to ``axes`` (n, k).
    At every sample of the turn the tip's radius is at least this distance, so no X and Z bring the tip nearer the
    spindle axis than about this (X and Z change it only through the error's slope, nm over μm of travel)."""
    P, u = _tip_over_turn(field, machine, axes, compiled)
    return (np.abs(u[..., 0] * P[..., 1] - u[..., 1] * P[..., 0]) * 1e3).mean(axis=1)


def _closest_approach(field, machine, q, axes_d, compiled=None) -> tuple:
    """``(q, ok)``: ``q`` (n, k) moved in X and Z so that the tip crosses the slide's plane at the spindle axis (its
    mean position along the slide 0) at the programmed Z: where the tip passes nearest the axis (its radius the height
    error); ``ok`` (n,) where that converged (both within :data:`TOL_UM`)."""
    P0, _ = _tip_over_turn(None, machine, axes_d, compiled)
    z0 = P0[..., 2].mean(axis=1)

    def along(qq, idx):
        P, u = _tip_over_turn(field, machine, qq, compiled)
        s = (u * P[..., :2]).sum(axis=2).mean(axis=1)
        return np.stack([s, P[..., 2].mean(axis=1) - z0[idx]], axis=1) * 1e3, np.zeros(len(idx))
    q, g, _, ok, _ = _newton(along, np.array(q, dtype=float), _indices(machine)[1], TOL_UM, MAX_ITER)
    return q, ok & (np.linalg.norm(g, axis=1) <= TOL_UM)


def unreachable_radius(field, machine, q, axes_d, bad) -> tuple:
    """``(indices, height_um, axes)`` of the points ``bad`` (indices into ``q``/``axes_d`` (n, k)) whose programmed
    radius is nearer the spindle axis than the tool tip passes it (:func:`height_um` at ``q``): no X and Z reach it
    (a point on the axis, X0: centre drilling, drilling, tapping, facing to the centre). ``axes`` (m, k): theirs
    where the tip passes nearest the axis (:func:`_closest_approach`; a point where that does not converge is left
    out: a solver failure), what is written for them, ``height_um`` (m,) the centre height there: what is left is
    that height error, physics, not a solver failure (:data:`SPINDLE_AXIS_WHY`)."""
    from .solvers.chain_exact import nominal_and_jacobian
    bad = np.asarray(bad, dtype=np.intp)
    if not len(bad):
        return bad, np.zeros(0), q[bad]
    r0 = np.hypot(*nominal_and_jacobian(machine, axes_d[bad])[0][:, :2].T) * 1e3
    h = height_um(field, machine, q[bad])
    hit = np.flatnonzero(r0 < h - TOL_UM)
    nearest, ok = _closest_approach(field, machine, q[bad[hit]], axes_d[bad[hit]])
    return bad[hit[ok]], height_um(field, machine, nearest[ok]), nearest[ok]


SPINDLE_AXIS_WHY = ("the tool tip passes {h:.3g} um off centre height (the plane through the spindle axis in which X "
                    "moves it), which X and Z cannot correct: written where it passes nearest the axis (its mean "
                    "radius there, at least that height, is the residual left); adjust the tool's centre height")
"""Why a point nearer the spindle axis than the tip passes it is written, not refused (``{h}``: the largest centre
height, μm; ASCII: it goes into a G-code program's header too)."""


def _newton(fun, q, lin, tol_um: float, max_iter: int) -> tuple:
    """``(q, g, extra, ok, iterations)``: ``q`` (n, k) moved along the linear axes ``lin`` by Newton steps
    (finite-difference 2×2 Jacobian, step :data:`FD_STEP_MM`) until ``|g| ≤ tol_um``; ``fun(q_rows, rows) -> (g
    (m, 2) μm, extra (m,))`` at those rows; ``ok`` False where the Jacobian was singular."""
    n = len(q)
    g, extra = fun(q, np.arange(n))
    active, ok_all = np.linalg.norm(g, axis=1) > tol_um, np.ones(n, dtype=bool)
    it = 0
    while active.any() and it < max_iter:
        it += 1
        idx = np.flatnonzero(active)
        J = np.empty((len(idx), 2, 2))
        for col, j in enumerate(lin):
            qh = q[idx].copy()
            qh[:, j] += FD_STEP_MM
            J[:, :, col] = (fun(qh, idx)[0] - g[idx]) / FD_STEP_MM
        ok = np.abs(np.linalg.det(J)) > 1e-12
        step = np.zeros((len(idx), 2))
        step[ok] = np.linalg.solve(J[ok], -g[idx][ok][..., None])[..., 0]
        q[idx[:, None], np.array(lin)[None, :]] += step
        g[idx], extra[idx] = fun(q[idx], idx)
        ok_all[idx] &= ok
        active[idx] = (np.linalg.norm(g[idx], axis=1) > tol_um) & ok
    return q, g, extra, ok_all, it


def solve_turning(field, machine, axes_d, ball_um: float, tol_um: float = TOL_UM, max_iter: int = MAX_ITER):
    """X and Z of every turning point ``axes_d`` (n, k) so that ``g = 0`` (module docstring); C untouched.
    Returns ``(axes (n, k), residual (n, 3) μm as (radial, 0, axial), converged (n,), spread (n,), iterations)``."""
    from errormap.chain_kernel import NominalChain
    compiled = NominalChain(machine)
    _, lin = _indices(machine)
    q, g, spread, _, it = _newton(lambda qq, idx: surface_residual_um(field, machine, qq, axes_d[idx], compiled),
                                  np.array(axes_d, dtype=float), lin, tol_um, max_iter)
    moved = np.linalg.norm(q[:, lin] - axes_d[:, lin], axis=1) * 1e3
    converged = (np.linalg.norm(g, axis=1) <= tol_um) & (moved <= ball_um)
    residual = np.stack([g[:, 0], np.zeros(len(q)), g[:, 1]], axis=1)
    return q, residual, converged, spread, it


def tool_groups(tool_xz, n: int):
    """``(x_mm, z_mm, indices)`` per distinct lathe tool offset of ``tool_xz`` (n, 2) (None: none); a NaN row
    (no offset: the machine file's tool point) gives ``(None, None, indices)``."""
    if tool_xz is None:
        yield None, None, np.arange(n)
        return
    t = np.asarray(tool_xz, dtype=float)
    on = np.isfinite(t).all(axis=1)
    if (~on).any():
        yield None, None, np.flatnonzero(~on)
    for x, z in np.unique(t[on], axis=0):
        yield float(x), float(z), np.flatnonzero(on & (t[:, 0] == x) & (t[:, 1] == z))


def at_tool(field, machine, x_mm, z_mm):
    """``(field, machine)`` at a lathe tool's offsets (:func:`compensation.nc_state.machine_with_lathe_tool`);
    the given ones where ``x_mm`` is None. ``field`` None stays None."""
    if x_mm is None:
        return field, machine
    from .nc_state import field_with_tool, machine_with_lathe_tool
    mt = machine_with_lathe_tool(machine, x_mm, z_mm)
    return (None if field is None else field_with_tool(field, mt)), mt


def surface_residual_by_tool(field, machine, axes, axes_d, tool_xz):
    """:func:`surface_residual_um` of every point at its lathe tool's offsets (``tool_xz`` (n, 2), None: none)."""
    n = len(axes)
    mean, spread = np.zeros((n, 2)), np.zeros(n)
    for x, z, idx in tool_groups(tool_xz, n):
        f, mt = at_tool(field, machine, x, z)
        mean[idx], spread[idx] = surface_residual_um(f, mt, axes[idx], axes_d[idx])
    return mean, spread


def nominal_by_tool(machine, axes, tool_xz) -> np.ndarray:
    """The nominal tool points (n, 3) mm of ``axes`` (n, k), each at its lathe tool's offsets."""
    from .solvers.chain_exact import nominal_and_jacobian
    out = np.zeros((len(axes), 3))
    for x, z, idx in tool_groups(tool_xz, len(axes)):
        out[idx] = nominal_and_jacobian(at_tool(None, machine, x, z)[1], axes[idx])[0]
    return out


def solve_with_turning(solve_rest, field, machine, targets, axes_d, turning, ball_um, tool_xz=None):
    """One :class:`~compensation.solvers.base.SolveResult` over all points: ``turning`` (n,) points by
    :func:`solve_turning` (each at its lathe tool's offsets, ``tool_xz`` (n, 2), None: none), the others by
    ``solve_rest(targets, axes_d)`` (the chosen chain method). A turning point nearer the spindle axis than the tip
    passes it (:func:`unreachable_radius`) is written where the tip passes nearest the axis, ``success`` False (its
    target is not reached), listed in ``info["spindle_axis"]`` ({point: centre height μm}), which the convergence
    guard does not count (:func:`compensation.guards.convergence_violations`)."""
    import time
    from .solvers._common import make_result
    t0 = time.perf_counter()
    rest = np.flatnonzero(~turning)
    turn = np.flatnonzero(turning)
    n, k = axes_d.shape
    axes, commands = axes_d.astype(float).copy(), targets.astype(float).copy()
    residual, converged = np.zeros((n, 3)), np.zeros(n, dtype=bool)
    info, nfev, method = {}, 0, "exact"
    if len(rest):
        r = solve_rest(targets[rest], axes_d[rest])
        axes[rest], commands[rest], residual[rest], converged[rest] = r.axes, r.commands_mm, r.residual_um, r.success
        info, nfev, method = dict(r.info), r.nfev, r.method
        for key in ("rotary_refused", "outside_ball"):
            if key in info:
                info[key] = rest[np.asarray(info[key], dtype=np.intp)]
        info.pop("iterations", None)
    if len(turn):
        spread, on_axis = np.zeros(len(turn)), {}
        for x, z, idx in tool_groups(None if tool_xz is None else np.asarray(tool_xz)[turn], len(turn)):
            f, mt = at_tool(field, machine, x, z)
            q, res, conv, spread[idx], _ = solve_turning(f, mt, axes_d[turn[idx]], ball_um)
            axes[turn[idx]], residual[turn[idx]], converged[turn[idx]] = q, res, conv
            hit, h, nearest = unreachable_radius(f, mt, q, axes_d[turn[idx]], np.flatnonzero(~conv))
            on_axis.update(zip(turn[idx][hit].tolist(), h.tolist()))
            if len(hit):  # where the tip passes nearest the axis: its radius is what is left
                axes[turn[idx][hit]] = nearest
                g, spread[idx[hit]] = surface_residual_um(f, mt, nearest, axes_d[turn[idx][hit]])
                residual[turn[idx][hit]] = np.stack([g[:, 0], np.zeros(len(hit)), g[:, 1]], axis=1)
        commands[turn] = nominal_by_tool(machine, axes[turn], None if tool_xz is None else np.asarray(tool_xz)[turn])
        nfev += len(turn) * TURN_SAMPLES
        names = machine.axis_columns
        c, lin = _indices(machine)
        info.setdefault("compensated_axes", [names[j] for j in lin])
        info.setdefault("kept_axes", [names[c]])
        info["turning_points"] = int(len(turn))
        info["turning_roundness_max_um"] = float(spread.max())
        if on_axis:  # {point: centre height um}: not converged, yet not a solver failure (compensation.guards)
            info["spindle_axis"] = on_axis
        info["note"] = ((info["note"] + "; ") if info.get("note") else "") + (
            f"turning mode: {len(turn)} point(s) compensated with {', '.join(names[j] for j in lin)} against the "
            f"surface of revolution, {names[c]} untouched (the spindle)")
    return make_result(method, targets, commands, axes, residual, converged, nfev, t0, ball_um, info=info)


def hold_contours(res, tp, field, machine):
    """``res`` with a lathe contour cycle's monotonic axes kept monotonic (:func:`compensation.nc_contour.
    hold_back_steps`): the points held get their model residual and commands recomputed over the turn;
    ``res.info["contour_held"]`` lists them. A ``G70`` run with other tool offsets than its contour was compensated
    for is refused (:func:`compensation.nc_contour.refuse_other_tool`)."""
    from .nc_contour import hold_back_steps, refuse_other_tool
    prog = tp.source.program
    events = prog.events  # a G-code program's (the caller's test)
    if not any(e[2] == "lathe-contour" for e in events):
        return res
    name = partial(source_line, prog)  # the summary's and the refusals' lines: the source's
    try:
        if tp.tool_xz is not None:  # G70 with another tool than its contour was compensated for
            refuse_other_tool(tp.path, events, tp.lines, tp.tool_xz,
                              lambda line: tp.source.frames.lathe_tool(np.array([line - 1]))[0], name)
        xc, zc = machine.axis_words.index("X"), machine.axis_words.index("Z")
        axes, rows, held = hold_back_steps(tp.path, events, tp.lines, tp.axes, res.axes, xc, zc, name)
    except InputError as exc:  # on the program's flat lines: named at the source, as the reader's
        raise (prog.expanded.relocate(exc) if prog.expanded is not None else exc) from None
    if rows.size:
        txz = None if tp.tool_xz is None else np.asarray(tp.tool_xz)[rows]
        mean, _ = surface_residual_by_tool(field, machine, axes[rows], tp.axes[rows], txz)
        res.axes = axes
        res.residual_um[rows] = np.stack([mean[:, 0], np.zeros(len(rows)), mean[:, 1]], axis=1)
        res.commands_mm[rows] = nominal_by_tool(machine, axes[rows], txz)
        res.info["contour_held"] = held
    return res


NOSE_ARM = 1.0 + np.sqrt(2.0)
"""Under tool nose radius compensation (``G41``/``G42``) a lathe's axes carry the imaginary tool tip, which lies up to
r·√2 from the nose centre (tip directions 1-4; r for 5-8, 0 for 0/9), the centre r from the contour: the axes move
up to (1 + √2)·r from the programmed point, whatever the tip number (a tool table here holds none)."""


def nose_radius_bound_um(field, machine, axes, radius_mm, tool_xz, turning) -> float:
    """The error a lathe's ``G41``/``G42`` leaves, at most (μm): the spectral norm of the field's gradient along the
    linear axes (:func:`compensation.evaluate.gradient_norm`, at each point's tool offsets, over one turn of the
    spindle for ``turning`` points) × :data:`NOSE_ARM` × the nose radius. ``axes`` (n, k), ``radius_mm`` (n,) (NaN:
    compensation off), ``tool_xz`` (n, 2) or None, ``turning`` (n,) bool."""
    _, lin = _indices(machine)
    out = 0.0
    for x, z, idx in tool_groups(tool_xz, len(axes)):
        f, _ = at_tool(field, machine, x, z)
        for spun in (True, False):
            sel = idx[np.isfinite(radius_mm[idx]) & (np.asarray(turning, bool)[idx] == spun)]
            if not sel.size:
                continue
            q = _over_turn(machine, axes[sel]) if spun else axes[sel]
            norm = gradient_norm(f, q, lin).reshape(len(sel), -1).max(axis=1)
            out = max(out, float((norm * NOSE_ARM * radius_mm[sel]).max()))
    return out
