"""``iso-tables``: per-axis ISO 230-1 component tables of an element set, on any machine tool.

``iso_<W>.csv`` for every axis ``W`` with component errors (the position column and the six components
``E{X,Y,Z}<W>_um``, ``E{A,B,C}<W>_urad``, one row per position) and ``iso_location.csv`` (the location and
squareness errors, one row each: ``name, value, unit, meaning``), in the fixed machine frame (MCS) with the
other axes at their reference pose, as :mod:`errormap.iso230` states the conventions. Controller (the
check): every component linearly between rows (a full-turn rotary axis periodic, other axes clamped), the
elements rebuilt from them, the exact chain's spatial error. The conventions and the rebuild:
docs/reference/controller-tables.md."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.io import InputError, read_table, write_csv
from errormap.iso230 import axis_from_mcs, axis_to_mcs
from errormap.chain_kernel import CompiledNominal

from .common import fold, meta_format

ISO_FORMAT = "volcomp-iso-table/1"
MAX_ISO_ROWS = 4096
DIRECTIONS = "XYZ"
ROTATIONS = "ABC"


def iso_columns(word: str) -> tuple:
    """The six ISO component names of axis ``word``: ``EX<W> EY<W> EZ<W> EA<W> EB<W> EC<W>``."""
    return tuple(f"E{d}{word}" for d in DIRECTIONS + ROTATIONS)


def unit_of(iso: str) -> str:
    return "um" if iso[1] in DIRECTIONS else "urad"


def table_axes(mt) -> list:
    """``[(index, axis)]`` of the axes with component errors."""
    return [(j, a) for j, a in enumerate(mt.axes) if mt.slots_of(a.word)]


def _slot_columns(mt, word):
    """``(slot indices (6,) or -1, ...)`` of axis ``word``'s components in :func:`iso_columns` order."""
    own = set(mt.slots_of(word))
    by_iso = {s.iso: p for p, s in enumerate(mt.slots) if s.name in own}
    return np.array([by_iso.get(n, -1) for n in iso_columns(word)])


def reference_axes(mt, n: int = 1) -> np.ndarray:
    """The reference pose (n, k): every axis at 0, clipped into its stroke."""
    return np.tile(np.clip(0.0, mt.stroke_lo, mt.stroke_hi), (n, 1))


@dataclass
class IsoTables:
    """Per-axis ISO component tables: ``positions[W]`` (m,), ``values[W]`` (m, 6) in :func:`iso_columns` order;
    ``location`` ``{iso name: value}`` of the constant slots."""

    positions: dict
    values: dict
    location: dict
    kind = "iso-tables"

    def slot_values(self, machine, axes) -> np.ndarray:
        """The elements (n, P) a controller rebuilds from the tables at ``axes`` (n, k)."""
        axes = np.asarray(axes, dtype=float)
        out = np.zeros((len(axes), len(machine.slots)))
        for j, a in table_axes(machine):
            pos, val = self.positions[a.word], self.values[a.word]
            x = fold(axes[:, j], pos[0]) if a.full_turn else axes[:, j]
            iso = np.stack([np.interp(x, pos, val[:, c]) for c in range(6)], axis=1)
            cols = _slot_columns(machine, a.word)
            pose = reference_axes(machine, len(axes))   # the table's frame: this axis moved, the others at reference
            pose[:, j] = axes[:, j]
            comp = axis_from_mcs(machine, a.word, pose, iso)
            out[:, cols[cols >= 0]] = comp[:, cols >= 0]
        for p, s in enumerate(machine.slots):
            if s.name in machine.constant_slots:
                out[:, p] = self.location[s.iso]
        return out

    def field(self, machine):
        from .common import TableField
        compiled = CompiledNominal(machine)
        return TableField(lambda axes: compiled.spatial_error(axes, self.slot_values(machine, axes)))

    def n_values(self) -> int:
        return sum(v.size + p.size for v, p in zip(self.values.values(), self.positions.values())) + len(self.location)


def iso_tables_from_model(elements, machine, n_rows: int) -> IsoTables:
    """The model's ISO components at ``n_rows`` equally spaced positions over each axis' stations."""
    pos, val = {}, {}
    for j, a in table_axes(machine):
        st = elements.stations[a.column]
        t = np.linspace(st[0], st[-1], int(n_rows))
        axes = reference_axes(machine, t.size)
        axes[:, j] = t
        v = elements.values(axes)
        cols = _slot_columns(machine, a.word)
        comp = np.where(cols >= 0, v[:, np.maximum(cols, 0)], 0.0)
        pos[a.word], val[a.word] = t, axis_to_mcs(machine, a.word, axes, comp)
    v0 = elements.values(reference_axes(machine))[0]
    loc = {s.iso: float(v0[p]) for p, s in enumerate(machine.slots) if s.name in machine.constant_slots}
    return IsoTables(pos, val, loc)


def _meaning(mt, slot) -> str:
    """What a constant slot's ISO name ``E<D>0<W>`` means."""
    d, w = slot.iso[1], slot.iso[3:]
    if slot.kind == "squareness":
        other = sorted(set(DIRECTIONS) - {w, DIRECTIONS[ROTATIONS.index(d)]}) if d in ROTATIONS else []
        to = f" to {other[0]}" if len(other) == 1 else ""
        return f"squareness of {w}{to} (about {DIRECTIONS[ROTATIONS.index(d)] if d in ROTATIONS else d})"
    if d in DIRECTIONS:
        return f"offset of the {w} axis line in {d}"
    return f"tilt of the {w} axis line about {DIRECTIONS[ROTATIONS.index(d)]}"


def _header(mt, j, a, model_desc) -> list:
    ref = mt.body_frames(a.word, reference_axes(mt))[1][0]
    side = mt.body_index[a.word][0]
    carries = "workpiece" if side == "work" else "tool"
    return [f"format: {ISO_FORMAT}", f"axis: {a.word}",
            f"reference point: the origin of the {a.word} body's frame in the machine's chain; at the reference "
            f"pose ({ref[0]:.4f}, {ref[1]:.4f}, {ref[2]:.4f}) mm in the MCS",
            f"sign: error motion of the {a.word} body (carries the {carries}) relative to its nominal pose, fixed "
            "machine frame (MCS) axes; translations um along +X/+Y/+Z, angles urad right-handed about +X/+Y/+Z"
            + ("; the tool moves relative to the workpiece by minus this" if side == "work" else
               "; the tool moves relative to the workpiece by this"),
            "interpolation: linear between rows" + (" (one turn, periodic)" if a.full_turn else ""),
            f"model: {model_desc}", f"machine: {mt.name} sha256 {mt.sha256}"]


def write_iso_tables(tables: IsoTables, folder, machine, model_desc: str) -> list[Path]:
    folder = Path(folder)
    out = []
    for j, a in table_axes(machine):
        cols = {a.column: tables.positions[a.word]}
        for c, n in enumerate(iso_columns(a.word)):
            cols[f"{n}_{unit_of(n)}"] = tables.values[a.word][:, c]
        out.append(write_csv(folder / f"iso_{a.word}.csv", cols, _header(machine, j, a, model_desc), "%.12g"))
    slots = [s for s in machine.slots if s.name in machine.constant_slots]
    loc = {"name": np.array([s.iso for s in slots]), "value": np.array([tables.location[s.iso] for s in slots]),
           "unit": np.array([unit_of(s.iso) for s in slots]), "meaning": np.array([_meaning(machine, s) for s in slots])}
    head = [f"format: {ISO_FORMAT}", "axis: location",
            "reference point: the origin of the axis line's frame in the machine's chain (location errors); the "
            "moving axis' stroke origin (squareness)",
            "sign: MCS axes; E<D>0<W> > 0 shifts the W axis line along +D (D = X, Y, Z) or tilts it right-handed "
            "about D (D = A, B, C about X, Y, Z); a squareness tilts the W line of motion",
            f"model: {model_desc}", f"machine: {machine.name} sha256 {machine.sha256}"]
    out.append(write_csv(folder / "iso_location.csv", loc, head, "%.12g"))
    return out


def read_iso_tables(folder, machine) -> IsoTables:
    """Read ``iso_<W>.csv`` and ``iso_location.csv`` of ``machine``; errors name file, row, column."""
    folder = Path(folder)
    pos, val = {}, {}
    for j, a in table_axes(machine):
        t = read_table(folder / f"iso_{a.word}.csv")
        meta_format(t, ISO_FORMAT)
        p = t.float(a.column)
        if p.size < 2 or np.any(np.diff(p) <= 0):
            k = int(np.argmax(np.diff(p) <= 0)) + 1 if p.size >= 2 else 0
            raise InputError(f"{t.path}: row {t.row_number(k)}, column '{a.column}': expected increasing positions "
                             f"(at least 2 rows)")
        pos[a.word] = p
        val[a.word] = np.stack([t.float(f"{n}_{unit_of(n)}") for n in iso_columns(a.word)], axis=1)
    want = [s.iso for s in machine.slots if s.name in machine.constant_slots]
    t = read_table(folder / "iso_location.csv")
    meta_format(t, ISO_FORMAT)
    loc = {}
    for k, (n, v) in enumerate(zip(t.raw("name"), t.float("value"))):
        if n not in want or n in loc:
            raise InputError(f"{t.path}: row {t.row_number(k)}, column 'name': expected each of {want} once, got {n!r}")
        loc[n] = float(v)
    if set(loc) != set(want):
        raise InputError(f"{t.path}: column 'name': missing {sorted(set(want) - set(loc))}")
    return IsoTables(pos, val, loc)
