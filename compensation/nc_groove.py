"""Fanuc/Haas lathe grooving / peck cycles: ``G74`` (face peck drilling, face grooving: pecks along Z) and ``G75``
(diameter grooving: pecks along X), on a lathe (X and Z; C the spindle).

Formats read (Fanuc 0i-TF operator's manual, "multiple repetitive cycles", G74/G75, as restated by the
Fanuc-compatible ADT-CNC4620 programming manual §3.6.6,
manualshelf.com/manual/adtech/adt-tp3340dj/programming-instructions-english/page-61.html, and
gcodetutor.com/cnc-machine-training/g75-groove-cycle.html; Haas lathe operator's manual, G74/G75):

- Fanuc first block ``G74 R(e)`` / ``G75 R(e)``: ``e`` the return after each peck, a radius length; modal, it sets
  parameter 5139, which both cycles use: without it in the program the control runs on the value it holds;
- Fanuc second block ``G74 X Z P(Δi) Q(Δk) R(Δd) F`` / ``G75 X Z P(Δi) Q(Δk) R(Δd) F``: X Z the end point (the last
  column's bottom); G74: Q the peck along Z, P the shift along X; G75: P the peck along X, Q the shift along Z; both
  unsigned radius values in the least input increment (0.001 mm, 0.0001 in) without a decimal point; ``Δd`` the
  relief at the bottom; an alarm where e > Δk or where the end differs across from the start and the shift is 0;
- Haas one block ``G74``/``G75 X Z I K D F``: I and K the X and Z increments (program units), D the relief; the
  peck return is a control setting, not a program word;
- U/W (incremental X/Z) are not read on the cycle line, as on every lathe move here; G74/G75 are one-shot (group 00):
  the G0-G3 in force before the cycle is in force after it, and the tool is back at the start point.

The control's moves (:func:`cycle_points`): from the start point S (the tool's position on the cycle line) it feeds
along the plunge axis (Z for G74, X for G75) toward the end point's plunge coordinate in pecks of Δk, returning e by
rapid after each peck and feeding on from there, to the bottom; rapid back along that axis to S's level; rapid
across by Δi toward the end point (the last shift to its across coordinate); and so on to the column at the end
point; then rapid back to S.

Kept (the default; :mod:`compensation.nc_groove_kept`): the cycle line stays, its plunge word (G74's Z, G75's X)
written compensated at the bottom. The control plunges at the across coordinate it stands at (the previous line's
written end), so the bottom's compensation across the plunge axis cannot be written: the cycle is kept where that error across is at most
:data:`ACROSS_UM` and reported per cycle line (as a kept drilling cycle's tilt, :mod:`compensation.nc_cycles`);
a cycle of several columns (the control spaces them by Δi from the written start: compensated columns are not
equally spaced) or with a larger error across is refused naming ``--expand-cycles``.

Expanded (``--expand-cycles``, :func:`expand_grooves`): each second block becomes the moves above in absolute X Z
(G1 at the cycle's F for the pecks, G0 for the returns), every one compensated point by point (the rapids too: they
run inside the groove); the first block ``G74 R(e)`` stays as written (it moves nothing). Refused: e not in the
program (no first block before the cycle: the control's parameter is not known here), the Haas form (its return is
a setting), a relief Δd (its direction at the bottom is not read exactly here), e > Δk (the control alarms)."""
from __future__ import annotations

import dataclasses

import numpy as np

from .gcode_state import MM_PER_INCH, _Refuse
from .gcode_words import GMove
from .nc_contour import HOLD_UM, LatheExpansion, _word_text, applies, expand_lines
from .nc_notes import note

GROOVING = {"G74": "face peck drilling / grooving cycle", "G75": "diameter grooving cycle"}
PLUNGE = {"G74": "Z", "G75": "X"}
"""The axis the cycle pecks along; the other is the axis it shifts across."""
ACROSS = {"G74": "X", "G75": "Z"}
LETTERS = {"fanuc": frozenset("NGXZPQRF"), "haas": frozenset("NGXZIKDF")}
"""Words a cycle line may hold on each control (module docstring)."""
PECK_WORD = {("fanuc", "G74"): "Q", ("fanuc", "G75"): "P", ("haas", "G74"): "K", ("haas", "G75"): "I"}
SHIFT_WORD = {("fanuc", "G74"): "P", ("fanuc", "G75"): "Q", ("haas", "G74"): "I", ("haas", "G75"): "K"}
INCREMENT_MM = {False: 1e-3, True: 1e-4 * MM_PER_INCH}
"""Fanuc's P/Q unit, the least input increment (IS-B): 0.001 mm in mm input, 0.0001 in in inch input."""
ACROSS_UM = HOLD_UM
"""A kept cycle's bottom may lie this far across the plunge axis from where its compensation would put it: the
contour cycles' bound on a compensated point the kept form cannot follow (half the 0.001 mm least input increment;
:data:`compensation.nc_contour.HOLD_UM`); the points are checked to 1 um."""


@dataclasses.dataclass
class Groove:
    """One G74/G75 second block: ``start``/``end`` (X radius, Z) mm in the program's frame, ``peck_mm``/``shift_mm``
    (None: not given), ``relief`` its Δd / D word (None: none), ``retract_mm`` the e of the program's last first
    block before it (None: none), ``words`` the line's words by letter, ``mode`` the G0-G3 in force before it."""
    code: str
    dialect: str
    start: np.ndarray
    end: np.ndarray
    peck_mm: float | None
    shift_mm: float | None
    relief: object
    retract_mm: float | None
    words: dict
    inch: bool
    diameter: bool
    mode: str | None
    feed: str | None

    def columns(self) -> np.ndarray:
        """The across coordinates (mm) of the columns the control cuts, from the start's to the end's (Δi apart)."""
        j = 0 if ACROSS[self.code] == "X" else 1
        a0, a1 = self.start[j], self.end[j]
        if abs(a1 - a0) < 1e-9:
            return np.array([a0])
        n = int(np.ceil(abs(a1 - a0) / self.shift_mm - 1e-9))
        return np.append(a0 + np.sign(a1 - a0) * self.shift_mm * np.arange(n), a1)


def groove_line(words, idx: int, st, ax, x_words):
    """``"state"`` for a first block (e recorded), ``("move", GMove)`` for a second block (its bottom, the end point,
    as one compensated point; the event ``"lathe-groove"`` recorded), None for any other line (or where no contour
    cycle is read: :func:`compensation.nc_contour.applies`). ``x_words(by)``: the reader's X rule on the line's words
    by letter (refused without ``--lathe-x``; a diameter replaced by the radius)."""
    if st.contours.pending is not None or st.contours.active is not None or not applies(st, ax):
        return None  # inside a contour's blocks G74/G75 is refused there
    g = next((w for w in words if w.letter == "G" and w.code in GROOVING), None)
    if g is None:
        return None
    name = st.dialect.name
    by = {}
    for w in words:
        if w.letter in "UW":
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {g.code} line: incremental {w.letter} is not read "
                                       "(as on every lathe move here): write the end point as absolute X and Z")
        if w.letter not in LETTERS[name] or (w.letter == "G" and w is not g):
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {name} {g.code} line: only "
                                       f"{' '.join(sorted(LETTERS[name] - {'G', 'N'}))} words are read there (write "
                                       "other words on a line of their own)")
        by[w.letter] = w
    if name == "fanuc" and set(by) <= {"N", "G", "R"} and "R" in by:  # the first block: e, the return per peck
        st.events.append((idx, g.start + 1, "groove-retract", by["R"].value * (MM_PER_INCH if st.inch else 1.0),
                          g.code))
        return "state"
    plunge = PLUNGE[g.code]
    if plunge not in by:
        raise _Refuse(g.start + 1, f"'{g.code}' without {plunge}: the {GROOVING[g.code]}'s end point needs its "
                                   f"{plunge} (the bottom along the axis it pecks)" + (
                                       "; a first block 'G74 R(e)' holds R only" if name == "fanuc" else ""))
    if st.incremental or st.cutter != "G40":
        raise _Refuse(g.start + 1, f"'{g.code}' under incremental distance (G91): write the cycle in G90" if
                      st.incremental else f"'{g.code}' with tool nose radius compensation ({st.cutter}) in force: "
                      "whether the control offsets the cycle's moves is not read here: cancel it (G40) before")
    x_words(by)  # X refused without --lathe-x; a diameter read as the radius
    ix, iz = ax.words.index("X"), ax.words.index("Z")
    start = np.array([st.pos[ix], st.pos[iz]], dtype=float)
    if not np.isfinite(start).all():
        raise _Refuse(g.start + 1, f"'{g.code}': its start point (the tool's X and Z on this line) is not known: give "
                                   "X and Z on a line before the cycle")
    scale = MM_PER_INCH if st.inch else 1.0
    end = np.array([by["X"].value * scale if "X" in by else start[0], by["Z"].value * scale if "Z" in by else start[1]])
    groove = Groove(g.code, name, start, end, *_increments(by, name, g.code, st.inch, scale), _retract(st.events),
                    by, st.inch, bool(st.diameter), st.mode, by["F"].text if "F" in by else None)
    jp, ja = (1, 0) if plunge == "Z" else (0, 1)
    if abs(end[jp] - start[jp]) < 1e-9:
        raise _Refuse(by[plunge].start + 1, f"'{plunge}{by[plunge].text}' on the {g.code} line is the start point's "
                                            f"{plunge}: no depth to cut")
    if groove.shift_mm is None and abs(end[ja] - start[ja]) >= 1e-9:
        raise _Refuse(g.start + 1, f"'{g.code}': the end point's {ACROSS[g.code]} differs from the start's and no "
                                   f"{SHIFT_WORD[(name, g.code)]} (the shift across) is given: the control alarms")
    st.events.append((idx, g.start + 1, "lathe-groove", groove, g.code))
    bottom = np.array(st.pos, dtype=float)
    bottom[[ix, iz]] = end
    return "move", GMove(idx, "linear", bottom.copy(), bottom, "inch" if st.inch else "mm", False,
                         {a: by[a] for a in "XZ" if a in by}, g, True, diameter=bool(st.diameter))


def _increments(by, name: str, code: str, inch: bool, scale: float) -> tuple:
    """``(peck mm, shift mm, relief word)`` of a second block (None where not given): Fanuc's P/Q in the least input
    increment without a decimal point, Haas' I/K in program units; each > 0."""
    out = []
    for w in (by.get(PECK_WORD[(name, code)]), by.get(SHIFT_WORD[(name, code)])):
        if w is None:
            out.append(None)
            continue
        if name == "fanuc" and ("." in w.text or w.value != int(w.value)):
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {code} line: Fanuc reads P and Q in the least input "
                                       f"increment without a decimal point (P1500 is {1.5 if not inch else 0.15:g} "
                                       f"{'mm' if not inch else 'in'}): write it so")
        if w.value <= 0:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {code} line: an increment > 0, unsigned")
        out.append(w.value * INCREMENT_MM[inch] if name == "fanuc" else w.value * scale)
    relief = by.get("R" if name == "fanuc" else "D")
    return out[0], out[1], relief


def _retract(events) -> float | None:
    """The e (mm) of the last Fanuc first block ``G74/G75 R(e)`` read (parameter 5139, both cycles'); None: none."""
    last = [e for e in events if e[2] == "groove-retract"]
    return last[-1][3] if last else None


def _where(prog, path, line0: int, col: int) -> str:
    exp = getattr(prog, "expanded", None)
    return exp.where(line0 + 1, col) if exp is not None else f"{path}: line {line0 + 1}, column {col}"


def refuse_kept(path, events) -> None:
    """Refuse (InputError) a kept (default) G74/G75 whose control cuts several columns: it spaces them by Δi from the
    written start, the compensated columns are not equally spaced (module docstring). Named on the program's flat
    lines (the caller relocates to the source)."""
    from errormap.io import InputError
    for idx, col, kind, g, code in events:
        if kind == "lathe-groove" and len(g.columns()) > 1:
            raise InputError(f"{path}: line {idx + 1}, column {col}: '{code}' ({GROOVING[code]}) of several "
                             f"columns (its end point's {ACROSS[code]} is not the start's): the control spaces them by "
                             f"{SHIFT_WORD[(g.dialect, code)]} from the written start, so compensated columns cannot "
                             "be written in the cycle; use --expand-cycles (the cycle written as its moves, "
                             "compensated point by point)")


def cycle_points(g: Groove) -> list:
    """The control's moves of a second block (module docstring) as ``[(motion code, X radius mm, Z mm)]``, from its
    start point to its return there: per column, feeds of Δk each returning e by rapid (the next feed from there),
    the last to the bottom, a rapid back to the start's level; rapids across between columns; a rapid back to S."""
    jp = 1 if PLUNGE[g.code] == "Z" else 0
    s_p, e_p = g.start[jp], g.end[jp]
    d = np.sign(e_p - s_p)
    depth = abs(e_p - s_p)
    pecks = g.peck_mm * np.arange(1, int(np.ceil(depth / g.peck_mm - 1e-9))) if g.peck_mm else np.zeros(0)

    def at(a, p):
        return (a, p) if jp == 1 else (p, a)
    out = []
    for a in g.columns():
        if out:
            out.append(("G0",) + at(a, s_p))
        for k in pecks:
            out += [("G1",) + at(a, s_p + d * k), ("G0",) + at(a, s_p + d * (k - g.retract_mm))]
        out += [("G1",) + at(a, e_p), ("G0",) + at(a, s_p)]
    out.append(("G0",) + at(g.start[1 - jp], s_p))
    return out


@dataclasses.dataclass(frozen=True)
class GrooveExpansion(LatheExpansion):
    """G74/G75 second blocks written as the controller's moves (:func:`expand_grooves`; ``count``: the cycles)."""

    WHAT = ("lathe G74/G75 grooving cycles written as the controller's moves ({n}: pecks, returns, shifts and the "
            "return to the start point), compensated point by point")


def _expansion_refusal(g: Groove, path: str) -> str | None:
    """Why a second block cannot be written as its moves (None: it can): module docstring."""
    if g.dialect == "haas":
        return (f"'{g.code}' on Haas: the return after each peck is a control setting, not a word of the program: not "
                "written as moves here; leave --expand-cycles out (kept) or post the groove as G1 moves")
    if g.retract_mm is None:
        return (f"'{g.code}': the return after each peck e is the control's parameter 5139 unless the program gives "
                f"it: write the first block '{g.code} R(e)' before this line, or leave --expand-cycles out")
    if g.peck_mm is None:
        return (f"'{g.code}' without {PECK_WORD[(g.dialect, g.code)]} (the peck): the control's depth per peck is "
                "not given: write it, or leave --expand-cycles out")
    if g.relief is not None and g.relief.value != 0:
        return (f"'R{g.relief.text}' (the relief at the bottom) on the {g.code} line: its direction at the bottom is "
                "not read exactly here: write R0 or leave it out, or leave --expand-cycles out")
    if g.retract_mm > g.peck_mm:
        return (f"'{g.code}': the return e ({g.retract_mm:g} mm) is more than the peck "
                f"{PECK_WORD[(g.dialect, g.code)]} ({g.peck_mm:g} mm): the control alarms")
    return None


def expand_grooves(prog, path, reparse):
    """``prog`` (a lathe program read with its grooving cycles, :func:`groove_line`) with every G74/G75 second block
    written as the control's moves (``--expand-cycles``, :func:`_groove_lines`), every move of them compensated (the
    rapids too: they run inside the groove), every other line kept (:func:`compensation.nc_contour.expand_lines`).
    ``reparse(text)`` reads the expanded text (a GProgram); returns ``prog`` where there is none."""
    cycles = {e[0]: e for e in prog.events if e[2] == "lathe-groove"}
    if not cycles:
        return prog
    return expand_lines(prog, path, reparse, cycles, lambda i: _groove_lines(prog, path, cycles[i]),
                        GrooveExpansion, compensated=True)


def _groove_lines(prog, path, e) -> tuple:
    """``(lines, summary note)`` of the second block of event ``e`` (:func:`cycle_points`) in absolute X Z of the
    program's units, G1 at the cycle's F for the pecks, G0 for the returns, ending in the G0-G3 in force before it
    (one-shot cycles). Refused (InputError): :func:`_expansion_refusal`."""
    from errormap.io import InputError
    idx, col, _, g, code = e
    why = _expansion_refusal(g, str(path))
    if why is not None:
        flat = prog.expanded.path if prog.expanded is not None else path  # expand_lines re-addresses to the source
        raise InputError(f"{flat}: line {idx + 1}, column {col}: {why}")
    line = prog.lines[idx]
    unit = MM_PER_INCH if g.inch else 1.0
    ending = line[len(line.rstrip("\r\n")):] or "\n"
    pts = cycle_points(g)
    new, feed = [], f" F{g.feed}" if g.feed else ""
    for code_, x, z in pts:
        new.append(f"{code_} X{_word_text(x * (2.0 if g.diameter else 1.0) / unit)} Z{_word_text(z / unit)}"
                   + (feed if code_ == "G1" else "") + ending)
        feed = "" if code_ == "G1" else feed
    if g.mode not in (None, "G0"):
        new.append(g.mode + ending)  # one-shot: the G0-G3 in force before the cycle stays after it
    return new, note("line ", idx + 1, f": {code} ({GROOVING[code]}) expanded: {len(g.columns())} column(s), "
                     f"{sum(c == 'G1' for c, _, _ in pts)} feed(s), written as {len(pts)} moves compensated point by "
                     "point (the rapids too)")
