"""Controller state a program runs with: work offsets and tool lengths (read from the shop's files).

The error map lives in machine coordinates; a program is written in part coordinates. The controller
places the program's points in the machine by the active **work offset** (``G54``–``G59``,
``G59.1``–``G59.3``, ``G54.1 Pn``) and the active **tool length** (``G43 Hn``; ``G49`` cancels):

    machine axis = program axis + work offset (every axis word, linear mm, rotary deg)
    machine Z    = ... + tool length (while ``G43 Hn`` is active, LinuxCNC / Fanuc rule)

plus the shift of every work system (``G92`` on LinuxCNC and grbl; ``G52``, the local coordinate shift, which
LinuxCNC keeps in the same registers), and, on LinuxCNC, the work system's XY rotation (``G10 L2 R``, a ``.var``'s
parameter ``5230 + 20·(P−1)``): the program's X Y are turned by it about the work system's origin before the
offsets are added (:meth:`ProgramFrames.place`).
and the tool tip is then the machine file's tool point with its gauge length (the ``[geometry]``
constant ``tool_length``) set to the tool table's length (:func:`machine_with_tool`):
the nominal tip does not depend on the tool, but the angular errors act on its Abbe arm.

On a lathe (a machine file with a ``[spindle]`` and no Y axis) a tool has an offset along X and along Z
(LinuxCNC's tool table ``X``/``Z``, selected by ``G43`` as on a mill; Fanuc/Haas ``TttOO``: tool ``tt``,
offset register ``OO``, ``OO = 00`` cancels): machine X = program X + work offset + tool X, and the same
along Z. The tool tip is the chain's tool point moved back by the offset at the end of the tool side
(:func:`machine_with_lathe_tool`): again the nominal tip is the programmed one and the angular errors act
on the offset's Abbe arm. The X offset is the X axis's offset (a radius: LinuxCNC stores it so in diameter
mode too).

Tables, each recognised by content (never by the file's name): work offsets (:func:`read_work_offsets`: a
LinuxCNC ``.var``, a CSV ``system,x_mm,y_mm,z_mm[,a_deg…]``, or ``machine``), tool tables
(:func:`read_tool_table`: a LinuxCNC ``.tbl`` or a CSV ``tool,length_mm[,radius_mm]``, a lathe's
``tool,x_mm,z_mm[,radius_mm]``), and the program's own ``G10`` lines in program order
(:mod:`compensation.gcode_state`); their formats and each dialect's ``G10 L..`` forms: docs/reference/tool-paths.md.

Every bad row is refused naming the file, the row and the column. A program that selects a work
system or a tool length it was not given is refused naming the word, the line and the option that
supplies it (:func:`program_frames`). A program that selects no work system at all is read in machine
coordinates, as written (the summary says so).
"""
from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from errormap.io import InputError, decode_text, not_a_file

from .nc_expand import source_line
from .nc_notes import event_notes

MACHINE = "machine"
"""``--work-offsets machine``: the program is written in machine coordinates (every offset zero)."""
OFFSET_WORDS = ("X", "Y", "Z", "A", "B", "C", "U", "V", "W")
"""LinuxCNC's order of a work system's nine parameters."""
SYSTEMS = ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")
"""The work systems by their number P = 1..9 (``G10 L2 Pn``, LinuxCNC parameters)."""
VAR_FIRST = 5221
VAR_STEP = 20
"""LinuxCNC: system P's X offset is parameter 5221 + 20·(P − 1), then Y Z A B C U V W, R (rotation) at +9."""
ROTATION = "R"
"""A work system's XY rotation about its origin (deg, counter-clockwise seen from +Z; LinuxCNC ``G10 L2 R``,
parameter ``5230 + 20·(P−1)``), kept in its row under this key; tables without one (CSV): 0."""
VAR_G92 = (5211, 5219)
"""LinuxCNC's G92 offsets (parameters 5211–5219): a non-zero one shifts every system; refused."""
EXTENDED_MAX = 300
"""``G54.1 Pn``: n from 1 to this (Fanuc: 48 or 300, by option)."""
HAAS_MAX = 99
"""Haas ``G154 Pn``: n from 1 to 99; ``G110``–``G129`` are ``G154 P1``–``P20``."""
CSV_OFFSET_COLUMNS = {"x_mm": "X", "y_mm": "Y", "z_mm": "Z", "a_deg": "A", "b_deg": "B", "c_deg": "C"}
_SYSTEM = re.compile(r"(G5[4-9](?:\.[123])?|G154|G1[12]\d)(?:[ \t]*P[ \t]*(\d+))?", re.IGNORECASE)


def system_name(code: str, p: int | None = None) -> str:
    """``G54`` … ``G59.3``, ``G54.1P3`` for an extended system, ``G154P12`` for a Haas one (``G110`` …
    ``G129``: ``G154P1`` … ``P20``)."""
    if code in ("G54.1", "G154"):
        return f"{code}P{p}"
    if re.fullmatch(r"G1[12]\d", code):
        return f"G154P{int(code[1:]) - 109}"
    return code


def parse_system(text: str):
    """A table's system cell (``G55``, ``G54.1P3``, ``G154 P12``, ``G112``) as its name, or None."""
    m = _SYSTEM.fullmatch(text.strip())
    if m is None:
        return None
    code, p = m.group(1).upper(), (int(m.group(2)) if m.group(2) else None)
    if code in ("G54.1", "G154"):
        top = EXTENDED_MAX if code == "G54.1" else HAAS_MAX
        return system_name(code, p) if p is not None and 1 <= p <= top else None
    if p is not None or (code.startswith("G1") and not 110 <= int(code[1:]) <= 129):
        return None
    return system_name(code)


@dataclass(frozen=True)
class WorkOffsets:
    """Work offsets: ``systems`` ``{name: {axis word: value}}`` (mm, deg; absent words are zero);
    ``source`` the file (or :data:`MACHINE`)."""

    systems: dict
    source: str

    @property
    def machine_coordinates(self) -> bool:
        return self.source == MACHINE


@dataclass(frozen=True)
class ToolTable:
    """Tools ``{number: (length_mm, radius_mm)}`` (radius NaN where not given; the length is the Z offset);
    ``x_mm`` ``{number: X offset mm}`` of a lathe's tools (absent: zero); ``source`` the file."""

    tools: dict
    source: str
    x_mm: dict = field(default_factory=dict)


def _refuse(path, row, col, msg):
    return InputError(f"{path}: row {row}, column {col}: {msg}")


def _number(text: str, path, row, col, what) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not np.isfinite(v):
        raise _refuse(path, row, col, f"{what}: expected a number, got {text!r}")
    return v


def _content_lines(path) -> list:
    """``(row, text)`` of the non-blank lines of a text file (1-based rows)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(not_a_file(p))
    text = decode_text(p.read_bytes(), p)
    return [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip()]


def _csv_rows(path, lines):
    """Header cells and the data rows ``(row, cells)`` of a CSV (``#`` lines are comments)."""
    body = [(r, ln) for r, ln in lines if not ln.lstrip().startswith("#")]
    if not body:
        raise InputError(f"{path}: no header row")
    head_row, head = body[0]
    header = [c.strip().lower() for c in next(csv.reader(io.StringIO(head)))]
    rows = [(r, [c.strip() for c in next(csv.reader(io.StringIO(ln)))]) for r, ln in body[1:]]
    for r, cells in rows:
        if len(cells) != len(header):
            raise _refuse(path, r, min(len(cells), len(header)) + 1,
                          f"expected {len(header)} cells (header row {head_row}), got {len(cells)}")
    return header, rows


def read_work_offsets(path) -> WorkOffsets:
    """A work-offset table by content: ``machine`` (:data:`MACHINE`), a LinuxCNC parameter file or
    a CSV (module docstring)."""
    if str(path) == MACHINE:
        return WorkOffsets({name: {} for name in SYSTEMS}, MACHINE)
    lines = _content_lines(path)
    first = next((ln for _, ln in lines if not ln.lstrip().startswith("#")), "")
    if re.fullmatch(r"[ \t]*\d+[ \t]+\S+[ \t]*", first):
        return _read_var(path, lines)
    if "," in first and "system" in [c.strip().lower() for c in first.split(",")]:
        return _read_offset_csv(path, lines)
    raise InputError(f"{path}: row 1: not a work-offset table (expected a LinuxCNC parameter file, lines "
                     "'NUMBER VALUE', or a CSV with the header system,x_mm,y_mm,z_mm[,a_deg,b_deg,c_deg])")


def _read_var(path, lines) -> WorkOffsets:
    params = {}
    for r, ln in lines:
        parts = ln.split()
        if len(parts) != 2 or not parts[0].isdigit():
            raise _refuse(path, r, 1, f"expected 'NUMBER VALUE' (a LinuxCNC parameter line), got {ln.strip()[:40]!r}")
        params[int(parts[0])] = (_number(parts[1], path, r, len(ln) - len(ln.lstrip()) + len(parts[0]) + 2,
                                         f"parameter {parts[0]}"), r)
    for n in range(VAR_G92[0], VAR_G92[1] + 1):
        if n in params and params[n][0] != 0.0:
            raise _refuse(path, params[n][1], 1, f"parameter {n} (a G92 offset) is {params[n][0]:g}: a G92 shift of "
                                                 "every work system is not supported; clear it (G92.1)")
    systems = {}
    for p, name in enumerate(SYSTEMS, start=1):
        base = VAR_FIRST + VAR_STEP * (p - 1)
        if not all(base + j in params for j in range(3)):
            continue
        systems[name] = {w: params[base + j][0] for j, w in enumerate(OFFSET_WORDS) if base + j in params}
        systems[name][ROTATION] = params.get(base + 9, (0.0, 0))[0]  # LinuxCNC's XY rotation (G10 L2 R), deg
    if not systems:
        raise InputError(f"{path}: no work system in the parameter file (G54 is parameters {VAR_FIRST}-{VAR_FIRST + 2})")
    return WorkOffsets(systems, str(path))


def _read_offset_csv(path, lines) -> WorkOffsets:
    header, rows = _csv_rows(path, lines)
    unknown = [c for c in header if c != "system" and c not in CSV_OFFSET_COLUMNS]
    if unknown:
        raise _refuse(path, 1, header.index(unknown[0]) + 1, f"unknown column {unknown[0]!r} (expected system, "
                                                             f"{', '.join(CSV_OFFSET_COLUMNS)})")
    for need in ("x_mm", "y_mm", "z_mm"):
        if need not in header:
            raise InputError(f"{path}: missing column {need!r} (header system,x_mm,y_mm,z_mm[,a_deg,b_deg,c_deg])")
    systems = {}
    js = header.index("system")
    for r, cells in rows:
        name = parse_system(cells[js])
        if name is None:
            raise _refuse(path, r, js + 1, f"system: expected G54..G59, G59.1..G59.3, G54.1Pn (n 1..{EXTENDED_MAX}) or "
                                           f"G154Pn (n 1..{HAAS_MAX}; G110..G129), got {cells[js]!r}")
        if name in systems:
            raise _refuse(path, r, js + 1, f"system {name} given twice")
        systems[name] = {CSV_OFFSET_COLUMNS[c]: _number(cells[j], path, r, j + 1, c)
                         for j, c in enumerate(header) if c != "system"}
    if not systems:
        raise InputError(f"{path}: no data rows")
    return WorkOffsets(systems, str(path))


def read_tool_table(path) -> ToolTable:
    """A tool table by content: a LinuxCNC tool table or a CSV (:data:`TOOL_CSV`)."""
    lines = _content_lines(path)
    first = next((ln for _, ln in lines if not ln.lstrip().startswith(("#", ";"))), "")
    if re.match(r"[ \t]*[Tt][ \t]*\d", first):
        return _read_tbl(path, lines)
    if "," in first and "tool" in [c.strip().lower() for c in first.split(",")]:
        return _read_tool_csv(path, lines)
    raise InputError(f"{path}: row 1: not a tool table (expected LinuxCNC's 'T1 P1 Z+150.0 D10.0 ;comment' lines "
                     f"or a CSV with the header {TOOL_CSV})")


TBL_IGNORED = {"P": "pocket", "I": "front angle", "J": "back angle", "Q": "orientation"}
"""LinuxCNC tool-table words that place no tool point (read and ignored)."""


def _read_tbl(path, lines) -> ToolTable:
    tools, xs = {}, {}
    for r, ln in lines:
        body = ln.split(";")[0]
        if not body.strip():
            continue
        words = {}
        for m in re.finditer(r"\S+", body):
            tok = m.group()
            letter, num = tok[0].upper(), tok[1:]
            col = m.start() + 1
            if letter not in "TPXYZABCUVWDIJQ" or letter in words:
                raise _refuse(path, r, col, f"unexpected word {tok!r} (LinuxCNC tool table: T P X..W D I J Q)")
            words[letter] = (_number(num, path, r, col, f"{letter} word"), col)
        if "T" not in words:
            raise _refuse(path, r, 1, "a tool line without T")
        t, tcol = words["T"]
        if t != int(t) or t < 0:
            raise _refuse(path, r, tcol, f"T{t:g}: expected a tool number")
        for letter, (v, col) in words.items():
            if letter in "YABCUVW" and v != 0.0:
                raise _refuse(path, r, col, f"{letter}{v:g}: a tool offset along {letter} is not supported (only "
                                            "the length Z, a lathe tool's X and the diameter D)")
        if int(t) in tools:
            raise _refuse(path, r, tcol, f"tool {int(t)} given twice")
        d = words.get("D", (float("nan"), 0))[0]
        tools[int(t)] = (words.get("Z", (0.0, 0))[0], d / 2.0)
        if words.get("X", (0.0, 0))[0] != 0.0:
            xs[int(t)] = words["X"][0]
    return ToolTable(tools, str(path), xs)


TOOL_CSV = "tool,length_mm[,radius_mm] (a lathe: tool,x_mm,z_mm[,radius_mm])"
"""The tool table CSV's header forms."""


def _read_tool_csv(path, lines) -> ToolTable:
    header, rows = _csv_rows(path, lines)
    allowed = ("tool", "length_mm", "radius_mm", "x_mm", "z_mm")
    unknown = [c for c in header if c not in allowed]
    if unknown:
        raise _refuse(path, 1, header.index(unknown[0]) + 1, f"unknown column {unknown[0]!r} (expected "
                                                             f"{', '.join(allowed)})")
    lathe = "x_mm" in header or "z_mm" in header
    if lathe and ("length_mm" in header or not ("x_mm" in header and "z_mm" in header)):
        raise InputError(f"{path}: a lathe's tool table has the columns x_mm and z_mm, and no length_mm (header {TOOL_CSV})")
    if not lathe and "length_mm" not in header:
        raise InputError(f"{path}: missing column 'length_mm' (header {TOOL_CSV})")
    tools, xs = {}, {}
    jt, jl = header.index("tool"), header.index("z_mm" if lathe else "length_mm")
    jr = header.index("radius_mm") if "radius_mm" in header else None
    for r, cells in rows:
        t = cells[jt]
        if not t.isdigit():
            raise _refuse(path, r, jt + 1, f"tool: expected a tool number, got {t!r}")
        if int(t) in tools:
            raise _refuse(path, r, jt + 1, f"tool {int(t)} given twice")
        radius = _number(cells[jr], path, r, jr + 1, "radius_mm") if jr is not None else float("nan")
        if radius < 0:
            raise _refuse(path, r, jr + 1, f"radius_mm: expected ≥ 0, got {radius:g}")
        tools[int(t)] = (_number(cells[jl], path, r, jl + 1, header[jl]), radius)
        if lathe:
            jx = header.index("x_mm")
            xs[int(t)] = _number(cells[jx], path, r, jx + 1, "x_mm")
    if not tools:
        raise InputError(f"{path}: no data rows")
    return ToolTable(tools, str(path), xs)


# ---------------------------------------------------------------------------- a program's frames
@dataclass
class ProgramFrames:
    """Where a program's lines run in the machine. Segments in line order: ``first_line`` (m,) the
    0-based line from which segment s holds, ``offset`` (m, k) mm / deg per axis word (the reader's
    order), ``tool_mm`` (m,) the active tool length (NaN: none, the machine file's own tool);
    ``notes``: what the summary records."""

    first_line: np.ndarray
    offset: np.ndarray
    tool_mm: np.ndarray
    notes: dict = field(default_factory=dict)
    radius_mm: np.ndarray | None = None
    """(m,) the cutter radius while G41/G42 is active (NaN: off)."""
    tool_x_mm: np.ndarray | None = None
    """(m,) a lathe tool's X offset while its offset is active (NaN: none; None: no lathe tool in the program)."""
    rot_deg: np.ndarray | None = None
    """(m,) the active work system's XY rotation (deg; LinuxCNC ``G10 L2 R``; None: none anywhere): machine axes
    are the program's X Y turned by it about the work system's origin, then shifted (:meth:`place`)."""

    @property
    def rotated(self) -> bool:
        return self.rot_deg is not None and bool(np.any(self.rot_deg != 0.0))

    def place(self, lines0, q, words) -> np.ndarray:
        """Machine axes (n, k) of program axes ``q`` (n, k) at 0-based lines: X Y turned by the rotation (LinuxCNC
        ``rotate(x, y, rotation_xy)`` before the offsets), then :meth:`shift` added."""
        return _turn_xy(q, self._rot(lines0), words) + self.shift(lines0, words)

    def unplace(self, lines0, m, words) -> np.ndarray:
        """Program axes (n, k) of machine axes ``m`` (n, k): :meth:`place` inverted."""
        return _turn_xy(np.asarray(m, dtype=float) - self.shift(lines0, words), -self._rot(lines0), words)

    def _rot(self, lines0) -> np.ndarray:
        s = np.maximum(np.searchsorted(self.first_line, np.asarray(lines0, dtype=np.int64), side="right") - 1, 0)
        return np.zeros(len(s)) if self.rot_deg is None else self.rot_deg[s]

    def lathe_tool(self, lines0) -> np.ndarray:
        """The active lathe tool offsets (n, 2) mm, X and Z, at 0-based lines (NaN rows: no tool offset active)."""
        s = np.maximum(np.searchsorted(self.first_line, np.asarray(lines0, dtype=np.int64), side="right") - 1, 0)
        if self.tool_x_mm is None:
            return np.full((len(s), 2), np.nan)
        return np.stack([self.tool_x_mm[s], np.where(np.isfinite(self.tool_x_mm[s]), self.tool_mm[s], np.nan)], axis=1)

    def radius(self, lines0) -> np.ndarray:
        """The active cutter radius compensation's radius (n,) mm at 0-based lines (NaN: off)."""
        s = np.maximum(np.searchsorted(self.first_line, np.asarray(lines0, dtype=np.int64), side="right") - 1, 0)
        return self.radius_mm[s]

    def at(self, lines0) -> tuple:
        """``(offset (n, k), tool_mm (n,))`` for 0-based source lines (n,)."""
        s = np.searchsorted(self.first_line, np.asarray(lines0, dtype=np.int64), side="right") - 1
        s = np.maximum(s, 0)
        return self.offset[s], self.tool_mm[s]

    def shift(self, lines0, words) -> np.ndarray:
        """Machine axes minus program axes (n, k) at those lines: the offset plus the tool length on Z (and a
        lathe tool's offset on X)."""
        off, tool = self.at(lines0)
        out = off.copy()
        if "Z" in words:
            out[:, list(words).index("Z")] += np.where(np.isfinite(tool), tool, 0.0)
        if self.tool_x_mm is not None and "X" in words:
            tx = self.lathe_tool(lines0)[:, 0]
            out[:, list(words).index("X")] += np.where(np.isfinite(tx), tx, 0.0)
        return out


def _turn_xy(q, deg, words) -> np.ndarray:
    """``q`` (n, k) with its X Y turned by ``deg`` (n,) about Z (counter-clockwise seen from +Z)."""
    out = np.array(q, dtype=float)
    if not np.any(deg != 0.0):
        return out
    jx, jy = list(words).index("X"), list(words).index("Y")
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    out[:, jx], out[:, jy] = c * q[:, jx] - s * q[:, jy], s * q[:, jx] + c * q[:, jy]
    return out


def lathe_words(words) -> bool:
    """A lathe's axis words (X and Z, no Y, no A or B; C the spindle): a tool offset acts along X and Z."""
    return "X" in words and "Z" in words and not {"Y", "A", "B"} & set(words)


def _offset_vector(values: dict, words) -> np.ndarray:
    return np.array([float(values.get(w, 0.0)) for w in words])


class _Controller:
    """The controller's tables and active frame while :func:`program_frames` walks a program's events."""

    def __init__(self, path, words, offsets: WorkOffsets | None, tools: ToolTable | None):
        self.path, self.words, self.offsets, self.tools = path, words, offsets, tools
        self.table = {k: dict(v) for k, v in (offsets.systems if offsets else {}).items()}
        self.tooltab = {k: v[0] for k, v in (tools.tools if tools else {}).items()}
        self.radii = {k: v[1] for k, v in (tools.tools if tools else {}).items()}
        self.tool_x = dict(tools.x_mm) if tools else {}  # a lathe's tools: X offsets
        self.parts = {}  # Fanuc/Haas G10 L10-L13: {(tool, "length"/"radius"): {"geometry"/"wear": mm}}
        # before any selection the controller runs its power-on G54: unknown (NaN) unless the tables give it
        # (never machine zero: --work-offsets machine says so explicitly; refuse_unknown_frames refuses the rest)
        self.system, self.tool, self.cutter = "G54", None, None
        self.used_systems, self.used_tools = set(), set()
        self.dynamic = []  # (line, text) of the summary's note per G43.1 (dynamic_length)
        self.name = int  # a 1-based line as refusals name it (program_frames: compensation.nc_expand.source_line)
        self.g92, self.g92_stored = np.zeros(len(words)), np.zeros(len(words))  # G92 offset: added to every system

    def offset(self) -> np.ndarray:
        if self.system not in self.table:
            return np.full(len(self.words), np.nan)
        return _offset_vector(self.table[self.system], self.words)

    def lathe(self) -> bool:
        return lathe_words(self.words)

    def rotation(self) -> float:
        """The active work system's XY rotation, deg (NaN: not known; 0 where the tables give none)."""
        return float(self.table[self.system].get(ROTATION, 0.0)) if self.system in self.table else np.nan

    def frame(self) -> tuple:
        """(offset (k,), tool length mm or NaN, cutter radius mm or NaN, a lathe tool's X offset mm or NaN, XY
        rotation deg) now."""
        on = self.tool is not None
        return (self.offset() + self.g92, self.tooltab[self.tool] if on else np.nan,
                self.radii[self.cutter] if self.cutter is not None else np.nan,
                self.tool_x.get(self.tool, 0.0) if on and self.lathe() else np.nan, self.rotation())

    def g92_event(self, kind, value) -> None:
        """``G92`` (``value``: values and the position before, program mm/deg): the offset grows by position minus
        value along those axes; ``G92.1`` zero (stored too), ``G92.2`` zero, ``G92.3`` the stored values."""
        if kind == "g92":
            vals, pos = value
            for a, v in vals.items():
                self.g92[list(self.words).index(a)] += pos[a] - v
            self.g92_stored = self.g92.copy()
        elif kind == "g52":  # G52: the shift along the axes given is the values (LinuxCNC: the G92 registers)
            vals, stores = value
            for a, v in vals.items():
                self.g92[list(self.words).index(a)] = v
            if stores:
                self.g92_stored = self.g92.copy()
        elif kind == "shift-end":  # M2/M30 with a shift in force: cleared or kept by the controller's parameter
            self.g92 = np.full(len(self.words), np.nan)
        else:
            self.g92 = self.g92_stored.copy() if kind == "g92.3" else np.zeros(len(self.words))
            if kind == "g92.1":
                self.g92_stored = np.zeros(len(self.words))

    def select_system(self, value, where) -> None:
        offsets, table = self.offsets, self.table
        if value not in table and offsets is not None and offsets.machine_coordinates:
            table[value] = {}  # machine coordinates: every system's offset is zero, extended ones too
        if value not in table:
            if offsets is None:
                raise InputError(f"{where}: selects the work offset {value}; no table given: --work-offsets FILE "
                                 "(.var/CSV), G10 L2, or --work-offsets machine (machine coordinates)")
            raise InputError(f"{where}: the work offset {value} is not in {offsets.source} (nor set by a G10 L2 "
                             "line before it): give it in --work-offsets")
        if not np.isfinite(table[value].get(ROTATION, 0.0)):
            raise InputError(f"{where}: the work offset {value} was set by G10 L2 without R, and its XY rotation is "
                             f"the controller's: give {value} in --work-offsets (a .var) or R on the G10 line")
        unset = [w for w in self.words if not np.isfinite(table[value].get(w, 0.0))]
        if unset:
            raise InputError(f"{where}: the work offset {value} was set by G10 along some axes only; its "
                             f"{' '.join(unset)} are the controller's: give {value} in --work-offsets (or every "
                             "axis on the G10 line)")
        self.system = value
        self.used_systems.add(value)

    def select_tool(self, value, where) -> None:
        if value is not None and value not in self.tooltab:
            text = where.rsplit("'", 2)[-2]  # the event's word ('G43 H1', 'T0202')
            what = f"lathe tool offset {value:02d}" if text.startswith("T") else f"tool length offset H{value}"
            raise InputError(f"{where}: {what}: " + _unknown_tool(value, self.tools, self.parts))
        if value is not None and "Z" not in self.words:
            raise InputError(f"{where}: a tool length offset acts on Z; the machine has no Z axis")
        if value is not None and self.tool_x.get(value, 0.0) != 0.0 and not self.lathe():
            raise InputError(f"{where}: tool {value} has an X offset of {self.tool_x[value]:g} mm in "
                             f"{self.tools.source}: a tool offset along X is read on a lathe only (X, Z and C)")
        self.tool = value
        if value is not None:
            self.used_tools.add(value)

    def dynamic_length(self, value, line, where) -> None:
        """LinuxCNC ``G43.1`` (:func:`compensation.gcode_state.dynamic_length`, ``value`` {axis: mm}): the active
        tool's offsets replaced along the axes given (the others kept; none active: 0), as a tool of its own."""
        on, key = self.tool is not None, ("G43.1", line + 1)  # a tool of its own, keyed by its line
        self.tooltab[key] = value.get("Z", self.tooltab[self.tool] if on else 0.0)
        self.tool_x[key] = value.get("X", self.tool_x.get(self.tool, 0.0) if on else 0.0)
        self.tool = key
        self.dynamic.append((line + 1, f"Z {self.tooltab[key]:g}" + (f", X {self.tool_x[key]:g}" * self.lathe())))

    def select_cutter(self, value, where, nose: bool = False) -> None:  # nose: a T register's (ttoo_lathe)
        if value is not None and not np.isfinite(self.radii.get(value, np.nan)):
            if nose:
                raise InputError(f"{where}: the nose radius of offset register {value:02d} is not known: the tool "
                                 f"table's radius_mm column gives it (--tool-table, row tool {value})")
            raise InputError(f"{where}: cutter radius compensation D{value}: the radius of tool {value} is not "
                             "known: give it in --tool-table (radius_mm, or D of a .tbl) or G10 L1 P.. R.."
                             + _part_note(value, "radius", self.parts))
        self.cutter = value

    def g10(self, kind, value, where) -> None:
        """A ``G10`` line's data (:mod:`compensation.gcode_state`) into the tables."""
        words = self.words
        if kind == "g10-work":
            _set_offset(self.table, value[0], value[1], words, self.offsets, value[3])
            if value[2] is not None:
                self.table[value[0]][ROTATION] = value[2]
            if value[0] == self.system and self.words_rotate() and not np.isfinite(self.rotation()):
                raise InputError(f"{where}: sets the active work offset {value[0]} without R, whose XY rotation is the "
                                 f"controller's: give {value[0]} in --work-offsets (a .var) or R on the G10 line")
        elif kind == "g10-here":
            _set_offset(self.table, value[0], _offset_here(value, self.offset(), words, where, self.system), words,
                        self.offsets)
        elif kind == "g10-tool":
            self.tooltab[value[0]] = value[1][0]
            if np.isfinite(value[1][1]):
                self.radii[value[0]] = value[1][1]
        elif kind == "g10-tool-here":
            now = self.tooltab.get(self.tool, 0.0) if self.tool is not None else 0.0
            self.tooltab[value[0]] = _tool_here(value, self.offset(), self.table, now, words, where, self.system)
            self.parts.pop((value[0], "length"), None)
            if np.isfinite(value[4]):
                self.radii[value[0]] = value[4]
        elif kind == "g10-tool-part":
            n, what, part, mm = value
            have = self.parts.setdefault((n, what), {})
            have[part] = mm
            dest = self.tooltab if what == "length" else self.radii
            if len(have) == 2:
                dest[n] = have["geometry"] + have["wear"]
            else:
                dest.pop(n, None)

    def words_rotate(self) -> bool:
        return "X" in self.words and "Y" in self.words

    def apply(self, event) -> None:
        """One event of :attr:`compensation.gcode.GProgram.events` ``(line, column, kind, value, text)``."""
        line, col, kind, value, text = event
        where = f"{self.path}: line {line + 1}, column {col}: '{text}'"
        select = {"system": self.select_system, "tool": self.select_tool, "cutter": self.select_cutter,
                  "nose": lambda v, w: self.select_cutter(v, w, nose=True)}
        if kind in select:
            select[kind](value, where)
        elif kind == "tool-dynamic":
            self.dynamic_length(value, line, where)
        elif kind == "cutter-dynamic":  # G41.1/G42.1 (gcode_state.dynamic_cutter): the line's radius, a tool's own
            self.cutter = ("G41.1/G42.1", line + 1)
            self.radii[self.cutter] = value
        elif kind.startswith("g10-"):
            self.g10(kind, value, where)
            self.check_active(where)
        elif kind.startswith("g92") or kind in ("g52", "shift-end"):
            if kind != "shift-end" and self.rotation() != 0.0:
                raise InputError(f"{where}: a G92/G52 shift while the work system {self.system} is rotated (G10 L2 "
                                 "R): LinuxCNC adds it to rotated coordinates; cancel the rotation (R0) first")
            self.g92_event(kind, value)

    def check_active(self, where) -> None:
        """The active tool and cutter radius are still known after a G10 line changed the tables (a ``G43.1``'s or
        ``G41.1``/``G42.1``'s, the program's own values, named by its line: :meth:`named`)."""
        if self.tool is not None and self.tool not in self.tooltab:
            raise InputError(f"{where}: the length of the active tool {self.named(self.tool, '{0} (G43 H{0})')} is "
                             "no longer known" + self.why(self.tool, ": " + _unknown_tool(self.tool, self.tools,
                                                                                          self.parts)))
        if self.cutter is not None and not np.isfinite(self.radii.get(self.cutter, np.nan)):
            raise InputError(f"{where}: the radius of the active cutter compensation {self.named(self.cutter, 'D{0}')}"
                             " is no longer known" + self.why(self.cutter, _part_note(self.cutter, "radius",
                                                                                      self.parts)))

    def named(self, key, table: str) -> str:
        """A tool or cutter key as a refusal names it: a table's number by ``table`` (``'{0} (G43 H{0})'``:
        ``'3 (G43 H3)'``), a ``G43.1``'s or ``G41.1``/``G42.1``'s by its line (:attr:`name`): ``'set by the G43.1 on
        line 12 (expanded line 40)'``."""
        return f"set by the {key[0]} on line {self.name(key[1])}" if isinstance(key, tuple) else table.format(key)

    @staticmethod
    def why(key, text: str) -> str:
        """``text`` (what gives a table's tool) for a table's key, nothing for a program's own (a tuple)."""
        return "" if isinstance(key, tuple) else text


def program_frames(program, offsets: WorkOffsets | None, tools: ToolTable | None) -> ProgramFrames:
    """The frames of a parsed program (:attr:`compensation.gcode.GProgram.events`, in line order)
    with the tables given (None: not given). Refuses (InputError: file, line, column, word, the
    option that supplies it) a work system or a tool not in the tables nor set by the program's own
    ``G10`` lines before it."""
    path, words = program.path, program.axis_words.words
    # in line order (stable: a line's own order kept): cycle notes are appended after the reading (nc_contour._carry)
    events = sorted(getattr(program, "events", ()) or (), key=lambda e: e[0])
    _refuse_set_from_compensated(program, events)
    c = _Controller(path, words, offsets, tools)
    c.name = partial(source_line, program)
    first, frames = [0], [c.frame()]
    for event in events:
        c.apply(event)
        first.append(event[0])
        frames.append(c.frame())
    notes = {"work_offsets": offsets.source if offsets else "program G10 lines",
             "work_systems_used": sorted(c.used_systems),
             "tool_table": tools.source if tools else None,
             "tools_used": {int(t): float(c.tooltab[t]) for t in sorted(c.used_tools)}}
    offsets = {s: [float(v) for v in _offset_vector(c.table.get(s, {}), words)] for s in sorted(c.used_systems)}
    notes.update(event_notes(program, events, c.dynamic, offsets))
    offs, tls, rads, txs, rots = zip(*frames)
    rots = np.array(rots, dtype=float)
    if np.any(np.nan_to_num(rots) != 0.0):
        notes["xy_rotation_deg"] = {s: float(c.table[s].get(ROTATION, 0.0)) for s in sorted(c.used_systems)}
        at = f"{path}: line {first[int(np.flatnonzero(np.nan_to_num(rots) != 0.0)[0])] + 1}"
        if not c.words_rotate():
            raise InputError(f"{at}: a rotated work system (XY rotation {notes['xy_rotation_deg']} deg) on a machine "
                             f"without X and Y axis words ({' '.join(words)}): set the rotation to 0")
        if getattr(program, "tcp", None) is not None:
            raise InputError(f"{at}: a rotated work system (G10 L2 R, or a .var's rotation) with tool-centre-point "
                             "lines: not supported; cancel the rotation (R0)")
    if c.lathe() and c.used_tools:
        notes["tool_x_used"] = {int(t): float(c.tool_x.get(t, 0.0)) for t in sorted(c.used_tools)}
    return ProgramFrames(np.array(first, dtype=np.int64), np.array(offs).reshape(len(first), len(words)),
                         np.array(tls, dtype=float), notes, np.array(rads, dtype=float),
                         np.array(txs, dtype=float) if c.lathe() and (c.used_tools or c.dynamic) else None,
                         rots if np.any(rots != 0.0) else None)


FROM_POSITION = ("g92", "g10-here", "g10-tool-here")
"""Events whose offset the controller takes from its current position (``G92``, LinuxCNC ``G10 L20``/``L10``/
``L11``): running the written program, that position is the written end of the move before."""


def _refuse_set_from_compensated(program, events) -> None:
    """Refuse an offset set from the current position right after a compensated move: the controller would
    take it from the compensated position (micrometres off the programmed one) and shift every later move by
    that much. After a move written unchanged (a ``G0`` kept by ``--rapids keep``) the two are the same."""
    t = program.table
    if t is not None:
        lines, comp = np.asarray(t.line), np.asarray(t.compensate, dtype=bool)
    else:
        lines = np.array([m.index for m in program.moves], dtype=np.int64)
        comp = np.array([m.compensate for m in program.moves], dtype=bool)
    for line, col, kind, _, text in events:
        k = int(np.searchsorted(lines, line)) - 1
        if kind in FROM_POSITION and k >= 0 and comp[k]:
            raise InputError(f"{program.path}: line {line + 1}, column {col}: '{text}' takes its offset from the current "
                             "position, the end of the compensated move of line "
                             f"{source_line(program, int(lines[k]) + 1)} (every later move would shift by its "
                             "correction): reach it by a G0 kept with --rapids keep")


def _set_offset(table, name, vals, words, offsets, rotates: bool = False) -> None:
    """Work system ``name``'s words ``vals`` set by a G10 line; a system not yet known gets the others
    unknown (NaN: the controller's stored values; its XY rotation too where the dialect has one, ``rotates``), or
    zero with ``--work-offsets machine``."""
    if name not in table:
        zero = offsets is not None and offsets.machine_coordinates
        table[name] = {} if zero else {w: np.nan for w in words} | ({ROTATION: np.nan} if rotates else {})
    table[name].update(vals)


def _offset_here(value, active_off, words, where, system) -> dict:
    """LinuxCNC/grbl ``G10 L20``: the offset that makes the current position read the values. The
    machine position is program + active offset (+ the tool length, the same before and after)."""
    name, vals, pos, active = value
    out = {}
    for a, v in vals.items():
        off = active_off[list(words).index(a)]
        if not np.isfinite(off):
            raise InputError(f"{where}: sets {name} from the current position in the active work system {system}, "
                             f"whose {a} offset is not known: give {system} in --work-offsets")
        out[a] = pos[a] + off - v
    return out


def _tool_here(value, active_off, table, tool_now_mm, words, where, system) -> float:
    """LinuxCNC ``G10 L10`` (``ref`` None: in the active system) / ``L11`` (in ``G59.3``): the length that
    makes the current Z read the value. Machine Z = program Z + offset Z + tool length."""
    n, z_value, z_pos, ref, _ = value
    jz = list(words).index("Z")
    off = active_off[jz]
    ref_off = off if ref is None else (_offset_vector(table[ref], words)[jz] if ref in table else np.nan)
    for o, s in ((off, system), (ref_off, ref or system)):
        if not np.isfinite(o):
            raise InputError(f"{where}: sets tool {n} from the current Z, which needs the Z offset of {s}: give {s} "
                             "in --work-offsets")
    return float(z_pos + off + tool_now_mm - ref_off - z_value)


def _part_note(n, what, parts) -> str:
    have = parts.get((n, what), {})
    if not have:
        return ""
    missing = ({"geometry", "wear"} - set(have)).pop()
    return (f"; the program sets its {what} {next(iter(have))} only (G10 L1x) and the {missing} is in the "
            f"controller's table: set the {missing} in the program too")


def _unknown_tool(n, tools, parts) -> str:
    src = f"the tool table {tools.source}" if tools else "no tool table was given"
    return (f"tool {n} is not known ({src}): give it in --tool-table FILE (.tbl or CSV) or G10 L1 P{n} Z.. before it"
            + _part_note(n, "length", parts))


def refuse_unknown_frames(program, frames: ProgramFrames, offsets: WorkOffsets | None, tables: bool = True) -> None:
    """Refuse (InputError: file, line, the option that supplies it) a program whose moves run in a work
    system whose offset is not known. Without a table (``offsets`` None) every move counts: a
    controller runs a program in its active work system (G54 at power-on), never at machine zero, so
    only the program's own ``G10 L2`` lines can place it; with a table, the compensated moves.
    ``tables``: the machine takes an offset table (False: only ``--work-offsets machine``, the grinder)."""
    t = program.table
    if t is not None:
        lines = t.line if offsets is None else t.line[t.compensate]
    else:
        lines = np.array([m.index for m in program.moves if offsets is None or m.compensate], dtype=np.int64)
    unknown = ~np.isfinite(frames.at(lines)[0]).all(axis=1) | ~np.isfinite(frames._rot(lines))
    if not unknown.any():
        return
    first = int(lines[np.argmax(unknown)])
    where = f"{program.path}: line {first + 1}"
    end = next((e for e in (getattr(program, "events", ()) or ()) if e[2] == "shift-end" and e[0] < first), None)
    if end is not None:
        raise InputError(f"{where}: a move after '{end[4]}' of line {source_line(program, end[0] + 1)}, with a G52/G92 "
                         "shift in force: whether the program end clears it is the controller's parameter or version; "
                         "cancel the shift (G52 X0 Y0 Z0, G92.1) before the program end")
    if offsets is None:  # (program_frames refused any other system no G10 L2 set: this is the first move)
        give = "--work-offsets FILE, or --work-offsets machine" if tables else "--work-offsets machine"
        raise InputError(f"{where}: the first move, with no work offset table (a controller runs G54 at power-on, "
                         f"not machine zero): give {give} if the program is written in machine coordinates")
    raise InputError(f"{where}: a move in the controller's power-on work system G54, which {offsets.source} does not "
                     "give: give G54 in --work-offsets (or select a work system before the first move)")


# ---------------------------------------------------------------------------- the chain at a tool length
TOOL_LENGTH_KEY = "tool_length"
"""The ``[geometry]`` constant a machine-tool file's tool chain ends with (``tz = "-tool_length"``): the
gauge length of its tool, spindle nose to tool point; a tool table's length replaces it."""


def machine_with_tool(machine, length_mm: float):
    """The machine-tool chain ``machine`` with its tool's gauge length set to ``length_mm`` (its file read
    again with ``[geometry] tool_length`` replaced; the same file, checked by its sha256). A machine whose
    file declares no ``tool_length`` raises ``ValueError``."""
    if TOOL_LENGTH_KEY not in getattr(machine, "geometry", {}):
        raise ValueError(f"the machine {machine.name!r} declares no [geometry] {TOOL_LENGTH_KEY} (the gauge length its "
                         "tool chain ends with): a tool length offset cannot be applied to it")
    doc = _machine_doc(machine)
    from errormap.machine_tool import parse_machine_tool
    doc["geometry"][TOOL_LENGTH_KEY] = float(length_mm)
    return parse_machine_tool(doc, machine.path, machine.sha256)


def _machine_doc(machine) -> dict:
    """The TOML document of ``machine``'s file, read again (the same file: checked by its sha256)."""
    import hashlib
    import tomllib
    raw = Path(machine.path).read_bytes()
    if machine.sha256 and hashlib.sha256(raw).hexdigest() != machine.sha256:
        raise ValueError(f"{machine.path}: the machine file changed since it was loaded")
    return tomllib.loads(raw.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))


def field_with_tool(field_, machine_at_tool):
    """The error field ``field_`` evaluated on ``machine_at_tool`` (:func:`machine_with_tool`): the same
    elements (and effects) at the other tool point. Fields that are element sets
    (:class:`errormap.chain_field.ChainField`) or simulated truths; any other raises ``TypeError``."""
    import dataclasses

    from errormap.chain_field import ChainField
    if isinstance(field_, ChainField):
        return ChainField(machine_at_tool, field_.elements)
    truth = getattr(field_, "truth", None)
    if truth is not None and hasattr(truth, "effects"):
        return type(field_)(dataclasses.replace(truth, machine=machine_at_tool))
    raise TypeError(f"a {type(field_).__name__} cannot be evaluated at another tool length (an element set can)")


def machine_with_lathe_tool(machine, x_mm: float, z_mm: float):
    """The chain ``machine`` (a lathe's) with its tool point moved back by a lathe tool's offsets: two
    translations (−``x_mm`` along x, −``z_mm`` along z) appended at the end of the tool side, where the
    controller's offset (machine X, Z = program X, Z + offset) puts the tool tip (its file read again, the
    same file, checked by its sha256). Zero offsets give the machine's own tool point."""
    doc = _machine_doc(machine)
    from errormap.machine_tool import parse_machine_tool
    doc["tool"] = list(doc["tool"]) + [{"tx": -float(x_mm)}, {"tz": -float(z_mm)}]
    return parse_machine_tool(doc, machine.path, machine.sha256)
