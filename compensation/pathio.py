"""Tool-path files: CSV and G-code readers and writers.

Formats (docs/schemas.md and docs/toolpaths.md):

* **CSV, axis commands** — columns ``x_mm, z_mm, a_deg`` (absolute mm / deg; A may run
  past 360° on multi-turn paths). The program means the nominal tool points
  ``forward(axes)``; those are the targets.
* **CSV, WCS targets** — columns ``px_mm, py_mm, pz_mm``. The targets are the values;
  the nominal axes are ``inverse(targets)`` with A unwrapped along the path.
  (A file with both sets of columns is refused as ambiguous.) Extra columns and leading
  ``#`` comment lines are kept.
* **G-code** — any file whose name does not end in ``.csv``. ``G0``/``G1`` (``G00``/``G01``)
  lines with ``X``, ``Z``, ``A`` words in absolute mm / deg are the motion; every other
  line, comment and word passes through unchanged, byte for byte (the file is handled
  as Latin-1, so any bytes survive; line endings and ``N`` line numbers are kept).
  Motion modes are modal: a line with only axis words moves in the last ``G0``/``G1``
  mode; axes a line does not give keep their previous values, so every motion line's
  target is the full ``(x, z, a)``.

  Refused with :class:`~errormap.io.InputError` naming the file and the line (1-based):
  an axis word without a plain number (parameters ``#1``, expressions ``[...]``),
  a repeated axis word, two motion codes on one line, axis words under ``G2``/``G3`` or
  any other motion mode than ``G0``/``G1``, axis words with no motion mode yet, axis
  words under ``G91`` (incremental) or ``G20`` (inch), axis words with a non-modal code
  that gives them another meaning (``G4 G10 G28 G30 G52 G53 G92``), a ``G`` word without a
  number, an unclosed ``(`` comment, a motion line before ``X``, ``Z`` and ``A`` are all
  known, and a file with no motion at all.

Writers (:func:`write_compensated`) produce the compensated program in the input's own
format, atomically (temporary file + rename, :func:`errormap.io.atomic_write`): CSV axis
files get new ``x_mm, z_mm, a_deg``; CSV target files get the compensated WCS commands
``p_r`` in ``px_mm, py_mm, pz_mm`` (the controller's post-processor then does the rest);
G-code gets new ``X Z A`` numbers on each motion line — words the line did not have are
appended after its last axis word, since the correction moves all three axes.
"""
from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import InputError, atomic_write, read_table
from errormap.kinematics import forward, inverse

AXIS_COLUMNS = ("x_mm", "z_mm", "a_deg")
TARGET_COLUMNS = ("px_mm", "py_mm", "pz_mm")
GCODE_AXES = ("X", "Z", "A")
DECIMALS_MM = 6   # 1 nm
DECIMALS_DEG = 6  # 1e-6 deg: 1 nm at 57 mm from the A axis

# G codes whose axis words are not a motion target in program coordinates
_NONMODAL_AXIS_G = {4.0: "G4", 10.0: "G10", 28.0: "G28", 30.0: "G30", 52.0: "G52", 53.0: "G53", 92.0: "G92"}
_MOTION_G = {0.0, 1.0, 2.0, 3.0, 33.0, 38.2, 38.3, 38.4, 38.5, 73.0, 76.0, 80.0, 81.0, 82.0, 83.0, 84.0,
             85.0, 86.0, 87.0, 88.0, 89.0}
_NUMBER = re.compile(r"[ \t]*([+-]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class GMotion:
    """One motion line: ``index`` into the program's lines, ``mode`` 0 or 1, and the
    character spans ``(start, end)`` of each axis word's number on that line."""

    index: int
    mode: int
    spans: dict


@dataclass
class GCodeProgram:
    """A parsed G-code file: its lines (Latin-1 text with their line endings) and motion."""

    path: Path
    lines: list
    motions: list
    positions: np.ndarray  # (n, 3) x_mm, z_mm, a_deg of each motion line

    @property
    def line_numbers(self) -> np.ndarray:
        """1-based file line of each motion, shape (n,)."""
        return np.array([m.index + 1 for m in self.motions], dtype=int)


@dataclass
class ToolPath:
    """A tool path read from a file.

    kind : ``"csv-axes"``, ``"csv-targets"`` or ``"gcode"``
    axes : shape (n, 3)         nominal axis commands (x_mm, z_mm, a_deg)
    targets_mm : shape (n, 3)   the WCS targets the program means
    lines : shape (n,)          file line (1-based) of each point
    """

    path: Path
    kind: str
    axes: np.ndarray
    targets_mm: np.ndarray
    lines: np.ndarray
    source: object = field(default=None, repr=False)

    def __len__(self) -> int:
        return self.axes.shape[0]


# ----------------------------------------------------------------------------- G-code

def _split_lines(text: str) -> list:
    """Lines with their ``\\n`` endings kept; only ``\\n`` ends a line (a ``\\r`` stays with it)."""
    parts = text.split("\n")
    lines = [p + "\n" for p in parts[:-1]]
    if parts[-1]:
        lines.append(parts[-1])
    return lines


def _scan_words(path, lineno: int, body: str):
    """Yield ``(letter_upper, value_or_None, start, end)`` for G/X/Z/A words outside comments.

    ``start, end`` span the number. Raises InputError for an unclosed comment or a G/X/Z/A
    word without a plain number.
    """
    i, n = 0, len(body)
    while i < n:
        c = body[i]
        if c == "(":
            j = body.find(")", i + 1)
            if j < 0:
                raise InputError(f"{path}: line {lineno}: unclosed '(' comment")
            i = j + 1
            continue
        if c == ";":
            return
        u = c.upper()
        if u in ("G", "X", "Z", "A"):
            m = _NUMBER.match(body, i + 1)
            if not m:
                raise InputError(f"{path}: line {lineno}: '{c}' word without a plain number "
                                 f"(parameters and expressions are not supported): {body.strip()!r}")
            v = float(m.group(1))
            if not math.isfinite(v):
                raise InputError(f"{path}: line {lineno}: '{c}' number out of range: {body.strip()[:80]!r}")
            yield u, v, m.start(1), m.end(1)
            i = m.end()
            continue
        i += 1


def parse_gcode(path) -> GCodeProgram:
    """Read a G-code file; see the module docstring for what is accepted and refused."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    text = path.read_bytes().decode("latin-1")
    lines = _split_lines(text)
    mode = None        # current motion mode: 0, 1, or another motion G value
    absolute, metric = True, True
    pos = [None, None, None]
    motions, positions = [], []
    for idx, line in enumerate(lines):
        lineno = idx + 1
        body = line.rstrip("\r\n")
        gs, spans, vals = [], {}, {}
        for letter, v, s, e in _scan_words(path, lineno, body):
            if letter == "G":
                gs.append(v)
            else:
                if letter in spans:
                    raise InputError(f"{path}: line {lineno}: repeated '{letter}' word: {body.strip()!r}")
                spans[letter], vals[letter] = (s, e), v
        motion_here = [g for g in gs if g in _MOTION_G]
        if len(motion_here) > 1:
            raise InputError(f"{path}: line {lineno}: two motion codes on one line: {body.strip()!r}")
        for g in gs:
            if g == 90.0:
                absolute = True
            elif g == 91.0:
                absolute = False
            elif g == 20.0:
                metric = False
            elif g == 21.0:
                metric = True
        if motion_here:
            mode = motion_here[0]
        if not spans:
            continue
        nonmodal = [_NONMODAL_AXIS_G[g] for g in gs if g in _NONMODAL_AXIS_G]
        if nonmodal:
            raise InputError(f"{path}: line {lineno}: axis words with {nonmodal[0]} are not supported "
                             f"(they are not a motion target): {body.strip()!r}")
        if mode is None:
            raise InputError(f"{path}: line {lineno}: axis words but no G0/G1 motion mode is active: {body.strip()!r}")
        if mode not in (0.0, 1.0):
            raise InputError(f"{path}: line {lineno}: axis words under G{mode:g}; only G0/G1 moves "
                             f"can be compensated: {body.strip()!r}")
        if not absolute:
            raise InputError(f"{path}: line {lineno}: incremental mode (G91) is not supported; "
                             f"use absolute G90: {body.strip()!r}")
        if not metric:
            raise InputError(f"{path}: line {lineno}: inch mode (G20) is not supported; use mm (G21): {body.strip()!r}")
        for j, ax in enumerate(GCODE_AXES):
            if ax in vals:
                pos[j] = vals[ax]
        if any(p is None for p in pos):
            missing = [ax for ax, p in zip(GCODE_AXES, pos) if p is None]
            raise InputError(f"{path}: line {lineno}: motion before X, Z and A are all known "
                             f"(no value yet for {', '.join(missing)}): {body.strip()!r}")
        motions.append(GMotion(idx, int(mode), spans))
        positions.append(list(pos))
    if not motions:
        raise InputError(f"{path}: no G0/G1 motion with X, Z or A words found")
    return GCodeProgram(path, lines, motions, np.array(positions, dtype=float))


def _fmt(v: float, decimals: int) -> str:
    s = f"{v:.{decimals}f}"
    if float(s) == 0.0:
        s = f"{0.0:.{decimals}f}"
    return s


def render_gcode(program: GCodeProgram, axes, decimals_mm: int = DECIMALS_MM,
                 decimals_deg: int = DECIMALS_DEG) -> str:
    """The program with each motion line's X Z A replaced by ``axes`` (shape (n, 3)).

    Every non-motion line is returned unchanged; on motion lines only the axis numbers
    change (missing axis words are appended after the line's last axis word).
    """
    axes = np.asarray(axes, dtype=float)
    if axes.shape != (len(program.motions), 3):
        raise ValueError(f"Expected axes of shape ({len(program.motions)}, 3), got {axes.shape}")
    if not np.all(np.isfinite(axes)):
        raise ValueError("Expected finite axis commands, got NaN or inf")
    out = list(program.lines)
    dec = (decimals_mm, decimals_mm, decimals_deg)
    for m, row in zip(program.motions, axes):
        line = program.lines[m.index]
        body = line.rstrip("\r\n")
        ending = line[len(body):]
        edits = [(m.spans[ax][0], m.spans[ax][1], _fmt(row[j], dec[j]))
                 for j, ax in enumerate(GCODE_AXES) if ax in m.spans]
        last_end = max(e for _, e, _ in edits)
        extra = "".join(f" {ax}{_fmt(row[j], dec[j])}" for j, ax in enumerate(GCODE_AXES) if ax not in m.spans)
        if extra:
            edits.append((last_end, last_end, extra))
        for s, e, txt in sorted(edits, key=lambda t: (t[0], t[1]), reverse=True):
            body = body[:s] + txt + body[e:]
        out[m.index] = body + ending
    return "".join(out)


# ----------------------------------------------------------------------------- CSV

def _read_csv(path, machine) -> ToolPath:
    t = read_table(path)
    has_axes = all(c in t for c in AXIS_COLUMNS)
    has_targets = all(c in t for c in TARGET_COLUMNS)
    if has_axes and has_targets:
        raise InputError(f"{path}: has both axis columns {list(AXIS_COLUMNS)} and target columns "
                         f"{list(TARGET_COLUMNS)}; expected one set")
    if not (has_axes or has_targets):
        raise InputError(f"{path}: expected columns {list(AXIS_COLUMNS)} (axis commands) or "
                         f"{list(TARGET_COLUMNS)} (WCS targets); found columns {t.names}")
    if len(t) == 0:
        raise InputError(f"{path}: no data rows")
    rows = np.array([t.row_number(k) for k in range(len(t))], dtype=int)
    if has_axes:
        axes = np.stack([t.float(c) for c in AXIS_COLUMNS], axis=1)
        return ToolPath(Path(path), "csv-axes", axes, forward(machine, axes), rows, t)
    targets = np.stack([t.float(c) for c in TARGET_COLUMNS], axis=1)
    return ToolPath(Path(path), "csv-targets", inverse(machine, targets, unwrap=True), targets, rows, t)


def _render_csv(table, replace: dict, comments=()) -> str:
    buf = io.StringIO(newline="")
    for c in list(table.comments) + list(comments):
        buf.write(f"# {c}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(table.names)
    cols = {k: i for i, k in enumerate(table.names)}
    for k, row in enumerate(table.rows):
        row = list(row)
        for name, (values, decimals) in replace.items():
            row[cols[name]] = _fmt(values[k], decimals)
        w.writerow(row)
    return buf.getvalue()


# ----------------------------------------------------------------------------- API

def is_csv(path) -> bool:
    return Path(path).suffix.lower() == ".csv"


def read_path(path, machine) -> ToolPath:
    """Read a tool-path file (CSV by the ``.csv`` suffix, otherwise G-code) for ``machine``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if is_csv(path):
        return _read_csv(path, machine)
    prog = parse_gcode(path)
    return ToolPath(path, "gcode", prog.positions, forward(machine, prog.positions), prog.line_numbers, prog)


def align_turns(a_deg, a_ref_deg) -> np.ndarray:
    """Shift each A by whole turns so it lies within ±180° of ``a_ref_deg`` (same shape)."""
    a = np.asarray(a_deg, dtype=float)
    ref = np.asarray(a_ref_deg, dtype=float)
    return a - 360.0 * np.round((a - ref) / 360.0)


def render_compensated(toolpath: ToolPath, axes, commands_mm, comments=()) -> str:
    """The compensated program's text (see the module docstring for what changes).

    ``axes`` shape (n, 3): compensated axis commands; ``commands_mm`` shape (n, 3):
    compensated WCS commands ``p_r``. ``comments`` become extra ``#`` lines in CSV output
    (G-code output gets nothing added: every non-motion line stays as it was).
    """
    axes = np.asarray(axes, dtype=float)
    commands_mm = np.asarray(commands_mm, dtype=float)
    n = len(toolpath)
    for name, arr in (("axes", axes), ("commands_mm", commands_mm)):
        if arr.shape != (n, 3):
            raise ValueError(f"Expected {name} of shape ({n}, 3), got {arr.shape}")
    if toolpath.kind == "gcode":
        return render_gcode(toolpath.source, axes)
    if toolpath.kind == "csv-axes":
        dec = (DECIMALS_MM, DECIMALS_MM, DECIMALS_DEG)
        return _render_csv(toolpath.source, {c: (axes[:, j], dec[j]) for j, c in enumerate(AXIS_COLUMNS)}, comments)
    return _render_csv(toolpath.source, {c: (commands_mm[:, j], DECIMALS_MM) for j, c in enumerate(TARGET_COLUMNS)},
                       comments)


def write_compensated(toolpath: ToolPath, out_path, axes, commands_mm, comments=()) -> Path:
    """Write the compensated program to ``out_path`` atomically; refuse to overwrite the input."""
    out_path = Path(out_path)
    if out_path.exists() and out_path.resolve() == toolpath.path.resolve():
        raise InputError(f"{out_path}: refusing to overwrite the input file")
    text = render_compensated(toolpath, axes, commands_mm, comments)
    with atomic_write(out_path, "wb") as fh:
        fh.write(text.encode("latin-1" if toolpath.kind == "gcode" else "utf-8"))
    return out_path


def write_targets_csv(path, targets_mm, comments=()) -> Path:
    """Write WCS targets as a ``px_mm, py_mm, pz_mm`` CSV, atomically."""
    from errormap.io import write_csv
    t = np.asarray(targets_mm, dtype=float)
    return write_csv(path, dict(zip(TARGET_COLUMNS, t.T)), header_comments=comments, float_fmt="%.9f")


def write_axes_gcode(path, axes, feed_mm_min: float = 200.0, header=()) -> Path:
    """Write axis commands as a plain G-code program (G21 G90, one ``G1 X Z A`` per point), atomically."""
    axes = np.asarray(axes, dtype=float)
    out = [f"({h})\n" for h in header] + ["G21 G90\n"]
    for k, (x, z, a) in enumerate(axes):
        feed = f" F{feed_mm_min:g}" if k == 0 else ""
        out.append(f"N{10 * (k + 1)} G1 X{_fmt(x, DECIMALS_MM)} Z{_fmt(z, DECIMALS_MM)} A{_fmt(a, DECIMALS_DEG)}{feed}\n")
    out.append("M30\n")
    with atomic_write(path, "w", encoding="latin-1", newline="") as fh:
        fh.write("".join(out))
    return Path(path)
