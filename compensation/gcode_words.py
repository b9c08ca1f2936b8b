"""The words of the G-code reader (:mod:`compensation.gcode`): the machine's axis words (:class:`AxisWords`),
the allow-list tables (:data:`ALLOWED_G`, :data:`REFUSED_G`, :data:`ALLOWED_M`, :data:`LETTER_RULES`), the records
a program is read into (:class:`Word`, :class:`GMove`, :class:`GProgram`), the byte checks and the tokeniser."""
from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import InputError, check_not_wide

from .gcode_state import MM_PER_INCH, _Refuse
from .nc_expand import SLASH_COMMENT


DECIMALS = {"mm": 6, "inch": 7, "deg": 6}
"""Decimals written: 1 nm in mm, 2.5 nm in inch, 1e-6 deg (1 nm at 57 mm from the A axis)."""
ARC_RADIUS_TOL_MM = 0.002
"""Start and end radius of an I/K arc may differ by this much (CAM output rounds centres);
more is refused as an ill-defined arc. A dialect may say what its controller accepts
(:attr:`compensation.dialects.Dialect.arc_radius_tol`: LinuxCNC's own defaults); the arc is read as a
spiral whose radius changes linearly with the angle, as those controllers run it."""
ARC_RADIUS_TOL_INCH_MM = 2 * 0.0001 * MM_PER_INCH * 2 ** 0.5
"""The same under G20 (7.18 μm): CAM posts write inch words to 0.0001 inch (2.54 μm), so the centre and the
end point each rounded by half of that already make the radii differ by more than 2 μm; the bound is
LinuxCNC's formula (:data:`compensation.dialects.LINUXCNC_ARC_TOL`) at that resolution."""
MAX_TOOL_DIGITS = 2
"""A ``T`` word of more digits is refused: on lathe controls (Fanuc's T-code form ``Tttoo``)
the digits after the tool number select a geometry/wear offset, which shifts the axes as
``G43 H`` does (refused too); one or two digits are a tool number only, on every dialect."""
BLOCK_DELETE_CHOICES = ("on", "off")
RAPIDS_CHOICES = ("keep", "compensate")
DEFAULT_RAPIDS = "keep"
AXIS_LETTERS = ("X", "Y", "Z", "U", "V", "W", "A", "B", "C")
"""Letters that are axis words on some machine: refused where the machine has no such axis."""
CENTRE_AXIS = {"I": "X", "J": "Y", "K": "Z"}
"""Arc centre word -> the axis it offsets along."""
PLANES = {"G17": ("X", "Y", "I", "J"), "G18": ("Z", "X", "K", "I"), "G19": ("Y", "Z", "J", "K")}
"""Arc plane -> (u axis, v axis, u centre word, v centre word); the arc turns counter-clockwise
(G3) from u towards v, seen from the positive third axis (RS274)."""
PLANE_NAMES = {"G17": "XY", "G18": "XZ", "G19": "YZ"}
LATHE_INCREMENTAL = {"U": "X", "V": "Y", "W": "Z"}
"""On lathe dialects these letters are incremental X, Y, Z (refused unless the machine has the axis)."""


@dataclass(frozen=True)
class AxisWords:
    """The axis words a program is read and written with: the machine's, in its axis order.

    ``machine`` the name refusals give; ``words`` the axis words (``("X", "Y", "Z")``);
    ``rotary`` the words in degrees (the others are linear, mm or inch); ``kept`` the words kept
    as the program wrote them where a compensated value equals the programmed one, and written
    on an added or rewritten line only where they move (a chain's rotary axes: the tool
    orientation); every other word is written on every compensated line.
    """

    machine: str
    words: tuple
    rotary: tuple = ()
    kept: tuple = ()
    harmless_m: tuple = ()
    """M code numbers the machine file's ``[controller] harmless_m`` adds to the dialect's harmless ones."""

    def __post_init__(self):
        bad = [w for w in self.words if w not in AXIS_LETTERS]
        if bad or len(set(self.words)) != len(self.words) or not self.words:
            raise ValueError(f"Expected distinct axis words of {list(AXIS_LETTERS)}, got {list(self.words)}")
        if not set(self.rotary) <= set(self.words) or not set(self.kept) <= set(self.words):
            raise ValueError(f"Expected rotary and kept words among {list(self.words)}, got {list(self.rotary)}, "
                             f"{list(self.kept)}")

    @classmethod
    def of(cls, machine, keep_rotary: bool = False) -> "AxisWords":
        """The axis words of a loaded machine (its file's axes, :func:`errormap.machine.machine_axes`);
        ``keep_rotary``: rotary words kept as programmed (a chain's tool orientation). A machine whose
        axes are not G-code axis words (an arm's joints, a PKM's legs) raises ``ValueError``."""
        from errormap.machine import machine_axes
        axes = machine_axes(machine)
        words = tuple(a.name for a in axes)
        if not all(w in AXIS_LETTERS for w in words):
            raise ValueError(f"the machine {machine.name!r} ({machine.kind}) has no G-code axis words "
                             f"(its axes: {' '.join(words)})")
        rotary = tuple(a.name for a in axes if a.type == "rotary")
        harmless = tuple((getattr(machine, "controller", None) or {}).get("harmless_m", ()))
        return cls(machine.name, words, rotary, rotary if keep_rotary else (), harmless)

    @functools.cached_property
    def is_rotary(self) -> tuple:
        """Per word: rotary (deg) or not (linear, mm or inch)."""
        return tuple(w in self.rotary for w in self.words)

    @functools.cached_property
    def lacking(self) -> dict:
        """Letter -> why it is refused, for the axis words of axes the machine lacks and the arc
        centre words along them (``J`` without a Y axis)."""
        out = {}
        for w in AXIS_LETTERS:
            if w not in self.words:
                inc = LATHE_INCREMENTAL.get(w)
                hint = f"; on lathe dialects {w} is incremental {inc}" if inc else ""
                out[w] = f"the machine {self.machine!r} has no {w} axis (its axes: {self.listed}{hint})"
        for c, a in CENTRE_AXIS.items():
            if a not in self.words:
                out[c] = (f"arc centre {a} offset, but the machine {self.machine!r} has no {a} axis "
                          f"(its axes: {self.listed})")
        return out

    @property
    def planes(self) -> tuple:
        """The arc planes whose two axes the machine has (``("G18",)`` on an X-Z-A machine)."""
        return tuple(p for p, (u, v, _, _) in PLANES.items() if u in self.words and v in self.words)

    @property
    def listed(self) -> str:
        return " ".join(self.words)

    def joined(self, last: str) -> str:
        """``"X, Z and A"`` (``last="and"``) or ``"X, Z or A"``."""
        w = self.words
        return w[0] if len(w) == 1 else f"{', '.join(w[:-1])} {last} {w[-1]}"


def default_axis_words() -> AxisWords:
    """The axis words of the built-in default machine (:func:`errormap.machine.load_machine` with no
    path), read from its file when called (never at import): the reader's words where a caller
    names no machine."""
    from errormap.machine import load_machine
    return AxisWords.of(load_machine())

# ---------------------------------------------------------------------------- allow-list
# G codes the reader understands. Value: (modal group, what the reader does).
ALLOWED_G = {
    "G0": ("motion", "rapid move; compensated or kept as written (--rapids)"),
    "G1": ("motion", "linear move; compensated, split where long"),
    "G2": ("motion", "clockwise arc in a plane of the machine's linear axes; linearised and compensated"),
    "G3": ("motion", "counter-clockwise arc in a plane of the machine's linear axes; linearised and compensated"),
    "G80": ("motion", "cancel motion mode (no axis words allowed after it; on Fanuc, Haas and Siemens ISO "
                      "the G0-G3 mode stays, as their G80 is group 09)"),
    "G4": ("nonmodal", "dwell with P (Fanuc, Siemens ISO: or X seconds); other axis words refused (LinuxCNC: a move "
                       "after the dwell, --dialect linuxcnc)"),
    "G28": ("nonmodal", "return to the reference: bare, or through the intermediate point its axis words give (a "
                        "rapid, written as programmed: --rapids keep); the axes it moves are unknown afterwards"),
    "G30": ("nonmodal", "return to the second reference: as G28"),
    "G17": ("plane", "XY plane, centre I J (arcs in it are refused on a machine without X and Y)"),
    "G18": ("plane", "XZ plane, centre I K"),
    "G19": ("plane", "YZ plane, centre J K (arcs in it are refused on a machine without Y and Z)"),
    "G20": ("units", "inch; read exactly, written back in inch"),
    "G21": ("units", "mm"),
    "G90": ("distance", "absolute"),
    "G91": ("distance", "incremental; read exactly, written back incremental"),
    "G90.1": ("arc_distance", "absolute arc centres I J K"),
    "G91.1": ("arc_distance", "incremental arc centres I J K (the default)"),
    "G94": ("feed", "feed per minute"),
    "G95": ("feed", "feed per revolution"),
    "G40": ("cutter", "cutter compensation off"),
    "G41": ("cutter", "cutter radius compensation left, D: the path is compensated as programmed; the bound on "
                      "the error left (field gradient x tool radius, --tool-table) is reported"),
    "G42": ("cutter", "cutter radius compensation right, D: as G41"),
    "G53": ("nonmodal", "machine coordinates for this line (G0/G1): passed through unchanged, not compensated; "
                        "its end placed in the program's frame where the work offsets are given, else the axes it "
                        "moves are unknown afterwards"),
    "G43": ("length", "tool length offset H (the tool table's length, --tool-table): machine Z = program Z + length"),
    "G49": ("length", "tool length offset off"),
    "G10": ("nonmodal", "L2 Pn: sets work offset n; L1 Pn Z.. R..: sets tool n (read as data, in program order)"),
    **{c: ("coords", "selects a work system: machine axes = program axes + its offset (--work-offsets)")
       for c in ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")},
    "G54.1": ("coords", "selects the extended work system P (--work-offsets)"),
    "G61": ("path", "exact path"),
    "G61.1": ("path", "exact stop"),
    "G64": ("path", "blending (P, Q tolerances allowed)"),
    "G8": ("lathe", "radius mode (the default)"),
    "G15": ("polar", "polar coordinates off"),
    "G67": ("macro", "modal macro off"),
    "G69": ("rotation", "coordinate rotation off"),
    "G96": ("spindle", "constant surface speed (spindle only)"),
    "G97": ("spindle", "constant spindle speed"),
    "G98": ("return", "canned-cycle return level: the Z before the cycle (cycles: machine-tool chains only)"),
    "G99": ("return", "canned-cycle return level: the R plane (cycles: machine-tool chains only)"),
}
G92_CODES = {
    "G92": "coordinate offset: the current position reads the axis words' values (every work system shifts by "
           "the same amount; the position along them must be known; refused under G91)",
    "G92.1": "G92 offset cleared (and its stored values zeroed)", "G92.2": "G92 offset suspended (values kept)",
    "G92.3": "G92 offset restored from its stored values"}
"""LinuxCNC G-code reference ("G92 Coordinate System Offset", "G92.1, G92.2", "G92.3"), grbl v1.1 (G92, G92.1):
read on the dialects whose ``g92_offsets`` is set (:mod:`compensation.dialects`), as events of the frames
(:mod:`compensation.gcode_state`, :func:`compensation.nc_state.program_frames`); the G92 offset the controller
holds at program start is taken as zero (LinuxCNC's stored 5211-5219 are refused when non-zero in a .var)."""
UNITS_OR_CYCLE = ("lathe cycle on Fanuc, Haas, LinuxCNC; {what} input in Fanuc lathe G-code system C, Sinumerik "
                  "native, NX generic posts: no dialect here says which; post units as G20/G21")
"""``G70``/``G71``: two meanings by controller; neither is read (the message names both and the fix)."""
REFUSED_G = {
    **{g: f"{what}: not interpretable exactly (no option reads it; post the path as G1/G2/G3)" for g, what in (
        ("G6.2", "NURBS block"),)},
    "G5.2": "NURBS block (read with --dialect linuxcnc)", "G5.3": "NURBS block end (read with --dialect linuxcnc)",
    "G5": "dialect-dependent: a spline or a machining mode", "G5.1": "dialect-dependent: a spline or look-ahead",
    "G7": "lathe diameter mode (read with --dialect linuxcnc)", "G7.1": "cylindrical interpolation",
    "G107": "cylindrical interpolation",
"G12": "circular pocket", "G13": "circular pocket",
    "G16": "polar coordinates", "G17.1": "UV plane", "G18.1": "WU plane", "G19.1": "VW plane",
    "G28.1": "sets the reference position", "G30.1": "sets the reference position",
    "G31": "skip (probing)", "G33": "spindle-synchronised motion (read with --dialect linuxcnc)",
    "G33.1": "rigid tapping (read with --dialect linuxcnc)",
    "G38.2": "probing", "G38.3": "probing", "G38.4": "probing", "G38.5": "probing",
    **{g: ("dynamic cutter radius compensation, D the diameter (LinuxCNC's, read with --dialect linuxcnc; Fanuc's "
           "G41.1/G42.1 is normal direction control)") for g in ("G41.1", "G42.1")},
    "G43.1": "dynamic tool length offset (LinuxCNC's read with --dialect linuxcnc)", "G43.2": "tool length offset",
    "G50": "scaling off / lathe coordinate setting (dialect-dependent)", "G50.1": "mirror off",
    "G51": "scaling", "G51.1": "mirror",
    "G54.2": ("dynamic fixture offset: the offset follows the rotary axes from a controller table that no file read "
              "here holds; give the offset at the program's rotary position as a G54-G59 or G54.1 P system in "
              "--work-offsets"),
    "G254": "Haas dynamic work offset (turned with B/C by the control's settings): post without it (G54 at the "
            "rotary position, in --work-offsets) or in TCPC (G234)",
    "G52": "local coordinate shift (read on LinuxCNC, Fanuc, Haas, Siemens ISO, Mach3, or with no dialect named)",
    "G60": "unidirectional approach", "G65": "macro call (its letters are arguments, not axes)",
    "G66": "modal macro call", "G66.1": "modal macro call", "G68": "coordinate rotation",
    "G68.2": "tilted work plane", "G70": UNITS_OR_CYCLE.format(what="inch"), "G71": UNITS_OR_CYCLE.format(what="mm"), "G72": "lathe cycle",
    "G73": "canned cycle (drilling cycles are read by compensate on chains with X Y Z: --machine mill-xyz)",
    "G74": "canned cycle (as G73)",
    "G75": "canned cycle", "G76": "lathe threading (LinuxCNC's read on a lathe with --dialect linuxcnc and "
                                  "--expand-cycles; Fanuc/Haas passes not interpretable exactly) or mill fine boring "
                                  "(kept on chains with X Y Z with --dialect fanuc/haas/siemens-iso)",
    **{f"G{k}": "canned cycle (as G73)" for k in range(81, 90)},
    "G87": "back boring cycle (kept on chains with X Y Z with --dialect fanuc/siemens-iso)",
    "G88": "boring cycle with a manual retract (kept on chains with X Y Z with --dialect fanuc/siemens-iso)",
    **{g: "coordinate offset (read with --dialect linuxcnc or grbl, whose manuals define it)" for g in (
        "G92", "G92.1", "G92.2", "G92.3")}, "G93": "inverse-time feed (a split move would change its time)",
}
ALLOWED_M = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30, 48, 49, 50, 51, 52, 53, 60}
"""M codes that move no axis (program stop/end, spindle, tool change, coolant, overrides).
Others (``M98``/``M99`` subprograms, user M codes) are refused."""
LETTER_RULES = {
    "N": "line number", "F": "feed", "S": "spindle speed", "T": "tool number", "M": "see ALLOWED_M",
    "G": "see ALLOWED_G", **{a: "an axis word of the machine (linear mm/inch, rotary deg); refused where the "
                                "machine has no such axis" for a in AXIS_LETTERS},
    **{c: f"arc centre {a} offset (G2/G3 only, in a plane with {a})" for c, a in CENTRE_AXIS.items()},
    "R": "arc radius (G2/G3 only; G10 L1 tool radius)",
    "P": "G4 dwell, G64 tolerance, P1 on an arc, G54.1 system, G10 number",
    "H": "tool length offset number (G43 only)",
    "L": "G10 data type (G10 only; LinuxCNC G41.1/G42.1: the lathe tool orientation)",
    "D": "cutter radius offset number (G41/G42 only; LinuxCNC G41.1/G42.1: the cutter diameter)",
    "Q": "G64 tolerance", "O": "program number on a line of its own",
}
REFUSED_LETTERS = {
    "E": "extruder / unknown axis",
}


@dataclass
class Word:
    letter: str       # upper case
    value: float
    text: str         # the number as written (may hold spaces)
    start: int        # column (0-based) of the letter
    num_start: int    # span of the number in the line
    num_end: int

    @property
    def code(self) -> str:
        """``G1``, ``G38.2``, ``M3`` ... (G and M words)."""
        v = round(self.value, 1)
        return f"{self.letter}{int(v)}" if v == int(v) else f"{self.letter}{v:g}"


@dataclass
class GMove:
    """One moving line. ``start``/``end`` (k,) absolute mm / deg in the reader's axis order
    (:class:`AxisWords`; ``start`` may hold NaN for an axis not yet known); ``arc`` for G2/G3:
    dict with centre, radii, sweep in the plane's axis columns ``ju``, ``jv`` (for a spline, kind
    ``"spline"``: its control points ``ctrl``, :mod:`compensation.gcode_spline`); ``words`` the
    line's axis and ``I J K R P`` (a spline's ``P Q``) words; ``units`` ``"mm"``/``"inch"``; ``incremental`` G91."""

    index: int
    kind: str            # "rapid", "linear", "arc" or "spline"
    start: np.ndarray
    end: np.ndarray
    units: str
    incremental: bool
    words: dict
    motion_word: Word | None
    compensate: bool
    arc: dict | None = None
    known: np.ndarray = field(default_factory=lambda: np.ones(3, bool))  # axes known at the end
    diameter: bool = False
    """Read in lathe diameter mode (LinuxCNC ``G7``): its X word was a diameter (``words["X"]`` holds the radius
    read; the writer writes X doubled)."""
    synced: str | None = None
    """``"G33"``/``"G33.1"``: a spindle-synchronised line (LinuxCNC), written as one line, never split (each
    synchronised move waits for the spindle index); None otherwise."""
    lead: tuple | None = None
    """A Fanuc/Haas lathe ``G32``: ``(F value, F text, lead axis column)``, the programmed lead (program units per
    revolution) along the axis of the larger travel; split like any move, each piece written with its own F
    (:func:`compensation.nc_thread.lead_texts`); None otherwise."""
    block_end: bool = False
    """The last block ``N(nf)`` of a lathe contour cycle (:mod:`compensation.nc_contour`): when split, its N word is
    written on the last piece (the contour ends where the block's programmed end is)."""

    @property
    def start_known(self) -> bool:
        return bool(np.all(np.isfinite(self.start)))


@dataclass
class GProgram:
    """A parsed G-code file: its lines (Latin-1 text, endings kept), their classes and moves."""

    path: Path
    lines: list
    classes: list
    moves: list
    rapids: str = DEFAULT_RAPIDS
    block_delete: str | None = None
    table: "MoveTable | None" = field(default=None, repr=False)
    """The moves as columns (:class:`MoveTable`, set by the block-wise reader); ``moves`` is then
    a lazy sequence that builds each :class:`GMove` only when asked for."""
    data: bytes | None = field(default=None, repr=False)
    """The file's bytes (block-wise reader; :func:`render_table` copies from them)."""
    axis_words: AxisWords | None = None
    """The machine's axis words the program was read with (the moves' columns, in order); the
    readers always set it."""
    events: tuple = ()
    """The program's controller-state words in line order: ``(line (0-based), column, kind, value,
    text)`` with kind ``system`` (value ``G54`` … ``G54.1P3``), ``tool`` (``G43 Hn``: n; ``G49``:
    None), ``g10-work`` (``(system, {word: mm/deg})``), ``g10-tool`` (``(n, (length_mm, radius_mm))``);
    resolved against the offset and tool tables by :func:`compensation.nc_state.program_frames`."""
    dialect: str = "rs274"
    """The controller dialect the program was read in (:mod:`compensation.dialects`)."""
    dialect_evidence: str = ""
    expanded: object = field(default=None, repr=False)
    """:class:`compensation.nc_expand.Expanded` where the program's subprograms, macros or
    parameters were expanded (``lines`` are then the flat program's); None otherwise."""

    tcp: object = field(default=None, repr=False)
    """:class:`compensation.tcp.TcpProgram` where the program holds tool-centre-point or G93 words (chain
    readers); None otherwise."""
    line_end: str = "\n"
    """The file's line end: ``"\r"`` for a CR-only file (old Mac style, :func:`cr_line_ends`: read with LF in its
    place, ``lines`` end with ``"\n"``); the writer ends every written line with it again."""
    g80_line: int | str = 0
    """Recognised as no dialect (:data:`compensation.dialects.UNRECOGNISED`): the first line (1-based, of the
    file; ``'k of FILE'`` in a ``--subprograms`` file) whose bare axis word after ``G80`` was read in the G0-G3 of
    before it (group 09); 0: none."""

    def notes(self) -> tuple:
        """Header lines every written program carries: what was expanded, how ``G80`` was read."""
        return (() if self.expanded is None else (self.expanded.note(),)) + (
            (f"volcomp: {g80_note(self.g80_line)}",) if self.g80_line else ())


def g80_note(line: int) -> str:
    """What the summary and the header say where a bare axis word after ``G80`` was read the group-09 way."""
    from .dialects import G09_NOTE
    return G09_NOTE.format(line=line)


_CSV_CELL = re.compile(r"^\s*\"?[A-Za-z_][A-Za-z0-9_ ()./%-]*\"?\s*$")


def check_program_bytes(path, data: bytes) -> None:
    """Refuse, before any line is parsed, what is not a G-code program in the bytes a controller
    reads: UTF-16/32 text (:func:`errormap.io.check_not_wide`), CR-only line endings at the start of a file with
    LF further on (mixed ends: the start would be one line, "repeated 'X' word"; a file of CR-only ends throughout
    is read by :func:`cr_line_ends` before this), and a CSV table (a header of names and
    comma-separated rows: no G-code word holds a comma), each one :class:`InputError` naming the file."""
    check_not_wide(data, path)
    head = data[:SNIFF_BYTES]
    if b"\n" not in head and head.count(b"\r") >= 2:
        raise InputError(f"{path}: CR-only line endings (old Mac style) at its start and LF line endings further "
                         "on: mixed line ends; convert it to LF or CRLF line endings")
    text = head.decode("latin-1").replace("\r", "")
    lines = [(k + 1, ln) for k, ln in enumerate(text.split("\n"))
             if ln.strip() and not ln.lstrip().startswith(("#", "(", ";", "%"))][:3]
    if len(lines) >= 2 and "," in lines[0][1]:
        row, first = lines[0]
        cells = first.split(",")
        if all(_CSV_CELL.match(c) for c in cells) and all(ln.count(",") == len(cells) - 1 for _, ln in lines[1:]):
            raise InputError(f"{path}: line {row} is a CSV header ({', '.join(c.strip() for c in cells[:4])}"
                             f"{', ...' if len(cells) > 4 else ''}), not G-code: a tool-path CSV needs the machine's "
                             "axis columns (the grinder's x_mm, z_mm, a_deg) or the target columns px_mm, py_mm, "
                             "pz_mm (docs/reference/tool-paths.md)")



def cr_line_ends(data: bytes) -> tuple:
    """``(bytes, line_end)``: a file with CR-only line ends (old Mac style: a CR ends each line and no LF occurs
    anywhere; Fanuc and LinuxCNC take CR as the end of a block too) with LF in place of each CR, byte for byte (same
    length, so every column is the file's), and ``"\r"``; any other file as it is, and ``"\n"``."""
    if b"\r" not in data or b"\n" in data:
        return data, "\n"
    return data.replace(b"\r", b"\n"), "\r"


def with_line_end(text: str, line_end: str) -> str:
    """A written program (LF line ends) with the source's line end (:attr:`GProgram.line_end`)."""
    return text if line_end == "\n" else text.replace("\n", line_end)


SNIFF_BYTES = 1 << 16
"""Bytes of a program's start looked at by :func:`check_program_bytes`."""




def split_lines(text: str) -> list:
    """Lines with their ``\\n`` endings kept; only ``\\n`` ends a line (a ``\\r`` stays with it)."""
    parts = text.split("\n")
    lines = [p + "\n" for p in parts[:-1]]
    if parts[-1]:
        lines.append(parts[-1])
    return lines


_NUMBER = re.compile(r"[ \t]*([+-]?[ \t]*(?:\d(?:[\d \t]*\d)?(?:[ \t]*\.(?:[\d \t]*\d)?)?|\.(?:[\d \t]*\d)?))")
"""An RS274 number: optional sign, digits with spaces/tabs anywhere inside, at most one point;
the match ends on a digit or the point (trailing blanks are not part of it)."""


def _number(body: str, j: int):
    """RS274 number at ``j``: spaces/tabs anywhere inside, optional sign, no exponent.
    Returns ``(value, text, start, end)`` or None."""
    m = _NUMBER.match(body, j)
    if m is None:
        return None
    text = m.group(1)
    compact = text.replace(" ", "").replace("\t", "")
    if not any(c.isdigit() for c in compact):
        return None
    return float(compact), text, m.start(1), m.end(1)


_PLAIN_LINE = re.compile(r"[ \t\r]*(?:[A-DF-NP-Za-df-np-z][+-]?(?:\d+(?:\.\d*)?|\.\d+)[ \t\r]*)+")
"""A line of plain words only: ASCII letters other than E and O, each followed at once by a
plain number (sign, digits, at most one point, no blanks inside), blanks between words. Such a
line reads the same word by word as by :func:`tokenize`'s general loop (nothing it could
refuse: no comment, no '%', no '/', no exponent, no O-word, no parameter); anything else takes
the general loop."""
_PLAIN_WORD = re.compile(r"([A-Za-z])([+-]?(?:\d+(?:\.\d*)?|\.\d+))")


def tokenize(body: str):
    """Words of one line (no line ending): ``(block_delete, [Word], percent_line)``.

    Raises :class:`_Refuse` (column, message) for what RS274 would not read exactly.
    """
    if _PLAIN_LINE.fullmatch(body):
        words = [Word(m.group(1).upper(), float(m.group(2)), m.group(2), m.start(), m.start() + 1, m.end())
                 for m in _PLAIN_WORD.finditer(body)]
        if all(math.isfinite(w.value) for w in words):
            return False, words, False
    i, n = 0, len(body)
    while i < n and body[i] in " \t":
        i += 1
    block_delete = i < n and body[i] == "/"
    if body.startswith("//", i):
        raise _Refuse(i + 1, SLASH_COMMENT)
    if block_delete:
        i += 1
    if body[i:].strip().startswith("%"):
        rest = body[i:].strip()[1:].strip()
        if rest and not rest.startswith(("(", ";")):
            raise _Refuse(i + 1, f"text after '%': {rest[:20]!r} ('%' on a line frames the program: LinuxCNC ends "
                                 "the program at a second '%' line, Fanuc reads it as the end of record): write the "
                                 "text in ( ) or after ';'")
        return block_delete, [], True
    words = []
    while i < n:
        c = body[i]
        if c in " \t\r":
            i += 1
        elif c == "(":
            j = body.find(")", i + 1)
            if j < 0:
                raise _Refuse(i + 1, "unclosed '(' comment")
            i = j + 1
        elif c == ";":
            break
        elif c in "@^":
            raise _Refuse(i + 1, f"'{c}': a LinuxCNC polar coordinate ({'distance' if c == '@' else 'angle'} from the XY "
                                 "zero): read on G0-G3 lines of LinuxCNC programs only (compensation.nc_polar)")
        elif c.isalpha() and c.isascii():
            u = c.upper()
            j = i + 1
            while j < n and body[j] in " \t":
                j += 1
            if j < n and body[j] in "#[<":
                raise _Refuse(i + 1, f"'{c}{body[j]}...': parameters and expressions are not evaluated")
            num = _number(body, i + 1)
            if num is None:
                raise _Refuse(i + 1, f"'{c}' word without a plain number")
            v, text, s, e = num
            if u == "O" and body[e:].split("(")[0].split(";")[0].strip():
                raise _Refuse(i + 1, f"'{c}{text} {body[e:].strip()[:12]}': O-word subroutines and control flow "
                                     "are not supported")
            if e < n and body[e] in "eE" and e + 1 < n and (body[e + 1].isdigit() or body[e + 1] in "+-"):
                raise _Refuse(i + 1, f"'{c}{text}{body[e:e + 2]}...': exponent notation is not RS274")
            if not math.isfinite(v):
                raise _Refuse(i + 1, f"'{c}' number out of range")
            words.append(Word(u, v, text, i, i + 1, e))  # rewriting replaces spaces after the letter too
            i = e
        elif c == ":":
            raise _Refuse(i + 1, "unexpected character ':' (not an RS274 word; in ISO code ':' is the program-number "
                                 "address, read only as ':1234' on a line of its own): remove it")
        else:
            raise _Refuse(i + 1, f"unexpected character {c!r} (not an RS274 word)")
    return block_delete, words, False



def _err(path, lineno, col, msg):
    return InputError(f"{path}: line {lineno}, column {col}: {msg}")
