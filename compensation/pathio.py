"""Tool-path helpers: the CSV sniffer and renderer, the option ranges, the move-extent check, and a G-code
reader/planner (:func:`read_path`, :func:`plan_gcode`: a global ``auto`` segment length from the field's
curvature) kept for the tool-path benchmark; ``volcomp compensate`` reads through
:func:`compensation.app.workflows.compensate_paths.read_tool_path` (formats: docs/reference/tool-paths.md)."""
from __future__ import annotations

import csv
import io
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import InputError, atomic_write, not_a_file
from errormap.chain_kernel import forward

from .gcode_kernels import linear_path_lengths_mm
from .gcode_spline import spline_extent_mm
from .gcode import (AxisWords, GProgram, arc_segments, fmt as _fmt, move_points, parse_program, render_program,
                    render_table)

TARGET_COLUMNS = ("px_mm", "py_mm", "pz_mm")
DECIMALS_MM = 6   # 1 nm
DECIMALS_DEG = 6  # 1e-6 deg: 1 nm at 57 mm from the A axis

@dataclass
class ToolPathFile:
    """A grinder tool path read from a file (CSV or G-code), with the file line of each point.

    kind : ``"csv-axes"``, ``"csv-targets"`` or ``"gcode"``
    axes : shape (n, 3)         nominal axis commands (x_mm, z_mm, a_deg)
    targets_mm : shape (n, 3)   the WCS targets the program means
    lines : shape (n,)          file line (1-based) of each point
    """

    path: Path
    kind: str
    axes: np.ndarray
    targets_mm: np.ndarray
    lines: np.ndarray
    source: object = field(default=None, repr=False)

    def __len__(self) -> int:
        return self.axes.shape[0]


# ----------------------------------------------------------------------------- G-code

DEFAULT_ARC_TOLERANCE_UM = 0.5
"""Chord tolerance of linearised arcs and split moves (μm; ``compensate --arc-tolerance-um``).
``compensate`` (:func:`compensation.chain_gcode.plan_chain_gcode`) gives each bound the whole of it:
the chord sagitta of a nominal arc (:func:`compensation.gcode_classify.arc_segments`) and, with
``--max-segment-mm auto``, the straight interpolation of the compensation between a move's vertices
(:func:`compensation.chain_gcode.field_pieces`, from the field's second differences at a quarter, half
and three quarters of the move). The error left between vertices is measured, not bounded: the summary's
``true_path`` (with ``--truth``; docs/reference/tool-paths.md, "Vertices")."""
ARC_TOLERANCE_RANGE_UM = (0.001, 5.0)
"""Accepted chord tolerances (μm; ``compensate --arc-tolerance-um``). Below 1 nm the program
cannot state the difference (it is written with :data:`DECIMALS_MM` = 6 decimals, 1 nm) and an
arc's chords multiply for nothing (their count grows as ``1/sqrt(tolerance)``). Above 5 μm the
chords' sagitta (up to the whole tolerance) is larger than what compensation leaves
(1-3 μm true RMS in docs/decisions/020-benchmark-notebook.md), so the flattening would undo the compensation: 1e9 μm
wrote a G2 arc as one G1 chord."""
SEGMENT_RANGE_MM = (0.01, 100.0)
"""Accepted ``--max-segment-mm`` lengths: the range the ``auto`` rule chooses from
(:data:`SEGMENT_LIMITS_MM`). Below 0.01 mm a metre of path is 1e5 vertices per metre, finer than
any field varies (calibration grids of millimetres); above 100 mm the bound binds no move of a
machine's working volume that 'none' (no splitting, said explicitly) would not leave alone."""
AUTO_SAMPLE_MM = 0.25      # spacing of the field samples that estimate its curvature along a move
AUTO_MAX_SAMPLES = 64      # samples per move at most (long moves: coarser spacing)
AUTO_SHORT_WINDOW_MM = 1.0  # of a run of moves shorter than AUTO_SAMPLE_MM, one sampled per this much path
SEGMENT_LIMITS_MM = SEGMENT_RANGE_MM  # the auto segment length is clipped into this range
MAX_VERTICES_PER_MOVE = 1_000_000
"""A move cut into more vertices is refused before any is placed: at the smallest ``auto``
segment (0.01 mm) that is a 10 m move, far beyond any stroke, so only a unit typo or an
absurd ``--max-segment-mm`` gets there."""
MAX_PATH_POINTS = 10_000_000
"""Vertices of one file at most, checked before any is placed: ``compensate`` holds about
1.2 kB per vertex from reading to writing (1.18 GB peak for 1,000,000 vertices measured,
docs/decisions/020-benchmark-notebook.md "G-code end to end"), so this bounds a file at about 12 GB."""


@dataclass
class GCodeJob:
    """A G-code program and where its compensated vertices lie.

    ``params[k]``: parameters in (0, 1] (the last 1.0) of the vertices of the k-th
    compensated move; ``max_segment_mm`` the segment length used (None: no splitting);
    ``kept_axes`` (m, 3) the nominal ends of the moves written as they are (kept rapids;
    NaN where an axis is not yet known) and ``kept_lines`` their 1-based lines.
    """

    program: GProgram
    params: list
    arc_tolerance_um: float
    max_segment_mm: float | None
    kept_axes: np.ndarray
    kept_lines: np.ndarray
    curvature_um_per_mm2: float | None = None
    counts: np.ndarray | None = None
    """(number of compensated moves,) vertices per move (block-wise programs; ``params`` then
    builds each move's parameters from it when asked)."""

    @property
    def compensated_moves(self) -> list:
        return [m for m in self.program.moves if m.compensate]


class _Params(Sequence):
    """``GCodeJob.params`` from vertex counts: ``k`` vertices at ``1/k, 2/k, ..., 1``."""

    def __init__(self, counts):
        self.counts = counts

    def __len__(self) -> int:
        return len(self.counts)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        k = int(self.counts[range(len(self))[i]])
        return np.arange(1, k + 1, dtype=float) / k


def _sample_moves(moves, counts):
    """Nominal axes at ``counts[k] + 1`` equally spaced parameters along each move, stacked
    (sum(counts + 1), 3), and the move index of each row. Linear moves in one vectorised pass."""
    counts = np.asarray(counts, dtype=int)
    owner = np.repeat(np.arange(len(moves)), counts + 1)
    first = np.concatenate([[0], np.cumsum(counts + 1)[:-1]]) if len(moves) else np.zeros(0, int)
    t = (np.arange(owner.size) - first[owner]) / np.maximum(counts[owner], 1)
    start = np.array([m.start for m in moves]).reshape(-1, 3)
    end = np.array([m.end for m in moves]).reshape(-1, 3)
    pts = start[owner] + t[:, None] * (end - start)[owner]
    for k, m in enumerate(moves):
        if m.arc is not None:
            pts[first[k]:first[k] + counts[k] + 1] = move_points(m, t[first[k]:first[k] + counts[k] + 1])
    return pts, owner


def _path_lengths_mm(machine, moves, samples: int = 16) -> np.ndarray:
    """WCS length of each move's nominal tool path (polyline of ``samples + 1`` points), (n,):
    linear moves through :func:`compensation.gcode_kernels.linear_path_lengths_mm`, arcs
    through :func:`move_points` and :func:`forward`."""
    if not moves:
        return np.zeros(0)
    start = np.array([m.start for m in moves]).reshape(-1, 3)
    end = np.array([m.end for m in moves]).reshape(-1, 3)
    out = linear_path_lengths_mm(machine, start, end, samples)
    arcs = [k for k, m in enumerate(moves) if m.arc is not None]
    if arcs:
        pts, owner = _sample_moves([moves[k] for k in arcs], np.full(len(arcs), samples))
        seg = np.linalg.norm(np.diff(forward(machine, pts), axis=0), axis=1)
        seg[owner[1:] != owner[:-1]] = 0.0
        out[arcs] = np.bincount(owner[1:], weights=seg, minlength=len(arcs))
    return out


def _long_moves(program):
    """Compensated moves that may be split (not rapids, start known)."""
    return [m for m in program.moves if m.compensate and m.kind != "rapid" and m.start_known]


def _curvature_sampled(length_mm) -> np.ndarray:
    """Which of the moves (lengths (n,), in program order) :func:`field_curvature_um_per_mm2`
    samples: every move of at least :data:`AUTO_SAMPLE_MM`, and of each run of shorter moves
    the first move starting in each :data:`AUTO_SHORT_WINDOW_MM` of the run's path; (n,) bool."""
    length = np.asarray(length_mm, dtype=float)
    short = length < AUTO_SAMPLE_MM
    window = np.floor((np.cumsum(length) - length) / AUTO_SHORT_WINDOW_MM)
    first = np.ones(length.size, bool)
    first[1:] = (window[1:] != window[:-1]) | ~short[:-1]
    return ~short | first


def field_curvature_um_per_mm2(program: GProgram, machine, field) -> float:
    """Largest ``|d²E/ds²|`` (μm per mm² of WCS path) of the field along the program's moves.

    Second differences of ``E`` sampled every :data:`AUTO_SAMPLE_MM` (at least two intervals,
    at most :data:`AUTO_MAX_SAMPLES` samples a move) along each compensated linear move and
    arc. Of a run of moves shorter than :data:`AUTO_SAMPLE_MM` (CAM output of a fine curve:
    thousands in a row), one move per :data:`AUTO_SHORT_WINDOW_MM` of path is sampled
    (:func:`_curvature_sampled`): the field varies on the scale of its calibration grid, many
    millimetres, so neighbouring short moves see the same curvature, and sampling each would
    cost three field evaluations a line.
    """
    from .solvers._common import field_error_um
    if program.table is not None:
        rows = _long_rows(program.table)
        length = _table_lengths_mm(machine, program.table)[rows]
        rows, length = rows[length > 0.0], length[length > 0.0]
        keep = _curvature_sampled(length)
        rows, length = rows[keep], length[keep]
        if not rows.size:
            return 0.0
        n = np.clip(np.ceil(length / AUTO_SAMPLE_MM), 2, AUTO_MAX_SAMPLES).astype(int)
        pts, owner = _sample_rows(program.table, rows, n)
    else:
        moves = _long_moves(program)
        length = _path_lengths_mm(machine, moves)
        keep = length > 0.0
        moves, length = [m for m, k in zip(moves, keep) if k], length[keep]
        keep = _curvature_sampled(length)
        moves, length = [m for m, k in zip(moves, keep) if k], length[keep]
        if not moves:
            return 0.0
        n = np.clip(np.ceil(length / AUTO_SAMPLE_MM), 2, AUTO_MAX_SAMPLES).astype(int)
        pts, owner = _sample_moves(moves, n)
    e = field_error_um(field, pts, machine)
    d2 = np.linalg.norm(e[:-2] - 2 * e[1:-1] + e[2:], axis=1)
    same = (owner[:-2] == owner[1:-1]) & (owner[1:-1] == owner[2:])
    h = (length / n)[owner[1:-1]]
    return float(np.max(np.where(same, d2 / (h * h), 0.0)))


def auto_segment_mm(kappa_um_per_mm2: float, tolerance_um: float) -> float:
    """Segment length whose chord error ``κ·L²/8`` is ``tolerance_um``, clipped to
    :data:`SEGMENT_LIMITS_MM`."""
    lo, hi = SEGMENT_LIMITS_MM
    if kappa_um_per_mm2 <= 0.0:
        return hi
    return float(np.clip(np.sqrt(8.0 * tolerance_um / kappa_um_per_mm2), lo, hi))


def plan_gcode(program: GProgram, machine, arc_tolerance_um: float = DEFAULT_ARC_TOLERANCE_UM,
               max_segment_mm=None, field=None) -> GCodeJob:
    """Place the vertices of every compensated move.

    Rapids: their end only. Linear moves: ``ceil(L / max_segment_mm)`` equal steps (``L`` the
    WCS length; one step when ``max_segment_mm`` is None or the start is unknown). Arcs:
    enough chords for a sagitta within half of ``arc_tolerance_um``, and no chord longer than
    ``max_segment_mm``. ``max_segment_mm="auto"`` (needs ``field``) is
    :func:`auto_segment_mm` of :func:`field_curvature_um_per_mm2` with half the tolerance.
    """
    if not (np.isfinite(arc_tolerance_um) and arc_tolerance_um > 0):
        raise ValueError(f"Expected a positive arc tolerance in μm, got {arc_tolerance_um!r}")
    check_move_extent(program, machine)
    kappa = None
    if isinstance(max_segment_mm, str):
        if max_segment_mm != "auto":
            raise ValueError(f"Expected max_segment_mm a number, None or 'auto', got {max_segment_mm!r}")
        if field is None:
            raise ValueError("max_segment_mm='auto' needs the error field")
        kappa = field_curvature_um_per_mm2(program, machine, field)
        max_segment_mm = auto_segment_mm(kappa, arc_tolerance_um / 2.0)
    elif max_segment_mm is not None and not (np.isfinite(max_segment_mm) and max_segment_mm > 0):
        raise ValueError(f"Expected a positive max_segment_mm, got {max_segment_mm!r}")
    tol_geo_mm = 0.5 * arc_tolerance_um * 1e-3
    if program.table is not None:
        return _plan_table(program, machine, float(arc_tolerance_um), max_segment_mm, kappa, tol_geo_mm)
    lengths = {}
    if max_segment_mm is not None:
        long_moves = _long_moves(program)
        lengths = dict(zip((m.index for m in long_moves), _path_lengths_mm(machine, long_moves)))
    params, kept, kept_lines = [], [], []
    for m in program.moves:
        if not m.compensate:
            kept.append(m.end)
            kept_lines.append(m.index + 1)
            continue
        k = 1
        if m.arc is not None:
            k = arc_segments(m, tol_geo_mm)
        if m.index in lengths:
            k = max(k, int(min(np.ceil(lengths[m.index] / max_segment_mm - 1e-9), 2.0 ** 62)))
        params.append(k)
    _check_vertex_counts(program, np.array(params, dtype=np.int64),
                         [m.index for m in program.moves if m.compensate], max_segment_mm)
    params = [np.arange(1, k + 1, dtype=float) / k for k in params]
    return GCodeJob(program, params, float(arc_tolerance_um), max_segment_mm,
                    np.array(kept, dtype=float).reshape(-1, 3), np.array(kept_lines, dtype=int), kappa)


def stroke_diagonal_mm(machine, cols=(0, 1)) -> float:
    """Length of the diagonal of the machine's strokes of the axes ``cols`` (mm; the grinder's X and Z by
    default): no move between two points inside the strokes is longer."""
    cols = list(cols)
    return float(np.linalg.norm(machine.stroke_hi[cols] - machine.stroke_lo[cols]))


def _move_extent_mm(start, end, arcs) -> np.ndarray:
    """Largest distance (mm) between two points of each move over the columns of ``start``/``end`` (n, c),
    (n,): the chord of a linear move (0 where its start is unknown: the end's distance outside the strokes
    is checked instead), and for an arc (``arcs``: {row: geometry}) also ``2r·sin(min(|sweep|, π)/2)`` (its
    widest chord)."""
    ext = np.linalg.norm(end - start, axis=1)
    ext[~np.isfinite(ext)] = 0.0
    for k, g in arcs.items():
        if "ctrl" in g:  # a spline: no chord is longer than its control points' widest distance
            ext[k] = max(ext[k], spline_extent_mm(g))
            continue
        r = max(g["r0"], g["r1"])
        ext[k] = max(ext[k], 2.0 * r * np.sin(min(abs(g["sweep"]), np.pi) / 2.0))
    return ext


def check_move_extent(program: GProgram, machine, cols=(0, 1), ends: bool = True) -> None:
    """Refuse a move longer (over the linear axes ``cols``: the grinder's X and Z by default) than the
    machine's stroke diagonal of those axes, or one ending farther than the diagonal outside the strokes: a
    likely unit typo (a number without its decimal point, μm or inch for mm), caught before any vertex is
    placed. One :class:`InputError` naming the file, line, column and word, the line's units and the
    stroke diagonal. ``ends=False``: the moves' lengths only (a program placed by work offsets: its
    coordinates are not the machine's)."""
    cols = list(cols)
    diag = stroke_diagonal_mm(machine, cols)
    lo, hi = machine.stroke_lo[cols], machine.stroke_hi[cols]
    t = program.table
    if t is not None:
        start, end = t.start[:, cols], t.end[:, cols]
        arcs = {k: t.objects[t.obj[k]].arc for k in np.flatnonzero(t.kind == 2).tolist()}
    else:
        moves = program.moves
        start = np.array([m.start for m in moves], dtype=float).reshape(len(moves), -1)[:, cols]
        end = np.array([m.end for m in moves], dtype=float).reshape(len(moves), -1)[:, cols]
        arcs = {k: m.arc for k, m in enumerate(moves) if m.arc is not None}
    ext = _move_extent_mm(start, end, arcs)
    outside = (np.clip(lo - end, 0.0, None) + np.clip(end - hi, 0.0, None)).max(axis=1, initial=0.0) \
        if end.size and ends else np.zeros(len(ext))
    outside = np.where(np.isfinite(outside), outside, 0.0)
    bad = np.flatnonzero((ext > diag) | (outside > diag))
    if not bad.size:
        return
    k = int(bad[0])
    m = program.moves[k]
    names = [program.axis_words.words[j] for j in cols] if program.axis_words is not None else ["X", "Z"]
    words = [m.words[a] for a in (*names, "I", "J", "K", "R") if a in m.words] or list(m.words.values())
    w = max(words, key=lambda w: abs(w.value))  # a move has axis words
    unit = "inch (G20)" if m.units == "inch" else "mm (G21 or no unit code)"
    axes = "/".join(names)
    what = (f"a move of {ext[k]:.6g} mm" if ext[k] > diag else
            f"an end {outside[k]:.6g} mm outside the {axes} strokes")
    raise InputError(f"{program.path}: line {m.index + 1}, column {w.start + 1}: '{w.letter}{w.text}': {what}, "
                     f"more than the machine's {axes} stroke diagonal {diag:.6g} mm; likely a unit typo (the line "
                     f"is read in {unit}): a number without its decimal point, or μm or inch where mm was meant")


def _check_vertex_counts(program: GProgram, counts, lines, max_segment_mm) -> None:
    """Refuse before allocation a move cut into more than :data:`MAX_VERTICES_PER_MOVE`
    vertices or a file of more than :data:`MAX_PATH_POINTS`; ``counts`` (k,) vertices of the
    compensated moves, ``lines`` (k,) their 0-based lines."""
    counts = np.asarray(counts, dtype=np.int64)
    if not counts.size:
        return
    seg = f"--max-segment-mm {max_segment_mm:.6g}" if max_segment_mm is not None else "no splitting"
    k = int(np.argmax(counts))
    if counts[k] > MAX_VERTICES_PER_MOVE:
        raise InputError(f"{program.path}: line {int(lines[k]) + 1}: the move would be cut into {int(counts[k]):,} "
                         f"vertices ({seg}), more than the limit of {MAX_VERTICES_PER_MOVE:,} per move; "
                         "give a larger --max-segment-mm")
    total = float(counts.sum(dtype=float))
    if total > MAX_PATH_POINTS:
        raise InputError(f"{program.path}: the program would be cut into {total:,.0f} vertices ({seg}), more than "
                         f"the limit of {MAX_PATH_POINTS:,} points per file; give a larger --max-segment-mm "
                         "or split the program")


def gcode_toolpath(job: GCodeJob, machine, path) -> "ToolPathFile":
    """The :class:`ToolPathFile` of a planned G-code job: one row per vertex."""
    if job.counts is not None:
        axes, lines = _table_vertices(job)
        return ToolPathFile(Path(path), "gcode", axes, forward(machine, axes), lines, job)
    moves = job.compensated_moves
    axes = np.concatenate([move_points(m, t) for m, t in zip(moves, job.params)], axis=0)
    lines = np.concatenate([np.full(len(t), m.index + 1, dtype=int) for m, t in zip(moves, job.params)])
    return ToolPathFile(Path(path), "gcode", axes, forward(machine, axes), lines, job)


def render_gcode(job: GCodeJob, axes, header=()) -> tuple[str, list]:
    """Text of the compensated program and its line groups (:func:`compensation.gcode.render_program`).

    ``axes`` (n, 3): the compensated vertices in the order of :func:`gcode_toolpath`.
    """
    axes = np.asarray(axes, dtype=float)
    counts = job.counts.tolist() if job.counts is not None else [len(t) for t in job.params]
    if axes.shape != (sum(counts), 3):
        raise ValueError(f"Expected axes of shape ({sum(counts)}, 3), got {axes.shape}")
    if not np.all(np.isfinite(axes)):
        raise ValueError("Expected finite axis commands, got NaN or inf")
    if job.counts is not None and not job.program.table.incremental.any():
        return render_table(job.program, axes, job.counts, header=header)
    return render_program(job.program, np.split(axes, np.cumsum(counts)[:-1]), header=header)


# ------------------------------------------------------------- block-wise programs ----------

TABLE_CHUNK = 65_536
"""Moves per block when sampling paths of block-wise programs (bounds memory: 17 samples a move)."""


def _long_rows(table) -> np.ndarray:
    """Table rows of the compensated moves that may be split (not rapids, start known)."""
    return np.flatnonzero(table.compensate & (table.kind != 0) & np.isfinite(table.start).all(axis=1))


def _sample_rows(table, rows, counts):
    """:func:`_sample_moves` for table rows (same points, same order)."""
    counts = np.asarray(counts, dtype=int)
    owner = np.repeat(np.arange(rows.size), counts + 1)
    first = np.concatenate([[0], np.cumsum(counts + 1)[:-1]]) if rows.size else np.zeros(0, int)
    t = (np.arange(owner.size) - first[owner]) / np.maximum(counts[owner], 1)
    start, end = table.start[rows], table.end[rows]
    pts = start[owner] + t[:, None] * (end - start)[owner]
    for k in np.flatnonzero(table.kind[rows] == 2).tolist():
        sl = slice(first[k], first[k] + counts[k] + 1)
        pts[sl] = move_points(table.objects[table.obj[rows[k]]], t[sl])
    return pts, owner


def _table_lengths_mm(machine, table, samples: int = 16) -> np.ndarray:
    """:func:`_path_lengths_mm` of every long move of a table (NaN for the other rows);
    computed once per machine and kept in the table."""
    hit = table.cache.get("lengths_mm")
    if hit is not None and hit[0] is machine and hit[1] == samples:
        return hit[2]
    rows = _long_rows(table)
    out = np.full(len(table), np.nan)
    out[rows] = linear_path_lengths_mm(machine, table.start[rows], table.end[rows], samples)
    arcs = rows[table.kind[rows] == 2]
    for b in range(0, arcs.size, TABLE_CHUNK):
        r = arcs[b:b + TABLE_CHUNK]
        pts, owner = _sample_rows(table, r, np.full(r.size, samples))
        seg = np.linalg.norm(np.diff(forward(machine, pts), axis=0), axis=1)
        seg[owner[1:] != owner[:-1]] = 0.0
        out[r] = np.bincount(owner[1:], weights=seg, minlength=r.size)
    table.cache["lengths_mm"] = (machine, samples, out)
    return out


def _plan_table(program, machine, arc_tolerance_um, max_segment_mm, kappa, tol_geo_mm) -> GCodeJob:
    """:func:`plan_gcode` of a block-wise program, vectorised (same vertices)."""
    t = program.table
    comp = t.compensate
    counts = np.ones(len(t), dtype=np.int64)
    for k in np.flatnonzero(comp & (t.kind == 2)).tolist():
        counts[k] = arc_segments(t.objects[t.obj[k]], tol_geo_mm)
    if max_segment_mm is not None:
        rows = _long_rows(t)
        split = np.minimum(np.ceil(_table_lengths_mm(machine, t)[rows] / max_segment_mm - 1e-9), 2.0 ** 62)
        counts[rows] = np.maximum(counts[rows], split.astype(np.int64))
    _check_vertex_counts(program, counts[comp], t.line[comp], max_segment_mm)
    kept = ~comp
    return GCodeJob(program, _Params(counts[comp]), arc_tolerance_um, max_segment_mm,
                    t.end[kept].reshape(-1, 3), (t.line[kept] + 1).astype(int), kappa, counts=counts[comp])


def _table_vertices(job: GCodeJob):
    """Vertices (n, 3) of a block-wise job (as :func:`move_points` places them) and their lines."""
    t = job.program.table
    rows = np.flatnonzero(t.compensate)
    counts = job.counts
    lines = np.repeat(t.line[rows] + 1, counts).astype(int)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]) if rows.size else np.zeros(0, int)
    axes = np.repeat(t.end[rows], counts, axis=0)  # one vertex: the end itself (the start may be unknown)
    if not np.all(counts == 1):
        owner = np.repeat(np.arange(rows.size), counts)
        multi = np.flatnonzero(counts[owner] > 1)  # vertices of moves cut into several
        o = owner[multi]
        tt = (multi - first[o] + 1).astype(float) / counts[o]
        start, end = t.start[rows[o]], t.end[rows[o]]
        axes[multi] = start + tt[:, None] * (end - start)
    for k in np.flatnonzero(t.kind[rows] == 2).tolist():
        sl = slice(first[k], first[k] + counts[k])
        axes[sl] = move_points(t.objects[t.obj[rows[k]]], (np.arange(counts[k]) + 1.0) / counts[k])
    return axes, lines


# ----------------------------------------------------------------------------- CSV

def _render_csv(table, replace: dict) -> str:
    """The CSV ``table`` with the columns of ``replace`` (name -> (values, decimals)) rewritten: a plain CSV,
    header first (its provenance goes to the sidecar: :func:`compensated_sidecar`)."""
    buf = io.StringIO(newline="")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(table.names)
    cols = {k: i for i, k in enumerate(table.names)}
    for k, row in enumerate(table.rows):
        row = list(row)
        for name, (values, decimals) in replace.items():
            row[cols[name]] = _fmt(values[k], decimals)
        w.writerow(row)
    return buf.getvalue()


# ----------------------------------------------------------------------------- API

SNIFF_BYTES = 1 << 16
"""How much of a tool-path file is read to tell a CSV from G-code (the header is on its first lines)."""


def is_csv(path) -> bool:
    """Whether the tool-path file ``path`` is a CSV path, by its content, whatever its name: its first
    line that is neither blank nor a ``#`` comment is a CSV header naming the axis columns
    (``x_mm, z_mm, a_deg``) or the target columns (``px_mm, py_mm, pz_mm``) — a row of column names,
    at least two, one with a ``_`` (no G-code word has one). Anything else is read as
    G-code (whose parser refuses what it does not understand, naming the line)."""
    with open(path, "rb") as fh:
        head = fh.read(SNIFF_BYTES)
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    for line in text.replace("\r", "\n").split("\n"):
        if not line.strip() or line.startswith("#"):
            continue
        cells = [c.strip().strip('"') for c in line.split(",")]
        # a header row of column names (G-code words have no '_'; the CSV reader then names what is missing)
        return len(cells) >= 2 and all(_COLUMN_NAME.match(c) for c in cells) and any("_" in c for c in cells)
    return False


_COLUMN_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def read_path(path, machine, *, rapids: str = "keep", block_delete=None,
              arc_tolerance_um: float = DEFAULT_ARC_TOLERANCE_UM, max_segment_mm=None, field=None,
              work_offsets=None, dialect: str | None = None) -> ToolPathFile:
    """Read a G-code program for ``machine`` (CSV paths: ``compensate_paths.read_tool_path``).

    Options: ``rapids``, ``block_delete``, ``dialect`` (:func:`compensation.gcode.parse_program`),
    ``arc_tolerance_um``, ``max_segment_mm``, ``field`` (:func:`plan_gcode`), ``work_offsets`` (:func:`grinder_frames`).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(not_a_file(path))
    prog = parse_program(path, rapids=rapids, block_delete=block_delete, axis_words=AxisWords.of(machine),
                         dialect=dialect)
    grinder_frames(prog, work_offsets)
    job = plan_gcode(prog, machine, arc_tolerance_um, max_segment_mm, field)
    return gcode_toolpath(job, machine, path)


def grinder_frames(prog, work_offsets=None) -> None:
    """The grinder's path applies no work offset and no tool length: a program is read only with
    ``work_offsets`` :data:`compensation.nc_state.MACHINE` (its axes are machine axes, every offset
    zero; without it the first move is refused: a controller never runs a program at an assumed
    machine zero); one that selects a tool length offset or sets tables (``G10``)
    is refused naming the word and line (machine-tool chains apply them, :mod:`compensation.nc_state`)."""
    from .nc_state import program_frames, refuse_unknown_frames
    if work_offsets is not None and not work_offsets.machine_coordinates:
        raise ValueError("Expected work_offsets None or 'machine' on the grinder")
    for line, col, kind, value, text in prog.events:
        if kind.startswith("g10") or (kind in ("tool", "cutter") and value is not None):
            raise InputError(f"{prog.path}: line {line + 1}, column {col}: '{text}': the grinder applies no work offset "
                             "tool length or cutter radius (machine-tool chains do: --machine mill-xyz ... with "
                             "--work-offsets / --tool-table); remove it or post the program in machine coordinates")
    # without 'machine' a work-system selection, and then any move, is refused (no assumed zero)
    refuse_unknown_frames(prog, program_frames(prog, work_offsets, None), work_offsets, tables=False)


def replan(toolpath: ToolPathFile, machine, **options) -> ToolPathFile:
    """A G-code tool path with its vertices placed again (:func:`plan_gcode` options,
    e.g. ``max_segment_mm="auto", field=...``)."""
    job = toolpath.source
    opts = {"arc_tolerance_um": job.arc_tolerance_um, "max_segment_mm": job.max_segment_mm, **options}
    return gcode_toolpath(plan_gcode(job.program, machine, **opts), machine, toolpath.path)


def align_turns(a_deg, a_ref_deg) -> np.ndarray:
    """Shift each A by whole turns so it lies within ±180° of ``a_ref_deg`` (same shape)."""
    a = np.asarray(a_deg, dtype=float)
    ref = np.asarray(a_ref_deg, dtype=float)
    return a - 360.0 * np.round((a - ref) / 360.0)


def compensated_sidecar(table, out_path, comments=()) -> str:
    """The provenance sidecar's text (:func:`errormap.io.sidecar_json`) of the compensated CSV ``out_path``
    rendered from the input CSV ``table``: the input's provenance lines, then ``comments``."""
    from errormap.io import sidecar_json
    return sidecar_json(out_path, table.names, len(table), [*table.comments, *comments])


def write_axes_gcode(path, axes, feed_mm_min: float = 200.0, header=()) -> Path:
    """Write axis commands as a plain G-code program (G21 G90, one ``G1 X Z A`` per point), atomically."""
    axes = np.asarray(axes, dtype=float)
    out = [f"({h})\n" for h in header] + ["G21 G90\n"]
    for k, (x, z, a) in enumerate(axes):
        feed = f" F{feed_mm_min:g}" if k == 0 else ""
        out.append(f"N{10 * (k + 1)} G1 X{_fmt(x, DECIMALS_MM)} Z{_fmt(z, DECIMALS_MM)} A{_fmt(a, DECIMALS_DEG)}{feed}\n")
    out.append("M30\n")
    with atomic_write(path, "w", encoding="latin-1", newline="") as fh:
        fh.write("".join(out))
    return Path(path)
