"""The tool-path files of ``volcomp compensate`` on a machine-tool chain: read, placed, written back.

A file is told apart by content (:func:`compensation.pathio.is_csv`): a CSV with the machine's axis
columns (``x_mm, y_mm, z_mm …``; the grinder's ``x_mm, z_mm, a_deg``), a CSV of WCS targets
(``px_mm, py_mm, pz_mm``: their axes from the chain's nominal inverse, written back as the
compensated commands ``p_r``), or G-code with the machine's axis words (:mod:`compensation.chain_gcode`,
placed by its work offsets and tool lengths, :mod:`compensation.nc_state`). The compensated file keeps
the input's text except the numbers it changes (6 decimals: 1 nm, 1e-6 deg).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.io import InputError, read_table
from errormap.units import check_units

from compensation.app.validate import UsageError

from ...chain_gcode import parse_chain_program, plan_chain_gcode, render_chain_axes
from ...nc_expand import source_line
from ...nc_state import MACHINE, program_frames, refuse_unknown_frames
from ...pathio import DECIMALS_MM, TARGET_COLUMNS, _render_csv, check_move_extent, is_csv
from ...solvers.chain_exact import chain_inverse, nominal_and_jacobian

DECIMALS = {"mm": 6, "deg": 6}  # 1 nm; 1e-6 deg


@dataclass
class ToolPath:
    """One input: ``kind`` ``"gcode"``, ``"csv-axes"`` or ``"csv-targets"``, ``axes`` (n, k) nominal MACHINE axes of
    every point (vertex; a program's points placed by its work offsets and tool lengths), ``lines``
    (n,) source line (G-code) or row (CSV), ``source`` the parsed job or table."""

    path: Path
    kind: str
    axes: np.ndarray
    lines: np.ndarray
    source: object
    shift: np.ndarray | None = None
    """Machine minus program axes per point (n, k): work offset and tool length (None: zero)."""
    tool_mm: np.ndarray | None = None
    """The active tool length per point (n,) mm; NaN (or None): the machine file's own tool."""
    columns: tuple = ()
    """G-code: the machine axes (indices) the program's words are, in order (all of them, or a lathe's
    X and Z where the program never commands the spindle's C)."""
    turning: np.ndarray | None = None
    """G-code on a machine with a ``[spindle]``: (n,) points cut while the spindle turns (X, Z only;
    :mod:`compensation.turning`)."""
    kept_machine: np.ndarray | None = None
    """G-code: the kept (not compensated) points' nominal machine axes (m, k); NaN where unknown."""
    tool_xz: np.ndarray | None = None
    """G-code on a lathe: the active tool offsets (n, 2) mm, X and Z, per point (NaN rows: none; the machine
    file's own tool point; :func:`compensation.nc_state.machine_with_lathe_tool`)."""
    targets_mm: np.ndarray | None = None
    """A WCS-target CSV: its targets (n, 3) mm as written (None: the nominal tool points of ``axes``)."""

    def __len__(self) -> int:
        return len(self.axes)


def read_tool_path(path, machine, s, field_=None) -> ToolPath:
    """A tool-path file for the chain ``machine`` read as the settings ``s`` say (rapids, block delete, dialect,
    work offsets, tool table, cycles, arc tolerance, segment length, units): CSV or G-code (module docstring);
    ``field_``: the error field whose curvature splits G-code moves (``max_segment_mm="auto"``)."""
    path = Path(path)
    if is_csv(path):
        t = read_table(path)
        cols = machine.axis_columns
        if all(c in t for c in TARGET_COLUMNS):
            if any(c in t for c in cols):
                raise InputError(f"{path}: has both axis columns {list(cols)} and target columns "
                                 f"{list(TARGET_COLUMNS)}; expected one set")
            return read_targets_csv(path, t, machine, s)
        t.require(*cols)
        if len(t) == 0:
            raise InputError(f"{path}: no data rows")
        axes = np.stack([t.float(c) for c in cols], axis=1)
        rows = t.row_number(0) + np.arange(len(t), dtype=int)
        check_units(path, rows, machine=machine, axes=axes, axes_columns=cols, coverage="path", temps=csv_temps(t),
                    units=s.units, option="--units")
        return ToolPath(path, "csv-axes", axes, rows, t)
    turning = None
    if getattr(machine, "spindle", None) is not None:  # a lathe: turning mode where the spindle turns
        from ...turning import ColumnsField, parse_lathe_program
        prog, turning = parse_lathe_program(path, machine, s.rapids, s.block_delete, dialect=s.dialect,
                                            lathe_x=getattr(s, "lathe_x", None), subprograms=s.subprograms,
                                            cycles=s.cycles)
    elif getattr(s, "lathe_x", None) is not None:
        raise UsageError(f"--lathe-x: the machine {machine.name!r} is not a lathe (no [spindle]); leave it out")
    else:
        prog = parse_chain_program(path, machine, rapids=s.rapids, block_delete=s.block_delete, dialect=s.dialect,
                                   cycles=s.cycles, tables=(s.work_offsets, s.tool_table), subprograms=s.subprograms)
    k = len(machine.axes)
    columns = tuple(machine.axis_words.index(w) for w in prog.axis_words.words)
    try:
        frames = program_frames(prog, s.work_offsets, s.tool_table)
        refuse_unknown_frames(prog, frames, s.work_offsets)
        if columns == tuple(range(k)):  # a likely unit typo (a move longer than the strokes allow), before planning
            check_move_extent(prog, machine, [j for j, a in enumerate(machine.axes) if a.kind == "linear"],
                              ends=s.work_offsets is not None and s.work_offsets.source == MACHINE)
    except InputError as exc:  # an expanded program's flat lines named at the source, as the reader's refusals
        exp = getattr(prog, "expanded", None)
        raise (exp.relocate(exc) if exp is not None else exc) from None
    partial = len(columns) < k

    def nominal(a):  # the tool point of program-column axes (m, len(columns)): a lathe's C never commanded is 0
        q = np.zeros((len(a), k))
        q[:, columns] = a
        return nominal_and_jacobian(machine, q)[0]

    job = plan_chain_gcode(prog, s.arc_tolerance_um,
                           ColumnsField(field_, columns, k) if partial and field_ is not None else field_, frames,
                           max_segment_mm=s.max_segment_mm, nominal=nominal, machine=machine)
    tool_mm, tool_xz = job.tool_mm, None
    if turning is not None:  # a lathe's tool offsets (X, Z) move its tool point (compensation.turning)
        tool_xz = job.frames.lathe_tool(job.lines - 1)
        tool_mm = np.where(np.isfinite(tool_xz).all(axis=1), np.nan, tool_mm)

    def full(a, fill):  # the program's columns placed in the machine's k columns
        out = np.full((len(a), k), fill, dtype=float)
        out[:, columns] = a
        return out

    shift = full(job.shift, 0.0)
    axes = full(job.axes, 0.0) + shift  # the spindle's C never commanded: a placeholder 0 (solved over the turn)
    kept_machine = full(job.kept_machine_axes, np.nan)
    if prog.tcp is not None:  # tool-centre-point lines: the tip through the chain's nominal inverse
        axes = prog.tcp.place(machine, prog, frames, job.lines - 1, job.axes)
        known = np.isfinite(job.kept_axes).all(axis=1) if len(job.kept_lines) else np.zeros(0, bool)
        if known.any():
            kept_machine[known] = prog.tcp.place(machine, prog, frames, job.kept_lines[known] - 1, job.kept_axes[known])
        kept_machine[prog.tcp.active(job.kept_lines - 1) & ~known] = np.nan  # a TCP rapid from an unknown pose: unknown
    if turning is not None:
        comp = np.array([t for m, t in zip(prog.moves, turning) if m.compensate], dtype=bool)
        turning = np.repeat(comp, job.counts)
        off = np.flatnonzero(~turning & np.isfinite(tool_xz).all(axis=1))
        if off.size:
            raise UsageError(f"{path}: line {source_line(prog, int(job.lines[off[0]]))}: a lathe tool offset in C-axis mode (the spindle "
                             "stopped): only turning moves are compensated at a tool's offsets; cancel the offset "
                             "(G49, T..00) for the C-axis moves")
    check_units(path, job.lines, machine=machine, axes=axes, axes_columns=machine.axis_columns, coverage="path",
                units=s.units, option="--units")
    return ToolPath(path, "gcode", axes, job.lines, job, shift=shift, tool_mm=tool_mm, columns=columns,
                     turning=turning, kept_machine=kept_machine, tool_xz=tool_xz)


def render(tp: ToolPath, axes, commands_mm, machine, comments, held=None) -> str:
    """The compensated file's text: the program axes of the compensated machine ``axes`` (n, k)
    (:func:`program_axes`), or the commands ``commands_mm`` (n, 3) of a WCS-target CSV. ``comments``: header
    lines of a G-code program (a CSV is plain: they go to its sidecar, :func:`compensation.pathio.compensated_sidecar`)."""
    if tp.kind == "csv-targets":
        return _render_csv(tp.source, {c: (commands_mm[:, j], DECIMALS_MM) for j, c in enumerate(TARGET_COLUMNS)})
    axes = program_axes(tp, axes, machine)
    if tp.kind == "csv-axes":
        dec = [DECIMALS[a.unit] for a in machine.axes]
        return _render_csv(tp.source, {c: (axes[:, j], dec[j]) for j, c in enumerate(machine.axis_columns)})
    job = tp.source
    return render_chain_axes(job.program, axes[:, list(tp.columns)], job.counts, header=comments,
                             held=held)  # held: per move, axes at a G53 value (compensation.held_axes)


def program_axes(tp: ToolPath, axes, machine) -> np.ndarray:
    """The program axes to write for the compensated machine ``axes`` (n, k): minus the work offset and tool
    length shift; in TCP form on tool-centre-point lines (:mod:`compensation.tcp`)."""
    out = axes - tp.shift if tp.shift is not None else axes
    frames = tp.source.frames if tp.kind == "gcode" else None
    if frames is not None and frames.rotated:  # a rotated work system: the correction turns back with it
        cols = list(tp.columns)
        out[:, cols] = frames.unplace(tp.lines - 1, axes[:, cols], tp.source.program.axis_words.words)
    tcp = tp.source.program.tcp if tp.kind == "gcode" else None
    if tcp is None:
        return out
    return tcp.program_axes(machine, tp.source.program, tp.source.frames, tp.lines - 1, axes, out)


def source_line_of(tp: ToolPath, line):
    """A point's line as the report names it (the source line of an expanded program)."""
    if tp.kind != "gcode":
        return int(line)
    return source_line(tp.source.program, int(line))


def read_targets_csv(path, table, machine, s) -> ToolPath:
    """A CSV of WCS targets ``px_mm, py_mm, pz_mm`` (n, 3): each row's axes from the chain's nominal inverse
    (its closed form, the rotary axis unwrapped along the path; a machine of linear axes only: its affine
    inverse); a chain with neither is refused naming the file and the columns to give instead."""
    if len(table) == 0:
        raise InputError(f"{path}: no data rows")
    targets = np.stack([table.float(c) for c in TARGET_COLUMNS], axis=1)
    rows = table.row_number(0) + np.arange(len(table), dtype=int)
    check_units(path, rows, machine=machine, targets=targets, target_columns=TARGET_COLUMNS, temps=csv_temps(table),
                units=s.units, option="--units")
    try:
        axes = closed_inverse_path(machine, targets)
    except ValueError:
        try:
            axes = chain_inverse(machine, targets)
        except ValueError:
            raise InputError(f"{path}: columns {list(TARGET_COLUMNS)}: the machine {machine.name!r} has no nominal "
                             f"inverse for WCS targets; give the axis columns {list(machine.axis_columns)}") from None
    return ToolPath(path, "csv-targets", axes, rows, table, targets_mm=targets)


def csv_temps(table):
    """``{"temp_c": (n,)}`` of a CSV path's temperature column (the shared unit check: °F, kelvin), else None."""
    return {"temp_c": table.float("temp_c")} if "temp_c" in table else None


def closed_inverse_path(machine, targets) -> np.ndarray:
    """Axes (n, 3) of WCS points (n, 3) mm along a path by the chain's compiled closed-form inverse, its rotary
    axis unwrapped along the path from the stroke's first turn (as :func:`errormap.chain_kernel.inverse`);
    ValueError where the chain has no closed form."""
    from errormap.machine_tool import rotary_on_turn
    from errormap.chain_kernel import closed_form_solver
    solve = closed_form_solver(machine)
    q = solve(np.ascontiguousarray(targets, dtype=float))
    r = solve.k.rotary
    q[:, r] = rotary_on_turn(q[:, r], solve.k.rotary_lo, unwrap=True)
    return q
