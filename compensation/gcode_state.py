"""The controller-state words of the G-code reader (:mod:`compensation.gcode`), line by line: work-system
selections (``G54`` … ``G59.3``, ``G54.1 Pn``, Haas ``G154 Pn``), tool length offsets (``G43 Hn`` / ``G49``; on
LinuxCNC a bare ``G43`` is the tool the program's ``Tn M6`` loaded), cutter radius compensation (``G41``/``G42
Dn`` / ``G40``; on a Fanuc/Haas lathe the nose radius of the ``TttOO`` word's register), the program's own
tables (``G10 L1 L2 L10–L13 L20`` by dialect; LinuxCNC's ``G10 L2 R`` rotation), the shifts of every work
system (``G92`` family, ``G52``), moves in machine coordinates (``G53``), a dialect's mode codes
(:mod:`compensation.dialects`), LinuxCNC's output/input M codes (:func:`io_line`) and Siemens native-mode lines
(:func:`siemens_native`, refused). Each is recorded as an event (:attr:`compensation.gcode.GProgram.events`) that
:func:`compensation.nc_state.program_frames` resolves against the controller's tables; where a frame changes, the
program position along the axes it moves becomes unknown (the next move there must give it absolutely)."""
from __future__ import annotations

import re

import numpy as np

from .nc_state import EXTENDED_MAX, HAAS_MAX, SYSTEMS, lathe_words, system_name

MM_PER_INCH = 25.4


class _Refuse(Exception):
    """A line the reader refuses: ``col`` (1-based) and the message (the reader adds file and line)."""

    def __init__(self, col: int, msg: str):
        self.col, self.msg = col, msg


def _forget(st: _State, ax: AxisWords, words) -> None:
    """The program position along ``words`` is unknown after its frame changed (the next move there
    must give it absolutely; incremental moves are refused until then)."""
    st.pos = st.pos.copy()  # the previous move's end is this array: it must keep its values
    for j, a in enumerate(ax.words):
        if a in words:
            st.pos[j] = np.nan


def probe_move(idx, st: _State, axis_words, arc_words, motion_word, ax: AxisWords) -> None:
    """A probe move (``G38.2``-``G38.5``, :data:`compensation.dialects.PROBES`): the machine moves towards the line's
    point at the feed and stops where the probe input changes, a measurement, not a cut: the line is written as
    programmed and recorded as a ``probe`` event; the position along the axes the line names is unknown afterwards
    (the next move there must give them absolutely; an offset set from the current position, ``G92``, ``G10 L20``,
    is refused until then). Refused as the controllers refuse it: arc words, or cutter radius compensation on
    (LinuxCNC: "Cannot probe with cutter radius compensation on")."""
    if arc_words:
        w = next(iter(arc_words.values()))
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {st.mode} probe line (arc words need G2/G3)")
    first = motion_word or min(axis_words.values(), key=lambda w: w.start)
    if not axis_words:
        raise _Refuse(first.start + 1, f"'{st.mode}' without axis words (the probe's target)")
    if st.cutter != "G40":
        raise _Refuse(first.start + 1, f"'{st.mode}' probe move with cutter radius compensation ({st.cutter}) on: the "
                                       "controllers refuse it; cancel it with G40 first")
    st.events.append((idx, first.start + 1, "probe", tuple(axis_words), st.mode))
    _forget(st, ax, tuple(axis_words))


def _work_state(idx, st: _State, groups, by, ax: AxisWords) -> None:
    """A work-system selection (``G54`` … ``G59.3``, ``G54.1 Pn``) or a tool length offset (``G43 Hn``,
    ``G49``): recorded as an event (:attr:`GProgram.events`); where the frame changes, the position
    along the axes it moves becomes unknown."""
    if "coords" in groups:
        code, w = groups["coords"]
        p = None
        if code in ("G54.1", "G154"):
            top = EXTENDED_MAX if code == "G54.1" else HAAS_MAX
            pw = by.get("P")
            if pw is None or pw.value != int(pw.value) or not 1 <= pw.value <= top:
                raise _Refuse(w.start + 1, f"'{code}' needs P1..P{top} (the {'extended' if code == 'G54.1' else 'additional'} "
                                           "work system)")
            p = int(pw.value)
        elif "P" in by and by["P"].start > w.start and code.startswith("G1"):
            raise _Refuse(by["P"].start + 1, f"'P{by['P'].text}' with {code} (G110..G129 are G154 P1..P20 already)")
        name = system_name(code, p)
        st.events.append((idx, w.start + 1, "system", name, name if p is None else f"{code} P{p}"))
        if name != st.system:
            _forget(st, ax, ax.words)
            st.system = name
    nose = ttoo_lathe(st.dialect, ax)
    if nose and st.t_changed is not None and st.cutter != "G40" and groups.get("cutter", ("",))[0] != "G40":
        raise _Refuse(st.t_changed, f"a T word changing the offset register while {st.cutter} is in force: the nose "
                                    "radius the control takes mid-contour is not read here; write G40 before it")
    if nose and "cutter" in groups:  # a Fanuc/Haas lathe: the nose radius of the T word's register
        code, w = groups["cutter"]
        value = None if code == "G40" else _nose_register(st, code, w)
        st.events.append((idx, w.start + 1, "nose", value, code if value is None else f"{code} (T offset {value:02d})"))
        st.cutter = code
    elif groups.get("cutter", ("",))[0] in DYNAMIC_CUTTER:
        dynamic_cutter(idx, st, groups["cutter"], by)
    elif "cutter" in groups or "D" in by:
        code, w = groups["cutter"] if "cutter" in groups else (st.cutter, by["D"])  # a D alone: Fanuc (d_modal)
        d = by.get("D")
        if d is not None and (d.value != int(d.value) or d.value < 0):
            raise _Refuse(d.start + 1, f"'D{d.text}': expected a tool number")
        st.last_d = int(d.value) if d is not None else st.last_d
        value = int(d.value) if d is not None else (None if code == "G40" else bare_d(st))
        value = None if code == "G40" else (_loaded(st, code, w) if value is None else value)
        text = code if value is None else (f"{code} D{value}" if d is not None else f"{code} (tool {value})")
        if "cutter" in groups or code != "G40":  # a D alone under G40 only sets the number
            st.events.append((idx, w.start + 1, "cutter", value, text))
        st.cutter = code
    fanuc_h = getattr(st.dialect, "h_offset_alone", False)
    if groups.get("length", ("",))[0] == "G43.1":
        dynamic_length(idx, st, groups, by, ax)
    elif "length" in groups or (fanuc_h and "H" in by and st.g43):
        code, w = groups["length"] if "length" in groups else ("G43", by["H"])
        value = None
        if code == "G43":
            h = by.get("H")
            if h is not None and (h.value != int(h.value) or h.value < 0):
                raise _Refuse(h.start + 1, f"'H{h.text}': expected a tool number")
            value = int(h.value) if h is not None else bare_g43_tool(st)
            value = _loaded(st, code, w) if value is None else value
            st.last_h = value
            value = None if fanuc_h and value == 0 else value  # H00: always a zero length
        text = code if code != "G43" else (f"G43 H{int(by['H'].value)}" if "H" in by else f"G43 (tool {value} loaded)")
        st.events.append((idx, w.start + 1, "tool", value, text))
        st.g43 = code == "G43"
        if value != st.tool:
            _forget(st, ax, _tool_axes(ax))
            st.tool = value


def dynamic_length(idx, st: _State, groups, by, ax: AxisWords) -> None:
    """LinuxCNC ``G43.1 axes`` (G-code reference, "G43.1 Dynamic Tool Length Offset"): the tool offset along the axes
    given replaced by their values (program units), the others kept; no motion. Recorded as the event
    ``"tool-dynamic"`` ``{axis: mm}`` (:meth:`compensation.nc_state._Controller.dynamic_length`); the position along
    the tool's axes unknown after it, as after ``G43``. Refused: a motion code on the line (LinuxCNC's error), no axis
    word, an axis other than Z (and X on a lathe), X under ``G7`` (whether it is read as a diameter is not read
    here)."""
    code, w = groups["length"]
    if "motion" in groups:
        m = groups["motion"][1]
        raise _Refuse(m.start + 1, f"'{groups['motion'][0]}' on a G43.1 line: LinuxCNC's error (motion with G43.1)")
    given = {a: by[a] for a in ax.words if a in by}
    allowed = _tool_axes(ax)
    bad = next((x for a, x in given.items() if a not in allowed), None)
    if bad is not None or not given:
        raise _Refuse((bad or w).start + 1, ("'G43.1' without " if bad is None else f"'{bad.letter}{bad.text}' with "
                                             "G43.1: ") + f"a tool offset along {' and '.join(allowed)} is read here "
                                                          "(the tool's length; X on a lathe)")
    if "X" in given and st.diameter:
        raise _Refuse(given["X"].start + 1, f"'X{given['X'].text}' with G43.1 under G7 (diameter mode): whether the "
                                            "offset is read as a diameter is not read here; write it under G8")
    scale = MM_PER_INCH if st.inch else 1.0
    vals = {a: x.value * scale for a, x in given.items()}
    st.events.append((idx, w.start + 1, "tool-dynamic", vals,
                      "G43.1 " + " ".join(f"{a}{x.text}" for a, x in given.items())))
    st.g43 = False
    st.tool = ("G43.1", idx)
    _forget(st, ax, allowed)


DYNAMIC_CUTTER = ("G41.1", "G42.1")
"""LinuxCNC's dynamic cutter radius compensation (:attr:`compensation.dialects.Dialect.dynamic_cutter`)."""


def dynamic_cutter(idx, st: _State, cutter, by) -> None:
    """LinuxCNC ``G41.1``/``G42.1 D<diameter> [L<orientation>]`` (G-code reference, "G41.1, G42.1 Dynamic Cutter
    Compensation"; its interpreter, ``Interp::convert_cutter_compensation_on``): compensation on with the radius D/2
    in program units (no tool table), recorded as the event ``"cutter-dynamic"`` (radius mm;
    :meth:`compensation.nc_state._Controller.dynamic_cutter`): the path is compensated as programmed, as under
    ``G41``/``G42``. Refused as LinuxCNC refuses it: no D; a plane other than G17/G18; compensation already on; L
    not a whole number 0-9, or L outside G18. Refused here besides: a negative D (the reference's D is the
    diameter; its interpreter would take the other side: write the side you mean with D ≥ 0)."""
    code, w = cutter
    d, el = by.get("D"), by.get("L")
    if d is None:
        raise _Refuse(w.start + 1, f"'{code}' without D (the cutter diameter): LinuxCNC's error ('{code} with no D "
                                   f"word'); write the diameter, like '{code} D6'")
    if st.plane not in ("G17", "G18"):
        raise _Refuse(w.start + 1, f"'{code}' in the plane {st.plane}: LinuxCNC compensates the cutter radius only "
                                   "in XY (G17) or XZ (G18)")
    if st.cutter != "G40":
        raise _Refuse(w.start + 1, f"'{code}' while {st.cutter} is on: LinuxCNC's error (compensation turned on when "
                                   "already on); write G40 before it")
    if not np.isfinite(d.value) or d.value < 0:
        raise _Refuse(d.start + 1, f"'D{d.text}' with {code}: D is the cutter diameter (≥ 0); a negative one "
                                   "(LinuxCNC's interpreter takes the other side) is not read here: write the side "
                                   "meant with G41.1/G42.1 and D ≥ 0")
    if el is not None and (el.value != int(el.value) or not 0 <= el.value <= 9):
        raise _Refuse(el.start + 1, f"'L{el.text}' with {code}: the tool orientation is a whole number 0-9")
    if el is not None and st.plane != "G18":
        raise _Refuse(el.start + 1, f"'L{el.text}' with {code} in {st.plane}: LinuxCNC's error (L, the lathe tool's "
                                    "orientation, only in the XZ plane G18)")
    radius_mm = d.value / 2 * (MM_PER_INCH if st.inch else 1.0)
    text = f"{code} D{d.text}" + (f" L{el.text}" if el is not None else "")
    st.events.append((idx, w.start + 1, "cutter-dynamic", radius_mm, text))
    st.cutter = code


def _tool_axes(ax: AxisWords) -> tuple:
    """The axes a tool offset moves: Z (the length), and X too on a lathe (:func:`compensation.nc_state.lathe_words`)."""
    return ("X", "Z") if lathe_words(ax.words) else ("Z",)


def lathe_t_offset(idx, st: _State, t, ax: AxisWords) -> None:
    """A lathe's ``TttOO`` word (Fanuc, Haas turning): tool ``tt``, offset register ``OO`` applied from this line
    (``OO = 00``: no offset), recorded as a tool event (:func:`compensation.nc_state.program_frames`). Three
    digits are the four with the leading zero left out (``T202``: tool 02, register 02)."""
    digits = t.text.strip()
    value = int(digits.zfill(4)[2:]) or None
    st.events.append((idx, t.start + 1, "tool", value, f"T{digits}"))
    st.t_changed = t.start + 1 if value != st.tool else None  # checked against G41/G42 (_work_state)
    if value != st.tool:
        _forget(st, ax, _tool_axes(ax))
        st.tool = value


def ttoo_lathe(dia, ax: AxisWords) -> bool:
    """A lathe (X and Z, no Y: :func:`compensation.nc_state.lathe_words`) of a dialect whose T word selects the tool
    and its offset register (``TttOO``: Fanuc, Haas turning, :attr:`compensation.dialects.Dialect.lathe_t_offset`).
    There ``G41``/``G42`` take the nose radius of the register in force (Fanuc 0i-TF, Haas lathe manual: the radius
    and imaginary tip are set on the offset page of the register the T word selects), not a D word."""
    return getattr(dia, "lathe_t_offset", False) and lathe_words(ax.words)


def _nose_register(st: _State, code, w) -> int:
    """The offset register whose nose radius ``G41``/``G42`` take on a :func:`ttoo_lathe` lathe: the T word's."""
    if st.tool is None:
        raise _Refuse(w.start + 1, f"'{code}' takes the nose radius of the T word's offset register (TttOO), and no "
                                   "register is in force: give the T word (like T0202) before it or on its line")
    return st.tool


def bare_g43_tool(st: _State):
    """The length offset number of a ``G43`` without ``H`` where the dialect says it without the tool in the spindle:
    Fanuc, Haas, Siemens ISO (``h_offset_alone``; the H number is modal) the H in force; with no dialect,
    that H where it is also the tool the program's ``M6`` loaded (LinuxCNC and Mach3 take the loaded tool: both
    readings agree); None otherwise (LinuxCNC: :func:`_loaded`; else refused). Only while ``G43`` is in force (a
    repeated ``G43 Z..``): after ``G49`` the number a Fanuc takes is not read here."""
    return _modal_number(st, st.last_h) if st.g43 else None


def bare_g43_rule(dia) -> str:
    """Why a ``G43`` without ``H`` is refused on dialect ``dia`` and what to write (the manuals: LinuxCNC takes the
    tool ``M6`` loaded; Fanuc, Haas, Siemens ISO the H in force, i.e. one given since the last ``G49``; Mach3 and
    grbl, as RS274NGC, need H)."""
    name = getattr(dia, "name", "rs274")
    if getattr(dia, "h_offset_alone", False):
        why = f"{name} takes the H number in force, and none was given since the last G49"
    elif name in ("rs274", None):
        why = ("LinuxCNC takes the tool an M6 loaded (--dialect linuxcnc), Fanuc and Haas the H in force, Mach3 "
               "needs H")
    else:
        why = f"{name} needs the H number"
    return f"{why}; write 'G43 Hn' with the tool table's number n"


def d_modal(st: _State) -> bool:
    """A ``D`` word alone sets the cutter radius offset number (modal; Fanuc, Haas, Siemens ISO, and with no dialect
    word, where only they run such a line: LinuxCNC refuses a D without G41/G42)."""
    return getattr(st.dialect, "h_offset_alone", False) or getattr(st.dialect, "g80_unrecognised", False)


def bare_d(st: _State):
    """The offset number of a ``G41``/``G42`` without ``D``, as :func:`bare_g43_tool` for ``H``: the last D on the
    Fanuc family; with no dialect, that D where it is also the tool ``M6`` loaded; None otherwise."""
    return _modal_number(st, st.last_d)


def _modal_number(st: _State, number):
    """An offset number left out of its word (``G43``'s H, ``G41``'s D): ``number`` (the last one given) on the
    Fanuc family (``h_offset_alone``); with no dialect, ``number`` where it is also the tool ``M6`` loaded; None
    otherwise."""
    if number is None:
        return None
    if getattr(st.dialect, "h_offset_alone", False):
        return number
    generic = st.dialect is None or st.dialect.name == "rs274"
    return number if generic and st.loaded == number else None


def _tool_change(st: _State, by, ms, idx: int = -1) -> None:
    """``Tn`` prepares tool n, ``M6`` loads the prepared one (the tool LinuxCNC's bare ``G43``/``G41`` use).
    ``M2``/``M30`` with a ``G52``/``G92`` shift in force: whether the controller clears it at the program end is
    its parameter or version (Fanuc 1202#3 RLC; LinuxCNC's M2/M30 reset changed between versions), recorded as a
    ``shift-end`` event (:func:`compensation.nc_state.program_frames` refuses a compensated move after it)."""
    if "T" in by and by["T"].value == int(by["T"].value):
        st.selected = int(by["T"].value)
    if any(m.value == 6 for m in ms):
        st.loaded = st.selected
    end = next((m for m in ms if m.value in (2.0, 30.0)), None)
    if end is not None and np.any(st.g92 != 0.0):
        st.events.append((idx, end.start + 1, "shift-end", None, f"M{end.text.strip()}"))


def _loaded(st: _State, code, w) -> int:
    """The tool in the spindle for a bare ``G43``/``G41``/``G42`` (LinuxCNC): the one the program loaded."""
    if st.loaded is None:
        raise _Refuse(w.start + 1, f"'{code}' without {'H' if code == 'G43' else 'D'} uses the tool in the spindle, which "
                                   "the program has not loaded (Tn M6) before it: write the number, or load the tool")
    return st.loaded


MODE_P = {"G8": ((0.0, 1.0), "P1 (look-ahead on) or P0 (off)"),
          "G5": ((0.0, 10000.0), "P10000 (high-precision contour control on) or P0 (off); another P is "
                                 "high-speed cycle machining (a stored cycle), not supported"),
          "G103": (tuple(float(n) for n in range(16)), "P0-P15 (blocks looked ahead)")}
"""The P a dialect's mode code needs (:mod:`compensation.dialects`): (allowed values, what the refusal says)."""
AICC_LEVELS = tuple(float(n) for n in range(1, 11))
"""``G05.1 Q1 Rn`` (Fanuc 30i-B "AI contour control II", machining quality level adjustment; Fusion 360's Fanuc post
writes it): R1 (speed) to R10 (precision) choose the tolerance the look-ahead keeps, not the path."""
MODE_P_OPTIONAL = ("G103", "G187")
"""Mode codes whose P may be left out (Haas mill manual: ``G103`` alone is ``G103 P0``, the normal look-ahead;
``G187`` alone returns smoothness and corner rounding to Settings 191 and 85)."""
MODE_E = {"G187": "P1 (rough), P2 (medium) or P3 (finish); E the largest corner rounding (> 0)"}
"""Mode codes that take an ``E`` word (Haas ``G187 Pn Ennn``: E overrides Setting 85, the corner rounding the
look-ahead may leave, a tolerance like ``G64 P``, not a path): the words they take."""


def _dialect_mode(idx, st: _State, groups, by, axis_words, arc_words) -> str:
    """A dialect's mode code (Fanuc ``G05.1 Q1``/``Q0`` look-ahead, Haas ``G187``, Siemens ``G291``): state,
    the path is the programmed one. ``G05.1 Q2`` (smooth interpolation: another path) and axis words are
    refused."""
    code, w = groups["dialect mode"]
    q = by.get("Q")
    if code == "G5.1" and (q is None or q.value not in (0.0, 1.0)):
        raise _Refuse(w.start + 1, f"'{code}' needs Q1 (look-ahead on) or Q0 (off); Q2 smooth interpolation "
                                   "changes the path and is not supported")
    if code == "G5.1" and "R" in arc_words:  # Fanuc 30i AI contour control II: 'G05.1 Q1 Rn', the quality level
        r = arc_words.pop("R") if len(arc_words) == 1 else arc_words["R"]
        if q.value != 1.0 or r.value not in AICC_LEVELS:
            raise _Refuse(r.start + 1, f"'R{r.text}' with G5.1: only 'G05.1 Q1 R1'-'R10' (the machining quality "
                                       "level, a tolerance) is read")
    p = by.get("P")
    if code in MODE_P and not (p is None and code in MODE_P_OPTIONAL) and (p is None or p.value not in MODE_P[code][0]):
        raise _Refuse(w.start + 1, f"'{code}' needs {MODE_P[code][1]}")
    e = by.get("E")
    if code in MODE_E and ((p is not None and p.value not in (1.0, 2.0, 3.0)) or (e is not None and e.value <= 0)):
        bad = e if p is None or p.value in (1.0, 2.0, 3.0) else p
        raise _Refuse(bad.start + 1, f"'{bad.letter}{bad.text}' with {code}: it takes {MODE_E[code]}")
    if code == "G50.1":  # its axis words name the axes whose mirroring ends: nothing moves
        axis_words = {}
    if axis_words or arc_words or groups.get("motion", ("G80",))[0] != "G80":  # G80 (no cycle) moves nothing
        first = next(iter({**axis_words, **arc_words}.values()), groups.get("motion", (None, w))[1])
        raise _Refuse(first.start + 1, f"'{first.letter}{first.text}' with {code} (a mode, not a move)")
    st.events.append((idx, w.start + 1, "mode", code, code))
    return "state"


def _machine_coordinates(idx, st: _State, groups, axis_words, arc_words, ax: AxisWords) -> str:
    """``G53 G0/G1 X..``: a move in machine coordinates, written back unchanged (machine coordinates are not
    the part's: not compensated); the axes it moves are unknown in program coordinates afterwards."""
    code, w = groups["nonmodal"]
    if arc_words:
        a = next(iter(arc_words.values()))
        raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with G53")
    if axis_words and st.mode not in ("G0", "G1"):
        raise _Refuse(w.start + 1, f"'G53' with axis words needs G0 or G1 active (got {st.mode or 'none'})")
    st.events.append((idx, w.start + 1, "g53", tuple(axis_words), "G53"))
    _forget(st, ax, tuple(axis_words))
    return "state"


G10_L20 = {"linuxcnc": "here", "grbl": "here", "fanuc": "G54.1", "siemens-iso": "G54.1", "haas": "G154"}
"""What ``G10 L20 Pn`` sets, by dialect: ``here`` work offset n (P0: the active one) so that the current
position reads the values (LinuxCNC, grbl); the extended system ``G54.1 Pn`` (Fanuc; Siemens ISO mode) or
``G154 Pn`` (Haas) to the values."""
G10_TOOL = {"linuxcnc": {10: ("here", None), 11: ("here", "G59.3")},
            "fanuc": {10: ("length", "geometry"), 11: ("length", "wear")},
            "haas": {10: ("length", "geometry"), 11: ("length", "wear"), 12: ("diameter", "geometry"),
                     13: ("diameter", "wear")}}
"""``G10 L10``-``L13`` by dialect: LinuxCNC L10/L11 set tool n's length so that the current Z reads the value
(in the active work system / in G59.3); Fanuc (tool offset memory B/C) and Haas set the H (length) and, on
Haas, the D (diameter) geometry and wear, whose sum is the offset."""


def _g10(idx, st: _State, groups, by, axis_words, ax: AxisWords) -> str:
    """``G10 L1/L2/L10-L13/L20`` as events, in the line's units, by the dialect's rules
    (:mod:`compensation.nc_state`); an L number the dialect does not define, or any ``G10`` under ``G91``
    (Fanuc adds the values to the stored ones), is refused."""
    code, w = groups["nonmodal"]
    if "motion" in groups:
        raise _Refuse(w.start + 1, "'G10' with a motion code on the same line")
    lw, pw = by.get("L"), by.get("P")
    if lw is None or pw is None or pw.value != int(pw.value) or pw.value < 0:
        raise _Refuse(w.start + 1, "'G10' needs L and a whole-number P")
    if st.incremental:
        raise _Refuse(w.start + 1, "'G10' under G91: Fanuc adds the values to the stored offset, LinuxCNC sets them; "
                                   "write G90 before the G10 line")
    scale = MM_PER_INCH if st.inch else 1.0
    vals = {a: v.value * (1.0 if a in ax.rotary else scale) for a, v in axis_words.items()}
    p, lnum, dia = int(pw.value), lw.value, (st.dialect.name if st.dialect is not None else "rs274")
    extra = [by[c] for c in ("I", "J", "K", "Q") if c in by]
    if extra:
        raise _Refuse(extra[0].start + 1, f"'{extra[0].letter}{extra[0].text}' with G10 (not read)")
    text = f"G10 L{lw.text.strip()} P{p}"
    if lnum in (2, 20):
        return _g10_work(idx, st, by, w, pw, p, lnum, dia, vals, axis_words, ax, text)
    if lnum == 1:
        if "Z" not in vals:
            raise _Refuse(w.start + 1, "'G10 L1' without Z (the tool length; Fanuc's L1 R form is dialect-dependent)")
        _only_z(vals, axis_words, "G10 L1")
        radius = by["R"].value * scale if "R" in by else float("nan")
        _not_active(st, p, w, text)
        st.events.append((idx, w.start + 1, "g10-tool", (p, (vals["Z"], radius)), text))
        return "state"
    rule = G10_TOOL.get(dia, {}).get(int(lnum)) if lnum == int(lnum) else None
    if rule is None:
        raise _Refuse(lw.start + 1, f"'G10 L{lw.text}': not defined on {dia} (LinuxCNC L10/L11 set a tool from the "
                                    "current position; Fanuc/Haas L10-L13 set offset memories: name the controller "
                                    "with --dialect), or give the values in --tool-table / --work-offsets")
    return _g10_tool(idx, st, by, w, p, rule, vals, axis_words, ax, scale, text)


def _g92(idx, st: _State, groups, axis_words, ax: AxisWords) -> str:
    """``G92 X..`` (the current position reads the values: the G92 offset grows by position minus value, along
    the axes given), ``G92.1`` (offset and stored values zero), ``G92.2`` (offset zero, stored values kept),
    ``G92.3`` (offset from the stored values), as events (``g92``: ``(values mm/deg, position before)``;
    ``g92.1``..``g92.3``: None) that :func:`compensation.nc_state.program_frames` adds to every work system's
    offset. The position in program coordinates is kept known: machine axes are program + work offset + G92."""
    code, w = groups["nonmodal"]
    if "motion" in groups:
        raise _Refuse(w.start + 1, f"'{code}' with a motion code on the same line")
    if code == "G52":
        return _g52(idx, st, w, axis_words, ax)
    if code in ("G92.2", "G92.3") and st.dialect is not None and st.dialect.name == "grbl":
        raise _Refuse(w.start + 1, f"'{code}': grbl has G92 and G92.1 only")
    if code != "G92":
        if axis_words:
            a = next(iter(axis_words.values()))
            raise _Refuse(a.start + 1, f"axis word '{a.letter}{a.text}' with {code}")
        new = st.g92_stored if code == "G92.3" else np.zeros_like(st.g92)
        st.pos = st.pos + st.g92 - new  # the machine stays where it is
        st.g92 = new.copy()
        if code == "G92.1":
            st.g92_stored = np.zeros_like(st.g92)
        st.events.append((idx, w.start + 1, code.lower(), None, code))
        return "state"
    if not axis_words:
        raise _Refuse(w.start + 1, "'G92' without axis words")
    if st.incremental:
        raise _Refuse(w.start + 1, "'G92' under G91: write G90 before the G92 line (its values are positions)")
    scale = MM_PER_INCH if st.inch else 1.0
    vals, pos = {}, {}
    st.pos, st.g92 = st.pos.copy(), st.g92.copy()
    for j, a in enumerate(ax.words):
        if a in axis_words:
            if not np.isfinite(st.pos[j]):
                raise _Refuse(axis_words[a].start + 1, f"'G92 {a}{axis_words[a].text}' sets {a} from the current "
                                                       "position, which is not known here (program an absolute move "
                                                       "along it before)")
            vals[a] = axis_words[a].value * (1.0 if a in ax.rotary else scale)
            pos[a] = float(st.pos[j])
            st.g92[j] += pos[a] - vals[a]
            st.pos[j] = vals[a]
    st.g92_stored = st.g92.copy()
    st.events.append((idx, w.start + 1, "g92", (vals, pos), "G92"))
    return "state"


LOCAL_SHIFT_DIALECTS = ("linuxcnc", "fanuc", "haas", "siemens-iso", "mach3", "rs274")
"""Dialects with ``G52`` (the local coordinate shift; ``rs274``: no dialect named, where every controller that runs
the line reads it alike); grbl and Heidenhain ISO have none (refused)."""


def _g52(idx, st: _State, w, axis_words, ax: AxisWords) -> str:
    """``G52 X.. Y..`` (Fanuc 0i-MF, Haas, Siemens ISO, Mach3 "local coordinate system"; LinuxCNC "G52 local
    offsets"): the shift of every work system along the axes given becomes the values (not added: ``G52 X0 Y0 Z0``
    cancels); nothing moves, so the current point's program coordinates change by the old shift minus the new one.
    LinuxCNC keeps it in the G92 registers (parameters 5211-5219: ``G92.1``/``G92.2`` clear it, ``G92.3`` restores
    it); Fanuc-family controllers have no G92 offset read here, so one register serves both. Under ``G91``
    (Mitsubishi and some Fanuc models add the values to the shift) refused; recorded as a ``g52`` event
    ``(values mm/deg, LinuxCNC's stored copy written)``."""
    if not axis_words:
        raise _Refuse(w.start + 1, "'G52' without axis words ('G52 X0 Y0 Z0' cancels the shift)")
    if st.incremental:
        raise _Refuse(w.start + 1, "'G52' under G91: some controllers add the values to the shift, others set it; "
                                   "write G90 before the G52 line")
    scale = MM_PER_INCH if st.inch else 1.0
    stores = st.dialect is not None and st.dialect.name == "linuxcnc"
    vals = {}
    st.pos, st.g92 = st.pos.copy(), st.g92.copy()
    for j, a in enumerate(ax.words):
        if a in axis_words:
            vals[a] = axis_words[a].value * (1.0 if a in ax.rotary else scale)
            st.pos[j] += st.g92[j] - vals[a]  # the machine stays where it is
            st.g92[j] = vals[a]
    if stores:
        st.g92_stored = st.g92.copy()
    st.events.append((idx, w.start + 1, "g52", (vals, stores), "G52"))
    return "state"


def synced_words(code, by, arc_words, col: int) -> None:
    """The words of a ``G33``/``G33.1`` line (LinuxCNC G-code reference): ``K`` the distance per spindle
    revolution (required, positive), ``I`` the return speed multiplier of ``G33.1`` (optional); no other
    arc word."""
    k = by.get("K")
    if k is None or not k.value > 0:
        raise _Refuse(k.start + 1 if k is not None else col, f"'{code}' needs K (the distance per spindle revolution, "
                                                             "positive)")
    bad = [w for a, w in arc_words.items() if a not in ("K", "I") or (a == "I" and code == "G33")]
    if bad:
        raise _Refuse(bad[0].start + 1, f"'{bad[0].letter}{bad[0].text}' with {code}")


def _not_active(st: _State, p, w, text) -> None:
    """A G10 that changes the length of the tool whose offset is active: when the controller applies the new
    length (at once, or at the next ``G43``/``H``) depends on the controller and its parameters: refused."""
    if p == st.tool:
        raise _Refuse(w.start + 1, f"'{text}' changes tool {p}, whose length offset is active (G43 H{p}): whether the "
                                   "controller applies the new length at once or at the next G43 depends on the "
                                   f"controller; cancel it first (G49) or set the tool before selecting it")


def _only_z(vals, axis_words, what):
    bad = [a for a in vals if a != "Z" and vals[a] != 0.0]
    if bad:
        raise _Refuse(axis_words[bad[0]].start + 1, f"'{what}' with a tool offset along {bad[0]}: not supported")


def _g10_work(idx, st: _State, by, w, pw, p, lnum, dia, vals, axis_words, ax: AxisWords, text) -> str:
    """``G10 L2`` (LinuxCNC P0: the active system; LinuxCNC's ``R``: the system's XY rotation, deg, about its origin)
    and ``G10 L20`` by dialect (:data:`G10_L20`)."""
    rot = None
    if "R" in by:
        r = by["R"]
        if lnum != 2 or dia != "linuxcnc":
            raise _Refuse(r.start + 1, f"'R' with G10 L{int(lnum)}: " + (
                "a rotated work system is read with G10 L2 only (set the rotation there)" if dia == "linuxcnc" else
                "the work system's XY rotation is LinuxCNC's (--dialect linuxcnc); Fanuc rotates with G68 (refused)"))
        rot = r.value
    how = "table" if lnum == 2 else G10_L20.get(dia)
    if how is None:
        raise _Refuse(w.start + 1, f"'{text}': dialect-dependent (LinuxCNC, grbl: work offset P set from the current "
                                   "position; Fanuc: G54.1 P; Haas: G154 P): name the controller with --dialect")
    active = st.system or "G54"  # the power-on system before any selection
    if how in ("G54.1", "G154"):
        top = EXTENDED_MAX if how == "G54.1" else HAAS_MAX
        if not 1 <= p <= top:
            raise _Refuse(pw.start + 1, f"'P{pw.text}' with G10 L20 on {dia}: expected P1..P{top} ({how} P1..P{top})")
        name = system_name(how, p)
    elif p == 0 and dia in ("linuxcnc", "grbl"):
        name = active
    elif 1 <= p <= len(SYSTEMS):
        name = SYSTEMS[p - 1]
    else:
        raise _Refuse(pw.start + 1, f"'P{pw.text}' with G10 L{int(lnum)}: expected P1..P{len(SYSTEMS)} (G54..G59.3; P0 is "
                                    "the active system on LinuxCNC and grbl (--dialect) but the external offset on Fanuc)")
    if how == "here":
        pos = {}
        for j, a in enumerate(ax.words):
            if a in vals:
                if not np.isfinite(st.pos[j]):
                    raise _Refuse(axis_words[a].start + 1, f"'{text}' sets {a} from the current position, which is not "
                                                           "known here (program an absolute move along it before)")
                pos[a] = float(st.pos[j])
        st.events.append((idx, w.start + 1, "g10-here", (name, vals, pos, active), text))
        if name == active:  # the current position now reads the values
            st.pos = st.pos.copy()
            for j, a in enumerate(ax.words):
                if a in vals:
                    st.pos[j] = vals[a]
        return "state"
    st.events.append((idx, w.start + 1, "g10-work", (name, vals, rot, dia == "linuxcnc"), text))
    if name == active:
        _forget(st, ax, tuple(vals) + (("X", "Y") if rot is not None else ()))
    return "state"


def _g10_tool(idx, st: _State, by, w, p, rule, vals, axis_words, ax: AxisWords, scale, text) -> str:
    """``G10 L10``-``L13`` (:data:`G10_TOOL`)."""
    kind, part = rule
    if kind != "diameter":
        _not_active(st, p, w, text)
    if kind == "here":
        if "Z" not in vals:
            raise _Refuse(w.start + 1, f"'{text}' without Z (the tool length is set so that the current Z reads it)")
        _only_z(vals, axis_words, text)
        jz = ax.words.index("Z")
        if not np.isfinite(st.pos[jz]):
            raise _Refuse(axis_words["Z"].start + 1, f"'{text}' sets the tool from the current Z, which is not known "
                                                     "here (program an absolute Z move before)")
        radius = by["R"].value * scale if "R" in by else float("nan")
        st.events.append((idx, w.start + 1, "g10-tool-here", (p, vals["Z"], float(st.pos[jz]), part, radius), text))
    else:
        if axis_words:
            a = next(iter(axis_words.values()))
            raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with {text} (the value is R)")
        if "R" not in by:
            raise _Refuse(w.start + 1, f"'{text}' without R (the offset value)")
        value = by["R"].value * scale * (0.5 if kind == "diameter" else 1.0)
        st.events.append((idx, w.start + 1, "g10-tool-part", (p, "length" if kind == "length" else "radius", part,
                                                              value), text))
    return "state"


# ---------------------------------------------------------------------------- outputs, inputs, native Siemens
def io_line(words, dia):
    """``"pass"`` for a LinuxCNC output/input line (``M62``-``M68`` with their words, nothing else; the
    dialect's :attr:`compensation.dialects.Dialect.io_codes`), checked as LinuxCNC's interpreter does;
    None for any other line."""
    codes = getattr(dia, "io_codes", None) or {}
    io = [x for x in words if x.letter == "M" and x.value == int(x.value) and int(x.value) in codes]
    if not io:
        return None
    m = io[0]
    code = int(m.value)
    by = {}
    for x in words:
        if x is m or x.letter == "N":
            continue
        if x.letter not in "PELQ" or x.letter in by:
            raise _Refuse(x.start + 1, f"'{x.letter}{x.text}' on an M{code} line ({codes[code]}): put it on a line of "
                                       "its own")
        by[x.letter] = x
    need = {62: "P", 63: "P", 64: "P", 65: "P", 67: "EQ", 68: "EQ"}.get(code, "")
    allowed = {66: "PELQ"}.get(code, need)
    for x in by.values():
        if x.letter not in allowed:
            raise _Refuse(x.start + 1, f"'{x.letter}{x.text}' with M{code} (it takes {' '.join(allowed)})")
    for letter in need:
        if letter not in by:
            raise _Refuse(m.start + 1, f"'M{code}' without {letter}")
    for letter in "PE":
        if letter in by and (by[letter].value != int(by[letter].value) or by[letter].value < 0):
            raise _Refuse(by[letter].start + 1, f"'{letter}{by[letter].text}': expected a channel number")
    if code == 66:
        if ("P" in by) == ("E" in by):
            raise _Refuse(m.start + 1, "'M66' needs P (a digital input) or E (an analog input), one of them")
        mode = by["L"].value if "L" in by else 0.0
        if mode not in (0.0, 1.0, 2.0, 3.0, 4.0):
            raise _Refuse(by["L"].start + 1, f"'L{by['L'].text}' with M66: expected L0..L4")
        if mode != 0.0 and ("Q" not in by or by["Q"].value <= 0):
            raise _Refuse(m.start + 1, "'M66' waiting (L1..L4) needs a timeout Q > 0 seconds")
    return "pass"


_SIEMENS_CALL = re.compile(r"[ \t]*(?:N\d+[ \t]*)?(?:(?:CALL|PCALL|MCALL)\b|G0*290(?![\d.]))", re.IGNORECASE)
_SIEMENS_L = re.compile(r"[ \t]*(?:N\d+[ \t]*)?L\d+[ \t]*(?:P\d+[ \t]*)?(?:;.*)?$", re.IGNORECASE)


def siemens_native(body: str, siemens: bool):
    """``(column, word)`` of a Siemens native-mode call or mode switch at the start of a line (``CALL "..."``,
    ``G290``; on ``siemens`` also a bare ``L100`` / ``L100 P2`` subprogram call), or None."""
    m = _SIEMENS_CALL.match(body) or (_SIEMENS_L.match(body) if siemens else None)
    if m is None:
        return None
    word = re.match(r"[ \t]*(?:N\d+[ \t]*)?", body)
    return word.end() + 1, re.match(r"[A-Za-z]+\d*", body[word.end():]).group()
