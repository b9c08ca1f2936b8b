"""G-code over a machine-tool chain: :mod:`compensation.gcode` read with the machine's axis words, and the
vertices of every compensated move planned (arcs in chords, moves split so the compensation between vertices
stays within the field's tolerance, :func:`plan_chain_gcode`). The contract: docs/reference/tool-paths.md,
"G-code over a chain"."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from errormap.io import InputError

from .gcode import DEFAULT_RAPIDS, AxisWords, GProgram, arc_segments, move_points, parse_program, render_program
from .gcode_words import cr_line_ends, with_line_end
from .nc_cycles import cycle_pass
from .nc_expand import source_line

MAX_SEGMENTS_PER_MOVE = 100_000
"""A move split or linearised into more pieces than this is refused (a tolerance far too tight)."""
TAP_SAMPLES = 17
"""Points along a ``G33.1`` at which :func:`tap_bend_um` evaluates the field (every 1/16 of the hole; the field's
stations are far apart beside a hole, so its bend between them is resolved)."""
MAX_PATH_POINTS = 10_000_000
"""Vertices of one file at most, checked before any is placed: ``compensate`` holds about 1.2 kB per vertex
from reading to writing (1.18 GB peak for 1,000,000 vertices measured, docs/decisions/020-benchmark-notebook.md
"G-code end to end"), so this bounds a file at about 12 GB."""


def parse_chain_program(path, machine, rapids: str = DEFAULT_RAPIDS, block_delete: str | None = None,
                        dialect: str | None = None, cycles: str | None = None, tables: tuple | None = None,
                        subprograms=None) -> GProgram:
    """Read a G-code file for the machine-tool chain ``machine``: :func:`compensation.gcode.parse_program`
    with its axis words, the rotary words of the axes the exact solver keeps kept as programmed, a
    solved rotary axis (a lathe's C) written like a linear one (module docstring). Moves'
    ``start``/``end`` are in ``machine.axis_columns`` order. ``cycles``: drilling canned cycles refused
    (None), kept or expanded (:mod:`compensation.nc_cycles`). ``tables``: ``(work offsets, tool table)``, as
    :func:`compensation.gcode.parse_program` takes them (a ``G53`` move's end placed in the program's frame)."""
    words = AxisWords.of(machine, keep_rotary=True)
    from .solvers.chain_exact import solved_and_kept
    try:
        solved = {machine.axes[j].word for j in solved_and_kept(machine)[0]}
    except ValueError:  # not solvable (compensate refuses it): every rotary word kept, as read
        solved = set()
    words = dataclasses.replace(words, kept=tuple(w for w in words.kept if w not in solved))
    from .gcode import MAX_PROGRAM_BYTES, _dialect_of, g80_note
    from .tcp import attach, flat_prepass
    data, pre, name, evidence, dia, flat = None, None, None, "", None, None
    if Path(path).is_file() and Path(path).stat().st_size <= MAX_PROGRAM_BYTES:  # TCP and G93 words (compensation.tcp)
        raw, line_end = cr_line_ends(Path(path).read_bytes())
        try:
            dia, evidence = _dialect_of(path, raw, dialect)
            name = dia.name
        except InputError:
            name = None  # the reader refuses it with its own words
        if name is not None:  # a program with calls or parameters: the pre-pass reads its flat program
            flat, data, pre = flat_prepass(path, raw, name, machine, subprograms)
    named = name if pre is not None and name != "rs274" else dialect  # the pre-pass blanked what recognised it
    if dialect == "auto" and name is not None and evidence.startswith("recognised"):
        named = name  # recognised once, above (its evidence kept below); none: auto (dialects.UNRECOGNISED)
    # read once: the pre-pass's bytes (the file's own where it found nothing); nothing recognised above is not looked
    # for again (blanking TCP words cannot add a dialect word)
    try:
        prog = parse_program(path, rapids=rapids, block_delete=block_delete, axis_words=words,
                             dialect=named, cycles=None if cycles is None else partial(cycle_pass, mode=cycles),
                             data=data, found=(dia, evidence) if named == "auto" and dia is not None else None,
                             tables=tables, subprograms=subprograms, flat=flat)
    except InputError as exc:  # the flat program's lines named at the source
        raise (flat.relocate(exc) if flat is not None else exc) from None
    if data is not None:
        prog.line_end = line_end  # the pre-pass's bytes: LF in place of a CR-only file's CR, read above
    if pre is not None:
        attach(prog, pre, flat)
    if pre is not None or (dialect == "auto" and name is not None):
        prog.dialect_evidence = evidence + (f"; {g80_note(prog.g80_line)}" if prog.g80_line else "")
    return prog


CURVATURE_FRACTIONS = (0.25, 0.5, 0.75)
"""Where along a move the field's second difference is taken (its largest counts)."""
CURVATURE_STEP = 0.25
"""Second difference step, as a share of the move."""


def field_pieces(moves, field, tol_um: float, shift=None, place=None, at_least=None) -> np.ndarray:
    """Pieces per move so that the straight interpolation between compensated vertices stays within
    ``tol_um`` of the field along it: an estimate from the field's second differences
    (:func:`curvature_pieces`: a piece of a move whose field has second derivative ``c`` deviates by
    ``c/(8 n²)``), then checked piece by piece and raised where it falls short (:func:`refined_pieces`).
    ``shift`` (m, k): machine minus program axes per move (work offset, tool length; None: zero); ``place``:
    ``(0-based lines (n,), program axes (n, k)) -> machine axes (n, k)`` instead of the shift (a program in TCP
    mode); ``at_least`` (m,): counts the pieces may not go below (an arc's chords). An arc's (or spline's) chords
    are checked with their own deviation from the curve added. Shape (m,) int ≥ 1."""
    if not moves:
        return np.zeros(0, dtype=int)
    f, pick = curvature_parameters()
    E = np.asarray(field.predict(_move_samples(moves, f, shift, place)))
    n = curvature_pieces(E, len(moves), pick, tol_um)
    if at_least is not None:
        n = np.maximum(n, at_least)

    def field_at(rows, owner, u):  # the field and the program axes at parameters u of the moves rows[owner]
        pick_moves = [moves[r] for r in rows]
        q = np.concatenate([move_points(m, u[owner == i]) for i, m in enumerate(pick_moves)])
        if place is not None:
            return field.predict(place(np.repeat([m.index for m in pick_moves], np.bincount(owner)), q)), q
        return field.predict(q if shift is None else q + np.asarray(shift, dtype=float)[rows][owner]), q
    curved = np.array([m.arc is not None for m in moves], dtype=bool)
    return refined_pieces(n, E.reshape(len(moves), len(f), 3), f, tol_um, field_at, curved)


def _move_samples(moves, f, shift, place) -> np.ndarray:
    """Machine axes (m·len(f), k) at parameters ``f`` of every move, placed by ``place`` or ``shift``."""
    q = np.concatenate([move_points(m, f) for m in moves])
    if place is not None:
        return place(np.repeat([m.index for m in moves], len(f)), q)
    return q if shift is None else q + np.repeat(np.asarray(shift, dtype=float), len(f), axis=0)


def curvature_parameters():
    """``(f, pick)``: the distinct parameters (u,) of a move where :func:`field_pieces` samples the field (the
    second differences at :data:`CURVATURE_FRACTIONS` share points: 5 of 9 with the defaults), and the index
    (len(CURVATURE_FRACTIONS), 3) of each difference's three points into ``f``."""
    h = CURVATURE_STEP
    every = np.array([c + d * h for c in CURVATURE_FRACTIONS for d in (-1.0, 0.0, 1.0)])
    f, pick = np.unique(every, return_inverse=True)
    return f, pick.reshape(len(CURVATURE_FRACTIONS), 3)


def curvature_pieces(E, m: int, pick, tol_um: float) -> np.ndarray:
    """Pieces per move (m,) int ≥ 1 from the field ``E`` (m·u, 3) μm at the parameters of
    :func:`curvature_parameters` of m moves: ``n = ⌈√(c/(8 tol))⌉``, ``c`` the largest second difference."""
    E = np.asarray(E).reshape(m, -1, 3)
    c = np.abs(E[:, pick[:, 0]] - 2 * E[:, pick[:, 1]] + E[:, pick[:, 2]]).max(axis=(1, 2)) / CURVATURE_STEP ** 2
    return np.maximum(1, np.ceil(np.sqrt(c / (8.0 * tol_um)))).astype(int)


def refined_pieces(n, E, f, tol_um: float, field_at, curved=None) -> np.ndarray:
    """Equal pieces per move (m,), raised from the estimate ``n`` until every piece passes the check: the field
    at the piece's midpoint differs from the mean of the field at its ends by at most ``tol_um`` (the straight
    interpolation's deviation there; Euclidean, μm), plus, on a ``curved`` (m,) bool move (an arc, a spline), the
    chord's own distance from the curve there (μm, axis space: the two add at worst). ``E`` (m, u, 3): the field at
    the parameters ``f`` (u,) of every move, which decide straight moves of one or two pieces without evaluating
    again; ``field_at(rows (r,), owner (N,), u (N,)) -> ((N, 3) μm, (N, k) mm)``: the field and the program axes at
    parameters ``u`` of the moves ``rows[owner]``. A move over tolerance
    gets ``max(n + 1, ⌈n·√(d/tol)⌉)`` pieces (``d`` its largest deviation; the deviation falls as ``1/n²``) and
    is checked again; past :data:`MAX_SEGMENTS_PER_MOVE` a move, or :data:`MAX_PATH_POINTS` all, the counts are
    left there (the caller refuses them)."""
    n = np.array(n, dtype=int)
    curved = np.zeros(len(n), bool) if curved is None else np.asarray(curved, dtype=bool)
    todo = (n > 2) | curved
    for c in (1, 2):
        want = np.arange(2 * c + 1) / (2 * c)
        at = np.minimum(np.searchsorted(f, want), len(f) - 1)
        sel = np.flatnonzero((n == c) & ~curved)
        if sel.size and np.array_equal(f[at], want):
            e = E[sel][:, at]
            d = np.linalg.norm(e[:, 1::2] - 0.5 * (e[:, 0:-1:2] + e[:, 2::2]), axis=2).max(axis=1)
            n[sel] = _grown(n[sel], d, tol_um)
            todo[sel] = d > tol_um
        else:
            todo[sel] = True
    while todo.any():
        rows = np.flatnonzero(todo)
        if n.max() > MAX_SEGMENTS_PER_MOVE or n.sum() > MAX_PATH_POINTS:
            break  # refused by the caller
        per = 2 * n[rows] + 1
        owner = np.repeat(np.arange(rows.size), per)
        local = np.arange(owner.size) - np.repeat(np.cumsum(per) - per, per)
        e, q = field_at(rows, owner, local / (2.0 * n[rows][owner]))
        e = np.asarray(e)
        mid = np.flatnonzero(local % 2 == 1)
        dev = np.linalg.norm(e[mid] - 0.5 * (e[mid - 1] + e[mid + 1]), axis=1)
        dev += 1e3 * np.linalg.norm(q[mid] - 0.5 * (q[mid - 1] + q[mid + 1]), axis=1) * curved[rows][owner[mid]]
        d = np.zeros(rows.size)
        np.maximum.at(d, owner[mid], dev)
        n[rows] = _grown(n[rows], d, tol_um)
        todo[:] = False
        todo[rows[d > tol_um]] = True
    return n


def _grown(n, d, tol_um: float) -> np.ndarray:
    """Pieces (r,) for moves of ``n`` pieces whose largest midpoint deviation is ``d`` (r,) μm: unchanged within
    ``tol_um``, else ``max(n + 1, ⌈n·√(d/tol)⌉)``."""
    over = d > tol_um
    grown = np.maximum(n + 1, np.ceil(n * np.sqrt(np.where(over, d, tol_um) / tol_um) - 1e-9).astype(int))
    return np.where(over, grown, n)


LENGTH_SAMPLES = 16
"""Intervals of the tool-point polyline that measures a move's length (:func:`length_pieces`)."""


def length_pieces(moves, nominal, max_segment_mm: float, shift=None, place=None) -> np.ndarray:
    """Pieces per move so that none is longer than ``max_segment_mm`` of tool-point path:
    ``⌈L / max_segment_mm⌉``, ``L`` the length of the polyline through :data:`LENGTH_SAMPLES` + 1
    points of the move (a rotary move's tool point sweeps an arc), placed by ``nominal(axes (m, k))
    -> (m, 3) mm`` (the machine's tool point) after ``shift`` (m, k) per move, or ``place`` as in
    :func:`field_pieces` (a program in TCP mode). Shape (m,) int ≥ 1."""
    if not moves:
        return np.zeros(0, dtype=int)
    t = np.linspace(0.0, 1.0, LENGTH_SAMPLES + 1)
    return _polyline_pieces(nominal, _move_samples(moves, t, shift, place), len(moves), max_segment_mm)


def _polyline_pieces(nominal, q, m: int, max_segment_mm: float) -> np.ndarray:
    """``⌈L / max_segment_mm⌉`` (m,) int ≥ 1, ``L`` the length of each move's tool-point polyline through its
    samples ``q`` (m·u, k) placed by ``nominal``."""
    p = np.asarray(nominal(q), dtype=float).reshape(m, -1, 3)
    length = np.linalg.norm(np.diff(p, axis=1), axis=2).sum(axis=1)
    return np.maximum(1, np.ceil(length / float(max_segment_mm) - 1e-9)).astype(int)


def _by_length(max_segment_mm, nominal) -> bool:
    """Whether ``max_segment_mm`` splits by tool-path length (a length in mm; ``"auto"``: by the field;
    None: not at all)."""
    if isinstance(max_segment_mm, str) and max_segment_mm != "auto":
        raise ValueError(f"Expected max_segment_mm 'auto', None or a length in mm, got {max_segment_mm!r}")
    by_length = max_segment_mm is not None and not isinstance(max_segment_mm, str)
    if by_length and not (np.isfinite(max_segment_mm) and max_segment_mm > 0 and nominal is not None):
        raise ValueError("Expected a positive max_segment_mm with the machine's nominal, "
                         f"got {max_segment_mm!r}")
    return by_length


def _check_counts(program, counts, lines0, arc_tolerance_um: float, max_segment_mm) -> None:
    """Refuse, before any vertex is placed, a move of more than :data:`MAX_SEGMENTS_PER_MOVE` pieces or a file of
    more than :data:`MAX_PATH_POINTS` vertices, naming the option that sets them: ``counts`` (c,) pieces of the
    compensated moves, ``lines0`` (c,) their 0-based lines (of the flat program where it was expanded; the refusal
    names the source line, :func:`compensation.nc_expand.source_line`)."""
    counts = np.asarray(counts, dtype=np.int64)
    if not counts.size:
        return
    by_length = max_segment_mm is not None and not isinstance(max_segment_mm, str)
    why = (f"no piece longer than {max_segment_mm:g} mm", "give a larger --max-segment-mm") if by_length else \
        (f"{arc_tolerance_um:g} μm", "raise --arc-tolerance-um")
    k = int(np.argmax(counts))
    if counts[k] > MAX_SEGMENTS_PER_MOVE:
        raise InputError(f"{program.path}: line {source_line(program, int(lines0[k]) + 1)}: the move needs "
                         f"{int(counts[k]):,} pieces for {why[0]} (more than {MAX_SEGMENTS_PER_MOVE:,}); {why[1]}")
    total = int(counts.sum())
    if total > MAX_PATH_POINTS:
        raise InputError(f"{program.path}: the program needs {total:,} vertices for {why[0]}, more than the limit of "
                         f"{MAX_PATH_POINTS:,} points per file; {why[1]} or split the program")


@dataclass
class ChainGCodeJob:
    """A parsed program with the vertices of every compensated move: ``counts`` (c,) vertices per compensated
    move, ``axes`` (n, k) all vertices in order (nominal axes, each move's last row its end) and ``lines``
    (n,) the 1-based source line of each; :attr:`vertices` the per-move views of ``axes``."""

    program: GProgram
    counts: np.ndarray
    axes: np.ndarray
    lines: np.ndarray
    arc_tolerance_um: float
    kept_lines: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    kept_axes: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    frames: object = None
    """:class:`compensation.nc_state.ProgramFrames` the vertices were placed with (None: machine coordinates)."""
    taps: dict = field(default_factory=dict)
    """``{0-based line: μm}`` per LinuxCNC ``G33.1``: the error its one move leaves along the hole
    (:func:`tap_bend_um`)."""

    @property
    def vertices(self) -> list:
        """``vertices[i]`` (m_i, k): the rows of ``axes`` of the i-th compensated move."""
        return np.split(self.axes, np.cumsum(self.counts)[:-1]) if len(self.counts) else []

    @property
    def shift(self) -> np.ndarray:
        """Machine minus program axes per vertex (n, k): the work offset and the tool length on Z."""
        if self.frames is None:
            return np.zeros_like(self.axes)
        if self.frames.rotated:  # a rotated work system: the shift of each vertex (ProgramFrames.place)
            return self.frames.place(self.lines - 1, self.axes, self.program.axis_words.words) - self.axes
        return self.frames.shift(self.lines - 1, self.program.axis_words.words)

    @property
    def tool_mm(self) -> np.ndarray:
        """The active tool length per vertex (n,), NaN: the machine file's own tool."""
        if self.frames is None:
            return np.full(len(self.axes), np.nan)
        return self.frames.at(self.lines - 1)[1]

    @property
    def kept_machine_axes(self) -> np.ndarray:
        """The kept rapids' ends in machine axes (m, k)."""
        if self.frames is None or not len(self.kept_lines):
            return self.kept_axes
        return self.frames.place(self.kept_lines - 1, self.kept_axes, self.program.axis_words.words)


def plan_chain_gcode(program: GProgram, arc_tolerance_um: float, field_=None, frames=None, max_segment_mm="auto",
                     nominal=None, machine=None) -> ChainGCodeJob:
    """Vertices of every compensated move (program coordinates): arcs in chords within
    ``arc_tolerance_um`` (axis space), and every move split as ``max_segment_mm`` says: ``"auto"``
    (with ``field_``) so the compensation between vertices stays within the tolerance too
    (:func:`field_pieces`, the field taken where ``frames`` — a
    :class:`compensation.nc_state.ProgramFrames` — puts the move in the machine); a length in mm: no
    piece longer than that along the tool point's path (:func:`length_pieces` with ``nominal``, the
    machine's tool point of (m, k) program-column axes); None: no splitting. A program in TCP mode is
    placed through ``machine``'s nominal inverse (:mod:`compensation.tcp`). A program read in bulk
    (:class:`compensation.gcode.MoveTable`) is planned column-wise (:func:`plan_table`): the same vertices."""
    by_length = _by_length(max_segment_mm, nominal)
    rotated = frames is not None and frames.rotated
    taps = tap_bend_um(program, field_, frames, arc_tolerance_um, machine)
    if program.table is not None and program.tcp is None and program.expanded is None and not rotated:
        return dataclasses.replace(plan_table(program, arc_tolerance_um, field_, frames, max_segment_mm, nominal),
                                   taps=taps)
    comp = [m for m in program.moves if m.compensate]
    tol_mm = arc_tolerance_um * 1e-3
    n_arc = np.array([arc_segments(m, tol_mm) if m.arc is not None else 1 for m in comp], dtype=int)
    with_start = [m for m in comp if np.all(np.isfinite(m.start))]
    n_fld = np.ones(len(comp), dtype=int)
    if with_start and (by_length or (max_segment_mm == "auto" and field_ is not None)):
        shift, place = _placing(program, with_start, frames, machine)
        pieces = (length_pieces(with_start, nominal, max_segment_mm, shift, place) if by_length
                  else field_pieces(with_start, field_, arc_tolerance_um, shift, place,
                                    at_least=[n_arc[i] for i, m in enumerate(comp) if np.all(np.isfinite(m.start))]))
        pos = {id(m): p for m, p in zip(with_start, pieces)}
        n_fld = np.array([pos.get(id(m), 1) for m in comp], dtype=int)
    counts = np.maximum(n_arc, n_fld)
    counts[[i for i, m in enumerate(comp) if m.synced == "G33.1"]] = 1  # a tap: one line (G32, G33: pieces)
    _check_counts(program, counts, [m.index for m in comp], arc_tolerance_um, max_segment_mm)
    verts = []
    for m, c in zip(comp, counts):
        if not np.all(np.isfinite(m.start)):
            verts.append(m.end[None, :].copy())
        else:
            verts.append(move_points(m, np.arange(1, c + 1) / c))
    axes = np.concatenate(verts) if verts else np.zeros((0, len(program.axis_words.words)))
    lines = np.concatenate([np.full(len(v), m.index + 1) for m, v in zip(comp, verts)]) if verts else np.zeros(0, int)
    kept = [m for m in program.moves if not m.compensate]
    return ChainGCodeJob(program, np.array([len(v) for v in verts], dtype=int), axes, lines, arc_tolerance_um,
                         np.array([m.index + 1 for m in kept], dtype=int),
                         np.array([m.end for m in kept]).reshape(len(kept), len(program.axis_words.words)), frames,
                         taps)


def _placing(program, moves, frames, machine) -> tuple:
    """``(shift, place)`` that put ``moves`` in the machine (:func:`field_pieces`' arguments): the frames' shift
    (m, k) per move (None: none), and ``place`` where the frames rotate or the program is in TCP mode (else None)."""
    words = program.axis_words.words
    shift = frames.shift([m.index for m in moves], words) if frames is not None else None
    place = partial(frames.place, words=words) if frames is not None and frames.rotated else None
    if program.tcp is not None and frames is not None and machine is not None:
        place = partial(program.tcp.place, machine, program, frames, count=False)
    return shift, place


def tap_bend_um(program, field_, frames, tol_um: float, machine=None) -> dict:
    """``{0-based line: μm}`` per compensated LinuxCNC ``G33.1`` (rigid tapping): the largest distance of the field
    along the tap, at :data:`TAP_SAMPLES` points, from the straight line between its values at the start and the
    bottom — the error the one synchronised move (its K' from the compensated ends, :mod:`compensation.nc_thread`)
    leaves along the hole, as a piece of a split move leaves within ``tol_um`` (``--arc-tolerance-um``). Refused
    (InputError) over ``tol_um``: a tap and its return cannot be split. {} without a field."""
    moves = program.table.objects if program.table is not None else program.moves
    taps = [m for m in moves if m.synced == "G33.1" and m.compensate and np.all(np.isfinite(m.start))]
    if not taps or field_ is None:
        return {}
    u = np.linspace(0.0, 1.0, TAP_SAMPLES)
    E = np.asarray(field_.predict(_move_samples(taps, u, *_placing(program, taps, frames, machine))))
    E = E.reshape(len(taps), len(u), 3)
    line = E[:, :1] * (1.0 - u)[None, :, None] + E[:, -1:] * u[None, :, None]
    bend = np.linalg.norm(E - line, axis=2).max(axis=1)
    if (bend > tol_um).any():
        k = int(np.argmax(bend > tol_um))  # the first in line order
        raise InputError(f"{program.path}: line {source_line(program, taps[k].index + 1)}: 'G33.1' (a tap and its "
                         f"return, one K): the field bends {bend[k]:.3g} um along the hole, more than "
                         f"--arc-tolerance-um {tol_um:g}; raise it or tap shorter holes")
    return {m.index: float(b) for m, b in zip(taps, bend)}


def plan_table(program: GProgram, arc_tolerance_um: float, field_=None, frames=None, max_segment_mm="auto",
               nominal=None) -> ChainGCodeJob:
    """:func:`plan_chain_gcode` of a program read in bulk, column-wise over its move table (linear moves as
    arrays; arcs, few, through their move objects): the same pieces per move, the same vertices."""
    t = program.table
    rows = np.flatnonzero(t.compensate)
    k = len(program.axis_words.words)
    start, end = t.start[rows], t.end[rows]
    arc = t.kind[rows] == 2
    moves = {int(i): t.objects[t.obj[rows[i]]] for i in np.flatnonzero(arc)}
    tol_mm = arc_tolerance_um * 1e-3
    counts = np.ones(len(rows), dtype=int)
    for i, m in moves.items():
        counts[i] = arc_segments(m, tol_mm)
    known = np.isfinite(start).all(axis=1)
    by_length = _by_length(max_segment_mm, nominal)
    if known.any() and (by_length or (max_segment_mm == "auto" and field_ is not None)):
        idx = np.flatnonzero(known)
        shift = frames.shift(t.line[rows[idx]], program.axis_words.words) if frames is not None else None
        if by_length:
            f = np.linspace(0.0, 1.0, LENGTH_SAMPLES + 1)
        else:
            f, pick = curvature_parameters()
        arcs = {int(j): moves[i] for i, j in zip(moves, np.searchsorted(idx, list(moves))) if known[i]}
        q = _table_points(start[idx], end[idx], f, arcs)
        if shift is not None:
            shift = np.asarray(shift, dtype=float)
            q = q + np.repeat(shift, len(f), axis=0)
        if by_length:
            counts[idx] = np.maximum(counts[idx], _polyline_pieces(nominal, q, len(idx), max_segment_mm))
        else:
            E = _field_chained(field_, q.reshape(len(idx), len(f), -1))
            n = np.maximum(counts[idx], curvature_pieces(E, len(idx), pick, arc_tolerance_um))
            field_at = partial(_table_field, field_, start[idx], end[idx], arcs, shift)
            curved = np.isin(np.arange(len(idx)), list(arcs))
            counts[idx] = refined_pieces(n, E.reshape(len(idx), len(f), 3), f, arc_tolerance_um, field_at, curved)
    _check_counts(program, np.where(known, counts, 1), t.line[rows], arc_tolerance_um, max_segment_mm)
    counts[~known] = 1  # a move whose start is unknown: its end alone
    objs = np.flatnonzero(t.obj[rows] >= 0)
    counts[[i for i in objs if t.objects[t.obj[rows[i]]].synced == "G33.1"]] = 1
    axes = _table_vertices(start, end, counts, known, moves)
    lines = np.repeat(t.line[rows] + 1, counts)
    kept = np.flatnonzero(~t.compensate)
    return ChainGCodeJob(program, counts, axes, lines, arc_tolerance_um, (t.line[kept] + 1).astype(int),
                         t.end[kept].reshape(len(kept), k), frames)


def _field_chained(field_, q) -> np.ndarray:
    """``field_.predict`` at the points ``q`` (m, u, k) of m moves (parameters 0 … 1), (m·u, 3): a move whose
    first point is bit for bit the previous move's last (a program's moves join) takes that value instead
    of evaluating the field there again."""
    m, u, k = q.shape
    if m < 2 or u < 2:
        return np.asarray(field_.predict(q.reshape(-1, k)))
    bits = np.ascontiguousarray(q).view(np.int64)
    joined = np.zeros(m, bool)
    joined[1:] = (bits[1:, 0] == bits[:-1, -1]).all(axis=1)
    need = np.ones((m, u), bool)
    need[joined, 0] = False
    E = np.empty((m, u, 3))
    E[need] = np.asarray(field_.predict(q[need]))
    E[joined, 0] = E[np.flatnonzero(joined) - 1, -1]  # every last point is evaluated (u ≥ 2)
    return E.reshape(m * u, 3)


def _table_field(field_, start, end, arcs, shift, rows, owner, u) -> np.ndarray:
    """The field (N, 3) and the program axes (N, k) at parameters ``u`` (N,) of the moves ``rows[owner]`` of
    ``start``/``end`` (m, k) (linear; ``arcs`` {row: GMove} along their arc), the field shifted by ``shift`` (m, k)
    (None: zero): :func:`refined_pieces`'s ``field_at`` for a program read in bulk."""
    r = rows[owner]
    q = start[r] + u[:, None] * (end[r] - start[r])
    for j in set(rows.tolist()) & set(arcs):
        at = r == j
        q[at] = move_points(arcs[j], u[at])
    return np.asarray(field_.predict(q if shift is None else q + shift[r])), q


def _table_points(start, end, f, arcs) -> np.ndarray:
    """Points (m·len(f), k) at parameters ``f`` of m moves (linear between ``start`` and ``end``; the moves of
    ``arcs`` {row: GMove} along their arc)."""
    q = (start[:, None, :] + f[None, :, None] * (end - start)[:, None, :]).reshape(-1, start.shape[1])
    for j, m in arcs.items():
        q[j * len(f):(j + 1) * len(f)] = move_points(m, f)
    return q


def _table_vertices(start, end, counts, known, arcs) -> np.ndarray:
    """Every move's vertices at ``(1..c)/c`` of it, in order (n, k): :func:`compensation.gcode.move_points`
    column-wise (a move whose start is unknown: its end)."""
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    owner = np.repeat(np.arange(len(counts)), counts)
    u = (np.arange(int(counts.sum())) - first[owner] + 1.0) / counts[owner]
    axes = start[owner] + u[:, None] * (end - start)[owner]
    whole = (u == 1.0) & (counts[owner] == 1)  # one piece: the end itself (move_points: every parameter 1)
    axes[whole | ~known[owner]] = end[owner][whole | ~known[owner]]
    for i, m in arcs.items():
        c = int(counts[i])
        axes[first[i]:first[i] + c] = move_points(m, np.arange(1, c + 1) / c)
    return axes


# ---------------------------------------------------------------------------- writing
def render_chain_axes(program: GProgram, axes, counts, header=(), held=None) -> str:
    """The program with its compensated vertices ``axes`` (n, k), ``counts`` (c,) of them per compensated
    move; every other line byte for byte, with the file's line end (:func:`compensation.gcode.render_program`; a
    program read in bulk written in bulk, :func:`compensation.gcode.render_table`; kept canned cycles written back
    as cycles, :func:`compensation.nc_cycles.render_kept`; kept lathe grooving cycles likewise,
    :func:`compensation.nc_groove_kept.render_kept`). ``held`` (c, k) bool: the axes each move holds at a ``G53``
    value (:mod:`compensation.held_axes`)."""
    t = program.table
    from .gcode import _bulk_words, render_table
    if any(e[2] == "lathe-groove" for e in program.events):  # kept G74/G75: their cycle lines rewritten
        from .nc_groove_kept import render_kept as render_grooves
        vertices = np.split(np.asarray(axes), np.cumsum(counts)[:-1]) if len(counts) else []
        text = render_grooves(program, vertices, header=header, held=held)
    elif (program.tcp is None and t is not None and not t.incremental.any() and program.expanded is None
            and _bulk_words(program.axis_words) and held is None):  # read in bulk: written in bulk, the same text
        text = render_table(program, np.asarray(axes), list(counts), header=header)[0]
    else:
        vertices = np.split(np.asarray(axes), np.cumsum(counts)[:-1]) if len(counts) else []
        if program.tcp is not None:
            from .tcp import render_tcp
            text = render_tcp(program, vertices, header=header)
        elif getattr(program.expanded, "mode", None) == "keep":
            from .nc_cycles import render_kept
            text = render_kept(program, vertices, header=header)
        else:
            text = render_program(program, vertices, header=header, held=held)[0]
    return with_line_end(text, program.line_end)
