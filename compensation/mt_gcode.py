"""G-code over a machine-tool chain (``kind = "machine-tool"``): axis words from the machine.

The grinder's reader (:mod:`compensation.gcode`) knows X, Z and A; a chain machine declares its own
axis words (``X Y Z`` on ``mill-xyz``, ``X Y Z A C`` on ``five-axis-ac``). This reader applies the
grinder's contract line by line — the same allow-lists (:data:`compensation.gcode.ALLOWED_G`,
``REFUSED_G``, ``ALLOWED_M``), the same number syntax (:func:`compensation.gcode.tokenize`), the
same pass-through and refusal rules — with three differences that come from the machine:

* **axis words** are the machine's: a word of an axis the machine lacks (``B`` on ``mill-xyz``, any
  of ``X Y Z U V W A B C``) is refused, naming the machine;
* **arcs** ``G2/G3`` in the planes the machine has: ``G17`` (XY, centre ``I J``), ``G18`` (XZ,
  ``I K``), ``G19`` (YZ, ``J K``), or ``R``; an arc in a plane of an axis the machine lacks (the
  plane code alone is a state line, as on the grinder), or a centre word of another plane, is
  refused; the other axes of an arc line move linearly along it (a helix);
* the **tool-tip** is compensated: linear axes get the corrected numbers, rotary axes (the tool's
  orientation) are written as the program commands them.

Line classes: ``pass`` (written back byte for byte: comments, ``N F S T``, allowed ``M``, modal
codes that change no axis meaning, ``G54``), ``state`` (modal codes the reader follows:
``G90/G91``, ``G20/G21``, ``G17/18/19``, ``G90.1/G91.1``, ``G4 P``, ``G28/G30``; byte for byte),
``move`` (``G0/G1/G2/G3`` with axis words; compensated, or a rapid kept under ``rapids="keep"``),
``skipped`` (block delete on). Anything else that can move or reinterpret an axis is refused with
:class:`~errormap.io.InputError` naming file, line, column and word.

A compensated move becomes its line with the axis numbers replaced (missing linear axes appended
after the last axis word); an arc becomes ``G1`` with its ``I J K R P`` words removed and its
chords as added lines; a long move is split into added lines. Numbers are written in the line's
own units and distance mode (incremental numbers as differences of what was written).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import InputError

from .gcode import (ALLOWED_G, ALLOWED_M, BLOCK_DELETE_CHOICES, DECIMALS, DEFAULT_RAPIDS, LETTER_RULES,
                    MAX_TOOL_DIGITS, MM_PER_INCH, RAPIDS_CHOICES, REFUSED_G, REFUSED_LETTERS, _Refuse, _check_p_q,
                    _err, _modal_groups, _plain_tool_number, _with_header, arc_segments, fmt, plane_arc, split_lines,
                    tokenize)

ALL_AXIS_WORDS = ("X", "Y", "Z", "U", "V", "W", "A", "B", "C")
PLANES = {"G17": ("X", "Y", "I", "J"), "G18": ("Z", "X", "K", "I"), "G19": ("Y", "Z", "J", "K")}
"""Arc plane -> (u axis, v axis, u centre word, v centre word); the arc turns counter-clockwise
(G3) from u towards v, seen from the positive third axis (RS274)."""
CENTRE_WORDS = ("I", "J", "K")
MAX_SEGMENTS_PER_MOVE = 100_000
"""A move split or linearised into more pieces than this is refused (a tolerance far too tight)."""


@dataclass
class ChainMove:
    """One moving line over a chain's axes: ``start``/``end`` (k,) absolute mm / deg in
    ``machine.axis_columns`` order (``start`` NaN where not yet known); ``arc`` (G2/G3) the
    centre, radii and sweep in its plane's (u, v) columns ``plane``; ``words`` the line's axis and
    arc words."""

    index: int
    kind: str
    start: np.ndarray
    end: np.ndarray
    units: str
    incremental: bool
    words: dict
    motion_word: object
    compensate: bool
    arc: dict | None = None


@dataclass
class ChainProgram:
    """A parsed program for ``machine``: lines (Latin-1 text, endings kept), classes, moves."""

    path: Path
    machine: object
    lines: list
    classes: list
    moves: list
    rapids: str = DEFAULT_RAPIDS
    block_delete: str | None = None

    @property
    def words(self) -> tuple:
        return self.machine.axis_words


class _State:
    def __init__(self, k):
        self.mode = None
        self.incremental = False
        self.arc_abs = False
        self.inch = False
        self.plane = "G17"
        self.pos = np.full(k, np.nan)


def parse_chain_program(path, machine, rapids: str = DEFAULT_RAPIDS, block_delete: str | None = None) -> ChainProgram:
    """Read a G-code file for the machine-tool chain ``machine`` (module docstring)."""
    path = Path(path)
    if rapids not in RAPIDS_CHOICES:
        raise ValueError(f"Expected rapids in {list(RAPIDS_CHOICES)}, got {rapids!r}")
    if block_delete not in (None,) + BLOCK_DELETE_CHOICES:
        raise ValueError(f"Expected block_delete in {list(BLOCK_DELETE_CHOICES)} or None, got {block_delete!r}")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    lines = split_lines(path.read_bytes().decode("latin-1"))
    st = _State(len(machine.axes))
    classes, moves = [], []
    for idx, line in enumerate(lines):
        body = line.rstrip("\r\n")
        try:
            cls, move = _classify(body, idx, st, machine, rapids, block_delete)
        except _Refuse as r:
            raise _err(path, idx + 1, r.col, r.msg) from None
        classes.append(cls)
        if move is not None:
            moves.append(move)
    if not any(m.compensate for m in moves):
        raise InputError(f"{path}: no G0/G1/G2/G3 motion with {', '.join(machine.axis_words)} words to compensate "
                         "found")
    return ChainProgram(path, machine, lines, classes, moves, rapids, block_delete)


def _checked_words(words, machine):
    """The grinder's allow-lists with the machine's axis words (module docstring)."""
    axis_words = set(machine.axis_words)
    by, gs, ms = {}, [], []
    for w in words:
        if w.letter == "G":
            code = w.code
            if round(w.value, 1) != round(w.value, 6):
                raise _Refuse(w.start + 1, f"'G{w.text}': unknown G code")
            if code in REFUSED_G:
                raise _Refuse(w.start + 1, f"'{code}' ({REFUSED_G[code]}) is not supported")
            if code not in ALLOWED_G:
                raise _Refuse(w.start + 1, f"'{code}': unknown G code (not on the allow-list)")
            gs.append((code, w))
        elif w.letter == "M":
            if w.value != int(w.value) or int(w.value) not in ALLOWED_M:
                raise _Refuse(w.start + 1, f"'M{w.text}': M code not on the allow-list (may move or call a program)")
            ms.append(w)
        elif w.letter in ALL_AXIS_WORDS and w.letter not in axis_words:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': the machine {machine.name!r} has no {w.letter} axis "
                                       f"(its axes: {' '.join(machine.axis_words)}); not supported")
        elif w.letter in CENTRE_WORDS or w.letter in axis_words:
            if w.letter in by:
                raise _Refuse(w.start + 1, f"repeated '{w.letter}' word")
            by[w.letter] = w
        elif w.letter in REFUSED_LETTERS:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': {REFUSED_LETTERS[w.letter]}; not supported")
        elif w.letter not in LETTER_RULES:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': unknown word")
        elif w.letter == "T" and not _plain_tool_number(w):
            raise _Refuse(w.start + 1, f"'T{w.text}': a T word of more than {MAX_TOOL_DIGITS} digits (or not a "
                                       "whole number) may select a tool offset that shifts the axes, like G43 H; "
                                       f"not supported (write the tool number alone, at most {MAX_TOOL_DIGITS} digits)")
        else:
            if w.letter in by:
                raise _Refuse(w.start + 1, f"repeated '{w.letter}' word")
            by[w.letter] = w
    return by, gs, ms


def _classify(body, idx, st: _State, machine, rapids, block_delete):
    bd, words, pct = tokenize(body)
    if pct:
        return "pass", None
    if bd and block_delete == "on":
        return "skipped", None
    by, gs, ms = _checked_words(words, machine)
    groups = _modal_groups(gs)
    if "O" in by:
        if len(words) > 1 and any(w.letter not in ("O", "N") for w in words):
            raise _Refuse(by["O"].start + 1, "'O' word with other words (subroutines and control flow are not supported)")
        return "pass", None
    axis_words = {a: by[a] for a in machine.axis_words if a in by}
    arc_words = {a: by[a] for a in ("I", "J", "K", "R") if a in by}
    changes = any(g in groups for g in ("motion", "plane", "units", "distance", "arc_distance", "nonmodal"))
    if bd and block_delete is None and (axis_words or arc_words or changes):
        raise _Refuse(body.index("/") + 1, "block delete '/' on a line that moves or changes modal state; "
                                           "say whether the controller skips it: --block-delete on|off")
    _apply_modal(st, groups)
    motion_word = groups["motion"][1] if "motion" in groups else None
    _check_p_q(st, by, gs, axis_words, arc_words)
    if "nonmodal" in groups and groups["nonmodal"][0] in ("G28", "G30"):
        return _reference_return(st, groups, axis_words, arc_words, machine)
    if "nonmodal" in groups and axis_words:
        w = next(iter(axis_words.values()))
        raise _Refuse(w.start + 1, f"axis word '{w.letter}{w.text}' with {groups['nonmodal'][0]} (a dwell time on "
                                   "some controls, not a move)")
    if not axis_words:
        if arc_words:
            w = next(iter(arc_words.values()))
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' without axis words")
        return ("state" if changes else "pass"), None
    return "move", _move(idx, st, by, axis_words, arc_words, motion_word, rapids, machine)


def _apply_modal(st: _State, groups: dict):
    if "units" in groups:
        st.inch = groups["units"][0] == "G20"
    if "plane" in groups:
        st.plane = groups["plane"][0]
    if "distance" in groups:
        st.incremental = groups["distance"][0] == "G91"
    if "arc_distance" in groups:
        st.arc_abs = groups["arc_distance"][0] == "G90.1"
    if "motion" in groups:
        code = groups["motion"][0]
        st.mode = None if code == "G80" else code


def _reference_return(st, groups, axis_words, arc_words, machine):
    """``G28``/``G30`` as the grinder's reader takes them: bare, or zero incremental words; the
    axes moved are unknown afterwards."""
    code, w = groups["nonmodal"]
    if "motion" in groups:
        raise _Refuse(w.start + 1, f"'{code}' with a motion code on the same line")
    if arc_words:
        a = next(iter(arc_words.values()))
        raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with {code}")
    for a in axis_words.values():
        if not st.incremental or a.value != 0.0:
            raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with {code}: an intermediate point is an uncompensated "
                                       f"program point; only a bare {code} or zero incremental words "
                                       f"('{code} G91 Z0') are accepted")
    st.pos = st.pos.copy()
    for j, a in enumerate(machine.axis_words):
        if not axis_words or a in axis_words:
            st.pos[j] = np.nan
    return "state", None


def _move(idx, st: _State, by, axis_words, arc_words, motion_word, rapids, machine) -> ChainMove:
    first = min(axis_words.values(), key=lambda w: w.start)
    if st.mode is None:
        raise _Refuse(first.start + 1, f"axis word '{first.letter}{first.text}' but no motion mode (G0/G1/G2/G3) is active")
    if arc_words and st.mode not in ("G2", "G3"):
        w = next(iter(arc_words.values()))
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {st.mode} line (arc words need G2/G3)")
    scale = MM_PER_INCH if st.inch else 1.0
    start = st.pos.copy()
    end = st.pos.copy()
    for j, ax in enumerate(machine.axes):
        a = ax.word
        if a in axis_words:
            v = axis_words[a].value * (scale if ax.kind == "linear" else 1.0)
            if st.incremental:
                if not np.isfinite(start[j]):
                    raise _Refuse(axis_words[a].start + 1, f"incremental '{a}{axis_words[a].text}' before {a} "
                                                           "is known (no absolute position yet)")
                end[j] = start[j] + v
            else:
                end[j] = v
    kind = {"G0": "rapid", "G1": "linear"}.get(st.mode, "arc")
    compensate = not (kind == "rapid" and rapids == "keep")
    words = dict(axis_words)
    words.update(arc_words)
    if "P" in by and kind == "arc":
        words["P"] = by["P"]
    known = np.isfinite(end)
    if compensate and not known.all():
        missing = ", ".join(a for a, k in zip(machine.axis_words, known) if not k)
        raise _Refuse(first.start + 1, f"'{first.letter}{first.text}': motion before {', '.join(machine.axis_words)} "
                                       f"are all known (no value yet for {missing})")
    move = ChainMove(idx, kind, start, end, "inch" if st.inch else "mm", st.incremental, words, motion_word, compensate)
    if kind == "arc":
        try:
            move.arc = _arc_geometry(st, move, arc_words, scale, machine, first)
        except _Refuse as r:
            raise _Refuse(r.col, f"'{first.letter}{first.text}': {r.msg}") from None
    st.pos = end
    return move


def _arc_geometry(st, move, arc_words, scale, machine, first):
    """Centre, radii and sweep of a G2/G3 arc in the active plane's (u, v) columns."""
    u_ax, v_ax, u_c, v_c = PLANES[st.plane]
    col = {a: j for j, a in enumerate(machine.axis_words)}
    missing = [a for a in (u_ax, v_ax) if a not in col]
    if missing:
        raise _Refuse(first.start + 1, f"{st.mode} arc in the {st.plane} plane: the machine {machine.name!r} has no "
                                       f"{missing[0]} axis")
    for w in arc_words:
        if w in CENTRE_WORDS and w not in (u_c, v_c):
            raise _Refuse(arc_words[w].start + 1, f"'{w}' on a {st.plane} arc (its centre words are {u_c} {v_c})")
    if not np.all(np.isfinite(move.start)):
        raise _Refuse(first.start + 1, f"{st.mode} arc before the start position is known")
    ju, jv = col[u_ax], col[v_ax]
    u0, v0, u1, v1 = move.start[ju], move.start[jv], move.end[ju], move.end[jv]
    return {"ju": ju, "jv": jv, **plane_arc(u0, v0, u1, v1, st.mode, arc_words, (u_c, v_c), st.arc_abs, scale,
                                             first, pair=f"{u_c}/{v_c}", both=f"{u_c} and {v_c}")}


# ---------------------------------------------------------------------------- geometry
def move_points(move: ChainMove, t) -> np.ndarray:
    """Nominal axes at parameters ``t`` in [0, 1] along a move, (m,) -> (m, k): linear in the axes
    (what the controller interpolates); an arc turns uniformly in its plane, the other axes linear."""
    t = np.asarray(t, dtype=float)
    if move.arc is None:
        if t.size and np.all(t == 1.0):
            return np.repeat(move.end[None, :], t.size, axis=0)
        return move.start[None, :] + t[:, None] * (move.end - move.start)[None, :]
    g = move.arc
    out = move.start[None, :] + t[:, None] * (move.end - move.start)[None, :]
    th = g["theta0"] + t * g["sweep"]
    r = g["r0"] + t * (g["r1"] - g["r0"])
    out[:, g["ju"]] = g["uc"] + r * np.cos(th)
    out[:, g["jv"]] = g["vc"] + r * np.sin(th)
    return out


def arc_chords(move: ChainMove, tol_mm: float) -> int:
    """Chords so the sagitta of an arc stays within ``tol_mm`` (≥ 1): the grinder reader's rule."""
    return arc_segments(move, tol_mm)


CURVATURE_FRACTIONS = (0.25, 0.5, 0.75)
"""Where along a move the field's second difference is taken (its largest counts)."""
CURVATURE_STEP = 0.25
"""Second difference step, as a share of the move."""


def field_pieces(moves, field, tol_um: float) -> np.ndarray:
    """Pieces per move so that the straight interpolation between compensated vertices stays within
    ``tol_um`` of the field along it: a piece of a move whose field has second derivative ``c``
    (μm per unit of the move's parameter squared) deviates by ``c/(8 n²)``, so ``n = ⌈√(c/(8 tol))⌉``;
    ``c`` is the largest second difference of the field along the move at
    :data:`CURVATURE_FRACTIONS` (step :data:`CURVATURE_STEP` of the move). Shape (m,) int ≥ 1."""
    if not moves:
        return np.zeros(0, dtype=int)
    h = CURVATURE_STEP
    pts = []
    for m in moves:
        for f in CURVATURE_FRACTIONS:
            pts.append(move_points(m, np.array([f - h, f, f + h])))
    q = np.concatenate(pts)
    E = np.asarray(field.predict(q)).reshape(len(moves), len(CURVATURE_FRACTIONS), 3, 3)
    c = np.abs(E[:, :, 0] - 2 * E[:, :, 1] + E[:, :, 2]).max(axis=(1, 2)) / h ** 2
    return np.maximum(1, np.ceil(np.sqrt(c / (8.0 * tol_um)))).astype(int)


@dataclass
class ChainGCodeJob:
    """A parsed program with the vertices of every compensated move: ``vertices[i]`` (m_i, k)
    nominal axes, the last row the move's end; ``axes`` (n, k) all vertices in order and ``lines``
    (n,) the 1-based source line of each."""

    program: ChainProgram
    vertices: list
    axes: np.ndarray
    lines: np.ndarray
    arc_tolerance_um: float
    kept_lines: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    kept_axes: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def plan_chain_gcode(program: ChainProgram, arc_tolerance_um: float, field_=None) -> ChainGCodeJob:
    """Vertices of every compensated move: arcs in chords within ``arc_tolerance_um`` (axis space),
    and with ``field_`` every move split so the compensation between vertices stays within it too
    (:func:`field_pieces`)."""
    comp = [m for m in program.moves if m.compensate]
    tol_mm = arc_tolerance_um * 1e-3
    n_arc = np.array([arc_chords(m, tol_mm) if m.arc is not None else 1 for m in comp], dtype=int)
    with_start = [m for m in comp if np.all(np.isfinite(m.start))]
    n_fld = np.ones(len(comp), dtype=int)
    if field_ is not None and with_start:
        pieces = field_pieces(with_start, field_, arc_tolerance_um)
        pos = {id(m): p for m, p in zip(with_start, pieces)}
        n_fld = np.array([pos.get(id(m), 1) for m in comp], dtype=int)
    counts = np.maximum(n_arc, n_fld)
    big = np.flatnonzero(counts > MAX_SEGMENTS_PER_MOVE)
    if big.size:
        m = comp[big[0]]
        raise InputError(f"{program.path}: line {m.index + 1}: the move needs {counts[big[0]]} pieces for "
                         f"{arc_tolerance_um:g} μm (more than {MAX_SEGMENTS_PER_MOVE}); raise --arc-tolerance-um")
    verts = []
    for m, c in zip(comp, counts):
        if not np.all(np.isfinite(m.start)):
            verts.append(m.end[None, :].copy())
        else:
            verts.append(move_points(m, np.arange(1, c + 1) / c))
    axes = np.concatenate(verts) if verts else np.zeros((0, len(program.machine.axes)))
    lines = np.concatenate([np.full(len(v), m.index + 1) for m, v in zip(comp, verts)]) if verts else np.zeros(0, int)
    kept = [m for m in program.moves if not m.compensate]
    return ChainGCodeJob(program, verts, axes, lines, arc_tolerance_um,
                         np.array([m.index + 1 for m in kept], dtype=int),
                         np.array([m.end for m in kept]).reshape(len(kept), len(program.machine.axes)))


# ---------------------------------------------------------------------------- writing
def render_chain_program(program: ChainProgram, vertices: list, header=()) -> str:
    """The program with each compensated move's (compensated) vertices ``vertices[i]`` (m_i, k);
    every other line byte for byte (module docstring)."""
    comp = [m for m in program.moves if m.compensate]
    if len(vertices) != len(comp):
        raise ValueError(f"Expected vertices for {len(comp)} compensated moves, got {len(vertices)}")
    machine = program.machine
    groups = [[ln] for ln in program.lines]
    ctrl = np.full(len(machine.axes), np.nan)
    k = 0
    for m in program.moves:
        if not m.compensate:
            ctrl = _kept_position(m, ctrl, machine)
            continue
        q = np.asarray(vertices[k], dtype=float).reshape(-1, len(machine.axes))
        k += 1
        groups[m.index], ctrl = _render_move(program.lines[m.index], m, q, ctrl, machine)
    return _with_header([ln for g in groups for ln in g], header)


def _kept_position(m, ctrl, machine):
    out = ctrl.copy()
    scale = MM_PER_INCH if m.units == "inch" else 1.0
    for j, ax in enumerate(machine.axes):
        if ax.word in m.words:
            v = m.words[ax.word].value * (scale if ax.kind == "linear" else 1.0)
            out[j] = out[j] + v if m.incremental else v
    return out


def _written(row, ctrl, m, machine):
    scale = MM_PER_INCH if m.units == "inch" else 1.0
    vals, new = [], ctrl.copy()
    for j, ax in enumerate(machine.axes):
        s = scale if ax.kind == "linear" else 1.0
        dec = DECIMALS[m.units] if ax.kind == "linear" else DECIMALS["deg"]
        if m.incremental:
            txt = fmt((row[j] - ctrl[j]) / s, dec)
            new[j] = ctrl[j] + float(txt) * s
        else:
            txt = fmt(row[j] / s, dec)
            new[j] = float(txt) * s
        vals.append(txt)
    return vals, new


def _needed(j, vals, ctrl_before, m, machine) -> bool:
    """An axis word a written line must carry: a linear axis always (the correction moves it), a
    rotary one where its written value moves it."""
    ax = machine.axes[j]
    if ax.kind == "linear" or ax.word in m.words:
        return True
    return float(vals[j]) != 0.0 if m.incremental else not (np.isfinite(ctrl_before[j])
                                                           and abs(float(vals[j]) - ctrl_before[j]) < 1e-12)


def _render_move(line, m, q, ctrl, machine):
    if not np.all(np.isfinite(q)):
        raise ValueError(f"Expected finite vertices, got NaN/inf for line {m.index + 1}")
    body = line.rstrip("\r\n")
    ending = line[len(body):] or "\n"
    written, before = [], []
    for row in q:
        before.append(ctrl)
        vals, ctrl = _written(row, ctrl, m, machine)
        written.append(vals)
    first = _rewrite_line(body, m, written[0], before[0], machine)
    slash = "/" if body.lstrip(" \t").startswith("/") else ""
    extra = []
    for vals, c0 in zip(written[1:], before[1:]):
        extra.append(slash + " ".join(f"{ax.word}{vals[j]}" for j, ax in enumerate(machine.axes)
                                      if _needed(j, vals, c0, m, machine)) + ending)
    if extra and not line.endswith("\n"):
        return [first + ending] + extra[:-1] + [extra[-1][:-len(ending)]], ctrl
    return [first + line[len(body):]] + extra, ctrl


def _rewrite_line(body, m, vals, ctrl_before, machine) -> str:
    words = machine.axis_words
    kind = {a.word: a.kind for a in machine.axes}
    # a rotary word whose value is unchanged keeps its text as written (the orientation is the program's)
    edits = [(m.words[a].num_start, m.words[a].num_end, vals[j]) for j, a in enumerate(words) if a in m.words
             and not (kind[a] == "rotary" and float(vals[j]) == m.words[a].value)]
    last_end = max(m.words[a].num_end for a in words if a in m.words)
    missing = "".join(f" {a}{vals[j]}" for j, a in enumerate(words)
                      if a not in m.words and _needed(j, vals, ctrl_before, m, machine))
    if missing:
        edits.append((last_end, last_end, missing))
    if m.kind == "arc":
        if m.motion_word is not None:
            edits.append((m.motion_word.start, m.motion_word.num_end, "G1"))
        else:
            first = min(m.words[a].start for a in words if a in m.words)
            edits.append((first, first, "G1 "))
        for a in ("I", "J", "K", "R", "P"):
            if a in m.words:
                w = m.words[a]
                s = w.start - 1 if w.start > 0 and body[w.start - 1] in " \t" else w.start
                edits.append((s, w.num_end, ""))
    for s, e, txt in sorted(edits, key=lambda t: (t[0], t[1]), reverse=True):
        body = body[:s] + txt + body[e:]
    return body
