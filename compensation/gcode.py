"""G-code reading and rewriting with an explicit allow-list (RS274/NGC semantics).

The contract, line by line
--------------------------
Every line of a program is put in exactly one class by :func:`classify_line`:

``pass``     nothing on it moves or reinterprets an axis (comments, ``N F S T``, allowed
             ``M`` codes, modal codes that change no axis meaning). Written back **byte for
             byte**.
``state``    modal codes the reader follows and that do not move by themselves: ``G90/G91``
             (distance), ``G90.1/G91.1`` (arc centres), ``G20/G21`` (units), ``G17/G18/G19``
             (plane), a motion code with no axis words (``G1`` alone), ``G4 P``; and
             ``G28``/``G30`` (a return to a machine reference, after which the axes it
             moved are unknown). Written back byte for byte.
``move``     a ``G0``/``G1``/``G2``/``G3`` line with axis words. Compensated (its axis numbers
             replaced; split or linearised into several lines where needed) — or, for a
             rapid under ``rapids="keep"``, written back byte for byte.
``skipped``  a block-delete line (``/``) when block delete is ``on``: the controller skips
             it, so the reader does too. Written back byte for byte.

Anything else that can move or reinterpret an axis is **refused** with
:class:`~errormap.io.InputError` naming the file, the 1-based line, the 1-based column and
the word (``prog.nc: line 7, column 4: 'G65' ...``). The full tables of what is allowed and
why each refused code is refused are :data:`ALLOWED_G`, :data:`REFUSED_G`,
:data:`ALLOWED_M` and :data:`LETTER_RULES` (docs/reference/tool-paths.md prints them).

Work systems (``G54`` … ``G59.3``, ``G54.1 P``), tool length offsets (``G43 H`` / ``G49``), cutter
radius compensation (``G41``/``G42 D`` / ``G40``) and the program's own tables (``G10 L2`` / ``L1``) are
read as events (:attr:`GProgram.events`), resolved against the controller's tables by
:func:`compensation.nc_state.program_frames`; the moves stay in program coordinates. A controller
dialect (:mod:`compensation.dialects`) widens the M codes and mode codes accepted.

Numbers are read as RS274 reads them: spaces and tabs inside a number are ignored (``X1 0``
is X10), an optional sign and decimal point, no exponent (``X1e2`` is refused), no
parameters or expressions (``#1``, ``[1+2]``).

Axis words are the machine's (:class:`AxisWords`, from the machine file by
:meth:`AxisWords.of`; where a caller names no machine, the built-in default machine's file,
read when called: :func:`default_axis_words`): ``X Z A`` on an X-Z-A machine, ``X Y Z`` on a
3-axis mill, ``X Y Z A C`` on a five-axis machine, ``X Z C`` on a lathe; linear words in mm or
inch, rotary ones in degrees. A word of an axis the machine lacks (``Y`` on an X-Z-A machine, ``B`` on a mill;
``U V W``, incremental axes on lathe dialects) is refused naming the machine, and so is an arc
centre word along such an axis (``J`` without a Y axis). Arcs ``G2/G3`` run in the planes of the
machine's linear axes: ``G17`` (XY, centre ``I J``), ``G18`` (XZ, ``I K``), ``G19`` (YZ,
``J K``), or by ``R``; an arc in a plane whose axes the machine lacks (the plane code alone is a
state line), or with a centre word of another plane, is refused; the other axes of an arc line
move linearly along it.

Moves are kept as :class:`GMove` records (start and end in absolute mm / deg in the machine's
axis order, whatever the program's mode and units were), so a caller can place vertices along
each move (:func:`move_points`) and :func:`render_program` writes them back in the program's
own distance mode and units. Long programs of a machine with three axis words, each written on
every compensated line, go through a block-wise reader and writer (:func:`_parse_blockwise`,
:func:`render_table`; same result, in bulk).
"""
from __future__ import annotations

import functools
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import InputError, check_not_wide

from . import gcode_kernels as gscan
from .gcode_state import (MM_PER_INCH, _dialect_mode, _g10, _machine_coordinates, _Refuse, _tool_change,
                          _work_state, io_line, siemens_native)
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
        return cls(machine.name, words, rotary, rotary if keep_rotary else ())

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
    "G4": ("nonmodal", "dwell with P; refused with axis words (Fanuc G4 X is a dwell time)"),
    "G28": ("nonmodal", "return to the reference: bare, or with zero incremental words ('G28 G91 Z0'); "
                        "the axes it moves are unknown afterwards"),
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
                        "the axes it moves are unknown in program coordinates afterwards"),
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
REFUSED_G = {
    **{g: f"{what}: not interpretable exactly (no option reads it; post the path as G1/G2/G3)" for g, what in (
        ("G5", "cubic spline"), ("G5.1", "quadratic spline"), ("G5.2", "NURBS block"), ("G5.3", "NURBS block end"),
        ("G6.2", "NURBS block"))},
    "G7": "lathe diameter mode (X would mean a diameter)", "G7.1": "cylindrical interpolation",
    "G107": "cylindrical interpolation",
"G12": "circular pocket", "G13": "circular pocket",
    "G16": "polar coordinates", "G17.1": "UV plane", "G18.1": "WU plane", "G19.1": "VW plane",
    "G28.1": "sets the reference position", "G30.1": "sets the reference position",
    "G31": "skip (probing)", "G33": "spindle-synchronised motion", "G33.1": "rigid tapping",
    "G38.2": "probing", "G38.3": "probing", "G38.4": "probing", "G38.5": "probing",
    "G41.1": "dynamic cutter radius compensation", "G42.1": "dynamic cutter radius compensation",
    "G43.1": "tool length offset", "G43.2": "tool length offset",
    "G50": "scaling off / lathe coordinate setting (dialect-dependent)", "G50.1": "mirror off",
    "G51": "scaling", "G51.1": "mirror", "G52": "local coordinate shift",
    "G60": "unidirectional approach", "G65": "macro call (its letters are arguments, not axes)",
    "G66": "modal macro call", "G66.1": "modal macro call", "G68": "coordinate rotation",
    "G68.2": "tilted work plane", "G70": "lathe cycle", "G71": "lathe cycle", "G72": "lathe cycle",
    "G73": "canned cycle (drilling cycles are read by compensate on chains with X Y Z: --machine mill-xyz)",
    "G74": "canned cycle (as G73)",
    "G75": "canned cycle", "G76": "lathe threading (spindle-synchronised passes: not interpretable exactly) or mill "
                                  "fine boring (kept on chains with X Y Z with --dialect fanuc/haas/siemens-iso)",
    **{f"G{k}": "canned cycle (as G73)" for k in range(81, 90)},
    "G87": "back boring cycle (kept on chains with X Y Z with --dialect fanuc/siemens-iso)",
    "G88": "boring cycle with a manual retract (kept on chains with X Y Z with --dialect fanuc/siemens-iso)",
    "G92": "coordinate offset", "G92.1": "coordinate offset", "G92.2": "coordinate offset",
    "G92.3": "coordinate offset", "G93": "inverse-time feed (a split move would change its time)",
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
    "H": "tool length offset number (G43 only)", "L": "G10 data type (G10 only)",
    "D": "cutter radius offset number (G41/G42 only)",
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
    dict with centre, radii, sweep in the plane's axis columns ``ju``, ``jv``; ``words`` the
    line's axis and ``I J K R P`` words; ``units`` ``"mm"``/``"inch"``; ``incremental`` G91."""

    index: int
    kind: str            # "rapid", "linear" or "arc"
    start: np.ndarray
    end: np.ndarray
    units: str
    incremental: bool
    words: dict
    motion_word: Word | None
    compensate: bool
    arc: dict | None = None
    known: np.ndarray = field(default_factory=lambda: np.ones(3, bool))  # axes known at the end

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
    g80_line: int = 0
    """Recognised as no dialect (:data:`compensation.dialects.UNRECOGNISED`): the first line (1-based, of the
    file) whose bare axis word after ``G80`` was read in the G0-G3 of before it (group 09); 0: none."""

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
    reads: UTF-16/32 text (:func:`errormap.io.check_not_wide`), CR-only line endings (the whole
    program would be one line: "repeated 'X' word"), and a CSV table (a header of names and
    comma-separated rows: no G-code word holds a comma), each one :class:`InputError` naming the file."""
    check_not_wide(data, path)
    head = data[:SNIFF_BYTES]
    if b"\n" not in head and head.count(b"\r") >= 2:
        raise InputError(f"{path}: CR-only line endings (old Mac style): the file reads as one line; convert it to "
                         "LF or CRLF line endings")
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


SNIFF_BYTES = 1 << 16
"""Bytes of a program's start looked at by :func:`check_program_bytes`."""
MAX_PROGRAM_BYTES = 2**30
"""Bytes of a G-code file, checked before it is read: a compensated line is about 30 bytes, so
1 GiB is over 30 million lines, three times the vertices a file may have
(:data:`compensation.pathio.MAX_PATH_POINTS`); the parser holds about 1.2 kB a line."""


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
            raise _Refuse(i + 1, f"text after '%': {rest[:20]!r}")
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
                                 "zero) is not read: write the point as X Y")
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
        else:
            raise _Refuse(i + 1, f"unexpected character {c!r} (not an RS274 word)")
    return block_delete, words, False


def _err(path, lineno, col, msg):
    return InputError(f"{path}: line {lineno}, column {col}: {msg}")


def parse_program(path, rapids: str = DEFAULT_RAPIDS, block_delete: str | None = None,
                  fast: bool = True, axis_words: AxisWords | None = None, dialect: str | None = None,
                  cycles=None, data: bytes | None = None, found: tuple | None = None) -> GProgram:
    """Read a G-code file into a :class:`GProgram` (see the module docstring).

    ``found``: ``(Dialect, evidence)`` already recognised from these bytes under ``dialect="auto"`` (a
    caller that looked first, :mod:`compensation.chain_gcode`): not recognised again.

    ``axis_words``: the machine's (:meth:`AxisWords.of`); ``None``: the built-in default machine's
    (:func:`default_axis_words`, read from its file now).

    ``fast`` (default): the block-wise reader (:func:`_parse_blockwise`) where the machine has three
    axis words, none kept (:func:`_bulk_words`): the common move and comment lines in bulk, every other line through the exact
    per-line classifier; same classes, moves and refusals as ``fast=False`` (the per-line
    reader, kept as the reference, and the reader of every other machine's words).

    ``rapids``: ``"keep"`` (G0 lines written as they are) or ``"compensate"``.
    ``block_delete``: ``None`` refuses a ``/`` line that moves or changes modal state;
    ``"on"`` skips ``/`` lines (the controller's switch is on); ``"off"`` runs them.
    ``dialect``: a controller of :data:`compensation.dialects.DIALECT_NAMES`, ``"auto"`` (recognised
    from the content, :func:`compensation.dialects.detect_dialect`) or None (the words every dialect
    shares); the program's ``dialect`` records which (and ``dialect_evidence`` why).
    ``cycles``: None refuses drilling canned cycles; a pass ``(text, path, dialect name, expanded or
    None) -> Expanded or None`` that makes them plain moves (the machine-tool chains give
    :func:`compensation.nc_cycles.cycle_pass`) reads them. ``data``: the file's bytes as a pre-pass left
    them (:func:`compensation.tcp.tcp_prepass`; None: read from ``path``).
    """
    path = Path(path)
    if rapids not in RAPIDS_CHOICES:
        raise ValueError(f"Expected rapids in {list(RAPIDS_CHOICES)}, got {rapids!r}")
    if block_delete not in (None,) + BLOCK_DELETE_CHOICES:
        raise ValueError(f"Expected block_delete in {list(BLOCK_DELETE_CHOICES)} or None, got {block_delete!r}")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    ax = default_axis_words() if axis_words is None else axis_words
    size = path.stat().st_size
    if size > MAX_PROGRAM_BYTES:
        raise InputError(f"{path}: {size / 2**30:.3g} GiB exceeds the limit of {MAX_PROGRAM_BYTES / 2**30:g} GiB per "
                         "program (more lines than the 10,000,000 vertices a file may have); split the program")
    data = path.read_bytes() if data is None else data
    check_program_bytes(path, data)
    dia, evidence = found if found is not None and dialect == "auto" else _dialect_of(path, data, dialect)
    try:  # the allow-list refuses every mark of a subprogram, macro or parameter: a program without
        return _g80_noted(_parse_data(path, data, rapids, block_delete, fast, ax, dia, evidence))  # at full speed
    except InputError as plain_refusal:
        from . import nc_expand
        expanded = nc_expand.expand_if_needed(data, path, dialect if dialect in nc_expand.DIALECTS else None)
        if cycles is not None:
            text = expanded.text if expanded is not None else data.decode("latin-1")
            try:  # unrecognised: the cycle's moves end in the G0-G3 of before it, as group 09 leaves it
                expanded = cycles(text, path, dia.name, expanded, **(
                    {"g80_keeps": True} if dia.g80_unrecognised else {})) or expanded
            except InputError as exc:
                raise (expanded.relocate(exc) if expanded is not None else exc) from None
        if expanded is None:
            raise plain_refusal from None
    try:
        prog = _parse_data(path, expanded.text.encode("latin-1"), rapids, block_delete, fast, ax, dia, evidence)
    except InputError as exc:
        raise expanded.relocate(exc) from None
    prog.expanded = expanded
    return _g80_noted(prog)


def _g80_noted(prog: GProgram) -> GProgram:
    """``prog`` with the line of its group-09 ``G80`` reading in the source's numbering and in its evidence."""
    if prog.g80_line:
        if prog.expanded is not None:
            prog.g80_line = prog.expanded.origin[prog.g80_line - 1][0]
        prog.dialect_evidence += f"; {g80_note(prog.g80_line)}"
    return prog


def _parse_data(path: Path, data: bytes, rapids, block_delete, fast: bool, ax: AxisWords, dia,
                evidence: str) -> GProgram:
    if fast and _bulk_words(ax):
        prog = _parse_blockwise(path, rapids, block_delete, data, ax, dia)
    else:
        prog = _parse_lines(path, rapids, block_delete, data, ax, dia)
    prog.dialect, prog.dialect_evidence = dia.name, evidence
    return prog


def _dialect_of(path, data: bytes, dialect) -> tuple:
    """``(Dialect, evidence)`` for :func:`parse_program`'s ``dialect``."""
    from .dialects import RS274, UNRECOGNISED, detect_dialect
    from .dialects import dialect as by_name
    if dialect == "auto":
        try:
            name, evidence = detect_dialect(data[:1 << 20].decode("latin-1"))
        except ValueError as exc:
            raise InputError(f"{path}: {exc}") from None
        return (by_name(name), f"recognised from its content: {evidence}") if evidence else (
            UNRECOGNISED, f"no dialect word found: {RS274}")
    try:
        return by_name(dialect), ("named" if dialect is not None else "")
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None


def _parse_lines(path, rapids, block_delete, data: bytes, ax: AxisWords, dia) -> GProgram:
    """The per-line reader (the reference)."""
    lines = split_lines(data.decode("latin-1"))
    st = _State(len(ax.words))
    st.dialect = dia
    classes, moves = [], []
    for idx, line in enumerate(lines):
        body = line.rstrip("\r\n")
        try:
            cls, move = _classify(body, idx, st, rapids, block_delete, ax)
        except _Refuse as r:
            raise _err(path, idx + 1, r.col, r.msg) from None
        classes.append(cls)
        if move is not None:
            moves.append(move)
    if not any(m.compensate for m in moves):
        raise _no_motion(path, ax)
    return GProgram(path, lines, classes, moves, rapids, block_delete, axis_words=ax, events=tuple(st.events),
                    g80_line=st.g80_line)


def _bulk_words(ax: AxisWords) -> bool:
    """The block-wise reader and writer know machines of three axis words (any letters, linear or
    rotary), each written on every compensated line (none kept)."""
    return len(ax.words) == 3 and not ax.kept


def _no_motion(path, ax: AxisWords) -> InputError:
    return InputError(f"{path}: no G0/G1/G2/G3 motion with {ax.joined('or')} words to compensate found")


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


def classify_line(body: str, state: _State, rapids=DEFAULT_RAPIDS, block_delete=None,
                  axis_words: AxisWords | None = None):
    """Public form of the per-line classifier: ``(class, GMove or None)``; updates ``state``
    (``_State(len(axis_words.words))``); ``axis_words`` ``None``: :func:`default_axis_words`."""
    return _classify(body, -1, state, rapids, block_delete, default_axis_words() if axis_words is None else axis_words)


def _checked_words(words, ax: AxisWords, dia=None):
    """Check every word against the allow-lists (``dia``: the :class:`compensation.dialects.Dialect`'s
    M codes and mode codes; None: the generic one) and the machine's axis words:
    ``(by letter, [(G code, word)], [M words])``."""
    from .dialects import GENERIC, other_dialects_with_m
    dia = GENERIC if dia is None else dia
    by = {}
    gs, ms = [], []
    for w in words:
        if w.letter == "G":
            code = w.code
            if round(w.value, 1) != round(w.value, 6):
                raise _Refuse(w.start + 1, f"'G{w.text}': unknown G code")
            if code in dia.modes or code in dia.work_systems:
                gs.append((code, w))
                continue
            if code in REFUSED_G:
                raise _Refuse(w.start + 1, f"'{code}' ({REFUSED_G[code]}) is not supported")
            if code not in ALLOWED_G:
                raise _Refuse(w.start + 1, f"'{code}': unknown G code (not on the allow-list)")
            gs.append((code, w))
            continue
        if w.letter == "M":
            if w.value != int(w.value) or int(w.value) not in dia.m_codes:
                raise _Refuse(w.start + 1, f"'M{w.text}': M code not on the {dia.name} allow-list (may move or call a "
                                           f"program){other_dialects_with_m(w.value, dia.name)}")
            ms.append(w)
            continue
        if w.letter in ax.words:
            pass  # an axis word of the machine
        elif w.letter in ax.lacking:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': {ax.lacking[w.letter]}; not supported")
        elif w.letter in REFUSED_LETTERS:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': {REFUSED_LETTERS[w.letter]}; not supported")
        elif w.letter not in LETTER_RULES:
            raise _Refuse(w.start + 1, f"'{w.letter}{w.text}': unknown word")
        elif w.letter == "T" and not _plain_tool_number(w):
            raise _Refuse(w.start + 1, f"'T{w.text}': a T word of more than {MAX_TOOL_DIGITS} digits (or not a "
                                       "whole number) may select a tool offset (lathe 'TttOO': tool tt, offset "
                                       "OO) that shifts the axes, like G43 H; not supported (write the tool "
                                       f"number alone, at most {MAX_TOOL_DIGITS} digits)")
        if w.letter in by:
            raise _Refuse(w.start + 1, f"repeated '{w.letter}' word")
        by[w.letter] = w
    return by, gs, ms


def _plain_tool_number(w: Word) -> bool:
    """A ``T`` word that can only be a tool number: a whole number of at most
    :data:`MAX_TOOL_DIGITS` digits as written (``T1``, ``T01``, ``T12``; not ``T0101``,
    ``T101``, ``T1.5``, ``T-1``)."""
    digits = w.text.replace(" ", "").replace("\t", "")
    return digits.isdigit() and len(digits) <= MAX_TOOL_DIGITS


def _modal_groups(gs, dia=None) -> dict:
    """``{modal group: (G code, word)}``; two codes of one group on a line are refused (but ``G80`` with
    a motion code where the dialect runs them so: the motion code is kept)."""
    groups = {}
    for code, w in gs:
        grp = ALLOWED_G[code][0] if code in ALLOWED_G else (
            "coords" if dia is not None and code in dia.work_systems else "dialect mode")
        if grp == "motion" and grp in groups and dia is not None and dia.g80_with_motion and "G80" in (
                code, groups[grp][0]):
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
        if code != "G80":
            st.mode = code
        elif not getattr(st.dialect, "g80_keeps_motion", False):
            st.mode = None  # RS274NGC: G80 ends the motion mode; Fanuc group 09: G0-G3 stays (nc_cycles restores it)
    return motion_word


def _check_p_q(st: _State, by: dict, gs, axis_words, arc_words):
    """``P`` only with G4/G64 (or P1 on an arc), ``Q`` only with G64."""
    for letter, allowed_with in (("P", ("G4", "G64", "G54.1", "G154", "G10", "G187")), ("Q", ("G64", "G5.1")), ("H", ("G43",)),
                                 ("L", ("G10",))):
        if letter in by:
            h_alone = letter == "H" and getattr(st.dialect, "h_offset_alone", False)  # Fanuc: H alone in G43 mode
            arc_p1 = letter == "P" and st.mode in ("G2", "G3") and bool(axis_words or arc_words) and by["P"].value == 1
            if not (h_alone or arc_p1 or any(c in allowed_with for c, _ in gs)):
                raise _Refuse(by[letter].start + 1, f"'{letter}{by[letter].text}' outside {'/'.join(allowed_with)}"
                              + (" (or P1 on an arc)" if letter == "P" else "") + (H_HINT if letter == "H" else ""))
    for letter, code in (("D", ("G41", "G42")),):
        if letter in by and not any(c in code for c, _ in gs):
            raise _Refuse(by[letter].start + 1, f"'{letter}{by[letter].text}' outside {'/'.join(code)}")
    loaded = st.dialect is not None and st.dialect.name in LOADED_TOOL_DIALECTS  # resolved by _work_state
    for c, w in gs:
        if c in ("G41", "G42") and "D" not in by and not loaded:
            raise _Refuse(w.start + 1, f"'{c}' without D (the current tool's radius): write '{c} Dn' with the tool "
                                       "table's number n")
    if "G43" in (c for c, _ in gs) and "H" not in by and not loaded:
        w = next(w for c, w in gs if c == "G43")
        raise _Refuse(w.start + 1, "'G43' without H (the current tool's length): write 'G43 Hn' with the tool "
                                   "table's number n")


G80_HINT = " after G80 (Fanuc, Haas, Siemens ISO keep the G0-G3 of before a cycle: name the controller with --dialect)"
H_HINT = ("; Fanuc, Haas, Siemens ISO: an H alone changes the length offset in G43 mode (H0: zero): name the "
          "controller with --dialect")
LOADED_TOOL_DIALECTS = ("linuxcnc",)
"""Dialects whose ``G43`` without ``H`` and ``G41``/``G42`` without ``D`` use the tool in the spindle (LinuxCNC
G-code reference: "G43 ... if H is not given, the current tool's"; "G41 ... D omitted: the current tool")."""
_COLON_NUMBER = re.compile(r"[ \t]*:[ \t]*\d+[ \t]*(?:\([^)]*\)[ \t]*)?")


def _classify(body, idx, st: _State, rapids, block_delete, ax: AxisWords):
    dia = st.dialect
    if dia is not None and ":" in dia.program_number and _COLON_NUMBER.fullmatch(body):
        return "pass", None  # ':1234' program number (ISO code)
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
    _tool_change(st, by, ms)
    groups = _modal_groups(gs, dia)
    if "O" in by:
        if len(words) > 1 and any(w.letter not in ("O", "N") for w in words):
            raise _Refuse(by["O"].start + 1, "'O' word with other words (subroutines and control flow are not supported)")
        return "pass", None
    axis_words = {a: by[a] for a in ax.words if a in by}
    arc_words = {a: by[a] for a in ("I", "J", "K", "R") if a in by}
    changes = any(g in groups for g in ("motion", "plane", "units", "distance", "arc_distance", "nonmodal", "coords",
                                        "length", "cutter", "dialect mode"))
    if bd and block_delete is None and (axis_words or arc_words or changes):
        raise _Refuse(body.index("/") + 1, "block delete '/' on a line that moves or changes modal state; "
                                           "say whether the controller skips it: --block-delete on|off")
    motion_word = _apply_modal(st, groups)
    _check_p_q(st, by, gs, axis_words, arc_words)
    if "nonmodal" in groups and groups["nonmodal"][0] == "G10":
        return _g10(idx, st, groups, by, axis_words, ax), None
    _work_state(idx, st, groups, by, ax)
    if "dialect mode" in groups:
        return _dialect_mode(idx, st, groups, by, axis_words, arc_words), None
    if "nonmodal" in groups and groups["nonmodal"][0] == "G53":
        return _machine_coordinates(idx, st, groups, axis_words, arc_words, ax), None
    if "nonmodal" in groups and groups["nonmodal"][0] in ("G28", "G30"):
        return _reference_return(st, groups, axis_words, arc_words, ax)
    if "nonmodal" in groups and axis_words:
        w = next(iter(axis_words.values()))
        raise _Refuse(w.start + 1, f"axis word '{w.letter}{w.text}' with {groups['nonmodal'][0]} (a dwell time on "
                                   "some controls, not a move)")
    if not axis_words:
        if arc_words:
            w = next(iter(arc_words.values()))
            if st.mode not in ("G2", "G3") or "R" in arc_words:
                raise _Refuse(w.start + 1, f"'{w.letter}{w.text}' without axis words (only a centre-format G2/G3 "
                                           "full circle may omit them)")
            return "move", _move(idx, st, by, axis_words, arc_words, motion_word, rapids, ax)  # a full circle
        return ("state" if changes else "pass"), None
    return "move", _move(idx, st, by, axis_words, arc_words, motion_word, rapids, ax)


def _move(idx, st: _State, by: dict, axis_words, arc_words, motion_word, rapids, ax: AxisWords) -> GMove:
    """The move of a line with axis words in the active motion mode (or a centre-format full circle, whose
    end is its start: RS274NGC, LinuxCNC and Fanuc); advances ``st.pos``."""
    first = min((axis_words or arc_words).values(), key=lambda w: w.start)
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
    kind = {"G0": "rapid", "G1": "linear"}.get(st.mode, "arc")
    compensate = not (kind == "rapid" and rapids == "keep")
    words = dict(axis_words)
    words.update(arc_words)
    if "P" in by and kind == "arc":
        words["P"] = by["P"]
    known = np.isfinite(end)
    if compensate and not known.all():
        missing = ", ".join(a for a, k in zip(ax.words, known) if not k)
        raise _Refuse(first.start + 1, f"'{first.letter}{first.text}': motion before {ax.joined('and')} are all "
                                       f"known (no value yet for {missing})")
    move = GMove(idx, kind, start, end, "inch" if st.inch else "mm", st.incremental, words, motion_word,
                 compensate, known=known)
    if kind == "arc":
        try:
            move.arc = _arc_geometry(st, move, arc_words, scale, ax, first)
        except _Refuse as r:
            raise _Refuse(r.col, f"'{first.letter}{first.text}': {r.msg}") from None
    st.pos = end
    return move


def _reference_return(st, groups, axis_words, arc_words, ax: AxisWords):
    """``G28``/``G30``: the machine goes to a reference position (not a program point, so
    not compensated; the line is written as it is). Accepted bare (all axes) or with zero
    incremental axis words (``G28 G91 Z0``: only Z, with no intermediate move); the axes
    it moves are unknown afterwards, so the next compensated move must give them
    absolutely. An intermediate point (non-zero or absolute words) would be an
    uncompensated program point: refused."""
    code, w = groups["nonmodal"]
    if "motion" in groups:
        raise _Refuse(w.start + 1, f"'{code}' with a motion code on the same line")
    if arc_words:
        a = next(iter(arc_words.values()))
        raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with {code}")
    for a in axis_words.values():
        if not st.incremental or a.value != 0.0:
            raise _Refuse(a.start + 1, f"'{a.letter}{a.text}' with {code}: an intermediate point is an uncompensated "
                                       f"program point; only a bare {code} or zero incremental words "
                                       f"('{code} G91 Z0') are accepted")
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
        {"abs_tol_mm": tol[1] if st.inch else tol[0], "rel_tol": tol[2]}
    return {"ju": ju, "jv": jv, **plane_arc(u0, v0, u1, v1, st.mode, arc_words, (u_c, v_c), st.arc_abs, scale,
                                             first, pair=f"{u_c}/{v_c}", both=f"{u_c} and {v_c}", **tols)}


def plane_arc(u0, v0, u1, v1, mode, arc_words, centre_words, arc_abs, scale, first, pair, both,
              abs_tol_mm: float = ARC_RADIUS_TOL_MM, rel_tol: float | None = None) -> dict:
    """Centre, radii and sweep of a G2/G3 (``mode``) arc from (u0, v0) to (u1, v1) mm in its plane's
    (u, v) coordinates; ``centre_words`` the words giving the centre's u and v offsets (G18: K, I; G17:
    I, J), or ``R``; ``pair`` / ``both`` how the refusals name them. Returns ``uc vc r0 r1 theta0 sweep``."""
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
    if abs(r1 - r0) > abs_tol_mm or (rel_tol is not None and abs(r1 - r0) > rel_tol * max(r0, r1)):
        limit = f"{abs_tol_mm * 1e3:.4g} μm" + (f" or {rel_tol:.2%} of the radius" if rel_tol is not None else "")
        raise _Refuse(first.start + 1, f"arc start and end radii differ by {abs(r1 - r0) * 1e3:.3f} μm "
                                       f"(more than {limit})")
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
    th = g["theta0"] + t * g["sweep"]
    r = g["r0"] + t * (g["r1"] - g["r0"])
    out = move.start[None, :] + t[:, None] * (move.end - move.start)[None, :]
    out[:, g["ju"]] = g["uc"] + r * np.cos(th)
    out[:, g["jv"]] = g["vc"] + r * np.sin(th)
    return out


def arc_segments(move: GMove, tol_mm: float) -> int:
    """Chords needed so the chord sagitta of an arc stays within ``tol_mm`` (≥ 1)."""
    g = move.arc
    r = max(g["r0"], g["r1"])
    if tol_mm >= r:
        return max(1, int(math.ceil(abs(g["sweep"]) / math.pi)))
    step = 2.0 * math.acos(1.0 - tol_mm / r)
    return max(1, int(math.ceil(abs(g["sweep"]) / step - 1e-12)))


# ---------------------------------------------------------------------------- writing

def fmt(v: float, decimals: int) -> str:
    s = f"{v:.{decimals}f}"
    if float(s) == 0.0:
        s = f"{0.0:.{decimals}f}"
    return s


def render_program(program: GProgram, vertices: list, header=(), track: dict | None = None) -> tuple[str, list]:
    """Write the program with each compensated move's vertices.

    ``vertices[k]``: shape (m_k, k_axes) absolute axes (mm, deg; the reader's axis order) for
    the k-th *compensated* move, in order, the last row the move's end. Returns ``(text,
    groups)`` where ``groups[i]`` is the list of output lines that source line ``i`` became (the
    header lines are not in ``groups``). Lines of class ``pass``/``state``/``skipped`` and kept
    rapids come back byte for byte; on a compensated line only the axis numbers change (missing
    axes are appended after the last axis word, since a correction moves every compensated
    axis; a kept word, :class:`AxisWords`, keeps its text where its value is unchanged and is
    appended only where it moves); an arc line becomes ``G1`` (its ``I J K R P`` words removed)
    and each extra vertex is an added line of the axis words (``X.. Z.. A..``) after it. ``header`` lines become
    ``(...)`` comments after a leading ``%`` line and a program-number line, if any. Numbers are
    written in the line's own units and distance mode; incremental numbers are differences of
    what was actually written, so rounding never accumulates. ``track`` (a dict): filled with
    ``{line index: (k,) position of the controller running the output after that move}``.
    """
    comp = [m for m in program.moves if m.compensate]
    if len(vertices) != len(comp):
        raise ValueError(f"Expected vertices for {len(comp)} compensated moves, got {len(vertices)}")
    ax = program.axis_words
    k_axes = len(ax.words)
    groups = [[ln] for ln in program.lines]
    ctrl = np.full(k_axes, np.nan)  # where the controller running the output is, mm / deg
    k = 0
    for m in program.moves:
        if not m.compensate:
            ctrl = _kept_position(m, ctrl, ax)
        else:
            q = np.asarray(vertices[k], dtype=float).reshape(-1, k_axes)
            k += 1
            groups[m.index], ctrl = _render_move(program.lines[m.index], m, q, ctrl, ax)
        if track is not None:
            track[m.index] = ctrl
    out = [ln for g in groups for ln in g]
    return _with_header(out, program.notes() + tuple(header)), groups


def _render_move(line: str, m: GMove, q, ctrl, ax: AxisWords):
    """Output lines of one compensated move with vertices ``q`` (m, k), and the controller
    position after them (see :func:`render_program`)."""
    if not np.all(np.isfinite(q)):
        raise ValueError(f"Expected finite vertices, got NaN/inf for line {m.index + 1}")
    body = line.rstrip("\r\n")
    ending = line[len(body):] or "\n"
    written, before = [], []
    for row in q:
        before.append(ctrl)
        vals, ctrl = _written_values(row, ctrl, m, ax)
        written.append(vals)
    first = _rewrite_line(body, m, written[0], before[0], ax)
    # a block-delete move (run under --block-delete off) keeps its '/' on every piece, so
    # that switching block delete on at the controller skips the whole move, not its first piece
    slash = "/" if body.lstrip(" \t").startswith("/") else ""
    if ax.kept:
        extra = [slash + " ".join(f"{a}{vals[j]}" for j, a in enumerate(ax.words) if _needed(j, vals, c0, m, ax))
                 + ending for vals, c0 in zip(written[1:], before[1:])]
    else:  # every word on every added line
        extra = [slash + " ".join(f"{a}{v}" for a, v in zip(ax.words, vals)) + ending for vals in written[1:]]
    if extra and not line.endswith("\n"):
        return [first + ending] + extra[:-1] + [extra[-1][:-len(ending)]], ctrl
    return [first + line[len(body):]] + extra, ctrl


def _with_header(out: list, header) -> str:
    """``out`` (output lines) joined, with ``header`` lines as ``(...)`` comments after a
    leading ``%`` line and a program-number line, if any."""
    head = "".join(f"({_comment_safe(h)})\n" for h in header)
    at = 0  # after a leading '%' line and a program-number line ('O1000 (NAME)')
    if at < len(out) and out[at].strip() == "%":
        at += 1
    if at < len(out) and re.match(r"[ \t]*[Oo][ \t]*\d", out[at]):
        at += 1
    return "".join(out[:at]) + head + "".join(out[at:])


def _comment_safe(text: str) -> str:
    return str(text).replace("(", "[").replace(")", "]").replace("\n", " ")


def _kept_position(m: GMove, ctrl, ax: AxisWords):
    """Controller position after a line written as it was (a kept rapid)."""
    out = ctrl.copy()
    scale = MM_PER_INCH if m.units == "inch" else 1.0
    for j, a in enumerate(ax.words):
        if a in m.words:
            v = m.words[a].value * (1.0 if a in ax.rotary else scale)
            out[j] = out[j] + v if m.incremental else v
    return out


def _written_values(row, ctrl, m: GMove, ax: AxisWords):
    """The numbers written for one vertex ``row`` (k,) (text per axis) and the controller
    position they take it to: the line's units and distance mode."""
    scale = MM_PER_INCH if m.units == "inch" else 1.0
    lin_fmt, rot_fmt = (scale, DECIMALS[m.units]), (1.0, DECIMALS["deg"])  # (scale, decimals)
    vals, new = [], ctrl.copy()
    for j, rotary in enumerate(ax.is_rotary):
        s, dec = rot_fmt if rotary else lin_fmt
        if m.incremental:
            txt = fmt((row[j] - ctrl[j]) / s, dec)
            new[j] = ctrl[j] + float(txt) * s
        else:
            txt = fmt(row[j] / s, dec)
            new[j] = float(txt) * s
        vals.append(txt)
    return vals, new


def _needed(j: int, vals, ctrl_before, m: GMove, ax: AxisWords) -> bool:
    """An axis word a written line must carry: every word that is not kept (the correction moves
    it), a kept one where the line had it or where its written value moves it."""
    a = ax.words[j]
    if not ax.kept or a not in ax.kept or a in m.words:
        return True
    return float(vals[j]) != 0.0 if m.incremental else not (np.isfinite(ctrl_before[j])
                                                           and abs(float(vals[j]) - ctrl_before[j]) < 1e-12)


def _rewrite_line(body: str, m: GMove, vals, ctrl_before, ax: AxisWords) -> str:
    # a kept word whose value is unchanged keeps its text as written (a chain's tool orientation)
    words, kept = m.words, ax.kept
    given = [(j, words[a]) for j, a in enumerate(ax.words) if a in words]
    edits = [(w.num_start, w.num_end, vals[j]) for j, w in given
             if not (kept and w.letter in kept and float(vals[j]) == w.value)]  # (start, end, text)
    last_end = max(w.num_end for w in (dict(given).values() if given else words.values()))  # a full circle: its I J K
    if len(given) < len(ax.words):
        missing = "".join(f" {a}{vals[j]}" for j, a in enumerate(ax.words)
                          if a not in words and (not kept or _needed(j, vals, ctrl_before, m, ax)))
        if missing:
            edits.append((last_end, last_end, missing))
    if m.kind == "arc":
        if m.motion_word is not None:
            edits.append((m.motion_word.start, m.motion_word.num_end, "G1"))
        else:
            first = min(w.start for w in m.words.values())
            edits.append((first, first, "G1 "))
        for a in ("I", "J", "K", "R", "P"):
            if a in m.words:
                w = m.words[a]
                s = w.start - 1 if w.start > 0 and body[w.start - 1] in " \t" else w.start
                edits.append((s, w.num_end, ""))
    for s, e, txt in sorted(edits, key=lambda t: (t[0], t[1]), reverse=True):
        body = body[:s] + txt + body[e:]
    return body


# ---------------------------------------------------------------------------- block-wise (issue 20)
#
# The reader above classifies one line at a time (about 0.25 ms a line). A long program is
# nearly all plain move lines ('N120 G1 X.. Z.. A.. F..', or modal 'X.. Z..') and comments.
# The block-wise reader recognises exactly those lines with two strict patterns, reads their
# numbers in bulk and follows the modal state (motion mode, positions) with vectorised
# forward fills and sums; every other line — and any plain line the bulk step would not read
# exactly as the per-line reader does (no motion mode yet, an arc mode, an axis not yet known)
# — goes through the per-line classifier, in order, with the state it would have had. The
# result (classes, moves, refusals) is the per-line reader's; tests/test_gcode_blockwise.py
# checks that on the corpus and on generated programs.

_BULK_NUM = r"[+-]?(?:\d{1,300}(?:\.\d*)?|\.\d+)"
"""A plain RS274 number, no blanks inside; at most 300 digits before the point, so it is finite."""


@functools.lru_cache(maxsize=16)
def _bulk_move(words: tuple) -> re.Pattern:
    """A plain move line of a machine with the three axis words ``words`` (``("X", "Z", "A")``):
    optional N, optional G0/G1 (G00/G01), then the three axis words in this order (any of them),
    optional F, an optional trailing comment. Upper case, blanks only between words; a number
    followed by blanks and a digit (RS274 reads 'X1 0' as X10) does not match. Group 1 is the G
    word, groups 2-4 the three axis numbers."""
    axes = "".join(rf"(?:{w}({_BULK_NUM})[ \t]*)?" for w in words)
    return re.compile(r"[ \t]*(?:N\d{1,300}[ \t]*)?(?:(G0?[01])[ \t]*)?" + axes + rf"(?:F{_BULK_NUM}[ \t]*)?"
                      r"(?:\([^)]*\)[ \t]*)?(?:;.*)?")
_BULK_PASS = re.compile(r"[ \t]*(?:\([^)]*\)[ \t]*)*(?:;.*)?")
"""A blank or comment-only line (class pass)."""
BULK_MIN_RUN = 32
"""Runs of bulk lines shorter than this go through the per-line classifier (no gain)."""


@dataclass
class MoveTable:
    """The moves of a program as columns, in order (n moves).

    ``line`` (n,) 0-based line; ``kind`` (n,) 0 rapid, 1 linear, 2 arc; ``start``/``end``
    (n, 3) absolute mm / deg (NaN: not known); ``inch``, ``incremental``, ``compensate`` (n,)
    bool; ``known`` (n, 3); ``obj`` (n,) index into ``objects`` (the :class:`GMove` of a move
    read line by line) or -1 for a move read in bulk, whose G word and three axis word
    spans in its line are ``spans`` (n, 4, 2) (-1 where absent).
    """

    line: np.ndarray
    kind: np.ndarray
    start: np.ndarray
    end: np.ndarray
    inch: np.ndarray
    incremental: np.ndarray
    compensate: np.ndarray
    known: np.ndarray
    obj: np.ndarray
    objects: list
    spans: np.ndarray
    cache: dict = field(default_factory=dict, repr=False)  # derived arrays (pathio: path lengths)

    def __len__(self) -> int:
        return self.line.shape[0]

    @classmethod
    def concat(cls, pieces: list, objects: list) -> "MoveTable":
        if not pieces:
            z3 = np.zeros((0, 3))
            return cls(np.zeros(0, np.int64), np.zeros(0, np.int8), z3, z3.copy(), *(np.zeros(0, bool),) * 3,
                       np.zeros((0, 3), bool), np.zeros(0, np.int64), objects, np.zeros((0, 4, 2), np.int32))
        cols = list(zip(*pieces))
        return cls(*(np.concatenate(c) for c in cols[:9]), objects, np.concatenate(cols[9]))


def _piece_from_move(m: GMove, k: int) -> tuple:
    """One table row (the columns of :class:`MoveTable`, ``objects`` aside) for a per-line move."""
    kind = {"rapid": 0, "linear": 1, "arc": 2}[m.kind]
    return (np.array([m.index]), np.array([kind], np.int8), m.start[None, :].astype(float),
            m.end[None, :].astype(float), np.array([m.units == "inch"]), np.array([m.incremental]),
            np.array([m.compensate]), np.asarray(m.known, bool)[None, :], np.array([k]),
            np.full((1, 4, 2), -1, np.int32))


class _LazyMoves(Sequence):
    """``GProgram.moves`` of a block-wise read program: the :class:`GMove` of each move, built
    from the table when first asked for (a bulk move's words are re-read from its line)."""

    def __init__(self, table: MoveTable, lines: list, words: tuple):
        self._t, self._lines, self._words, self._cache = table, lines, words, {}

    def __len__(self) -> int:
        return len(self._t)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        k = range(len(self))[k]
        if k not in self._cache:
            self._cache[k] = self._build(k)
        return self._cache[k]

    def _build(self, k: int) -> GMove:
        t = self._t
        if t.obj[k] >= 0:
            return t.objects[t.obj[k]]
        i = int(t.line[k])
        body = self._lines[i].rstrip("\r\n")
        words = {}
        for j, a in enumerate(self._words):
            s, e = (int(v) for v in t.spans[k, j + 1])
            if s >= 0:
                words[a] = Word(a, float(body[s:e]), body[s:e], s - 1, s, e)
        gs, ge = (int(v) for v in t.spans[k, 0])
        motion = Word("G", float(body[gs + 1:ge]), body[gs + 1:ge], gs, gs + 1, ge) if gs >= 0 else None
        return GMove(i, "rapid" if t.kind[k] == 0 else "linear", t.start[k].copy(), t.end[k].copy(),
                     "inch" if t.inch[k] else "mm", bool(t.incremental[k]), words, motion,
                     bool(t.compensate[k]), known=t.known[k].copy())


def _forward_fill(values, given, initial):
    """Per column, the last given value up to each row (``initial`` before the first), (m, 3)."""
    m = values.shape[0]
    out = np.empty_like(values)
    rows = np.arange(m)
    for j in range(values.shape[1]):
        last = np.maximum.accumulate(np.where(given[:, j], rows, -1))
        out[:, j] = np.where(last >= 0, values[np.maximum(last, 0), j], initial[j])
    return out


class _Lines(Sequence):
    """``GProgram.lines`` of a block-wise read file: each line (its ending kept) cut from the
    file's text when asked for, as :func:`split_lines` cuts them."""

    def __init__(self, text: str, starts, stops):
        self._text, self._starts, self._stops = text, starts, stops

    def __len__(self) -> int:
        return self._starts.size

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = range(len(self))[i]
        return self._text[self._starts[i]:self._stops[i]]

    def __iter__(self):
        text = self._text
        for s, e in zip(self._starts.tolist(), self._stops.tolist()):
            yield text[s:e]


def _parse_blockwise(path: Path, rapids: str, block_delete, data: bytes, ax: AxisWords, dia=None) -> GProgram:
    buf = np.frombuffer(data, np.uint8)
    starts, ends = gscan.line_bounds(buf)
    lines = _Lines(data.decode("latin-1"), starts, np.append(starts[1:], buf.size))
    n = len(lines)
    kind, spans_all, vals_all = gscan.scan_lines(buf, starts, ends, ax.words)
    bulk_move = _bulk_move(ax.words)
    linear = ~np.array(ax.is_rotary)  # the columns scaled by the line's units (mm or inch)
    ask = np.flatnonzero(kind == gscan.KIND_ASK)
    for i in ask.tolist():  # lines the kernel leaves to the patterns themselves
        body = lines[i].rstrip("\r\n")
        m = bulk_move.fullmatch(body)
        if m is not None and m.lastindex is not None and m.lastindex >= 2:
            kind[i] = gscan.KIND_MOVE
            spans_all[i] = np.array(m.regs[1:5], dtype=np.int32)
            for j in range(3):
                if m.start(j + 2) >= 0:
                    vals_all[i, j] = float(m.group(j + 2))
        else:
            kind[i] = gscan.KIND_PASS if _BULK_PASS.fullmatch(body) else gscan.KIND_OTHER
    is_move = kind == gscan.KIND_MOVE
    bulk = is_move | (kind == gscan.KIND_PASS)
    mlines = np.flatnonzero(is_move)
    spans = spans_all[mlines]
    vals = vals_all[mlines]
    del spans_all, vals_all
    gcode = np.full(mlines.size, -1, np.int8)  # -1: no G word, 0: G0, 1: G1
    sel = np.flatnonzero(spans[:, 0, 0] >= 0)
    gcode[sel] = buf[starts[mlines[sel]] + spans[sel, 0, 1] - 1] == ord("1")
    given = np.isfinite(vals)

    st = _State(len(ax.words))
    st.dialect = dia
    classes = ["pass"] * n
    moved = []  # ordinals (k0, k1) of the bulk moves read
    pieces, objects = [], []

    def per_line(i: int) -> None:
        try:
            cls, move = _classify(lines[i].rstrip("\r\n"), i, st, rapids, block_delete, ax)
        except _Refuse as r:
            raise _err(path, i + 1, r.col, r.msg) from None
        classes[i] = cls
        if move is not None:
            pieces.append(_piece_from_move(move, len(objects)))
            objects.append(move)

    def bulk_moves(k0: int, k1: int) -> int:
        """Read bulk moves k0..k1-1 (ordinals into mlines); return the ordinal of the first
        that must go through the per-line classifier (k1 if none)."""
        gm = gcode[k0:k1]
        rows = np.arange(k1 - k0)
        last = np.maximum.accumulate(np.where(gm >= 0, rows, -1))
        mode0 = {"G0": 0, "G1": 1}.get(st.mode, -1)
        mode = np.where(last >= 0, gm[np.maximum(last, 0)], mode0)
        scale = MM_PER_INCH if st.inch else 1.0
        v = vals[k0:k1] * np.where(linear, scale, 1.0)
        giv = given[k0:k1]
        bad = mode < 0
        if st.incremental:
            cum = np.cumsum(np.vstack([st.pos[None, :], np.where(giv, v, 0.0)]), axis=0)
            start, end = cum[:-1], cum[1:]
            bad |= (giv & ~np.isfinite(start)).any(axis=1)
        else:
            end = _forward_fill(v, giv, st.pos)
            start = np.vstack([st.pos[None, :], end[:-1]])
        known = np.isfinite(end)
        compensate = ~((mode == 0) & (rapids == "keep"))
        bad |= compensate & ~known.all(axis=1)
        p = int(np.argmax(bad)) if bad.any() else k1 - k0
        if p:
            sl = slice(0, p)
            pieces.append((mlines[k0:k0 + p], mode[sl].astype(np.int8), start[sl], end[sl],
                           np.full(p, st.inch), np.full(p, st.incremental), compensate[sl], known[sl],
                           np.full(p, -1), spans[k0:k0 + p]))
            moved.append((k0, k0 + p))
            st.mode = "G0" if mode[p - 1] == 0 else "G1"
            st.pos = end[p - 1].copy()
        return k0 + p

    # runs of bulk lines long enough to be worth it; everything else line by line
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bulk.astype(np.int8), [0]])))
    runs = [(s, e) for s, e in zip(edges[0::2].tolist(), edges[1::2].tolist()) if e - s >= BULK_MIN_RUN]
    at = 0
    for s, e in runs + [(n, n)]:
        for i in range(at, s):
            per_line(i)
        at = e
        k0, k1 = (int(v) for v in np.searchsorted(mlines, [s, e]))
        while k0 < k1:
            k = bulk_moves(k0, k1)
            if k < k1:  # this line needs the per-line classifier (it refuses or changes the state)
                per_line(int(mlines[k]))
                k += 1
            k0 = k
    if moved:
        cls_arr = np.array(classes, dtype=object)
        cls_arr[np.concatenate([mlines[a:b] for a, b in moved])] = "move"
        classes = cls_arr.tolist()
    table = MoveTable.concat(pieces, objects)
    if not table.compensate.any():
        raise _no_motion(path, ax)
    return GProgram(path, lines, classes, _LazyMoves(table, lines, ax.words), rapids, block_delete, table=table,
                    data=data, axis_words=ax, events=tuple(st.events), g80_line=st.g80_line)


class _Groups(Sequence):
    """``groups`` of :func:`render_table`: output lines per source line, built when asked for.
    ``changed[i]``: the output lines of a move written line by line; ``simple[i]``: a line
    rewritten in bulk, its output ``text[off[i]:off[i + 1]]``; otherwise the line itself."""

    def __init__(self, lines: list, text: str, off, simple, changed: dict):
        self._lines, self._text, self._off, self._simple, self._changed = lines, text, off, simple, changed

    def __len__(self) -> int:
        return len(self._lines)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = range(len(self))[i]
        g = self._changed.get(i)
        if g is not None:
            return list(g)
        if self._simple[i]:
            return [self._text[self._off[i]:self._off[i + 1]]]
        return [self._lines[i]]


def _fixed_str(mag: int, neg: bool, decimals: int) -> str:
    """The text of one number of :func:`gcode_kernels.format_fixed`."""
    d = str(mag).rjust(decimals + 1, "0")
    return f"{'-' if neg else ''}{d[:-decimals]}.{d[-decimals:]}"


def render_table(program: GProgram, axes, counts, header=()) -> tuple:
    """:func:`render_program` of a block-wise read program in absolute mode, in bulk: same text.

    ``axes`` (n, 3): every compensated vertex in order; ``counts`` vertices per compensated
    move. Untouched lines are copied as they are; the three axis numbers of every compensated
    bulk line are formatted column-wise (:func:`gcode_kernels.format_fixed`) and put in place of
    the old ones by a compiled pass over the file's bytes (:func:`gcode_kernels.render_lines`);
    lines with missing axes (appended after the last axis word) or extra vertices (added
    lines), and moves read line by line (arcs, through the per-line writer), are written here
    and copied in. A program with incremental moves needs the controller's position line by
    line: :func:`render_program`.
    """
    t = program.table
    if t is None or t.incremental.any():
        raise ValueError("Expected a block-wise read program without incremental moves")
    axes = np.asarray(axes, dtype=float)
    counts = np.asarray(counts, dtype=np.int64)
    rows = np.flatnonzero(t.compensate)
    if counts.shape != rows.shape or axes.shape != (int(counts.sum()), 3):
        raise ValueError(f"Expected counts for {rows.size} compensated moves and matching axes, "
                         f"got {counts.shape} and {axes.shape}")
    if not np.all(np.isfinite(axes)):
        raise ValueError("Expected finite vertices, got NaN/inf")
    if axes.size and np.abs(axes).max() >= gscan.FIXED_MAX:  # absurd numbers: the per-line writer
        return render_program(program, np.split(axes, np.cumsum(counts)[:-1]), header=header)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    inch_v = np.repeat(t.inch[rows], counts)
    mags = np.empty(axes.shape, np.int64)
    negs = np.empty(axes.shape, bool)
    ax = program.axis_words
    words = ax.words
    # per axis column: decimals written on a mm line, on an inch line (rotary: degrees on both)
    decs = np.array([(DECIMALS["deg"],) * 2 if r else (DECIMALS["mm"], DECIMALS["inch"]) for r in ax.is_rotary])
    for j, rotary in enumerate(ax.is_rotary):
        if rotary:
            mags[:, j], negs[:, j] = gscan.format_fixed(axes[:, j], DECIMALS["deg"])
        elif inch_v.any():
            col = np.where(inch_v, axes[:, j] / MM_PER_INCH, axes[:, j])
            mags[:, j], negs[:, j] = gscan.format_fixed(col, np.where(inch_v, DECIMALS["inch"], DECIMALS["mm"]))
        else:
            mags[:, j], negs[:, j] = gscan.format_fixed(axes[:, j], DECIMALS["mm"])

    def word(v: int, j: int) -> str:
        return _fixed_str(int(mags[v, j]), bool(negs[v, j]), int(decs[j, int(inch_v[v])]))

    lines = program.lines
    data = program.data if program.data is not None else "".join(lines).encode("latin-1")
    buf = np.frombuffer(data, np.uint8)
    n = len(lines)
    if isinstance(lines, _Lines):
        starts, stops = lines._starts, lines._stops
    else:
        starts, _ = gscan.line_bounds(buf)
        stops = np.append(starts[1:], buf.size)
    mode = np.zeros(n, np.int8)
    changed = {}
    bulk = t.obj[rows] < 0
    sp = t.spans[rows]
    for k in np.flatnonzero(~bulk).tolist():  # moves read line by line (arcs, ...)
        m = program.moves[int(rows[k])]
        q = axes[first[k]:first[k] + counts[k]]
        changed[m.index], _ = _render_move(lines[m.index], m, q, np.full(3, np.nan), program.axis_words)
    kb = np.flatnonzero(bulk)
    full = (sp[kb, 1:, 0] >= 0).all(axis=1)  # all three axis words on the line (the common case)
    one = counts[kb] == 1
    fa = kb[full & one]  # the common case, in the compiled pass
    mode[t.line[rows[fa]]] = 1
    row_of_line = np.full(n, -1, np.int64)
    row_of_line[t.line[rows[fa]]] = rows[fa]
    vert_of_row = np.full(len(t), -1, np.int64)
    vert_of_row[rows] = first
    rest = kb[~(full & one)]
    for i, f, c, spans3 in zip(t.line[rows[rest]].tolist(), first[rest].tolist(), counts[rest].tolist(),
                               sp[rest, 1:].tolist()):
        line = lines[i]
        body = line.rstrip("\r\n")
        vals = [word(f, j) for j in range(3)]
        parts, pos = [], 0
        for (sj, ej), v in zip(spans3, vals):  # the words on the line, in place
            if sj >= 0:
                parts += [body[pos:sj], v]
                pos = ej
        parts += [f" {w}{v}" for w, v, (sj, _) in zip(words, vals, spans3) if sj < 0]  # the missing ones appended
        parts.append(body[pos:])
        first_line = "".join(parts)
        if c == 1:
            changed[i] = [first_line + line[len(body):]]
            continue
        ending = line[len(body):] or "\n"
        extra = [" ".join(f"{w}{word(v, j)}" for j, w in enumerate(words)) + ending for v in range(f + 1, f + c)]
        if not line.endswith("\n"):
            g = [first_line + ending] + extra[:-1] + [extra[-1][:-len(ending)]]
        else:
            g = [first_line + line[len(body):]] + extra
        changed[i] = g
    blob_off = np.zeros(n + 1, np.int64)
    blob = np.zeros(0, np.uint8)
    if changed:
        idx = np.array(sorted(changed), dtype=np.int64)
        enc = ["".join(changed[i]).encode("latin-1") for i in idx.tolist()]
        mode[idx] = 2
        size = np.zeros(n, np.int64)
        size[idx] = [len(e) for e in enc]
        blob_off[1:] = np.cumsum(size)
        blob = np.frombuffer(b"".join(enc), np.uint8)
    out, off = gscan.render_lines(buf, starts, stops, mode, row_of_line, vert_of_row, t.spans, mags, negs, inch_v,
                                  decs, blob, blob_off)
    text = out.tobytes().decode("latin-1")
    at = 0  # the header goes after a leading '%' line and a program-number line (as _with_header)
    if at < n and text[off[at]:off[at + 1]].strip() == "%":
        at += 1
    if at < n and re.match(r"[ \t]*[Oo][ \t]*\d", text[off[at]:off[at + 1]]):
        at += 1
    head = "".join(f"({_comment_safe(h)})\n" for h in program.notes() + tuple(header))
    full_text = text[:off[at]] + head + text[off[at]:] if head else text
    return full_text, _Groups(lines, text, off, mode == 1, changed)
