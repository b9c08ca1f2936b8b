"""The machine-tool benchmark's test parts and its judge (:mod:`.chain_benchmark`).

A test part is what a machine of that structure is accepted on, read from its chain, never from its name: the
flute of a micro drill (:func:`flute_part`, where :func:`compensation.toolpath.runs_flute`: a workpiece turned
about X by a full-turn A axis, the wheel fed by the other linear axis), the four body diagonals of three linear
axes (ISO 230-6, :func:`diagonal_path`), a turning centre's lines and face/diameter set (:func:`turning_path`);
:func:`judging_path` takes the first the machine can make. :func:`volume_path`: random points over every stroke. :func:`compensate_true`: the ``exact``
(or ``batched-ga``) solve of a part with a field and the TRUE residual on the hidden truth at the part's
conditions. docs/reference/benchmark.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from errormap.stats import residual_stats

from .benchmark_common import PATH_CONDITIONS

INSET = 0.02
"""The diagonals start and end this fraction of each linear stroke inside its ends (the compensated axes
must stay inside the strokes)."""
PATH_TEMP_C = PATH_CONDITIONS["temp_c"]
"""Temperature of every test part: a warm machine (24 °C)."""
PATH_TIME_S = PATH_CONDITIONS["time_s"]
"""Time into the warm-up of every test part (2 h), for fitted drift terms (the truth has none)."""
TURNING_C_POSITIONS = 8
"""Positions of the rotary axis (equally spaced over the turn) of the turning path's face/diameter set."""
TURNING_CLEARANCE_MM = 10.0
"""Points whose nominal tool point is closer than this to the rotary axis' line are left out of the turning
path: there the rotary axis' lever (|d tool point / d angle| in mm per rad) vanishes and the exact solver
must turn it far for a sideways error (``tests/test_lathe_compensate.py``); a turning program does not
ask a C move on the centre line."""
TURNING_RADIUS_FRACTION = 0.75
"""The diameter line and set: the radial axis at this fraction of its stroke."""
VOLUME_CLEARANCE_MM = 5.0
"""Volume points whose tool point is closer than this to a full-turn rotary axis' line (its lever below 5 mm per
rad) are left out: there the workpiece coordinates are singular (a sideways error needs a large turn)."""


@dataclass
class ChainPath:
    """Test points: ``axes`` (n, k) nominal axes, ``cond`` {name: (n,)} the truth's conditions, ``name``;
    ``targets`` (n, 3) the part's WCS targets (None: the nominal tool points of ``axes``)."""

    name: str
    axes: np.ndarray
    cond: dict
    targets: np.ndarray | None = None

    def targets_mm(self, machine) -> np.ndarray:
        if self.targets is None:
            from ...solvers.chain_exact import nominal_and_jacobian
            self.targets = nominal_and_jacobian(machine, self.axes)[0]
        return self.targets


def _conditions(machine, n, dirs) -> dict:
    return {"temp_c": np.full(n, PATH_TEMP_C), **{f"dir_{a.word.lower()}": dirs[:, j] for j, a in enumerate(machine.axes)}}


def flute_part(machine, s) -> ChainPath:
    """The variable-helix flute of a micro drill (``compensation/toolpath.py``, ``flute_turns`` ×
    ``flute_points_per_turn``) on a machine it runs on (:func:`compensation.toolpath.runs_flute`); at 24 °C, X
    and A approached in the path's direction of motion (+), the radial axis from above (−: the wheel plunges in
    to the flute-bottom radius). ValueError for any other machine, or a flute outside the linear strokes."""
    from ...toolpath import FLUTE_DRILL_AXIS, check_in_strokes, flute_path, runs_flute
    if not runs_flute(machine):
        raise ValueError(f"{machine.name}: the flute needs the workpiece turned about X by a full-turn A axis and one "
                         f"radial linear axis beside X (its axes: {' '.join(a.word for a in machine.axes)})")
    fl = flute_path(turns=s.flute_turns, points_per_turn=s.flute_points_per_turn)
    axes = fl.axes(machine)
    check_in_strokes(machine, axes, f"{machine.name}: the flute")   # its linear axes (the A turns fully)
    dirs = np.array([1.0 if a.kind == "rotary" or a.word == FLUTE_DRILL_AXIS else -1.0 for a in machine.axes])
    n = len(axes)
    return ChainPath(f"flute ({n} points)", axes, _conditions(machine, n, np.tile(dirs, (n, 1))), fl.targets_mm)


def _rotary_home(machine) -> np.ndarray:
    """(k,) the value each rotary axis is held at on the diagonals: 0 where inside its stroke, else the middle."""
    lo, hi = machine.stroke_lo, machine.stroke_hi
    return np.where((lo <= 0.0) & (hi >= 0.0), 0.0, 0.5 * (lo + hi))


def diagonal_path(machine, points_per_diagonal: int) -> ChainPath:
    """The four body diagonals of the linear axes' box (ISO 230-6), each from a corner to the opposite one;
    the approach direction of each axis is that of its motion along the diagonal."""
    from ...solvers.chain_exact import linear_axes
    lin, _ = linear_axes(machine)
    lo, hi = machine.stroke_lo, machine.stroke_hi
    span = hi - lo
    a0, a1 = lo + INSET * span, hi - INSET * span
    home = _rotary_home(machine)
    t = np.linspace(0.0, 1.0, points_per_diagonal)
    axes, dirs = [], []
    for flip in ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)):   # start corners; the end is the opposite corner
        start, end = home.copy(), home.copy()
        d = np.ones(len(machine.axes))
        for f, j in zip(flip, lin):
            start[j], end[j] = (a1[j], a0[j]) if f else (a0[j], a1[j])
            d[j] = -1.0 if f else 1.0
        axes.append(start + t[:, None] * (end - start))
        dirs.append(np.broadcast_to(d, (len(t), len(d))))
    axes, dirs = np.vstack(axes), np.vstack(dirs)
    return ChainPath(f"4 body diagonals ({len(axes)} points)", axes, _conditions(machine, len(axes), dirs))


def _rotary_lever_mm(machine, axes, r: int) -> np.ndarray:
    """(n,) |d tool point / d angle| of rotary axis ``r`` at ``axes``, mm per rad."""
    from ...solvers.chain_exact import nominal_and_jacobian
    _, J = nominal_and_jacobian(machine, axes)
    return np.linalg.norm(J[:, :, r], axis=1) * (180.0 / np.pi)


def turning_path(machine, points_per_line: int) -> ChainPath:
    """The judging path of a machine with two linear axes and one full-turn rotary axis (module doc): a
    line along each linear axis (the other linear axis at :data:`TURNING_RADIUS_FRACTION` of its stroke
    for the first axis' line, at its stroke middle for the second's, the rotary axis at 0), then at
    :data:`TURNING_C_POSITIONS` rotary positions a face set (first linear axis' lower end + inset, four
    positions of the second) and a diameter set (second axis at the radius fraction, four positions of the
    first). Points nearer than :data:`TURNING_CLEARANCE_MM` to the rotary axis' line are left out. Positive
    approach on every axis. ValueError for any other machine."""
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    rot = [j for j, a in enumerate(machine.axes) if a.kind == "rotary"]
    if len(machine.axes) != 3 or len(lin) != 2 or len(rot) != 1 or not machine.axes[rot[0]].full_turn:
        raise ValueError(f"{machine.name}: the turning path needs two linear axes and one full-turn rotary axis "
                         f"(its axes: {' '.join(a.word for a in machine.axes)})")
    lo, hi = machine.stroke_lo, machine.stroke_hi
    a0, a1 = lo + INSET * (hi - lo), hi - INSET * (hi - lo)
    r = rot[0]
    pts = []
    for j, other, at in ((lin[0], lin[1], TURNING_RADIUS_FRACTION), (lin[1], lin[0], 0.5)):
        line = np.zeros((points_per_line, 3))
        line[:, j] = np.linspace(a0[j], a1[j], points_per_line)
        line[:, other] = lo[other] + at * (hi[other] - lo[other])
        pts.append(line)
    u = np.linspace(0.0, 1.0, 4)
    for c in lo[r] + (hi[r] - lo[r]) * np.arange(TURNING_C_POSITIONS) / TURNING_C_POSITIONS:
        for j, other, at in ((lin[1], lin[0], None), (lin[0], lin[1], TURNING_RADIUS_FRACTION)):
            blk = np.zeros((4, 3))
            blk[:, j] = a0[j] + u * (a1[j] - a0[j])
            blk[:, other] = a0[other] if at is None else lo[other] + at * (hi[other] - lo[other])
            blk[:, r] = c
            pts.append(blk)
    axes = np.vstack(pts)
    axes = axes[_rotary_lever_mm(machine, axes, r) >= TURNING_CLEARANCE_MM]
    n = len(axes)
    name = (f"turning: lines along {machine.axes[lin[0]].word} and {machine.axes[lin[1]].word}, face/diameter set "
            f"at {TURNING_C_POSITIONS} {machine.axes[r].word} positions ({n} points)")
    return ChainPath(name, axes, _conditions(machine, n, np.ones((n, 3))))


def judging_path(machine, s) -> ChainPath:
    """The benchmark's test part of ``machine`` under the settings ``s``: the flute where the machine can make
    it, else the body diagonals (``chain_path_points`` each) where it has three linear axes, else the turning
    path; ValueError naming every reason for any other machine."""
    why = []
    for make in (lambda: flute_part(machine, s), lambda: diagonal_path(machine, s.chain_path_points),
                 lambda: turning_path(machine, s.chain_path_points)):
        try:
            return make()
        except ValueError as exc:
            why.append(str(exc))
    raise ValueError("; ".join(why))


def volume_path(machine, n: int, seed) -> ChainPath:
    """``n`` uniform random points over every stroke (drawn four times over; the first ``n`` at least
    :data:`VOLUME_CLEARANCE_MM` from every full-turn rotary axis' line kept), positive approach."""
    from errormap.chain_truth import random_axes
    axes = random_axes(machine, 4 * n, np.random.default_rng(seed))
    for r, a in enumerate(machine.axes):
        if a.kind == "rotary" and a.full_turn:
            axes = axes[_rotary_lever_mm(machine, axes, r) >= VOLUME_CLEARANCE_MM]
    axes = axes[:n]
    return ChainPath(f"volume ({len(axes)} points)", axes,
                     _conditions(machine, len(axes), np.ones((len(axes), len(machine.axes)))))


def with_path_conditions(field_, cond: dict):
    """``field_`` told the part's conditions its effect terms need (as ``compensate --temp-c/--dir-x`` tells it;
    ``time_s`` :data:`PATH_TIME_S`)."""
    needs = tuple(getattr(field_, "needs", ()))
    if not needs:
        return field_
    cond = {"time_s": np.array([PATH_TIME_S]), **cond}
    # a condition constant along the path is told as one value: the solver may evaluate the field on a subset
    # of the points (its retries of unconverged points, as near a turning centre's spindle axis)
    return field_.with_conditions({c: (float(cond[c][0]) if np.all(cond[c] == cond[c][0]) else cond[c])
                                   for c in needs})


def compensate_true(machine, s, path: ChainPath, truth, field_, method: str = "exact", idx=None) -> dict:
    """Compensate ``path`` (its points ``idx``, None: all) with ``field_`` (None: the program run as written) and
    ``method``; the TRUE residual on ``truth`` at the part's conditions (RMS, max) and, with a field, the
    solver's time per point, its worst model residual and its failures."""
    from ...evaluate import true_residual_um
    from ...solvers import solve
    tg, nom, cond = path.targets_mm(machine), path.axes, path.cond
    if idx is not None:
        tg, nom, cond = tg[idx], nom[idx], {k: v[idx] for k, v in cond.items()}
    r = None
    if field_ is not None:
        opts = {"target_axes": nom, "progress": False}
        if method == "batched-ga":
            opts.update(seed=s.seed, generations=s.ga_generations)
        r = solve(method, with_path_conditions(field_, cond), tg, machine, **opts)
    st = residual_stats(true_residual_um(truth, nom if r is None else r.axes, tg, cond))
    out = {"true_rms_um": st["rms_um"], "true_max_um": st["max_um"]}
    if r is not None:
        out.update(seconds_per_point=r.seconds / len(tg), points=len(tg),
                   model_max_um=float(np.max(r.residual_norm_um)), failures=int(np.count_nonzero(~r.success)))
    return out
