"""Feature points: the spatial error on a grid over a machine tool's axis strokes (:data:`DEFAULT_GRID` per axis).

Written as a plain CSV (the machine's axis columns, e.g. ``x_mm, z_mm, a_deg`` on the grinder, then ``dx_um,
dy_um, dz_um``) whose provenance (its sidecar, :func:`errormap.io.sidecar_path`; leading ``#`` lines of an older
file) names the axis columns (``axis_columns``; an older grinder's file without it is read as the grinder's) and
records where the data came from (machine name, file and SHA-256; element-set file and
SHA-256), so a trained model can always be traced back. File paths in the provenance
(``elements_file``, ``machine_file``) are written relative to the CSV's own folder and read
back relative to it, so the pair can be moved or used from any working folder (the built-in
machine file is recorded by its absolute path and found again by its SHA-256).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .io import InputError, read_table, write_csv

COLUMNS = ("x_mm", "z_mm", "a_deg", "dx_um", "dy_um", "dz_um")
PATH_KEYS = ("elements_file", "machine_file")  # provenance paths, relative to the CSV's folder


def _relative_to(value: str, folder: Path) -> str:
    if not value:
        return value
    from .machine import builtin_machine_path
    p = Path(value)
    if p.resolve() == builtin_machine_path().resolve() or p.resolve().parent == builtin_machine_path().resolve().parent:
        return str(p.resolve())  # a built-in machine file (the grinder's or a named chain's)
    return os.path.relpath(p.resolve(), folder.resolve())


def _resolve(value: str, folder: Path) -> str:
    if not value:
        return value
    p = Path(value)
    return str(p if p.is_absolute() else (folder / p).resolve())


def grid_axes(machine, n: int = 11) -> np.ndarray:
    """The grid over each of a machine tool's k axes' strokes in ``machine.axis_columns`` order, n per axis
    (the grinder: A from its lower stroke over 360°), shape (nᵏ, k)."""
    names = machine.axis_columns
    g = [np.linspace(*machine.strokes[k], n) for k in names]
    return np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, len(names))


# errors of a real machine tool's volume: a largest |error| outside this range is a unit mistake
MIN_MAX_ERROR_UM = 1.0      # below: the errors are in mm (a whole volume within 1 μm is not a machine tool)
MAX_ERROR_UM = 5000.0       # above: nm, or positions written as errors


@dataclass
class FeaturePoints:
    """Axes shape (n, 3) and errors shape (n, 3) μm, with provenance ``meta``.

    ``source`` and ``rows`` (file line of each point) are set by :meth:`load`.
    """

    axes: np.ndarray
    errors_um: np.ndarray
    meta: dict
    source: str = ""
    rows: np.ndarray | None = None
    axis_columns: tuple = COLUMNS[:3]
    """The axes' column names (a machine-tool chain: its own, e.g. x_mm, y_mm, z_mm)."""

    @property
    def columns(self) -> tuple:
        return tuple(self.axis_columns) + COLUMNS[3:]

    def check_units(self, machine) -> None:
        """Refuse feature points whose units do not fit the machine, naming row, column and the
        likely mistake: axes in metres or radians, errors in mm, nm or positions."""
        from .units import check_units
        rows = self.rows if self.rows is not None else np.arange(1, len(self.axes) + 1)
        src = self.source or "feature points"
        # metres, radians: the shared check (errormap/units.py), the volume-covering form
        check_units(src, rows, machine=machine, axes=self.axes, axes_columns=tuple(self.axis_columns),
                    coverage="volume")
        e = np.abs(self.errors_um)
        k, j = np.unravel_index(int(np.argmax(e)), e.shape)
        if e[k, j] > MAX_ERROR_UM:
            raise InputError(f"{src}: row {rows[k]}, column '{COLUMNS[3 + j]}': units do not fit: {e[k, j]:g} μm is "
                             f"beyond the plausible {MAX_ERROR_UM:g} μm; expected μm (not nm, not a position)")
        if e[k, j] < MIN_MAX_ERROR_UM:
            raise InputError(f"{src}: row {rows[k]}, column '{COLUMNS[3 + j]}': units do not fit: the largest error "
                             f"is {e[k, j]:.3g} μm over the whole volume; mm rather than μm?")

    def save(self, path) -> Path:
        cols = dict(zip(self.columns, np.hstack([self.axes, self.errors_um]).T))
        folder = Path(path).parent
        meta = {k: (_relative_to(str(v), folder) if k in PATH_KEYS else v) for k, v in self.meta.items()}
        lines = ["format: volcomp-featurepoints/1"] + [f"{k}: {v}" for k, v in meta.items()]
        return write_csv(path, cols, header_comments=lines, float_fmt="%.12g")

    @classmethod
    def load(cls, path) -> "FeaturePoints":
        t = read_table(path, "featurepoints")
        meta = t.meta()
        # feature points name their axis columns in the header (axis_columns: ...); an older grinder's file does not
        names = tuple(c.strip() for c in meta["axis_columns"].split(",")) if "axis_columns" in meta else COLUMNS[:3]
        cols = names + COLUMNS[3:]
        t.require(*cols)
        data = np.stack([t.float(c) for c in cols], axis=1)
        if len(t) < 10:
            raise InputError(f"{path}: expected at least 10 feature points, got {len(t)}")
        for k in PATH_KEYS:
            if k in meta:
                meta[k] = _resolve(meta[k], Path(path).parent)
        k = len(names)
        return cls(data[:, :k], data[:, k:], meta, str(path), np.array([t.row_number(k) for k in range(len(t))]),
                   axis_columns=names)


DEFAULT_GRID = 21
"""Feature points per axis of ``volcomp featurepoints`` / ``simulate`` / ``demo`` on a machine of up to three axes: a
node at every element station of the simulated truth (21 per axis), where the measured best training setting
(training.DEFAULT_PHYSICS) meets 0.0267 μm on the grid and 0.1 μm between its nodes (docs/decisions/020-benchmark-notebook.md, "The surrogate
network on feature points"; on the 11^3 grid no learner gets under 1 μm between nodes)."""


def default_grid(n_axes: int) -> int:
    """Points per axis when none are given: :data:`DEFAULT_GRID` on up to three axes; on more, the largest count
    whose grid has no more points than DEFAULT_GRID³ (9,261: five axes get 6)."""
    if n_axes <= 3:
        return DEFAULT_GRID
    n = int(round(DEFAULT_GRID ** (3 / n_axes)))
    return n if n ** n_axes <= DEFAULT_GRID ** 3 else n - 1


def make_feature_points(machine, field, n: int | None = None, meta: dict | None = None) -> FeaturePoints:
    """Evaluate ``field.predict`` on the n×n×n grid (``n`` None: :func:`default_grid` of the machine's axes)."""
    if n is None:
        n = default_grid(grid_axes(machine, 1).shape[1])
    axes = grid_axes(machine, n)
    k = axes.shape[1]
    m = {"machine": machine.name, "machine_file": machine.path, "machine_sha256": machine.sha256,
         "grid": "x".join([str(n)] * k)}
    m.update(meta or {})
    names = machine.axis_columns
    m["axis_columns"] = ",".join(names)   # every machine's (a file without them is an older grinder's)
    return FeaturePoints(axes, field.predict(axes), m, axis_columns=tuple(names))
