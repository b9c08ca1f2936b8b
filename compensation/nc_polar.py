"""LinuxCNC's polar coordinates, written out as the X and Y they mean (the flat program of
:mod:`compensation.nc_expand`).

LinuxCNC G-code reference, "Polar Coordinates": ``@`` is the distance and ``^`` the angle (degrees,
counter-clockwise from +X about Z) of the **XY** point of a move, always from the XY zero of the current
coordinate system (whatever the plane). Its interpreter (``find_ends``) reads them so:

* absolute (``G90``): both given: ``X = @·cos ^``, ``Y = @·sin ^``; ``@`` alone keeps the current point's
  angle (an error at the origin); ``^`` alone keeps its distance;
* incremental (``G91``): cumulative: ``@`` adds to the current point's distance along its angle, then ``^``
  adds to the angle of the point so reached, keeping its distance (an error at the origin: "indeterminate");
* with ``X`` or ``Y`` on the line, or with ``G53``, it is an error.

Read here exactly that way on ``G0``/``G1`` lines and as the end of a ``G2``/``G3`` arc (its interpreter takes
an arc's end from the same function; ``I J K R`` stay as written), from the controller position the lines
before reach (:class:`compensation.gcode_classify.ProgramState`), and written in the line's own distance mode
and units (``@5 ^30`` → ``X4.3301270189 Y2.5``; under ``G91`` the increments).

A canned-cycle line (``G73 G74 G76 G81``-``G89`` on the line, in ``G17``) takes its hole from the polar words as
its interpreter's ``convert_cycle_xy`` does: under ``G90`` the distance ``@`` (else the current point's) at the
angle ``^`` (else the current point's), written as the hole's ``X Y`` (``L`` repeats drill that hole again);
under ``G91`` each of the ``L`` repeats (default 1) first adds ``@`` to the distance of the previous hole, then
``^`` to its angle (an error at the origin), so ``G91 G81 R.1 Z-.5 ^60 L6`` drills six holes 60° apart on the
circle through the current point. The holes are not equally spaced in X Y: the line is written with the first
hole's ``X Y`` increments and without its ``L``, and one modal-repeat line ``X.. Y..`` per further hole
(:mod:`compensation.nc_cycles` reads them as the same series: the same R plane, bottom and clear level).

Everything else with a polar word is refused naming it: a spline or NURBS, a canned cycle's modal repeat (the
reader does not follow the controller's position after a cycle line) or a cycle outside ``G17``, a non-modal
code (``G53 G28 G30 G92 G10 G4``), a work-system or other mode change on the line, lathe diameter mode, a dialect
other than LinuxCNC, a position the reader does not know.
"""
from __future__ import annotations

import math
import re

POLAR = re.compile(r"[@^]")
"""A polar word's mark (outside comments)."""
PLAIN_G = {0.0: "G0", 1.0: "G1", 2.0: "G2", 3.0: "G3", 17.0: "G17", 18.0: "G18", 19.0: "G19", 20.0: "G20", 21.0: "G21", 90.0: "G90",
           91.0: "G91", 93.0: "G93", 94.0: "G94", 61.0: "G61", 61.1: "G61.1", 64.0: "G64", 40.0: "G40",
           49.0: "G49", 98.0: "G98", 99.0: "G99"}
"""G codes a polar line may carry: the motions whose end LinuxCNC's interpreter takes from the polar words
(``find_ends``: G0 G1 and the arcs G2 G3), the canned cycles (:data:`CYCLE_G`) and modes that do not move the
current point or its frame."""
CYCLE_G = {73.0: "G73", 74.0: "G74", 76.0: "G76", **{float(k): f"G{k}" for k in range(81, 90)}}
"""Canned cycles whose hole LinuxCNC's ``convert_cycle_xy`` takes from the polar words."""
MM_PER_INCH = 25.4


def has_polar(code: str) -> bool:
    """Whether a program's text (comments blanked or not) holds a polar word's mark."""
    return POLAR.search(re.sub(r"\([^)]*\)|;[^\n]*", "", code)) is not None


def polar_cuts(m, pc: int, body: str, words, value, fmt) -> tuple:
    """``(cuts, more)``: the cuts ``(start, end, text)`` that write a line's polar words as X and Y (module
    docstring), or ``([], [])`` where the line has none, and the lines to write after it (a ``G91`` canned cycle's
    further holes). ``m``: the expander (its ``state``, ``given`` dialect and ``_err``); ``words``: the line's
    ``(letter, start, end, node, value)`` items of its text ``body``; ``value(w)``: a word's number;
    ``fmt(v, col)``: a number as the flat program writes it."""
    polar = [w for w in words if w[0] in "@^"]
    if not polar:
        return [], []
    first = polar[0]
    col = first[1] + 1

    def refuse(msg, at=col):
        return m._err(pc, at, f"'{first[0]}': a LinuxCNC polar coordinate {msg}")
    if m.given not in (None, "linuxcnc"):
        raise refuse(f"on a {m.given} program (polar words are LinuxCNC's: --dialect linuxcnc)")
    seen = set()
    for w in polar:
        if w[0] in seen:
            raise refuse(f"given twice on the line", w[1] + 1)
        seen.add(w[0])
    for w in words:
        if w[0] in "XY":
            raise refuse(f"with '{w[0]}' on the line (LinuxCNC: 'Cannot specify X or Y words with polar coordinate')")
    motion, inch, incremental = _line_modes(m, pc, words, value, refuse)
    st = m.state
    if st is None or st.unknown_after is not None:
        after = "" if st is None else f" after line {m.named(st.unknown_after)} (a line the reader does not follow)"
        raise refuse(f"needs the current X Y, which is not known{after}: write the point as X Y")
    s, ax = st.st, st.ax
    if s.diameter:
        raise refuse("in lathe diameter mode (G7): not read")
    if motion not in ("G0", "G1", "G2", "G3", *CYCLE_G.values()):
        raise refuse(f"on a {motion or 'line without a motion mode'} move: read on G0 G1 G2 G3 and canned cycles "
                     "only (write the end as X Y)")
    scale = MM_PER_INCH if inch else 1.0
    cx, cy = (s.pos[ax.words.index(a)] / scale for a in "XY")
    given = {w[0]: value(w) for w in polar}
    cycle = motion in CYCLE_G.values()
    if cycle and s.plane != "G17":
        raise refuse(f"on a {motion} cycle in {s.plane}: LinuxCNC reads polar words in G17 only")
    if (incremental or len(given) < 2) and not (math.isfinite(cx) and math.isfinite(cy)):
        raise refuse("before X and Y are known (a lone or incremental polar word reads the current point)")
    drop = [(len(body[:w[1]].rstrip(" \t")), w[2], "") for w in polar[1:]]
    if cycle:
        holes = _cycle_holes(cx, cy, given, incremental, _repeats(words, value, refuse), refuse)
        steps = [(px - qx, py - qy) for (px, py), (qx, qy) in zip(holes, [(cx, cy)] + holes[:-1])] if incremental \
            else holes[:1]
        text = f"X{fmt(steps[0][0], col)} Y{fmt(steps[0][1], col)}"
        cut_l = [(len(body[:w[1]].rstrip(" \t")), w[2], "") for w in words if w[0] == "L"] if incremental else []
        return [(first[1], first[2], text)] + drop + cut_l, [f"X{fmt(dx, col)} Y{fmt(dy, col)}" for dx, dy in steps[1:]]
    px, py = _polar_point(cx, cy, given, incremental, refuse)
    if incremental:
        px, py = px - cx, py - cy
    text = f"X{fmt(px, col)} Y{fmt(py, col)}"
    return [(first[1], first[2], text)] + drop, []


def _repeats(words, value, refuse) -> int:
    """A cycle line's ``L`` (LinuxCNC: the repeats; absent: 1)."""
    lw = [w for w in words if w[0] == "L"]
    if not lw:
        return 1
    n = value(lw[0])
    if lw[0][3] is not None:
        raise refuse("on a cycle line whose 'L' is an expression: write the repeats as a number", lw[0][1] + 1)
    if n != int(n) or n < 1:
        raise refuse(f"with 'L' = {n:g} on a cycle line: the repeats must be a whole number ≥ 1", lw[0][1] + 1)
    return int(n)


def _cycle_holes(cx, cy, given, incremental, repeats, refuse) -> list:
    """A polar cycle line's holes (program units; ``convert_cycle_xy``): under G90 one (its L repeats drill it
    again), from the words or the current point's distance and angle; under G91 one per repeat, each from the
    previous by ``@`` along its direction, then ``^`` about the XY zero."""
    if not incremental:
        r = given["@"] if "@" in given else math.hypot(cx, cy)
        th = math.radians(given["^"]) if "^" in given else math.atan2(cy, cx)
        return [(r * math.cos(th), r * math.sin(th))]
    holes, (px, py) = [], (cx, cy)
    for _ in range(repeats):
        for word in ("@", "^"):
            if word not in given:
                continue
            if px == 0.0 and py == 0.0:
                raise refuse("incremental (G91) at the origin (LinuxCNC: 'indeterminate when at the origin')")
            th, r = math.atan2(py, px), math.hypot(py, px)
            th, r = (th, r + given["@"]) if word == "@" else (th + math.radians(given["^"]), r)
            px, py = r * math.cos(th), r * math.sin(th)
        holes.append((px, py))
    return holes


def _line_modes(m, pc, words, value, refuse):
    """The line's motion (``"G0"`` …, its own or the modal one), units (inch) and distance mode."""
    st = m.state
    s = st.st if st is not None else None
    motion = None if s is None else s.mode
    inch = False if s is None else s.inch
    incremental = False if s is None else s.incremental
    for w in words:
        if w[0] != "G":
            continue
        v = round(value(w), 1)
        code = PLAIN_G.get(v)
        if code is None and v not in CYCLE_G:
            raise refuse(f"on a line with G{v:g}: read with G0 G1 G2 G3, canned cycles and plain modes only")
        if code is None and v in CYCLE_G:
            motion = CYCLE_G[v]
        elif code in ("G0", "G1"):
            motion = code
        elif code in ("G20", "G21"):
            inch = code == "G20"
        elif code in ("G90", "G91"):
            incremental = code == "G91"
    return motion, inch, incremental


def _polar_point(cx, cy, given, incremental, refuse):
    """LinuxCNC's end point (program units) from the current point and the polar words (module docstring)."""
    at_origin = cx == 0.0 and cy == 0.0
    if not incremental:
        if "@" in given and "^" in given:
            r, th = given["@"], math.radians(given["^"])
        elif "@" in given:
            if at_origin:
                raise refuse("'@' alone at the origin (LinuxCNC: 'Must specify angle in polar coordinate if at the "
                             "origin')")
            r, th = given["@"], math.atan2(cy, cx)
        else:
            r, th = math.hypot(cx, cy), math.radians(given["^"])
        return r * math.cos(th), r * math.sin(th)
    px, py = cx, cy
    if "@" in given:
        if at_origin:
            raise refuse("incremental (G91) at the origin (LinuxCNC: 'indeterminate when at the origin')")
        th, r = math.atan2(py, px), math.hypot(py, px) + given["@"]
        px, py = r * math.cos(th), r * math.sin(th)
    if "^" in given:
        if px == 0.0 and py == 0.0:
            raise refuse("incremental (G91) at the origin (LinuxCNC: 'indeterminate when at the origin')")
        th, r = math.atan2(py, px) + math.radians(given["^"]), math.hypot(py, px)
        px, py = r * math.cos(th), r * math.sin(th)
    return px, py
