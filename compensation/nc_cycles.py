"""Drilling canned cycles (``G73 G81 G82 G83 G85 G86 G89``; ``G74 G84``, and by dialect ``G76 G87 G88``, kept
only) on a machine-tool chain.

The reader refuses the cycles (:data:`compensation.gcode.REFUSED_G`); a chain program read with
``cycles="keep"`` or ``"expand"`` (``compensate --machine ...``, ``--expand-cycles``) is first turned
by :func:`expand_cycles` into a program of plain moves, whose :attr:`CycleExpansion.origin` maps
every line back to its source line (refusals name the source).

Semantics (LinuxCNC 2.9 ``rs274ngc`` ``convert_cycle_xy`` and the Fanuc 0i/Haas manuals; XY plane, ``G17``):

* A cycle line is one with a cycle G code, or, while a cycle is the motion mode (until ``G80`` or
  another motion code), a line with an ``X``, ``Y`` or ``Z`` word (a *modal repeat*: one more
  hole). A line with none of them drills nothing (Fanuc: positioning words are needed).
* ``Z`` (hole bottom), ``R`` (R plane), ``Q`` (peck), ``P`` (dwell) are sticky until ``G80``;
  ``L``/``K`` (repeats) belongs to its line only; ``F`` is the modal feed.
* ``G90``: ``X Y`` the hole, ``R`` and ``Z`` absolute; repeats drill the same hole again.
  ``G91``: ``X Y`` increments from the current position (each repeat steps by them), ``R`` the
  distance from the initial level to the R plane, ``Z`` the distance from the R plane to the
  bottom (both controllers).
* The *initial level* is the Z when the cycle mode began (the series' first cycle line; Fanuc, and
  LinuxCNC 2.9's ``cycle_il``); under ``G91`` ``R`` is measured from it.
* Per hole: rapid ``X Y`` at the current level, rapid ``Z`` to ``R``, the body, and the return to
  the *clear level*: ``G98`` the initial level, ``G99`` the R plane. What the controllers (or their
  versions) do differently is refused: an initial level below R (LinuxCNC first rapids up to R at the current
  X Y and then clears to R, ``G98`` or ``G99``: read so with ``--dialect linuxcnc``; Fanuc does not), a ``G98``
  hole after a ``G99`` hole of one series (older LinuxCNC returns to the Z at the line's start), a change of
  cycle without its ``Z R`` (``Q``/``P``) words (LinuxCNC needs them, Fanuc keeps the earlier ones); a bottom
  above R is an error on both.
* Bodies: ``G81`` feed to Z, rapid out; ``G82`` feed, dwell ``P``, rapid out; ``G83`` peck: for
  each depth ``R − nQ`` above Z, feed to it, rapid to R, rapid to 0.010 in (0.254 mm) above it; then
  feed to Z and rapid out; ``G73`` chip break: as G83 but retracting only by that 0.254 mm; ``G85``
  feed to Z, feed to R, rapid to the clear level if above R; ``G89`` feed, dwell, feed out to the
  clear level; ``G86`` (spindle stop at the bottom) and the tapping cycles ``G74``/``G84`` (spindle
  reversal synchronised with Z) have no plain-move form. The peck constants are LinuxCNC 2.9's;
  Fanuc's are controller parameters (#5114/#5115): ``G73``/``G83`` are expanded only with
  ``--dialect linuxcnc``.
* By dialect (:data:`DIALECT_CYCLES`): on Fanuc (and Siemens ISO mode) and Haas ``G76`` is fine boring
  (feed to Z, dwell ``P``, spindle orient, shift ``Q`` off the wall, rapid out); on Fanuc ``G87`` is back
  boring (orient, shift, rapid down to ``R`` *below* ``Z``, shift back, feed *up* to ``Z``, return to the
  initial level: ``G98`` only) and ``G88`` boring with a dwell, a spindle stop and a manual retract. They
  are kept (each hole's bottom — for ``G87`` its top ``Z`` — and ``R`` compensated), never expanded (the
  orient, the shift and the manual retract have no plain-move form). On LinuxCNC ``G76`` is multi-pass
  lathe threading (spindle-synchronised passes): refused; without ``--dialect`` the three are refused
  as dialect-dependent.
* The dwell ``P`` is written as ``G4 P`` with the same number: the cycle's and G4's P have the same
  unit on each controller (LinuxCNC seconds, Fanuc milliseconds).

``"keep"`` (the default): each hole becomes, for the solver, a move to its R point ``(X, Y, R)``,
a move to its bottom ``(X, Y, Z)`` and the retract; the written program has the cycle line back with
the compensated ``X Y Z`` of the bottom and the compensated Z of the R point as ``R``
(:func:`render_kept`); the XY corrections at R and at the bottom differ by the *tilt* the cycle
cannot follow (the hole is drilled straight from the compensated XY), reported per line. Under
``G91`` the kept line is written in increments from where the controller running the output really is
(``X Y`` from its position before the hole, ``R`` from the series' initial level as written, ``Z`` from
the written R plane; :func:`render_kept`); ``L``/``K`` repeats under ``G91`` drill a hole each, written as
the line (without its repeat word) followed by one modal-repeat line per further hole (the compensated holes are
not equally spaced). After a kept cycle the controller stands at the written (compensated) clear level, not the
programmed one: an incremental move is refused until an absolute ``Z``. ``"expand"``: each hole
becomes the controller's moves above, compensated point by point.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from errormap.io import InputError

from .dialects import PROBES, SYNCED  # motion codes too (they end a cycle mode); after a probe line the axes it
# names are unknown (compensation.gcode_state.probe_move)
from .gcode import DECIMALS, fmt, tokenize
from .gcode_state import MM_PER_INCH, _Refuse
from .nc_expand import Expanded

CYCLE_CODES = ("G73", "G74", "G76", "G81", "G82", "G83", "G84", "G85", "G86", "G87", "G88", "G89")
NOT_EXPANDABLE = {"G74": "left-hand tapping (spindle reversal synchronised with Z)",
                  "G84": "tapping (spindle reversal synchronised with Z)",
                  "G86": "boring with the spindle stopped at the bottom",
                  "G76": "fine boring (spindle oriented and the tool shifted by Q at the bottom)",
                  "G87": "back boring (spindle oriented, the tool shifted by Q to pass the bore)",
                  "G88": "boring with a manual retract"}
DIALECT_CYCLES = {"G76": ("fanuc", "haas", "siemens-iso"), "G87": ("fanuc", "siemens-iso"),
                  "G88": ("fanuc", "siemens-iso")}
"""Cycles read only on these dialects (their manuals' mill form; module docstring)."""
INITIAL_LEVEL_DIALECTS = ("fanuc", "haas", "siemens-iso")
"""(Also the dialects whose ``G86`` takes no ``P``: Fanuc 0i-MF and Haas "G86 X Y Z R F": no dwell; LinuxCNC's has
one, so there it needs ``P``.)"""
"""Dialects whose ``G98`` returns to the series' initial level even after ``G99`` holes of the series (Fanuc 0i-MF
"initial level return": the Z when the cycle mode began; Haas mill manual, G98 "Initial Point Return"; Siemens ISO
mode as Fanuc). LinuxCNC before 2.9 returns to the Z at the line's start: refused without a dialect."""
PECK_DIALECTS = ("linuxcnc",)
"""Dialects whose G73/G83 peck retract is known (LinuxCNC 2.9: G83_RAPID_DELTA)."""
RAPID_DELTA_IN = 0.010
"""LinuxCNC 2.9 G83_RAPID_DELTA (inch; ×25.4 under G21): G83 re-entry clearance and G73 chip-break retract."""
OTHER_G = ("G90", "G91", "G98", "G99", "G17")
INVALIDATE_G = ("G54", "G55", "G56", "G57", "G58", "G59", "G54.1", "G59.1", "G59.2", "G59.3", "G10", "G92", "G52",
                "G154", *(f"G{c}" for c in range(110, 130)))
"""Codes after which the current position in program coordinates is not known to this pass (every axis)."""
INVALIDATE_NAMED_G = ("G28", "G30", "G53")
NOT_A_POSITION_G = ("G28", "G30", "G53", "G10", "G92", "G52")
"""Codes whose axis words are a via point, machine coordinates or data, not the program position."""
"""Codes that move only the axes named on their line (to the reference, or in machine coordinates): those become
unknown; ``G28``/``G30`` with no axis word move every axis on LinuxCNC (none on Fanuc): every axis."""
INVALIDATE_Z_G = ("G43", "G49")
"""The tool length offset is along Z (G17; cycles are read only there): Z in program coordinates becomes unknown,
X and Y stay."""


@dataclass
class Hole:
    """One drilled hole: ``line`` its 1-based line in the cycle pass's input, ``code`` the cycle,
    ``xyz``/``r`` program units (absolute), ``inch``, ``out_r``/``out_bottom`` 1-based output lines of the
    R and bottom moves (kept cycles), ``inc`` drilled under ``G91``, ``series`` the cycle series (a cycle mode
    from its start to ``G80`` or another motion code) it belongs to."""

    line: int
    code: str
    xyz: tuple
    r: float
    inch: bool
    out_r: int = 0
    out_bottom: int = 0
    inc: bool = False
    series: int = 0


@dataclass(frozen=True)
class CycleExpansion(Expanded):
    """:class:`compensation.nc_expand.Expanded` of the cycle pass: ``mode`` ``keep``/``expand``, ``holes``,
    ``spans[i]`` the output lines ``(a, b)`` (0-based, b exclusive) of input line i, ``source`` the input
    lines, ``inner`` the subprogram expansion run before it (None)."""

    mode: str = "keep"
    holes: list = field(default_factory=list)
    spans: list = field(default_factory=list)
    source: list = field(default_factory=list)
    inner: object = None

    @cached_property
    def _starts(self) -> list:
        return [a for a, _ in self.spans]

    def name(self, line: int):
        """1-based output ``line`` as a report names it: kept cycles are written on their own lines (the output is
        the input's line for line), so the input line the cycle pass read it from, named by the expansion before
        it (``inner``) where there is one; written as moves: :meth:`Expanded.name`."""
        if self.mode != "keep" or not 1 <= line <= len(self.origin):
            return super().name(line)
        j = bisect.bisect_right(self._starts, line - 1)
        return j if self.inner is None else self.inner.name(j)

    def note(self) -> str:
        what = ("canned cycles kept, each hole's X Y Z and R compensated at its bottom and R point"
                if self.mode == "keep" else "canned cycles written as the controller's moves")
        head = self.inner.note() + "; " if self.inner is not None else "volcomp: "
        return head + f"{what} ({len(self.holes)} holes)"


def cycle_pass(text: str, path, dialect, inner, mode: str, g80_keeps: bool = False):
    """The reader's hook (:func:`compensation.gcode.parse_program` ``cycles``): :func:`expand_cycles` of a
    program holding a cycle code (after ``inner``, the subprogram expansion, if any); None otherwise."""
    return expand_cycles(text, path, mode, dialect, inner, g80_keeps) if has_cycles(text) else None


def has_cycles(text: str) -> bool:
    import re
    return re.search(r"[gG]\s*0*(7\s*[346]|8\s*[1-9])(?![\d.])", text) is not None


class _St:
    def __init__(self):
        self.inc = self.inch = False
        self.plane = "G17"
        self.mode = None
        self.pos = np.full(3, np.nan)
        self.ret = "G98"
        self.sticky = {}
        self.feed = None
        self.series_g99 = False
        self.initial = math.nan  # the series' initial level (the Z when the cycle mode began)
        self.why_unknown = "the program start"
        self.kept_line = 0  # the last kept cycle line while the controller's Z differs from the programmed one
        self.series = 0
        self.g01 = None  # the G0-G3 mode written before the cycle (in force again after G80 where it is group 09)
        self.keeps_g01 = False  # G80 keeps it (the cycle's moves end in it)
        self.keeps_g01_unrecognised = False  # no dialect recognised: a bare G70/G71 sets the units
        self.dwell_x = False  # 'G04 X' is a dwell time (compensation.dialects.Dialect.dwell_x)
        self.tapping = False  # G33.1 in force: each of its lines ends where it started (rigid tapping returns)
        self.probing = False  # G38.2-G38.5 in force: each of its lines stops where the probe trips (not known)
        self.name = int  # a 1-based line of the text read as a refusal's text names it (expand_cycles)


def expand_cycles(text: str, path, mode: str, dialect: str | None = None, inner=None,
                  g80_keeps: bool = False) -> CycleExpansion:
    """The program ``text`` with its cycles made plain moves (module docstring); ``mode`` ``keep``/``expand``;
    ``g80_keeps``: each cycle's moves end in the G0-G3 written before it, as on the dialects whose ``G80`` is
    group 09 (:attr:`compensation.dialects.Dialect.g80_unrecognised`: no dialect recognised)."""
    if mode not in ("keep", "expand"):
        raise ValueError(f"Expected mode keep or expand, got {mode!r}")
    lines = text.splitlines(keepends=True)
    st, out, origin, spans, holes = _St(), [], [], [], []
    st.name = int if inner is None else inner.name  # the lines of inner's flat text: compensation.nc_expand.source_line
    st.keeps_g01 = g80_keeps or _keeps_motion(dialect)
    st.keeps_g01_unrecognised = g80_keeps
    from .dialects import DIALECTS
    st.dwell_x = dialect in DIALECTS and DIALECTS[dialect].dwell_x
    for i, line in enumerate(lines):
        body = line.rstrip("\r\n")
        end = line[len(body):]
        a = len(out)
        try:
            new = _line(body, st, mode, dialect, i + 1, holes, a)
        except _Refuse as r:
            raise InputError(f"{path}: line {i + 1}, column {r.col}: {r.msg}") from None
        if new is None:
            out.append(line)
            origin.append((i + 1, True, ()))
        else:
            out += [t + (end or "\n") for t in new]
            origin += [(i + 1, False, ())] * len(new)
        spans.append((a, len(out)))
    if inner is not None:
        origin = [(inner.origin[s - 1][0], v and inner.origin[s - 1][1], inner.origin[s - 1][2]) for s, v, _ in origin]
    return CycleExpansion("".join(out), tuple(origin), dialect or "rs274", str(path), getattr(inner, "files", ()),
                          mode=mode, holes=holes, spans=spans, source=[ln.rstrip("\r\n") for ln in lines], inner=inner)


def _codes(words) -> list:
    return [w for w in words if w.letter == "G"]


def _line(body, st: _St, mode, dialect, lineno, holes, out_at):
    """Output lines for one input line (None: the line itself), updating ``st``."""
    try:
        bd, words, _ = tokenize(body)
    except _Refuse:
        return None  # the reader refuses it, naming the column
    by = {w.letter: w for w in words}
    gs = [w.code for w in _codes(words)]
    cyc = [c for c in gs if c in CYCLE_CODES]
    motion = [c for c in gs if c in ("G0", "G1", "G2", "G3", "G80", *SYNCED, *PROBES)]
    if cyc or (st.mode is not None and not motion and any(a in by for a in "XYZ")):
        if bd:
            raise _Refuse(body.index("/") + 1, "'/' (block delete) on a canned-cycle line: whether the hole is "
                                               "drilled depends on the controller's switch; remove the '/'")
        return _cycle_line(body, words, by, gs, cyc, st, mode, dialect, lineno, holes, out_at)
    _g80_motion(motion, st)
    _track(words, by, gs, motion, st)
    _after_kept(by, gs, st)
    if bd and any(a in by for a in "XYZ"):  # run or skipped by the operator's switch
        st.pos[[j for j, a in enumerate("XYZ") if a in by]] = np.nan
        st.why_unknown = "a '/' (block delete) line"
    return None


def _keeps_motion(dialect) -> bool:
    from .dialects import DIALECTS
    return dialect in DIALECTS and DIALECTS[dialect].g80_keeps_motion


def _g80_motion(motion, st: _St) -> None:
    """The G0-G3 mode last written: where G80 is group 09 (:attr:`compensation.dialects.Dialect.g80_keeps_motion`)
    it moves the axes through and after a cycle (a cycle needs a known Z, so one was written before it)."""
    if any(c in ("G0", "G1", "G2", "G3") for c in motion):
        st.g01 = next(c for c in reversed(motion) if c != "G80")


def _after_kept(by, gs, st: _St) -> None:
    """After a kept cycle the controller's Z is the written (compensated) R or initial level, not the
    programmed one the reader continues from: an incremental move is refused until an absolute Z."""
    if not st.kept_line or not any(a in by for a in "XYZ") or any(c in NOT_A_POSITION_G for c in gs):
        return
    if st.inc:
        w = next(by[a] for a in "XYZ" if a in by)
        raise _Refuse(w.start + 1, f"an incremental move after the kept canned cycle of line {st.name(st.kept_line)}: "
                                   "the controller is then at the cycle's compensated clear level, not the programmed "
                                   "one; program an absolute Z (G90) first, or use --expand-cycles")
    if "Z" in by:
        st.kept_line = 0


def _track(words, by, gs, motion, st: _St):
    for c in gs:
        if c in ("G90", "G91"):
            st.inc = c == "G91"
        elif c in ("G20", "G21") or (st.keeps_g01_unrecognised and c in ("G70", "G71")):
            st.inch = c in ("G20", "G70")  # a bare G70/G71 with no dialect word: compensation.gcode_classify.BARE_UNITS
        elif c in ("G17", "G18", "G19"):
            st.plane = c
        elif c in ("G98", "G99"):
            st.ret = c
        elif c in INVALIDATE_G or c in INVALIDATE_NAMED_G or c in INVALIDATE_Z_G:
            named = [j for j, a in enumerate("XYZ") if a in by]
            st.pos[[2] if c in INVALIDATE_Z_G else named if c in INVALIDATE_NAMED_G and named else slice(None)] = np.nan
            st.why_unknown = c
    if motion:
        st.tapping = motion[-1] == "G33.1"
        st.probing = motion[-1] in PROBES
        st.mode = None
        st.sticky = {}
        st.series_g99 = False
        st.initial = math.nan
    if "F" in by:
        st.feed = by["F"].text
    if st.probing and any(a in by for a in "XYZ"):
        st.pos[[j for j, a in enumerate("XYZ") if a in by]] = np.nan
        st.why_unknown = "a probe move (G38.2-G38.5)"
        return
    if any(c in NOT_A_POSITION_G for c in gs) or st.tapping or ("G4" in gs and st.dwell_x):
        return  # a via point, machine coordinates or data (the position stays unknown), a tap that returned, or a
        # Fanuc 'G04 X' dwell time
    for j, a in enumerate("XYZ"):  # after G43/G49 or a work system only absolute words are known again
        if a in by and (not st.inc or math.isfinite(st.pos[j])):
            st.pos[j] = st.pos[j] + by[a].value if st.inc else by[a].value


def _cycle_line(body, words, by, gs, cyc, st: _St, mode, dialect, lineno, holes, out_at):
    """Output lines of a cycle line (module docstring): its holes' moves, in ``G90``."""
    col = (next((w for w in words if w.code in cyc), words[0]).start + 1) if words else 1
    _check_words(words, cyc, col)
    code = _enter(st, gs, by, cyc, col)
    _check_mode(code, st, mode, dialect, col)
    extra = " ".join([f"{w.letter}{w.text}" for w in words if w.letter == "N"] + ["G90"]
                     + [f"{w.letter}{w.text}" for w in words if w.letter in "MS"])
    if not any(a in by for a in "XYZ"):
        return [extra.replace("G90", "G91" if st.inc else "G90")]
    r, bottom, clear = _levels(code, st, col, dialect)
    dec = DECIMALS["inch" if st.inch else "mm"]
    out = []
    x, y = st.pos[0], st.pos[1]
    if mode == "expand" and st.pos[2] < r:  # LinuxCNC: below R, first a rapid up to it at the current X Y
        out.append(f"{extra} G0 Z{fmt(r, dec)}")
        extra = "G90"
    for _ in range(_repeats(by) if (st.inc or mode == "expand") else 1):
        x = x + by["X"].value if st.inc and "X" in by else (by["X"].value if "X" in by else x)
        y = y + by["Y"].value if st.inc and "Y" in by else (by["Y"].value if "Y" in by else y)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise _Refuse(col, f"{code}: the hole's X/Y is not known (no X/Y word and none before the cycle)")
        hole = Hole(lineno, code, (x, y, bottom), r, st.inch, inc=st.inc, series=st.series)
        xy = f"X{fmt(x, dec)} Y{fmt(y, dec)}"
        if mode == "keep":
            hole.out_r = out_at + len(out) + 1
            out.append(f"{extra} G1 {xy} Z{fmt(r, dec)}" + (f" F{st.feed}" if st.feed else ""))
            hole.out_bottom = out_at + len(out) + 1
            out += [f"G1 Z{fmt(bottom, dec)}", f"G0 Z{fmt(clear, dec)}"]
        else:
            out += _expanded_hole(code, xy, r, bottom, clear, dec, st, extra)
            extra = "G90"
        holes.append(hole)
    st.pos[:] = (x, y, clear)
    if st.g01 is not None and st.keeps_g01 and out[-1].split(" ")[0] != st.g01:
        out.append(st.g01)  # the controller's group-01 mode through and after the cycle (G80 is group 09)
    if mode == "keep":
        st.kept_line = lineno
    if st.inc:
        out.append("G91")
    return out


def _check_words(words, cyc, col):
    if len(cyc) > 1:
        raise _Refuse(col, f"two canned cycles ({', '.join(cyc)}) on one line")
    for w in words:
        if w.letter == "G" and w.code not in CYCLE_CODES + OTHER_G:
            raise _Refuse(w.start + 1, f"'{w.code}' on a canned-cycle line is not read (put it on a line of its own)")
        if w.letter not in "GXYZRQPFLKNMS":
            raise _Refuse(w.start + 1, f"'{w.letter}' word on a canned-cycle line is not read")
        if w.letter == "M" and w.code not in ("M3", "M4", "M5", "M7", "M8", "M9"):
            raise _Refuse(w.start + 1, f"'{w.code}' on a canned-cycle line is not read (put it on a line of its own)")


def _enter(st: _St, gs, by, cyc, col) -> str:
    """The line's modes and sticky words into ``st``; returns the cycle in force."""
    for c in gs:
        if c in ("G90", "G91"):
            st.inc = c == "G91"
        elif c in ("G98", "G99"):
            st.ret = c
        elif c == "G17":
            st.plane = c
    if st.plane != "G17":
        raise _Refuse(col, f"canned cycle in the {st.plane} plane: only G17 (XY) cycles are read")
    if st.mode is None:
        st.initial = st.pos[2]
        st.series += 1
    if cyc and cyc[0] != st.mode:
        need = "ZR" + {"G73": "Q", "G83": "Q", "G82": "P", "G86": "P", "G89": "P"}.get(cyc[0], "")
        missing = [a for a in need if a not in by]
        if st.mode is not None and missing:
            raise _Refuse(col, f"{cyc[0]} after {st.mode} without {' '.join(missing)}: LinuxCNC needs them when the "
                               "cycle changes, Fanuc keeps the earlier ones; write them on this line")
        st.mode = cyc[0]
    if "F" in by:
        st.feed = by["F"].text
    for a in "ZRQP":
        if a in by:
            st.sticky[a] = by[a]
    return st.mode


def _check_mode(code, st: _St, mode, dialect, col):
    if code in DIALECT_CYCLES and dialect not in DIALECT_CYCLES[code]:
        what = ("multi-pass lathe threading (spindle-synchronised passes), not interpretable as compensated moves"
                if code == "G76" and dialect == "linuxcnc" else
                f"dialect-dependent; read as {NOT_EXPANDABLE[code]} on {'/'.join(DIALECT_CYCLES[code])} "
                "(name the controller with --dialect)")
        raise _Refuse(col, f"{code} on {dialect or 'rs274'}: {what}")
    if mode == "expand" and code in NOT_EXPANDABLE:
        raise _Refuse(col, f"{code} ({NOT_EXPANDABLE[code]}) has no form in plain moves: leave --expand-cycles "
                           "out to keep the cycle (its hole compensated at the bottom and R plane)")
    if mode == "expand" and code in ("G73", "G83") and dialect not in PECK_DIALECTS:
        raise _Refuse(col, f"{code} pecks by a retract the controller keeps in a parameter (Fanuc #5114/#5115): "
                           "expanded only with --dialect linuxcnc (LinuxCNC 2.9's 0.254 mm); or leave "
                           "--expand-cycles out to keep the cycle")


def _repeats(by) -> int:
    reps = 1
    for a in "LK":
        if a in by:
            v = by[a].value
            if v != round(v) or v < 1:
                raise _Refuse(by[a].start + 1, f"{a}{by[a].text}: repeats must be a whole number ≥ 1")
            reps = int(v)
    return reps


def _levels(code, st: _St, col, dialect=None) -> tuple:
    """``(R plane, bottom, clear level)`` absolute, in the program's units, of the cycle in force."""
    for a in "ZR":
        if a not in st.sticky:
            raise _Refuse(col, f"{code} without {a} (the {'hole bottom' if a == 'Z' else 'R plane'}) on this or an "
                               "earlier line of the cycle")
    if code in ("G73", "G83") and "Q" not in st.sticky:
        raise _Refuse(col, f"{code} without Q (the peck depth)")
    if code in ("G82", "G86", "G89") and "P" not in st.sticky and not (code == "G86" and dialect in INITIAL_LEVEL_DIALECTS):
        raise _Refuse(col, f"{code} without P (the dwell at the bottom)")
    if code in ("G73", "G83") and st.sticky["Q"].value <= 0:
        raise _Refuse(st.sticky["Q"].start + 1, f"{code} Q must be > 0")
    old_z = st.initial
    if not math.isfinite(old_z):
        raise _Refuse(col, f"{code}: the Z before the cycle (its initial level) is not known after {st.why_unknown}; "
                           "program a Z move before the cycle")
    if st.inc and not np.isfinite(st.pos[:2]).all():
        raise _Refuse(col, f"{code} under G91: the X Y before the cycle are not known after {st.why_unknown}")
    r = st.sticky["R"].value + (old_z if st.inc else 0.0)
    bottom = st.sticky["Z"].value + (r if st.inc else 0.0)
    if code == "G87":
        return _back_boring_levels(st, r, bottom, old_z, col)
    if bottom > r:
        raise _Refuse(col, f"{code}: the hole bottom Z {bottom:g} is above R {r:g}")
    if old_z < r and dialect != "linuxcnc":
        raise _Refuse(col, f"{code}: the Z at the cycle's start ({old_z:g}) is below R ({r:g}): LinuxCNC first rapids "
                           "up to R (--dialect linuxcnc), Fanuc does not; program a Z move to or above R before the "
                           "cycle")
    if old_z < r:  # LinuxCNC convert_cycle_xy: a rapid up to R at the current X Y, then R is the clear level
        return r, bottom, r
    if st.ret == "G98" and st.series_g99 and dialect not in INITIAL_LEVEL_DIALECTS:
        raise _Refuse(col, f"{code} G98 after a G99 hole of the same series: Fanuc, Haas and LinuxCNC 2.9 return to "
                           "the series' initial level, older LinuxCNC to the R plane; name the controller with "
                           "--dialect fanuc/haas/siemens-iso, or program G98 or G99 for the whole series")
    st.series_g99 = st.series_g99 or st.ret == "G99"
    return r, bottom, old_z if st.ret == "G98" else r


def _back_boring_levels(st: _St, r, top, old_z, col) -> tuple:
    """G87 (Fanuc back boring): R is the hole's bottom, below the bored Z; the return is to the initial level."""
    if top < r:
        raise _Refuse(col, f"G87: Z {top:g} is below R {r:g} (back boring feeds up from R to Z)")
    if st.ret == "G99":
        raise _Refuse(col, "G87 with G99: back boring returns to the initial level only (Fanuc: G98)")
    if old_z < top:
        raise _Refuse(col, f"G87: the Z at the cycle's start ({old_z:g}) is below Z ({top:g}); program a Z move above "
                           "the part before the cycle")
    return r, top, old_z


def _expanded_hole(code, xy, r, bottom, clear, dec, st: _St, lead) -> list:
    """The controller's moves of one hole (module docstring), absolute, in the program's units."""
    z = lambda v: f"Z{fmt(v, dec)}"  # noqa: E731
    feed = f" F{st.feed}" if st.feed else ""
    out = [f"{lead} G0 {xy}", f"G0 {z(r)}"]
    dwell = [f"G4 P{st.sticky['P'].text}"] if "P" in st.sticky else []
    if code in ("G73", "G83"):
        q = st.sticky["Q"].value
        delta = RAPID_DELTA_IN * (1.0 if st.inch else MM_PER_INCH)
        d = r - q
        while d > bottom:
            out.append(f"G1 {z(d)}{feed}")
            feed = ""
            if code == "G83":
                out.append(f"G0 {z(r)}")
            out.append(f"G0 {z(d + delta)}")
            d -= q
    out.append(f"G1 {z(bottom)}{feed}")
    if code in ("G82", "G89"):
        out += dwell
    if code == "G85":
        out.append(f"G1 {z(r)}")
        if clear > r:
            out.append(f"G0 {z(clear)}")
    elif code == "G89":
        out.append(f"G1 {z(clear)}")
    else:
        out.append(f"G0 {z(clear)}")
    return out


# ---------------------------------------------------------------------------- kept cycles written back
def hole_vertices(program, vertices) -> dict:
    """``{output line (1-based): last vertex (k,)}`` of every compensated move of ``program``."""
    comp = [m for m in program.moves if m.compensate]
    return {m.index + 1: np.asarray(v, float).reshape(-1, len(program.axis_words.words))[-1]
            for m, v in zip(comp, vertices)}


def render_kept(program, vertices, header=()) -> str:
    """The program with kept cycles: every non-cycle line as :func:`compensation.gcode.render_program`
    writes it, every cycle line as read with the compensated ``X Y Z R`` of its hole (program units)."""
    from .gcode import _with_header, render_program
    exp = program.expanded
    track = {}
    _, groups = render_program(program, vertices, track=track)
    ends = hole_vertices(program, vertices)
    words = program.axis_words.words
    jx, jy, jz = (words.index(a) for a in "XYZ")
    moved = sorted(track)
    before = {}  # hole (id): the controller's position before it (output units: mm / deg)
    initial = {}  # series: the controller's Z when it began (its initial level)
    for h in exp.holes:
        k = bisect.bisect_left(moved, h.out_r - 1) - 1
        before[id(h)] = track[moved[k]] if k >= 0 else np.full(len(words), np.nan)
        initial.setdefault(h.series, before[id(h)][jz])
    by_line = {}
    for h in exp.holes:  # G91 repeats drill a hole each (one line per hole written); G90 repeats one: the last
        by_line[h.line] = by_line.get(h.line, []) + [h] if h.inc else [h]
    out = []
    for i, (a, b) in enumerate(exp.spans):
        hs = by_line.get(i + 1)
        if hs is None and b - a == 1 and exp.origin[a][1]:
            out += groups[a]
            continue
        end = program.lines[a][len(program.lines[a].rstrip("\r\n")):] if b > a else "\n"
        if hs is None:  # a cycle line that drills nothing (sets the cycle's words)
            out.append(exp.source[i] + (end or "\n"))
            continue
        for n, h in enumerate(hs):
            scale = MM_PER_INCH if h.inch else 1.0
            bot, rp = ends[h.out_bottom], ends[h.out_r]
            dec = DECIMALS["inch" if h.inch else "mm"]
            if h.inc:
                text = _incremental_words(bot[[jx, jy, jz]], rp[jz], before[id(h)][[jx, jy]], initial[h.series], scale,
                                          dec, exp.where(h.out_r))
            else:
                vals = {"X": bot[jx], "Y": bot[jy], "Z": bot[jz], "R": rp[jz]}
                text = {k: fmt(v / scale, dec) for k, v in vals.items()}
            if n == 0:  # the line itself (its L/K repeats written out as the lines after it)
                out.append(_substitute(_drop(exp.source[i], "LK") if len(hs) > 1 else exp.source[i], text)
                           + (end or "\n"))
            else:  # a modal repeat of the cycle: one more hole
                out.append(" ".join(f"{k}{v}" for k, v in text.items()) + (end or "\n"))
    if out and not program.lines[-1].endswith("\n") and out[-1].endswith("\n"):
        out[-1] = out[-1].rstrip("\r\n")
    return _with_header(out, program.notes() + tuple(header))


def _incremental_words(bottom, r_z, ctrl_xy, initial_z, scale, dec, where) -> dict:
    """A kept ``G91`` hole's words (program units, text): ``X Y`` from the controller's position before it,
    ``R`` from the series' initial level, ``Z`` from the R plane the written ``R`` gives (so rounding does not
    accumulate); all positions as the controller running the output has them (mm)."""
    if not (np.isfinite(ctrl_xy).all() and np.isfinite(initial_z)):
        raise InputError(f"{where}: a kept G91 cycle after a position the written program does not fix (G28, G53, "
                         "a work system): program an absolute X Y Z before it, or use --expand-cycles")
    rw = fmt((r_z - initial_z) / scale, dec)
    return {"X": fmt((bottom[0] - ctrl_xy[0]) / scale, dec), "Y": fmt((bottom[1] - ctrl_xy[1]) / scale, dec),
            "Z": fmt((bottom[2] - (initial_z + float(rw) * scale)) / scale, dec), "R": rw}


def _drop(body: str, letters: str) -> str:
    """``body`` without its words of ``letters`` (a cycle line's ``L``/``K`` repeats)."""
    _, words, _ = tokenize(body)
    for w in sorted((w for w in words if w.letter in letters), key=lambda w: -w.start):
        body = body[:w.start].rstrip(" \t") + body[w.num_end:]
    return body


def _substitute(body: str, values: dict) -> str:
    """``body`` with the numbers of its ``values`` words replaced, missing ones appended after the last word."""
    _, words, _ = tokenize(body)
    s, last, done = body, 0, set()
    for w in sorted(words, key=lambda w: -w.start):
        if w.letter in values and w.letter not in done:
            s = s[:w.start] + w.letter + values[w.letter] + s[w.num_end:]
            done.add(w.letter)
    _, words2, _ = tokenize(s)
    last = max((w.num_end for w in words2), default=len(s))
    add = "".join(f" {k}{v}" for k, v in values.items() if k not in done)
    return s[:last] + add + s[last:]
