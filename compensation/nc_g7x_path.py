"""The moves of LinuxCNC's lathe cycles ``G70`` (finishing) and ``G71``/``G72`` (roughing, ``.1`` without pockets,
``.2`` the pockets only) from their contour, computed as LinuxCNC's interpreter computes them (``interp_g7x.cc``,
LinuxCNC 2.9, read as the reference; this is its algorithm written here, step by step, with its tolerances).

Points are complex numbers ``z + 1j·x`` (the interpreter's convention: real part Z, imaginary part X), in the
program's units. A contour is a list of segments, each a straight line or an arc (``ccw``: G3), the first one the
lead-in from the cycle's start point (X, Z of the cycle line) to the contour's first point. Before cutting, the
interpreter turns the contour so that X and Z decrease along it (:meth:`Path.swap`; for G72, and a G70 contour not
monotonic in Z, first a quarter turn, :meth:`Path.rotate`) and maps every move back (:data:`MAPS`).

- ``G70`` (:func:`finishing`): P passes, pass k (from P down to 1) at distance (k − 1)(D − E)/P + E from the contour
  (:meth:`Path.add_distance`); each a rapid to the start point, a rapid to the offset contour's first point, then its
  segments.
- ``G71``/``G72`` (:func:`roughing`): the contour offset by D, its start rapid, then :meth:`Path.pocket`: cuts at
  X levels I apart below the start, each a feed along Z to the contour, a rapid escape of R·(1 + j) (scaled down for a
  short cut), a rapid back and a move to the next level; along the contour where it rises (pockets cut after,
  recursively, unless ``.1``).

Where the reference's code would loop without end, divide by zero, dereference past the list or throw its own
error ("Not monotonic", "x too large in straight dive", "Cannot intersect parallel lines"), :class:`G7xError` is
raised with its reason (the reader refuses the cycle naming it)."""
from __future__ import annotations

import copy
import math

MAPS = {0: (False, lambda p: p), 1: (True, lambda p: -p.conjugate()), 2: (True, lambda p: p.conjugate()),
        3: (False, lambda p: -p), 4: (False, lambda p: 1j * p), 5: (True, lambda p: (1j * p).conjugate()),
        6: (True, lambda p: -(1j * p).conjugate()), 7: (False, lambda p: -1j * p)}
"""Flip state -> (G2/G3 swapped, point map) that writes a move of the turned contour in the program's axes."""
MAX_STEPS = 100_000
"""Offset steps or roughing levels beyond this: the reference would not end (a contour or words it loops on)."""


class G7xError(Exception):
    """The cycle cannot be computed as the reference computes it (the message says why)."""


class Out:
    """The moves written: ``moves`` ``[(code, end, centre or None)]`` in the program's axes (``code`` G0 G1 G2 G3),
    through the flip state's map."""

    def __init__(self, state: int):
        self.swap, self.map = MAPS[state]
        self.moves = []

    def rapid(self, p):
        self.moves.append(("G0", self.map(p), None))

    def line(self, p):
        self.moves.append(("G1", self.map(p), None))

    def arc(self, ccw: bool, c, p):
        self.moves.append(("G3" if ccw != self.swap else "G2", self.map(p), self.map(c)))


class Straight:
    def __init__(self, s: complex, e: complex):
        self.s, self.e = complex(s), complex(e)

    def cuts(self, x: float) -> list:
        """The Z of the points at X = ``x`` (both ends of a segment along Z)."""
        s, e = self.s, self.e
        if min(s.imag, e.imag) > x + 1e-6 or max(s.imag, e.imag) < x - 1e-6:
            return []
        if abs((s - e).imag) < 1e-6:
            return [s.real, e.real]
        return [(x - s.imag) / (e.imag - s.imag) * (e.real - s.real) + s.real]

    def climb(self, at: list, out: Out) -> bool:
        if self.e.imag < self.s.imag:
            return True
        if abs(at[0] - self.s) > 1e-6:
            raise G7xError("the reference's 'How did we get here?' (a climb not from the segment's start)")
        out.line(self.e)
        at[0] = self.e
        return False

    def climb_only(self, at: list, out: Out) -> None:
        if self.e.imag < self.s.imag:
            return
        hits = self.cuts(at[0].imag)
        if hits:
            at[0] = complex(hits[0], at[0].imag)
            out.line(at[0])
            out.line(self.e)
            at[0] = self.e

    def dive(self, at: list, x: float, out: Out, fast: bool) -> bool:
        if self.s.imag <= self.e.imag:
            return True
        to = self.e
        if x >= self.e.imag:
            hits = self.cuts(x)
            if not hits:
                raise G7xError("the reference's 'x too large in straight dive'")
            to = complex(hits[0], x)
        (out.rapid if fast else out.line)(to)
        at[0] = to
        return False

    def draw(self, out: Out) -> None:
        out.line(self.e)

    def offset(self, d: float) -> None:
        v = 1j * d * (self.s - self.e) / abs(self.s - self.e)
        self.s, self.e = self.s + v, self.e + v

    def radius(self) -> float:
        return abs(self.s - self.e)

    def monotonic(self) -> bool:
        return (self.e - self.s).real <= 1e-3

    def transform(self, f, flip: bool) -> None:
        self.s, self.e = f(self.s), f(self.e)


class Arc(Straight):
    def __init__(self, ccw: bool, s: complex, c: complex, e: complex):
        super().__init__(s, e)
        self.ccw, self.c = bool(ccw), complex(c)

    def _on(self, p) -> bool:
        a = ((self.s - self.c).conjugate() * (p - self.c)).imag
        b = ((self.e - self.c).conjugate() * (p - self.c)).imag
        return (a >= -1e-6 and b <= 1e-6) if self.ccw else (a <= 1e-6 and b >= -1e-6)

    def cuts(self, x: float) -> list:
        r = abs(self.s - self.c)
        q = -(x - r - self.c.imag) * (x + r - self.c.imag)
        if q < -1e-6:
            return []
        q = math.sqrt(max(q, 0.0))
        return [z for z in (self.c.real + q, self.c.real - q) if self._on(complex(z, x))]

    def _top(self):
        """The arc's end, or for a G3 ending beyond its centre's Z, its top (the point at the centre's Z)."""
        return complex(self.c.real, self.c.imag + abs(self.s - self.c)) if self.e.real < self.c.real else self.e

    def climb(self, at: list, out: Out) -> bool:
        if not self.ccw:
            if at[0].real > self.c.real:
                return True
            if abs(at[0] - self.e) > 1e-3:
                out.arc(False, self.c, self.e)
            at[0] = self.e
            return False
        if at[0].real < self.c.real:
            return True
        to = self._top()
        if abs(at[0] - to) > 1e-3:
            out.arc(True, self.c, to)
        at[0] = to
        return True

    def climb_only(self, at: list, out: Out) -> None:
        hits = self.cuts(at[0].imag)
        if not hits or (hits[-1] > self.c.real if not self.ccw else hits[0] < self.c.real):
            return
        at[0] = complex(hits[0] if self.ccw else hits[-1], at[0].imag)
        out.line(at[0])
        to = self._top() if self.ccw else self.e
        if abs(at[0] - to) > 1e-3:
            out.arc(self.ccw, self.c, to)
        at[0] = to

    def dive(self, at: list, x: float, out: Out, fast: bool) -> bool:
        if abs(at[0] - self.e) < 1e-3:
            return False
        hits = self.cuts(x)
        if self.ccw:
            if at[0].real > self.c.real:
                return True
            whole = not hits or hits[-1] > self.c.real
            to = self.e if whole else complex(hits[-1], x)
        else:
            if at[0].real <= self.c.real:
                return True
            whole = not hits or hits[0] < self.c.real
            to = self.e if whole else complex(hits[0], x)
        if whole or abs(at[0] - to) > 1e-3:
            out.arc(self.ccw, self.c, to)
        at[0] = to
        return False

    def draw(self, out: Out) -> None:
        out.arc(self.ccw, self.c, self.e)

    def offset(self, d: float) -> None:
        r = abs(self.s - self.c)
        f = (r + (d if self.ccw else -d)) / r
        self.s, self.e = f * (self.s - self.c) + self.c, f * (self.e - self.c) + self.c

    def radius(self) -> float:
        return min(abs(self.s - self.e), abs(self.s - self.c))

    def monotonic(self) -> bool:
        entry, leave, dz = (self.s - self.c).imag, (self.e - self.c).imag, (self.e - self.s).real
        if self.ccw:
            return entry >= -1e-3 and leave >= -1e-3 and dz <= -1e-3
        return entry <= 1e-3 and leave <= 1e-3 and dz <= -1e-3

    def transform(self, f, flip: bool) -> None:
        self.s, self.e, self.c = f(self.s), f(self.e), f(self.c)
        self.ccw = self.ccw != flip


def _meet(cur, nxt) -> None:
    """The reference's joining of ``cur``'s end and ``nxt``'s start after an offset step: two lines at their
    lines' crossing, a line and an arc at the crossing nearer ``nxt``'s start, two arcs turning the same way at their
    circles' crossing (turning opposite ways: left as they are)."""
    if isinstance(nxt, Arc) and isinstance(cur, Arc):
        if nxt.ccw != cur.ccw:
            return
        a, b, c = abs(nxt.s - nxt.c), abs(cur.s - cur.c), abs(nxt.c - cur.c)
        if a == 0 or c == 0:
            raise G7xError("concentric or degenerate arcs in the offset contour (the reference divides by zero)")
        cos_b = (c * c + a * a - b * b) / 2.0 / a / c
        p = complex(cos_b, math.sqrt(1.0 - min(cos_b * cos_b, 1.0))) * (cur.c - nxt.c) / c * a + nxt.c
    elif isinstance(nxt, Arc) or isinstance(cur, Arc):
        if abs(nxt.s - cur.e) < 1e-6:
            return
        line, arc = (cur, nxt) if isinstance(nxt, Arc) else (nxt, cur)
        rot = (line.s - line.e).conjugate() / abs(line.s - line.e)
        pe, pc = (arc.e - line.e) * rot, (arc.c - line.e) * rot
        b = math.sqrt(max(abs(pc - pe) ** 2 - pc.imag ** 2, 0.0))
        s1, s2 = (pc.real + b) / rot + line.e, (pc.real - b) / rot + line.e
        p = s1 if abs(nxt.s - s1) < abs(nxt.s - s2) else s2
    else:
        rot = (nxt.s - nxt.e).conjugate() / abs(nxt.s - nxt.e)
        ps, pe = (cur.s - nxt.e) * rot, (cur.e - nxt.e) * rot
        if (ps - pe).imag == 0:
            raise G7xError("the reference's 'Cannot intersect parallel lines'")
        p = (ps + ps.imag / (ps - pe).imag * (pe - ps)) / rot + nxt.e
    if not (math.isfinite(p.real) and math.isfinite(p.imag)):
        raise G7xError("the offset contour's segments do not meet (the reference computes no finite point)")
    cur.e = nxt.s = p


class Path:
    """A cycle's contour (module docstring): ``segs`` its segments, the first the lead-in; ``state`` the flip state
    (:data:`MAPS`); ``delta`` the depth of cut, ``escape`` the retract (roughing)."""

    def __init__(self, segs: list):
        if len(segs) < 2:
            raise G7xError("the contour has no segment (the subroutine moves neither X nor Z)")
        self.segs, self.state, self.delta, self.escape = segs, 0, 0.5, 0.3 + 0.3j

    def copy(self) -> "Path":
        return copy.deepcopy(self)

    def _all(self, f, flip: bool, bit: int) -> None:
        for s in self.segs:
            s.transform(f, flip)
        self.state ^= bit

    def rotate(self) -> None:
        self._all(lambda p: -1j * p, False, 4)

    def swap(self) -> None:
        """Mirror so that X and Z decrease from the first segment's end to the last one's."""
        d = self.segs[0].e - self.segs[-1].e
        if d.imag > 0:
            self._all(lambda p: p.conjugate(), True, 2)
        if d.real < 0:
            self._all(lambda p: -p.conjugate(), True, 1)

    def add_distance(self, distance: float) -> None:
        """Offset the contour (all but the lead-in) by ``distance`` away from the start point's side, in steps of at
        most half the shortest segment, arcs inserted at opened corners, the lead-in then ending at its start."""
        self.swap()
        first, segs = self.segs[0], self.segs[1:]
        if segs[-1].s == first.s:
            raise G7xError("the contour's last segment starts at the start point (the reference divides by zero)")
        if ((first.e - first.s) / (segs[-1].s - first.s)).imag < 0:
            distance = -distance
        done, steps = 0.0, 0
        while done != distance:
            steps += 1
            if steps > MAX_STEPS or not segs:
                raise G7xError("the offset contour vanishes or its steps do not end (the reference would loop)")
            step = min(min(s.radius() / 2 for s in segs), abs(distance - done))
            step = -step if distance < 0 else step
            segs = self._offset_step(segs, step, distance > 0)
            done += step
        for a, b in zip(segs, segs[1:]):
            a.e = b.s = (a.e + b.s) / 2.0
        first.e = segs[0].s
        self.segs = [first] + segs

    @staticmethod
    def _offset_step(segs: list, step: float, ccw: bool) -> list:
        kept = []
        for s in segs:
            s.offset(step)
            if s.radius() >= 1e-3:
                kept.append(s)
        if not kept:
            raise G7xError("every segment of the offset contour vanished (the reference reads an empty list)")
        segs, k = kept, 0
        while k < len(segs) - 1:
            a, b = segs[k], segs[k + 1]
            if (a.e - b.s).real > 1e-2:
                sa, sb = copy.deepcopy(a), copy.deepcopy(b)
                sa.offset(-step)
                sb.offset(-step)
                segs.insert(k + 1, Arc(ccw, a.e, (sa.e + sb.s) / 2.0, b.s))
                k += 1
            k += 1
        k = 0
        while len(segs) >= 2 and k < len(segs) - 1:
            if not segs[k].monotonic():
                if k == 0:
                    raise G7xError("the offset contour's first segment turns back (the reference reads before its "
                                   "list)")
                del segs[k if segs[k].radius() < segs[k - 1].radius() else k - 1]
                k = 0
                if len(segs) < 2:
                    raise G7xError("the offset contour shrank to one segment (the reference reads past its list)")
            if segs[k].radius() < 1e-3:
                del segs[k]
                if len(segs) < 2:
                    raise G7xError("the offset contour shrank to one segment (the reference reads past its list)")
                k = 1
                continue
            _meet(segs[k], segs[k + 1])
            k += 1
        return segs

    def pocket(self, cycle: int, at: complex, k: int, out: Out, count: list) -> None:
        """The roughing passes from ``at`` along the segments from ``k`` on (module docstring); ``cycle`` 0 all, 1
        no pocket, 2 the pockets only; ``count`` [levels so far] bounds the work."""
        segs, at, x = self.segs, [at], self.segs[0].s.imag
        if cycle == 2:
            while k < len(segs) and not segs[k].dive(at, -1e9, out, k == 0):
                k += 1
            cycle = 0
        while k < len(segs):
            count[0] += 1
            if count[0] > MAX_STEPS:
                raise G7xError(f"more than {MAX_STEPS} roughing steps (the reference would not end)")
            while x > at[0].imag:
                x -= self.delta
            if segs[k].dive(at, x, out, k == 0):
                if cycle == 1:
                    for s in segs[k:]:
                        s.climb_only(at, out)
                    return
                for j in range(k, len(segs)):
                    if segs[j].climb(at, out):
                        self.pocket(0, at[0], j, out, count)
                        return
                return
            if at[0].imag > x or abs(at[0].imag - x) > 1e-6:
                k += 1
                continue
            for j in range(k, len(segs)):
                hits = segs[j].cuts(at[0].imag)
                if not hits:
                    continue
                z = hits[0] if j != k else hits[-1]
                run = abs(z - at[0].real)
                if run < 1e-6:
                    if j == k:
                        continue
                    k += 1
                    break
                to = complex(z, at[0].imag)
                out.line(to)
                scale = min(1.0, run / 2 / self.escape.real) if self.escape.real != 0 else 1.0
                out.rapid(to + scale * self.escape)
                out.rapid(at[0] - (scale * self.escape).conjugate())
                (out.rapid if k == 0 else out.line)(at[0])
                x -= self.delta
                break


def finishing(segs: list, x: float, z: float, d: float, e: float, p: int) -> list:
    """LinuxCNC's ``G70`` from (``x``, ``z``) along ``segs`` (the lead-in first): ``p`` passes from distance ``d`` to
    ``e`` (module docstring). Returns the moves ``[(code, end, centre or None)]``."""
    path = Path(segs)
    path.segs[0].s = complex(z, x)
    if not all(s.monotonic() for s in path.segs):
        path.rotate()
    path.swap()
    out = Out(path.state)
    for k in range(p, 0, -1):
        one = path.copy()
        one.add_distance((k - 1) * (d - e) / p + e)
        out.rapid(one.segs[0].s)
        out.rapid(one.segs[0].e)
        for s in one.segs[1:]:
            s.draw(out)
    return out.moves


def roughing(segs: list, cycle: int, x: float, z: float, d: float, i: float, r: float, facing: bool) -> list:
    """LinuxCNC's ``G71`` (``facing``: ``G72``, the contour turned a quarter first) from (``x``, ``z``): the contour
    offset by ``d``, cuts ``i`` deep, retract ``r``; ``cycle`` the ``.n`` (0, 1 no pockets, 2 pockets only). Returns
    the moves ``[(code, end, centre or None)]``."""
    path = Path(segs)
    path.segs[0].s = complex(z, x)
    if facing:
        path.rotate()
    path.add_distance(d)
    path.swap()
    out = Out(path.state)
    path.delta, path.escape = i, r * (1 + 1j)
    first = path.segs[0]
    if (first.e - first.s).real > 0:
        first.s = complex(first.e.real, first.s.imag)  # the reference moves the start over the first point's Z
    bad = next((k for k, s in enumerate(path.segs) if not s.monotonic()), None)
    if bad is not None:
        raise G7xError(f"the reference's 'Not monotonic' (segment {bad} of the offset contour, the lead-in 0, goes "
                       "back along the cut)")
    out.rapid(first.s)
    last = path.segs[-1].e
    if last.imag < first.s.imag:
        path.segs.append(Straight(last, complex(last.real, first.s.imag)))
    path.pocket(cycle, first.s, 0, out, [0])
    return out.moves
