"""LinuxCNC's splines in the XY plane, read exactly (LinuxCNC G-code reference, "G5 Cubic spline",
"G5.1 Quadratic spline"):

* ``G5 X Y I J P Q``: a cubic Bézier from the current point P0 to the end P3 = (X, Y), with the control
  points P1 = P0 + (I, J) and P2 = P3 + (P, Q). ``P`` and ``Q`` are required; ``I`` and ``J`` both or
  neither; without them (only right after a ``G5`` move) P1 = P0 − (P, Q) of that move, so the new
  cubic starts in the direction the last one ended.
* ``G5.1 X Y I J``: a quadratic Bézier from P0 to P2 = (X, Y), control point P1 = P0 + (I, J) (a missing
  one of ``I``/``J`` is 0; both missing or zero is an error).

``X``/``Y`` follow ``G90``/``G91`` as any axis word; ``I J P Q`` are offsets (mm or inch as the line's
units). Only under ``G17`` and only with ``X``/``Y`` axis words (other axes keep their values). A spline
is compensated by sampling the exact curve with chords whose deviation from it stays within the
tolerance (:func:`spline_segments`) and written as compensated ``G1`` moves, as arcs are.
"""
from __future__ import annotations

import math

import numpy as np

from .gcode_state import MM_PER_INCH, _Refuse
from .gcode_words import GMove

def spline_move(idx, st, by: dict, axis_words: dict, motion_word, ax) -> GMove:
    """The :class:`GMove` (kind ``"spline"``) of a ``G5``/``G5.1`` line (``st.mode``); its ``arc`` holds the
    control points ``ctrl`` ((4, 2) or (3, 2) mm, in the columns ``ju`` ``jv`` of X and Y); advances
    ``st.pos`` and keeps ``st.spline_pq`` (the P Q offset of a G5) for the next ``G5`` without I J."""
    code = st.mode
    first = min([*axis_words.values(), *(by[a] for a in "IJPQ" if a in by)], key=lambda w: w.start)
    if st.plane != "G17":
        raise _Refuse(first.start + 1, f"'{code}' in the {st.plane} plane (splines are defined in G17 XY only)")
    if "X" not in ax.words or "Y" not in ax.words:
        raise _Refuse(first.start + 1, f"'{code}': the machine {ax.machine!r} has no X and Y axes")
    for a, w in axis_words.items():
        if a not in ("X", "Y"):
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {code} line (a spline moves X and Y only)")
    for a in ("K", "R") + (("P", "Q") if code == "G5.1" else ()):
        if a in by:
            raise _Refuse(by[a].start + 1, f"'{a}{by[a].text}' on a {code} line ({st.dialect.splines[code]})")
    if not axis_words:
        raise _Refuse(first.start + 1, f"'{first.letter}{first.text}' on a {code} line without X or Y")
    jx, jy = ax.words.index("X"), ax.words.index("Y")
    start = st.pos.copy()
    if not (np.isfinite(start[jx]) and np.isfinite(start[jy])):
        raise _Refuse(first.start + 1, f"'{code}' before X and Y are known (its start is the current point)")
    scale = MM_PER_INCH if st.inch else 1.0
    end = start.copy()
    for a, j in (("X", jx), ("Y", jy)):
        if a in axis_words:
            v = axis_words[a].value * scale
            end[j] = start[j] + v if st.incremental else v
    known = np.isfinite(end)
    if not known.all():
        missing = ", ".join(a for a, k in zip(ax.words, known) if not k)
        raise _Refuse(first.start + 1, f"'{code}': motion before {ax.joined('and')} are all known (no value yet "
                                       f"for {missing})")
    p0, p_end = start[[jx, jy]], end[[jx, jy]]
    off = {a: by[a].value * scale for a in "IJPQ" if a in by}
    if code == "G5":
        ctrl, pq = _cubic(by, off, p0, p_end, st, first)
    else:
        if not off.get("I", 0.0) and not off.get("J", 0.0):
            raise _Refuse(first.start + 1, "'G5.1' without a non-zero I or J (its control point's offset)")
        ctrl, pq = (p0, p0 + (off.get("I", 0.0), off.get("J", 0.0)), p_end), None
    words = dict(axis_words)
    words.update({a: by[a] for a in "IJPQ" if a in by})
    move = GMove(idx, "spline", start, end, "inch" if st.inch else "mm", st.incremental, words, motion_word, True,
                 known=known)
    move.arc = {"ju": jx, "jv": jy, "ctrl": tuple(tuple(float(c) for c in p) for p in ctrl)}
    st.pos = end
    st.spline_pq = None if pq is None else (pq, end.copy())
    return move


def _cubic(by, off, p0, p3, st, first):
    """Control points of a ``G5`` and its (P, Q) offset (mm)."""
    for a in ("P", "Q"):
        if a not in by:
            raise _Refuse(first.start + 1, f"'G5' without {a} (P and Q are required: the second control point's "
                                           "offset from the end)")
    if ("I" in by) != ("J" in by):
        w = by["I"] if "I" in by else by["J"]
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' alone on a G5 line (I and J both, or neither)")
    pq = np.array([off["P"], off["Q"]])
    if "I" in by:
        p1 = p0 + (off["I"], off["J"])
    else:
        prev = getattr(st, "spline_pq", None)
        if prev is None or not np.array_equal(prev[1], st.pos):
            raise _Refuse(first.start + 1, "'G5' without I and J right after a move that is not a G5 spline (only a "
                                           "continuing G5 may omit them)")
        p1 = p0 - prev[0]
    return (p0, p1, p3 + pq, p3), pq


def spline_points(g: dict, t) -> np.ndarray:
    """The curve's (X, Y) mm at parameters ``t`` (m,) -> (m, 2) (Bernstein form)."""
    c = np.asarray(g["ctrl"], dtype=float)
    t = np.asarray(t, dtype=float)[:, None]
    n = len(c) - 1
    return sum(math.comb(n, i) * t ** i * (1.0 - t) ** (n - i) * c[i][None, :] for i in range(n + 1))


def second_derivative_bound(g: dict) -> float:
    """max over [0, 1] of |B''(t)| (mm): B'' is linear (cubic) or constant (quadratic) in t, so its norm is
    largest at an end."""
    c = np.asarray(g["ctrl"], dtype=float)
    n = len(c) - 1
    d2 = [n * (n - 1) * np.linalg.norm(c[i] - 2.0 * c[i + 1] + c[i + 2]) for i in range(n - 1)]
    return float(max(d2))


def spline_segments(g: dict, tol_mm: float) -> int:
    """Chords (equal steps of the parameter) so every point of the curve lies within ``tol_mm`` of its chord
    (≥ 1): |B(t) − chord(t)| ≤ h²/8 · max|B''| for a step h, so h = sqrt(8·tol / max|B''|)."""
    m = second_derivative_bound(g)
    if m <= 0.0:
        return 1
    return max(1, int(math.ceil(math.sqrt(m / (8.0 * tol_mm)) - 1e-12)))


def spline_extent_mm(g: dict) -> float:
    """The widest distance between two control points (mm): the curve lies in their convex hull, so no chord
    of it is longer."""
    c = np.asarray(g["ctrl"], dtype=float)
    return float(max(np.linalg.norm(a - b) for a in c for b in c))


def spline_lines(program) -> list:
    """The 1-based lines of a parsed program's spline moves (its block-wise table's curved rows, or its moves)."""
    t = program.table
    moves = [t.objects[t.obj[k]] for k in np.flatnonzero(t.kind == 2).tolist()] if t is not None else program.moves
    return [m.index + 1 for m in moves if m.kind == "spline"]
