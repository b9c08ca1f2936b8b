"""G-code reading and rewriting with an explicit allow-list (RS274/NGC semantics).

Every line is put in one class by :func:`classify_line` (``pass``, ``state``, ``move``, ``skipped``): moves
compensated, every other line written back byte for byte; anything else that can move or reinterpret an axis
is refused naming file, line, column and word. The contract, the number syntax, the
machine's axis words and arc planes: docs/reference/tool-paths.md ("Files", "G-code over a chain"); the tables
:data:`ALLOWED_G`, :data:`REFUSED_G`, :data:`ALLOWED_M` and :data:`LETTER_RULES`.

Moves are kept as :class:`GMove` records (absolute mm / deg in the machine's axis order), so a caller places
vertices along them (:func:`move_points`) and :func:`render_program` writes them back in the program's own
distance mode and units. Long programs of a machine with three axis words go through a block-wise reader and
writer (:func:`_parse_blockwise`, :func:`render_table`; same result, in bulk).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.io import InputError, not_a_file

from . import gcode_kernels as gscan
from .gcode_classify import _classify, _State
from .gcode_state import MM_PER_INCH, _Refuse
from .nc_state import ToolTable, WorkOffsets, _Controller
from .gcode_table import _BULK_PASS, MoveTable, _bulk_move, _forward_fill, _LazyMoves, _Lines, _piece_from_move
from .gcode_words import (AxisWords, BLOCK_DELETE_CHOICES, DEFAULT_RAPIDS, GProgram, RAPIDS_CHOICES, _err,
                          check_program_bytes, cr_line_ends, default_axis_words, g80_note, split_lines)
# the reader's other public names, importable from here (callers and docs name compensation.gcode.X):
from .gcode_classify import arc_segments, classify_line, move_points, plane_arc  # noqa: F401
from .gcode_words import (ALLOWED_G, ALLOWED_M, ARC_RADIUS_TOL_INCH_MM, ARC_RADIUS_TOL_MM,  # noqa: F401
                          AXIS_LETTERS, DECIMALS, LETTER_RULES, REFUSED_G, GMove, Word, _PLAIN_LINE, tokenize)
from .gcode_write import _comment_safe, _fixed_str, _with_header, fmt, render_program, render_table  # noqa: F401

MAX_PROGRAM_BYTES = 2**30
"""Bytes of a G-code file, checked before it is read: a compensated line is about 30 bytes, so
1 GiB is over 30 million lines, three times the vertices a file may have
(:data:`compensation.chain_gcode.MAX_PATH_POINTS`); the parser holds about 1.2 kB a line."""
BULK_MIN_RUN = 32
"""Runs of bulk lines shorter than this go through the per-line classifier (no gain)."""


def parse_program(path, rapids: str = DEFAULT_RAPIDS, block_delete: str | None = None,
                  fast: bool = True, axis_words: AxisWords | None = None, dialect: str | None = None,
                  cycles=None, data: bytes | None = None, found: tuple | None = None, lathe_x: str | None = None,
                  tables: tuple | None = None, subprograms=None, flat=None) -> GProgram:
    """Read a G-code file into a :class:`GProgram` (see the module docstring).

    ``found``: ``(Dialect, evidence)`` already recognised from these bytes under ``dialect="auto"`` (a
    caller that looked first, :mod:`compensation.chain_gcode`): not recognised again. ``lathe_x``: ``"diameter"`` or
    ``"radius"``, what a Fanuc, Haas or Siemens ISO lathe's X words are (the control's parameter, ``--lathe-x``);
    None: on a lathe such a program's first X word is refused.

    ``axis_words``: the machine's (:meth:`AxisWords.of`); ``None``: the built-in default machine's
    (:func:`default_axis_words`, read from its file now).

    ``fast`` (default): the block-wise reader (:func:`_parse_blockwise`) where the machine has three axis
    words, none kept; same classes, moves and refusals as ``fast=False`` (the per-line reader, the reference).

    ``rapids``: ``"keep"`` (G0 lines written as they are) or ``"compensate"``.
    ``block_delete``: ``None`` refuses a ``/`` line that moves or changes modal state;
    ``"on"`` skips ``/`` lines (the controller's switch is on); ``"off"`` runs them.
    ``dialect``: a controller of :data:`compensation.dialects.DIALECT_NAMES`, ``"auto"`` (recognised
    from the content, :func:`compensation.dialects.detect_dialect`) or None (the words every dialect
    shares); the program's ``dialect`` records which (and ``dialect_evidence`` why).
    ``cycles``: None refuses drilling canned cycles; a pass ``(text, path, dialect name, expanded or
    None) -> Expanded or None`` that makes them plain moves (the machine-tool chains give
    :func:`compensation.nc_cycles.cycle_pass`) reads them. ``data``: the file's bytes as a pre-pass left
    them (:func:`compensation.tcp.tcp_prepass`; None: read from ``path``). ``tables``: ``(work offsets, tool
    table)`` the program runs with (:mod:`compensation.nc_state`; either None: not given, the program's own
    ``G10`` lines only): a ``G53`` move's end is then placed in the program's frame (machine axis minus work
    offset, ``G92`` and tool length), so the moves after it are known; None: the axes a ``G53`` moves are
    unknown until the program gives them. ``subprograms``: the :class:`compensation.nc_subfiles.SubprogramFiles` a
    call of a subprogram kept outside the file reads (``--subprograms``; None: such a call is refused).
    ``flat``: the :class:`compensation.nc_expand.Expanded` whose flat program ``data`` is (a caller expanded it:
    :func:`compensation.tcp.flat_prepass`), by which a refusal's text names the lines it refers to
    (:func:`compensation.nc_expand.source_line`); None: ``data`` is the program's own text.
    """
    path = Path(path)
    if rapids not in RAPIDS_CHOICES:
        raise ValueError(f"Expected rapids in {list(RAPIDS_CHOICES)}, got {rapids!r}")
    if block_delete not in (None,) + BLOCK_DELETE_CHOICES:
        raise ValueError(f"Expected block_delete in {list(BLOCK_DELETE_CHOICES)} or None, got {block_delete!r}")
    if not path.is_file():
        raise InputError(not_a_file(path))
    ax = default_axis_words() if axis_words is None else axis_words
    size = path.stat().st_size
    if size > MAX_PROGRAM_BYTES:
        raise InputError(f"{path}: {size / 2**30:.3g} GiB exceeds the limit of {MAX_PROGRAM_BYTES / 2**30:g} GiB per "
                         "program (more lines than the 10,000,000 vertices a file may have); split the program")
    data, line_end = cr_line_ends(path.read_bytes() if data is None else data)
    check_program_bytes(path, data)
    dia, evidence = found if found is not None and dialect == "auto" else _dialect_of(path, data, dialect)
    try:  # the allow-list refuses every mark of a subprogram, macro or parameter: a program without
        return _g80_noted(_parse_data(path, data, rapids, block_delete, fast, ax, dia, evidence, lathe_x,  # full speed
                                      tables, name=int if flat is None else flat.name), line_end)
    except InputError as plain_refusal:
        from . import nc_expand
        from .gcode_classify import ProgramState
        expanded = nc_expand.expand_if_needed(data, path, dialect if dialect in nc_expand.DIALECTS else None,
                                              ProgramState, subprograms)
        if cycles is not None:
            text = expanded.text if expanded is not None else data.decode("latin-1")
            try:  # unrecognised: the cycle's moves end in the G0-G3 of before it, as group 09 leaves it
                expanded = cycles(text, path, dia.name, expanded, **(
                    {"g80_keeps": True} if dia.g80_unrecognised else {})) or expanded
            except InputError as exc:
                raise (expanded.relocate(exc) if expanded is not None else exc) from None
        if expanded is None:
            raise plain_refusal from None
    try:
        prog = _parse_data(path, expanded.text.encode("latin-1"), rapids, block_delete, fast, ax, dia, evidence,
                           lathe_x, tables, dict(expanded.contours), expanded.name)
    except InputError as exc:
        raise expanded.relocate(exc) from None
    prog.expanded = expanded
    return _g80_noted(prog, line_end)


def _g80_noted(prog: GProgram, line_end: str = "\n") -> GProgram:
    """``prog`` with the line of its group-09 ``G80`` reading named as the source's (its line in the main file, or
    ``'k of FILE'`` in a ``--subprograms`` file: :meth:`compensation.nc_expand.Expanded.named`) and in its evidence,
    and the file's line end (:attr:`GProgram.line_end`)."""
    prog.line_end = line_end
    if prog.g80_line:
        if prog.expanded is not None:
            prog.g80_line = prog.expanded.named(prog.expanded.origin[prog.g80_line - 1][0])
        prog.dialect_evidence += f"; {g80_note(prog.g80_line)}"
    return prog


def _parse_data(path: Path, data: bytes, rapids, block_delete, fast: bool, ax: AxisWords, dia,
                evidence: str, lathe_x: str | None = None, tables: tuple | None = None, contours=None,
                name=int) -> GProgram:
    """The reader of ``data`` (block-wise where it applies, else per line); ``contours`` the LinuxCNC G70-G72
    contours by line (:attr:`compensation.nc_expand.Expanded.contours`; the per-line reader reads those cycles);
    ``name`` names a 1-based line of ``data`` inside a refusal's text (:func:`compensation.nc_expand.source_line`:
    ``int`` for a program read as it is, :meth:`compensation.nc_expand.Expanded.name` for a flat one)."""
    replay = None if tables is None else (lambda: FrameReplay(path, ax.words, *tables))
    prog = _parse_blockwise(path, rapids, block_delete, data, ax, dia, lathe_x, replay, name) if (
        fast and _bulk_words(ax)) else None
    if prog is None or any(m.synced for m in prog.table.objects):  # a synchronised move (G33) makes the rapid before
        prog = _parse_lines(path, rapids, block_delete, data, ax, dia, lathe_x, replay, contours, name)  # G33: per line
    prog.dialect, prog.dialect_evidence = dia.name, evidence
    return prog


class FrameReplay:
    """Machine minus program axes (k,) after a program's events so far (a ``G53`` move's end placed in the
    program's frame while it is read): the work offset, ``G92``, the tool length on Z (a lathe tool's offset on X), as
    :meth:`compensation.nc_state.ProgramFrames.shift`, by the controller state
    :func:`compensation.nc_state.program_frames` walks (:class:`compensation.nc_state._Controller`); NaN where not
    known (a table not given; a refused event: :func:`compensation.nc_state.program_frames` refuses it with its
    words)."""

    def __init__(self, path, words, offsets: WorkOffsets | None, tools: ToolTable | None):
        self.c, self.seen, self.failed = _Controller(path, words, offsets, tools), 0, False

    @property
    def system(self) -> str:
        """The work system in force after the events replayed (the power-on ``G54`` before any)."""
        return self.c.system

    @property
    def offsets_given(self) -> bool:
        return self.c.offsets is not None

    def shift(self, events) -> np.ndarray:
        try:
            for event in events[self.seen:]:
                self.c.apply(event)
        except InputError:
            self.failed = True
        self.seen = len(events)
        off, tool, _, tool_x, rotation = self.c.frame()
        if np.nan_to_num(rotation) != 0.0:  # a rotated system: the G53 point's X Y in it is not carried
            self.failed = True
        out, words = np.array(off, dtype=float), list(self.c.words)
        if "Z" in words and np.isfinite(tool):
            out[words.index("Z")] += tool
        if "X" in words and np.isfinite(tool_x):
            out[words.index("X")] += tool_x
        return np.full(len(words), np.nan) if self.failed else out


def _dialect_of(path, data: bytes, dialect) -> tuple:
    """``(Dialect, evidence)`` for :func:`parse_program`'s ``dialect``."""
    from .dialects import RS274, UNRECOGNISED, detect_dialect
    from .dialects import dialect as by_name
    if dialect == "auto":
        try:
            name, evidence = detect_dialect(data[:1 << 20].decode("latin-1"))
        except ValueError as exc:
            raise InputError(f"{path}: {exc}") from None
        return (by_name(name), f"recognised from its content: {evidence}") if evidence else (
            UNRECOGNISED, f"no dialect word found: {RS274}")
    try:
        return by_name(dialect), ("named" if dialect is not None else "")
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None


def _lathe_x(dia, lathe_x) -> tuple:
    """``(lathe_x, diameter)`` of the reader's state: ``lathe_x`` applies only to a dialect whose X is a diameter or
    a radius by a control parameter (Fanuc, Haas, Siemens ISO); LinuxCNC's G7/G8 say it in the program."""
    lx = lathe_x if getattr(dia, "lathe_x_by_parameter", False) else None
    return lx, lx == "diameter"


def _parse_lines(path, rapids, block_delete, data: bytes, ax: AxisWords, dia, lathe_x=None, replay=None,
                 contours=None, name=int) -> GProgram:
    """The per-line reader (the reference). ``replay``: None, or a maker of the
    :class:`FrameReplay` that places a ``G53`` move's end (:func:`parse_program`'s ``tables``); ``name``:
    :func:`_parse_data`'s."""
    lines = split_lines(data.decode("latin-1"))
    st = _State(len(ax.words))
    st.replay = replay() if replay is not None else None
    st.g7x_contours, st.name = contours or {}, name
    st.dialect, st.lathe_x, st.diameter = dia, *_lathe_x(dia, lathe_x)
    classes, moves = [], []
    for idx, line in enumerate(lines):
        body = line.rstrip("\r\n")
        try:
            cls, move = _classify(body, idx, st, rapids, block_delete, ax)
        except _Refuse as r:
            raise _err(path, idx + 1, r.col, r.msg) from None
        classes.append(cls)
        if move is not None:
            moves.append(move)
    if not any(m.compensate for m in moves) and not any(e[2] in ("lathe-thread", "lathe-g7x") for e in st.events):
        raise _no_motion(path, ax)
    return GProgram(path, lines, classes, moves, rapids, block_delete, axis_words=ax, events=tuple(st.events),
                    g80_line=st.g80_line)


def _bulk_words(ax: AxisWords) -> bool:
    """The block-wise reader and writer know machines of three axis words (any letters, linear or
    rotary), each written on every compensated line (none kept)."""
    return len(ax.words) == 3 and not ax.kept


def _no_motion(path, ax: AxisWords) -> InputError:
    return InputError(f"{path}: no G0/G1/G2/G3 motion with {ax.joined('or')} words to compensate found")


def _parse_blockwise(path: Path, rapids: str, block_delete, data: bytes, ax: AxisWords, dia=None,
                     lathe_x: str | None = None, replay=None, name=int) -> GProgram:
    buf = np.frombuffer(data, np.uint8)
    starts, ends = gscan.line_bounds(buf)
    lines = _Lines(data.decode("latin-1"), starts, np.append(starts[1:], buf.size))
    n = len(lines)
    kind, spans_all, vals_all = gscan.scan_lines(buf, starts, ends, ax.words)
    bulk_move = _bulk_move(ax.words)
    linear = ~np.array(ax.is_rotary)  # the columns scaled by the line's units (mm or inch)
    ask = np.flatnonzero(kind == gscan.KIND_ASK)
    for i in ask.tolist():  # lines the kernel leaves to the patterns themselves
        body = lines[i].rstrip("\r\n")
        m = bulk_move.fullmatch(body)
        if m is not None and m.lastindex is not None and m.lastindex >= 2:
            kind[i] = gscan.KIND_MOVE
            spans_all[i] = np.array(m.regs[1:5], dtype=np.int32)
            for j in range(3):
                if m.start(j + 2) >= 0:
                    vals_all[i, j] = float(m.group(j + 2))
        else:
            kind[i] = gscan.KIND_PASS if _BULK_PASS.fullmatch(body) else gscan.KIND_OTHER
    is_move = kind == gscan.KIND_MOVE
    bulk = is_move | (kind == gscan.KIND_PASS)
    mlines = np.flatnonzero(is_move)
    spans = spans_all[mlines]
    vals = vals_all[mlines]
    del spans_all, vals_all
    gcode = np.full(mlines.size, -1, np.int8)  # -1: no G word, 0: G0, 1: G1
    sel = np.flatnonzero(spans[:, 0, 0] >= 0)
    gcode[sel] = buf[starts[mlines[sel]] + spans[sel, 0, 1] - 1] == ord("1")
    given = np.isfinite(vals)

    st = _State(len(ax.words))
    st.dialect, st.lathe_x, st.diameter = dia, *_lathe_x(dia, lathe_x)
    st.replay, st.name = (replay() if replay is not None else None), name
    classes = ["pass"] * n
    moved = []  # ordinals (k0, k1) of the bulk moves read
    pieces, objects = [], []

    def per_line(i: int) -> None:
        try:
            cls, move = _classify(lines[i].rstrip("\r\n"), i, st, rapids, block_delete, ax)
        except _Refuse as r:
            raise _err(path, i + 1, r.col, r.msg) from None
        classes[i] = cls
        if move is not None:
            pieces.append(_piece_from_move(move, len(objects)))
            objects.append(move)

    def bulk_moves(k0: int, k1: int) -> int:
        """Read bulk moves k0..k1-1 (ordinals into mlines); return the ordinal of the first
        that must go through the per-line classifier (k1 if none)."""
        if st.diameter:
            return k0  # lathe diameter mode: X words are read line by line (halved)
        gm = gcode[k0:k1]
        rows = np.arange(k1 - k0)
        last = np.maximum.accumulate(np.where(gm >= 0, rows, -1))
        mode0 = {"G0": 0, "G1": 1}.get(st.mode, -1)
        mode = np.where(last >= 0, gm[np.maximum(last, 0)], mode0)
        scale = MM_PER_INCH if st.inch else 1.0
        v = vals[k0:k1] * np.where(linear, scale, 1.0)
        giv = given[k0:k1]
        bad = mode < 0
        if st.incremental:
            cum = np.cumsum(np.vstack([st.pos[None, :], np.where(giv, v, 0.0)]), axis=0)
            start, end = cum[:-1], cum[1:]
            bad |= (giv & ~np.isfinite(start)).any(axis=1)
        else:
            end = _forward_fill(v, giv, st.pos)
            start = np.vstack([st.pos[None, :], end[:-1]])
        known = np.isfinite(end)
        compensate = ~((mode == 0) & (rapids == "keep"))
        bad |= compensate & ~known.all(axis=1)
        p = int(np.argmax(bad)) if bad.any() else k1 - k0
        if p:
            sl = slice(0, p)
            pieces.append((mlines[k0:k0 + p], mode[sl].astype(np.int8), start[sl], end[sl],
                           np.full(p, st.inch), np.full(p, st.incremental), compensate[sl], known[sl],
                           np.full(p, -1), spans[k0:k0 + p]))
            moved.append((k0, k0 + p))
            st.mode = "G0" if mode[p - 1] == 0 else "G1"
            st.spline_pq = None
            st.pos = end[p - 1].copy()
        return k0 + p

    # runs of bulk lines long enough to be worth it; everything else line by line
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bulk.astype(np.int8), [0]])))
    runs = [(s, e) for s, e in zip(edges[0::2].tolist(), edges[1::2].tolist()) if e - s >= BULK_MIN_RUN]
    at = 0
    for s, e in runs + [(n, n)]:
        for i in range(at, s):
            per_line(i)
        at = e
        k0, k1 = (int(v) for v in np.searchsorted(mlines, [s, e]))
        while k0 < k1:
            k = bulk_moves(k0, k1)
            if k < k1:  # this line needs the per-line classifier (it refuses or changes the state)
                per_line(int(mlines[k]))
                k += 1
            k0 = k
    if moved:
        cls_arr = np.array(classes, dtype=object)
        cls_arr[np.concatenate([mlines[a:b] for a, b in moved])] = "move"
        classes = cls_arr.tolist()
    table = MoveTable.concat(pieces, objects)
    if not table.compensate.any():
        raise _no_motion(path, ax)
    return GProgram(path, lines, classes, _LazyMoves(table, lines, ax.words), rapids, block_delete, table=table,
                    data=data, axis_words=ax, events=tuple(st.events), g80_line=st.g80_line)
