"""``grid``: the volumetric error on a regular grid over every axis of a machine tool (``grid.csv``).

The nodes span each linear axis' stroke and a full-turn rotary axis' turn (last node = first + 360); the
values are the volumetric error at the commanded axes (tool actual minus nominal, workpiece frame, μm).
Controller (the check): multilinear interpolation between the ``2^k`` surrounding nodes (trilinear on a
three-axis machine), full-turn axes periodic, every other axis clamped to the grid; then the exact solve.
The node counts come from the model's curvature and are refined, then coarsened axis by axis, to the
fewest that meet the tolerance.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from errormap.field import CalibratedVolume
from errormap.io import InputError, read_table, write_csv

from .common import FULL_TURN_DEG, fold, meta_format

GRID_FORMAT = "volcomp-grid/1"
MAX_GRID_NODES = 2_000_000
REFINE_STEPS = 12
REFINE_FACTOR = 0.8
"""Grid spacing is shrunk by this factor per refinement step until the tolerance is met."""
VALUE_COLUMNS = ("dx_um", "dy_um", "dz_um")


@dataclass
class VolumetricGrid:
    """Volumetric error (WCS, μm) at the nodes of a regular axis grid: ``ticks[j]`` (m_j,) per axis,
    ``values`` (m_1, …, m_k, 3); ``periodic[j]``: axis j spans one turn (last tick = first + 360)."""

    ticks: tuple
    values: np.ndarray
    periodic: tuple
    kind = "grid"
    capabilities = frozenset()  # no optional error-field methods (errormap.field)

    def __post_init__(self):
        self._interp = RegularGridInterpolator(self.ticks, self.values, method="linear")

    def predict(self, axes) -> np.ndarray:
        """Multilinear interpolation; full-turn axes folded into their turn, the others clamped. (n, k) -> (n, 3)."""
        axes = np.array(axes, dtype=float, copy=True)
        for j, t in enumerate(self.ticks):
            axes[:, j] = fold(axes[:, j], t[0]) if self.periodic[j] else np.clip(axes[:, j], t[0], t[-1])
        return self._interp(axes)

    __call__ = predict

    def field(self, machine) -> "VolumetricGrid":
        return self

    @property
    def calibrated_volume(self) -> CalibratedVolume:
        """The grid's box: first to last tick per axis."""
        return CalibratedVolume([t[0] for t in self.ticks], [t[-1] for t in self.ticks])

    @property
    def spacing(self) -> tuple:
        return tuple(float(t[1] - t[0]) for t in self.ticks)

    def n_values(self) -> int:
        return int(self.values.size)


def grid_span(model, j: int) -> tuple:
    """``(lo, hi)`` of axis j's ticks: the stroke, or a full-turn axis' turn from its start."""
    a = model.mt.axes[j]
    if a.full_turn:
        a0 = model.turn_start(j)
        return a0, a0 + FULL_TURN_DEG
    return float(a.stroke[0]), float(a.stroke[1])


def grid_from_model(model, counts) -> VolumetricGrid:
    ticks = tuple(np.linspace(*grid_span(model, j), counts[j]) for j in range(len(counts)))
    nodes = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, len(ticks))
    vals = model(nodes).reshape(*[len(t) for t in ticks], 3)
    return VolumetricGrid(ticks, vals, tuple(a.full_turn for a in model.mt.axes))


def curvature_counts(model, tolerance_um: float, n_probe: int = 400, seed: int = 0) -> list:
    """First guess of the node counts: multilinear interpolation leaves at most ``h²/8·|∂²E/∂q²|`` per axis;
    each of the k axes gets 1/k of the tolerance, with the largest second difference on probes."""
    mt = model.mt
    k = len(mt.axes)
    rng = np.random.default_rng(seed)
    lo_s, hi_s = mt.stroke_lo, mt.stroke_hi
    q = lo_s + (hi_s - lo_s) * rng.random((n_probe, k))
    counts = []
    for j, a in enumerate(mt.axes):
        lo, hi = grid_span(model, j)
        h = (hi - lo) / 40.0
        qc = q.copy()
        qc[:, j] = qc[:, j] if a.full_turn else np.clip(qc[:, j], lo + h, hi - h)
        qp, qm = qc.copy(), qc.copy()
        qp[:, j] += h
        qm[:, j] -= h
        d2 = np.linalg.norm(model(qp) - 2 * model(qc) + model(qm), axis=1).max() / h**2
        step = np.sqrt(8.0 * (tolerance_um / float(k)) / max(d2, 1e-12))
        counts.append(int(np.clip(np.ceil((hi - lo) / step) + 1, 3, 2001)))
    return counts


def _and(words) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def write_grid(grid: VolumetricGrid, folder, machine, model_desc: str) -> Path:
    k = len(grid.ticks)
    nodes = np.stack(np.meshgrid(*grid.ticks, indexing="ij"), axis=-1).reshape(-1, k)
    v = grid.values.reshape(-1, 3)
    w = [a.word.lower() for a in machine.axes]
    turns = [w[j] for j in range(k) if grid.periodic[j]]
    clamped = [w[j] for j in range(k) if not grid.periodic[j]]
    order = f"order: {w[0]} slowest, then {', '.join(w[1:-1])}, {w[-1]} fastest"
    order += "".join(f"; {t} spans one turn (last node = first + 360)" for t in turns)
    how = "trilinear between the 8" if k == 3 else f"{k}-linear between the {2 ** k}"
    interp = f"interpolation: {how} surrounding nodes; " + (f"{_and(turns)} periodic, " if turns else "")
    interp += f"{_and(clamped)} clamped to the grid" if clamped else ""
    head = [f"format: {GRID_FORMAT}",
            "counts: " + " ".join(str(len(t)) for t in grid.ticks),
            "spacing: " + " ".join(f"{c} {s:.9g}" for c, s in zip(machine.axis_columns, grid.spacing)),
            "values: volumetric error at the commanded axes, tool actual minus nominal, in the workpiece frame "
            "(WCS), um", order, interp.rstrip("; "),
            f"model: {model_desc}", f"machine: {machine.name} sha256 {machine.sha256}"]
    cols = {c: nodes[:, j] for j, c in enumerate(machine.axis_columns)}
    cols.update({c: v[:, i] for i, c in enumerate(VALUE_COLUMNS)})
    return write_csv(Path(folder) / "grid.csv", cols, head, "%.12g")


def read_grid(path, machine) -> VolumetricGrid:
    """Read ``grid.csv`` of ``machine``; refuses anything that is not a complete regular grid in the stated order."""
    k = len(machine.axes)
    t = read_table(path)
    meta_format(t, GRID_FORMAT)
    try:
        counts = [int(c) for c in t.meta().get("counts", "").split()]
    except ValueError:
        counts = []
    if len(counts) != k or min(counts) < 2:
        raise InputError(f"{t.path}: provenance line 'counts' (its sidecar): expected {k} integers >= 2, "
                         f"got {t.meta().get('counts')!r}")
    q = np.stack([t.float(c) for c in machine.axis_columns], axis=1)
    if q.shape[0] != int(np.prod(counts)):
        raise InputError(f"{t.path}: expected {int(np.prod(counts))} rows for counts {counts}, got {q.shape[0]}")
    strides = [int(np.prod(counts[j + 1:])) for j in range(k)]
    ticks = tuple(q[: strides[j] * counts[j]: strides[j], j] for j in range(k))
    want = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, k)
    bad = np.argwhere(np.abs(want - q) > 1e-9 * (1 + np.abs(q)))
    if bad.size:
        r, c = bad[0]
        raise InputError(f"{t.path}: row {t.row_number(int(r))}, column '{machine.axis_columns[c]}': expected "
                         f"{want[r, c]:.9g} (regular grid, first axis slowest), got {q[r, c]:.9g}")
    periodic = tuple(a.full_turn for a in machine.axes)
    for j, tk in enumerate(ticks):
        if np.any(np.diff(tk) <= 0):
            raise InputError(f"{t.path}: column '{machine.axis_columns[j]}': expected increasing grid ticks")
        if periodic[j] and abs(tk[-1] - tk[0] - FULL_TURN_DEG) > 1e-6:
            raise InputError(f"{t.path}: column '{machine.axis_columns[j]}': expected one turn (last = first + 360), got "
                             f"{tk[0]:.9g}..{tk[-1]:.9g}")
    v = np.stack([t.float(c) for c in VALUE_COLUMNS], axis=1).reshape(*counts, 3)
    return VolumetricGrid(ticks, v, periodic)
