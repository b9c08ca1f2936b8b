"""The check every controller table passes before it is written, and the sizing it drives.

:func:`check_export` re-simulates the controller using a table on point sets — seeded random points over
the machine's strokes (random approach directions), and on a machine whose chain runs it the default flute
path (its motion directions) — and reports the **model residual** (``1e3·(nominal(q_c) − p_d) + E(q_c)``
with the model ``E``, μm) and, given a simulated truth machine, the **true residual** (where the truth puts
the tool minus the target), beside two baselines: no compensation, and the model's own exact compensation
(what ``volcomp compensate --method exact`` leaves). :func:`build_checked_table` sizes the table for the
tolerance (rows, node counts) and tightens the sizing until the check itself meets it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.stats import residual_stats

from .common import FORMATS, LINUXCNC_MAX_POINTS, TableField
from .grid import MAX_GRID_NODES, VolumetricGrid, REFINE_FACTOR, REFINE_STEPS, curvature_counts, grid_from_model, read_grid, write_grid
from .iso_tables import MAX_ISO_ROWS, IsoTables, iso_tables_from_model, read_iso_tables, write_iso_tables
from .linuxcnc import JOINT_SAMPLES, JointTables, joint_tables_from_model, read_joint_tables, write_joint_tables
from .model import ModelError, exact_corrections, nominal_mm

TIGHTEN = 0.8
"""When the full check misses the tolerance that the cheap sizing bound met (the controller's commands lie
off the check axes by the correction), the sizing target is multiplied by this and the table rebuilt."""
MAX_TIGHTEN = 4


def motion_dirs(axes) -> np.ndarray:
    """Approach direction (±1) of each joint along a path, shape (n, k): the sign of the next nominal move;
    a joint that does not move keeps its last direction (its first move's at the start, else +1)."""
    axes = np.asarray(axes, dtype=float)
    d = np.sign(np.diff(axes, axis=0, prepend=axes[:1]))
    out = np.ones_like(d)
    for k in range(d.shape[1]):
        nz = np.flatnonzero(d[:, k])
        if nz.size:   # forward fill from the latest move (before the first: the first move's)
            out[:, k] = d[np.maximum.accumulate(np.where(d[:, k] != 0, np.arange(len(d)), nz[0])), k]
    return out


def flute_axes(machine, flute=None):
    """``(targets (n, 3) mm, axes (n, k))`` of the flute path (:func:`compensation.toolpath.flute_path`) on a
    machine it runs on (:func:`compensation.toolpath.runs_flute`) that reaches every point of it inside the
    strokes of its axes that do not turn fully, else None."""
    from ..toolpath import check_in_strokes, flute_path, runs_flute
    if not runs_flute(machine):
        return None
    fp = flute if flute is not None else flute_path()
    ax = fp.axes(machine)
    try:
        check_in_strokes(machine, ax)
    except ValueError:
        return None
    return fp.targets_mm, ax


def check_sets(machine, n_volume: int = 2000, seed: int = 0, flute=None) -> dict:
    """The check's point sets ``{name: (targets (n, 3) mm, axes (n, k), dirs (n, k))}``: the flute path where
    the machine runs it (its motion directions) and ``n_volume`` seeded random points over the strokes
    (random approach directions)."""
    k = len(machine.axes)
    out = {}
    fl = flute_axes(machine, flute)
    if fl is not None:
        out["flute"] = (fl[0], fl[1], motion_dirs(fl[1]))
    ss = np.random.SeedSequence(seed).spawn(2)
    lo, hi = machine.stroke_lo, machine.stroke_hi
    q = lo + (hi - lo) * np.random.default_rng(ss[0]).random((n_volume, k))
    dirs = np.random.default_rng(ss[1]).choice([-1.0, 1.0], size=(n_volume, k))
    out["volume"] = (nominal_mm(machine, q), q, dirs)
    return out


def point_set(machine, axes, dirs=None) -> tuple:
    """One check set ``(targets (n, 3) mm, axes (n, k), dirs (n, k))`` at given axes (dirs None: all +)."""
    axes = np.asarray(axes, dtype=float)
    return nominal_mm(machine, axes), axes, np.ones_like(axes) if dirs is None else np.asarray(dirs, float)


def volume_points(elements, n: int, seed) -> np.ndarray:
    """Seeded uniform random axes (n, k) over an element set's calibrated volume (its stations' range per
    axis; the stroke of an axis without stations)."""
    m = elements.machine
    lo = np.array([elements.stations[a.column][0] if a.column in elements.stations else a.stroke[0] for a in m.axes])
    hi = np.array([elements.stations[a.column][-1] if a.column in elements.stations else a.stroke[1] for a in m.axes])
    return np.random.default_rng(seed).uniform(lo, hi, (n, len(m.axes)))


def solved_commands(table, machine, targets, axes) -> np.ndarray:
    """Axis commands (n, k) of a volumetric controller: the exact solve on the table's values as the controller
    reads them (a plain field over the machine's axes, which the solver differentiates)."""
    from ..solvers import solve
    fld = TableField(table.field(machine).predict)
    return solve("exact", fld, targets, machine, target_axes=axes, progress=False).axes


def controller_commands(table, machine, targets, axes, dirs) -> np.ndarray:
    """Axis commands (n, k) the controller sends with the table: per-joint tables command each joint from its
    own table; the volumetric formats solve for the target (:func:`solved_commands`)."""
    if isinstance(table, JointTables):
        return table.command(axes, dirs)
    return solved_commands(table, machine, targets, axes)


def check_export(table, model: ModelError, machine, sets: dict, truth=None, cache: dict | None = None) -> dict:
    """Re-simulate the controller using ``table`` on each point set; residual statistics
    ``{set: {"model", "true" (None without a truth), "baseline_none", "baseline_exact", "excluded"}}``.
    Points the model itself cannot compensate (its exact solution leaves the solver's ball) are excluded.
    ``truth(q, dirs) -> (n, 3)`` mm tool points; ``cache`` (kept by the caller for one model and one ``sets``)
    keeps the exact baseline."""
    out = {}
    for name, (targets, axes, dirs) in sets.items():
        if cache is not None and name in cache:
            c_exact, ok = cache[name]
        else:
            c_exact, ok = exact_corrections(model, machine, axes, dirs)
            if cache is not None:
                cache[name] = (c_exact, ok)
        targets, axes, dirs = targets[ok], axes[ok], dirs[ok]
        q_exact = axes + c_exact[ok]
        q_c = controller_commands(table, machine, targets, axes, dirs)

        def model_res(q):
            return 1e3 * (nominal_mm(machine, q) - targets) + model(q, dirs)

        rec = {"model": residual_stats(model_res(q_c), drop_nonfinite=True), "excluded": int((~ok).sum()),
               "baseline_none": {"model": residual_stats(model_res(axes), drop_nonfinite=True)},
               "baseline_exact": {"model": residual_stats(model_res(q_exact), drop_nonfinite=True)}}
        rec["true"] = None
        if truth is not None:
            def true_res(q):
                return 1e3 * (truth(q, dirs) - targets)
            rec["true"] = residual_stats(true_res(q_c), drop_nonfinite=True)
            rec["baseline_none"]["true"] = residual_stats(true_res(axes), drop_nonfinite=True)
            rec["baseline_exact"]["true"] = residual_stats(true_res(q_exact), drop_nonfinite=True)
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


def _size_iso(model, machine, tolerance_um, sets, say):
    if model.elements is None:
        raise ValueError("iso-tables are the elements' components: they need an element-set model (JSON)")
    if model.reversal:
        raise ValueError("iso-tables carry no reversal; a diagnosed backlash is exported by --format linuxcnc")
    n = max(len(s) for s in model.elements.stations.values())
    while True:
        t = iso_tables_from_model(model.elements, machine, n)
        err = interpolation_error_um(t.field(machine), model, sets)
        say(f"iso-tables: {n} rows per axis, interpolation error {err:.4g} um")
        if err <= tolerance_um or 2 * n - 1 > MAX_ISO_ROWS:
            return t, {"rows_per_axis": n, "interpolation_error_um": err}
        n = 2 * n - 1


def _size_grid(model, tolerance_um, sets, seed, say):
    if model.needs:
        raise ValueError("the grid carries no reversal or temperature; a diagnosed backlash is exported by "
                         "--format linuxcnc")
    counts = curvature_counts(model, tolerance_um, seed=seed)

    def attempt(c):
        g = grid_from_model(model, c)
        err = interpolation_error_um(g, model, sets)
        say(f"grid: counts {c} spacing {tuple(round(s, 4) for s in g.spacing)}, interpolation error {err:.4g} um")
        return g, err
    if np.prod(counts) > MAX_GRID_NODES:
        raise ValueError(f"grid: the model's curvature needs {int(np.prod(counts))} nodes for the tolerance, more "
                         f"than {MAX_GRID_NODES}; a larger --tolerance-um, or --format iso-tables / linuxcnc")
    g, err = attempt(counts)
    for _ in range(REFINE_STEPS):  # refine while the tolerance is not met ...
        if err <= tolerance_um:
            break
        nxt = [int(np.ceil((c - 1) / REFINE_FACTOR)) + 1 for c in counts]
        if np.prod(nxt) > MAX_GRID_NODES:
            break
        counts = nxt
        g, err = attempt(counts)
    for k in (range(len(counts)) if err <= tolerance_um else ()):  # ... then coarsen one axis at a time
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


def build_table(fmt: str, model: ModelError, machine, tolerance_um: float, sets: dict, *, n_points: int | None = None,
                region: dict | None = None, seed=0, log=None) -> tuple:
    """The table of ``fmt`` sized for ``tolerance_um`` and a dict of how it was sized (``seed``: the grid's
    curvature probes, the per-joint tables' samples)."""
    say = log or (lambda *_: None)
    if fmt == "iso-tables":
        return _size_iso(model, machine, tolerance_um, sets, say)
    if fmt == "grid":
        return _size_grid(model, tolerance_um, sets, seed, say)
    if fmt == "linuxcnc":
        n = n_points or LINUXCNC_MAX_POINTS
        t = joint_tables_from_model(model, machine, n, seed=seed, region=region)
        return t, {"points_per_joint": n, "region": region or "calibrated volume", "samples_per_point": JOINT_SAMPLES,
                   "nodes_filled_from_neighbours": t.unfilled}
    raise ValueError(f"Expected format in {list(FORMATS)}, got {fmt!r}")


def build_checked_table(fmt: str, model: ModelError, machine, tolerance_um: float, sets: dict, truth=None,
                        cache: dict | None = None, **options) -> tuple:
    """:func:`build_table` then :func:`check_export`; for the sized formats (iso-tables, grid) the sizing
    target is tightened until the check itself meets the tolerance (at most MAX_TIGHTEN times). Returns
    ``(table, sizing, check)``; ``sizing["target_um"]`` is the last target."""
    target = tolerance_um
    for k in range(MAX_TIGHTEN + 1):
        table, sizing = build_table(fmt, model, machine, target, sets, **options)
        check = check_export(table, model, machine, sets, truth, cache)
        if isinstance(table, JointTables) or worst_model_um(check) <= tolerance_um or k == MAX_TIGHTEN:
            sizing["target_um"] = target
            return table, sizing, check
        target *= TIGHTEN


WRITERS = {IsoTables: lambda t, folder, machine, desc: write_iso_tables(t, folder, machine, desc),
           VolumetricGrid: lambda t, folder, machine, desc: [write_grid(t, folder, machine, desc)],
           JointTables: lambda t, folder, machine, desc: write_joint_tables(t, folder)}
READERS = {IsoTables: lambda t, folder, machine: read_iso_tables(folder, machine),
           VolumetricGrid: lambda t, folder, machine: read_grid(Path(folder) / "grid.csv", machine),
           JointTables: lambda t, folder, machine: read_joint_tables(folder, t)}
"""Each table type's writer and reader (the files of :mod:`.iso_tables`, :mod:`.grid`, :mod:`.linuxcnc`)."""


def write_table(table, folder, machine, model_desc: str) -> list:
    return WRITERS[type(table)](table, folder, machine, model_desc)


def read_back(table, folder, machine):
    """The table ``table`` as read back from ``folder``."""
    return READERS[type(table)](table, folder, machine)


def table_difference_um(table, back, machine, sets) -> float:
    """Largest difference (μm, or μm-equivalent of the joint commands: μm and millidegrees) between two tables
    as the controller uses them, at the check axes."""
    worst = 0.0
    for targets, axes, dirs in sets.values():
        if isinstance(table, JointTables):
            d = (table.command(axes, dirs) - back.command(axes, dirs)) * 1e3
        else:
            d = table.field(machine)(axes) - back.field(machine)(axes)
        worst = max(worst, float(np.abs(d).max()))
    return worst
