"""The per-line classifier of the G-code reader (:mod:`compensation.gcode`): modal state (:class:`_State`),
modal groups, the words each line may carry, moves and arc geometry (:func:`plane_arc`, :func:`move_points`)."""
from __future__ import annotations

import math
from dataclasses import replace
import re

import numpy as np

from .gcode_state import (DYNAMIC_CUTTER, LOCAL_SHIFT_DIALECTS, lathe_t_offset, ttoo_lathe, MODE_E, bare_d, bare_g43_rule, bare_g43_tool, d_modal, _dialect_mode, _forget, _g10, _g92, probe_move, synced_words, io_line, _machine_coordinates, MM_PER_INCH, _Refuse, siemens_native,
                          _tool_change, _work_state)
from .nc_contour import ContourState, after_line, cycle_line
from .nc_groove import groove_line
from .nc_contour import applies as contour_reading
from .nc_flow import TRACKED_NAMES
from .nc_g76 import g76_line
from .nc_g7x import g7x_line
from .nc_thread import feed_word_seen, g32_move, g33_move, thread_line
from .nc_state import lathe_words
from .gcode_spline import nurbs_end, nurbs_line, spline_move, spline_points, spline_segments
from .gcode_words import (ALLOWED_G, ARC_RADIUS_TOL_INCH_MM, ARC_RADIUS_TOL_MM, AxisWords, CENTRE_AXIS,
                          default_axis_words, DEFAULT_RAPIDS, G92_CODES, GMove, LETTER_RULES, MAX_TOOL_DIGITS, PLANE_NAMES,
                          PLANES, REFUSED_G, REFUSED_LETTERS, tokenize, Word)


class _State:
    def __init__(self, k: int = 3):
        self.mode = None           # "G0".."G3" or None
        self.incremental = False
        self.arc_abs = False
        self.inch = False
        self.plane = "G17"         # the RS274 power-on default
        self.pos = np.full(k, np.nan)
        self.system = None         # the work system selected (None: none yet)
        self.tool = None           # the tool length offset H number (None: G49 / none / H0)
        self.g43 = False           # G43 in force (an H word alone changes it on Fanuc-family dialects)
        self.after_g80 = False     # the motion mode was ended by G80 (the refusal names the dialects that keep it)
        self.before_g80 = None     # the G0-G3 that G80 ended (read again where no dialect was recognised)
        self.g80_line = 0          # the first line read so (GProgram.g80_line)
        self.events = []           # GProgram.events
        self.dialect = None        # compensation.dialects.Dialect (None: the generic one)
        self.selected = None       # the last T word (the tool prepared)
        self.loaded = None         # the tool an M6 of the program loaded (None: the controller's, unknown)
        self.last_h = None         # the last H number the program gave (Fanuc: H is modal; a bare G43 takes it)
        self.last_d = None         # the last D number (Fanuc: D is modal; a bare G41/G42 takes it)
        self.cutter = "G40"        # the cutter compensation in force (G40, G41, G42)
        self.t_changed = None      # the column of a lathe T word that changed the offset register on this line
        self.spline_pq = None      # ((P, Q) mm, end) of the G5 move just read (a next G5 may omit I J)
        self.nurbs = None          # the open G5.2 block (compensation.gcode_spline.nurbs_line)
        self.diameter = False      # lathe diameter mode (LinuxCNC G7): X words are diameters
        self.lathe_x = None        # a Fanuc/Haas/Siemens ISO lathe's X: "diameter", "radius" (--lathe-x; None: refused)
        self.g92 = np.zeros(k)     # the G92 offset in force (mm / deg; gcode_state._g92)
        self.g92_stored = np.zeros(k)  # the G92 offset stored (LinuxCNC parameters 5211-5219; G92.3 restores it)
        self.last_given = {}       # axis letter -> index of the last move line that gave it (the refusals say why)
        self.replay = None         # gcode.FrameReplay: a G53 move's end in the program's frame (None: no tables)
        self.contours = ContourState()  # a Fanuc/Haas lathe's G70-G73 contour cycles (compensation.nc_contour)
        self.thread = None         # a modal G92 thread cutting cycle in force (compensation.nc_thread)
        self.thread_lead = None    # (value, text) of the lead a G32 without F takes (compensation.nc_thread)
        self.last_move = None      # the last move read (a G32's start: compensation.nc_thread.g32_move)
        self.g7x_contours = {}     # LinuxCNC G70-G72 contours by line (compensation.nc_expand.Expanded.contours)
        self.name = int            # a 1-based line as a refusal's text names it (compensation.nc_expand.source_line)


def classify_line(body: str, state: _State, rapids=DEFAULT_RAPIDS, block_delete=None,
                  axis_words: AxisWords | None = None):
    """Public form of the per-line classifier: ``(class, GMove or None)``; updates ``state``
    (``_State(len(axis_words.words))``); ``axis_words`` ``None``: :func:`default_axis_words`."""
    return _classify(body, -1, state, rapids, block_delete, default_axis_words() if axis_words is None else axis_words)


def _checked_words(words, ax: AxisWords, dia=None):
    """Check every word against the allow-lists (``dia``: the :class:`compensation.dialects.Dialect`'s
    M codes and mode codes; None: the generic one) and the machine's axis words:
    ``(by letter, [(G code, word)], [M words])``."""
    from .dialects import GENERIC, g7x_refusal, other_dialects_with_g, other_dialects_with_m
    dia = GENERIC if dia is None else dia
    by = {}
    gs, ms = [], []
    e_mode = any(w.letter == "G" and w.code in MODE_E and w.code in dia.modes for w in words)  # Haas G187 E
    for w in words:
        if w.letter == "G":
            code = w.code
            if round(w.value, 1) != round(w.value, 6):
                raise _Refuse(w.start + 1, f"'G{w.text}': unknown G code")
            if code in dia.modes or code in dia.work_systems or code in dia.splines or code in dia.synced or (
                    code in dia.lathe_modes) or code in dia.probes or (
                    dia.g92_offsets and code in G92_CODES) or (code == "G52" and dia.name in LOCAL_SHIFT_DIALECTS) or (
                    code == "G43.1" and dia.dynamic_length) or (code in DYNAMIC_CUTTER and dia.dynamic_cutter):
                gs.append((code, w))
                continue
            if code in BARE_UNITS and dia.g80_unrecognised and "Y" in ax.words and all(x.letter in "GN" for x in words):
                gs.append((BARE_UNITS[code], w))  # a bare G70/G71 on a mill: inch/mm wherever it runs
                continue
            g7x = g7x_refusal(code, dia.name, lathe_words(ax.words)) if code in ("G70", "G71", "G72") else None
            if g7x is not None:
                raise _Refuse(w.start + 1, g7x)
            if code in REFUSED_G:
                raise _Refuse(w.start + 1, f"'{code}' ({REFUSED_G[code]}) is not supported"
                                           f"{other_dialects_with_g(code, dia.name)}")
            if code not in ALLOWED_G:
                raise _Refuse(w.start + 1, f"'{code}': unknown G code (not on the allow-list)"
                                           f"{other_dialects_with_g(code, dia.name)}")
            gs.append((code, w))
            continue
        if w.letter == "M":
            if w.value != int(w.value) or int(w.value) not in dia.m_codes and int(w.value) not in ax.harmless_m:
                raise _Refuse(w.start + 1, f"'M{w.text}': M code not on the {dia.name} allow-list (may move or call a "
                                           f"program){other_dialects_with_m(w.value, dia.name)}")
            ms.append(w)
            continue
        if w.letter in ax.words or (w.letter == "E" and e_mode):
            pass  # an axis word of the machine, or a mode code's E (checked by gcode_state._dialect_mode)
        elif w.letter in ax.lacking:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': {ax.lacking[w.letter]}; not supported")
        elif w.letter in REFUSED_LETTERS:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': {REFUSED_LETTERS[w.letter]}; not supported")
        elif w.letter not in LETTER_RULES:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': unknown word")
        elif w.letter == "T" and ttoo_lathe(dia, ax) and not _lathe_t_word(w, ax, dia):
            raise _lathe_t_refusal(w, dia)
        elif w.letter == "T" and not _plain_tool_number(w, ax) and not _lathe_t_word(w, ax, dia):
            raise _Refuse(w.start + 1, f"'T{w.text}': a T word of more than {MAX_TOOL_DIGITS} digits (or not a "
                                       "whole number) may select a tool offset (lathe 'TttOO': tool tt, offset "
                                       "OO) that shifts the axes, like G43 H; not supported (write the tool "
                                       f"number alone, at most {MAX_TOOL_DIGITS} digits)")
        if w.letter in by:
            raise _Refuse(w.start + 1, f"repeated '{w.letter}' word")
        by[w.letter] = w
    return by, gs, ms


def _machine_m_codes(st: _State, ms, idx: int, ax: AxisWords, dia) -> None:
    """Record (an event ``"machine-m"``) each M word passed only because the machine file lists it as harmless."""
    from .dialects import GENERIC
    for w in ms:
        if ax.harmless_m and int(w.value) in ax.harmless_m and int(w.value) not in (dia or GENERIC).m_codes:
            st.events.append((idx, w.start + 1, "machine-m", int(w.value), f"M{w.text}"))


def _lathe_t_refusal(w: Word, dia) -> _Refuse:
    """A T word of a lathe that reads ``TttOO`` (:func:`compensation.gcode_state.ttoo_lathe`) that is not one
    (:func:`_lathe_t_word`)."""
    short = w.text.strip().isdigit() and len(w.text.strip()) <= 2
    why = "1 or 2 digits leave the offset register to a machine setting (the station's own or OO)" if short else \
        "not four digits"
    return _Refuse(w.start + 1, f"'T{w.text}': a {dia.name} lathe's T word is TttOO (tool tt, offset register OO; "
                                f"T202 reads as T0202): {why}; write the four digits, like T0202")


def _lathe_t_word(w: Word, ax: AxisWords, dia) -> bool:
    """A ``TttOO`` word of a dialect that reads it so, on a lathe (:func:`compensation.gcode_state.ttoo_lathe`):
    tool ``tt`` with offset ``OO`` (:func:`compensation.gcode_state.lathe_t_offset`), four digits as written or
    three (a word's leading zeros may be left out: ``T202`` is ``T0202``). One or two digits are not read: the
    control takes the offset register from them by a machine setting (the station's own offset, or ``OO``)."""
    digits = w.text.strip()
    return ttoo_lathe(dia, ax) and len(digits) in (3, 4) and digits.isdigit()


def _plain_tool_number(w: Word, ax: AxisWords) -> bool:
    """A ``T`` word that can only be a tool number: a whole number of at most :data:`MAX_TOOL_DIGITS` digits as
    written (``T1``, ``T01``, ``T12``; not ``T0101``, ``T101``, ``T1.5``, ``T-1``), or of any number of digits
    on a mill (X, Y and Z axis words: :func:`mill_words`), where T only selects the tool (Fanuc, Haas, LinuxCNC,
    Mach3 mills; a Mastercam Fanuc post writes ``T212``) and its length comes from ``G43 H``."""
    digits = w.text.replace(" ", "").replace("\t", "")
    return digits.isdigit() and (len(digits) <= MAX_TOOL_DIGITS or mill_words(ax.words))


def mill_words(words) -> bool:
    """A mill's axis words: X, Y and Z (a lathe's ``TttOO`` offset form is read only without Y)."""
    return {"X", "Y", "Z"} <= set(words)


def _modal_groups(gs, dia=None) -> dict:
    """``{modal group: (G code, word)}``; two codes of one group on a line are refused (but ``G80`` with
    a motion code where the dialect runs them so: the motion code is kept)."""
    groups = {}
    for code, w in gs:
        grp = "length" if code == "G43.1" else "cutter" if code in DYNAMIC_CUTTER else "lathe" if dia is not None and code in dia.lathe_modes else "nonmodal" if code in G92_CODES or code == "G52" else "dialect mode" if dia is not None and code in dia.modes else "motion" if dia is not None and (
            code in dia.splines or code in dia.synced or code in dia.probes) else ALLOWED_G[code][0] if code in ALLOWED_G else (
            "coords" if dia is not None and code in dia.work_systems else "dialect mode")  # a dialect's own first
        g80_motion = dia is not None and (dia.g80_with_motion or dia.g80_unrecognised)  # no dialect: the one reading
        if grp == "motion" and grp in groups and g80_motion and "G80" in (code, groups[grp][0]):
            if code != "G80":
                groups[grp] = (code, w)
            continue
        if grp in groups:
            why = ("; Fanuc, Haas, Siemens ISO and Mach3 cancel the cycle and take the motion code: name the controller "
                   "with --dialect" if grp == "motion" and "G80" in (code, groups[grp][0]) else "")
            raise _Refuse(w.start + 1, f"'{code}' and '{groups[grp][0]}' on one line (same modal group){why}")
        groups[grp] = (code, w)
    return groups


def _apply_modal(st: _State, groups: dict):
    """Modal state first (RS274 order of execution: units, plane, distance before motion); the motion word."""
    if "units" in groups:
        st.inch = groups["units"][0] == "G20"
    if "plane" in groups:
        st.plane = groups["plane"][0]
    if "distance" in groups:
        st.incremental = groups["distance"][0] == "G91"
    if "arc_distance" in groups:
        st.arc_abs = groups["arc_distance"][0] == "G90.1"
    motion_word = None
    if "motion" in groups:
        code, motion_word = groups["motion"]
        st.after_g80 = code == "G80" and (st.mode is not None or st.after_g80)
        if code == "G80" and st.mode is not None:
            st.before_g80 = st.mode
        if code != "G5":
            st.spline_pq = None
        if code != "G80":
            st.mode = code
        elif not getattr(st.dialect, "g80_keeps_motion", False):
            st.mode = None  # RS274NGC: G80 ends the motion mode; Fanuc group 09: G0-G3 stays (nc_cycles restores it)
    return motion_word


LATHE_NOSE_HINT = "; on a Fanuc or Haas lathe the TttOO word's register gives it: name the controller with --dialect"


def _check_p_q(st: _State, by: dict, gs, axis_words, arc_words, nose: bool = False, lathe: bool = False):
    """``P`` only with G4/G64 (or P1 on an arc), ``Q`` only with G64; ``D`` only with G41/G42 (and LinuxCNC's
    G41.1/G42.1, ``L`` too), and not at all on a lathe whose ``G41``/``G42`` take the T word's register (``nose``: :func:`compensation.gcode_state.ttoo_lathe`)."""
    for letter, allowed_with in (("P", ("G4", "G64", "G54.1", "G154", "G10", "G187")), ("Q", ("G64", "G5.1")), ("H", ("G43",)),
                                 ("L", ("G10",) + DYNAMIC_CUTTER)):
        if letter in by:
            h_alone = letter == "H" and getattr(st.dialect, "h_offset_alone", False)  # Fanuc: H alone in G43 mode
            arc_p1 = letter == "P" and st.mode in ("G2", "G3") and bool(axis_words or arc_words) and by["P"].value == 1
            mode_p = letter == "P" and st.dialect is not None and any(c in st.dialect.modes for c, _ in gs)
            spline = (letter in "PQ" or (letter == "L" and st.mode == "G5.2")) and st.dialect is not None and (
                st.mode in st.dialect.splines)  # gcode_spline checks
            if not (h_alone or arc_p1 or mode_p or spline or any(c in allowed_with for c, _ in gs)):
                raise _Refuse(by[letter].start + 1, f"'{letter}{by[letter].text}' outside {'/'.join(allowed_with)}"
                              + (" (or P1 on an arc)" if letter == "P" else "") + (H_HINT if letter == "H" else ""))
    if nose and "D" in by:
        raise _Refuse(by["D"].start + 1, f"'D{by['D'].text}' on a {st.dialect.name} lathe: G41/G42 take the nose radius "
                                         "of the T word's offset register (TttOO); what a D word selects is not settled "
                                         "here: leave it out and give the radius in the tool table's radius_mm column")
    for letter, code in (("D", ("G41", "G42") + DYNAMIC_CUTTER),):
        if letter in by and not any(c in code for c, _ in gs) and not d_modal(st):
            raise _Refuse(by[letter].start + 1, f"'{letter}{by[letter].text}' outside {'/'.join(code)}")
    loaded = st.dialect is not None and st.dialect.name in LOADED_TOOL_DIALECTS  # resolved by _work_state
    for c, w in gs:
        if c in ("G41", "G42") and "D" not in by and not loaded and not nose and bare_d(st) is None:
            raise _Refuse(w.start + 1, f"'{c}' without D (the current tool's radius): write '{c} Dn' with the tool "
                                       "table's number n" + (LATHE_NOSE_HINT if lathe else ""))
    if "G43" in (c for c, _ in gs) and "H" not in by and not loaded and bare_g43_tool(st) is None:
        w = next(w for c, w in gs if c == "G43")
        raise _Refuse(w.start + 1, "'G43' without H (the current tool's length): " + bare_g43_rule(st.dialect))


G80_HINT = " after G80 (Fanuc, Haas, Siemens ISO keep the G0-G3 of before a cycle: name the controller with --dialect)"
H_HINT = ("; Fanuc, Haas, Siemens ISO: an H alone changes the length offset in G43 mode (H0: zero): name the "
          "controller with --dialect")
LOADED_TOOL_DIALECTS = ("linuxcnc",)
"""Dialects whose ``G43`` without ``H`` and ``G41``/``G42`` without ``D`` use the tool in the spindle (LinuxCNC
G-code reference: "G43 ... if H is not given, the current tool's"; "G41 ... D omitted: the current tool")."""
_COLON_NUMBER = re.compile(r"[ \t]*:[ \t]*\d+[ \t]*(?:\([^)]*\)[ \t]*)?")


BARE_UNITS = {"G70": "G20", "G71": "G21"}
"""``G70``/``G71`` alone (no word but other G codes and N) on a machine with X and Y, under ``--dialect auto`` with no
dialect word: inch / mm, the one reading under which the line runs (Siemens native, Heidenhain ISO, NUM, Fagor and
NX's generic posts; a lathe cycle needs P Q or U W words, Fanuc and LinuxCNC mills have no bare G70/G71, Haas' G70
bolt circle needs I J L); the line is named in the summary. Named dialects keep refusing it."""
GRBL_VIEW = {"$$": "view settings", "$#": "view parameters", "$G": "view parser state", "$I": "view build info",
             "$N": "view startup blocks", "$X": "kill the alarm lock"}
"""grbl v1.1 '$' system commands that move nothing and change nothing the path depends on (passed through)."""


def _grbl_system(body: str, st: _State, ax: AxisWords) -> str:
    """A grbl ``$`` system command line (grbl v1.1 "Grbl $ commands"): the views and ``$X`` pass; ``$H`` (the homing
    cycle) moves every axis to machine home, so the program position is unknown until the next absolute word; the
    others (``$J=`` jog, ``$C`` check mode, ``$x=`` settings that scale or limit the axes, ``$Nx=`` startup blocks,
    ``$RST=``, ``$SLP``) are refused."""
    cmd = body.strip().split(";")[0].split("(")[0].strip().upper()
    if cmd in GRBL_VIEW:
        return "pass"
    if cmd == "$H":
        _forget(st, ax, ax.words)
        return "pass"
    raise _Refuse(body.index("$") + 1, f"grbl system command '{cmd[:20]}' (a jog, check mode, setting or startup "
                                       "block: moves or changes what the axes do) is not read; remove it from the "
                                       "program (only $$ $# $G $I $N $X and $H pass)")


_LCNC_G76 = re.compile(r"[gG]\s*0*7\s*6(?![\d.])")
"""A line that may hold LinuxCNC's G76 (read by :func:`compensation.nc_g76.g76_line` on a lathe)."""
_LCNC_G7X = re.compile(r"[gG]\s*0*7\s*[012]")
"""A line that may hold LinuxCNC's G70-G72 (read by :func:`compensation.nc_g7x.g7x_line` on a lathe)."""


def _classify(body, idx, st: _State, rapids, block_delete, ax: AxisWords):
    """One line: ``(class, GMove or None)``; a lathe's contour cycle lines kept as written and their contour
    blocks read as moves (:mod:`compensation.nc_contour`), its grooving cycles and threading read
    (:mod:`compensation.nc_groove`, :mod:`compensation.nc_thread`)."""
    cs = st.contours
    if getattr(st.dialect, "name", None) == "linuxcnc" and lathe_words(ax.words) and _LCNC_G76.search(body):
        try:
            bd, words, _ = tokenize(body)
        except _Refuse:
            words = ()  # the line's own reading names what it holds
        if words and g76_line(words, idx, st, ax) == "state":  # LinuxCNC's G76 (compensation.nc_g76)
            if bd:
                raise _Refuse(body.index("/") + 1, "block delete '/' on a G76 line: not read; remove it")
            return "state", None
    if getattr(st.dialect, "name", None) == "linuxcnc" and lathe_words(ax.words) and _LCNC_G7X.search(body):
        try:
            bd, words, _ = tokenize(body)
        except _Refuse:
            words = ()  # the line's own reading names what it holds
        if words and g7x_line(words, idx, st, ax) == "state":  # LinuxCNC's G70-G72 (compensation.nc_g7x)
            if bd:
                raise _Refuse(body.index("/") + 1, "block delete '/' on a G7x cycle line: not read; remove it")
            return "state", None
    if cs.pending is None and cs.active is None and not contour_reading(st, ax):
        return _classify_words(body, idx, st, rapids, block_delete, ax)  # not a Fanuc/Haas lathe: no cycle to read
    try:
        words = tokenize(body)[1] if any(c in body for c in ("G7", "g7", "G3", "g3", "G9", "g9")) or cs.pending or \
            cs.active or st.thread else ()
    except _Refuse:
        words = ()  # the line's own reading names what it holds
    read = groove_line(words, idx, st, ax, lambda by: _diameter_mode(st, {}, by, ax)) if words else None
    if read is not None:
        return ("state", None) if read == "state" else read  # G74/G75 (compensation.nc_groove): state, or its bottom
    if words and contour_reading(st, ax) and thread_line(words, idx, st, ax) == "state":  # G92 (compensation.nc_thread)
        return "state", None
    if words and cycle_line(words, idx, st, ax) == "state":
        return "state", None
    out = _classify_words(body, idx, st, rapids, block_delete, ax)
    if cs.active is not None:
        after_line(words or tokenize(body)[1], idx, st, ax, out[1])
    return out


def _classify_words(body, idx, st: _State, rapids, block_delete, ax: AxisWords):
    dia = st.dialect
    if dia is not None and ":" in dia.program_number and _COLON_NUMBER.fullmatch(body):
        return "pass", None  # ':1234' program number (ISO code)
    if dia is not None and dia.name == "grbl" and body.lstrip().startswith("$"):
        return _grbl_system(body, st, ax), None
    native = siemens_native(body, dia is not None and dia.name == "siemens-iso")
    if native is not None:
        from .dialects import SIEMENS_NATIVE
        raise _Refuse(native[0], f"'{native[1]}': {SIEMENS_NATIVE}")
    bd, words, pct = tokenize(body)
    if pct:
        return "pass", None
    io = io_line(words, dia)
    if io is not None:
        return io, None
    if bd and dia is not None and not dia.block_delete:
        raise _Refuse(body.index("/") + 1, f"block delete '/': {dia.name} has no block-delete switch")
    if bd and block_delete == "on":
        return "skipped", None
    by, gs, ms = _checked_words(words, ax, dia)
    _machine_m_codes(st, ms, idx, ax, dia)
    _tool_change(st, by, ms, idx)
    st.t_changed = None
    if "T" in by and _lathe_t_word(by["T"], ax, dia):
        lathe_t_offset(idx, st, by["T"], ax)
    groups = _modal_groups(gs, dia)
    if getattr(dia, "g80_unrecognised", False) and (groups.get("motion", ("G80",))[0] != "G80" and any(
            c == "G80" for c, _ in gs) or any(w.letter == "G" and w.code in BARE_UNITS for w in words)):
        st.g80_line = st.g80_line or idx + 1  # LinuxCNC refuses the line: the controllers that run it take the G0-G3
    if "O" in by:
        if len(words) > 1 and any(w.letter not in ("O", "N") for w in words):
            raise _Refuse(by["O"].start + 1, "'O' word with other words (subroutines and control flow are not supported)")
        return "pass", None
    _diameter_mode(st, groups, by, ax)
    axis_words = {a: by[a] for a in ax.words if a in by}
    arc_words = {a: by[a] for a in ("I", "J", "K", "R") if a in by}
    changes = any(g in groups for g in ("motion", "plane", "units", "distance", "arc_distance", "nonmodal", "coords",
                                        "length", "cutter", "dialect mode"))
    if bd and block_delete is None and (axis_words or arc_words or changes):
        raise _Refuse(body.index("/") + 1, "block delete '/' on a line that moves or changes modal state; "
                                           "say whether the controller skips it: --block-delete on|off")
    motion_word = _apply_modal(st, groups)
    feed_word_seen(st, by, st.mode)
    _check_p_q(st, by, gs, axis_words, arc_words, ttoo_lathe(dia, ax), lathe_words(ax.words))
    if "nonmodal" in groups and groups["nonmodal"][0] == "G10":
        return _g10(idx, st, groups, by, axis_words, ax), None
    if "nonmodal" in groups and (groups["nonmodal"][0] in G92_CODES or groups["nonmodal"][0] == "G52"):
        return _g92(idx, st, groups, axis_words, ax), None
    _work_state(idx, st, groups, by, ax)
    if groups.get("length", ("",))[0] == "G43.1":
        return "state", None  # its axis words are the tool's offsets (compensation.gcode_state.dynamic_length)
    if "dialect mode" in groups:
        return _dialect_mode(idx, st, groups, by, axis_words, arc_words), None
    if "nonmodal" in groups and groups["nonmodal"][0] == "G53":
        cls = _machine_coordinates(idx, st, groups, axis_words, arc_words, ax)
        _g53_end(st, axis_words, ax)
        return cls, None
    if "nonmodal" in groups and groups["nonmodal"][0] in ("G28", "G30"):
        return _reference_return(st, groups, axis_words, arc_words, ax, rapids, idx)
    # RS274NGC / LinuxCNC: G4 uses no axis words, so a G4 line's axis words are the motion mode's (dwell, then move)
    plain = "nonmodal" not in groups or (groups["nonmodal"][0] == "G4" and getattr(dia, "dwell_with_motion", False))
    move = _mode_move(idx, st, groups, by, axis_words, arc_words, motion_word, rapids, ax, plain)
    if move is not None:
        return ("state", None) if move == "state" else ("move", move)
    if not plain and groups["nonmodal"][0] == "G4" and getattr(dia, "dwell_x", False) and set(axis_words) == {"X"} and (
            not arc_words and "motion" not in groups and by["X"].value >= 0):
        return "state", None  # Fanuc 'G04 X1.': a dwell of X seconds, nothing moves
    if not plain and axis_words:
        w = next(iter(axis_words.values()))
        raise _Refuse(w.start + 1, f"axis word '{w.letter}{w.text}' with {groups['nonmodal'][0]} (a dwell time on "
                                   "some controls, not a move; on linuxcnc a move after the dwell: --dialect)")
    if not axis_words:
        if arc_words:
            w = next(iter(arc_words.values()))
            if st.mode not in ("G2", "G3") or "R" in arc_words:
                raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' without axis words (only a centre-format G2/G3 "
                                           "full circle may omit them)")
            return "move", _move(idx, st, by, axis_words, arc_words, motion_word, rapids, ax)  # a full circle
        return ("state" if changes else "pass"), None
    return "move", _move(idx, st, by, axis_words, arc_words, motion_word, rapids, ax)


def _mode_move(idx, st: _State, groups, by, axis_words, arc_words, motion_word, rapids, ax, plain):
    """The move of a line in a dialect's spline mode (:func:`spline_move`) or spindle-synchronised mode
    (:func:`synced_move`), ``"state"`` for a probe move (:func:`probe_move`: written as programmed); None where the line is not one (``plain``: no non-modal code, or a G4 that moves)."""
    dia = st.dialect
    if dia is None:
        return None
    nurbs = _nurbs_move(idx, st, groups, by, axis_words, motion_word, ax)
    if nurbs is not None:
        return nurbs
    if st.mode in dia.splines and (axis_words or ("nonmodal" not in groups and any(a in by for a in "IJKRPQ"))):
        if "nonmodal" in groups or st.diameter:
            w = groups["nonmodal"][1] if "nonmodal" in groups else next(iter(axis_words.values()), motion_word)
            raise _Refuse(w.start + 1, "a spline line with G4 (its P would be the spline's) or in diameter mode (G7)")
        return spline_move(idx, st, by, axis_words, motion_word, ax)
    if plain and st.mode in dia.synced and axis_words:
        return synced_move(idx, st, by, axis_words, arc_words, motion_word, rapids, ax)
    if plain and st.mode in dia.probes and (axis_words or arc_words):
        probe_move(idx, st, axis_words, arc_words, motion_word, ax)
        return "state"
    return None


def _nurbs_move(idx, st: _State, groups, by, axis_words, motion_word, ax):
    """A NURBS block's lines (:func:`compensation.gcode_spline.nurbs_line`): ``"state"`` for a G5.2 line, the
    curve's move for the G5.3 line; None for any other line (refused inside a block: only G5.2 lines there)."""
    code = groups.get("motion", (None,))[0]
    if code == "G5.3":
        return nurbs_end(idx, st, by, axis_words, motion_word, ax)
    if st.mode == "G5.2" and "nonmodal" not in groups and (axis_words or any(a in by for a in "PL") or code == "G5.2"):
        nurbs_line(idx, st, by, axis_words, motion_word, ax)
        return "state"
    if st.nurbs is not None and any(a != "N" for a in by):
        w = min((w for a, w in by.items() if a != "N"), key=lambda w: w.start)
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' inside a NURBS block (between G5.2 and G5.3 only G5.2 lines)")
    return None


def _diameter_mode(st: _State, groups, by, ax: AxisWords) -> None:
    """LinuxCNC ``G7``/``G8`` (this line's X read in the new mode, as its interpreter does): in diameter mode the
    line's X word is replaced by one holding the radius (its text and span kept for the writer). On a lathe of a
    dialect whose X is a diameter or a radius by a control parameter, X is refused unless ``st.lathe_x`` says which
    (``--lathe-x`` or the machine file: :func:`compensation.turning.lathe_x_words`)."""
    if "X" in by and st.lathe_x is None and getattr(st.dialect, "lathe_x_by_parameter", False) and lathe_words(ax.words):
        w = by["X"]
        raise _Refuse(w.start + 1, f"'X{w.text}': on a {st.dialect.name} lathe X is a diameter or a radius by a machine "
                                   "parameter, not a word of the program: say which with --lathe-x diameter|radius or "
                                   "the machine file's [spindle] x_words")
    if "lathe" in groups:
        st.diameter = groups["lathe"][0] == "G7"
    if st.diameter and "X" in by:
        by["X"] = replace(by["X"], value=by["X"].value * 0.5)


def _move(idx, st: _State, by: dict, axis_words, arc_words, motion_word, rapids, ax: AxisWords) -> GMove:
    """The move of a line with axis words in the active motion mode (or a centre-format full circle, whose
    end is its start: RS274NGC, LinuxCNC and Fanuc); advances ``st.pos``."""
    first = min((axis_words or arc_words).values(), key=lambda w: w.start)
    st.spline_pq = None
    if st.mode is None and st.after_g80 and getattr(st.dialect, "g80_unrecognised", False):
        st.mode = st.before_g80  # the only reading that runs: RS274NGC controllers refuse the line
        st.g80_line = st.g80_line or idx + 1
    if st.mode is None:
        raise _Refuse(first.start + 1, f"axis word '{first.letter}{first.text}' but no motion mode (G0/G1/G2/G3) is "
                                       "active" + (G80_HINT if st.after_g80 else ""))
    if arc_words and st.mode not in ("G2", "G3"):
        w = next(iter(arc_words.values()))
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a {st.mode} line (arc words need G2/G3)")
    scale = MM_PER_INCH if st.inch else 1.0
    start = st.pos.copy()
    end = st.pos.copy()
    for j, (a, rotary) in enumerate(zip(ax.words, ax.is_rotary)):
        if a in axis_words:
            v = axis_words[a].value * (1.0 if rotary else scale)
            if st.incremental:
                if not np.isfinite(start[j]):
                    raise _Refuse(axis_words[a].start + 1, f"incremental '{a}{axis_words[a].text}' before {a} "
                                                           "is known (no absolute position yet)")
                end[j] = start[j] + v
            else:
                end[j] = v
    kind = {"G0": "rapid", "G1": "linear", "G33": "linear", "G33.1": "linear", "G32": "linear"}.get(st.mode, "arc")
    compensate = not (kind == "rapid" and rapids == "keep")
    words = dict(axis_words)
    words.update(arc_words)
    if "P" in by and kind == "arc":
        words["P"] = by["P"]
    known = np.isfinite(end)
    if compensate and not known.all():
        lacking = [a for a, k in zip(ax.words, known) if not k]
        compensate = not (kind == "rapid" or _from_start_position(st, axis_words, lacking, ax))
    if compensate and not known.all():
        raise _Refuse(first.start + 1, f"'{first.letter}{first.text}': {st.mode} before {ax.joined('and')} are all "
                                       f"known (no value yet for {', '.join(lacking)}; a feed may cut: only a G0 is "
                                       f"kept){_unknown_since(st, lacking)}")
    move = GMove(idx, kind, start, end, "inch" if st.inch else "mm", st.incremental, words, motion_word,
                 compensate, known=known, diameter=st.diameter)
    if kind == "arc":
        try:
            move.arc = _arc_geometry(st, move, arc_words, scale, ax, first)
        except _Refuse as r:
            raise _Refuse(r.col, f"'{first.letter}{first.text}': {r.msg}") from None
    st.pos = end
    st.last_given.update(dict.fromkeys(axis_words, idx))
    st.last_move = move
    return move


def _g53_end(st: _State, axis_words, ax: AxisWords) -> None:
    """A ``G53`` move's end in the program's frame: machine axis minus the frame the controller has then (work
    offset, ``G92``, tool length on Z; :class:`compensation.gcode.FrameReplay`), so that later moves start
    from it exactly. Left unknown without tables, under ``G91`` (LinuxCNC refuses G53 there, Fanuc ignores
    it), with cutter compensation on (LinuxCNC refuses) or for a lathe's X in diameter mode."""
    if st.replay is None or st.incremental or st.cutter != "G40" or not axis_words:
        return
    shift = st.replay.shift(st.events)
    pos = st.pos.copy()
    for j, a in enumerate(ax.words):
        if a in axis_words and not (a == "X" and (st.diameter or st.lathe_x == "diameter")):
            scale = MM_PER_INCH if st.inch and not ax.is_rotary[j] else 1.0
            pos[j] = axis_words[a].value * scale - shift[j]
    st.pos = pos
    if all(np.isfinite(pos[ax.words.index(a)]) for a in axis_words):
        st.system = st.system or st.replay.system  # placed in the power-on system: selecting it is no change


def _from_start_position(st: _State, axis_words, lacking, ax: AxisWords) -> bool:
    """(A ``G0`` rapid with an axis not known, whatever it moves, is written as programmed and listed the same way
    under ``--rapids compensate`` too: the machine goes where it goes without compensation, and a rapid cuts
    nothing; :func:`_move`.) On a mill (X, Y, Z), a line moving Z alone before the program ever gave the ``lacking`` X or Y (no ``G53``
    moved them either): the controller keeps them where the machine stands at cycle start, which the program does
    not say. Such a line (the first retract of many posts, ``G0 Z5``) is written as programmed, not compensated,
    and listed (:func:`compensation.nc_state.program_frames`, ``moves_before_position_known``)."""
    if set(axis_words) != {"Z"} or not set(lacking) <= {"X", "Y"} or not {"X", "Y", "Z"} <= set(ax.words):
        return False
    moved_g53 = {a for e in st.events if e[2] in ("g53", "probe") for a in e[3]}  # or a probe move
    return not any(a in st.last_given or a in moved_g53 for a in lacking)


def _unknown_since(st: _State, lacking) -> str:
    """Why an axis has no value in the program's frame, and what gives it one: a ``G53`` line that moved it after
    the program last gave it (machine coordinates are not the part's), else none given yet."""
    for idx, _col, kind, axes, _text in reversed(st.events):
        probed = kind == "probe" and ", ".join(a for a in lacking if a in axes and idx > st.last_given.get(a, -1))
        if probed:
            return f"; line {st.name(idx + 1)} probed {probed} ({_text}: it stops where the probe trips): give it " \
                   "in the program (absolute) before this move"
        moved = kind == "g53" and ", ".join(a for a in lacking if a in axes and idx > st.last_given.get(a, -1))
        if moved:
            tables = st.replay is not None and st.replay.offsets_given
            place = ("its work offset is not known (--work-offsets), or it ran under G91 or G41/G42:" if tables
                     else "give the work offsets (--work-offsets FILE) to place it in the part's frame, or")
            return f"; line {st.name(idx + 1)} moved {moved} in machine coordinates (G53): {place} give it in the " \
                   "program before this move"
    return f"; give {', '.join(lacking)} in the program (absolute) before this move"


def synced_move(idx, st: _State, by, axis_words, arc_words, motion_word, rapids, ax: AxisWords) -> GMove:
    """A ``G32``/``G33``/``G33.1`` line: one straight move to its end (F or K the lead, :func:`synced_words`), marked
    ``synced``, its lead read (:mod:`compensation.nc_thread`); after ``G33.1`` the position is its start again (the
    tap returns)."""
    first = min(axis_words.values(), key=lambda w: w.start)
    if st.mode == "G32" and arc_words:  # Fanuc/Haas lathe thread cutting: F the lead (compensation.nc_thread)
        w = next(iter(arc_words.values()))
        raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' on a G32 line (F is the lead)")
    if st.mode != "G32":
        synced_words(st.mode, by, arc_words, (motion_word or first).start + 1)
    prev = st.last_move  # the move before it (its end the thread's start); _move makes this one the last
    move = _move(idx, st, by, axis_words, {}, motion_word, rapids, ax)
    move.kind, move.synced = "linear", st.mode
    (g32_move if st.mode == "G32" else g33_move)(st, by, ax, move, prev)  # the lead, the start (nc_thread)
    if st.mode == "G33.1":
        st.pos = move.start.copy()
    return move


def _reference_return(st, groups, axis_words, arc_words, ax: AxisWords, rapids=DEFAULT_RAPIDS, idx=-1):
    """``G28``/``G30``: the machine goes to a reference position (not a program point, so
    not compensated; the line is written as it is). Bare: all axes; with axis words: only those axes,
    first at rapid through the intermediate point they give (RS274NGC, Fanuc, Haas: absolute under
    ``G90``, incremental under ``G91``; ``G28 G91 Z0`` has none), a rapid like a ``G0`` line and, as
    ``G0`` lines under ``rapids="keep"``, written unchanged; under ``"compensate"`` an intermediate point
    (a rapid this line cannot rewrite) is refused naming ``--rapids keep``. The axes it moves are unknown
    afterwards, so the next compensated move must give them absolutely."""
    code, w = groups["nonmodal"]
    if "motion" in groups and not (groups["motion"][0] in ("G0", "G1") and (
            getattr(st.dialect, "h_offset_alone", False) or getattr(st.dialect, "g80_unrecognised", False))):
        raise _Refuse(w.start + 1, f"'{code}' with a motion code on the same line" + (
            "; Fanuc, Haas, Siemens ISO run 'G0 G28' (G28 takes the axis words, G0 stays the motion mode): name the "
            "controller with --dialect" if groups["motion"][0] in ("G0", "G1") else ""))
    if "motion" in groups and getattr(st.dialect, "g80_unrecognised", False):
        st.g80_line = st.g80_line or idx + 1  # LinuxCNC refuses the line: the controllers that run it read it so
    if arc_words:
        a = next(iter(arc_words.values()))
        raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with {code}")
    for a in axis_words.values():
        if rapids != "keep" and (not st.incremental or a.value != 0.0):
            raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with {code}: its intermediate point is a rapid this "
                                       "line cannot carry compensated; --rapids keep writes rapids (and this line) "
                                       "as programmed")
    st.pos = st.pos.copy()  # the previous move's end is this array: it must keep its values
    for j, a in enumerate(ax.words):
        if not axis_words or a in axis_words:
            st.pos[j] = np.nan
    return "state", None


def _arc_geometry(st, move, arc_words, scale, ax: AxisWords, first) -> dict:
    """Centre, radii and sweep of a G2/G3 arc in the active plane's (u, v) axis columns
    ``ju``, ``jv`` (:func:`plane_arc`)."""
    u_ax, v_ax, u_c, v_c = PLANES[st.plane]
    missing = [a for a in (u_ax, v_ax) if a not in ax.words]
    if missing:
        where = (f"its arc planes: {', '.join(f'{p} {PLANE_NAMES[p]}' for p in ax.planes)}" if ax.planes
                 else "it has no arc plane")
        raise _Refuse(first.start + 1, f"{st.mode} arc in the {st.plane} plane: the machine {ax.machine!r} has no "
                                       f"{missing[0]} axis ({where})")
    for w in arc_words:
        if w in CENTRE_AXIS and w not in (u_c, v_c):
            raise _Refuse(arc_words[w].start + 1, f"'{w}' on a {st.plane} arc (its centre words are {u_c} {v_c})")
    if not move.start_known:
        raise _Refuse(first.start + 1, f"{st.mode} arc before the start position is known")
    ju, jv = ax.words.index(u_ax), ax.words.index(v_ax)
    u0, v0, u1, v1 = move.start[ju], move.start[jv], move.end[ju], move.end[jv]
    tol = getattr(st.dialect, "arc_radius_tol", None)
    tols = ({"abs_tol_mm": ARC_RADIUS_TOL_INCH_MM} if st.inch else {}) if tol is None else \
        {"abs_tol_mm": tol[1] if st.inch else tol[0], "rel_tol": tol[2], "cap": tol[3]}
    tols["rule"] = ARC_RADIUS_RULES.get(getattr(st.dialect, "name", None), "")
    return {"ju": ju, "jv": jv, **plane_arc(u0, v0, u1, v1, st.mode, arc_words, (u_c, v_c), st.arc_abs, scale,
                                             first, pair=f"{u_c}/{v_c}", both=f"{u_c} and {v_c}", **tols)}


ARC_RADIUS_RULES = {"fanuc": "; Fanuc: parameter 3410 sets the tolerance; manuals differ on the path within it"}
"""What decides, on a dialect's controller, whether an arc whose radii differ more than the reader allows runs (named in
the refusal). Fanuc: parameter 3410 (16/18 series; 15i: 2410) is the machine's limit, P/S alarm 020 beyond it. The
path within it is not one rule: the 16/18/160/180-C lathe operator's manual says the tool "moves in a straight line
along one of the axes after reaching the end point" (which axis is not given), the 15i/150i-MA manual (B-63324EN)
that the radius changes linearly with the centre angle (a spiral, with parameter 2410). So the reader keeps its own
bound (:data:`compensation.gcode_words.ARC_RADIUS_TOL_MM`, a rounding of the program's words) and refuses more
rather than take the machine's tolerance: beyond a rounding, which path the controller cuts is not known."""


def plane_arc(u0, v0, u1, v1, mode, arc_words, centre_words, arc_abs, scale, first, pair, both,
              abs_tol_mm: float = ARC_RADIUS_TOL_MM, rel_tol: float | None = None, rule: str = "",
              cap: float | None = None) -> dict:
    """Centre, radii and sweep of a G2/G3 (``mode``) arc from (u0, v0) to (u1, v1) mm in its plane's
    (u, v) coordinates; ``centre_words`` the words giving the centre's u and v offsets (G18: K, I; G17:
    I, J), or ``R``; ``pair`` / ``both`` how the refusals name them; ``rule`` the controller's rule on radii that
    differ (:data:`ARC_RADIUS_RULES`), named in that refusal. Radii that differ by d are refused when d >
    ``abs_tol_mm``; with ``rel_tol`` and ``cap`` (LinuxCNC's rule, :data:`compensation.dialects.LINUXCNC_ARC_TOL`)
    only when d > ``cap`` · ``abs_tol_mm`` or d exceeds both ``abs_tol_mm`` and ``rel_tol`` · the larger radius.
    Returns ``uc vc r0 r1 theta0 sweep``."""
    u_c, v_c = centre_words
    ccw = mode == "G3"
    if "R" in arc_words:
        if u_c in arc_words or v_c in arc_words:
            raise _Refuse(arc_words["R"].start + 1, f"both R and {pair} on an arc")
        r = arc_words["R"].value * scale
        d = math.hypot(u1 - u0, v1 - v0)
        if d < 1e-9 or abs(r) < 1e-9:
            raise _Refuse(arc_words["R"].start + 1, "R-form arc with equal start and end (or zero R): undefined")
        if d > 2 * abs(r) + ARC_RADIUS_TOL_MM:
            raise _Refuse(arc_words["R"].start + 1, f"R {abs(r):.6g} mm is smaller than half the chord {d / 2:.6g} mm")
        h = math.sqrt(max(r * r - d * d / 4, 0.0))
        sgn = (1.0 if ccw else -1.0) * (1.0 if r > 0 else -1.0)
        mu, mv = (u0 + u1) / 2, (v0 + v1) / 2
        uc, vc = mu + sgn * h * (-(v1 - v0) / d), mv + sgn * h * ((u1 - u0) / d)
    else:
        if u_c not in arc_words and v_c not in arc_words:
            raise _Refuse(first.start + 1, f"{mode} without {pair} or R")
        cu = arc_words[u_c].value * scale if u_c in arc_words else (None if arc_abs else 0.0)
        cv = arc_words[v_c].value * scale if v_c in arc_words else (None if arc_abs else 0.0)
        if arc_abs:
            if cu is None or cv is None:
                raise _Refuse(first.start + 1, f"absolute arc centre (G90.1) needs both {both}")
            uc, vc = cu, cv
        else:
            uc, vc = u0 + cu, v0 + cv
    r0 = math.hypot(u0 - uc, v0 - vc)
    r1 = math.hypot(u1 - uc, v1 - vc)
    if r0 < 1e-9:
        raise _Refuse(first.start + 1, "arc of zero radius")
    d = abs(r1 - r0)
    if d > abs_tol_mm and (rel_tol is None or d > cap * abs_tol_mm or d > rel_tol * max(r0, r1)):
        limit = f"{abs_tol_mm * 1e3:.4g} μm" if rel_tol is None else (
            f"{cap * abs_tol_mm:.4g} mm, or both {abs_tol_mm * 1e3:.4g} μm and {rel_tol:.2%} of the radius")
        raise _Refuse(first.start + 1, f"arc start and end radii differ by {abs(r1 - r0) * 1e3:.3f} μm "
                                       f"(more than {limit}{rule}): correct the end point or the centre")
    t0 = math.atan2(v0 - vc, u0 - uc)
    t1 = math.atan2(v1 - vc, u1 - uc)
    full = math.hypot(u1 - u0, v1 - v0) < 1e-9
    if ccw:
        sweep = 2 * math.pi if full else (t1 - t0) % (2 * math.pi)
    else:
        sweep = -2 * math.pi if full else -((t0 - t1) % (2 * math.pi))
    return {"uc": uc, "vc": vc, "r0": r0, "r1": r1, "theta0": t0, "sweep": sweep}


# ---------------------------------------------------------------------------- geometry

def move_points(move: GMove, t) -> np.ndarray:
    """Nominal axes (mm, deg; the reader's axis order) at parameters ``t`` in [0, 1] along a
    move, (m,) -> (m, k).

    A linear move is linear in the axes (what the controller interpolates); an arc turns
    uniformly in angle in its plane's columns with the radius linear in the parameter, the
    other axes linear (a helix).
    """
    t = np.asarray(t, dtype=float)
    if move.arc is None:
        if t.size and np.all(t == 1.0):  # the end alone (the start may not be known)
            return np.repeat(move.end[None, :], t.size, axis=0)
        return move.start[None, :] + t[:, None] * (move.end - move.start)[None, :]
    g = move.arc
    out = move.start[None, :] + t[:, None] * (move.end - move.start)[None, :]
    if "ctrl" in g:  # a spline (compensation.gcode_spline): its X Y on the curve, other axes unchanged
        out[:, [g["ju"], g["jv"]]] = spline_points(g, t)
        return out
    th = g["theta0"] + t * g["sweep"]
    r = g["r0"] + t * (g["r1"] - g["r0"])
    out[:, g["ju"]] = g["uc"] + r * np.cos(th)
    out[:, g["jv"]] = g["vc"] + r * np.sin(th)
    return out


def arc_segments(move: GMove, tol_mm: float) -> int:
    """Chords needed so the chord sagitta of an arc (the chords' deviation from a spline,
    :func:`compensation.gcode_spline.spline_segments`) stays within ``tol_mm`` (≥ 1)."""
    g = move.arc
    if "ctrl" in g:
        return spline_segments(g, tol_mm)
    r = max(g["r0"], g["r1"])
    if tol_mm >= r:
        return max(1, int(math.ceil(abs(g["sweep"]) / math.pi)))
    step = 2.0 * math.acos(1.0 - tol_mm / r)
    return max(1, int(math.ceil(abs(g["sweep"]) / step - 1e-12)))


# ---------------------------------------------------------------------------- writing


_AXIS_WORD = re.compile(r"(?<![A-Za-z_<#])([XYZABCUVWxyzabcuvw])\s*(?=[-+.\d\[#])")


class ProgramState:
    """The controller's position and modes along the lines the expander writes (:mod:`compensation.nc_expand`,
    ``#<_x>`` …: :data:`compensation.nc_flow.TRACKED_NAMES`), read by this module's line classifier (:func:`classify_line`; the axis words the program's text uses,
    the program's dialect). A line it cannot read (a canned cycle, a probing move, a move before every axis
    the program uses is known …) leaves the state unknown from there on."""

    def __init__(self, dialect_name, text: str):
        from .dialects import DIALECTS
        code = re.sub(r"\([^)]*\)|;[^\n]*", "", text)
        used = {c.upper() for c in _AXIS_WORD.findall(code)} | ({"X", "Y"} if re.search(r"[@^]", code) else set())
        used = used or {"X"}
        words = tuple(a for a in "XYZABCUVW" if a in used)
        self.ax = AxisWords("program", words, tuple(a for a in words if a in "ABC"))
        self.st = _State(len(self.ax.words))
        self.st.dialect = DIALECTS.get(dialect_name)
        self.unknown_after = None  # the 0-based line of the lines run the state is unknown after (named: m.named)

    def line(self, i: int, text: str) -> None:
        if self.unknown_after is None:
            try:
                classify_line(text.rstrip("\r\n"), self.st, "keep", "off", self.ax)
            except Exception:  # noqa: BLE001 - any line the classifier refuses: the state is unknown from here
                self.unknown_after = i

    def value(self, m, name: str, pc, col) -> float:
        if self.unknown_after is not None:
            raise m._err(pc, col, f"#<{name}>: the controller's state is not known after line "
                                  f"{m.named(self.unknown_after)} (a line the reader does not follow)")
        st, axis = self.st, TRACKED_NAMES[name]
        if axis is None:
            return float({"_metric": not st.inch, "_imperial": st.inch, "_absolute": not st.incremental,
                          "_incremental": st.incremental, "_lathe_diameter_mode": st.diameter}[name])
        v = st.pos[self.ax.words.index(axis)]
        if not math.isfinite(v) or (axis == "X" and st.diameter):
            raise m._err(pc, col, f"#<{name}>: the {axis} position is not known here" + (
                " (diameter mode)" if math.isfinite(v) else " (no absolute move along it yet)"))
        return float(v / 25.4 if st.inch and axis not in self.ax.rotary else v)
