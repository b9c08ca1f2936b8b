"""Writing a compensated G-code program back (:mod:`compensation.gcode`): line by line in the program's own
distance mode and units (:func:`render_program`), or in bulk for a block-wise read program (:func:`render_table`)."""
from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from . import gcode_kernels as gscan
from .gcode_state import MM_PER_INCH
from .gcode_table import _Lines
from .gcode_words import AxisWords, DECIMALS, GMove, GProgram


def fmt(v: float, decimals: int) -> str:
    s = f"{v:.{decimals}f}"
    if float(s) == 0.0:
        s = f"{0.0:.{decimals}f}"
    return s


def render_program(program: GProgram, vertices: list, header=(), track: dict | None = None,
                   held=None) -> tuple[str, list]:
    """Write the program with each compensated move's vertices ``vertices[k]`` (m_k, k_axes) absolute axes
    (mm, deg; the last row the move's end): ``(text, groups)``, ``groups[i]`` the output lines source line
    ``i`` became (header lines aside). Every other line comes back byte for byte; on a compensated line only
    the axis numbers change, in the line's own units and distance mode (an arc becomes ``G1``, extra vertices
    added lines; docs/reference/tool-paths.md). ``header`` lines become ``(...)`` comments after a leading
    ``%`` and program-number line. ``track`` (a dict): filled with ``{line index: (k,) position of the
    controller running the output after that move}``. ``held`` (c, k) bool per compensated move: axes held at
    a ``G53`` value (:mod:`compensation.held_axes`), never written where the line has no word for them."""
    comp = [m for m in program.moves if m.compensate]
    if len(vertices) != len(comp):
        raise ValueError(f"Expected vertices for {len(comp)} compensated moves, got {len(vertices)}")
    ax = program.axis_words
    k_axes = len(ax.words)
    groups = [[ln] for ln in program.lines]
    ctrl = np.full(k_axes, np.nan)  # where the controller running the output is, mm / deg
    k, feed = 0, None  # feed: the programmed F a feed move after a thread gets back (compensation.nc_thread)
    for m in program.moves:
        if not m.compensate:
            ctrl = _kept_position(m, ctrl, ax)
        else:
            q = np.asarray(vertices[k], dtype=float).reshape(-1, k_axes)
            k += 1
            skip = () if held is None else tuple(a for a, h in zip(ax.words, held[k - 1]) if h and a not in m.words)
            start = ctrl
            try:
                groups[m.index], ctrl = _render_move(program.lines[m.index], m, q, ctrl, ax, skip)
            except ValueError as exc:
                if m.lead is None:
                    raise
                from errormap.io import InputError
                raise InputError(f"{program.path}: {exc}") from None
            if m.synced == "G33.1":  # the tap returns: the controller is at its start again
                ctrl = start
            if m.synced == "G32" or (feed is not None and m.kind != "rapid" and m.lead is None):
                from .nc_thread import restore_feed
                if m.lead is None:
                    groups[m.index] = restore_feed(groups[m.index], feed[0], program.lines[feed[1] + 1:m.index])
                feed = (m.lead[1], m.index) if m.lead is not None else None
            for j, g in nurbs_block_lines(m, program.lines).items():
                groups[j] = g
        if track is not None:
            track[m.index] = ctrl
    out = [ln for g in groups for ln in g]
    return _with_header(out, program.notes() + tuple(header)), groups


def _render_move(line: str, m: GMove, q, ctrl, ax: AxisWords, skip=()):
    """Output lines of one compensated move with vertices ``q`` (m, k), and the controller
    position after them (see :func:`render_program`; ``skip``: axis words never written, held)."""
    if not np.all(np.isfinite(q)):
        raise ValueError(f"Expected finite vertices, got NaN/inf for line {m.index + 1}")
    body = line.rstrip("\r\n")
    ending = line[len(body):] or "\n"
    written, before = [], []
    for row in q:
        before.append(ctrl)
        vals, ctrl = _written_values(row, ctrl, m, ax)
        written.append(vals)
    first = _rewrite_line(body, m, written[0], before[0], ax, skip)
    leads = None
    if m.lead is not None:  # a G32's or G33's pieces, each with its own lead (compensation.nc_thread)
        from .nc_thread import LEAD_WORD, lead_texts, with_lead
        after = np.array(before[1:] + [ctrl])
        leads, word = lead_texts(m, np.array(before), after, m.units), LEAD_WORD[m.synced]
        first = with_lead(first, leads[0], word=word)
    # a block-delete move (run under --block-delete off) keeps its '/' on every piece, so
    # that switching block delete on at the controller skips the whole move, not its first piece
    slash = "/" if body.lstrip(" \t").startswith("/") else ""
    if ax.kept:
        extra = [slash + " ".join(f"{a}{vals[j]}" for j, a in enumerate(ax.words) if _needed(j, vals, c0, m, ax))
                 + ending for vals, c0 in zip(written[1:], before[1:])]
    else:  # every word on every added line
        extra = [slash + " ".join(f"{a}{v}" for a, v in zip(ax.words, vals) if a not in skip) + ending
                 for vals in written[1:]]
    if leads is not None:
        extra = [with_lead(e, t, word=word) for e, t in zip(extra, leads[1:])]
    if m.block_end and extra:  # a contour's last block N(nf): its number goes with its end (the last piece)
        first, extra[-1] = _n_to_last(first, extra[-1], m)
    return _pieces(line, body, first, extra), ctrl


def _n_to_last(first: str, last: str, m: GMove) -> tuple:
    """``(first, last)`` with the block number moved from the first piece's front to the last piece's."""
    n = re.match(r"([ \t]*/?[ \t]*)([Nn][ \t]*\d+)[ \t]*", first)
    if n is None:
        raise ValueError(f"line {m.index + 1}: a contour's last block whose N word is not its first word")
    return n.group(1) + first[n.end():], n.group(1) + n.group(2) + " " + last.lstrip(" \t/")


def _pieces(line: str, body: str, first: str, extra: list) -> list:
    """Output lines of a move: its rewritten ``first`` line and the ``extra`` added lines, the source line's
    ending kept on the last (none on a last line without one)."""
    if extra and not line.endswith("\n"):
        ending = line[len(body):] or "\n"
        return [first + ending] + extra[:-1] + [extra[-1][:-len(ending)]]
    return [first + line[len(body):]] + extra


def nurbs_block_lines(m: GMove, lines) -> dict:
    """``{line index: [output line]}`` of a NURBS move's G5.2 lines (:func:`compensation.gcode_spline.nurbs_end`):
    each written as a comment (the curve is the G5.3 line's compensated chords); {} for any other move."""
    out = {}
    for j in (m.arc or {}).get("block", ()):
        body = lines[j].rstrip("\r\n")
        text = body.replace("(", "[").replace(")", "]")
        out[j] = [f"(volcomp: NURBS control point, written as the chords below: {text.strip()})" + lines[j][len(body):]]
    return out


def _with_header(out: list, header) -> str:
    """``out`` (output lines) joined, with ``header`` lines as ``(...)`` comments after a
    leading ``%`` line and a program-number line, if any."""
    head = "".join(f"({_comment_safe(h)})\n" for h in header)
    at = _header_at(out[:2])
    return "".join(out[:at]) + head + "".join(out[at:])


def _header_at(first_two: list) -> int:
    """Where header lines go among the first two output lines: after a leading ``%`` line and a
    program-number line (``O1000 (NAME)``), if any."""
    at = 0
    if at < len(first_two) and first_two[at].strip() == "%":
        at += 1
    if at < len(first_two) and re.match(r"[ \t]*[Oo][ \t]*\d", first_two[at]):
        at += 1
    return at


def _comment_safe(text: str) -> str:
    return str(text).replace("(", "[").replace(")", "]").replace("\n", " ")


def _kept_position(m: GMove, ctrl, ax: AxisWords):
    """Controller position after a line written as it was (a kept rapid)."""
    out = ctrl.copy()
    scale = MM_PER_INCH if m.units == "inch" else 1.0
    for j, a in enumerate(ax.words):
        if a in m.words:
            v = m.words[a].value * (1.0 if a in ax.rotary else scale)
            out[j] = out[j] + v if m.incremental else v
    return out


def _written_values(row, ctrl, m: GMove, ax: AxisWords):
    """The numbers written for one vertex ``row`` (k,) (text per axis) and the controller
    position they take it to: the line's units and distance mode."""
    scale = MM_PER_INCH if m.units == "inch" else 1.0
    lin_fmt, rot_fmt = (scale, DECIMALS[m.units]), (1.0, DECIMALS["deg"])  # (scale, decimals)
    vals, new = [], ctrl.copy()
    for j, rotary in enumerate(ax.is_rotary):
        s, dec = rot_fmt if rotary else lin_fmt
        s = s * 0.5 if m.diameter and ax.words[j] == "X" else s  # a diameter written for the radius
        if m.incremental:
            txt = fmt((row[j] - ctrl[j]) / s, dec)
            new[j] = ctrl[j] + float(txt) * s
        else:
            txt = fmt(row[j] / s, dec)
            new[j] = float(txt) * s
        vals.append(txt)
    return vals, new


def _needed(j: int, vals, ctrl_before, m: GMove, ax: AxisWords) -> bool:
    """An axis word a written line must carry: every word that is not kept (the correction moves
    it), a kept one where the line had it or where its written value moves it."""
    a = ax.words[j]
    if not ax.kept or a not in ax.kept or a in m.words:
        return True
    return float(vals[j]) != 0.0 if m.incremental else not (np.isfinite(ctrl_before[j])
                                                           and abs(float(vals[j]) - ctrl_before[j]) < 1e-12)


def _rewrite_line(body: str, m: GMove, vals, ctrl_before, ax: AxisWords, skip=()) -> str:
    # a kept word whose value is unchanged keeps its text as written (a chain's tool orientation)
    words, kept = m.words, ax.kept
    given = [(j, words[a]) for j, a in enumerate(ax.words) if a in words]
    edits = [(w.num_start, w.num_end, vals[j]) for j, w in given
             if not (kept and w.letter in kept and float(vals[j]) == w.value)]  # (start, end, text)
    last_end = max((w.num_end for w in (dict(given).values() if given else words.values())),  # a full circle: its I J K
                   default=m.motion_word.num_end if m.motion_word is not None else len(body))  # a NURBS: its G5.3
    if len(given) < len(ax.words):
        missing = "".join(f" {a}{vals[j]}" for j, a in enumerate(ax.words)
                          if a not in words and a not in skip and (not kept or _needed(j, vals, ctrl_before, m, ax)))
        if missing:
            edits.append((last_end, last_end, missing))
    if m.kind in ("arc", "spline"):  # written as its compensated chords: G1, without the curve's words
        if m.motion_word is not None:
            edits.append((m.motion_word.start, m.motion_word.num_end, "G1"))
        else:
            axis = [w.start for a, w in m.words.items() if a in ax.words]  # not a word the edits below remove
            first = min(axis or [w.start for w in m.words.values()])
            edits.append((first, first, "G1 "))
        for a in ("I", "J", "K", "R", "P") + (("Q",) if m.kind == "spline" else ()):
            if a in m.words:
                w = m.words[a]
                s = w.start - 1 if w.start > 0 and body[w.start - 1] in " \t" else w.start
                edits.append((s, w.num_end, ""))
    for s, e, txt in sorted(edits, key=lambda t: (t[0], t[1]), reverse=True):
        body = body[:s] + txt + body[e:]
    return body



class _Groups(Sequence):
    """``groups`` of :func:`render_table`: output lines per source line, built when asked for.
    ``changed[i]``: the output lines of a move written line by line; ``simple[i]``: a line
    rewritten in bulk, its output ``text[off[i]:off[i + 1]]``; otherwise the line itself."""

    def __init__(self, lines: list, text: str, off, simple, changed: dict):
        self._lines, self._text, self._off, self._simple, self._changed = lines, text, off, simple, changed

    def __len__(self) -> int:
        return len(self._lines)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = range(len(self))[i]
        g = self._changed.get(i)
        if g is not None:
            return list(g)
        if self._simple[i]:
            return [self._text[self._off[i]:self._off[i + 1]]]
        return [self._lines[i]]


def _fixed_str(mag: int, neg: bool, decimals: int) -> str:
    """The text of one number of :func:`gcode_kernels.format_fixed`."""
    d = str(mag).rjust(decimals + 1, "0")
    return f"{'-' if neg else ''}{d[:-decimals]}.{d[-decimals:]}"


def render_table(program: GProgram, axes, counts, header=()) -> tuple:
    """:func:`render_program` of a block-wise read program in absolute mode, in bulk: same text.
    ``axes`` (n, 3): every compensated vertex in order; ``counts`` vertices per compensated move. The bulk
    lines' numbers are formatted column-wise (:func:`gcode_kernels.format_fixed`) and put in place by a
    compiled pass (:func:`gcode_kernels.render_lines`); other compensated lines are written here and copied
    in."""
    t = program.table
    if t is None or t.incremental.any():
        raise ValueError("Expected a block-wise read program without incremental moves")
    axes = np.asarray(axes, dtype=float)
    counts = np.asarray(counts, dtype=np.int64)
    rows = np.flatnonzero(t.compensate)
    if counts.shape != rows.shape or axes.shape != (int(counts.sum()), 3):
        raise ValueError(f"Expected counts for {rows.size} compensated moves and matching axes, "
                         f"got {counts.shape} and {axes.shape}")
    if not np.all(np.isfinite(axes)):
        raise ValueError("Expected finite vertices, got NaN/inf")
    if axes.size and np.abs(axes).max() >= gscan.FIXED_MAX:  # absurd numbers: the per-line writer
        return render_program(program, np.split(axes, np.cumsum(counts)[:-1]), header=header)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    inch_v = np.repeat(t.inch[rows], counts)
    mags = np.empty(axes.shape, np.int64)
    negs = np.empty(axes.shape, bool)
    ax = program.axis_words
    words = ax.words
    # per axis column: decimals written on a mm line, on an inch line (rotary: degrees on both)
    decs = np.array([(DECIMALS["deg"],) * 2 if r else (DECIMALS["mm"], DECIMALS["inch"]) for r in ax.is_rotary])
    for j, rotary in enumerate(ax.is_rotary):
        if rotary:
            mags[:, j], negs[:, j] = gscan.format_fixed(axes[:, j], DECIMALS["deg"])
        elif inch_v.any():
            col = np.where(inch_v, axes[:, j] / MM_PER_INCH, axes[:, j])
            mags[:, j], negs[:, j] = gscan.format_fixed(col, np.where(inch_v, DECIMALS["inch"], DECIMALS["mm"]))
        else:
            mags[:, j], negs[:, j] = gscan.format_fixed(axes[:, j], DECIMALS["mm"])

    def word(v: int, j: int) -> str:
        return _fixed_str(int(mags[v, j]), bool(negs[v, j]), int(decs[j, int(inch_v[v])]))

    lines = program.lines
    data = program.data if program.data is not None else "".join(lines).encode("latin-1")
    buf = np.frombuffer(data, np.uint8)
    n = len(lines)
    if isinstance(lines, _Lines):
        starts, stops = lines._starts, lines._stops
    else:
        starts, _ = gscan.line_bounds(buf)
        stops = np.append(starts[1:], buf.size)
    mode = np.zeros(n, np.int8)
    changed = {}
    bulk = t.obj[rows] < 0
    sp = t.spans[rows]
    for k in np.flatnonzero(~bulk).tolist():  # moves read line by line (arcs, ...)
        m = program.moves[int(rows[k])]
        q = axes[first[k]:first[k] + counts[k]]
        changed[m.index], _ = _render_move(lines[m.index], m, q, np.full(3, np.nan), program.axis_words)
        changed.update(nurbs_block_lines(m, lines))
    kb = np.flatnonzero(bulk)
    full = (sp[kb, 1:, 0] >= 0).all(axis=1)  # all three axis words on the line (the common case)
    one = counts[kb] == 1
    fa = kb[full & one]  # the common case, in the compiled pass
    mode[t.line[rows[fa]]] = 1
    row_of_line = np.full(n, -1, np.int64)
    row_of_line[t.line[rows[fa]]] = rows[fa]
    vert_of_row = np.full(len(t), -1, np.int64)
    vert_of_row[rows] = first
    rest = kb[~(full & one)]
    for i, f, c, spans3 in zip(t.line[rows[rest]].tolist(), first[rest].tolist(), counts[rest].tolist(),
                               sp[rest, 1:].tolist()):
        line = lines[i]
        body = line.rstrip("\r\n")
        vals = [word(f, j) for j in range(3)]
        parts, pos = [], 0
        for (sj, ej), v in zip(spans3, vals):  # the words on the line, in place
            if sj >= 0:
                parts += [body[pos:sj], v]
                pos = ej
        parts += [f" {w}{v}" for w, v, (sj, _) in zip(words, vals, spans3) if sj < 0]  # the missing ones appended
        parts.append(body[pos:])
        ending = line[len(body):] or "\n"
        extra = [" ".join(f"{w}{word(v, j)}" for j, w in enumerate(words)) + ending for v in range(f + 1, f + c)]
        changed[i] = _pieces(line, body, "".join(parts), extra)
    blob_off = np.zeros(n + 1, np.int64)
    blob = np.zeros(0, np.uint8)
    if changed:
        idx = np.array(sorted(changed), dtype=np.int64)
        enc = ["".join(changed[i]).encode("latin-1") for i in idx.tolist()]
        mode[idx] = 2
        size = np.zeros(n, np.int64)
        size[idx] = [len(e) for e in enc]
        blob_off[1:] = np.cumsum(size)
        blob = np.frombuffer(b"".join(enc), np.uint8)
    out, off = gscan.render_lines(buf, starts, stops, mode, row_of_line, vert_of_row, t.spans, mags, negs, inch_v,
                                  decs, blob, blob_off)
    text = out.tobytes().decode("latin-1")
    at = _header_at([text[off[j]:off[j + 1]] for j in range(min(n, 2))])
    head = "".join(f"({_comment_safe(h)})\n" for h in program.notes() + tuple(header))
    full_text = text[:off[at]] + head + text[off[at]:] if head else text
    return full_text, _Groups(lines, text, off, mode == 1, changed)
