"""LinuxCNC's lathe cycles ``G70`` (finishing), ``G71``/``G71.1``/``G71.2`` (roughing along Z) and
``G72``/``G72.1``/``G72.2`` (facing) on a lathe: the contour is the o-subroutine named by Q, which the cycle reads
without running it (:meth:`compensation.nc_expand._Machine` hands its lines over, values evaluated). Read here
exactly, written with ``--expand-cycles`` as the moves LinuxCNC's interpreter makes (:mod:`compensation.nc_g7x_path`),
each compensated point by point as every move is; kept as a cycle they are refused naming that option.

Rules read (LinuxCNC 2.9 G-code reference, "G70 Lathe finishing cycle", "G71 G72 Lathe roughing cycles"; its
interpreter, ``Interp::convert_g7x`` in src/emc/rs274ngc/interp_g7x.cc):

- ``G70 Q- [X- Z-] [D-] [E-] [P-]``: X Z the start point (the tool's position without them), D the first pass's
  distance from the contour, E the last's (both 0 by default), P the passes (1); ``G71``/``G72 Q- [X- Z-] [D-] [I-]
  [R-]``: D the distance left to the contour, I the depth of cut (1), R the retract (0.5); ``.1`` cuts no pocket,
  ``.2`` only the pockets;
- refused by LinuxCNC (and so here): no Q, a subroutine not defined before the cycle, G91, cutter compensation on
  (G71/G72), an arc of the contour without I or K (or R);
- ``G70`` under cutter compensation (``G41``/``G42``, ``G41.1``/``G42.1``): LinuxCNC runs it (``convert_g7x`` refuses
  only G71/G72), each move it makes going through ``convert_straight``/``convert_arc`` as a written move's does, so
  its compensation offsets them as it offsets written moves: read so, the path compensated as programmed (the
  bound the radius leaves reported, as for written moves under G41/G42);
- the contour: from the start point, a segment per contour line that moves X or Z (others skipped), G0 and G1 alike
  straight, G2/G3 arcs (I K centres as the arc distance mode says; R: the centre on the side G2/G3 says, R's sign not
  read); its lines are parsed (``Interp::read``), never executed, up to the first ``endsub``: an O-word line (a
  ``repeat``, ``if``, ``while``, ``call`` …) moves nothing and runs nothing (a loop's body is read once), other axes'
  words (A B C Y U V W) are skipped, expressions are valued as the line is read (``#<_x>``: the position before the
  cycle).

Refused here besides (not read exactly): other words on the cycle line (those the cycle does not read), U and W
(LinuxCNC's axis words), G7 diameter mode, a plane other than G18 (the written arcs are ZX arcs), a contour line
with other words than G0-G3, X Z I K R, N and other axes', a parameter setting in the contour (never applied there),
a line moving before the contour names G0-G3, an arc line without its own G2/G3 (the interpreter takes its direction from the line's own word), an R
arc shorter than its chord, and what :mod:`compensation.nc_g7x_path` cannot compute as the reference does."""
from __future__ import annotations

import dataclasses

import numpy as np

from .gcode_state import MM_PER_INCH, _Refuse
from .gcode_words import tokenize
from .nc_contour import LatheExpansion, _word_text, expand_lines
from .nc_g7x_path import Arc, G7xError, Straight, finishing, roughing
from .nc_notes import note

CODES = {"G70": (70, 0), "G71": (71, 0), "G71.1": (71, 1), "G71.2": (71, 2), "G72": (72, 0), "G72.1": (72, 1),
         "G72.2": (72, 2)}
"""The cycles read: code -> (cycle, sub-cycle)."""
READ = {70: "DEP", 71: "DIR", 72: "DIR"}
"""The words each cycle reads beside N G Q X Z (module docstring)."""
DEFAULTS = {"D": 0.0, "E": 0.0, "P": 1.0, "I": 1.0, "R": 0.5}
"""Their values without the word (the interpreter's)."""
WHAT = {70: "finishing cycle", 71: "roughing cycle", 72: "facing cycle"}
CONTOUR_LETTERS = frozenset("NGXZIKR")
IGNORED_AXES = frozenset("ABCYUVW")
"""Axis words of a contour line the cycle parses and never uses (``convert_g7x`` reads only X Z I K R of a line):
skipped, the segment is the X Z move (LinuxCNC's lathe_g70_71_demo's ``G1 X10 A0.2``)."""


def g7x_line(words, idx: int, st, ax) -> str | None:
    """``"state"`` for a LinuxCNC G70-G72 line on a lathe (its moves recorded as the event ``"lathe-g7x"``:
    ``(moves [(code, end, centre)] in program units as ``z + 1j·x``, inch, arc_abs, Q)``; the tool at the last move's
    end, no motion mode in force), None for any other line. Refused: module docstring."""
    code = next((w for w in words if w.letter == "G" and w.code in CODES), None)
    if code is None:
        return None
    cycle, sub = CODES[code.code]
    col = code.start + 1
    by = _words(words, code, cycle)
    why = ("under G91 (LinuxCNC: it works only in absolute distance mode)" if st.incremental else
           f"with cutter compensation {st.cutter} on (LinuxCNC's error: 'G{cycle}.{sub} cannot be used with cutter "
           "compensation turned on'; write G40 before it)" if st.cutter != "G40" and cycle != 70 else
           "in diameter mode G7 (not read here: write the cycle under G8)" if st.diameter else
           "in a plane other than G18 (ZX; the moves it writes are ZX arcs)" if st.plane != "G18" else None)
    if why is not None:
        raise _Refuse(col, f"'{code.code}' ({WHAT[cycle]}) {why}")
    q = by["Q"].value
    lines = st.g7x_contours.get(idx)
    if lines is None:
        raise _Refuse(by["Q"].start + 1, f"'Q{by['Q'].text}': no subroutine o{round(q)} defined before the "
                                         f"{code.code} (LinuxCNC: 'Q routine not found'; its contour is that "
                                         "subroutine)")
    unit = MM_PER_INCH if st.inch else 1.0
    ix, iz = ax.words.index("X"), ax.words.index("Z")
    x = by["X"].value if "X" in by else float(st.pos[ix]) / unit
    z = by["Z"].value if "Z" in by else float(st.pos[iz]) / unit
    if not (np.isfinite(x) and np.isfinite(z)):
        raise _Refuse(col, f"'{code.code}' from an unknown position: give X and Z on the cycle line or before it")
    v = {a: by[a].value if a in by else DEFAULTS[a] for a in READ[cycle]}
    segs, unrun = contour(lines, x, z, st.arc_abs, round(q))
    try:
        moves = finishing(segs, x, z, v["D"], v["E"], int(v["P"])) if cycle == 70 else \
            roughing(segs, sub, x, z, v["D"], v["I"], v["R"], cycle == 72)
    except (G7xError, ZeroDivisionError, ValueError) as exc:
        raise _Refuse(col, f"'{code.code}' ({WHAT[cycle]}, contour o{round(q)}): not computed as LinuxCNC computes "
                           f"it: {exc}") from None
    st.events.append((idx, col, "lathe-g7x", (moves, st.inch, bool(st.arc_abs), round(q), unrun), code.code))
    st.pos = np.array(st.pos, dtype=float)  # a new array: the moves read hold the old one as their end
    st.pos[ix], st.pos[iz] = moves[-1][1].imag * unit, moves[-1][1].real * unit
    st.mode, st.last_move = None, None  # which G0-G3 LinuxCNC leaves in force the reference does not say
    return "state"


def _words(words, code, cycle: int) -> dict:
    """The cycle line's words by letter; refused: a word the cycle does not read, a repeated one, no Q, values the
    interpreter would loop on or misread."""
    by, allowed = {}, set("NGQXZ") | set(READ[cycle])
    for w in words:
        if w.letter not in allowed or (w.letter == "G" and w is not code):
            why = ("U and W are LinuxCNC's axis words; the displacement they give the roughing contour is not read "
                   "here" if w.letter in "UW" else "write it on a line of its own")
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {code.code} line: only Q X Z "
                                       f"{' '.join(READ[cycle])} are read there ({why})")
        if w.letter in by:
            raise _Refuse(w.start + 1, f"repeated '{w.letter}' word")
        by[w.letter] = w
    if "Q" not in by:
        raise _Refuse(code.start + 1, f"'{code.code}' without Q (LinuxCNC: 'G7x.x requires a Q word'): Q names the "
                                      "o-subroutine that holds the contour")
    bad = ("P", "the passes: a whole number ≥ 1") if "P" in by and (
        by["P"].value != int(by["P"].value) or by["P"].value < 1) else \
        ("I", "the depth of cut must be > 0") if "I" in by and cycle != 70 and not by["I"].value > 0 else \
        ("D", "the distance must be ≥ 0") if "D" in by and by["D"].value < 0 else \
        ("E", "the distance must be ≥ 0") if "E" in by and by["E"].value < 0 else \
        ("R", "the retract must be ≥ 0") if "R" in by and by["R"].value < 0 else None
    if bad is not None:
        w = by[bad[0]]
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {code.code} line: {bad[1]}")
    return by


def contour(lines, x: float, z: float, arc_abs: bool, name) -> tuple:
    """``(segments, unrun)``: the cycle's segments (:mod:`compensation.nc_g7x_path`) from (``x``, ``z``) along
    ``lines`` ``[(source line, text)]`` (the subroutine's lines, named as reports name them: an int, ``'k of FILE'``
    in a subprogram file; values evaluated; text None: an O-word line, read
    and not run), as ``convert_g7x`` reads them (module docstring): its first segment from the start point to the
    contour's first point; ``unrun`` the source lines of the O-word lines."""
    segs, at, unrun = [], complex(z, x), []
    motion = None
    for src, text in lines:
        if text is None:
            unrun.append(src)
            continue
        where = f"line {src} (the contour o{name})"
        try:
            ws = tokenize(text)[1]
        except _Refuse as r:
            raise _Refuse(1, f"{where}, column {r.col}: {r.msg}") from None
        for w in ws:
            if w.letter not in CONTOUR_LETTERS or (w.letter == "G" and w.code not in ("G0", "G1", "G2", "G3")):
                if w.letter in IGNORED_AXES:
                    continue
                raise _Refuse(1, f"{where}, column {w.start + 1}: '{w.letter}{w.text}' in a G7x contour: the cycle "
                                 "reads only G0-G3, X Z I K R and skips the other axes' words; what LinuxCNC makes "
                                 "of this one there is not read here")
        by = {w.letter: w for w in ws}
        own = by["G"].code if "G" in by else None
        motion = own or motion
        to = complex(by["Z"].value if "Z" in by else at.real, by["X"].value if "X" in by else at.imag)
        if to == at:
            continue
        if motion is None:
            raise _Refuse(1, f"{where}: the contour moves before it names G0-G3 (which the cycle takes from the mode "
                             "before it is not read here): write G0 or G1 on the contour's first line")
        if motion in ("G0", "G1"):
            segs.append(Straight(at, to))
        else:
            segs.append(Arc(own == "G3", at, _centre(by, at, to, motion, own, arc_abs, where), to))
        at = to
    if len(segs) < 2:
        raise _Refuse(1, f"the contour o{name} makes {len(segs)} move(s) from the start point: the cycle needs the "
                         "move to the contour and at least one along it")
    return segs, unrun


def _centre(by, at: complex, to: complex, motion, own, arc_abs: bool, where) -> complex:
    """An arc's centre (``z + 1j·x``) as ``convert_g7x`` computes it (module docstring)."""
    if own is None:
        raise _Refuse(1, f"{where}: an arc line without its own {motion} (LinuxCNC's cycle reads its direction from "
                         "the line's own G word: G2 whatever the mode): write G2 or G3 on it")
    if "R" in by:
        r, chord = by["R"].value, to - at
        h = (r * r - abs(chord) ** 2 / 4) / abs(chord) ** 2
        if h < 0:
            raise _Refuse(1, f"{where}, column {by['R'].start + 1}: 'R{by['R'].text}': the radius is shorter than half "
                             "the chord (the reference's centre is not a number)")
        d = 1j * h ** 0.5 * chord
        return (at + to) / 2 + (d if motion == "G3" else -d)
    if "I" not in by and "K" not in by:
        raise _Refuse(1, f"{where}: an arc without I or K (LinuxCNC: 'G7X error: either I or K must be present for "
                         "arc')")
    c = complex(by["K"].value if "K" in by else 0.0, by["I"].value if "I" in by else 0.0)
    return c if arc_abs else c + at


@dataclasses.dataclass(frozen=True)
class G7xExpansion(LatheExpansion):
    """LinuxCNC G70-G72 lines written as the interpreter's moves (:func:`expand_g7x`)."""

    WHAT = "LinuxCNC lathe cycles G70/G71/G72 written as the interpreter's moves ({n})"


def refuse_kept(path, events) -> None:
    """Refuse (InputError) a LinuxCNC G70-G72 left as a cycle (no ``--expand-cycles``): its contour is an o-subroutine
    the cycle reads and the written program, the flat one, no longer defines it (the cycle line kept would name a
    subroutine LinuxCNC cannot find), and the passes the interpreter computes from a compensated contour (offsets,
    roughing levels) are not the compensated passes."""
    from errormap.io import InputError
    for line, col, _, e, code in (e for e in events if e[2] == "lathe-g7x"):
        raise InputError(f"{path}: line {line + 1}, column {col}: '{code}' ({WHAT[CODES[code][0]]}, contour o{e[3]}) "
                         "kept as a cycle: the written program is the flat one (its subroutines expanded), which no "
                         f"longer defines o{e[3]}, and the moves LinuxCNC computes from a compensated contour are not "
                         "the compensated moves; use --expand-cycles (the cycle written as its moves, each compensated)")


def expand_g7x(prog, path, reparse):
    """``prog`` with every LinuxCNC G70-G72 written as the interpreter's moves (``--expand-cycles``;
    :func:`compensation.nc_contour.expand_lines`); ``prog`` itself where there is none."""
    cycles = {e[0]: e for e in prog.events if e[2] == "lathe-g7x"}
    if not cycles:
        return prog
    return expand_lines(prog, path, reparse, cycles, lambda i: g7x_lines(prog.lines[i], cycles[i], i), G7xExpansion)


def g7x_lines(line, e, i: int) -> tuple:
    """``(lines, summary note)`` of the cycle of event ``e`` on ``line`` (0-based ``i``): its moves as ``G00``/
    ``G01`` and ``G02``/``G03`` lines in absolute X Z of the program's units (arc centres I K as the arc distance mode
    in force says)."""
    moves, _, arc_abs, name, unrun = e[3]
    ending = line[len(line.rstrip("\r\n")):] or "\n"
    out, at = [], None
    for code, p, c in moves:
        words = f"{code[0]}0{code[1]} X{_word_text(p.imag)} Z{_word_text(p.real)}"
        if c is not None:
            k = c if arc_abs else c - at
            words += f" I{_word_text(k.imag)} K{_word_text(k.real)}"
        out.append(words + ending)
        at = p
    read = (f"; its O-word lines {', '.join(map(str, unrun))} read and not run, as the interpreter reads a contour "
            "(a loop's body once)") if unrun else ""
    return out, note("line ", i + 1, f": {e[4]} (contour o{name}) expanded: {len(moves)} moves as LinuxCNC's "
                     f"interpreter computes them, each compensated point by point{read}")
