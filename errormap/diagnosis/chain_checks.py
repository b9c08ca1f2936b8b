"""Check measurements of a machine-tool chain for the closed loop (``docs/reference/file-formats.md``): the machine's axis columns,
``dx_um, dy_um, dz_um`` and the optional conditions (``time_s``, ``temp_c``, ``dir_<w>``, ``seq``), read and
checked (:func:`load_chain_checks`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..io import InputError, read_table
from ..machine_tool import MachineTool
from ..units import temperature_mistake
from .plausibility import stated_noise

ERROR_COLUMNS = ("dx_um", "dy_um", "dz_um")
MAX_ERROR_UM = 5000.0
"""Largest plausible measured error component (μm)."""
STROKE_TOL = 1e-6
MIN_CHECKS = 10


@dataclass
class ChainChecks:
    """Checks of a machine tool in ``seq`` order: ``axes`` (n, k), ``measured_um`` (n, 3),
    ``conditions`` (name -> (n,)), ``seq`` (n,), ``rows`` (n,) file lines."""

    axes: np.ndarray
    measured_um: np.ndarray
    conditions: dict = field(default_factory=dict)
    seq: np.ndarray | None = None
    rows: np.ndarray | None = None
    path: str = "<checks>"
    stated_noise_um: float | None = None
    """The instrument's noise σ per coordinate (μm) the file states (a ``# noise_um: σ`` header line), or None."""

    def __post_init__(self):
        n = len(self.axes)
        self.seq = np.arange(n) if self.seq is None else np.asarray(self.seq, dtype=np.int64)
        self.rows = np.zeros(n, dtype=np.int64) if self.rows is None else np.asarray(self.rows)
        o = np.argsort(self.seq, kind="stable")
        self.axes, self.measured_um = np.asarray(self.axes, float)[o], np.asarray(self.measured_um, float)[o]
        self.conditions = {k: np.asarray(v, float)[o] for k, v in self.conditions.items()}
        self.seq, self.rows = self.seq[o], self.rows[o]

    def __len__(self):
        return len(self.axes)

    @classmethod
    def from_columns(cls, machine: MachineTool, cols: dict, path: str = "<checks>") -> "ChainChecks":
        axes = np.stack([np.asarray(cols[c], float) for c in machine.axis_columns], axis=1)
        meas = np.stack([np.asarray(cols[c], float) for c in ERROR_COLUMNS], axis=1)
        cond = {k: np.asarray(v, float) for k, v in cols.items() if k in condition_columns(machine)}
        return cls(axes, meas, cond, cols.get("seq"), None, path)


def condition_columns(machine: MachineTool) -> tuple:
    return ("time_s", "temp_c") + tuple(f"dir_{a.word.lower()}" for a in machine.axes)


def load_chain_checks(path, machine: MachineTool, units: str = "check") -> ChainChecks:
    """Read and validate a machine tool's check CSV (module doc); errors name file, row, column."""
    t = read_table(path, "checks")
    t.require(*machine.axis_columns, *ERROR_COLUMNS)
    if len(t) < MIN_CHECKS:
        raise InputError(f"{path}: expected at least {MIN_CHECKS} check measurements, got {len(t)}")
    rows = np.array([t.row_number(k) for k in range(len(t))])
    axes = np.stack([t.float(c) for c in machine.axis_columns], axis=1)
    meas = np.stack([t.float(c) for c in ERROR_COLUMNS], axis=1)
    bad = np.argwhere(np.abs(meas) > MAX_ERROR_UM)
    if bad.size:
        k, j = bad[0]
        raise InputError(f"{path}: row {rows[k]}, column '{ERROR_COLUMNS[j]}': units do not fit: {meas[k, j]:g} μm is "
                         f"beyond the plausible {MAX_ERROR_UM:g} μm; expected an error in μm (not nm, not a position)")
    for j, a in enumerate(machine.axes):
        if a.full_turn:
            continue
        lo, hi = a.stroke
        out = np.flatnonzero((axes[:, j] < lo - STROKE_TOL * max(1, abs(lo))) | (axes[:, j] > hi + STROKE_TOL * max(1, abs(hi))))
        if out.size:
            k = out[0]
            raise InputError(f"{path}: row {rows[k]}, column '{a.column}': check point outside the stroke "
                             f"[{lo:g}, {hi:g}] {a.unit}: {axes[k, j]:g}")
    if units == "check" and len(axes) >= MIN_CHECKS:  # metres for mm, radians for degrees (as the grinder's check)
        for j, a in enumerate(machine.axes):
            span, stroke = float(np.ptp(axes[:, j])), a.stroke[1] - a.stroke[0]
            k = int(np.argmax(np.abs(axes[:, j])))
            if (a.kind == "linear" and 0 < span <= stroke / 200 and span * 1000 >= stroke / 4
                    and np.abs(axes[:, j]).max() <= 1.5e-3 * max(abs(a.stroke[0]), abs(a.stroke[1]))):
                raise InputError(f"{path}: row {rows[k]}, column '{a.column}': units do not fit: values span only "
                                 f"{span:.4g} mm of the {stroke:g} mm stroke; 1000x that fits it: metres rather than mm? "
                                 "(--units as-written if they are mm)")
            on_grid = np.allclose(axes[:, j] * 2, np.round(axes[:, j] * 2), rtol=0, atol=1e-9)
            if (a.kind == "rotary" and stroke >= 180 and np.all(np.abs(axes[:, j]) <= 2 * np.pi + 1e-6)
                    and span >= 1.5 * np.pi and not on_grid):
                raise InputError(f"{path}: row {rows[k]}, column '{a.column}': units do not fit: values lie within "
                                 f"±2π and span {span:.4g}: radians rather than degrees? (--units as-written if degrees)")
    cond = {}
    for c in condition_columns(machine):
        if c in t:
            cond[c] = t.int(c, allowed=(-1, 1)).astype(float) if c.startswith("dir_") else t.float(c)
    if "temp_c" in cond:
        m = temperature_mistake(cond["temp_c"], units)
        if m is not None:
            raise InputError(f"{path}: row {rows[m[0]]}, column 'temp_c': units do not fit: {m[1]}")
    seq = t.int("seq") if "seq" in t else None
    if seq is not None:
        u, first = np.unique(seq, return_index=True)
        if u.size != seq.size:
            dup = np.setdiff1d(np.arange(seq.size), first)[0]
            raise InputError(f"{path}: row {rows[dup]}, column 'seq': duplicated value {seq[dup]}")
    return ChainChecks(axes, meas, cond, seq, rows, str(path), stated_noise(path, t.comments))


# -- the update ---------------------------------------------------------------------------------
