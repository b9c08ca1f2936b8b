"""Lathe threading: Fanuc/Haas ``G32`` thread cutting and LinuxCNC ``G33`` compensated exactly, ``G92`` (thread cutting
cycle) and LinuxCNC's ``G76`` (:mod:`compensation.nc_g76`) written as their passes' moves with ``--expand-cycles``,
Fanuc/Haas ``G76`` refused.

Rules read (Fanuc 0i-TF operator's manual, G-code system A, "thread cutting (G32)", "thread cutting cycle (G92)",
"multiple threading cycle (G76)"; Haas lathe operator's manual, "G32 Thread Cutting (Group 01)", "G76 Threading
Cycle, Multiple Pass"):

- ``G32 X(U) Z(W) F``: a straight line synchronised with the spindle; ``F`` the lead, the travel per revolution
  along the axis of the larger travel (Z where the taper is at most 45°; Haas: "set the feedrate to the larger of
  the two leads"), in radius. G32 is modal (group 01). Consecutive G32 blocks are one continuous thread: the
  spindle's index synchronises the first, the others follow without re-synchronising (Haas: "this synchronization
  remains in effect for each line in a G32 sequence"; Fanuc: continuous thread cutting). Chamfering (M23/M24) does
  not act on G32. ``Q`` (the start angle of a multi-start thread) and ``E`` are not read (refused).
- ``G92 X Z F`` (Fanuc; 30i-A user's manual B-63944EN-1, 4.1.2 "Threading cycle (G92)", operations 1-4): rapid
  along X from the start point A to X, thread (as G32) to Z, rapid along X back to A's X, rapid along Z back to A's
  Z; the thread chamfer at the end of operation 2 has the control's amount (parameter 5130), written here as none;
  modal: a following line with X alone is one more pass (Z and F kept). ``R``
  (taper), ``U``/``W`` and Haas' G92 (its ``I`` taper and M23 chamfer-out) are not read here (refused).
- Fanuc/Haas ``G76``: the passes (depths Δd·√n, the infeed along the flank, the chamfer r) are the control's:
  refused in both modes (post the passes as G32 or G92 lines). LinuxCNC's ``G76`` is defined in its interpreter's
  source: read (:mod:`compensation.nc_g76`).

Compensation (:func:`lead_texts`): the machine's true tool position is the commanded one plus the error there, so a
synchronised piece from compensated A' to B' travels the programmed A to B on the true machine while the control
moves the commanded distance per revolution F': the true lead is F' × (true travel / commanded travel) along the
lead axis. Each piece is written with ``F' = F × commanded travel / programmed travel`` (its true lead is F), and a
G32 block is split into consecutive G32 pieces (continuous threading) as every move is split
(:func:`compensation.chain_gcode.plan_chain_gcode`: the field's curvature within ``--arc-tolerance-um``, or
``--max-segment-mm``), each with its own F'. The move that ends at a thread's start point is compensated even
where ``--rapids keep`` keeps rapids (the start is where the spindle's index synchronises the pass: a start off by
the error there shifts the thread's phase); so every pass of a thread starts where the TRUE machine is at the
programmed start, whatever pass depth X the error there depends on: the passes' phases match. After a thread the
modal F is the last piece's F': the next feed move without F gets the programmed F back (:func:`restore_feed`)."""
from __future__ import annotations

import dataclasses

import numpy as np

from .gcode_state import MM_PER_INCH, _Refuse
from .nc_contour import LatheExpansion, _word_text, expand_lines
from .nc_expand import source_line
from .nc_g76 import g76_lines
from .nc_notes import note

THREADING = {"G32": "thread cutting", "G92": "thread cutting cycle", "G76": "multiple threading cycle"}
"""Fanuc/Haas lathe threading codes (Fanuc 0i-TF G-code system A, Haas lathe manual)."""
LEAD_DECIMALS = {"mm": 6, "inch": 7}
"""Decimals of a written lead F' (1 nm, 0.1 μin per revolution, as the axis words): its rounding changes a piece's
lead by at most 0.5e-6 mm (0.5e-7 in) per revolution. A control whose F input increment is coarser (Fanuc IS-B
threading: 0.0001 mm) rounds it further: that rounding is the control's, not the compensation's."""
LEAD_TOL_REL = 1e-5
"""A written piece's TRUE lead equals the programmed F within this share of F: the F' rounding (0.5e-6 mm, ≤ 5e-6 of
a lead ≥ 0.1 mm) plus the end points' error (each ≤ 0.5 nm written rounding + 1e-4 μm solver residual) over a piece
of at least 1 mm (≤ 1.2e-6), with margin. Over a thread the axial error of the cut helix is bounded by the position
tolerance at every piece's end (the ends are exact) and by LEAD_TOL_REL × a piece's length between them."""
LEAD_WORD = {"G32": "F", "G33": "K", "G33.1": "K"}
"""The word that holds a synchronised move's lead (Fanuc/Haas G32: F; LinuxCNC G33, G33.1: K)."""
SPLIT = ("G32", "G33")
"""Synchronised moves split into consecutive pieces, each with its own lead: the control keeps the synchronisation
from one to the next (module docstring); a G33.1 (a tap and its return) is one move."""
RAPID_NOTE = "compensated: its end is a thread's start (the spindle's index synchronises the pass there)"


def g32_move(st, by, ax, move, prev) -> None:
    """The lead of a ``G32`` move read (:func:`compensation.gcode_classify.synced_move`): ``move.lead`` set to
    ``(F value, F text, lead axis column)``; the move before it, a rapid kept as written, made compensated (module
    docstring). Refused: a G32 off a lathe, without a lead (no F on it and none from a G32 before it), from an
    unknown position, or at 45° (the lead axis undecided)."""
    from .nc_state import lathe_words
    col = (move.motion_word or next(iter(move.words.values()))).start + 1
    if not lathe_words(ax.words):
        raise _Refuse(col, "'G32' (thread cutting) is read on a lathe only")
    if "F" in by:
        if not by["F"].value > 0:
            raise _Refuse(by["F"].start + 1, f"'F{by['F'].text}': a thread's lead must be positive")
        st.thread_lead = (by["F"].value, by["F"].text)
    if st.thread_lead is None:
        raise _Refuse(col, "'G32' without F (the lead): give F on the line (an F of another move before it is not "
                           "taken as a lead here)")
    if not move.start_known:
        raise _Refuse(col, "'G32' from an unknown position: give X and Z before the thread")
    jx, jz = ax.words.index("X"), ax.words.index("Z")
    d = np.abs(move.end - move.start)
    if abs(d[jx] - d[jz]) <= 1e-9 * max(1.0, d.max()):
        raise _Refuse(col, "'G32' at 45°: its lead axis (the one of the larger travel) is not decided; thread at "
                           "another angle")
    move.lead = (by["F"].value if "F" in by else st.thread_lead[0], st.thread_lead[1],
                 jz if d[jz] > d[jx] else jx)
    _start_compensated(st, prev, move)


def g33_move(st, by, ax, move, prev) -> None:
    """The lead of a LinuxCNC ``G33``/``G33.1`` move read (:func:`compensation.gcode_classify.synced_move`, its K
    checked by :func:`compensation.gcode_state.synced_words`): ``move.lead`` set to ``(K value, K text, drive-line
    columns)``, K the distance per revolution along the drive line X Y Z (LinuxCNC G-code reference: "K follows the
    drive line described by X- Y- Z-"); the rapid before it made compensated (module docstring). Refused: from an
    unknown position, or moving a rotary axis (K's drive line is X Y Z: a rotary word's share is not read)."""
    col = (move.motion_word or next(iter(move.words.values()))).start + 1
    if not move.start_known:
        raise _Refuse(col, f"'{move.synced}' from an unknown position: give {ax.joined('and')} before it")
    rot = [a for j, a in enumerate(ax.words) if a in ax.rotary and move.end[j] != move.start[j]]
    if rot:
        w = move.words[rot[0]]
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {move.synced} line: K follows the drive line X Y Z; "
                                   "a synchronised rotary move is not read: move the rotary axis on a line of its own")
    cols = tuple(j for j, a in enumerate(ax.words) if a in "XYZ" and move.end[j] != move.start[j])
    if not cols:
        raise _Refuse(col, f"'{move.synced}' that moves none of X Y Z (its drive line)")
    move.lead = (by["K"].value, by["K"].text, cols)
    _start_compensated(st, prev, move)


def _start_compensated(st, prev, move) -> None:
    """The move before a synchronised ``move`` (``prev``, None: none), a rapid kept as written that ends at its
    start, made compensated (module docstring), with the summary's note."""
    if prev is not None and not prev.compensate and prev.kind == "rapid" and np.array_equal(prev.end, move.start):
        prev.compensate = True
        st.events.append((prev.index, 1, "lathe-cycle", move.synced,
                          note("line ", prev.index + 1, f": rapid {RAPID_NOTE}")))


def feed_word_seen(st, by, code) -> None:
    """An F word on a line that is not a G32 move (a feed, another cycle's F): the next G32 must give its lead."""
    if "F" in by and code != "G32":
        st.thread_lead = None


def lead_texts(m, before, after, units: str) -> list:
    """The lead text (F' of a G32, K' of a G33/G33.1) of each written piece of the synchronised move ``m`` (module
    docstring): ``before``/``after`` (c, k) the controller's positions before and after each written piece (mm, as
    written); ValueError where a piece's lead axis differs from the block's (a G32 taper near 45°), or a piece does
    not move along it (or, a G33's, along its drive line)."""
    f, _, j = m.lead
    before, after = np.asarray(before, float), np.asarray(after, float)
    if not (np.isfinite(before).all() and np.isfinite(after).all()):
        raise ValueError(f"line {m.index + 1}: a {m.synced} whose start the written program does not fix (a position "
                         "not known before it): give its axes absolutely before the thread")
    c = len(after)
    prog = (m.end - m.start) / c
    cmd = after - before
    if isinstance(j, tuple):  # LinuxCNC: K along the drive line X Y Z
        ratio = np.linalg.norm(cmd[:, j], axis=1) / np.linalg.norm(prog[list(j)])
        if not np.all(cmd[:, j] @ prog[list(j)] > 0):
            raise ValueError(f"line {m.index + 1}: a compensated {m.synced} piece that does not move along its "
                             "drive line")
        return [f"{v:.{LEAD_DECIMALS[units]}f}" for v in f * ratio]
    other = 1 - j if len(m.end) == 2 else [k for k in range(len(m.end)) if k != j and abs(m.end[k] - m.start[k])
                                             > 0][:1] or [j]
    across = np.abs(after[:, other] - before[:, other]).reshape(c, -1).max(axis=1)
    if not (np.all(np.sign(cmd[:, j]) == np.sign(prog[j])) and np.all(np.abs(cmd[:, j]) > across)):
        raise ValueError(f"line {m.index + 1}: a compensated G32 piece whose lead axis is not the block's (a taper "
                         "near 45°): thread at another angle")
    return [f"{v:.{LEAD_DECIMALS[units]}f}" for v in f * cmd[:, j] / prog[j]]


def lead_notes(program, counts, axes, taps=None) -> list:
    """The summary's line per compensated ``G32``/``G33``/``G33.1`` block of ``program`` (its source line): its pieces
    and the range of their F' or K' (:func:`lead_texts` of the compensated program axes ``axes`` (n, k) mm, ``counts``
    (c,) vertices per compensated move, before the written rounding; a block whose start is a kept move's end is left
    out); a G33.1's the error left along the hole, ``taps`` {0-based line: μm}
    (:func:`compensation.chain_gcode.tap_bend_um`)."""
    order = {id(m): k for k, m in enumerate(program.moves)}
    comp = [m for m in program.moves if m.compensate]
    ends = np.cumsum(counts)
    out = []
    for i, m in enumerate(comp):
        if m.lead is None or i == 0 or order[id(comp[i - 1])] != order[id(m)] - 1:
            continue
        rows = np.asarray(axes)[ends[i - 1] - 1:ends[i]]
        f, w = lead_texts(m, rows[:-1], rows[1:], m.units), LEAD_WORD[m.synced]
        bend = (taps or {}).get(m.index)
        left = "" if bend is None else f"; one move and its return, error left along the hole {bend:.3g} um"
        out.append(f"line {source_line(program, m.index + 1)}: {m.synced} {w}{m.lead[1]} written as {len(f)} "
                   f"piece(s), {w}' {min(f, key=float)} to {max(f, key=float)} (each piece's true lead the "
                   f"programmed {w}{left})")
    return out


def with_lead(line: str, text: str, add: bool = True, word: str = "F") -> str:
    """``line`` (one output line) with its ``word`` (F, a G33's K)'s number replaced by ``text``, or ``{word}{text}``
    added after its last word (``add``)."""
    from .gcode_words import tokenize
    body = line.rstrip("\r\n")
    end = line[len(body):]
    _, words, _ = tokenize(body)
    f = next((w for w in words if w.letter == word), None)
    if f is not None:
        return body[:f.start] + word + text + body[f.num_end:] + end
    if not add:
        return line
    last = max((w.num_end for w in words), default=len(body))
    return body[:last] + f" {word}{text}" + body[last:] + end


def restore_feed(lines: list, text: str, between) -> list:
    """The output lines of the first feed move after a thread with the programmed F (``text``) on the first, where
    neither its line nor one of the source lines ``between`` (the thread's last line to it) gives an F: the modal F is
    the last piece's F' there."""
    from .gcode_words import tokenize

    def has_f(line):
        try:
            return any(w.letter == "F" for w in tokenize(line.rstrip("\r\n"))[1])
        except _Refuse:
            return True  # a line the reader would refuse: not read here (it keeps the program from being written)
    if any(has_f(ln) for ln in list(between) + lines[:1]):
        return lines
    return [with_lead(lines[0], text)] + lines[1:]


@dataclasses.dataclass(frozen=True)
class ThreadExpansion(LatheExpansion):
    """G92 passes written as the control's moves (:func:`expand_threading`; ``count``: the passes)."""

    WHAT = ("lathe threading cycles written as the controller's moves ({n}: a G92 pass as G0 X, G32 Z in compensated "
            "pieces each with its own F, G0 X and G0 Z back to the start point; a LinuxCNC G76 as its passes' G0 moves "
            "and G33 pieces each with its own K)")


# ---------------------------------------------------------------------------- G92 / G76 on the reader's lines
class ThreadState:
    """A modal ``G92`` in force: its end Z (mm), F (value, text) and the column of its code."""

    def __init__(self, z_mm, f, code):
        self.z_mm, self.f, self.code = z_mm, f, code


def thread_line(words, idx: int, st, ax) -> str | None:
    """``"state"`` for a ``G92``/``G76`` line or a modal G92 pass (recorded as an event ``"lathe-thread"``:
    ``(start X radius mm, start Z mm, X radius mm, Z mm, F text, inch, diameter)``), None for any other line (a
    G32 line is read as a move; a group-01 code ends the modal G92)."""
    code = next((w for w in words if w.letter == "G" and w.code in THREADING), None)
    ts = getattr(st, "thread", None)
    if code is None and ts is None:
        return None
    if code is None:
        other = next((w for w in words if w.letter == "G"), None)
        if other is not None:
            if other.code in ("G0", "G1", "G2", "G3"):
                st.thread = None
                return None
            raise _Refuse(other.start + 1, f"'{other.code}' while the G92 thread cutting cycle is modal: end it with "
                                           "G0 (or G1-G3) first")
        if not any(w.letter in "XZUW" for w in words):
            return None
        return _g92_pass(words, idx, st, ax, None)
    if code.code == "G32":
        st.thread = None
        bad = next((w for w in words if w.letter in "QE"), None)
        if bad is not None:
            raise _Refuse(bad.start + 1, f"'{bad.letter}{bad.text}' on a G32 line (the thread's start angle or an inch "
                                         "lead) is not read: write the thread with F alone")
        return None
    if code.code == "G76":
        raise _Refuse(code.start + 1, f"'G76' on a {st.dialect.name} lathe: {THREADING['G76']}: its passes (depths "
                                      "Δd·√n, the infeed along the flank, the chamfer) are the control's, not written "
                                      "in the program: not read, kept or with --expand-cycles; post the passes as G32 "
                                      "or G92 lines")
    if st.dialect.name != "fanuc":
        raise _Refuse(code.start + 1, f"'G92' on a {st.dialect.name} lathe: {THREADING['G92']}: its taper I and the "
                                      "M23 chamfer out of the thread (settings 95/96) are the control's: not read; "
                                      "post the passes as G32 lines")
    return _g92_pass(words, idx, st, ax, code)


def _g92_pass(words, idx, st, ax, code) -> str:
    """One G92 pass (its line or a modal X line): the event for :func:`expand_threading`."""
    by = {w.letter: w for w in words}
    for w in words:
        if w.letter not in "NGXZF" or (w.letter == "G" and w is not code):
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a G92 thread cutting line: only X Z F are read "
                                       "(R taper, U/W increments and Q not); write other words on a line of their own")
    scale = MM_PER_INCH if st.inch else 1.0
    ts = st.thread
    z = by["Z"].value * scale if "Z" in by else (ts.z_mm if ts is not None else None)
    f = (by["F"].value, by["F"].text) if "F" in by else (ts.f if ts is not None else None)
    col = (code or words[0]).start + 1
    if "X" not in by or z is None or f is None or not f[0] > 0:
        raise _Refuse(col, "a G92 pass needs X, Z and a positive F (the lead; Z and F kept from the G92 line before "
                           "it); G92 is read as Fanuc G-code system A's threading cycle (in systems B and C, a "
                           "parameter, it sets the coordinate system: not read)")
    if st.incremental:
        raise _Refuse(col, "a G92 pass under G91: not read; write it under G90")
    start = np.array([st.pos[ax.words.index("X")], st.pos[ax.words.index("Z")]], dtype=float)
    if not np.isfinite(start).all():
        raise _Refuse(col, "a G92 pass from an unknown start point: give X and Z on a line before it")
    x = by["X"].value * scale * (0.5 if st.diameter else 1.0)
    st.thread = ThreadState(z, f, "G92")
    st.thread_lead = None  # the control's F is the cycle's now: a G32 after it gives its own
    st.events.append((idx, col, "lathe-thread", (start[0], start[1], x, z, f[1], st.inch, st.diameter), "G92"))
    return "state"


def refuse_kept(path, events) -> None:
    """Refuse (InputError) a G92 pass or a LinuxCNC G76 left as a cycle (no ``--expand-cycles``): every pass starts
    from the one point the cycle rapids from along X, whose compensation cannot be each pass's start's (the error there
    differs with the pass's depth X: the passes' phases would differ), and one lead (F, P) for the whole pass cannot
    give the true lead where the error is not linear along the thread."""
    from errormap.io import InputError
    for line, col, _, _, code in (e for e in events if e[2] == "lathe-thread"):
        lead, cut = ("P", "G33 pieces, each with its own K") if code == "G76" else \
            ("F", "G32 pieces, each with its own F")
        raise InputError(f"{path}: line {line + 1}, column {col}: '{code}' ({THREADING[code]}) kept as a cycle: its "
                         f"passes start from one point whose compensation cannot be each pass's, and one {lead} cannot "
                         "give the true lead along the thread; use --expand-cycles (each pass written as G0 and "
                         f"compensated {cut})")


def expand_threading(prog, path, reparse):
    """``prog`` with every G92 pass and LinuxCNC G76 written as the moves the control makes (``--expand-cycles``): a
    G92 pass as ``G0 X`` to the pass's X, ``G32 Z F`` to its end, ``G0 X`` back to the start point's X, ``G0 Z`` back
    to its Z; a G76 as its passes (:func:`compensation.nc_g76.g76_lines`); absolute, in the program's units (X as the
    program writes it: diameter or radius). ``reparse(text)`` reads the expanded text; ``prog`` itself where there is
    none."""
    passes = {e[0]: e for e in prog.events if e[2] == "lathe-thread"}
    if not passes:
        return prog

    def lines_of(i):
        return (g76_lines if passes[i][4] == "G76" else _pass_lines)(prog.lines[i], passes[i], i)
    return expand_lines(prog, path, reparse, passes, lines_of, ThreadExpansion)


def _pass_lines(line, e, i: int) -> tuple:
    """``(lines, note)`` of the G92 pass of event ``e`` on ``line`` (0-based ``i``; :func:`expand_threading`)."""
    sx, sz, x, z, f, inch, diameter = e[3]
    unit = MM_PER_INCH if inch else 1.0
    xw = lambda v: _word_text(v * (2.0 if diameter else 1.0) / unit)  # noqa: E731
    ending = line[len(line.rstrip("\r\n")):] or "\n"
    new = [f"G00 X{xw(x)}", f"G32 Z{_word_text(z / unit)} F{f}", f"G00 X{xw(sx)}", f"G00 Z{_word_text(sz / unit)}"]
    return [t + ending for t in new], note("line ", i + 1, f": G92 pass expanded: G0 X{xw(x)}, G32 "
                                           f"Z{_word_text(z / unit)} F{f} in compensated pieces (each its own F; the "
                                           "G0 to its start compensated), G0 back to the start point; written without "
                                           "a chamfer out of the thread (the control's G92 chamfer, its amount Fanuc "
                                           "parameter 5130, must be 0)")
