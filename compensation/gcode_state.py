"""The controller-state words of the G-code reader (:mod:`compensation.gcode`), line by line: work-system
selections (``G54`` … ``G59.3``, ``G54.1 Pn``), tool length offsets (``G43 Hn`` / ``G49``), cutter radius
compensation (``G41``/``G42 Dn`` / ``G40``), the program's own tables (``G10 L2`` / ``L1``), moves in machine
coordinates (``G53``) and a dialect's mode codes (:mod:`compensation.dialects`). Each is recorded as an
event (:attr:`compensation.gcode.GProgram.events`) that :func:`compensation.nc_state.program_frames`
resolves against the controller's tables; where a frame changes, the program position along the axes it
moves becomes unknown (the next move there must give it absolutely)."""
from __future__ import annotations

import numpy as np

from .nc_state import EXTENDED_MAX, SYSTEMS, system_name

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


def _work_state(idx, st: _State, groups, by, ax: AxisWords) -> None:
    """A work-system selection (``G54`` … ``G59.3``, ``G54.1 Pn``) or a tool length offset (``G43 Hn``,
    ``G49``): recorded as an event (:attr:`GProgram.events`); where the frame changes, the position
    along the axes it moves becomes unknown."""
    if "coords" in groups:
        code, w = groups["coords"]
        p = None
        if code == "G54.1":
            pw = by.get("P")
            if pw is None or pw.value != int(pw.value) or not 1 <= pw.value <= EXTENDED_MAX:
                raise _Refuse(w.start + 1, f"'G54.1' needs P1..P{EXTENDED_MAX} (the extended work system)")
            p = int(pw.value)
        name = system_name(code, p)
        st.events.append((idx, w.start + 1, "system", name, name if p is None else f"G54.1 P{p}"))
        if name != st.system:
            _forget(st, ax, ax.words)
            st.system = name
    if "cutter" in groups:
        code, w = groups["cutter"]
        d = by.get("D")
        if d is not None and (d.value != int(d.value) or d.value < 0):
            raise _Refuse(d.start + 1, f"'D{d.text}': expected a tool number")
        value = int(d.value) if d is not None else None
        st.events.append((idx, w.start + 1, "cutter", value, code if value is None else f"{code} D{value}"))
    if "length" in groups:
        code, w = groups["length"]
        value = None
        if code == "G43":
            h = by["H"]
            if h.value != int(h.value) or h.value < 0:
                raise _Refuse(h.start + 1, f"'H{h.text}': expected a tool number")
            value = int(h.value)
        st.events.append((idx, w.start + 1, "tool", value, code if value is None else f"G43 H{value}"))
        if value != st.tool:
            _forget(st, ax, ("Z",))
            st.tool = value


def _dialect_mode(idx, st: _State, groups, by, axis_words, arc_words) -> str:
    """A dialect's mode code (Fanuc ``G05.1 Q1``/``Q0`` look-ahead, Haas ``G187``, Siemens ``G291``): state,
    the path is the programmed one. ``G05.1 Q2`` (smooth interpolation: another path) and axis words are
    refused."""
    code, w = groups["dialect mode"]
    q = by.get("Q")
    if code == "G5.1" and (q is None or q.value not in (0.0, 1.0)):
        raise _Refuse(w.start + 1, f"'{code}' needs Q1 (look-ahead on) or Q0 (off); Q2 smooth interpolation "
                                   "changes the path and is not supported")
    if axis_words or arc_words or "motion" in groups:
        first = next(iter({**axis_words, **arc_words}.values()), w)
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


G10_REFUSED = ("dialect-dependent: Fanuc L10-L13 set tool offset memories and L20 the extended systems G54.1 Pn; "
               "LinuxCNC L10, L11, L20 set them from the current position; give the values in --tool-table / "
               "--work-offsets")


def _g10(idx, st: _State, groups, by, axis_words, ax: AxisWords) -> str:
    """``G10 L2 Pn`` (work offset n = 1..9: G54..G59.3) and ``G10 L1 Pn Z.. [R..]`` (tool n's length and
    radius) as events, in the line's units; other L numbers are refused (:data:`G10_REFUSED`)."""
    code, w = groups["nonmodal"]
    if "motion" in groups:
        raise _Refuse(w.start + 1, "'G10' with a motion code on the same line")
    lw, pw = by.get("L"), by.get("P")
    if lw is None or pw is None or pw.value != int(pw.value) or pw.value < 0:
        raise _Refuse(w.start + 1, "'G10' needs L and a whole-number P")
    scale = MM_PER_INCH if st.inch else 1.0
    vals = {a: v.value * (1.0 if a in ax.rotary else scale) for a, v in axis_words.items()}
    p = int(pw.value)
    extra = [by[c] for c in ("I", "J", "K", "Q") if c in by]
    if extra:
        raise _Refuse(extra[0].start + 1, f"'{extra[0].letter}{extra[0].text}' with G10 (not read)")
    if lw.value == 2:
        if "R" in by:
            raise _Refuse(by["R"].start + 1, "'R' with G10 L2: a rotated work system is not supported")
        if not 1 <= p <= len(SYSTEMS):
            raise _Refuse(pw.start + 1, f"'P{pw.text}' with G10 L2: expected P1..P{len(SYSTEMS)} (G54..G59.3; P0 is "
                                        "the active system on LinuxCNC but the external offset on Fanuc)")
        name = SYSTEMS[p - 1]
        st.events.append((idx, w.start + 1, "g10-work", (name, vals), f"G10 L2 P{p}"))
        if name == st.system:
            _forget(st, ax, tuple(vals))
        return "state"
    if lw.value == 1:
        if "Z" not in vals:
            raise _Refuse(w.start + 1, "'G10 L1' without Z (the tool length; Fanuc's L1 R form is dialect-dependent)")
        bad = [a for a in vals if a != "Z" and vals[a] != 0.0]
        if bad:
            raise _Refuse(axis_words[bad[0]].start + 1, f"'G10 L1' with a tool offset along {bad[0]}: not supported")
        radius = by["R"].value * scale if "R" in by else float("nan")
        st.events.append((idx, w.start + 1, "g10-tool", (p, (vals["Z"], radius)), f"G10 L1 P{p}"))
        if p == st.tool:
            _forget(st, ax, ("Z",))
        return "state"
    raise _Refuse(lw.start + 1, f"'G10 L{lw.text}': {G10_REFUSED}")
