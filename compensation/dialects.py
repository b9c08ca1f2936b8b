"""Controller dialects of G-code, as data: what each controller's manual says about the words that
differ between them (one table, :data:`DIALECTS`), and the dialect of a program recognised from its
content (:func:`detect_dialect`; never from the file's name).

What differs (and what the reader does with it, :mod:`compensation.gcode`):

* **program numbers**: ``O1234`` on every controller; ``:1234`` (the ISO-code program-number address)
  on Fanuc and Siemens ISO mode;
* **harmless M codes**: the codes that move no axis and call no program (stops, spindle, coolant,
  tool change, overrides, clamps, chip conveyors); the common ones on every dialect
  (:data:`COMMON_M`), the others only on their controller (Haas ``M31`` chip auger …). Program
  calls (``M98``/``M99``/``M97``), loops (Mach3 ``M47``) and user M codes stay refused;
* **look-ahead**: Fanuc ``G05.1 Q1`` (AI contour control) / ``Q0`` and Haas ``G187`` set a
  smoothing mode, not a path: read as state; on LinuxCNC ``G5.1`` is a quadratic spline and ``G5`` a cubic
  one (:data:`SPLINES`, read exactly under ``--dialect linuxcnc``, refused without a dialect);
* **mirror off, look-ahead** ``G50.1`` (its axis words name axes, nothing moves), Fanuc ``G08 P1/P0``, ``G05 P10000/P0``, Haas ``G103 P``: state (:data:`MIRROR_OFF`);
* **scaling off** ``G50`` alone (Fanuc, Haas, Siemens ISO, Mach3, Tormach PathPilot: :data:`SCALING_OFF`): state, as
  ``G51`` scaling is refused; ``G50`` with axis words (a lathe's coordinate setting) is refused;
* **G80 with a motion code on one line** (``G80 G0 X..``, the safe-start line of Mastercam, FeatureCAM and Mach3
  posts): Fanuc, Haas, Siemens ISO and Mach3 cancel the cycle and take the motion code; LinuxCNC refuses two
  group-1 codes on one line (so does the reader under ``--dialect linuxcnc`` or with no dialect at all); under
  ``--dialect auto`` with no dialect word found (:data:`UNRECOGNISED`) the line is read the one way the controllers
  that run it read it, and the summary names the line (:data:`G09_NOTE`);
* **G80 and the motion mode**: on Fanuc, Haas and Siemens ISO the cycles and ``G80`` are group 09, so the
  G0-G3 mode in force before a cycle is in force after its ``G80`` (CAM posts write ``G80`` then a bare
  ``Z`` retract); on LinuxCNC, Mach3 and grbl ``G80`` ends the motion mode (RS274NGC group 1) and a bare
  axis word after it is an error. Recognised from no word (Fusion 360's Fanuc and Haas posts write none),
  such a line is read the group-09 way (:data:`UNRECOGNISED`: the only reading under which it runs) and
  the summary says so;
* **probing** ``G38.2``-``G38.5`` (:data:`PROBES`): probe moves on LinuxCNC and grbl, and without a dialect (no
  controller read here gives them another meaning); Fanuc, Haas, Siemens ISO and Mach3 probe with ``G31`` and
  refuse them;
* **block delete** ``/``: every dialect but grbl (which has no block-delete switch) skips the line
  when the switch is on (``--block-delete``).
* **grbl** ``$`` **system commands** (a line that starts with ``$``; grbl v1.1 "Grbl $ commands"; such a line names
  the dialect): the views ``$$ $# $G $I $N`` and ``$X`` (unlock) pass; ``$H`` (homing) passes and leaves the
  position unknown until the next absolute word; jogs ``$J=``, check mode ``$C``, settings ``$n=`` and startup
  blocks ``$Nn=`` are refused (:func:`compensation.gcode_classify._grbl_system`).

Sources: LinuxCNC G- and M-code reference (linuxcnc.org/docs, "M-Codes": M0-M9, M19, M48-M53, M60,
M61-M68, M70-M73 state, M100-M199 user); Fanuc Series 0i/30i operator's manuals (program number
``O``/``:``, ``G05.1 Q1`` AI contour control); Haas mill operator's manual (M-code chapter: M10/M11
4th-axis brake, M12/M13 5th-axis brake, M16 tool change, M19 orient, M31/M33 chip auger, M41/M42
gear, M83/M84 air jet, M88/M89 through-spindle coolant, M130 display media (Fusion 360's Haas post writes
``M130 (tool1.png)``); G187 smoothness); Siemens Sinumerik 840D
ISO dialect manual (Fanuc-compatible ISO mode, G291); Mach3 Mill G/M code list (M47 repeats the
program); grbl v1.1 command reference (M0 M1 M2 M30 M3-M5 M7-M9 M56; no block delete; grbl writes no
word of its own, so it is named, never recognised).

* **outputs and inputs** (LinuxCNC ``M62``–``M68``, :data:`IO_CODES`): set a digital or analog output
  or wait on an input; they move nothing and are passed through on a line of their own, their
  ``P E L Q`` words checked as LinuxCNC's interpreter checks them (:func:`compensation.gcode_state.io_line`);
* **Haas additional work offsets**: ``G154 P1``–``P99`` (and ``G110``–``G129``, the same offsets as
  ``G154 P1``–``P20``) select a work system like ``G54.1 Pn`` (:data:`HAAS_SYSTEMS`);
* **Siemens native mode** (``G290``; ``CALL``, ``L`` subprogram calls, ``R`` parameters): a Sinumerik
  in ISO mode reads ``M98 P`` calls; a native-mode line in a program is refused naming the mode
  (:data:`SIEMENS_NATIVE`).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace

DIALECT_NAMES = ("fanuc", "haas", "linuxcnc", "siemens-iso", "mach3", "grbl", "heidenhain-iso")
COMMON_M = frozenset({0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30})
"""Program stop/end, spindle, tool change, coolant: the same meaning on every dialect read here."""
RS274 = "rs274"
"""No dialect named or recognised: the words common to all (the reader's allow-lists)."""


@dataclass(frozen=True)
class Dialect:
    """One controller's rules: ``m_codes`` harmless M codes {code: meaning}; ``program_number``
    letters (``"O"``, ``":"``); ``modes`` G codes that set a controller mode and move nothing
    (look-ahead / smoothing, the ISO-dialect switch) {code: meaning}; ``splines`` motion codes of the
    dialect's splines {code: meaning} (:mod:`compensation.gcode_spline`);
    ``g80_with_motion`` G80 and a motion code on one line; ``block_delete`` the ``/`` switch exists."""

    name: str
    m_codes: dict
    program_number: tuple = ("O",)
    modes: dict = field(default_factory=dict)
    g80_with_motion: bool = False
    block_delete: bool = True
    work_systems: dict = field(default_factory=dict)
    """Work-system codes of the dialect beyond ``G54``–``G59.3``/``G54.1``: {code: fixed P or None (P
    on the line)}."""
    splines: dict = field(default_factory=dict)
    io_codes: dict = field(default_factory=dict)
    """Output / input M codes passed through on a line of their own {code: meaning}."""
    g80_keeps_motion: bool = False
    """The canned cycles and ``G80`` are a modal group of their own (Fanuc, Haas, Siemens ISO: group 09): the
    group-01 motion mode (G0-G3) in force before a cycle is in force again after ``G80``, and a ``G80``
    outside a cycle leaves it alone; otherwise (LinuxCNC, Mach3, grbl: RS274NGC group 1) ``G80`` ends the
    motion mode and axis words need a new G0/G1 (:mod:`compensation.nc_cycles`)."""
    g80_unrecognised: bool = False
    """No dialect named or recognised (``--dialect auto`` found no word of one): a bare axis word after ``G80``
    where a G0-G3 mode was in force before it is read as the group-09 controllers read it (the G0-G3 stays), the
    line recorded; the controllers whose ``G80`` ends the motion mode (LinuxCNC, Mach3, grbl: RS274NGC group 1)
    refuse such a line, so this is the only reading under which the program runs at all."""
    h_offset_alone: bool = False
    """An ``H`` word without ``G43`` changes the length offset where ``G43`` is in force and is held otherwise,
    and ``H0`` (``H00``) is a zero length (Fanuc 0i, Haas, Siemens ISO: "tool length compensation": the offset
    number may be changed in G43 mode; H00's value is always 0). Otherwise ``H`` only with ``G43``."""
    synced: dict = field(default_factory=dict)
    """Spindle-synchronised motion codes {code: meaning} (LinuxCNC ``G33``, ``G33.1``: :data:`SYNCED`)."""
    probes: dict = field(default_factory=dict)
    """Probe move codes {code: meaning} (RS274NGC ``G38.2``; LinuxCNC and grbl ``G38.2``-``G38.5``: :data:`PROBES`)."""
    lathe_modes: dict = field(default_factory=dict)
    """Lathe X modes of the program {code: meaning} (LinuxCNC ``G7`` diameter / ``G8`` radius, :data:`LATHE_MODES`)."""
    lathe_x_by_parameter: bool = False
    """On a lathe, whether X is a diameter or a radius is a machine parameter, not a word of the program (Fanuc
    diameter programming, parameter DIA; Haas, Siemens ISO turning likewise): a lathe program's X is refused unless
    ``--lathe-x diameter|radius`` says which (:mod:`compensation.turning`)."""
    lathe_t_offset: bool = False
    """On a lathe a four-digit ``T`` word is ``TttOO``: tool ``tt`` and its offset register ``OO``, applied
    from that line (``OO = 00`` cancels the offset; Fanuc, Haas turning: :mod:`compensation.nc_state`)."""
    dynamic_length: bool = False
    """``G43.1 axes`` is a tool length offset the program gives (LinuxCNC, "G43.1 Dynamic Tool Length Offset": it
    replaces the current offset along the axes given; :func:`compensation.gcode_state.dynamic_length`); elsewhere
    G43.1 is refused (Fanuc's G43.1 is length compensation along the tool axis)."""
    dynamic_cutter: bool = False
    """``G41.1``/``G42.1 D<diameter> [L<orientation>]`` is cutter radius compensation with the diameter on the line
    (LinuxCNC, "G41.1, G42.1 Dynamic Cutter Compensation": radius D/2, no tool table;
    :func:`compensation.gcode_state.dynamic_cutter`); elsewhere refused (Fanuc's G41.1/G42.1 is normal direction
    control, a rotary axis turned to the path)."""
    dwell_x: bool = False
    """``G04 X`` is a dwell time in seconds and the line moves nothing (Fanuc 0i-MF "Dwell": ``G04 X_`` or ``G04 P_``;
    Siemens ISO mode as Fanuc); elsewhere an X on a ``G4`` line is refused (LinuxCNC: a move after the dwell)."""
    dwell_with_motion: bool = False
    """Axis words on a ``G4`` line belong to the motion mode (RS274NGC, LinuxCNC: G4 uses no axis words; the line
    dwells, then moves); elsewhere ``G04 X`` is a dwell time (Fanuc, Haas) and such a line is refused."""
    g92_offsets: bool = False
    """``G92``/``G92.1``/``G92.2``/``G92.3`` are coordinate offsets (LinuxCNC; grbl: G92, G92.1) read exactly
    (:data:`compensation.gcode_words.G92_CODES`); elsewhere ``G92`` is refused (a Fanuc lathe's threading cycle in
    G-code system A, a coordinate setting or a spindle clamp on others)."""
    arc_radius_tol: tuple | None = None
    """``(mm under G21, mm under G20, relative)``: a centre-format arc whose start and end radii differ by
    more than the absolute tolerance of its units or by more than the relative one is an error; None: the
    reader's own 2 μm under G21 (:data:`compensation.gcode.ARC_RADIUS_TOL_MM`), 7.18 μm under G20
    (:data:`compensation.gcode.ARC_RADIUS_TOL_INCH_MM`)."""


LOOKAHEAD = "look-ahead / AI contour control (Q1 on, Q0 off; Q2 smooth interpolation refused)"
SCALING_OFF = ("scaling off (G51 scaling is refused, so nothing is scaled; on a lathe G50 S clamps the spindle speed; "
               "G50 with axis words, a lathe's coordinate setting, is refused)")
MIRROR_OFF = "mirror image off (its axis words name the axes, nothing moves; G51.1 mirroring is refused)"
PREVIEW = "advanced preview control (look-ahead; P1 on, P0 off)"
HPCC = "high-precision contour control (look-ahead; P10000 on, P0 off; other P, high-speed cycle machining, refused)"
LOOKAHEAD_BLOCKS = "limit look-ahead blocks (P0-P15)"
"""Mode codes that move nothing (Fanuc 0i/16i/30i manuals: ``G50.1`` programmable mirror image cancel, ``G08 P1/P0``
advanced preview control, ``G05 P10000/P0`` high-precision contour control; Haas mill manual: ``G50.1``, ``G103 P``
block look-ahead limit; Siemens ISO dialect manual: ``G50.1``)."""
"""``G50`` alone: Fanuc 0i-M, Haas mill, Siemens ISO mode and Mach3 "scaling cancel", Tormach PathPilot (the LinuxCNC
of Tormach mills; Fusion 360's Tormach post writes ``G50`` in its safe-start line) "cancel scaling"; Fanuc and Haas
lathes "spindle speed clamp" with ``S`` (moves nothing either way)."""
_COMMON = {0: "program stop", 1: "optional stop", 2: "program end", 3: "spindle cw", 4: "spindle ccw",
           5: "spindle stop", 6: "tool change", 7: "mist coolant", 8: "flood coolant", 9: "coolant off",
           30: "program end and rewind"}
IO_CODES = {62: "digital output on, with the next move", 63: "digital output off, with the next move",
            64: "digital output on, now", 65: "digital output off, now", 66: "wait on an input",
            67: "analog output, with the next move", 68: "analog output, now"}
"""LinuxCNC's output and input M codes (G-code reference, "M62-M65", "M66", "M67", "M68")."""
HAAS_SYSTEMS = {"G154": None, **{f"G{109 + n}": n for n in range(1, 21)}}
"""Haas mill manual, "G154 Select Work Coordinates P1-P99": G110-G129 are the same offsets as G154 P1-P20."""
HAAS_EXTENDED_MAX = 99
SIEMENS_NATIVE = ("Siemens native mode (G290: CALL/PCALL/MCALL and L subprogram calls, R parameters) is not the ISO "
                  "dialect: the siemens-iso dialect reads ISO-mode (G291) programs, whose calls are M98 P; post the "
                  "program in ISO mode")
LINUXCNC_ARC_TOL = (2 * 0.01 * 2 ** 0.5, 2 * 0.001 * 2 ** 0.5 * 25.4, 0.001, 100.0)
"""LinuxCNC's rule on a centre-format arc whose start and end radii differ by d: ``(tol mm, tol under G20 in mm,
rel, cap factor)``, its defaults (``interp_internal.hh`` CENTER_ARC_RADIUS_TOLERANCE_MM / _INCH = 2·0.01·√2 mm /
2·0.001·√2 inch, the INI's [RS274NGC] CENTER_ARC_RADIUS_TOLERANCE_* where set; SPIRAL_RELATIVE_TOLERANCE 0.001).
LinuxCNC 2.9 (``interp_arc.cc`` arc_data_ijk and arc_data_comp_ijk; the G-code reference, "Center Format Arcs",
"It is an error if") refuses only when d > cap · tol, or when d > rel · the larger radius *and* d > tol: every
arc within tol runs (28.3 μm; 71.8 μm under G20), whatever its radius. It is run as a spiral whose radius changes
linearly with the angle (posemath's circle: radius + spiral · angle / total angle), as the reader reads it."""
SPLINES = {"G5": "a cubic spline (G5 X Y I J P Q)", "G5.1": "a quadratic spline (G5.1 X Y I J)",
           "G5.2": "a NURBS block (G5.2 X Y P [L] lines, then G5.3)", "G5.3": "the end of a NURBS block"}
"""LinuxCNC G-code reference, "G5 Cubic spline", "G5.1 Quadratic spline": motion codes, read exactly
(:mod:`compensation.gcode_spline`)."""
LATHE_MODES = {"G7": "lathe diameter mode: X words (positions, G92/G10 values) are diameters, read halved",
               "G8": "lathe radius mode (the power-on default)"}
"""LinuxCNC G-code reference "G7 Lathe Diameter Mode", "G8 Lathe Radius Mode"; its interpreter halves every X
number of a block read in diameter mode (arc centre offsets I are radii in both)."""
SYNCED = {"G33": "spindle-synchronised motion (G33 X Y Z K: a straight line, K per spindle revolution)",
          "G33.1": "rigid tapping (G33.1 X Y Z K [I]: a synchronised line to the point and back to the start)"}
"""LinuxCNC G-code reference, "G33 Spindle Synchronized Motion", "G33.1 Rigid Tapping": motion codes read as one
straight line each, its end compensated, never split (:mod:`compensation.gcode_state`)."""
LATHE_SYNCED = {"G32": "thread cutting (G32 X Z F: a straight line synchronised with the spindle, F the lead)"}
"""Fanuc 0i-TF / Haas lathe ``G32``: read on a lathe only, split and written with a lead per piece
(:mod:`compensation.nc_thread`)."""
PROBES = {"G38.2": "probe towards the part, stop on contact (an error if none)",
          "G38.3": "probe towards the part, stop on contact", "G38.4": "probe away from the part, stop on loss of "
          "contact (an error if none)", "G38.5": "probe away from the part, stop on loss of contact"}
"""RS274NGC v3 "Straight Probe" (G38.2), LinuxCNC G-code reference "G38.x Straight Probe", grbl v1.1 (G38.2-G38.5):
a motion code (group 1); the machine moves in a straight line at the feed towards the programmed point and stops
where the probe input changes (or at the point): its position along the axes of the line is not known afterwards
(LinuxCNC's interpreter: "after probing is performed, the location of the probe cannot be predicted"). No other
controller read here gives G38.2-G38.5 another meaning (Fanuc's G38 is a cutter-compensation vector hold, no
decimal), so the reader without a dialect reads them too; Fanuc, Haas, Siemens ISO and Mach3 probe with G31
(refused). The line is written as programmed (a measurement, not a cut;
:func:`compensation.gcode_state.probe_move`); a read of its result (``#5061``-``#5070``) is refused by name."""
DIALECTS = {
    "linuxcnc": Dialect("linuxcnc", {**_COMMON, 19: "orient spindle", 48: "overrides on", 49: "overrides off",
                                     50: "feed override control", 51: "spindle override control",
                                     52: "adaptive feed", 53: "feed stop control", 60: "pallet change pause"},
                        io_codes=IO_CODES, arc_radius_tol=LINUXCNC_ARC_TOL, modes={"G50": SCALING_OFF},
                        splines=SPLINES, g92_offsets=True, synced=SYNCED, dwell_with_motion=True,
                        lathe_modes=LATHE_MODES, probes=PROBES, dynamic_length=True, dynamic_cutter=True),
    "fanuc": Dialect("fanuc", {**_COMMON, 19: "orient spindle", 29: "rigid tapping mode for the next G84 (moves nothing)",
                               48: "overrides on", 49: "overrides off"},
                     program_number=("O", ":"), modes={"G5.1": LOOKAHEAD, "G50": SCALING_OFF, "G50.1": MIRROR_OFF,
                                                         "G8": PREVIEW, "G5": HPCC}, g80_with_motion=True, dwell_x=True,
                     g80_keeps_motion=True, h_offset_alone=True, lathe_x_by_parameter=True, lathe_t_offset=True,
                     synced=LATHE_SYNCED),
    "haas": Dialect("haas", {**_COMMON, 10: "4th-axis brake on", 11: "4th-axis brake off", 12: "5th-axis brake on",
                             13: "5th-axis brake off", 16: "tool change", 19: "orient spindle",
                             31: "chip auger forward", 33: "chip auger stop", 34: "coolant spigot +",
                             35: "coolant spigot -", 41: "low gear", 42: "high gear", 83: "air jet on",
                             84: "air jet off", 88: "through-spindle coolant on", 89: "through-spindle coolant off",
                             130: "display media (an image or video named in the comment)"},
                    modes={"G5.1": LOOKAHEAD, "G187": "smoothness / accuracy (P1-P3, E corner rounding)", "G50": SCALING_OFF,
                           "G50.1": MIRROR_OFF, "G103": LOOKAHEAD_BLOCKS}, g80_with_motion=True,
                    g80_keeps_motion=True, h_offset_alone=True, work_systems=HAAS_SYSTEMS, lathe_x_by_parameter=True,
                    lathe_t_offset=True, synced=LATHE_SYNCED),
    "siemens-iso": Dialect("siemens-iso", {**_COMMON, 19: "orient spindle", 41: "gear 1", 42: "gear 2"},
                           program_number=("O", ":"), modes={"G5.1": LOOKAHEAD, "G291": "ISO dialect mode", "G50": SCALING_OFF,
                                  "G50.1": MIRROR_OFF},
                           g80_with_motion=True, g80_keeps_motion=True, h_offset_alone=True, dwell_x=True,
                           lathe_x_by_parameter=True),
    "mach3": Dialect("mach3", {**_COMMON, 48: "overrides on", 49: "overrides off"}, g80_with_motion=True,
                     modes={"G50": SCALING_OFF}),
    "grbl": Dialect("grbl", {**_COMMON, 56: "parking motion override"}, block_delete=False, g92_offsets=True,
                    probes=PROBES),
    # Heidenhain TNC DIN/ISO programs: '%NAME G71 *' framing and the '*' block end are read by the
    # tool-centre-point pre-pass (compensation.tcp), as are M128/M129 (TCPM) and the 'T n' tool call
    "heidenhain-iso": Dialect("heidenhain-iso", dict(_COMMON)),
}
GENERIC = Dialect(RS274, {**_COMMON, 48: "overrides on", 49: "overrides off", 50: "feed override control",
                          51: "spindle override control", 52: "adaptive feed", 53: "feed stop control",
                          60: "pallet change pause"}, probes=PROBES)
"""The reader without a dialect (what every controller read here agrees on)."""
UNRECOGNISED = replace(GENERIC, g80_unrecognised=True)
"""The reader under ``--dialect auto`` where the content names no dialect: :data:`GENERIC`, and a bare axis
word after ``G80`` read in the G0-G3 of before it (:attr:`Dialect.g80_unrecognised`)."""
G09_NOTE = ("read as the controllers that run it read it (G80, G28 or G30 with a G0-G3 on one line; G80 keeps the G0-G3 "
            "of before the cycle; a bare G70/G71 is inch/mm; first at line {line}); --dialect names the controller")
"""What the summary and the written program's header say where :data:`UNRECOGNISED` read such a line."""

MARKERS = {  # content that only one dialect writes: (pattern, what it is)
    "linuxcnc": ((r"(?im)^\s*/?\s*(?:n\d+\s*)?o\s*<", "o<name> subroutine"), (r"#<", "#<name> parameter")),
    "fanuc": ((r"(?im)^\s*:\s*\d", "':' program number"), (r"(?i)G0?5\.1\s*Q", "G05.1 Q look-ahead"),
              (r"(?im)^\s*(?:n\d+\s*)?G0?8\s*P[01]\s*(?:$|[(;])", "G08 P1 preview control"),
              (r"(?i)\bM0*29\s*S\d", "M29 S rigid tapping"),
              (r"(?im)^\s*(?:n\d+\s*)?G0?5\s*P(?:10000|0)\s*(?:$|[(;])", "G05 P10000 high-precision contour control")),
    "haas": ((r"(?i)\bG187\b", "G187 smoothness"), (r"(?i)\bG154\s*P", "G154 P work offset"),
             (r"(?i)\bM31\b", "M31 chip auger"), (r"(?i)\bM0*97\s*P", "M97 local subprogram call")),
    "siemens-iso": ((r"(?i)\bG291\b", "G291 ISO mode"), (r"(?im)^\s*(?:n\d+\s*)?TRAORI\b", "TRAORI transformation")),
    "heidenhain-iso": ((r"(?im)^\s*%\s*\w+\s+G7[01]\s*\*", "'%NAME G71 *' program framing"),),
    "grbl": ((r"(?im)^[ \t]*\$(?:[$#GINXHCJ]|\d|RST|SLP)", "'$' system command"),),
}
DETECT_BYTES = 1 << 20
"""Detection reads the first MiB (a program declares its dialect near the top, and a marker further on
is still refused by the reader with the option to name)."""


def dialect(name: str | None) -> Dialect:
    """The :class:`Dialect` called ``name``; None or :data:`RS274`: :data:`GENERIC`."""
    if name is None or name == RS274:
        return GENERIC
    if name not in DIALECTS:
        raise ValueError(f"Expected a dialect from {list(DIALECT_NAMES)}, got {name!r}")
    return DIALECTS[name]


def detect_dialect(text: str) -> tuple:
    """``(name, evidence)`` from a program's content: the dialect whose markers (:data:`MARKERS`) it
    holds — haas and siemens-iso win over fanuc where both match (Fanuc-compatible, adding their own); no
    marker: ``(RS274, "")``; markers of two other dialects: ``ValueError`` naming them (give
    ``--dialect``)."""
    head = text[:DETECT_BYTES]
    found = {}  # name: (what, offset of its first marker)
    for name, pats in MARKERS.items():
        for pat, what in pats:
            m = re.search(pat, head)
            if m and (name not in found or m.start() < found[name][1]):
                found[name] = (what, m.start() + len(m.group()) - len(m.group().lstrip()))
    if "haas" in found or "siemens-iso" in found:  # Fanuc-compatible controllers that add their own words
        found.pop("fanuc", None)
    if not found:
        return RS274, ""
    if len(found) > 1:  # named at the later of the dialects' first markers, the others' lines beside
        def at(pos):
            line = head.count("\n", 0, pos) + 1
            return line, pos - (head.rfind("\n", 0, pos) + 1) + 1
        order = sorted(found.items(), key=lambda kv: kv[1][1])
        (name, (what, pos)), first = order[-1], order[:-1]
        line, col = at(pos)
        raise ValueError(f"line {line}, column {col}: {what} ({name}) in a program that holds words of another "
                         "dialect too (" + ", ".join(f"{n}: {w}, line {at(p)[0]}" for n, (w, p) in first)
                         + "): the program holds words of several dialects; name its dialect with --dialect")
    name, (what, _) = next(iter(found.items()))
    return name, what


ROUGHING = ("a lathe roughing cycle (contour in an o-subroutine named by Q): read on a lathe (a machine with X and Z, "
            "no Y: compensation.nc_g7x), not on this machine; post the passes as G1/G2/G3")
FINISHING = ("a lathe finishing cycle (contour in an o-subroutine named by Q): read on a lathe (a machine with X and "
             "Z, no Y: compensation.nc_g7x), not on this machine; post the contour as G1/G2/G3")
BOLT_HOLES = ("a hole pattern whose positions the control computes, each drilled by the canned cycle in force: not "
              "read; --expand-cycles does not apply; post each hole's X Y")
LATHE_G7X = {"G70": f"finishing cycle: {FINISHING}", "G71": f"stock removal along Z: {ROUGHING}",
             "G72": f"facing stock removal: {ROUGHING}"}
G7X = {("linuxcnc", None): LATHE_G7X,
       ("haas", False): {"G70": f"bolt hole circle: {BOLT_HOLES}", "G71": f"bolt hole arc: {BOLT_HOLES}",
                         "G72": f"bolt holes along an angle: {BOLT_HOLES}"}}
"""``G70``-``G72`` by dialect and machine (lathe: True) where they are refused: Haas mill manual (G70 bolt hole
circle, G71 bolt hole arc, G72 bolt holes along an angle), LinuxCNC 2.9 (G70 finishing, G71 roughing, G72 facing,
on a machine that is not a lathe; on a lathe :mod:`compensation.nc_g7x` reads them, the contour a subroutine). A Fanuc
or Haas lathe's G70-G73 with their contour blocks in the program are read by :mod:`compensation.nc_contour`.
Elsewhere the generic two-reading message."""


def g7x_refusal(code: str, current: str, lathe: bool) -> str | None:
    """Why ``code`` (``G70``-``G72``) is refused on dialect ``current`` (a lathe or not): :data:`G7X`; None: no
    dialect-specific reading."""
    meaning = G7X.get((current, lathe), G7X.get((current, None), {})).get(code)
    where = f"a {current} {'lathe' if lathe else 'mill'}" if (current, lathe) in G7X else current
    return None if meaning is None else f"'{code}' on {where}: {meaning}"


def other_dialects_with_g(code: str, current: str) -> str:
    """``"; on fanuc, haas it is scaling off: name the controller with --dialect"``: the dialects whose mode codes hold
    a G code the current one refuses (empty when none)."""
    known = [n for n, d in DIALECTS.items() if n != current and code in d.modes]
    what = DIALECTS[known[0]].modes[code].split(" (")[0] if known else ""
    spl = [n for n, d in DIALECTS.items() if n != current and code in d.splines]
    out = f"; on {', '.join(known)} it is {what}" if known else ""
    out += f"; on {', '.join(spl)} it is {DIALECTS[spl[0]].splines[code].split(' (')[0]}" if spl else ""
    prb = [n for n, d in DIALECTS.items() if n != current and code in d.probes]
    out += f"; on {', '.join(prb)} it is a probe move" if prb else ""
    return f"{out}: name the controller with --dialect" if out else ""


def other_dialects_with_m(code: float, current: str) -> str:
    """``"; haas: chip auger forward (name it with --dialect)"``: the dialects that know an M code the
    current one refuses (empty when none)."""
    if code != int(code):
        return ""
    known = [f"{n}: {d.m_codes[int(code)]}" for n, d in DIALECTS.items() if n != current and int(code) in d.m_codes]
    return f"; {', '.join(known)} (name the controller with --dialect)" if known else ""
