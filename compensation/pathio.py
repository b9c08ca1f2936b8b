"""Tool-path helpers beside the G-code planner (:mod:`compensation.chain_gcode`): the tool-path options' defaults
and ranges, the CSV sniffer, renderer and sidecar, the move-extent check, A's turn alignment and a plain G-code
writer. ``volcomp compensate`` reads through :func:`compensation.app.workflows.compensate_paths.read_tool_path`
(formats: docs/reference/tool-paths.md)."""
from __future__ import annotations

import csv
import io
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from errormap.io import InputError, atomic_write

from .gcode_spline import spline_extent_mm

if TYPE_CHECKING:  # the G-code reader (numba kernels) loads where a program is written, not with the defaults
    from .gcode import GProgram

TARGET_COLUMNS = ("px_mm", "py_mm", "pz_mm")
DECIMALS_MM = 6   # 1 nm
DECIMALS_DEG = 6  # 1e-6 deg: 1 nm at 57 mm from the A axis

DEFAULT_ARC_TOLERANCE_UM = 0.5
"""Tolerance of the straight pieces a G-code move is written in (μm; ``compensate --arc-tolerance-um``),
:func:`compensation.chain_gcode.plan_chain_gcode`: an arc's chords keep its sagitta within it
(:func:`compensation.gcode_classify.arc_segments`), and with ``--max-segment-mm auto`` every piece of a move is
checked at its midpoint so the straight interpolation of the compensation between vertices stays within it, an
arc's own sagitta added (:func:`compensation.chain_gcode.field_pieces`). Measured, with ``--truth``, by the
summary's ``true_path`` (docs/reference/tool-paths.md, "Vertices")."""
ARC_TOLERANCE_RANGE_UM = (0.001, 5.0)
"""Accepted chord tolerances (μm; ``compensate --arc-tolerance-um``). Below 1 nm the program
cannot state the difference (it is written with :data:`DECIMALS_MM` = 6 decimals, 1 nm) and an
arc's chords multiply for nothing (their count grows as ``1/sqrt(tolerance)``). Above 5 μm the
chords' sagitta (up to the whole tolerance) is larger than what compensation leaves
(1-3 μm true RMS in docs/decisions/020-benchmark-notebook.md), so the flattening would undo the compensation: 1e9 μm
wrote a G2 arc as one G1 chord."""
SEGMENT_RANGE_MM = (0.01, 100.0)
"""Accepted ``--max-segment-mm`` lengths. Below 0.01 mm a metre of path is 1e5 vertices per metre, finer than
any field varies (calibration grids of millimetres); above 100 mm the bound binds no move of a
machine's working volume that 'none' (no splitting, said explicitly) would not leave alone."""


def stroke_diagonal_mm(machine, cols=(0, 1)) -> float:
    """Length of the diagonal of the machine's strokes of the axes ``cols`` (mm; the grinder's X and Z by
    default): no move between two points inside the strokes is longer."""
    cols = list(cols)
    return float(np.linalg.norm(machine.stroke_hi[cols] - machine.stroke_lo[cols]))


def _move_extent_mm(start, end, arcs) -> np.ndarray:
    """Largest distance (mm) between two points of each move over the columns of ``start``/``end`` (n, c),
    (n,): the chord of a linear move (0 where its start is unknown: the end's distance outside the strokes
    is checked instead), and for an arc (``arcs``: {row: geometry}) also ``2r·sin(min(|sweep|, π)/2)`` (its
    widest chord)."""
    ext = np.linalg.norm(end - start, axis=1)
    ext[~np.isfinite(ext)] = 0.0
    for k, g in arcs.items():
        if "ctrl" in g:  # a spline: no chord is longer than its control points' widest distance
            ext[k] = max(ext[k], spline_extent_mm(g))
            continue
        r = max(g["r0"], g["r1"])
        ext[k] = max(ext[k], 2.0 * r * np.sin(min(abs(g["sweep"]), np.pi) / 2.0))
    return ext


def check_move_extent(program: GProgram, machine, cols=(0, 1), ends: bool = True) -> None:
    """Refuse a move longer (over the linear axes ``cols``: the grinder's X and Z by default) than the
    machine's stroke diagonal of those axes, or one ending farther than the diagonal outside the strokes: a
    likely unit typo (a number without its decimal point, μm or inch for mm), caught before any vertex is
    placed. One :class:`InputError` naming the file, line, column and word, the line's units and the
    stroke diagonal. ``ends=False``: the moves' lengths only (a program placed by work offsets: its
    coordinates are not the machine's)."""
    cols = list(cols)
    diag = stroke_diagonal_mm(machine, cols)
    lo, hi = machine.stroke_lo[cols], machine.stroke_hi[cols]
    t = program.table
    if t is not None:
        start, end = t.start[:, cols], t.end[:, cols]
        arcs = {k: t.objects[t.obj[k]].arc for k in np.flatnonzero(t.kind == 2).tolist()}
    else:
        moves = program.moves
        start = np.array([m.start for m in moves], dtype=float).reshape(len(moves), -1)[:, cols]
        end = np.array([m.end for m in moves], dtype=float).reshape(len(moves), -1)[:, cols]
        arcs = {k: m.arc for k, m in enumerate(moves) if m.arc is not None}
    ext = _move_extent_mm(start, end, arcs)
    outside = (np.clip(lo - end, 0.0, None) + np.clip(end - hi, 0.0, None)).max(axis=1, initial=0.0) \
        if end.size and ends else np.zeros(len(ext))
    outside = np.where(np.isfinite(outside), outside, 0.0)
    bad = np.flatnonzero((ext > diag) | (outside > diag))
    if not bad.size:
        return
    k = int(bad[0])
    m = program.moves[k]
    names = [program.axis_words.words[j] for j in cols] if program.axis_words is not None else ["X", "Z"]
    words = [m.words[a] for a in (*names, "I", "J", "K", "R") if a in m.words] or list(m.words.values())
    w = max(words, key=lambda w: abs(w.value))  # a move has axis words
    unit = "inch (G20)" if m.units == "inch" else "mm (G21 or no unit code)"
    axes = "/".join(names)
    what = (f"a move of {ext[k]:.6g} mm" if ext[k] > diag else
            f"an end {outside[k]:.6g} mm outside the {axes} strokes")
    raise InputError(f"{program.path}: line {m.index + 1}, column {w.start + 1}: '{w.letter}{w.text}': {what}, "
                     f"more than the machine's {axes} stroke diagonal {diag:.6g} mm; likely a unit typo (the line "
                     f"is read in {unit}): a number without its decimal point, or μm or inch where mm was meant")


# ----------------------------------------------------------------------------- CSV

def _render_csv(table, replace: dict) -> str:
    """The CSV ``table`` with the columns of ``replace`` (name -> (values, decimals)) rewritten: a plain CSV,
    header first (its provenance goes to the sidecar: :func:`compensated_sidecar`)."""
    from .gcode import fmt as _fmt
    buf = io.StringIO(newline="")
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

SNIFF_BYTES = 1 << 16
"""How much of a tool-path file is read to tell a CSV from G-code (the header is on its first lines)."""


def is_csv(path) -> bool:
    """Whether the tool-path file ``path`` is a CSV path, by its content, whatever its name: its first
    line that is neither blank nor a ``#`` comment is a CSV header naming the axis columns
    (``x_mm, z_mm, a_deg``) or the target columns (``px_mm, py_mm, pz_mm``) — a row of column names,
    at least two, one with a ``_`` (no G-code word has one). Anything else is read as
    G-code (whose parser refuses what it does not understand, naming the line)."""
    with open(path, "rb") as fh:
        head = fh.read(SNIFF_BYTES)
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    for line in text.replace("\r", "\n").split("\n"):
        if not line.strip() or line.startswith("#"):
            continue
        cells = [c.strip().strip('"') for c in line.split(",")]
        # a header row of column names (G-code words have no '_'; the CSV reader then names what is missing)
        return len(cells) >= 2 and all(_COLUMN_NAME.match(c) for c in cells) and any("_" in c for c in cells)
    return False


_COLUMN_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def align_turns(a_deg, a_ref_deg) -> np.ndarray:
    """Shift each A by whole turns so it lies within ±180° of ``a_ref_deg`` (same shape)."""
    a = np.asarray(a_deg, dtype=float)
    ref = np.asarray(a_ref_deg, dtype=float)
    return a - 360.0 * np.round((a - ref) / 360.0)


def compensated_sidecar(table, out_path, comments=()) -> str:
    """The provenance sidecar's text (:func:`errormap.io.sidecar_json`) of the compensated CSV ``out_path``
    rendered from the input CSV ``table``: the input's provenance lines, then ``comments``."""
    from errormap.io import sidecar_json
    return sidecar_json(out_path, table.names, len(table), [*table.comments, *comments])


def write_axes_gcode(path, axes, feed_mm_min: float = 200.0, header=()) -> Path:
    """Write axis commands as a plain G-code program (G21 G90, one ``G1 X Z A`` per point), atomically."""
    from .gcode import fmt as _fmt
    axes = np.asarray(axes, dtype=float)
    out = [f"({h})\n" for h in header] + ["G21 G90\n"]
    for k, (x, z, a) in enumerate(axes):
        feed = f" F{feed_mm_min:g}" if k == 0 else ""
        out.append(f"N{10 * (k + 1)} G1 X{_fmt(x, DECIMALS_MM)} Z{_fmt(z, DECIMALS_MM)} A{_fmt(a, DECIMALS_DEG)}{feed}\n")
    out.append("M30\n")
    with atomic_write(path, "w", encoding="latin-1", newline="") as fh:
        fh.write("".join(out))
    return Path(path)
