"""Laser-tracker axis sweeps of any machine-tool chain: the sweep file, its reader and its grouping.

Three target balls on each moving body, measured at the axis' stations while the other axes stand parked
(the simulator and the body chains: :mod:`errormap.chain_sweeps`). The file
(``axis,station,command,target,x_mm,y_mm,z_mm[,direction,time_s,temp_c]``, one tracker set-up per file, a
shared set-up said by the same ``# setup: <id>`` line; extra columns kept and ignored):
``docs/reference/file-formats.md``, "Axis sweeps"."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .io import InputError, read_table, write_csv
from .machine_tool import MachineTool

REQUIRED_COLUMNS = ("axis", "station", "command", "target", "x_mm", "y_mm", "z_mm")
OPTIONAL_COLUMNS = ("direction", "time_s", "temp_c")
SWEEP_FORMAT = "volcomp-sweeps/1"
MAX_STATION = 100_000  # station numbers count positions along one stroke; more is a typing mistake
GAUGES = ("first-station", "reference-line", "station-mean")
"""The machine-frame gauges one set-up's sweeps are identified in (:mod:`errormap.identification`; here, beside the
file they are read from, so that ``volcomp identify`` lists them without loading the identification's scipy)."""


def swept_words(machine: MachineTool) -> tuple:
    """The axes a sweep set-up covers: every axis with component errors, canonical order."""
    return tuple(a.word for a in machine.axes if machine.slots_of(a.word))


def write_sweeps(path, columns: dict, comments=()) -> Path:
    """Write a sweep file atomically (12 significant digits: 0.01 nm at metres)."""
    lines = [f"format: {SWEEP_FORMAT}"] + list(comments)
    return write_csv(path, columns, header_comments=lines, float_fmt="%.12g")


# -- reading ---------------------------------------------------------------------------------
@dataclass
class AxisSweep:
    """One axis' sweep, stations in increasing order.

    ``command`` shape (m,) (mm or deg); ``balls_mm`` shape (m, 3, 3) [station, target, xyz]
    in the tracker frame, the mean over directions; ``by_direction`` maps +1/-1 to (m, 3, 3)
    where a direction covers every station; ``stations`` (m,) the station numbers;
    ``source`` names the file(s) for messages.
    """

    axis: str
    command: np.ndarray
    balls_mm: np.ndarray
    stations: np.ndarray
    by_direction: dict = field(default_factory=dict)
    source: str = ""
    time_s: np.ndarray | None = None
    temp_c: np.ndarray | None = None


@dataclass
class Sweeps:
    """Sweeps of one tracker set-up: ``axes`` maps X/Z/A to :class:`AxisSweep`."""

    axes: dict
    setup: str = ""
    sources: list = field(default_factory=list)

    def __getitem__(self, axis) -> AxisSweep:
        return self.axes[axis]

    def __contains__(self, axis) -> bool:
        return axis in self.axes


_UNIT_ALTERNATIVES = ("m", "cm", "um", "in", "inch", "mil")


def _check_units(names, path):
    for c in ("x", "y", "z"):
        if f"{c}_mm" not in names:
            alt = [f"{c}_{u}" for u in _UNIT_ALTERNATIVES if f"{c}_{u}" in names]
            if alt:
                raise InputError(f"{path}: column {alt[0]!r}: ball coordinates must be in mm (column '{c}_mm'); "
                                 "convert the file, units are never guessed")


def columns_from_table(table, axes, rotary, axes_note: str = "") -> dict:
    """Validated sweep columns from a :class:`errormap.io.Table`; errors name file, row, column.
    ``axes``: the axis words a row may name (the machine's swept words, :func:`swept_words`),
    ``rotary``: those commanded in deg; ``axes_note``: said after the expected words in a refusal."""
    _check_units(table.names, table.path)
    table.require(*REQUIRED_COLUMNS)
    axis = np.array(table.raw("axis"))
    for k, a in enumerate(axis):
        if a not in axes:
            raise InputError(f"{table.path}: row {table.row_number(k)}, column 'axis': expected one of "
                             f"{list(axes)}{axes_note}, got {str(a)!r}")
    n = len(table)
    cols = {"axis": axis, "station": table.int("station"), "command": table.float("command"),
            "target": table.int("target", allowed=(1, 2, 3)),
            "x_mm": table.float("x_mm"), "y_mm": table.float("y_mm"), "z_mm": table.float("z_mm"),
            "direction": table.int("direction", allowed=(1, -1)) if "direction" in table else np.ones(n, int),
            "row": np.array([table.row_number(k) for k in range(n)])}
    for k in ("time_s", "temp_c"):
        if k in table:
            cols[k] = table.float(k)
    if "command_unit" in table:  # optional, per row: mm for linear axes, deg for rotary ones
        units = np.array(table.raw("command_unit"))
        for k in range(n):
            want = "deg" if axis[k] in rotary else "mm"
            if units[k] != want:
                raise InputError(f"{table.path}: row {table.row_number(k)}, column 'command_unit': axis {axis[k]}, "
                                 f"station {cols['station'][k]}: expected {want!r}, got {str(units[k])!r} (mixed units)")
    bad = (cols["station"] < 0) | (cols["station"] > MAX_STATION)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise InputError(f"{table.path}: row {table.row_number(k)}, column 'station': expected a station number "
                         f"0..{MAX_STATION}, got {cols['station'][k]}")
    return cols


def sweeps_from_columns(cols: dict, source: str = "<columns>", setup: str = "", axes=None) -> Sweeps:
    """Group sweep columns (as from :func:`errormap.chain_sweeps.simulated_sweeps` or a file) by axis and
    station; ``axes``: the axis words to group (the machine's, :func:`swept_words`; None: every word in
    the columns, in the order they first appear).

    Refuses duplicated rows, missing targets, missing stations, inconsistent commands and
    commands that do not increase with the station number, naming the axis and station.
    """
    n = len(cols["axis"])
    axis = np.asarray(cols["axis"]).astype(str)
    station = np.asarray(cols["station"]).astype(int)
    target = np.asarray(cols["target"]).astype(int)
    direction = np.asarray(cols.get("direction", np.ones(n))).astype(int)
    command = np.asarray(cols["command"], dtype=float)
    xyz = np.stack([np.asarray(cols[k], dtype=float) for k in ("x_mm", "y_mm", "z_mm")], axis=1)
    rows = np.asarray(cols.get("row", np.arange(1, n + 1)))
    files = np.asarray(cols.get("file", np.full(n, source)))
    time_s = np.asarray(cols["time_s"], dtype=float) if "time_s" in cols else None
    temp_c = np.asarray(cols["temp_c"], dtype=float) if "temp_c" in cols else None

    def where(k):
        return f"{files[k]}: row {rows[k]}"

    if temp_c is not None:  # °F or kelvin: the shared unit check (errormap/units.py)
        from .units import temperature_mistake
        bad = temperature_mistake(temp_c)
        if bad is not None:
            raise InputError(f"{where(bad[0])}, column 'temp_c': units do not fit: {bad[1]}")

    if axes is None:
        first = np.unique(axis, return_index=True)[1]
        axes = tuple(axis[np.sort(first)])
    out = {}
    for ax in axes:
        sel = np.flatnonzero(axis == ax)
        if sel.size == 0:
            continue
        st_numbers = np.unique(station[sel])
        span = int(st_numbers.max()) - int(st_numbers.min()) + 1
        if span != st_numbers.size:  # gaps: name the first few without building the whole range
            missing = []
            for g in np.flatnonzero(np.diff(st_numbers) > 1):
                missing += range(int(st_numbers[g]) + 1, min(int(st_numbers[g + 1]), int(st_numbers[g]) + 11))
                if len(missing) >= 10:
                    break
            more = span - st_numbers.size - len(missing[:10])
            raise InputError(f"{source}: axis {ax}: station(s) {missing[:10]}{f' and {more} more' if more > 0 else ''} "
                             f"missing (have {st_numbers.min()}..{st_numbers.max()} with gaps); every station is needed")
        full = np.arange(st_numbers.min(), st_numbers.max() + 1)
        m = full.size
        if m < 4:
            raise InputError(f"{source}: axis {ax}: expected at least 4 stations, got {m}")
        dirs = sorted(set(direction[sel].tolist()), reverse=True)
        balls = {d: np.full((m, 3, 3), np.nan) for d in dirs}
        seen = {}
        cmd = np.full(m, np.nan)
        cmd_row = np.zeros(m, dtype=int)
        for k in sel:
            i = station[k] - full[0]
            key = (station[k], target[k], direction[k])
            if key in seen:
                raise InputError(f"{where(k)}: axis {ax}, station {station[k]}, target {target[k]}, direction "
                                 f"{direction[k]:+d} measured twice (also {where(seen[key])})")
            seen[key] = k
            if np.isnan(cmd[i]):
                cmd[i], cmd_row[i] = command[k], k
            elif abs(command[k] - cmd[i]) > 1e-6 * max(1.0, abs(cmd[i])):
                raise InputError(f"{where(k)}, column 'command': axis {ax}, station {station[k]}: command "
                                 f"{command[k]:g} differs from {cmd[i]:g} at {where(cmd_row[i])}")
            balls[direction[k]][i, target[k] - 1] = xyz[k]
        for d in dirs:
            bad = np.argwhere(np.isnan(balls[d][:, :, 0]))
            if bad.size:
                i, j = bad[0]
                raise InputError(f"{source}: axis {ax}, station {full[i]}: target {j + 1} missing"
                                 + (f" (direction {d:+d})" if len(dirs) > 1 else ""))
        if np.any(np.diff(cmd) <= 0):
            i = int(np.argmax(np.diff(cmd) <= 0)) + 1
            raise InputError(f"{source}: axis {ax}, station {full[i]}: expected commands increasing with the "
                             f"station number, got {cmd[i - 1]:g} then {cmd[i]:g}")
        mean = np.mean(np.stack(list(balls.values())), axis=0)
        out[ax] = AxisSweep(ax, cmd, mean, full, balls, source,
                            None if time_s is None else time_s[sel], None if temp_c is None else temp_c[sel])
    if not out:
        raise InputError(f"{source}: no sweep rows")
    return Sweeps(out, setup, [source])


def read_sweeps(paths, machine: MachineTool) -> Sweeps:
    """Read one or more sweep files of ONE tracker set-up of ``machine`` (its axis words with error
    slots, :func:`swept_words`; commands in deg on its rotary axes).

    A single file is one set-up. Several files are merged only when every file names the
    same set-up in a ``# setup: <id>`` header line (every axis must share the tracker set-up:
    squareness and the rotary axes' lines relate the bodies through it); an axis may then
    appear in one file only. Errors name the file, row and column.
    """
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if not paths:
        raise InputError("no sweep files given")
    words = swept_words(machine)
    rotary = tuple(a.word for a in machine.axes if a.kind == "rotary")
    note = f" (the axes of {machine.name!r} with error slots)"
    tables = [read_table(p, "sweeps") for p in paths]
    setups = [t.meta().get("setup", "") for t in tables]
    if len(paths) > 1 and (len(set(setups)) != 1 or not setups[0]):
        raise InputError(f"{', '.join(map(str, paths))}: several sweep files must all name the same tracker "
                         f"set-up ('# setup: <id>' header line); got {setups}. One file is one set-up.")
    merged: dict = {}
    axis_file: dict = {}
    for t in tables:
        c = columns_from_table(t, axes=words, rotary=rotary, axes_note=note)
        c["file"] = np.full(len(t), str(t.path))
        for ax in set(c["axis"].tolist()):
            if ax in axis_file and axis_file[ax] != str(t.path):
                raise InputError(f"{t.path}: axis {ax} is also in {axis_file[ax]}; give each axis in one file")
            axis_file[ax] = str(t.path)
        for k, v in c.items():
            merged.setdefault(k, []).append(v)
    keys = [k for k in merged if len(merged[k]) == len(tables)]
    cols = {k: np.concatenate(merged[k]) for k in keys}
    source = ", ".join(map(str, paths))
    sw = sweeps_from_columns(cols, source=source, setup=setups[0], axes=words)
    sw.sources = [str(p) for p in paths]
    return sw
