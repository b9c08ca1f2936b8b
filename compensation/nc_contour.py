"""Lathe contour cycles of Fanuc and Haas lathes whose contour is written in the program: ``G71`` (stock removal
in turning), ``G72`` (in facing), ``G73`` (pattern repeating) and ``G70`` (finishing), each with ``P(ns) Q(nf)``
naming the blocks ``N(ns)`` … ``N(nf)`` that hold the part's finished contour.

The contour is geometry, not the controller's passes: its blocks are read as the turning moves they are (X and Z
compensated while the spindle turns, like every turning move) and the cycle lines are kept as written. The
controller computes its roughing passes from the compensated contour (plus the U/W allowance) and ``G70`` runs the
compensated contour exactly. Rules read here (Fanuc 0i-TF operator's manual, "multiple repetitive cycles"; Haas
lathe operator's manual, G70-G73):

- the cycle's start point (the tool's position on the cycle line) is known;
- ``N(ns)`` is the block right after a ``G71``/``G72``/``G73`` line (blank and comment lines between are read over);
  ``N(nf)`` follows it; after ``N(nf)`` the tool is back at the start point (both manuals: the cycle returns there),
  and so after ``G70``; the G0-G3 in force after either is not read from the contour (the manuals do not say it):
  the next move must name its own;
- contour blocks hold motion (``G0``-``G3``, ``G40``-``G42``), axis, arc, ``F``, ``S`` and ``N`` words only (no
  ``T``, ``M``, other G codes or a nested cycle);
- ``G70 P Q`` names a contour a roughing cycle before it read (a G70 whose contour is written elsewhere is refused);
- two-block format ``G71 U(Δd) R(e)`` / ``G72 W(Δd) R(e)`` / ``G73 U(Δi) W(Δk) R(d)`` first blocks, and Haas'
  one-block ``D`` depth of cut, are kept as written (they set the controller's pass depths, not geometry).

Compensation must not break what the controller checks: a ``G71``/``G72`` contour monotonic along an axis as
programmed (type I: both; type II: Z for G71, X for G72) must stay monotonic in the same direction after compensation
(:func:`hold_back_steps`): where a compensated step goes back (a Z-only step whose X the compensation moves the other
way) by at most :data:`HOLD_UM` the point keeps the previous value on that axis (listed in the summary); by more, the
program is refused with the line, as the controller would alarm on it.

With ``--expand-cycles`` (:func:`expand_finishing`) the roughing cycles and their contours are written as they are,
uncompensated (the controller roughs from the programmed contour), and each ``G70`` becomes the moves it makes: its
contour's lines, compensated point by point with no monotonic rule, then a ``G0`` back to its start point."""
from __future__ import annotations

import dataclasses

import numpy as np

from .gcode_state import MM_PER_INCH, _Refuse
from .nc_expand import Expanded, source_line
from .nc_notes import line_span, note

CONTOUR_DIALECTS = ("fanuc", "haas")
ROUGHING = {"G71": "stock removal in turning", "G72": "stock removal in facing", "G73": "pattern repeating"}
CYCLE_CODES = ("G70",) + tuple(ROUGHING)
CYCLE_LETTERS = frozenset("NGPQUWRDFSIK")
"""Words a cycle line may hold: P Q (contour), U W (allowance, or the first block's depths), R (retract or
division count), D (Haas depth of cut), I K (Haas rough allowance), F S (the cycle's feed and speed)."""
FIRST_BLOCK = {"G71": frozenset("NGUR"), "G72": frozenset("NGWR"), "G73": frozenset("NGUWR")}
"""The first block of the two-block format (no P Q): depth of cut and retract, or G73's relief and count."""
CONTOUR_LETTERS = frozenset("NGXZUWIKRFS")
CONTOUR_G = ("G0", "G1", "G2", "G3", "G40", "G41", "G42")
MAIN_AXIS = {"G71": "Z", "G72": "X"}
"""The axis a type II contour must keep monotonic (it may have pockets across it: Fanuc 0i-TF, Haas lathe manual)."""
MONOTONIC_TOL_MM = 1e-6
"""A compensated step against the contour's direction smaller than this (1 nm: the written resolution) is none."""
HOLD_UM = 0.5
"""A compensated back-step along a contour's monotonic axis up to this is written as no step (half the least input
increment, 0.001 mm, of a Fanuc or Haas control in mm: a step the control's rounding may show either way); the
point's error that leaves is in the TRUE and model residuals (the points are checked to 1 um)."""


@dataclasses.dataclass
class Contour:
    """One contour cycle: its line (0-based), code, blocks ``N(ns)``…``N(nf)``, start point (X, Z mm) and the
    lines its blocks span (0-based, ``first``…``last``); ``kind``: ``type I``/``type II`` (G71/G72), ``""`` (G73):
    type II where ``N(ns)`` gives both axes (Fanuc 0i-TF) and, on Haas, the cycle line has ``R1`` (its type II
    selection; without it the contour is checked as type I, the stricter reading)."""
    code: str
    line: int
    col: int
    ns: int
    nf: int
    start: np.ndarray
    first: int = -1
    last: int = -1
    kind: str = ""
    points: list = dataclasses.field(default_factory=list)
    type2_ok: bool = True


class ContourState:
    """The contour cycles of one program read so far (``pending``: a cycle line waiting for its ``N(ns)``;
    ``active``: blocks being read; ``done``: ``{(ns, nf): Contour}``)."""

    def __init__(self):
        self.pending = self.active = None
        self.done = {}


def applies(st, ax) -> bool:
    """Contour cycles are read on a Fanuc or Haas lathe (X and Z words, no Y)."""
    from .nc_state import lathe_words
    return getattr(st.dialect, "name", None) in CONTOUR_DIALECTS and lathe_words(ax.words)


def _xz(st, ax) -> np.ndarray:
    return np.array([st.pos[ax.words.index("X")], st.pos[ax.words.index("Z")]], dtype=float)


def cycle_line(words, idx: int, st, ax) -> str | None:
    """``"state"`` for a contour cycle line (kept as written; the state records the cycle), None for any other
    line (read as usual; its N word checked against an open cycle's contour)."""
    cs = st.contours
    g = [w for w in words if w.letter == "G" and w.code in CYCLE_CODES]
    if not g or not applies(st, ax):
        if cs.pending is not None or cs.active is not None:
            _contour_block(words, cs, st.name)
        return None
    w = g[0]
    if cs.pending is not None or cs.active is not None:
        c = cs.pending or cs.active
        raise _Refuse(w.start + 1, f"'{w.code}' inside the contour blocks N{c.ns}-N{c.nf} of the {c.code} on line "
                                   f"{st.name(c.line + 1)}: a cycle may not be nested; end the contour (N{c.nf}) first")
    by = {}
    for x in words:
        if x.letter not in CYCLE_LETTERS or (x.letter == "G" and x is not w):
            raise _Refuse(x.start + 1, f"'{x.letter}{x.text}' on a {w.code} cycle line: only "
                                       f"{' '.join(sorted(CYCLE_LETTERS - {'G', 'N'}))} words are read there "
                                       "(write other words on a line of their own)")
        by[x.letter] = x
    if "P" not in by and "Q" not in by:
        bare = set(by) <= {"G", "N"}
        if w.code == "G70" or bare or not set(by) <= FIRST_BLOCK[w.code]:
            sys_c = (" (in Fanuc G-code system C, a parameter, G70/G71 are inch/mm input: write G20/G21)"
                     if bare and w.code in ("G70", "G71") and st.dialect.name == "fanuc" else "")
            raise _Refuse(w.start + 1, f"'{w.code}' on a {st.dialect.name} lathe: a contour cycle needs P(ns) and "
                                       f"Q(nf), its contour's first and last block numbers{sys_c}")
        return "state"  # the two-block format's first block: pass depths, kept as written
    if "P" not in by or "Q" not in by or any(by[k].value != int(by[k].value) or by[k].value <= 0 for k in "PQ"):
        raise _Refuse(w.start + 1, f"'{w.code}' needs whole positive P(ns) and Q(nf) block numbers")
    ns, nf = int(by["P"].value), int(by["Q"].value)
    if w.code == "G70":
        c = cs.done.get((ns, nf))
        if c is None:
            raise _Refuse(by["P"].start + 1, f"'G70 P{ns} Q{nf}': no G71/G72/G73 before it read the contour "
                                             f"N{ns}-N{nf}; a G70 is read only after the roughing cycle whose contour "
                                             "blocks follow it")
        st.events.append((idx, w.start + 1, "lathe-finish", (c.first + 1, c.last + 1, idx + 1, _xz(st, ax),
                                                             st.inch, st.diameter, st.incremental, ns, nf), "G70"))
        st.events.append((idx, w.start + 1, "lathe-cycle", "G70",
                          note("line ", idx + 1, f": G70 P{ns} Q{nf}: finishing pass: exactly the compensated contour "
                               "(lines ", (c.first + 1, c.last + 1), ")")))
        st.mode = None  # as after N(nf): the next move names its G0-G3
        return "state"
    start = _xz(st, ax)
    if not np.isfinite(start).all():
        raise _Refuse(w.start + 1, f"'{w.code}': the cycle's start point (the tool's X and Z on this line) is not "
                                   "known: give X and Z on a line before the cycle")
    cs.pending = Contour(w.code, idx, w.start + 1, ns, nf, start)
    cs.pending.type2_ok = st.dialect.name != "haas" or ("R" in by and by["R"].value == 1)  # Haas: R1 selects type II
    st.events.append((idx, w.start + 1, "contour-open", (ns, nf), w.code))
    return "state"


def _contour_block(words, cs: ContourState, name) -> None:
    """A line while a cycle's contour is open: ``N(ns)`` must come first; contour words only. ``name`` names the
    cycle's 1-based line in a refusal (the reader's: :func:`compensation.nc_expand.source_line`)."""
    if not words:
        return  # a blank or comment line
    n = next((x for x in words if x.letter == "N"), None)
    if cs.pending is not None:
        c = cs.pending
        if n is None or n.value != c.ns:
            raise _Refuse(words[0].start + 1, f"the {c.code} on line {name(c.line + 1)} names its contour's first "
                                              f"block N{c.ns}: that block must follow the cycle line; this line is "
                                              "not it")
        given = {x.letter for x in words} & set("XZUW")
        if not given:
            raise _Refuse(words[0].start + 1, f"N{c.ns}, the first block of the {c.code} contour, moves neither X "
                                              "nor Z")
        if c.code in ("G71", "G72"):
            across = {"G71": set("XU"), "G72": set("ZW")}[c.code]
            c.kind = "type II" if (given - across) and c.type2_ok else "type I"  # else checked as type I (stricter)
            if not given & across:
                raise _Refuse(words[0].start + 1, f"N{c.ns}, the first block of a {c.code} contour, gives no "
                                                  f"{'X' if c.code == 'G71' else 'Z'} (the manuals' rule)")
        cs.active, cs.pending = c, None
    for x in words:
        if x.letter not in CONTOUR_LETTERS or (x.letter == "G" and x.code not in CONTOUR_G):
            c = cs.active
            raise _Refuse(x.start + 1, f"'{x.letter}{x.text}' in the contour blocks N{c.ns}-N{c.nf} of the {c.code} "
                                       f"on line {name(c.line + 1)}: only G0-G3, G40-G42, axis, arc, F, S, N words "
                                       "there")


def after_line(words, idx: int, st, ax, move=None) -> None:
    """After a contour block was read (``move``: its GMove or None): its end point recorded; after ``N(nf)`` the
    contour closed (the move marked ``block_end``) and the tool back at the cycle's start point."""
    cs = getattr(st, "contours", None)
    c = None if cs is None else cs.active
    if c is None:
        return
    if c.first < 0:
        c.first = idx
    if any(x.letter in "XZUW" for x in words):
        c.points.append(_xz(st, ax))
    n = next((x for x in words if x.letter == "N"), None)
    if n is None or n.value != c.nf:
        return
    c.last = idx
    if move is not None:
        move.block_end = True
    cs.done[(c.ns, c.nf)] = c
    cs.active = None
    st.mode = None  # which G0-G3 the control keeps after the cycle the manuals leave open: the next move names it
    st.pos = np.array(st.pos, dtype=float)  # a new array: the moves read hold the old one as their end
    for j, a in enumerate(("X", "Z")):
        st.pos[ax.words.index(a)] = c.start[j]
    what = ROUGHING[c.code] + (f", {c.kind}" if c.kind else "")
    st.events.append((idx, c.col, "lathe-cycle", c.code,  # at N(nf): the events stay in line order
                      note("line ", c.line + 1, f": {c.code} P{c.ns} Q{c.nf} ({what}): roughing passes computed by the "
                           "controller from the compensated contour (lines ", (c.first + 1, c.last + 1), ") plus its "
                           "U/W allowance")))
    st.events.append((idx, c.col, "lathe-contour", (c.first + 1, c.last + 1, c.line + 1, c.kind, c.ns, c.nf), c.code))


def refuse_open(path, events) -> None:
    """Refuse (InputError) a program whose contour cycle's ``N(nf)`` (or ``N(ns)``) never came."""
    from errormap.io import InputError
    closed = {(e[3][2] - 1) for e in events if e[2] == "lathe-contour"}
    for line, col, kind, (ns, nf), code in (e for e in events if e[2] == "contour-open"):
        if line not in closed:
            raise InputError(f"{path}: line {line + 1}, column {col}: '{code} P{ns} Q{nf}': the contour's blocks "
                             f"N{ns}-N{nf} do not follow it to the end (N{nf} not found); write them after the cycle")


def _direction(steps: np.ndarray) -> int:
    """+1 / -1 where every non-zero step of ``steps`` (m,) has that sign (monotonic), 0 otherwise."""
    nz = steps[np.abs(steps) > MONOTONIC_TOL_MM]
    if nz.size == 0 or not ((nz > 0).all() or (nz < 0).all()):
        return 0
    return 1 if nz[0] > 0 else -1


def hold_back_steps(path, events, lines, axes_d, axes, x_col: int, z_col: int, name=int) -> tuple:
    """A ``G71``/``G72`` contour monotonic along an axis the control checks (type I: X and Z; type II:
    :data:`MAIN_AXIS`) as programmed (:func:`_direction`) kept monotonic after compensation: a compensated step
    back along it of at most :data:`HOLD_UM` is written as no step (the point takes
    the previous point's value on that axis); a larger one is refused (InputError, the line and axis: the controller
    would alarm). ``lines`` (n,) 1-based line of each compensated point (of the program read: ``name(line)`` as the
    summary and the refusal name it, :func:`compensation.nc_expand.source_line`), ``axes_d``/``axes`` (n, k)
    programmed / compensated machine axes. Returns ``(axes (n, k), rows changed, [summary line per hold])``."""
    from errormap.io import InputError
    lines, out, held, rows = np.asarray(lines), np.array(axes, dtype=float), [], []
    for _, _, kind, span, code in events:
        if kind != "lathe-contour" or code not in ("G71", "G72"):
            continue
        sel = np.flatnonzero((lines >= span[0]) & (lines <= span[1]))
        checked = ("X", "Z") if span[3] == "type I" else (MAIN_AXIS[code],)  # type II: pockets across
        for axis, col in ((a, x_col if a == "X" else z_col) for a in checked):
            d = _direction(np.diff(axes_d[sel, col]))
            for a, b in zip(sel[:-1], sel[1:]) if d else ():
                back_um = -(out[b, col] - out[a, col]) * d * 1e3
                if back_um <= MONOTONIC_TOL_MM * 1e3:
                    continue
                if back_um > HOLD_UM:
                    raise InputError(f"{path}: line {int(lines[b])}: compensation moves {axis} back by {back_um:.3g} "
                                     f"um in the {code} contour of line {name(span[2])}, monotonic in {axis} as "
                                     f"programmed (the controller would alarm; up to {HOLD_UM:g} um is held); use "
                                     "--expand-cycles (G70 written as its moves), G73, or post the passes as G1/G2/G3")
                out[b, col] = out[a, col]
                rows.append(b)
                held.append(f"line {name(int(lines[b]))}: {axis} held at the previous point's ({back_um:.3g} um "
                            f"back-step of the {code} contour of line {name(span[2])})")
    return out, np.unique(np.array(rows, dtype=np.intp)), held


def refuse_other_tool(path, events, lines, contour_tool, finish_tool, name=int) -> None:
    """Refuse (InputError) a ``G70`` whose tool offsets (X, Z mm) differ from those its contour was compensated at
    (the roughing cycle's tool): its points would be the other tool's. ``lines`` (n,) 1-based line of each
    compensated point, ``contour_tool`` (n, 2) their tool offsets (NaN: none), ``finish_tool(line)`` (2,) the
    offsets in force on a 1-based line; ``name`` names the contour's lines (:func:`hold_back_steps`)."""
    from errormap.io import InputError
    lines = np.asarray(lines)
    for _, col, kind, span, _ in events:
        if kind != "lathe-finish":
            continue
        sel = np.flatnonzero((lines >= span[0]) & (lines <= span[1]))
        at = np.asarray(finish_tool(span[2]), dtype=float)
        for t in np.asarray(contour_tool, dtype=float)[sel]:
            if not np.allclose(np.nan_to_num(t, nan=np.inf), np.nan_to_num(at, nan=np.inf), rtol=0, atol=1e-9):
                raise InputError(f"{path}: line {span[2]}, column {col}: 'G70': its tool's offsets (X, Z) "
                                 f"{np.round(at, 6).tolist()} mm differ from the contour's (lines "
                                 f"{line_span(name(span[0]), name(span[1]))}: {np.round(t, 6).tolist()} mm), "
                                 "compensated for the roughing tool; use --expand-cycles (G70 as its moves, at its "
                                 "tool's offsets) or give both the same offsets")


FEED_WORDS = ("F", "S")
"""Fanuc 0i-TF (G70): the F, S (and T) of the blocks N(ns)-N(nf) are the ones in effect during G70; which F and S
the control has before the contour's first and after its finishing pass the manual does not say: the expansion
refuses a feed move that would run on them (:func:`_feed_refusals`)."""


@dataclasses.dataclass(frozen=True)
class LatheExpansion(Expanded):
    """:class:`compensation.nc_expand.Expanded` of a lathe program whose cycle lines of one kind are written as the
    controller's moves (:func:`expand_lines`): ``count`` the lines expanded, ``inner`` the expansion before it (None:
    the program as read); ``WHAT`` the written header's words on them (``{n}``: ``count``)."""

    count: int = 0
    inner: object = None
    WHAT = ""

    def note(self) -> str:
        head = self.inner.note() + "; " if self.inner is not None else "volcomp: "
        return head + self.WHAT.format(n=self.count)


@dataclasses.dataclass(frozen=True)
class FinishExpansion(LatheExpansion):
    """G70 lines written as the controller's moves (:func:`expand_finishing`)."""

    WHAT = ("lathe G70 finishing cycles written as the controller's moves ({n}: the contour's blocks, then G0 back to "
            "the start point); G71/G72/G73 and their contours kept")


def _word_text(v: float) -> str:
    s = f"{v:.7f}".rstrip("0")
    return "0." if s in ("-0.", "0.") else s


def _feed_refusals(path, lines, first: int, last: int, g70: int, g70_named: int) -> None:
    """Refuse (InputError) a G70 expansion whose feed moves would run at an F or S the manual leaves open
    (:data:`FEED_WORDS`): a G1-G3 block of the contour before its first F, or, where the contour gives F (S), a
    G1-G3 block after the G70 before the program's next F (S). ``first``/``last``/``g70`` 0-based lines,
    ``g70_named`` the G70's line as the messages name it (:func:`compensation.nc_expand.source_line`)."""
    from errormap.io import InputError
    from .gcode_words import tokenize

    def words(i):
        try:
            return tokenize(lines[i].rstrip("\r\n"))[1]
        except _Refuse:
            return ()

    given, mode = set(), None
    for i in range(first, last + 1):
        ws = words(i)
        mode = next((w.code for w in ws if w.letter == "G" and w.code in ("G0", "G1", "G2", "G3")), mode)
        given |= {w.letter for w in ws if w.letter in FEED_WORDS}
        if mode in ("G1", "G2", "G3") and "F" not in given and any(w.letter in "XZUW" for w in ws):
            raise InputError(f"{path}: line {i + 1}: a feed block of the G70 on line {g70_named} before any F of its "
                             "contour: its feed in G70 the manual does not say; give F on N(ns) or leave "
                             "--expand-cycles out")
    for i in range(g70 + 1, len(lines)):
        ws = words(i)
        open_ = given - {w.letter for w in ws}
        if any(w.letter == "G" and w.code in ("G1", "G2", "G3") for w in ws) and open_:
            raise InputError(f"{path}: line {i + 1}: a feed block after the expanded G70 of line {g70_named} before "
                             f"the program gives {' and '.join(sorted(open_))} again: which the control has after "
                             f"G70 the manual does not say; give {' '.join(sorted(open_))} here or leave "
                             "--expand-cycles out")
        given -= {w.letter for w in ws}
        if not given:
            return


def expand_finishing(prog, path, reparse):
    """``prog`` (a lathe program read with its contour cycles, :func:`cycle_line`) with every ``G70 P Q`` that a
    roughing cycle's contour precedes written as the moves G70 makes (``--expand-cycles``, :func:`_finish_lines`);
    the roughing cycles and their contour blocks kept as written (:func:`_roughing_as_written`). ``reparse(text)``
    reads the expanded text (a GProgram); returns ``prog`` where there is no G70 to expand."""
    finishes = {e[0]: e for e in prog.events if e[2] == "lathe-finish"}
    if not finishes:
        return prog
    return expand_lines(_roughing_as_written(prog), path, reparse, finishes,
                        lambda i: _finish_lines(prog, path, finishes[i]), FinishExpansion)


def expand_lines(prog, path, reparse, by_line, lines_of, cls, compensated: bool = False):
    """The one step that writes a lathe program's cycles of one kind as the controller's moves (``--expand-cycles``:
    G70 :func:`expand_finishing`, G92 :func:`compensation.nc_thread.expand_threading`, G74/G75
    :func:`compensation.nc_groove.expand_grooves`): ``prog``'s text with each line ``i`` of ``by_line`` (its event:
    column ``[1]``, code ``[4]``) replaced by the lines ``lines_of(i) -> (lines, summary note)`` give (the note a
    :class:`compensation.nc_notes.LineNote` at ``prog``'s lines; an InputError named at ``prog``'s line, re-addressed
    here to the source), read again by ``reparse(text)`` with its expansion (a :class:`LatheExpansion` ``cls``)
    attached, and what ``prog`` held beyond its text carried (:func:`_carry`); ``compensated``: every move of the lines
    written compensated (else as read). Returns the program read."""
    from errormap.io import InputError
    inner = prog.expanded
    src = (lambda i: inner.origin[i]) if inner is not None else (lambda i: (i + 1, True, ()))
    text, origin, copied, added, notes, at = [], [], {}, set(), [], {}
    for i, line in enumerate(prog.lines):
        at[i + 1] = len(text) + 1  # prog's line i + 1 in the text written: the first of its lines there
        if i not in by_line:
            copied[len(text)] = i
            text.append(line)
            origin.append(src(i))
            continue
        try:
            new, written = lines_of(i)
        except InputError as exc:  # on the flat lines of a program whose calls were expanded: named at the source
            raise (inner.relocate(exc) if inner is not None else exc) from None
        notes.append((len(text), by_line[i][1], "lathe-cycle", by_line[i][4], written))
        if compensated:
            added.update(range(len(text), len(text) + len(new)))
        text += new
        origin += [(src(i)[0], False, src(i)[2])] * len(new)
    exp = cls("".join(text), tuple(origin), prog.dialect, str(path), getattr(inner, "files", ()),
              count=len(by_line), inner=inner)
    try:
        out = reparse(exp.text)
    except InputError as exc:
        raise exp.relocate(exc) from None
    out.expanded = exp
    return _carry(prog, out, copied, added, notes, at.__getitem__)


def _carry(prog, out, copied: dict, added: set, notes: list, to):
    """``out`` (:func:`expand_lines`' text read) with what ``prog`` held beyond its text: the moves of each copied
    line (``copied``: output line to ``prog``'s line) compensated or not as ``prog``'s were (an earlier step's
    roughing contour stays as written), those of the ``added`` output lines compensated; its cycle notes ``prog``'s
    of the copied lines and ``notes`` (the written lines'), in output line order, their lines moved to ``out``'s by
    ``to`` (1-based; :meth:`compensation.nc_notes.LineNote.moved`; ``out``'s reading's own dropped: it sees neither
    the cycles written nor what an earlier step decided)."""
    flags = {}
    for m in prog.moves:
        flags.setdefault(m.index, []).append(m.compensate)
    seen = {}
    for m in out.moves:
        if m.index in added:
            m.compensate = True
        elif m.index in copied:
            k = seen[m.index] = seen.get(m.index, -1) + 1
            was = flags.get(copied[m.index], ())
            m.compensate = was[k] if k < len(was) else m.compensate
    at = {i: j for j, i in copied.items()}
    kept = [(at[e[0]],) + tuple(e[1:]) for e in prog.events if e[2] == "lathe-cycle" and e[0] in at]
    notes = sorted([e[:4] + (e[4].moved(to),) for e in kept + notes], key=lambda e: e[0])
    out.events = tuple(e for e in out.events if e[2] != "lathe-cycle") + tuple(notes)
    return out


def _finish_lines(prog, path, e) -> tuple:
    """``(lines, summary note)`` of the G70 of event ``e`` as the controller runs it: a copy of its contour's lines
    (their leading ``N`` word dropped; the G70 line's own on the first), then ``G0`` to the G70's start point in
    absolute X Z words. Refused (InputError): a G70 under incremental distance (``G91``) or from an unknown position,
    a G70 line with other words than ``N G P Q``, an F/S the manual leaves open (:func:`_feed_refusals`)."""
    import re
    from errormap.io import InputError
    from .gcode_words import tokenize
    i, lines = e[0], prog.lines
    line = lines[i]
    path = prog.expanded.path if prog.expanded is not None else path  # its flat lines (expand_lines re-addresses)
    first, last, _, start, inch, diameter, incremental, ns, nf = e[3]
    if incremental or not np.isfinite(start).all():
        raise InputError(f"{path}: line {i + 1}, column {e[1]}: 'G70': its start point is not known in absolute X Z "
                         "(incremental distance mode or an unknown position): leave --expand-cycles out")
    other = [w for w in tokenize(line.rstrip("\r\n"))[1] if w.letter not in "NGPQ"]
    if other:
        raise InputError(f"{path}: line {i + 1}, column {other[0].start + 1}: '{other[0].letter}{other[0].text}' on "
                         "a G70 line: the manuals' G70 is 'G70 P(ns) Q(nf)' (F S T from its contour): leave "
                         "--expand-cycles out")
    _feed_refusals(path, lines, first - 1, last - 1, i, source_line(prog, i + 1))
    n = re.match(r"[ \t/]*([nN]\s*\d+\s*)?", line).group(1) or ""
    out = [re.sub(r"^([ \t/]*)([nN]\s*\d+\s*)?", lambda m, j=j: m.group(1) + (n if j == first - 1 else ""),
                  lines[j], count=1) for j in range(first - 1, last)]
    unit = MM_PER_INCH if inch else 1.0
    ending = line[len(line.rstrip("\r\n")):] or "\n"
    out.append(f"G00 X{_word_text(start[0] * (2.0 if diameter else 1.0) / unit)} Z{_word_text(start[1] / unit)}"
               + ending)
    return out, note("line ", i + 1, f": G70 P{ns} Q{nf} expanded: the contour's blocks (lines ", (first, last),
                     f") written as their {last - first + 1} line(s) of moves, compensated point by point, then G0 "
                     "back to its start point")


def _roughing_as_written(prog):
    """``prog`` (as read) with its roughing cycles as :func:`expand_finishing` writes them: their contours' moves
    uncompensated (the controller roughs from the programmed contour) and their cycle notes saying so (at the cycle
    line; :func:`expand_lines` carries both)."""
    spans = [e for e in prog.events if e[2] == "lathe-contour"]
    for m in prog.moves:
        if any(e[3][0] - 1 <= m.index <= e[3][1] - 1 for e in spans):
            m.compensate = False
    notes = [(e[3][2] - 1, e[1], "lathe-cycle", e[4],
              note("line ", e[3][2], f": {e[4]} P{e[3][4]} Q{e[3][5]} ({ROUGHING[e[4]]}"
                   f"{', ' + e[3][3] if e[3][3] else ''}): kept as written with its contour (lines ", e[3][:2],
                   ") uncompensated: the controller roughs from the programmed contour, leaving its U/W allowance "
                   "(roughing accuracy is not the part's)"))
             for e in spans]
    prog.events = tuple(e for e in prog.events if e[2] != "lathe-cycle" or e[3] not in ROUGHING) + tuple(notes)
    return prog
