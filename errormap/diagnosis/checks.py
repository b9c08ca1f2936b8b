"""Check measurements (schema in docs/reference/file-formats.md) for diagnosis: loading, validation, the measured residual.

Columns: ``x_mm, z_mm, a_deg, dx_um, dy_um, dz_um`` (required); ``time_s``, ``temp_c``,
``dir_x``, ``dir_z``, ``dir_a`` (+1/-1), ``seq`` (order taken) optional; extra columns are kept
in the file and ignored here.

Validation (every error is an :class:`~errormap.io.InputError` naming the file, the row — the
file line, header = row 1 — and the column):

* a missing required column; a cell that is not a finite number (NaN, inf, text);
* a direction that is not +1/-1; a ``seq`` that is not an integer;
* units that do not fit: a measured error beyond ``MAX_ERROR_UM`` (a value in metres or nm, or
  a position typed into an error column), a temperature outside 0 … 45 °C (°F or kelvin; the
  shared check of :mod:`errormap.units`), and — once the model is known, see :func:`measured_residual` — a measured
  column ~1000× smaller than the model predicts (mm or m written as μm) or deviation columns that fit another
  axis order far better (headers exchanged; :mod:`.plausibility`);
* duplicated rows (every cell equal to an earlier row) and duplicated ``seq`` values;
* a check point outside the X or Z stroke of the machine (A is periodic; any finite A passes).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..io import InputError, read_table
from ..units import TEMP_HARD_RANGE_C, UNITS_CHECK, check_units
from .plausibility import check_deviations, stated_noise

AXES_COLUMNS = ("x_mm", "z_mm", "a_deg")
ERROR_COLUMNS = ("dx_um", "dy_um", "dz_um")
REQUIRED_COLUMNS = AXES_COLUMNS + ERROR_COLUMNS
CONDITION_COLUMNS = ("time_s", "temp_c", "dir_x", "dir_z", "dir_a")
DIR_COLUMNS = ("dir_x", "dir_z", "dir_a")
MAX_ERROR_UM = 5000.0
"""Largest plausible measured error component (μm): 5 mm. The grinder's errors are < 250 μm."""
TEMP_RANGE_C = TEMP_HARD_RANGE_C  # refused even with --units as-written; 0 … 45 °C without it (errormap/units.py)
STROKE_TOL_MM = 1e-6


@dataclass
class CheckData:
    """Check measurements, in ``seq`` order (file order when there is no ``seq``).

    ``axes`` shape (n, 3) (x_mm, z_mm, a_deg); ``measured_um`` shape (n, 3); ``conditions``
    maps the optional condition names present (``time_s``, ``temp_c``, ``dir_x`` ...) to
    arrays shape (n,); ``seq`` shape (n,) int; ``rows`` shape (n,) file line of each point
    (for error messages; 0 when the data did not come from a file).
    """

    axes: np.ndarray
    measured_um: np.ndarray
    conditions: dict = field(default_factory=dict)
    seq: np.ndarray | None = None
    rows: np.ndarray | None = None
    path: str = "<checks>"
    stated_noise_um: float | None = None
    """The instrument's noise σ per coordinate (μm) the file states (``# noise_um: σ``) or the user gives
    (``diagnose --noise-um``); None: not stated. The verdict judges the loop's noise estimate against it."""

    def __post_init__(self):
        self.axes = np.asarray(self.axes, dtype=float)
        self.measured_um = np.asarray(self.measured_um, dtype=float)
        n = self.axes.shape[0]
        if self.axes.shape != (n, 3) or self.measured_um.shape != (n, 3):
            raise ValueError(f"Expected axes and measured_um of shape (n, 3), got {self.axes.shape} and {self.measured_um.shape}")
        self.conditions = {k: np.asarray(v, dtype=float) for k, v in self.conditions.items()}
        for k, v in self.conditions.items():
            if k not in CONDITION_COLUMNS or v.shape != (n,):
                raise ValueError(f"Expected conditions from {CONDITION_COLUMNS} of shape ({n},), got {k!r} {v.shape}")
        self.seq = np.arange(n) if self.seq is None else np.asarray(self.seq, dtype=np.int64)
        self.rows = np.zeros(n, dtype=np.int64) if self.rows is None else np.asarray(self.rows, dtype=np.int64)
        order = np.argsort(self.seq, kind="stable")
        if np.any(order != np.arange(n)):
            self.axes, self.measured_um = self.axes[order], self.measured_um[order]
            self.conditions = {k: v[order] for k, v in self.conditions.items()}
            self.seq, self.rows = self.seq[order], self.rows[order]

    def __len__(self) -> int:
        return self.axes.shape[0]

    def subset(self, idx) -> "CheckData":
        return CheckData(self.axes[idx], self.measured_um[idx], {k: v[idx] for k, v in self.conditions.items()},
                         self.seq[idx], self.rows[idx], self.path, self.stated_noise_um)

    @classmethod
    def from_columns(cls, cols: dict, path: str = "<checks>") -> "CheckData":
        """From a dict of columns (e.g. :meth:`TruthGrinder.check_measurements`)."""
        axes = np.stack([np.asarray(cols[k], dtype=float) for k in AXES_COLUMNS], axis=1)
        meas = np.stack([np.asarray(cols[k], dtype=float) for k in ERROR_COLUMNS], axis=1)
        cond = {k: np.asarray(cols[k], dtype=float) for k in CONDITION_COLUMNS if k in cols}
        return cls(axes, meas, cond, cols.get("seq"), None, path)


def _fail(path, row, column, msg) -> InputError:
    return InputError(f"{path}: row {row}, column '{column}': {msg}")


def load_checks(path, machine, units: str = UNITS_CHECK, units_option: str | None = None) -> CheckData:
    """Read and validate a check-measurement CSV against ``machine``'s strokes (see module doc).
    ``units``, ``units_option``: :func:`errormap.units.check_units` (``"as-written"`` skips the
    likely-unit-mistake tests; the option that says so is named in the messages)."""
    t = read_table(path, "checks")
    t.require(*REQUIRED_COLUMNS)
    if len(t) < 10:
        raise InputError(f"{path}: expected at least 10 check measurements, got {len(t)}")
    axes = np.stack([t.float(c) for c in AXES_COLUMNS], axis=1)
    meas = np.stack([t.float(c) for c in ERROR_COLUMNS], axis=1)
    rows = np.array([t.row_number(k) for k in range(len(t))])
    cond = {}
    for c in CONDITION_COLUMNS:
        if c in t:
            cond[c] = t.int(c, allowed=(-1, 1)).astype(float) if c in DIR_COLUMNS else t.float(c)
    seq = t.int("seq") if "seq" in t else None
    # units
    bad = np.argwhere(np.abs(meas) > MAX_ERROR_UM)
    if bad.size:
        k, j = bad[0]
        v = meas[k, j]
        raise _fail(path, rows[k], ERROR_COLUMNS[j],
                    f"units do not fit: {v:g} μm (= {v * 1e-6:g} m) is beyond the plausible {MAX_ERROR_UM:g} μm; "
                    "expected an error in μm (not nm, not a position)")
    # temperatures in °F or kelvin, positions in metres, angles in radians: the one shared check
    check_units(path, rows, machine=machine, axes=axes, axes_columns=AXES_COLUMNS, coverage="volume",
                temps={"temp_c": cond["temp_c"]} if "temp_c" in cond else None, units=units, option=units_option)
    # strokes (A is periodic: any finite value passes)
    for j, c in enumerate(AXES_COLUMNS[:2]):
        lo, hi = machine.strokes[c]
        bad = np.flatnonzero((axes[:, j] < lo - STROKE_TOL_MM) | (axes[:, j] > hi + STROKE_TOL_MM))
        if bad.size:
            raise _fail(path, rows[bad[0]], c, f"check point outside the stroke [{lo:g}, {hi:g}] mm: {axes[bad[0], j]:g}")
    # duplicates
    seen = {}
    for k, r in enumerate(t.rows):
        key = tuple(r)
        if key in seen:
            raise InputError(f"{path}: row {rows[k]}: duplicated row (every column equals row {rows[seen[key]]}; "
                             f"columns {t.names})")
        seen[key] = k
    if seq is not None:
        first = {}
        for k, s in enumerate(seq):
            if s in first:
                raise _fail(path, rows[k], "seq", f"duplicated value {s} (also in row {rows[first[s]]})")
            first[s] = k
    return CheckData(axes, meas, cond, seq, rows, str(path), stated_noise(path, t.comments))


def measured_residual(checks: CheckData, field_) -> tuple[np.ndarray, np.ndarray]:
    """The measured residual (measurement − model prediction) and the prediction, both (n, 3) μm.

    Raises :class:`InputError` naming the file, a row and the columns when the deviations fit another unit
    (mm or m written as μm) or another axis order (headers exchanged) far better than as written
    (:func:`errormap.diagnosis.plausibility.check_deviations`).
    """
    pred = np.asarray(field_.predict(checks.axes), dtype=float)
    if pred.shape != checks.measured_um.shape or not np.all(np.isfinite(pred)):
        raise ValueError(f"Expected a finite model prediction of shape {checks.measured_um.shape}, got {pred.shape}")
    check_deviations(checks.path, checks.measured_um, pred, rows=checks.rows, noise_um=checks.stated_noise_um,
                     option=None)
    return checks.measured_um - pred, pred
