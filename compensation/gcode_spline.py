"""LinuxCNC's splines in the XY plane, read exactly: ``G5`` cubic and ``G5.1`` quadratic Béziers and
``G5.2`` … ``G5.3`` NURBS blocks (LinuxCNC G-code reference; what is read and refused:
docs/reference/tool-paths.md).
A spline is compensated as chords whose deviation from the exact curve stays within the tolerance
(:func:`spline_segments`), written as compensated ``G1`` moves, as arcs are.
"""
from __future__ import annotations

import math

import numpy as np

from .gcode_state import MM_PER_INCH, _Refuse
from .gcode_words import GMove
from .nc_expand import source_lines

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
    known = _known(end, ax, first, f"'{code}': motion")
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


def _known(end, ax, word, what: str) -> np.ndarray:
    """Which axes of a curve's ``end`` are known (k,); refused at ``word`` unless all are."""
    known = np.isfinite(end)
    if not known.all():
        missing = ", ".join(a for a, k in zip(ax.words, known) if not k)
        raise _Refuse(word.start + 1, f"{what} before {ax.joined('and')} are all known (no value yet "
                                      f"for {missing})")
    return known


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
    """The curve's (X, Y) mm at parameters ``t`` (m,) in [0, 1] -> (m, 2) (Bernstein form; a NURBS, with weights
    ``w``: the rational B-spline of :func:`nurbs_end` at u = t·(n − k + 2))."""
    c = np.asarray(g["ctrl"], dtype=float)
    if "w" in g:
        w = np.asarray(g["w"], dtype=float)
        N = nurbs_basis(len(c), g["order"], np.asarray(t, dtype=float) * (len(c) - g["order"] + 1)) * w[None, :]
        return (N @ c) / N.sum(axis=1, keepdims=True)
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
    (≥ 1): |B(t) − chord(t)| ≤ h²/8 · max|B''| for a step h, so h = sqrt(8·tol / max|B''|). A NURBS: the
    fewest chords (from one per control point, doubled) whose deviation from the curve, at
    :data:`DEVIATION_SAMPLES` points of every chord, is within half ``tol_mm`` (the margin for the curve
    between the checked points; no closed bound as the Bézier's)."""
    if "w" in g:
        return _nurbs_segments(g, tol_mm)
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
    """The lines of a parsed program's spline moves (its block-wise table's curved rows, or its moves), as reports
    name them (:func:`compensation.nc_expand.source_line`)."""
    t = program.table
    moves = [t.objects[t.obj[k]] for k in np.flatnonzero(t.kind == 2).tolist()] if t is not None else program.moves
    return source_lines(program, [m.index + 1 for m in moves if m.kind == "spline"])


# ---------------------------------------------------------------------------- NURBS (G5.2 ... G5.3)
NURBS_DEFAULT_ORDER = 3
"""LinuxCNC: the order is 3 unless a G5.2 line's L is greater than 3 (its interpreter ignores L ≤ 3)."""
DEVIATION_SAMPLES = 32
"""Curve points per chord at which a NURBS's chords are checked against the curve (:func:`spline_segments`)."""


def nurbs_line(idx, st, by: dict, axis_words: dict, motion_word, ax) -> None:
    """A line of a LinuxCNC NURBS block (``G5.2`` mode; module docstring of :func:`nurbs_end`): its control point
    and weight into ``st.nurbs``; the first line of a block takes the current point as the first control point."""
    first = min([*axis_words.values(), *(by[a] for a in "PL" if a in by)] or [motion_word], key=lambda w: w.start)
    if st.plane != "G17" or st.incremental or st.diameter:
        raise _Refuse(first.start + 1, "'G5.2' under " + ("G91 (incremental control points follow the block's start, not "
                                       "the last point)" if st.incremental else "G7" if st.diameter else st.plane)
                      + ": read in G17 G90 only")
    for a, w in axis_words.items():
        if a not in ("X", "Y"):
            raise _Refuse(w.start + 1, f"'{a}{w.text}' on a G5.2 line (a NURBS control point is X Y: LinuxCNC ignores it)")
    for a in "IJKRQ":
        if a in by:
            raise _Refuse(by[a].start + 1, f"'{a}{by[a].text}' on a G5.2 line (G5.2 takes X Y P L)")
    if ("X" in axis_words) != ("Y" in axis_words):
        raise _Refuse(first.start + 1, "a NURBS control point needs both X and Y (LinuxCNC: 'You must specify both X "
                                       "and Y coordinates for Control Points')")
    jx, jy = ax.words.index("X"), ax.words.index("Y")
    p = by.get("P")
    if st.nurbs is None:
        if not (np.isfinite(st.pos[jx]) and np.isfinite(st.pos[jy])):
            raise _Refuse(first.start + 1, "'G5.2' before X and Y are known (the current point is the first control point)")
        w0 = p.value if p is not None and "X" not in axis_words and p.value > 0 else 1.0
        st.nurbs = {"start": st.pos.copy(), "ctrl": [(float(st.pos[jx]), float(st.pos[jy]))], "w": [w0],
                    "order": NURBS_DEFAULT_ORDER, "lines": []}
    elif p is not None and "X" not in axis_words:
        raise _Refuse(p.start + 1, f"'P{p.text}' without X and Y: only the first control point's weight is given so "
                                   "(LinuxCNC)")
    st.nurbs["lines"].append(idx)
    if "L" in by:
        lw = by["L"]
        if lw.value != int(lw.value) or lw.value < 1:
            raise _Refuse(lw.start + 1, f"'L{lw.text}': the NURBS order is a whole number")
        if lw.value > NURBS_DEFAULT_ORDER:
            st.nurbs["order"] = int(lw.value)
    if "X" in axis_words:
        if p is None or p.value <= 0:
            raise _Refuse(first.start + 1, "a NURBS control point needs a positive weight P (LinuxCNC: 'Must specify "
                                           "positive weight P for every Control Point')")
        scale = MM_PER_INCH if st.inch else 1.0
        st.nurbs["ctrl"].append((axis_words["X"].value * scale, axis_words["Y"].value * scale))
        st.nurbs["w"].append(float(p.value))


def nurbs_end(idx, st, by: dict, axis_words: dict, motion_word, ax) -> GMove:
    """The ``G5.3`` line: the NURBS of the block (LinuxCNC G-code reference, "G5.2 G5.3 NURBS Block"; its
    interpreter's curve: control points P_i with weights w_i, order k (L), the clamped knot vector
    0 (k times), 1 … n − k + 1, n − k + 2 (k times) for n + 1 points, ``C(u) = Σ w_i N_i,k(u) P_i / Σ w_i
    N_i,k(u)`` over u in [0, n − k + 2]) as one move (kind ``"spline"``, ``arc`` its ``ctrl``, weights ``w``,
    ``order`` and the block's ``lines``) from the block's start to its last control point."""
    if st.nurbs is None:
        raise _Refuse(motion_word.start + 1, "'G5.3' without a G5.2 block before it")
    extra = [w for a, w in by.items() if a not in ("N", "G")]
    if extra:
        raise _Refuse(extra[0].start + 1, f"'{extra[0].letter}{extra[0].text}' on the G5.3 line (it ends the block)")
    nb, st.nurbs = st.nurbs, None
    if len(nb["ctrl"]) < nb["order"]:
        raise _Refuse(motion_word.start + 1, f"'G5.3': {len(nb['ctrl'])} control points (the current point and "
                                             f"{len(nb['ctrl']) - 1} G5.2 points); the order L = {nb['order']} needs "
                                             "at least that many (LinuxCNC)")
    jx, jy = ax.words.index("X"), ax.words.index("Y")
    start, end = nb["start"], nb["start"].copy()
    end[jx], end[jy] = nb["ctrl"][-1]
    known = _known(end, ax, motion_word, "'G5.3': a NURBS")
    move = GMove(idx, "spline", start, end, "inch" if st.inch else "mm", False, {}, motion_word, True, known=known)
    move.arc = {"ju": jx, "jv": jy, "ctrl": tuple(nb["ctrl"]), "w": tuple(nb["w"]), "order": nb["order"],
                "block": tuple(nb["lines"])}
    st.pos = end
    st.mode = None  # LinuxCNC: no motion mode after G5.3
    return move


def _knots(count: int, k: int) -> np.ndarray:
    """LinuxCNC's knot vector for ``count`` control points and order ``k`` (:func:`nurbs_end`)."""
    n = count - 1
    return np.array([0] * k + list(range(1, n - k + 2)) + [n - k + 2] * k, dtype=float)


def nurbs_basis(count: int, k: int, u) -> np.ndarray:
    """The B-spline basis N_i,k(u) (m, count) of LinuxCNC's knot vector (order ``k``, degree ``k − 1``;
    ``scipy.interpolate.BSpline.design_matrix``, the last knot span closed)."""
    from scipy.interpolate import BSpline
    return BSpline.design_matrix(np.asarray(u, dtype=float), _knots(count, k), k - 1).toarray()


def _nurbs_segments(g: dict, tol_mm: float) -> int:
    m = max(1, len(g["ctrl"]) - 1)
    s = (np.arange(DEVIATION_SAMPLES) + 0.5) / DEVIATION_SAMPLES
    while True:
        ts = np.linspace(0.0, 1.0, m + 1)
        ends = spline_points(g, ts)
        a, b = ends[:-1, None, :], ends[1:, None, :]
        pts = spline_points(g, (ts[:-1, None] + s[None, :] / m).ravel()).reshape(m, DEVIATION_SAMPLES, 2)
        ab = b - a
        lam = np.clip(((pts - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
        dev = np.linalg.norm(pts - (a + lam[..., None] * ab), axis=-1).max()
        if dev <= tol_mm / 2 or m >= 1 << 20:
            return m
        m *= 2
