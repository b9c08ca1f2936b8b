"""Controller compensation tables from an error model, each checked against the model before writing.

Three table formats of a volumetric error model (``FORMATS``), and a drift model's coefficients
(``drift``, at the end), each with a writer, a reader and a *controller simulation* — how
a controller uses the table — so that :func:`check_export` can report, before anything is
written, the error the table leaves:

``iso-tables``
    Per-axis ISO 230-1 component tables (``iso_X.csv``, ``iso_Z.csv``, ``iso_A.csv``: one row per
    position, six components) and the location errors (``iso_location.csv``), in the naming,
    signs and reference points of :mod:`errormap.iso230`. Controller: a kinematic (volumetric)
    compensation that interpolates every component *linearly* between rows, rebuilds the
    23-element rigid-body model from them, and solves for the axis command that puts the tool on
    the target. The number of rows is chosen to meet the tolerance.
``grid``
    A regular 3D grid over the axis space (x_mm, z_mm, a_deg; A over one turn) of the volumetric
    error (WCS, tool actual − nominal, μm) — ``grid.csv``. Controller: *trilinear* interpolation
    between the eight surrounding nodes (A periodic, X/Z clamped to the grid), then the same
    solve. The spacing is chosen to meet the tolerance.
``linuxcnc``
    One file per joint (``joint_x.comp``, ``joint_z.comp``, ``joint_a.comp``), LinuxCNC style:
    lines ``nominal forward reverse`` (mm, mm, deg), at most 256 lines, increasing nominal.
    ``forward``/``reverse`` are the positions the joint *actually* reaches when commanded to
    ``nominal`` moving in the + / − direction; the controller commands
    ``nominal + (nominal − actual)``, interpolated linearly (A folded into one turn, as a
    wrapped rotary joint). A joint's correction may depend on that joint's position only, so
    the volumetric correction is projected onto one function per joint: its mean over the
    other axes, sampled over the fitting region (``region``, default the whole strokes). What
    that cannot represent — every coupling between axes — is left in the residual, and the
    check shows how much. Reversal comes from a diagnosed backlash (``diagnosis.json``
    reversal terms on a joint's own positioning element ``dx_x``, ``dz_z``, ``ex_a``);
    without one, forward == reverse.

The check (:func:`check_export`) re-simulates the controller on the flute path and on random
points over the volume and reports the **model residual** (``fwd(q_c) + E(q_c) − p_d`` with the
model ``E``, μm) and, given a simulated truth machine, the **true residual** (where the truth
puts the tool minus the target), beside two baselines: no compensation, and the model's own
exact compensation (what ``volcomp compensate --method exact`` leaves).

``drift`` (:func:`export_drift_coefficients`)
    A thermal-drift model (``volcomp.drift_model`` JSON from ``volcomp diagnose --drift``) as the
    discrete-time coefficients a controller runs at a fixed sample period (``drift_coefficients.csv``:
    one row per first-order filter — input, a = exp(−dt/τ), b = 1 − a, delay in samples, a gain per
    channel — and an offset row, with pseudo-code in the header). Its check re-simulates that
    recursion from the file alone on a log and compares it with ``DriftModel.predict`` (model
    residual) and, on a simulated log, with the noise-free displacement (true residual).
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from errormap.effect_kinds import diagnosed_kind
from errormap.elements import ElementSet
from errormap.field import CalibratedVolume
from errormap.htm import IDX, spatial_error_exact
from errormap.io import InputError, read_document_text, read_table, write_csv, write_json
from errormap.stats import residual_stats
from errormap.iso230 import ISO_MEANING, ISO_NAMES, from_iso, reference_points_mm, to_iso
from errormap.kinematics import forward
from errormap.simulator import random_axes

FORMATS = ("iso-tables", "grid", "linuxcnc")
"""The table formats of a volumetric error model; ``drift`` (a drift model's coefficients) is apart."""
ALL_FORMATS = FORMATS + ("drift",)
LINUXCNC_MAX_POINTS = 256
"""LinuxCNC's limit on compensation triplets per joint."""
AXIS_KEYS = ("x_mm", "z_mm", "a_deg")
JOINTS = ("x", "z", "a")
ISO_AXIS_COLUMNS = {
    "X": ("x_mm", ("EXX", "EYX", "EZX", "EAX", "EBX", "ECX")),
    "Z": ("z_mm", ("EXZ", "EYZ", "EZZ", "EAZ", "EBZ", "ECZ")),
    "A": ("a_deg", ("EXA", "EYA", "EZA", "EAA", "EBA", "ECA")),
}
ISO_LOCATION = ("EY0A", "EZ0A", "EB0A", "EC0A", "EB0Z")
OWN_ELEMENT = {"x": "dx_x", "z": "dz_z", "a": "ex_a"}
"""The element that is a joint's own positioning error (a reversal on it is a joint backlash)."""
OWN_TO_JOINT_UNIT = {"x": 1e-3, "z": 1e-3, "a": np.rad2deg(1e-6)}
"""μm -> mm for X and Z; μrad -> deg for A."""
MAX_ISO_ROWS = 4096
MAX_GRID_NODES = 2_000_000
REFINE_STEPS = 12
REFINE_FACTOR = 0.8
"""Grid spacing is shrunk by this factor per refinement step until the tolerance is met."""
ISO_FORMAT = "volcomp-iso-table/1"
GRID_FORMAT = "volcomp-grid/1"


def _unit(name: str) -> str:
    return "um" if name[1] in "XYZ" else "urad"


def _fold_a(a_deg, a0: float) -> np.ndarray:
    return a0 + np.mod(np.asarray(a_deg, dtype=float) - a0, 360.0)


def _interp_periodic(a_deg, ticks, values):
    """Linear interpolation over one turn (``ticks`` span 360°), values shape (m, k) -> (n, k)."""
    a = _fold_a(a_deg, ticks[0])
    return np.stack([np.interp(a, ticks, values[:, j]) for j in range(values.shape[1])], axis=1)


def _interp_clamped(x, ticks, values):
    return np.stack([np.interp(x, ticks, values[:, j]) for j in range(values.shape[1])], axis=1)


# -- the model: elements plus an optional diagnosed reversal -------------------------------------
@dataclass
class ModelError:
    """The model's spatial error (μm) at axes: an element set (the HTM model) or any error field
    (``predict(axes) -> (n, 3)``, e.g. the learned network), plus optional reversal terms
    ``{joint: backlash}`` added to the joint's own element as ``b/2·dir`` (dir = ±1, the approach
    direction; element sets only)."""

    machine: object
    elements: ElementSet | None = None
    backlash: dict = field(default_factory=dict)
    field: object = None

    def __post_init__(self):
        if (self.elements is None) == (self.field is None):
            raise ValueError("Expected exactly one of elements (ElementSet) or field (predict(axes))")
        if self.backlash and self.elements is None:
            raise ValueError("Expected an element-set model to carry a reversal (backlash) term")

    @property
    def a0_deg(self) -> float:
        return float(self.elements.stations["a_deg"][0] if self.elements is not None
                     else self.machine.strokes["a_deg"][0])

    def __call__(self, axes, dirs=None) -> np.ndarray:
        axes = np.asarray(axes, dtype=float)
        if self.elements is None:
            a = axes.copy()
            a[:, 2] = _fold_a(a[:, 2], self.a0_deg)
            return np.asarray(self.field.predict(a), dtype=float)
        v = self.elements.values(axes)
        for j, b in self.backlash.items():
            d = np.ones(len(axes)) if dirs is None else dirs[:, JOINTS.index(j)]
            v[:, IDX[OWN_ELEMENT[j]]] += 0.5 * b * d
        return spatial_error_exact(self.machine, axes, v)


# -- ISO component tables -----------------------------------------------------------------------
@dataclass
class IsoTables:
    """Per-axis ISO component tables: ``positions[body]`` shape (m,), ``values[body]`` shape (m, 6)
    in the order of ``ISO_AXIS_COLUMNS[body]``; ``location`` maps the five location names to values."""

    positions: dict
    values: dict
    location: dict
    kind = "iso-tables"

    def iso_values(self, axes) -> np.ndarray:
        """The 23 ISO values at axes, linearly interpolated, shape (n, 23) in ISO_NAMES order."""
        axes = np.asarray(axes, dtype=float)
        out = np.zeros((axes.shape[0], 23))
        for b, (key, names) in ISO_AXIS_COLUMNS.items():
            col = axes[:, AXIS_KEYS.index(key)]
            f = _interp_periodic if b == "A" else _interp_clamped
            out[:, [ISO_NAMES.index(n) for n in names]] = f(col, self.positions[b], self.values[b])
        for n in ISO_LOCATION:
            out[:, ISO_NAMES.index(n)] = self.location[n]
        return out

    def field(self, machine) -> "TableField":
        def predict(axes):
            axes = np.asarray(axes, dtype=float)
            return spatial_error_exact(machine, axes, from_iso(self.iso_values(axes), axes, machine))
        return TableField(predict)

    def n_values(self) -> int:
        return sum(v.size + p.size for v, p in zip(self.values.values(), self.positions.values())) + len(self.location)


@dataclass
class TableField:
    """An error field (``predict(axes) -> (n, 3) μm``) as the controller evaluates it from a table.

    No optional capabilities and no calibrated volume of its own (:mod:`errormap.field`): it is
    compared with the model it was sampled from, not used to guard commands.
    """

    fn: object
    capabilities = frozenset()
    calibrated_volume = None

    def predict(self, axes):
        return self.fn(np.asarray(axes, dtype=float))

    __call__ = predict


def iso_tables_from_model(elements: ElementSet, machine, n_rows: dict) -> IsoTables:
    """Sample the model's ISO components at ``n_rows[body]`` equally spaced positions per axis."""
    pos, val = {}, {}
    for b, (key, names) in ISO_AXIS_COLUMNS.items():
        st = elements.stations[key]
        lo, hi = st[0], st[-1]
        t = np.linspace(lo, hi, int(n_rows[b]))
        axes = np.zeros((t.size, 3))
        axes[:, AXIS_KEYS.index(key)] = t
        iso = to_iso(elements.values(axes), axes, machine)
        pos[b] = t
        val[b] = iso[:, [ISO_NAMES.index(n) for n in names]]
    iso0 = to_iso(elements.values(np.zeros((1, 3))), np.zeros((1, 3)), machine)[0]
    loc = {n: float(iso0[ISO_NAMES.index(n)]) for n in ISO_LOCATION}
    return IsoTables(pos, val, loc)


def _iso_header(machine, body: str, model_desc: str) -> list[str]:
    ref = reference_points_mm(machine, np.zeros((1, 3)))[body][0]
    where = {"X": "the X carriage origin (l5 + x, 0, l6)", "Z": "the Z carriage origin RotZ(theta1)·(l2, 0, l1 + z)",
             "A": "the A-axis end on the X carriage (l5 + x + l7, 0, l6 + l8)"}[body]
    carries = {"X": "workpiece", "Z": "wheel", "A": "workpiece"}[body]
    return [f"format: {ISO_FORMAT}",
            f"axis: {body}",
            f"reference point: {where}; at the stroke origin ({ref[0]:.4f}, {ref[1]:.4f}, {ref[2]:.4f}) mm in the MCS",
            f"sign: error motion of the {body} body (carries the {carries}) relative to its nominal pose, fixed "
            "machine frame (MCS) axes; translations um along +X/+Y/+Z, angles urad right-handed about +X/+Y/+Z"
            + ("; the tool moves relative to the workpiece by minus this" if carries == "workpiece" else
               "; the tool moves relative to the workpiece by this"),
            "interpolation: linear between rows" + (" (one turn, periodic)" if body == "A" else ""),
            f"model: {model_desc}", f"machine: {machine.name} sha256 {machine.sha256}"]


def write_iso_tables(tables: IsoTables, folder, machine, model_desc: str) -> list[Path]:
    folder = Path(folder)
    out = []
    for b, (key, names) in ISO_AXIS_COLUMNS.items():
        cols = {key: tables.positions[b]}
        for j, n in enumerate(names):
            cols[f"{n}_{_unit(n)}"] = tables.values[b][:, j]
        out.append(write_csv(folder / f"iso_{b}.csv", cols, _iso_header(machine, b, model_desc), "%.12g"))
    loc = {"name": np.array(ISO_LOCATION), "value": np.array([tables.location[n] for n in ISO_LOCATION]),
           "unit": np.array([_unit(n) for n in ISO_LOCATION]), "meaning": np.array([ISO_MEANING[n] for n in ISO_LOCATION])}
    head = [f"format: {ISO_FORMAT}", "axis: location",
            "reference point: the A-axis end on the X carriage (A line offsets and tilts); the Z stroke origin (EB0Z)",
            "sign: MCS axes; EB0Z > 0 tilts the Z line of motion towards +X; EY0A/EZ0A > 0 shift the A axis line "
            "along +Y/+Z; EB0A/EC0A right-handed tilts of the A line about +Y/+Z",
            f"model: {model_desc}", f"machine: {machine.name} sha256 {machine.sha256}"]
    out.append(write_csv(folder / "iso_location.csv", loc, head, "%.12g"))
    return out


def _meta_format(table, want: str) -> None:
    got = table.meta().get("format")
    if got != want:
        raise InputError(f"{table.path}: header line 'format': expected {want!r}, got {got!r}")


def read_iso_tables(folder) -> IsoTables:
    """Read ``iso_X.csv``, ``iso_Z.csv``, ``iso_A.csv``, ``iso_location.csv``; errors name file, row, column."""
    folder = Path(folder)
    pos, val = {}, {}
    for b, (key, names) in ISO_AXIS_COLUMNS.items():
        t = read_table(folder / f"iso_{b}.csv")
        _meta_format(t, ISO_FORMAT)
        p = t.float(key)
        if p.size < 2 or np.any(np.diff(p) <= 0):
            k = int(np.argmax(np.diff(p) <= 0)) + 1 if p.size >= 2 else 0
            raise InputError(f"{t.path}: row {t.row_number(k)}, column '{key}': expected increasing positions "
                             f"(at least 2 rows)")
        pos[b] = p
        val[b] = np.stack([t.float(f"{n}_{_unit(n)}") for n in names], axis=1)
    t = read_table(folder / "iso_location.csv")
    _meta_format(t, ISO_FORMAT)
    names = t.raw("name")
    values = t.float("value")
    loc = {}
    for k, (n, v) in enumerate(zip(names, values)):
        if n not in ISO_LOCATION or n in loc:
            raise InputError(f"{t.path}: row {t.row_number(k)}, column 'name': expected each of {list(ISO_LOCATION)} "
                             f"once, got {n!r}")
        loc[n] = float(v)
    if set(loc) != set(ISO_LOCATION):
        raise InputError(f"{t.path}: column 'name': missing {sorted(set(ISO_LOCATION) - set(loc))}")
    return IsoTables(pos, val, loc)


# -- volumetric grid ----------------------------------------------------------------------------
@dataclass
class VolumetricGrid:
    """Volumetric error (WCS, μm) at the nodes of a regular axis grid.

    ``ticks[k]`` shape (m_k,) for x_mm, z_mm, a_deg (A spans one turn, last tick = first + 360);
    ``values`` shape (m_x, m_z, m_a, 3).
    """

    ticks: tuple
    values: np.ndarray
    kind = "grid"
    capabilities = frozenset()  # no optional error-field methods (errormap.field)

    def __post_init__(self):
        self._interp = RegularGridInterpolator(self.ticks, self.values, method="linear")

    def predict(self, axes) -> np.ndarray:
        """Trilinear interpolation; X and Z clamped to the grid, A folded into its turn. (n, 3) -> (n, 3)."""
        axes = np.array(axes, dtype=float, copy=True)
        for k in (0, 1):
            axes[:, k] = np.clip(axes[:, k], self.ticks[k][0], self.ticks[k][-1])
        axes[:, 2] = _fold_a(axes[:, 2], self.ticks[2][0])
        return self._interp(axes)

    __call__ = predict

    def field(self, machine) -> "VolumetricGrid":
        return self

    @property
    def calibrated_volume(self) -> CalibratedVolume:
        """The grid's box: first to last tick per axis (X and Z are clamped outside it)."""
        return CalibratedVolume([t[0] for t in self.ticks], [t[-1] for t in self.ticks])

    @property
    def spacing(self) -> tuple:
        return tuple(float(t[1] - t[0]) for t in self.ticks)

    def n_values(self) -> int:
        return int(self.values.size)


def grid_ticks(machine, a0: float, counts) -> tuple:
    (x0, x1), (z0, z1) = machine.strokes["x_mm"], machine.strokes["z_mm"]
    return (np.linspace(x0, x1, counts[0]), np.linspace(z0, z1, counts[1]), np.linspace(a0, a0 + 360.0, counts[2]))


def grid_from_model(model_error, machine, counts, a0: float = 0.0) -> VolumetricGrid:
    ticks = grid_ticks(machine, a0, counts)
    nodes = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, 3)
    vals = model_error(nodes).reshape(*[len(t) for t in ticks], 3)
    return VolumetricGrid(ticks, vals)


def curvature_counts(model_error, machine, tolerance_um: float, a0: float = 0.0, n_probe: int = 400, seed: int = 0):
    """First guess of the node counts: trilinear interpolation leaves at most ``h²/8·|∂²E/∂q²|`` per
    axis; each axis gets a third of the tolerance, with the largest second difference on probes."""
    rng = np.random.default_rng(seed)
    q = random_axes(machine, n_probe, rng)
    counts = []
    for k, key in enumerate(AXIS_KEYS):
        lo, hi = machine.strokes[key] if k < 2 else (a0, a0 + 360.0)
        h = (hi - lo) / 40.0
        qc = q.copy()
        qc[:, k] = np.clip(qc[:, k], lo + h, hi - h) if k < 2 else qc[:, k]
        qp, qm = qc.copy(), qc.copy()
        qp[:, k] += h
        qm[:, k] -= h
        d2 = np.linalg.norm(model_error(qp) - 2 * model_error(qc) + model_error(qm), axis=1).max() / h**2
        step = np.sqrt(8.0 * (tolerance_um / 3.0) / max(d2, 1e-12))
        counts.append(int(np.clip(np.ceil((hi - lo) / step) + 1, 3, 2001)))
    return counts


def write_grid(grid: VolumetricGrid, folder, machine, model_desc: str) -> Path:
    nodes = np.stack(np.meshgrid(*grid.ticks, indexing="ij"), axis=-1).reshape(-1, 3)
    v = grid.values.reshape(-1, 3)
    head = [f"format: {GRID_FORMAT}",
            "counts: " + " ".join(str(len(t)) for t in grid.ticks),
            "spacing: x_mm {:.9g} z_mm {:.9g} a_deg {:.9g}".format(*grid.spacing),
            "values: volumetric error at the commanded axes, tool actual minus nominal, in the workpiece frame "
            "(WCS), um",
            "order: x slowest, then z, a fastest; a spans one turn (last node = first + 360)",
            "interpolation: trilinear between the 8 surrounding nodes; a periodic, x and z clamped to the grid",
            f"model: {model_desc}", f"machine: {machine.name} sha256 {machine.sha256}"]
    return write_csv(Path(folder) / "grid.csv", {"x_mm": nodes[:, 0], "z_mm": nodes[:, 1], "a_deg": nodes[:, 2],
                                                 "dx_um": v[:, 0], "dy_um": v[:, 1], "dz_um": v[:, 2]}, head, "%.12g")


def read_grid(path) -> VolumetricGrid:
    """Read ``grid.csv``; refuses anything that is not a complete regular grid in the stated order."""
    t = read_table(path)
    _meta_format(t, GRID_FORMAT)
    try:
        counts = [int(c) for c in t.meta().get("counts", "").split()]
    except ValueError:
        counts = []
    if len(counts) != 3 or min(counts) < 2:
        raise InputError(f"{t.path}: header line 'counts': expected three integers >= 2, got {t.meta().get('counts')!r}")
    q = np.stack([t.float(k) for k in AXIS_KEYS], axis=1)
    if q.shape[0] != int(np.prod(counts)):
        raise InputError(f"{t.path}: expected {int(np.prod(counts))} rows for counts {counts}, got {q.shape[0]}")
    ticks = (q[:: counts[1] * counts[2], 0], q[: counts[1] * counts[2]: counts[2], 1], q[: counts[2], 2])
    want = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, 3)
    bad = np.argwhere(np.abs(want - q) > 1e-9 * (1 + np.abs(q)))
    if bad.size:
        k, c = bad[0]
        raise InputError(f"{t.path}: row {t.row_number(int(k))}, column '{AXIS_KEYS[c]}': expected {want[k, c]:.9g} "
                         f"(regular grid, x slowest, a fastest), got {q[k, c]:.9g}")
    for k, tk in enumerate(ticks):
        if np.any(np.diff(tk) <= 0):
            raise InputError(f"{t.path}: column '{AXIS_KEYS[k]}': expected increasing grid ticks")
    if abs(ticks[2][-1] - ticks[2][0] - 360.0) > 1e-6:
        raise InputError(f"{t.path}: column 'a_deg': expected one turn (last = first + 360), got "
                         f"{ticks[2][0]:.9g}..{ticks[2][-1]:.9g}")
    v = np.stack([t.float(k) for k in ("dx_um", "dy_um", "dz_um")], axis=1).reshape(*counts, 3)
    return VolumetricGrid(ticks, v)


# -- LinuxCNC per-joint tables ------------------------------------------------------------------
@dataclass
class JointTables:
    """Per-joint corrections: ``nominal[j]`` shape (m,), ``correction[j]`` shape (m,) (joint units:
    mm, mm, deg; added to the command), ``backlash[j]`` (joint units, 0 when not diagnosed)."""

    nominal: dict
    correction: dict
    backlash: dict
    kind = "linuxcnc"
    unfilled: dict = field(default_factory=dict)

    def actual(self, j: str):
        """(forward, reverse) actual positions at the nominal ones: ``nominal − correction ± b/2``."""
        base = self.nominal[j] - self.correction[j]
        b = self.backlash.get(j, 0.0)
        return base + 0.5 * b, base - 0.5 * b

    def command(self, axes, dirs) -> np.ndarray:
        """Motor commands for nominal joint commands ``axes`` (n, 3) moving in ``dirs`` (n, 3) ±1."""
        axes = np.asarray(axes, dtype=float)
        out = axes.copy()
        for k, j in enumerate(JOINTS):
            fwd, rev = self.actual(j)
            nom = self.nominal[j]
            q = _fold_a(axes[:, k], nom[0]) if j == "a" else axes[:, k]
            act = np.where(dirs[:, k] >= 0, np.interp(q, nom, fwd), np.interp(q, nom, rev))
            out[:, k] = axes[:, k] + (np.interp(q, nom, nom) - act)
        return out

    def n_values(self) -> int:
        return int(sum(3 * v.size for v in self.nominal.values()))


def model_corrections(model_error, machine, axes, dirs=None, progress: bool = False):
    """The model's exact axis correction at nominal axes (what the exact solver commands minus the
    nominal axes), shape (n, 3), and a success mask (n,).

    With a reversal in the model the points are solved per approach-direction pattern (at most
    eight), each with its own fixed-direction field, since a solver evaluates fields on subsets.
    """
    from .solvers import solve
    axes = np.asarray(axes, dtype=float)
    c = np.zeros_like(axes)
    ok = np.zeros(len(axes), bool)
    if dirs is None or not getattr(model_error, "backlash", None):
        groups = [(np.arange(len(axes)), None)]
    else:
        key = ((dirs > 0) * np.array([4, 2, 1])).sum(axis=1)
        groups = [(np.flatnonzero(key == k), dirs[np.flatnonzero(key == k)[0]]) for k in np.unique(key)]
    for idx, d in groups:
        if d is None:
            fld = TableField(lambda q: model_error(q))
        else:
            fld = TableField(lambda q, d=d: model_error(q, np.broadcast_to(d, (len(q), 3))))
        res = solve("exact", fld, forward(machine, axes[idx]), machine, target_axes=axes[idx], progress=progress)
        c[idx] = res.axes - axes[idx]
        ok[idx] = np.asarray(res.success, bool)
    return c, ok


def joint_tables_from_model(model_error, machine, n_points: int = LINUXCNC_MAX_POINTS, region: dict | None = None,
                            samples: int = 48, seed: int = 0, backlash: dict | None = None, a0: float = 0.0) -> JointTables:
    """Project the model's correction onto one function per joint.

    For each joint, at ``n_points`` nominal positions over its stroke, the exact correction is
    averaged over ``samples`` random positions of the other two axes inside ``region``
    (``{"x_mm": (lo, hi), "z_mm": (lo, hi)}``, default the strokes); points the model itself
    cannot compensate (outside the solver's ball) are left out of the mean.
    """
    if not 2 <= n_points <= LINUXCNC_MAX_POINTS:
        raise ValueError(f"Expected 2 <= points per joint <= {LINUXCNC_MAX_POINTS}, got {n_points}")
    rng = np.random.default_rng(seed)
    box = {k: tuple(machine.strokes[k]) for k in AXIS_KEYS}
    box["a_deg"] = (a0, a0 + 360.0)
    for k, v in (region or {}).items():
        box[k] = tuple(v)
    nominal, corr, unfilled = {}, {}, {}
    for k, j in enumerate(JOINTS):
        lo, hi = (machine.strokes[AXIS_KEYS[k]] if j != "a" else (a0, a0 + 360.0))
        nom = np.linspace(lo, hi, n_points)
        others = np.column_stack([rng.uniform(*box[key], samples) for key in AXIS_KEYS])
        q = np.repeat(others[None], n_points, axis=0)
        q[:, :, k] = nom[:, None]
        c, ok = model_corrections(model_error, machine, q.reshape(-1, 3))
        c = c[:, k].reshape(n_points, samples)
        ok = ok.reshape(n_points, samples)
        mean, good = node_means(nom, c, ok, f"joint {j}: the model cannot be compensated at any sampled point "
                                            f"of the fitting region")
        unfilled[j] = int((~good).sum())
        if j == "a":
            mean[-1] = mean[0] = 0.5 * (mean[0] + mean[-1])   # one turn closes
        nominal[j], corr[j] = nom, mean
    out = JointTables(nominal, corr, {j: float(b) for j, b in (backlash or {}).items()})
    out.unfilled = unfilled
    return out


def node_means(nom, c, ok, empty_message: str) -> tuple[np.ndarray, np.ndarray]:
    """Per table node the mean correction over its compensable samples: ``c``, ``ok`` (n_nodes, samples)
    at the nodes ``nom`` (n_nodes,). Nodes where no sample is compensable (e.g. on the A axis, outside the
    250 μm ball) take the linear interpolation of their neighbours. Returns ``(mean (n_nodes,), filled
    (n_nodes,) bool)``; ValueError ``empty_message`` when no node has a compensable sample."""
    cnt = ok.sum(axis=1)
    if not np.any(cnt):
        raise ValueError(empty_message)
    mean = np.where(ok, c, 0.0).sum(axis=1) / np.maximum(cnt, 1)
    good = cnt > 0
    mean[~good] = np.interp(nom[~good], nom[good], mean[good])
    return mean, good


def write_joint_tables(tables: JointTables, folder) -> list[Path]:
    """``joint_<j>.comp`` for every joint of ``tables.nominal`` (the grinder's x, z, a; a chain's solved joints,
    :class:`compensation.mt_export.ChainJointTables`): lines ``nominal forward reverse`` in the joint's unit
    (mm; deg for a rotary joint), 9 decimals."""
    from errormap.io import atomic_write
    out = []
    for j in tables.nominal:
        fwd, rev = tables.actual(j)
        path = Path(folder) / f"joint_{j}.comp"
        with atomic_write(path, "w", encoding="utf-8") as fh:
            for a, b, c in zip(tables.nominal[j], fwd, rev):
                fh.write(f"{a:.9f} {b:.9f} {c:.9f}\n")
        out.append(path)
    return out


def read_joint_tables(folder) -> JointTables:
    """Read ``joint_{x,z,a}.comp``: three numbers a line, increasing nominal, at most 256 lines."""
    nominal, corr, back = {}, {}, {}
    for j in JOINTS:
        path = Path(folder) / f"joint_{j}.comp"
        if not path.is_file():
            raise InputError(f"{path}: no such compensation file")
        rows = []
        for ln, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if not line.strip():
                continue
            cells = line.split()
            if len(cells) != 3:
                raise InputError(f"{path}: line {ln}: expected 3 numbers (nominal forward reverse), got {len(cells)}")
            try:
                vals = [float(c) for c in cells]
            except ValueError:
                bad = next(i for i, c in enumerate(cells) if not _is_float(c))
                raise InputError(f"{path}: line {ln}, column {bad + 1}: expected a number, got {cells[bad]!r}") from None
            if not np.all(np.isfinite(vals)):
                raise InputError(f"{path}: line {ln}: expected finite numbers, got {line!r}")
            if rows and vals[0] <= rows[-1][0]:
                raise InputError(f"{path}: line {ln}, column 1: expected increasing nominal positions, got "
                                 f"{vals[0]} after {rows[-1][0]}")
            rows.append(vals)
        if not 2 <= len(rows) <= LINUXCNC_MAX_POINTS:
            raise InputError(f"{path}: expected 2 to {LINUXCNC_MAX_POINTS} lines, got {len(rows)}")
        r = np.array(rows)
        nominal[j] = r[:, 0]
        corr[j] = r[:, 0] - 0.5 * (r[:, 1] + r[:, 2])
        b = r[:, 1] - r[:, 2]
        if np.ptp(b) > 1e-8:
            raise InputError(f"{path}: column 2-3: expected a constant forward − reverse difference (a backlash), "
                             f"got {b.min():.9g}..{b.max():.9g}")
        back[j] = float(b.mean())
    return JointTables(nominal, corr, back)


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


BACKLASH_EXPORT = "linuxcnc-backlash"
"""The registry's ``export`` of a kind a per-joint table carries (:mod:`errormap.effect_kinds`)."""
CHECKS_DIAGNOSIS_FORMAT = "volcomp-checks-diagnosis/1"
"""The ``format`` key of ``diagnosis.json`` written by ``volcomp diagnose CHECKS`` (the drift
diagnosis has its own content and no ``effects``)."""


def backlash_from_diagnosis(path) -> tuple[dict, list[str]]:
    """Joint backlash (in its element's unit, μm or μrad) from ``diagnosis.json`` reversal terms, and the
    effects NOT exported.

    A reversal term on a joint's own positioning element (``dx_x``, ``dz_z``, ``ex_a``) is a
    joint backlash; one on any other element cannot be carried by a per-joint table and is refused.
    Returns ``({joint: backlash_um_or_urad}, [labels of other effects left out])``.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such diagnosis file")
    try:
        d = json.loads(read_document_text(path, "a diagnosis"))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON: {exc}") from None
    fmt = d.get("format") if isinstance(d, dict) else None
    if fmt is not None and fmt != CHECKS_DIAGNOSIS_FORMAT:  # by content; files from before the key: by 'effects'
        raise InputError(f"{path}: key 'format': {str(fmt)!r}; expected {CHECKS_DIAGNOSIS_FORMAT!r} (the "
                         "diagnosis.json of `volcomp diagnose CHECKS`)")
    effects = d.get("effects") if isinstance(d, dict) else None
    if not isinstance(effects, list):
        raise InputError(f"{path}: key 'effects': expected a list of diagnosed effects")
    back, left = {}, []
    for i, e in enumerate(effects):
        if not isinstance(e, dict) or "kind" not in e:
            raise InputError(f"{path}: key 'effects[{i}]': expected an object with 'kind'")
        try:
            spec = diagnosed_kind(e["kind"])  # the registry: an unknown kind is refused, never skipped
        except ValueError as exc:
            raise InputError(f"{path}: key 'effects[{i}].kind': {exc}") from None
        if spec.export != BACKLASH_EXPORT:
            left.append(f"{e.get('kind')}({e.get('axis')}) on {e.get('element')}")
            continue
        j, el = e.get("axis"), e.get("element")
        if j not in OWN_ELEMENT or el != OWN_ELEMENT[j]:
            raise InputError(f"{path}: key 'effects[{i}].element': a per-joint table carries a reversal on the "
                             f"joint's own element ({OWN_ELEMENT}), got reversal({j}) on {el!r}")
        p = (e.get("parameters") or {})
        key = next((k for k in p if k.startswith("backlash_")), None)
        try:
            b = float(p[key]["value"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: key 'effects[{i}].parameters': expected backlash_<unit>.value") from None
        if j in back:
            raise InputError(f"{path}: key 'effects[{i}]': a second reversal term on joint {j}")
        back[j] = b
    return back, left


# -- drift model: coefficient form for a controller's fixed sample period ------------------------
DRIFT_FORMAT = "volcomp-drift-coefficients/1"
DRIFT_FILE = "drift_coefficients.csv"
DRIFT_CONST = "const"
"""Input name of the offset row: a constant 1 through a pass-through filter, gains = intercepts."""
DRIFT_TICK_EPS_S = 1e-3
"""A logged sample counts as available at a controller tick when its time is at most 1 ms after
the tick (log times are written with finite digits; without this a tick equal to a sample time
could miss it by rounding)."""
DRIFT_MAX_PERIOD_S = 3600.0
DRIFT_PSEUDO_CODE = (
    "pseudo-code (run once per sample period dt; every row r is one filter, the last row the offset):",
    "  at power-on (k = 0): v_r = (u_r / scale_r) ** power_r; y_r = v_r; fill buf_r with y_r",
    "  every tick k:  v_r = (u_r / scale_r) ** power_r      # u_r = latest valid reading of input_r",
    "                 y_r = a_r * y_r + b_r * v_r           # first-order lag, a = exp(-dt/tau_s), b = 1 - a",
    "                 push y_r into buf_r (ring of delay_samples_r + 2 values)",
    "                 f_r = (1 - delay_frac_r) * buf_r[k - delay_samples_r] + delay_frac_r * buf_r[k - delay_samples_r - 1]",
    "                 pred_<ch>_um = sum over rows r of gain_<ch>_r * f_r",
    "                 axis command -= pred_<ch>_um          # compensate by subtracting the prediction",
    "  input_r = const: u = 1 (a = 0, b = 1, no delay): its gains are the channels' offsets in um",
    "  a missed or invalid reading: use the last valid value of that input and still run the tick",
    "  a tick period dt' other than dt: a = exp(-dt'/tau_s), b = 1 - a for that tick (tau_s = 0: a = 0);",
    "  delay_samples/delay_frac hold for dt only",
    "updating the gains (how these coefficients change on the machine): the gains are fixed between exports;",
    "  `volcomp drift-predict MODEL LOG --update --save-model NEW.json` re-fits each channel's offset and gains",
    "  from on-machine measurements of <ch>_um by a Kalman filter on the parameters (random walk, opened up on",
    "  a 3-sigma innovation); `volcomp export NEW.json --format drift` then writes the new gain_<ch> columns.",
    "  The filter rows (input, scale, power, tau_s, a, b, delay) do not change in an update: only gain_<ch>.",
    "distance rule (export.json controller.distance_shrink, where a channel has one): the gains above are the model",
    "  inside the fitting data's range. Per tick, rho = |(u - mean) . W| / range_distance over the raw inputs listed",
    "  there; beyond rho = 1 the controller blends toward the baseline gains: pred = base + g * (pred - base),",
    "  g = exp(-(rho - 1) / scale); base = sum over rows r of base_gain_<ch>_r * f_r. The 95 % band grows as",
    "  band95_um * max(1, rho) ** band_gamma. Where a channel lists feature_distance, rho is the larger of that and the same",
    "  distance over the filter outputs f_r of its listed rows (its own filtered inputs: a slow state can leave its",
    "  range while every raw input stays inside). A controller that does not run the rule runs the gains as written.",
)


def _base_gains(c, keys) -> list:
    """A channel's OLS baseline (``ChannelFit.base``) in the coefficient file's rows: one gain per feature ``keys``
    (the model's features, in order) and the offset last."""
    bf, ba, bc = c.base
    g = np.zeros(len(keys) + 1)
    for f, b in zip(bf, bc):
        g[keys.index(f.key)] += float(b)
    g[-1] = float(ba)
    return g.tolist()


def drift_distance_rule(model, coef: DriftCoefficients) -> dict | None:
    """The per-sample shrinkage toward the baseline, in the coefficient file's rows: {"inputs", "mean", "whiten",
    "range_distance", "rule", "channels": {ch: {"scale", "base_gains" (m,), "band95_um", "band_gamma"}}}, or None when no
    channel has one."""
    nov = (model.meta or {}).get("novelty") or {}
    chans = {ch: c for ch, c in model.channels.items() if c.base is not None and np.isfinite(c.shrink_scale)}
    if not chans or not nov.get("range_distance"):
        return None
    keys = [f.key for f in model.features]
    out = {}
    for ch, c in chans.items():
        out[ch] = {"scale": float(c.shrink_scale), "base_gains": _base_gains(c, keys), "band95_um": float(c.band95_um),
                   "band_gamma": float(c.band_gamma)}
        if c.novelty:       # the distance on the channel's own filtered features (rows of the coefficient file)
            nv = c.novelty
            out[ch]["feature_distance"] = {"rows": [keys.index(f.key) for f in nv["features"]],
                                           "mean": np.asarray(nv["mean"], float).tolist(),
                                           "whiten": np.asarray(nv["whiten"], float).tolist(),
                                           "range_distance": float(nv["range_distance"])}
    return {"inputs": list(nov["inputs"]), "mean": list(nov["mean"]), "whiten": nov["whiten"],
            "range_distance": float(nov["range_distance"]),
            "rule": "rho = norm((u - mean) @ whiten) / range_distance on the latest raw inputs; g = 1 for rho <= 1, "
                    "exp(-(rho - 1) / scale) beyond; pred = base + g * (gains . f - base), base = base_gains . f "
                    "(same rows as the coefficient file); band = band95_um * max(1, rho) ** band_gamma; where a channel has "
                    "feature_distance: rho = max(rho, norm((f[rows] - mean) @ whiten) / range_distance) over the filter "
                    "outputs f of those coefficient rows",
            "channels": out}


@dataclass
class DriftCoefficients:
    """A drift model as a controller runs it at a fixed sample period ``sample_period_s``.

    One row per filter (``m`` rows, the last the offset row): ``inputs`` (m,) log column names
    (``const`` for the offset), ``scale``, ``power``, ``tau_s``, ``a``, ``b`` (m,) — the recursion
    ``y ← a·y + b·v`` with ``a = exp(−dt/τ)``, ``b = 1 − a`` — ``delay_samples`` (m,) int and
    ``delay_frac`` (m,) in [0, 1): the delay ``delay_s/dt = n + frac`` read from the ring buffer as
    ``(1 − frac)·y[k−n] + frac·y[k−n−1]``; ``gains`` {channel: (m,)} (gain units ``gain_unit``).
    """

    sample_period_s: float
    inputs: list
    scale: np.ndarray
    power: np.ndarray
    tau_s: np.ndarray
    a: np.ndarray
    b: np.ndarray
    delay_samples: np.ndarray
    delay_frac: np.ndarray
    gains: dict
    gain_unit: list
    kind = "drift"

    def n_values(self) -> int:
        return int(len(self.inputs) * (7 + len(self.gains)))   # scale, power, tau_s, a, b, delay (2), gains


def drift_coefficients(model, sample_period_s: float) -> DriftCoefficients:
    """The controller coefficient form of a :class:`~errormap.diagnosis.drift_models.DriftModel`."""
    dt = float(sample_period_s)
    if not (np.isfinite(dt) and 0 < dt <= DRIFT_MAX_PERIOD_S):
        raise ValueError(f"Expected a sample period in (0, {DRIFT_MAX_PERIOD_S:g}] s, got {sample_period_s}")
    feats = model.features
    keys = [f.key for f in feats]
    tau = np.array([f.tau_s for f in feats] + [0.0])
    a = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    d = np.array([f.delay_s for f in feats] + [0.0]) / dt
    n = np.floor(d + 1e-9).astype(int)
    frac = d - n
    frac[np.abs(frac) < 1e-9] = 0.0
    gains = {}
    for ch, c in model.channels.items():
        g = np.zeros(len(feats) + 1)
        for f, coef in zip(c.features, c.coef):
            g[keys.index(f.key)] += float(coef)
        g[-1] = c.intercept_um
        gains[ch] = g
    return DriftCoefficients(dt, [f.input for f in feats] + [DRIFT_CONST],
                             np.array([f.scale for f in feats] + [1.0]), np.array([f.power for f in feats] + [1]),
                             tau, a, 1.0 - a, n, np.clip(frac, 0.0, 1.0), gains,
                             [f.unit() for f in feats] + ["um"])


def _input_unit(name: str) -> str:
    return "degC" if name.startswith("temp_") else "rpm" if name == "speed_rpm" else "1"


def write_drift_coefficients(coef: DriftCoefficients, folder, model_desc: str) -> Path:
    """``drift_coefficients.csv``: one row per filter, a ``gain_<ch>`` column per channel."""
    cols = {"row": np.array([f"f{i}" for i in range(len(coef.inputs) - 1)] + ["offset"]),
            "input": np.array(coef.inputs), "input_unit": np.array([_input_unit(i) for i in coef.inputs]),
            "scale": coef.scale.astype(float), "power": np.array([str(int(p)) for p in coef.power]),
            "tau_s": coef.tau_s, "a": coef.a, "b": coef.b,
            "delay_samples": np.array([str(int(k)) for k in coef.delay_samples]), "delay_frac": coef.delay_frac,
            "gain_unit": np.array(coef.gain_unit)}
    for ch, g in coef.gains.items():
        cols[f"gain_{ch}"] = g
    head = [f"format: {DRIFT_FORMAT}",
            f"sample_period_s: {coef.sample_period_s:.15g}",
            "channels: " + " ".join(coef.gains),
            "outputs: pred_<ch>_um = predicted thermal displacement of channel <ch>, um (subtract it)",
            "units: time s, temperature degC, speed rpm, displacement um; gain_unit per row",
            *DRIFT_PSEUDO_CODE,
            f"model: {model_desc}"]
    return write_csv(Path(folder) / DRIFT_FILE, cols, head, "%.15g")


def read_drift_coefficients(path) -> DriftCoefficients:
    """Read ``drift_coefficients.csv``; errors name the file, row and column."""
    t = read_table(path)
    _meta_format(t, DRIFT_FORMAT)
    try:
        dt = float(t.meta().get("sample_period_s", ""))
    except ValueError:
        dt = float("nan")
    if not (np.isfinite(dt) and 0 < dt <= DRIFT_MAX_PERIOD_S):
        raise InputError(f"{t.path}: header line 'sample_period_s': expected a period in (0, {DRIFT_MAX_PERIOD_S:g}] s, "
                         f"got {t.meta().get('sample_period_s')!r}")
    t.require("input", "scale", "power", "tau_s", "a", "b", "delay_samples", "delay_frac", "gain_unit")
    chans = [n[5:] for n in t.names if n.startswith("gain_") and n != "gain_unit"]
    if not chans or len(t) < 1:
        raise InputError(f"{t.path}: expected at least one 'gain_<channel>' column and one row")
    a, b, frac, tau = t.float("a"), t.float("b"), t.float("delay_frac"), t.float("tau_s")
    scale = t.float("scale")
    for name, v, ok in (("scale", scale, scale > 0), ("a", a, (a >= 0) & (a < 1)), ("b", b, np.abs(a + b - 1) <= 1e-12),
                        ("delay_frac", frac, (frac >= 0) & (frac < 1)), ("tau_s", tau, tau >= 0)):
        bad = np.flatnonzero(~ok)
        if bad.size:
            want = {"scale": "scale > 0", "a": "0 <= a < 1", "b": "b = 1 - a", "delay_frac": "0 <= delay_frac < 1",
                    "tau_s": "tau_s >= 0"}
            raise InputError(f"{t.path}: row {t.row_number(int(bad[0]))}, column '{name}': expected {want[name]}, "
                             f"got {v[bad[0]]:.15g}")
    inputs = t.raw("input")
    if inputs[-1] != DRIFT_CONST:
        raise InputError(f"{t.path}: row {t.row_number(len(t) - 1)}, column 'input': expected the offset row "
                         f"{DRIFT_CONST!r} last, got {inputs[-1]!r}")
    return DriftCoefficients(dt, inputs, scale, t.int("power"), tau, a, b,
                             t.int("delay_samples"), frac, {ch: t.float(f"gain_{ch}") for ch in chans},
                             t.raw("gain_unit"))


def controller_drift(coef: DriftCoefficients, time_s, inputs: dict) -> tuple[np.ndarray, dict]:
    """Run the coefficients as a controller does, deliberately plainly: one tick every
    ``sample_period_s`` from ``time_s[0]``, each tick reading the latest logged value at or before it
    (sample and hold), the recursion, the delay ring buffer, the gains.

    ``time_s`` (n,) log times; ``inputs`` {input name: (n,)} logged values (gaps already held).
    Returns ``(ticks_s (K,), {channel: (K,) prediction um})``. Independent of
    :func:`errormap.diagnosis.drift_models.feature_matrix` on purpose: it uses the file's numbers only.
    """
    time_s = np.asarray(time_s, float)
    dt = coef.sample_period_s
    n_ticks = int(np.floor((time_s[-1] - time_s[0]) / dt + 1e-9)) + 1
    ticks = time_s[0] + dt * np.arange(n_ticks)
    src = np.searchsorted(time_s, ticks + DRIFT_TICK_EPS_S, side="right") - 1
    U = np.stack([np.ones(len(time_s)) if name == DRIFT_CONST else np.asarray(inputs[name], float)
                  for name in coef.inputs], axis=1)
    V = (U / coef.scale) ** coef.power                             # (n, m)
    G = np.stack([coef.gains[ch] for ch in coef.gains], axis=1)    # (m, c)
    n, fr = coef.delay_samples.astype(int), coef.delay_frac
    L = int(n.max()) + 2
    cols = np.arange(len(coef.inputs))
    y = V[src[0]].copy()
    buf = np.tile(y, (L, 1))
    out = np.empty((n_ticks, G.shape[1]))
    for k in range(n_ticks):
        y = coef.a * y + coef.b * V[src[k]]
        buf[k % L] = y
        f = (1.0 - fr) * buf[(k - n) % L, cols] + fr * buf[(k - n - 1) % L, cols]
        out[k] = f @ G
    return ticks, {ch: out[:, j] for j, ch in enumerate(coef.gains)}


def controller_drift_at(coef: DriftCoefficients, log) -> dict:
    """The controller's prediction in force at each log time (its latest tick at or before it): {ch: (n,)}."""
    from errormap.diagnosis.drift_models import input_values
    inputs = {name: input_values(log, name) for name in set(coef.inputs) - {DRIFT_CONST}}
    ticks, pred = controller_drift(coef, log.time_s, inputs)
    j = np.searchsorted(ticks, log.time_s + DRIFT_TICK_EPS_S, side="right") - 1
    return {ch: p[j] for ch, p in pred.items()}


def check_drift_export(coef: DriftCoefficients, model, log, clean_um: dict | None = None) -> dict:
    """Re-simulate the controller from ``coef`` on ``log`` and compare, per channel:

    ``model`` — controller − ``model.predict(log)`` (the discretisation error of the export);
    ``measured`` (when the log has the channel) — displacement − controller, beside ``before``
    (the displacement itself), ``volcomp`` (displacement − the fixed model the gains run) and
    ``volcomp_distance_rule`` (displacement − model.predict with the per-sample shrinkage toward OLS);
    ``true`` (``clean_um`` of a simulated log) — the same three against the noise-free displacement.
    Returns ``{channel: {...}}``; statistics are max |·| and RMS over the log's samples (μm).
    """
    ctrl = controller_drift_at(coef, log)
    fixed = model.predict(log, distance_shrink=False)     # what the gains run (the rule beyond d0 is the controller's)
    pred = model.predict(log)
    out = {}
    for ch in model.channels:
        rec = {"model": residual_stats(ctrl[ch] - fixed[ch]), "measured": None, "true": None}
        for key, d in (("measured", log.disp_um.get(ch)), ("true", (clean_um or {}).get(ch))):
            if d is not None:
                rec[key] = {"controller": residual_stats(d - ctrl[ch]), "before": residual_stats(d),
                            "volcomp": residual_stats(d - fixed[ch]),
                            "volcomp_distance_rule": residual_stats(d - pred[ch])}
        out[ch] = rec
    return out


def worst_drift_model_um(check: dict) -> float:
    return max(r["model"]["max_um"] for r in check.values())


def export_drift_coefficients(model, folder, sample_period_s: float, log, model_desc: str,
                              tolerance_um: float, clean_um: dict | None = None, force: bool = False) -> dict:
    """Write ``drift_coefficients.csv`` into ``folder`` (a staging folder), read it back, re-simulate the
    controller from the file alone on ``log`` and check it; returns ``{"check", "worst_model_residual_um",
    "tolerance_met", "file"}``. Raises :class:`ValueError` when the tolerance is not met and not ``force``
    (the caller discards the staging folder: nothing is written)."""
    coef = drift_coefficients(model, sample_period_s)
    path = write_drift_coefficients(coef, folder, model_desc)
    back = read_drift_coefficients(path)
    check = check_drift_export(back, model, log, clean_um)
    worst = worst_drift_model_um(check)
    met = worst <= tolerance_um
    if not met and not force:
        raise ValueError(f"tolerance not met: at a sample period of {sample_period_s:g} s the drift coefficients leave "
                         f"a model residual up to {worst:.4g} um > --tolerance-um {tolerance_um:g}; nothing written "
                         "(--force writes anyway, recorded in export.json)")
    return {"check": check, "worst_model_residual_um": worst, "tolerance_met": bool(met), "file": path,
            "coefficients": back}


# -- the check ----------------------------------------------------------------------------------
def motion_dirs(axes) -> np.ndarray:
    """Approach direction (±1) of each joint along a path, shape (n, 3): the sign of the next
    nominal move; a joint that does not move keeps its last direction (+1 at the start)."""
    axes = np.asarray(axes, dtype=float)
    d = np.sign(np.diff(axes, axis=0, prepend=axes[:1]))
    out = np.ones_like(d)
    for k in range(3):
        last = 1.0
        nz = np.flatnonzero(d[:, k])
        if nz.size:
            last = d[nz[0], k]
        for i in range(len(d)):
            if d[i, k] != 0:
                last = d[i, k]
            out[i, k] = last
    return out


def check_sets(machine, n_volume: int = 2000, seed: int = 0, flute=None) -> dict:
    """The check's point sets: the flute path (its nominal axes, motion directions) and ``n_volume``
    random points over the strokes (random approach directions); each ``(targets, axes, dirs)``."""
    from .toolpath import flute_path
    fp = flute if flute is not None else flute_path()
    ax = fp.axes(machine)
    ss = np.random.SeedSequence(seed).spawn(2)
    q = random_axes(machine, n_volume, np.random.default_rng(ss[0]))
    dirs = np.random.default_rng(ss[1]).choice([-1.0, 1.0], size=(n_volume, 3))
    return {"flute": (fp.targets_mm, ax, motion_dirs(ax)), "volume": (forward(machine, q), q, dirs)}


def controller_commands(table, machine, targets, axes, dirs) -> np.ndarray:
    """Axis commands the controller sends with the table: (n, 3)."""
    if table.kind == "linuxcnc":
        return table.command(axes, dirs)
    from .solvers import solve
    res = solve("exact", table.field(machine), targets, machine, target_axes=axes, progress=False)
    return res.axes


def check_export(table, model: ModelError, machine, sets: dict, truth=None, cache: dict | None = None) -> dict:
    """Re-simulate the controller using ``table`` on each point set; residual statistics.

    Returns ``{set: {"model": stats, "true": stats | None, "baseline_none": {...},
    "baseline_exact": {...}, "excluded": k}}`` where the model residual is ``1e3·(fwd(q_c) − p_d)
    + E_model(q_c)`` μm and the true residual ``1e3·(truth.tool_point(q_c) − p_d)`` μm. Points the
    model itself cannot compensate (its exact solution leaves the 250 μm ball) are excluded.
    ``cache`` (a dict kept by the caller for one model and one ``sets``) keeps the exact baseline.
    """
    out = {}
    for name, (targets, axes, dirs) in sets.items():
        if cache is not None and name in cache:
            c_exact, ok = cache[name]
        else:
            c_exact, ok = model_corrections(model, machine, axes, dirs)
            if cache is not None:
                cache[name] = (c_exact, ok)
        targets, axes, dirs = targets[ok], axes[ok], dirs[ok]
        q_exact = axes + c_exact[ok]
        q_c = controller_commands(table, machine, targets, axes, dirs)

        def model_res(q):
            return 1e3 * (forward(machine, q) - targets) + model(q, dirs)

        rec = {"model": residual_stats(model_res(q_c), drop_nonfinite=True), "excluded": int((~ok).sum()),
               "baseline_none": {"model": residual_stats(model_res(axes), drop_nonfinite=True)},
               "baseline_exact": {"model": residual_stats(model_res(q_exact), drop_nonfinite=True)}}
        if truth is not None:
            cond = {"temp_c": np.full(len(axes), 20.0), "dir_x": dirs[:, 0], "dir_z": dirs[:, 1], "dir_a": dirs[:, 2]}

            def true_res(q):
                return 1e3 * (truth.tool_point(q, **cond) - targets)
            rec["true"] = residual_stats(true_res(q_c), drop_nonfinite=True)
            rec["baseline_none"]["true"] = residual_stats(true_res(axes), drop_nonfinite=True)
            rec["baseline_exact"]["true"] = residual_stats(true_res(q_exact), drop_nonfinite=True)
        else:
            rec["true"] = None
        out[name] = rec
    return out


def worst_model_um(check: dict) -> float:
    return max(v["model"]["max_um"] for v in check.values())


def interpolation_error_um(table_field, model: ModelError, sets: dict) -> float:
    """Largest |table field − model| (μm) at the check axes: the cheap bound used to size tables."""
    worst = 0.0
    for _, axes, dirs in sets.values():
        worst = max(worst, float(np.linalg.norm(table_field(axes) - model(axes, dirs), axis=1).max()))
    return worst


# -- building a table to a tolerance -------------------------------------------------------------
def build_table(fmt: str, model: ModelError, machine, tolerance_um: float, sets: dict, *, n_points: int | None = None,
                region: dict | None = None, seed: int = 0, log=None) -> tuple:
    """The table of ``fmt`` sized for ``tolerance_um`` and a dict of how it was sized."""
    say = log or (lambda *_: None)
    a0 = model.a0_deg
    if fmt == "iso-tables":
        if model.elements is None:
            raise ValueError("iso-tables are the 23 elements' components: they need an element-set model (JSON)")
        if model.backlash:
            raise ValueError("iso-tables carry no reversal; a diagnosed backlash is exported by --format linuxcnc")
        n = max(len(s) for s in model.elements.stations.values())
        while True:
            t = iso_tables_from_model(model.elements, machine, {"X": n, "Z": n, "A": n})
            err = interpolation_error_um(t.field(machine), model, sets)
            say(f"iso-tables: {n} rows per axis, interpolation error {err:.4g} um")
            if err <= tolerance_um or 2 * n - 1 > MAX_ISO_ROWS:
                return t, {"rows_per_axis": n, "interpolation_error_um": err}
            n = 2 * n - 1
    if fmt == "grid":
        if model.backlash:
            raise ValueError("the grid carries no reversal; a diagnosed backlash is exported by --format linuxcnc")
        counts = curvature_counts(model, machine, tolerance_um, a0, seed=seed)

        def attempt(c):
            g = grid_from_model(model, machine, c, a0)
            err = interpolation_error_um(g, model, sets)
            say(f"grid: counts {c} spacing {tuple(round(s, 4) for s in g.spacing)}, interpolation error {err:.4g} um")
            return g, err
        g, err = attempt(counts)
        # refine while the tolerance is not met, then coarsen while it still is (fewest nodes that meet it)
        for _ in range(REFINE_STEPS):
            if err <= tolerance_um:
                break
            nxt = [int(np.ceil((c - 1) / REFINE_FACTOR)) + 1 for c in counts]
            if np.prod(nxt) > MAX_GRID_NODES:
                break
            counts = nxt
            g, err = attempt(counts)
        # coarsen one axis at a time (the first guess splits the tolerance evenly; the axes differ)
        for k in (range(3) if err <= tolerance_um else ()):
            for _ in range(REFINE_STEPS):
                nxt = list(counts)
                nxt[k] = max(3, int(np.floor((counts[k] - 1) * REFINE_FACTOR)) + 1)
                if nxt == counts:
                    break
                g2, err2 = attempt(nxt)
                if err2 > tolerance_um:
                    break
                counts, g, err = nxt, g2, err2
        return g, {"counts": list(counts), "spacing": list(g.spacing), "interpolation_error_um": err}
    if fmt == "linuxcnc":
        n = n_points or LINUXCNC_MAX_POINTS
        base = ModelError(machine, model.elements, field=model.field)
        back = {j: b * OWN_TO_JOINT_UNIT[j] for j, b in model.backlash.items()}
        t = joint_tables_from_model(base, machine, n, region=region, seed=seed, backlash=back, a0=a0)
        return t, {"points_per_joint": n, "region": region or "strokes", "samples_per_point": 48,
                   "nodes_filled_from_neighbours": t.unfilled}
    raise ValueError(f"Expected format in {list(FORMATS)}, got {fmt!r}")


TIGHTEN = 0.8
"""When the full check misses the tolerance that the cheap sizing bound met (the controller's
commands lie off the check axes by the correction: up to ~16° in A on the flute), the sizing
target is multiplied by this and the table rebuilt."""
MAX_TIGHTEN = 4


def build_checked_table(fmt: str, model: ModelError, machine, tolerance_um: float, sets: dict, truth=None,
                        cache: dict | None = None, **options) -> tuple:
    """:func:`build_table` then :func:`check_export`; for the sized formats (iso-tables, grid) the
    sizing target is tightened until the check itself meets the tolerance (at most MAX_TIGHTEN
    times). Returns ``(table, sizing, check)``; ``sizing["target_um"]`` is the last target."""
    target = tolerance_um
    for k in range(MAX_TIGHTEN + 1):
        table, sizing = build_table(fmt, model, machine, target, sets, **options)
        check = check_export(table, model, machine, sets, truth, cache)
        if fmt == "linuxcnc" or worst_model_um(check) <= tolerance_um or k == MAX_TIGHTEN:
            sizing["target_um"] = target
            return table, sizing, check
        target *= TIGHTEN


def write_table(table, folder, machine, model_desc: str) -> list[Path]:
    if table.kind == "iso-tables":
        return write_iso_tables(table, folder, machine, model_desc)
    if table.kind == "grid":
        return [write_grid(table, folder, machine, model_desc)]
    return write_joint_tables(table, folder)


def read_back(fmt: str, folder):
    if fmt == "iso-tables":
        return read_iso_tables(folder)
    if fmt == "grid":
        return read_grid(Path(folder) / "grid.csv")
    if fmt == "linuxcnc":
        return read_joint_tables(folder)
    raise ValueError(f"Expected format in {list(FORMATS)}, got {fmt!r}")


@contextlib.contextmanager
def staged_folder(out):
    """A temporary folder beside ``out``; on success its files replace those in ``out``."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o777 & ~mask)  # mkdtemp makes 0700; give the folder the usual mode
    try:
        yield tmp
        if not out.exists():
            os.replace(tmp, out)
        else:
            for p in sorted(tmp.iterdir()):
                os.replace(p, out / p.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def table_bytes(paths) -> int:
    return int(sum(Path(p).stat().st_size for p in paths))


def write_manifest(folder, info: dict) -> Path:
    return write_json(Path(folder) / "export.json", info)


__all__ = ["FORMATS", "ALL_FORMATS", "DriftCoefficients", "drift_coefficients", "read_drift_coefficients",
           "controller_drift", "check_drift_export",
           "LINUXCNC_MAX_POINTS", "ModelError", "IsoTables", "VolumetricGrid", "JointTables",
           "build_table", "check_export", "check_sets", "read_back", "write_table", "backlash_from_diagnosis",
           "export_drift_coefficients", "drift_distance_rule"]
