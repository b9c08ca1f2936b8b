"""ISO 230-1 per-axis tables of a machine-tool chain's element set (``volcomp export --format
iso-tables --machine mill-xyz``), checked before writing.

Files (CSV, ``#`` header lines with the machine, its SHA-256 and the model):

* ``iso_<W>.csv`` for every axis ``W`` with component errors: the position column (``x_mm``,
  ``c_deg``) and one column per component error under its ISO name and unit (``EXX_um … ECX_urad``,
  the chain's own derived names, :attr:`errormap.mt_chain.MachineTool.iso_names`), rows equally
  spaced over the calibrated range (a full-turn rotary axis: one turn, last row = first);
* ``iso_constants.csv``: the location errors (ISO 230-7) and squareness errors, one row each
  (``name, iso, value, unit``).

Values are the element values in the chain file's conventions (``docs/machines.md``: each
component error applied right after its axis' motion, in the frame it moves in; squareness as the
file names it) — a controller reading these must apply them with the same chain.

The check (:func:`check_chain_tables`): a controller interpolates every component LINEARLY between
rows. At seeded random points over the calibrated volume the spatial error rebuilt from the table
(exact chain, :meth:`MachineTool.spatial_error`) is compared with the model's: the difference is
what the table leaves after an exact compensation with it (the MODEL residual of the table, μm),
beside no compensation (the model's error itself); with a truth element set the same against the
truth (TRUE residual). Rows are doubled from the stations' count until the model residual meets the
tolerance (at most :data:`MAX_ROWS`).
"""
from __future__ import annotations

import numpy as np

from errormap.io import write_csv

from .export import node_means

MAX_ROWS = 4097
"""Most rows per axis table (a controller's table is bounded; 4,097 rows of a 1 m stroke are 0.25 mm apart)."""


def _rows_axis(elements, a, n_rows):
    s = elements.stations[a.column]
    return np.linspace(s[0], s[-1], n_rows)


def chain_tables(elements, n_rows: int) -> dict:
    """``{word: (positions (m,), values (m, c) in slots_of(word) order)}`` at ``n_rows`` equally
    spaced positions over each axis' stations (the model's own splines)."""
    m = elements.machine
    out = {}
    for a in m.axes:
        names = m.slots_of(a.word)
        if not names:
            continue
        pos = _rows_axis(elements, a, n_rows)
        out[a.word] = (pos, np.asarray(elements.axis_spline(a.word)(pos)).reshape(len(pos), len(names)))
    return out


def table_values(tables: dict, elements, axes) -> np.ndarray:
    """Slot values (n, P) at ``axes`` (n, k) as a controller reads them from ``tables``: each
    component linearly between rows (a full-turn axis folded into its turn), constants as they are."""
    m = elements.machine
    axes = np.atleast_2d(np.asarray(axes, dtype=float))
    idx = {n: p for p, n in enumerate(m.slot_names)}
    out = np.zeros((len(axes), len(m.slots)))
    for j, a in enumerate(m.axes):
        if a.word not in tables:
            continue
        pos, val = tables[a.word]
        x = elements.wrap(a.column, axes[:, j]) if a.full_turn else np.clip(axes[:, j], pos[0], pos[-1])
        for c, name in enumerate(m.slots_of(a.word)):
            out[:, idx[name]] = np.interp(x, pos, val[:, c])
    for k, v in elements.constants.items():
        out[:, idx[k]] = v
    return out


def _stats(d) -> dict:
    n = np.linalg.norm(d, axis=1)
    return {"n": int(len(n)), "max_um": float(n.max()), "p95_um": float(np.percentile(n, 95)), "mean_um": float(n.mean())}


def check_points(elements, n: int, seed) -> np.ndarray:
    """Seeded random axes (n, k) over the calibrated volume (stations' range; strokes elsewhere)."""
    m = elements.machine
    lo = np.array([elements.stations[a.column][0] if a.column in elements.stations else a.stroke[0] for a in m.axes])
    hi = np.array([elements.stations[a.column][-1] if a.column in elements.stations else a.stroke[1] for a in m.axes])
    return np.random.default_rng(seed).uniform(lo, hi, (n, len(m.axes)))


def check_chain_tables(tables, elements, axes, truth=None) -> dict:
    """Model (and with ``truth`` true) residual the tables leave at ``axes`` (module docstring)."""
    m = elements.machine
    e_model = m.spatial_error(axes, elements.values(axes))
    e_table = m.spatial_error(axes, table_values(tables, elements, axes))
    out = {"model": _stats(e_table - e_model), "baseline_none": {"model": _stats(e_model)}}
    if truth is not None:
        e_true = m.spatial_error(axes, truth.values(axes))
        out["true"] = _stats(e_table - e_true)
        out["baseline_none"]["true"] = _stats(e_true)
        out["baseline_exact"] = {"true": _stats(e_model - e_true)}
    return out


def build_chain_tables(elements, tolerance_um: float, axes, truth=None):
    """Tables with rows doubled from the largest station count until the model residual at ``axes``
    is within ``tolerance_um`` (or :data:`MAX_ROWS`): ``(tables, n_rows, check)``."""
    n = max(len(s) for s in elements.stations.values()) if elements.stations else 2
    while True:
        tables = chain_tables(elements, n)
        check = check_chain_tables(tables, elements, axes, truth)
        if check["model"]["max_um"] <= tolerance_um or 2 * n - 1 > MAX_ROWS:
            return tables, n, check
        n = 2 * n - 1


def write_chain_tables(tables, elements, folder, model_desc: str) -> list:
    """``iso_<W>.csv`` per axis and ``iso_constants.csv`` (module docstring), each written atomically."""
    from pathlib import Path
    m = elements.machine
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    slot = {s.name: s for s in m.slots}
    head = [f"machine: {m.name}", f"machine_sha256: {m.sha256}", f"model: {model_desc}",
            "interpolation: linear between rows; values in the chain file's conventions (docs/machines.md)"]
    written = []
    for a in m.axes:
        if a.word not in tables:
            continue
        pos, val = tables[a.word]
        cols = {a.column: pos}
        for c, name in enumerate(m.slots_of(a.word)):
            cols[f"{slot[name].iso}_{slot[name].unit}"] = val[:, c]
        written.append(write_csv(folder / f"iso_{a.word}.csv", cols,
                                 header_comments=[f"format: volcomp-iso-table/1 axis {a.word}"] + head,
                                 float_fmt="%.9g"))
    names = list(m.constant_slots)
    rows = {"name": np.array(names, dtype=object), "iso": np.array([slot[k].iso for k in names], dtype=object),
            "value": np.array([elements.constants[k] for k in names]),
            "unit": np.array([slot[k].unit for k in names], dtype=object)}
    written.append(write_csv(folder / "iso_constants.csv", rows,
                             header_comments=["format: volcomp-iso-constants/1"] + head, float_fmt="%.9g"))
    return written


# -- a 3-D grid over the linear axes ------------------------------------------------------------
MAX_GRID_NODES = 2_000_000
"""Most nodes of a chain's grid (3 values each: 6e6 numbers, a ~150 MB CSV)."""


def linear_only(machine) -> None:
    """ValueError unless every axis of ``machine`` is linear: a grid over the linear axes alone cannot
    hold an error that depends on a rotary axis."""
    rot = [a.column for a in machine.axes if a.kind != "linear"]
    if rot:
        raise ValueError(f"a grid over the linear axes cannot hold errors that depend on the rotary axes "
                         f"{', '.join(rot)} of {machine.name!r}; use --format iso-tables")


def chain_grid(elements, field, n: int):
    """``(ticks per axis, values (n_1, …, n_k, 3) μm, interpolator)``: the field at the nodes of a
    regular grid of ``n`` ticks per axis over the calibrated volume; trilinear between nodes (points
    outside the grid clamped to it)."""
    from scipy.interpolate import RegularGridInterpolator
    m = elements.machine
    ticks = [np.linspace(elements.stations[a.column][0], elements.stations[a.column][-1], n)
             if a.column in elements.stations else np.linspace(*a.stroke, n) for a in m.axes]
    nodes = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, len(ticks))
    vals = np.asarray(field.predict(nodes)).reshape(*[len(t) for t in ticks], 3)
    interp = RegularGridInterpolator(ticks, vals, method="linear")

    def grid_predict(axes):
        axes = np.array(axes, dtype=float, copy=True)
        for j, t in enumerate(ticks):
            axes[:, j] = np.clip(axes[:, j], t[0], t[-1])
        return interp(axes)
    return ticks, vals, grid_predict


def build_chain_grid(elements, field, tolerance_um: float, axes, truth_field=None):
    """The grid with ticks per axis doubled (11, 21, 41 …) until the interpolated field is within
    ``tolerance_um`` of the model at ``axes`` (or :data:`MAX_GRID_NODES`): ``(ticks, values, n, check)``."""
    linear_only(elements.machine)
    k = len(elements.machine.axes)
    e_model = field.predict(axes)
    n = 11
    while True:
        ticks, vals, grid = chain_grid(elements, field, n)
        e_grid = grid(axes)
        check = {"model": _stats(e_grid - e_model), "baseline_none": {"model": _stats(e_model)}}
        if truth_field is not None:
            e_true = truth_field.predict(axes)
            check["true"] = _stats(e_grid - e_true)
            check["baseline_none"]["true"] = _stats(e_true)
            check["baseline_exact"] = {"true": _stats(e_model - e_true)}
        if check["model"]["max_um"] <= tolerance_um or (2 * n - 1) ** k > MAX_GRID_NODES:
            return ticks, vals, n, check
        n = 2 * n - 1


def write_chain_grid(ticks, vals, machine, folder, model_desc: str):
    """``grid.csv``: the machine's axis columns and ``dx_um, dy_um, dz_um`` at every node (first axis
    slowest), written atomically."""
    from pathlib import Path
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    nodes = np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1).reshape(-1, len(ticks))
    v = vals.reshape(-1, 3)
    cols = {c: nodes[:, j] for j, c in enumerate(machine.axis_columns)}
    cols.update({"dx_um": v[:, 0], "dy_um": v[:, 1], "dz_um": v[:, 2]})
    head = ["format: volcomp-grid/1", f"machine: {machine.name}", f"machine_sha256: {machine.sha256}",
            f"model: {model_desc}", f"ticks: {' x '.join(str(len(t)) for t in ticks)} (first axis slowest)",
            "interpolation: trilinear between nodes; volumetric error of the tool point in the workpiece frame, um"]
    return [write_csv(folder / "grid.csv", cols, header_comments=head, float_fmt="%.9g")]


# -- LinuxCNC per-joint tables of the joints the exact solver moves -------------------------------
JOINT_SAMPLES = 48
"""Positions of the other axes each node's correction is averaged over (as the grinder's per-joint tables)."""
TABLE_TEMP_C = 20.0
"""A pitch table has no temperature input: a thermal term of the model is evaluated at the reference temperature."""


class ChainJointTables:
    """Per-joint LinuxCNC tables of the joints the exact chain solver moves (a mill's X Y Z; a lathe's X, Z
    and C): ``nominal[j]``, ``forward[j]``, ``reverse[j]`` (m,) in the joint's unit (mm; deg for a rotary
    joint) — the positions joint ``j`` (lower-case axis word) actually reaches when commanded to ``nominal``
    approaching in + / − direction. ``joints``: ``{j: index into machine.axes}``; ``units``: ``{j: "mm" |
    "deg"}``; ``turns``: ``{j: first node}`` for a full-turn rotary joint, whose table covers one turn and
    is read with the position folded into it. Written by the grinder's writer
    (:func:`compensation.export.write_joint_tables`)."""

    kind = "linuxcnc"

    def __init__(self, nominal: dict, forward: dict, reverse: dict, joints: dict, units: dict | None = None,
                 turns: dict | None = None):
        self.nominal, self.forward, self.reverse, self.joints = nominal, forward, reverse, joints
        self.units = units if units is not None else {j: "mm" for j in nominal}
        self.turns = turns or {}

    def actual(self, j: str):
        return self.forward[j], self.reverse[j]

    def command(self, axes, dirs) -> np.ndarray:
        """Motor commands (n, k) for nominal axes ``axes`` (n, k) approached in ``dirs`` (n, k) ±1: each
        tabulated joint ``q + (q − actual(q))``, linear between lines, clamped to the table (a full-turn
        joint: its position folded into the table's turn first); other axes as given."""
        axes = np.asarray(axes, dtype=float)
        out = axes.copy()
        for j, k in self.joints.items():
            nom = self.nominal[j]
            q = axes[:, k]
            if j in self.turns:
                q = self.turns[j] + np.mod(q - self.turns[j], 360.0)
            act = np.where(dirs[:, k] >= 0, np.interp(q, nom, self.forward[j]), np.interp(q, nom, self.reverse[j]))
            out[:, k] = axes[:, k] + (np.interp(q, nom, nom) - act)
        return out

    def n_values(self) -> int:
        return int(sum(3 * v.size for v in self.nominal.values()))


def _range(elements, a) -> tuple:
    s = elements.stations.get(a.column)
    return (float(s[0]), float(s[-1])) if s is not None else tuple(a.stroke)


def model_at(field_, machine, dirs, constant: bool = False) -> object:
    """``field_`` with the conditions its terms need: the approach directions ``dirs`` (n, k) ±1 and the
    reference temperature :data:`TABLE_TEMP_C`; ``constant``: ``dirs`` is one row (1, k) given as constants
    (the field then takes any number of points)."""
    needs = tuple(getattr(field_, "needs", ()))
    if not needs:
        return field_
    if constant:
        cond = {f"dir_{a.word.lower()}": float(dirs[0, j]) for j, a in enumerate(machine.axes)}
        cond["temp_c"] = TABLE_TEMP_C
        return field_.with_conditions({c: cond[c] for c in needs})
    cond = {f"dir_{a.word.lower()}": dirs[:, j] for j, a in enumerate(machine.axes)}
    cond["temp_c"] = np.full(len(dirs), TABLE_TEMP_C)
    return field_.with_conditions({c: cond[c] for c in needs})


def exact_corrections(field_, machine, axes, dirs):
    """The exact chain solver's axis correction (n, k) at nominal ``axes`` approached in ``dirs``, and its
    success mask (n,). The points are solved in groups of equal approach directions on the axes the field's
    terms need, each group with its conditions as constants (the solver evaluates the field on subsets of
    the points it is given: per-point condition arrays would not follow them); a field without conditions
    is one group, solved as given."""
    from .solvers import solve
    from .solvers.chain_exact import nominal_and_jacobian
    needs = set(getattr(field_, "needs", ()))
    cols = [j for j, a in enumerate(machine.axes) if f"dir_{a.word.lower()}" in needs]
    keys, group = np.unique(np.asarray(dirs, float)[:, cols], axis=0, return_inverse=True)
    group = np.asarray(group).ravel()
    c, ok = np.empty_like(np.asarray(axes, float)), np.empty(len(axes), bool)
    for g in range(len(keys)):
        idx = np.flatnonzero(group == g) if len(keys) > 1 else slice(None)
        q = axes[idx]
        d = np.asarray(dirs, float)[idx][:1]   # one row: the group's directions, as constants
        targets, _ = nominal_and_jacobian(machine, q)
        fld = model_at(field_, machine, d, constant=True)
        r = solve("exact", fld, targets, machine, target_axes=q, progress=False)
        c[idx], ok[idx] = r.axes - q, np.asarray(r.success, bool)
    return c, ok


def weighted_node_means(nom, c, ok, w, empty_message: str) -> np.ndarray:
    """Per table node the ``w``-weighted mean correction over its compensable samples (``c``, ``ok``, ``w``
    (n_nodes, samples)); nodes with none take their neighbours' interpolation (as :func:`node_means`)."""
    ww = np.where(ok, w, 0.0)
    tot = ww.sum(axis=1)
    good = tot > 0
    if not good.any():
        raise ValueError(empty_message)
    mean = (ww * np.where(ok, c, 0.0)).sum(axis=1) / np.where(good, tot, 1.0)
    mean[~good] = np.interp(nom[~good], nom[good], mean[good])
    return mean


ROTARY_WEIGHTS = ("r2", "plain")
"""How a rotary joint's samples are averaged: ``r2`` (the least-squares angle, the default) or ``plain`` (the
unweighted mean of the linear joints; kept for the benchmark's comparison)."""


def chain_joint_tables(field_, elements, n_points: int, samples: int = JOINT_SAMPLES, seed=0,
                       rotary_weight: str = "r2", region: dict | None = None) -> ChainJointTables:
    """One table per joint the exact chain solver moves (:func:`compensation.solvers.chain_exact.solved_and_kept`:
    a mill's X, Y, Z; a lathe's X, Z and C; rotary joints it keeps get none): at ``n_points`` nominal positions
    over its calibrated range, the exact correction of that joint averaged over ``samples`` seeded positions of
    the other axes (their approach directions drawn ±1); ``forward`` with the joint approached in +, ``reverse``
    in − (equal unless the model has a reversal term on that joint). Nodes where no sample is compensable take
    their neighbours' values.

    A rotary joint's table is in degrees. Its samples are weighted by ``r²`` (``r`` the tool point's distance
    from the axis, from the chain's axis Jacobian): the node value is the least-squares angle over the samples'
    tool-point displacements ``r·Δθ`` (a plain mean would be ruled by the samples near the axis, where a small
    sideways error needs a large turn). A full-turn joint's table covers one turn of its calibrated range, the
    last line equal to the first.

    ``region``: ``{column: (lo, hi)}`` (a part's working region, as the grinder's ``--region``): the other axes'
    samples are drawn inside it instead of over the whole calibrated range; each joint's own nodes still span
    its calibrated range. A range outside the calibrated one is a ValueError naming it (the model says nothing
    reliable there)."""
    from .solvers.chain_exact import nominal_and_jacobian, rotary_radius_mm, solved_and_kept
    if rotary_weight not in ROTARY_WEIGHTS:
        raise ValueError(f"Expected rotary_weight in {ROTARY_WEIGHTS}, got {rotary_weight!r}")
    m = elements.machine
    sol, _ = solved_and_kept(m)
    rng = np.random.default_rng(seed)
    lo = np.array([_range(elements, a)[0] for a in m.axes])
    hi = np.array([_range(elements, a)[1] for a in m.axes])
    box_lo, box_hi = region_box(m, lo, hi, region)
    needs = set(getattr(field_, "needs", ()))
    nominal, fwd, rev, joints, units, turns = {}, {}, {}, {}, {}, {}
    for k in sol:
        k = int(k)
        a = m.axes[k]
        j = a.word.lower()
        rotary = a.kind != "linear"
        nom = np.linspace(lo[k], hi[k], n_points)
        q = np.repeat(rng.uniform(box_lo, box_hi, (samples, len(m.axes)))[None], n_points, axis=0)
        q[:, :, k] = nom[:, None]
        q = q.reshape(-1, len(m.axes))
        d = np.repeat(rng.choice([-1.0, 1.0], (samples, len(m.axes)))[None], n_points, axis=0).reshape(-1, len(m.axes))
        w = rotary_radius_mm(nominal_and_jacobian(m, q)[1][:, :, k]).reshape(n_points, samples) ** 2 if rotary else None
        if rotary and rotary_weight == "plain":
            w = np.ones_like(w)
        out = []
        for sign in ((1.0, -1.0) if f"dir_{j}" in needs else (1.0,)):
            d[:, k] = sign
            c, ok = exact_corrections(field_, m, q, d)
            c, ok = c[:, k].reshape(n_points, samples), ok.reshape(n_points, samples)
            msg = f"joint {a.word}: the model cannot be compensated at any sampled point"
            mean = weighted_node_means(nom, c, ok, w, msg) if rotary else node_means(nom, c, ok, msg)[0]
            if rotary and a.full_turn and hi[k] - lo[k] >= 360.0 - 1e-9:
                mean[-1] = mean[0]  # one turn: the last line is the first
            out.append(nom - mean)
        nominal[j], fwd[j], rev[j], joints[j] = nom, out[0], out[-1], k
        units[j] = "deg" if rotary else "mm"
        if rotary and a.full_turn and hi[k] - lo[k] >= 360.0 - 1e-9:
            turns[j] = float(lo[k])
    return ChainJointTables(nominal, fwd, rev, joints, units, turns)


def region_box(machine, lo, hi, region: dict | None) -> tuple:
    """The sampling box ``(lo, hi)`` (k,) of :func:`chain_joint_tables`: the calibrated ``lo``, ``hi`` with the
    ranges of ``region`` (``{column: (lo, hi)}``) in place of their axes'; ValueError for an unknown column or a
    range outside the calibrated one."""
    box_lo, box_hi = np.array(lo, float), np.array(hi, float)
    cols = list(machine.axis_columns)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(np.r_[box_lo, box_hi]))))
    for c, (a, b) in (region or {}).items():
        if c not in cols:
            raise ValueError(f"region: no axis column {c!r} on machine {machine.name!r} (columns: {', '.join(cols)})")
        k = cols.index(c)
        if not (box_lo[k] - tol <= a <= b <= box_hi[k] + tol):
            raise ValueError(f"region {c} {a:g}:{b:g} leaves the calibrated range {box_lo[k]:g}:{box_hi[k]:g}")
        box_lo[k], box_hi[k] = a, b
    return box_lo, box_hi


def check_chain_joint_tables(tables: ChainJointTables, field_, machine, axes, dirs, truth=None) -> dict:
    """MODEL residual (and with ``truth`` TRUE) the joint tables leave at ``axes`` (n, k) approached in ``dirs``:
    the tool point the model (truth) machine reaches with the table's commands minus the target, beside no
    compensation and the model's exact compensation. ``truth``: ``predict_at(axes, dirs) -> (n, 3)`` μm."""
    from .solvers.chain_exact import nominal_and_jacobian
    targets, _ = nominal_and_jacobian(machine, axes)

    def reached(q, f):
        p, _ = nominal_and_jacobian(machine, q)
        return (p - targets) * 1e3 + f(q)

    def model(q):
        return model_at(field_, machine, dirs).predict(q)
    q_t = tables.command(axes, dirs)
    c, _ = exact_corrections(field_, machine, axes, dirs)
    q_x = axes + c
    out = {"model": _stats(reached(q_t, model)), "baseline_none": {"model": _stats(model(axes))},
           "baseline_exact": {"model": _stats(reached(q_x, model))}}
    if truth is not None:
        def tr(q):
            return truth(q, dirs)
        out["true"] = _stats(reached(q_t, tr))
        out["baseline_none"]["true"] = _stats(tr(axes))
        out["baseline_exact"]["true"] = _stats(reached(q_x, tr))
    return out


def reversal_terms_from_diagnosis(path, machine) -> tuple[list, list]:
    """The terms of a chain loop's ``diagnosis.json`` (``volcomp diagnose --machine``: its ``effects``) that a
    per-joint table carries as its forward/reverse difference (the registry's ``export``, as the grinder's
    :func:`compensation.export.backlash_from_diagnosis`), and labels of the other effects, left out. An
    InputError names the file and key for another machine's diagnosis or anything unreadable."""
    import json
    from pathlib import Path
    from errormap.diagnosis.mt_model import read_terms
    from errormap.effect_kinds import effect_kind
    from errormap.io import InputError, read_document_text
    from .export import BACKLASH_EXPORT
    path = Path(path)
    try:
        d = json.loads(read_document_text(path, "a diagnosis"))
    except (OSError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a readable diagnosis file ({exc})") from None
    if not isinstance(d, dict) or d.get("machine") != machine.name or d.get("machine_sha256") not in (None, machine.sha256):
        got = d.get("machine") if isinstance(d, dict) else None
        raise InputError(f"{path}: key 'machine': expected the diagnosis of `volcomp diagnose --machine {machine.name}`, "
                         f"got {got!r}")
    terms = read_terms(d.get("effects"), machine, path, "effects")
    keep = [t for t in terms if effect_kind(t.kind).export == BACKLASH_EXPORT]
    left = [f"{t.kind}({'*'.join(t.axes)}) on {t.element}" for t in terms
            if effect_kind(t.kind).export != BACKLASH_EXPORT]
    return keep, left
