"""Compensating tool-path files (``volcomp compensate``) on any machine tool: plan, solve, guard, write.

Every machine tool is its chain (a ``kind = "grinder"`` file read as one, :mod:`errormap.grinder_file`), and
one order of work serves them all, so the output folder only ever holds whole files of one run: every input
read and checked (:func:`compensation.app.workflows.compensate_paths.read_tool_path`) before anything is
written, a non-empty folder refused unless ``force``; the model recognised by content; every point solved
(:mod:`compensation.solvers`) through the chunk plan of :mod:`compensation.batch` (local threads or Ray,
:mod:`compensation.app.workflows.cluster`, the same bytes), moves split as ``max_segment_mm`` says; the guards
(:mod:`compensation.guards`, ``allow`` overrides recorded); the accepted files written as one set,
``compensate_summary.json`` last. Residuals: the MODEL residual of every file; with ``truth`` also the TRUE
one (:mod:`compensation.app.workflows.compensate_report`). docs/reference/tool-paths.md ("volcomp compensate").
"""
from __future__ import annotations

import contextlib
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from errormap.io import atomic_write, sidecar_path, write_json
from errormap.jit import notice_cold_kernels
from errormap.progress import Progress
from errormap.units import UNITS_CHECK

from compensation.app.outputs import COMPENSATE_SUMMARY_NAME as SUMMARY_NAME, check_out_dir, plan_outputs
from compensation.app.validate import UsageError

from ... import guards
from ...batch import CHUNK_POINTS, GA_METHODS, LocalExecutor, gather_results, solve_batch
from ...conditions import ConditionedField, path_conditions, solve_with_conditions
from ...fields import FAILED_VERDICT, check_verdict, resolve_model, verdict_notes
from ...gcode import DEFAULT_RAPIDS
from ...gcode_spline import spline_lines
from ...held_axes import held_points, held_to_write, merge_held, solve_held
from ...nc_expand import source_lines
from ...nc_state import MACHINE, field_with_tool, machine_with_tool
from ...pathio import DEFAULT_ARC_TOLERANCE_UM, compensated_sidecar
from ...solvers import METHODS, solver_spec
from ...solvers.chain_exact import nominal_and_jacobian, solved_and_kept
from ...solvers.threads import small_batch_threads
from .compensate_paths import ToolPath, read_tool_path, render, source_line_of
from .compensate_report import (PATH_SAMPLES, cutter_radius_bound_um, cycle_report, orientation_pass, rotary_refusals,
                                spindle_axis_entry, spindle_axis_line, stats, tcp_entry, true_path_residual_um,
                                true_residual_um)

WORK_OFFSETS_MACHINE_NOTE = "volcomp: work offsets taken as machine zero (--work-offsets machine)"


@dataclass
class CompensateSettings:
    """How :func:`compensate_files` compensates (the ``compensate`` options): ``method``
    (:data:`compensation.solvers.METHODS`), ``model`` (a model file, folder or MLflow reference),
    ``out_dir``; ``force`` (replace earlier outputs), ``allow`` (guards overridden; ``("all",)``: every
    guard), ``rapids``, ``block_delete``, ``arc_tolerance_um``, ``units`` (``"check"`` or ``"as-written"``),
    ``truth`` (a truth file: the TRUE residual too), ``seed`` (seeded methods), ``show`` (offending points
    listed per refused file), ``rotary_limit_deg`` (a solved rotary axis' largest correction, None: the
    ball's bound), ``conditions`` ({name: value} for the model's condition terms; a diagnosed model takes a
    path's columns first), ``tracking_uri`` (MLflow)."""

    method: str
    model: str
    out_dir: Path
    force: bool = False
    allow: tuple = ()
    rapids: str = DEFAULT_RAPIDS
    block_delete: str | None = None
    arc_tolerance_um: float = DEFAULT_ARC_TOLERANCE_UM
    units: str = UNITS_CHECK
    truth: str | None = None
    seed: int = 0
    show: int = 20
    rotary_limit_deg: float | None = None
    conditions: dict = field(default_factory=dict)
    tracking_uri: str | None = None
    dialect: str | None = None   # compensation.dialects: a name, "auto" or None
    work_offsets: object = None  # compensation.nc_state.WorkOffsets (None: not given)
    tool_table: object = None    # compensation.nc_state.ToolTable (None: not given)
    cycles: str = "keep"         # canned cycles: "keep" (holes compensated) or "expand" (compensation.nc_cycles)
    orientation: bool = False    # the tool axis compensated too, by the rotary axes (compensation.tcp_orientation)
    chunk_points: int = CHUNK_POINTS  # points per chunk of the batch (compensation.batch)
    max_segment_mm: object = "auto"   # "auto" (the field's curvature), None (no splitting) or a length in mm
    lathe_x: str | None = None   # a Fanuc/Haas/Siemens ISO lathe's X words: "diameter", "radius" (None: refused)
    subprograms: object = None   # compensation.nc_subfiles.SubprogramFiles (--subprograms; None: not given)


@dataclass
class FileOutcome:
    """One input's result: ``entry`` its ``compensate_summary.json`` record; ``text`` the rendered output
    (None: refused); ``listed`` (point, line, reasons) of the violations that refuse it; ``kept`` (line,
    reason) of refusing kept rapids."""

    src: Path
    dst: Path
    tp: ToolPath
    entry: dict
    text: str | None
    meta: str | None = None   # a CSV output's provenance sidecar (compensation.pathio.compensated_sidecar)
    listed: list = field(default_factory=list)
    kept: list = field(default_factory=list)

    @property
    def refused(self) -> bool:
        return self.text is None

    @property
    def guards(self) -> list:
        return self.entry.get("refused_guards", [])


@dataclass
class CompensateRun:
    """All files of one job, the summary written, and the stale outputs removed."""

    outcomes: list
    summary_path: Path
    removed: list

    @property
    def refused(self) -> list:
        return [o for o in self.outcomes if o.refused]


def progress_callback(points: int, method: str):
    """``advance(k)``: a progress bar over ``points`` that worker threads may advance by ``k`` points."""
    bar = Progress(points, f"compensate ({method}, points)", every_s=1.0)
    lock = threading.Lock()

    def advance(k):
        with lock:
            bar.update(k)

    return advance


def kernel_modules(method: str) -> list:
    """The modules whose numba kernels a ``compensate`` run with ``method`` compiles on first use: the
    G-code planner's and the solver's own."""
    import importlib
    names = ["compensation.gcode_kernels", *solver_spec(method).kernels]
    return [importlib.import_module(n) for n in names]


# ----------------------------------------------------------------------------- the model

def load_model_field(machine, s: CompensateSettings):
    """``(source, verdict, field)`` of ``s.model`` for the machine tool ``machine`` (as loaded: a grinder file's
    models are read as it writes them): recognised by content (the caller says which on stderr); a failed diagnosis verdict
    refused unless allowed (:func:`compensation.model_file.read_model`, the one reader); a model whose terms
    take their conditions per point (:attr:`~compensation.model_file.Model.per_point`) a :class:`ConditionedField`
    (conditions per path, from its columns or these constants), any other its constant conditions
    (:func:`field_conditions`)."""
    from ...model_file import read_model
    src = resolve_model(s.model)
    verdict = check_verdict(src.path, FAILED_VERDICT in s.allow)
    model = read_model(s.model, machine, s.tracking_uri, source=src)
    if model.per_point:
        return src, verdict, ConditionedField(model.field.corrected, dict(s.conditions or {}), check=False)
    return src, verdict, field_conditions(model.field, {k: v for k, v in s.conditions.items() if v is not None}, machine)


def field_conditions(field_, conditions: dict, machine):
    """``field_`` with the constant ``conditions`` its effect terms need (``--temp-c``, ``--dir-x`` …, one
    value for the whole program); a condition given that the model does not use, or one it needs that was
    not given, is refused in one line (UsageError)."""
    needs = tuple(getattr(field_, "needs", ()))
    extra = [c for c in conditions if c not in needs]
    if extra:
        raise UsageError(f"{', '.join('--' + c.replace('_', '-') for c in extra)}: the model has no effect term that "
                         f"uses it on the machine tool {machine.name!r}; leave it out")
    from ...conditions import CONDITIONS
    missing = [c for c in needs if c not in conditions]
    if missing:
        opts = [c for c in missing if c in CONDITIONS]
        none = [c for c in missing if c not in CONDITIONS]
        if none:
            raise UsageError(f"the model's effect terms need the condition(s) {none}, which compensate on a chain "
                             "cannot take yet (no option; the program has no condition columns)")
        raise UsageError(f"the model's effect terms need the condition(s) {opts}: give them for the whole program "
                         f"({', '.join('--' + c.replace('_', '-') for c in opts)})")
    if not needs:
        return field_
    if "temp_c" in conditions:
        from errormap.units import temperature_mistake
        m = temperature_mistake([float(conditions["temp_c"])], UNITS_CHECK)
        if m is not None:
            raise UsageError(f"--temp-c: units do not fit: {m[1]}")
    for c in needs:
        if c.startswith("dir_") and float(conditions[c]) not in (-1.0, 1.0):
            raise UsageError(f"--{c.replace('_', '-')}: expected +1 or -1, got {conditions[c]}")
    return field_.with_conditions({c: float(conditions[c]) for c in needs})


def axes_field(field_):
    """The part of ``field_`` over the axes alone (a diagnosed model's elements without its condition terms):
    what plans a program's segments and says where the model is calibrated."""
    return field_.corrected.base if isinstance(field_, ConditionedField) else field_


# ----------------------------------------------------------------------------- solving

def tool_context(contexts: dict, key: float, field_, truth, machine) -> int:
    """The index in ``contexts`` ({tool key: (index, field, machine, truth)}) of the chain with the tool
    length ``key`` mm (-inf: the machine file's own tool, index 0), added on first use
    (:func:`compensation.nc_state.machine_with_tool`: the field and the truth at that tool point)."""
    if key not in contexts:
        try:
            mt = machine_with_tool(machine, float(key))
            f = field_with_tool(field_, mt)
            tr = field_with_tool(truth, mt) if truth is not None else None
        except (ValueError, TypeError) as exc:
            raise UsageError(f"--tool-table: tool length {key:g} mm: {exc}") from None
        contexts[key] = (len(contexts), f, mt, tr)
    return contexts[key][0]


def batch_units(paths, field_, truth, machine):
    """The points of ``paths`` as the batch units of :func:`compensation.batch.solve_batch`: one unit per
    file and tool length (``targets_mm`` (m, 3) the nominal tool points at that tool, ``axes`` (m, k),
    ``context`` the tool's chain), turning points left out (solved over the turn, not by the method).
    Returns ``(units, owners, contexts)``: ``owners[u] = (file, point indices)``, ``contexts`` as in
    :func:`tool_context`."""
    contexts = {-np.inf: (0, field_, machine, truth)}
    units, owners = [], []
    for f, tp in enumerate(paths):
        n = len(tp.axes)
        tool = np.full(n, np.nan) if tp.tool_mm is None else np.asarray(tp.tool_mm, float)
        keys = np.where(np.isfinite(tool), tool, -np.inf)
        solved = np.ones(n, bool) if tp.turning is None else ~np.asarray(tp.turning, bool)
        for key in np.unique(keys[solved]):
            idx = np.flatnonzero((keys == key) & solved)
            j = tool_context(contexts, float(key), field_, truth, machine)
            mt = next(c[2] for c in contexts.values() if c[0] == j)
            targets = tp.targets_mm[idx] if tp.targets_mm is not None and j == 0 else \
                nominal_and_jacobian(mt, tp.axes[idx])[0]
            units.append(SimpleNamespace(targets_mm=targets, axes=tp.axes[idx], context=j, path=str(tp.path)))
            owners.append((f, idx))
    return units, owners, contexts


def solve_paths(paths, field_, truth, machine, s: CompensateSettings, conds=None, executor=None,
                progress=None) -> list:
    """Solve every point of ``paths`` with ``s.method``. Per path ``(SolveResult, targets (n, 3) mm, TRUE
    residual (n, 3) μm, TRUE residual of the program as written)`` (the last two None without a truth, or
    for a program with turning points: taken over the turn by the caller). ``conds``: per path the
    per-point conditions {name: (n,)} of a diagnosed model (:func:`solve_with_conditions`, file by file in
    this process), else None: every point through :func:`solve_units`."""
    if conds is not None and any(c is not None for c in conds):
        out = []
        opts = {"seed": s.seed} if s.method in GA_METHODS else {}
        for tp, cond in zip(paths, conds):
            targets = tp.targets_mm if tp.targets_mm is not None else nominal_and_jacobian(machine, tp.axes)[0]
            with small_batch_threads(s.method, len(tp)):
                res = solve_with_conditions(s.method, field_, targets, machine, cond, target_axes=tp.axes, **opts)
            res.info = dict(res.info or {}, chunks=1)
            out.append((res, targets, None, None))
            if progress is not None:
                progress(len(tp))
        return out
    return solve_units(paths, field_, truth, machine, s, executor, progress)


def solve_units(paths, field_, truth, machine, s: CompensateSettings, executor=None, progress=None) -> list:
    """:func:`solve_paths` without per-point conditions: the points of all files, one unit per file and tool
    length (:func:`batch_units`), through the chunk plan of :mod:`compensation.batch` on ``executor``; a
    lathe's turning points over the turn (:func:`compensation.turning.solve_with_turning`)."""
    units, owners, contexts = batch_units(paths, field_, truth, machine)
    ctx = sorted(contexts.values(), key=lambda c: c[0])
    options = {"rotary_limit_deg": s.rotary_limit_deg} if s.rotary_limit_deg is not None else {}
    results = solve_batch(s.method, field_, machine, units, seed=s.seed, options=options,
                          chunk_points=s.chunk_points, executor=executor, progress=progress,
                          contexts=[(c[1], c[2]) for c in ctx[1:]]) if units else []
    out = []
    for f, tp in enumerate(paths):
        mine = [(u, owners[k][1], results[k]) for k, u in enumerate(units) if owners[k][0] == f]
        held = held_points(tp, len(machine.axes))
        if held is not None:  # axes a G53 line set: held there, the others solved (compensation.held_axes)
            mine = [(u, idx, solve_held(ctx[u.context][1], ctx[u.context][2], r, u.targets_mm, u.axes, held[idx]))
                    for u, idx, r in mine]
        chunks = sum(r.info["chunks"] for _, _, r in mine)
        turning = tp.turning if tp.turning is not None and tp.turning.any() else None
        true_r = base = None
        if turning is None:
            res = gather_results([r for _, _, r in mine], [idx for _, idx, _ in mine])
            if held is not None:
                res.info["held"] = merge_held([r.info.get("held") for _, _, r in mine])
            targets = res.targets_mm
            if truth is not None:
                true_r, base = np.empty((len(targets), 3)), np.empty((len(targets), 3))
                for u, idx, r in mine:
                    _, _, mt, tr = ctx[u.context]
                    true_r[idx] = true_residual_um(tr, mt, r.axes, u.targets_mm)
                    base[idx] = true_residual_um(tr, mt, u.axes, u.targets_mm)
        else:
            from ...solvers.base import BALL_RADIUS_UM
            from ...turning import nominal_by_tool, solve_with_turning
            rest = np.flatnonzero(~turning)
            rest_res = gather_results([r for _, _, r in mine], [np.searchsorted(rest, idx) for _, idx, _ in mine]) \
                if mine else None
            targets = nominal_by_tool(machine, tp.axes, tp.tool_xz)
            res = solve_with_turning(lambda t, a: rest_res, field_, machine, targets, tp.axes, turning, BALL_RADIUS_UM,
                                     tp.tool_xz)
        res.info["chunks"] = chunks
        out.append((res, targets, true_r, base))
    return out


def check_settings(machine, s: CompensateSettings) -> None:
    """Refuse (UsageError, naming the option) a method or rotary limit the machine cannot take."""
    if s.method not in METHODS:
        raise UsageError(f"--method {s.method}: on the machine tool {machine.name!r} the methods are "
                         f"{', '.join(METHODS)}")
    try:  # every method moves the three axes read from the chain (a lathe's X, Z, C; a mill's X, Y, Z)
        solved_and_kept(machine)
    except ValueError as exc:
        raise UsageError(f"--machine {machine.name} --method {s.method}: {exc}; compensate is not available "
                         f"on this machine") from None
    if s.rotary_limit_deg is not None:
        sol, _ = solved_and_kept(machine)
        if all(machine.axes[j].kind == "linear" for j in sol):
            raise UsageError(f"--max-rotary-correction-deg: the solver moves no rotary axis on {machine.name!r} "
                             f"(it moves {', '.join(machine.axis_columns[j] for j in sol)}; the rotary axes are kept "
                             "as programmed); leave it out")


# ----------------------------------------------------------------------------- the order of work

def compensate_files(files, machine, s: CompensateSettings, executor=None, on_file=None) -> CompensateRun:
    """Compensate the tool-path ``files`` of the machine tool ``machine`` (as loaded: a chain file or a
    grinder file, compensated on its chain) as ``s`` says, in the order of work above; ``on_file(outcome)``
    after each file is guarded and rendered (nothing written yet). ``executor``:
    :class:`compensation.batch.LocalExecutor` by default, or Ray; a
    :class:`~compensation.app.workflows.cluster.ClusterError` it raises leaves nothing written."""
    check_settings(machine, s)
    plan = plan_outputs(files, Path(s.out_dir))
    old_outputs = check_out_dir(Path(s.out_dir), s.force)
    notice_cold_kernels(*kernel_modules(s.method))  # one line before numba's first compilation after install
    src, verdict, field_ = load_model_field(machine, s)
    truth = None
    if s.truth:
        from .measurement import load_chain_truth
        truth = load_chain_truth(s.truth, machine)
    paths = [read_tool_path(p, machine, s, axes_field(field_)) for p, _ in plan]
    print(f"compensate: model {src.description}", file=sys.stderr)  # every input read: a bad one is the one line
    needs = field_.needs if isinstance(field_, ConditionedField) else ()
    conds = [path_conditions(tp, needs, field_.conditions, s.units, "--units") for tp in paths] if needs else None
    advance = progress_callback(sum(len(tp.axes) for tp in paths), s.method)
    solved = solve_paths(paths, field_, truth, machine, s, conds, executor=executor, progress=advance)
    outcomes = []
    for (p, dst), tp, (res, targets, true_r, true_base) in zip(plan, paths, solved):
        o = compensate_one(p, dst, tp, res, targets, true_r, true_base, field_, truth, machine, s, verdict)
        outcomes.append(o)
        (on_file or print_file)(o)
    return write_run(outcomes, old_outputs, src, verdict, field_, truth, machine, s, executor)


def compensate_one(p, dst, tp: ToolPath, res, targets, true_r, true_base, field_, truth, machine,
                   s: CompensateSettings, verdict) -> FileOutcome:
    """Guard and render one solved file (in memory; nothing is written): its summary entry and text."""
    turning = tp.turning if tp.turning is not None and tp.turning.any() else None
    if turning is not None and tp.kind == "gcode":  # a lathe contour cycle stays monotonic (compensation.nc_contour)
        from ...nc_groove_kept import hold_kept
        from ...turning import hold_contours
        res = hold_kept(hold_contours(res, tp, field_, machine), tp, field_, machine)  # kept G74/G75: their bottoms
    if turning is None and s.orientation:
        res, true_r = orientation_pass(field_, truth, machine, tp, res, targets, true_r)
    report = guards_report(res, machine, field_, s, tp)
    rotary_refused = rotary_refusals(res, report)
    kept = kept_rapids(tp, machine)
    entry = file_entry(p, tp, res, report, kept, machine, s)
    if "retry" in (res.info or {}):  # GA points retried / Newton-polished after the paper's generations
        entry["ga_retry"] = dict(res.info["retry"])
    if "rotary_refused" in res.info:
        entry["rotary_refused"] = rotary_refused
        entry["rotary_limit_deg"] = res.info.get("rotary_limit_deg")
    if truth is not None:
        truth_entry(entry, tp, res, targets, true_r, true_base, truth, machine, turning, s)
    if tp.kind == "gcode":
        gcode_entry(entry, tp, res, true_r, true_base, field_, truth, machine, s)
    blocking = report.blocking
    refused = bool(blocking) or (bool(kept) and "stroke" not in report.allowed)
    o = FileOutcome(p, dst, tp, entry, None)
    if refused:
        entry["refused"] = True
        bad = np.unique(np.concatenate(list(blocking.values()))) if blocking else np.zeros(0, int)
        o.listed = [(int(i), source_line_of(tp, tp.lines[i]), "; ".join(r for r in report.point_reasons(int(i))
                                                                      if r.split(":")[0] in blocking)) for i in bad]
        o.kept = kept
        entry["refused_guards"] = sorted(blocking) or ["stroke"]
        return o
    comments = [f"compensated by volcomp: method={s.method} model={s.model}",
                f"model residual max {entry['model_max_um']:.4g} um"]
    if entry["overridden"]:
        counts = ", ".join(f"{g} {n}" for g, n in entry["overridden"].items())
        comments.insert(0, f"volcomp compensate: GUARDS OVERRIDDEN (--allow {','.join(entry['allowed_guards'])}): "
                           f"{counts} point(s) violate; method={s.method} model={s.model}")
    elif tp.kind == "gcode":
        comments = []  # a clean G-code output gets no added lines (but the frame the user gave, below)
    if tp.kind == "gcode" and s.work_offsets is not None and s.work_offsets.source == MACHINE:
        comments = [WORK_OFFSETS_MACHINE_NOTE] + comments
    if "spindle_axis_points" in entry:  # said in the program, as an override is
        comments = [spindle_axis_line(entry["spindle_axis_points"])] + comments
    comments = verdict_notes(verdict) + comments   # a failed verdict used on request: said in the program
    held = held_to_write(tp, res.axes) if res.info.get("held", {}).get("points") else None
    o.text = render(tp, res.axes, res.commands_mm, machine, comments, held)
    if tp.kind != "gcode":
        o.meta = compensated_sidecar(tp.source, dst, comments)
    return o


def guards_report(res, machine, field_, s: CompensateSettings, tp: ToolPath):
    """:func:`compensation.guards.check` of one file's result (the calibrated volume of the axes-only part)."""
    try:
        return guards.check(res, machine, axes_field(field_), allow=s.allow, target_axes=tp.axes)
    except TypeError as exc:  # a field that cannot say where it is calibrated
        raise UsageError(f"{s.model}: {exc}") from None


def kept_rapids(tp: ToolPath, machine) -> list:
    """(line, reason) of the rapids kept as written whose nominal end is outside the strokes."""
    if tp.kind != "gcode" or not len(tp.source.kept_lines):
        return []
    ka = np.where(np.isfinite(tp.kept_machine), tp.kept_machine, 0.5 * (machine.stroke_lo + machine.stroke_hi))
    idx, reasons = guards.stroke_violations(ka, machine)
    return [(source_line_of(tp, tp.source.kept_lines[i]), f"stroke: kept rapid {r}") for i, r in zip(idx, reasons)]


def file_entry(p, tp: ToolPath, res, report, kept, machine, s: CompensateSettings) -> dict:
    """The summary record of one file: points, model residual, correction, guards, axes moved."""
    norm = np.linalg.norm(res.residual_um, axis=1)
    viol = {g: int(len(v)) for g, v in report.violations.items()}
    viol["stroke"] += len(kept)
    entry = {"input": str(p), "output": None, "format": tp.kind, "points": len(tp.axes), "machine": machine.name,
             "residual": "model", "model_max_um": float(norm.max()), "model_mean_um": float(norm.mean()),
             "max_correction_um": float(res.correction_um.max()),
             "failures": int(np.count_nonzero(guards.solver_failures(res))), "guard_violations": viol,
             "allowed_guards": sorted(report.allowed),
             "overridden": {g: n for g, n in viol.items() if n and g in report.allowed},
             "compensated_axes": res.info.get("compensated_axes"), "kept_axes": res.info.get("kept_axes"),
             "seconds": float(res.seconds), "chunks": res.info.get("chunks", 1)}
    if res.info.get("note"):
        entry["note"] = res.info["note"]
    on_axis = spindle_axis_entry(res, lambda idx: source_lines(tp.source.program, np.unique(tp.lines[idx])))
    if on_axis is not None:  # a lathe's points on the spindle axis: written, not failures (compensation.turning)
        entry["spindle_axis_points"] = on_axis
    if res.info.get("held", {}).get("points"):  # axes held at a G53 value: how many points, what is left along them
        entry["held"] = dict(res.info["held"])
    if res.info.get("conditions"):
        entry["conditions"] = res.info["conditions"]
    return entry


def truth_entry(entry, tp: ToolPath, res, targets, true_r, true_base, truth, machine, turning, s) -> None:
    """The TRUE residual of one file (with ``--truth``) into its summary ``entry``."""
    after, before = true_r, true_base
    if turning is not None:
        after = true_residual_um(truth, machine, res.axes, targets)
        before = true_residual_um(truth, machine, tp.axes, targets)
        from ...turning import surface_residual_by_tool
        t = np.flatnonzero(turning)
        tool = None if tp.tool_xz is None else tp.tool_xz[t]
        (a2, spread), (b2, _) = (surface_residual_by_tool(truth, machine, ax[t], tp.axes[t], tool)
                                 for ax in (res.axes, tp.axes))
        after[t] = np.stack([a2[:, 0], np.zeros(len(t)), a2[:, 1]], axis=1)
        before[t] = np.stack([b2[:, 0], np.zeros(len(t)), b2[:, 1]], axis=1)
        entry["turning"] = {"points": int(len(t)), "residual": "turning points: radial and axial deviation "
                            "from the programmed surface of revolution, mean over one spindle turn (um)",
                            "true": stats(after[t]), "true_uncompensated": stats(before[t]),
                            "true_roundness_max_um": float(spread.max())}
    entry["true"] = stats(after)
    entry["true_uncompensated"] = stats(before)
    along = true_path_residual_um(tp, res.axes, truth, machine) if tp.kind == "gcode" and turning is None else None
    if along is not None:
        entry["true_path"], entry["true_path_uncompensated"] = stats(along[0]), stats(along[1])
        entry["true_path_residual"] = (f"along the linear moves as the controller interpolates them, "
                                       f"{PATH_SAMPLES} points per written segment (um)")
    entry["truth"] = str(s.truth)
    entry["truth_conditions"] = "reference: 20 C, positive approach on every axis"


def gcode_entry(entry, tp: ToolPath, res, true_r, true_base, field_, truth, machine, s) -> None:
    """What a G-code file's summary ``entry`` says beyond the points: lines, moves, frames, dialect, TCP,
    cycles, the cutter radius bound."""
    job = tp.source
    entry.update({"lines": len(job.program.lines), "moves_compensated": len(job.counts),
                  "moves_kept": int(len(job.kept_lines)), "rapids": s.rapids, "block_delete": s.block_delete,
                  "arc_tolerance_um": s.arc_tolerance_um, **job.frames.notes,
                  "dialect": job.program.dialect, "dialect_evidence": job.program.dialect_evidence})
    leads = []
    if any(m.lead is not None for m in job.program.moves):  # G32/G33 pieces, G33.1, their leads (nc_thread)
        from ...nc_thread import lead_notes
        from .compensate_paths import program_axes
        leads = lead_notes(job.program, job.counts, program_axes(tp, res.axes, machine)[:, list(tp.columns)],
                           job.taps)
    if leads and tp.turning is None:
        entry["spindle_synchronised"] = leads
    if tp.turning is not None:  # a lathe: what its X words are and who said it (option or machine file)
        from ...turning import lathe_x_entry
        entry.update(lathe_x_entry(machine, getattr(s, "lathe_x", None), job.program.dialect))
        from ...nc_notes import cycle_notes  # lathe cycles kept or written as moves, at their source lines
        notes = cycle_notes(job.program) + leads
        if notes:
            entry["lathe_cycles"] = notes
            entry["lathe_contour_held"] = res.info.get("contour_held", [])
        if res.info.get("grooves"):  # kept G74/G75 (compensation.nc_groove): the error across left per cycle line
            entry["lathe_grooves"] = res.info["grooves"]
    files = getattr(job.program.expanded, "files", ())
    if files:  # subprograms read from --subprograms folders (compensation.nc_subfiles)
        entry["subprogram_files"] = [{"path": p, "sha256": h} for _, p, h in files]
    splines = spline_lines(job.program)
    if splines:
        entry["spline_lines"] = splines
    if job.program.tcp is not None or s.orientation or (truth is not None and res.info.get("kept_axes")):
        entry["tcp"] = tcp_entry(tp, res, machine, truth)
    cyc = cycle_report(tp, res, true_r, true_base)
    if cyc is not None:
        entry["cycles"] = cyc
    bound = cutter_radius_bound_um(axes_field(field_), machine, tp)
    if bound is not None:
        entry["cutter_radius_bound_um"] = bound
        entry["cutter_radius_arm"] = ("tool radius" if tp.turning is None else
                                      "(1 + sqrt 2) x nose radius: the imaginary tip")


def write_outputs(outcomes) -> None:
    """Write the accepted files (with a CSV's provenance sidecar) as one set: each in full to a temporary file
    beside its target, then all renamed into place; an error or interrupt before that leaves none of them."""
    with contextlib.ExitStack() as stack:
        for o in outcomes:
            if not o.refused:
                fh = stack.enter_context(atomic_write(o.dst, "wb"))
                fh.write(o.text.encode("latin-1" if o.tp.kind == "gcode" else "utf-8"))
                o.entry["output"] = str(o.dst)
                if o.meta is not None:
                    side = sidecar_path(o.dst)
                    stack.enter_context(atomic_write(side, "w", encoding="utf-8")).write(o.meta)
                    o.entry["provenance"] = str(side)


def write_run(outcomes, old_outputs, src, verdict, field_, truth, machine, s: CompensateSettings,
              executor) -> CompensateRun:
    """Remove what a previous run left, write the accepted files as one set, the summary last."""
    written = {o.dst.name for o in outcomes if not o.refused}
    removed = []
    for p in sorted(set(old_outputs) | {o.dst for o in outcomes if o.refused}):
        for q in (p, sidecar_path(p)):
            if q.is_file() and p.name not in written:
                q.unlink()
                removed.append(str(q))
    write_outputs(outcomes)
    conditions = getattr(field_, "conditions", {}) or {}
    summary = write_json(Path(s.out_dir) / SUMMARY_NAME, {
        "conditions": {k: v for k, v in dict(conditions).items() if v is not None},
        "method": s.method, "model": s.model, "model_source": src.to_dict(), "model_verdict": verdict,
        "units": s.units, **({"seed": s.seed} if solver_spec(s.method).seeded else {}),
        "machine": machine.path, "machine_name": machine.name, "allow": list(s.allow),
        "residual": "model: p_r + E(axes(p_r)) - p_d (um)"
                    + ("; true: truth tool point at the compensated axes - p_d (um)" if truth is not None else ""),
        "chunk_points": s.chunk_points, "max_segment_mm": s.max_segment_mm,
        "solved_on": (executor or LocalExecutor()).describe(),
        "files": [o.entry for o in outcomes], "removed_stale": removed})
    return CompensateRun(outcomes, summary, removed)


def print_file(o: FileOutcome) -> None:
    """The lines ``compensate`` prints for one file as it is solved."""
    entry = o.entry
    status = "REFUSED (not written)" if o.refused else f"-> {o.dst}"
    tail = ""
    if "true" in entry:
        tail = (f", TRUE residual max {entry['true']['max_um']:.4g} um rms {entry['true']['rms_um']:.4g} um "
                f"(uncompensated {entry['true_uncompensated']['max_um']:.4g} um max)")
        if "true_path" in entry:
            tail += (f", along the moves max {entry['true_path']['max_um']:.4g} um (uncompensated "
                     f"{entry['true_path_uncompensated']['max_um']:.4g} um)")
    print(f"{o.src}: {entry['points']} points, model residual max {entry['model_max_um']:.4g} um mean "
          f"{entry['model_mean_um']:.4g} um, max correction {entry['max_correction_um']:.1f} um{tail}, failures "
          f"{entry['failures']}, guard violations {sum(entry['guard_violations'].values())} {status}")
    if entry.get("note"):
        print(f"  {entry['note']}")
    if "spindle_axis_points" in entry:
        print(f"  {spindle_axis_line(entry['spindle_axis_points']).removeprefix('volcomp: ')}")
    retry = entry.get("ga_retry")
    if retry and retry["retried"]:
        print(f"  {retry['retried']} point(s) above the GA tolerance after its generations: retried "
              f"({retry['retry_rounds']} round(s)), {retry['polished']} Newton-polished, {retry['unconverged']} "
              f"still unconverged; {retry['retry_seconds']:.2f} s")
    if o.tp.kind == "gcode":
        print_gcode_notes(entry)
    if entry.get("rotary_refused"):
        print(f"  rotary continuity: {entry['rotary_refused']} point(s) refused (their rotary correction exceeds "
              f"asin(ball/r){' or the limit' if entry.get('rotary_limit_deg') is not None else ''}; programmed "
              "axes kept)")
    if entry["overridden"] and not o.refused:
        print(f"  warning: guards overridden ({', '.join(f'{g} {n}' for g, n in entry['overridden'].items())} "
              f"point(s)); recorded in the output file's header and the summary")


def print_gcode_notes(entry) -> None:
    """A G-code file's lines: dialect, work offsets, tools, G53 lines, canned cycles, cutter radius."""
    print(f"  dialect {entry['dialect']}" + (f" ({entry['dialect_evidence']})" if entry["dialect_evidence"] else "")
          + f"; work offsets: {entry['work_offsets']}" + (f"; tools {entry['tools_used']}" if entry["tools_used"]
                                                           else "")
          + (f" (lathe tools' X offsets {entry['tool_x_used']})" if entry.get("tool_x_used") else "")
          + (f"; X words: {entry['lathe_x']} ({entry['lathe_x_source']})" if "lathe_x" in entry else ""))
    for note in entry.get("lathe_cycles", ())[:10]:  # a lathe's contour cycles (compensation.nc_contour)
        print(f"  {note}")
    for g in entry.get("lathe_grooves", ())[:10]:
        print(f"  line {g['line']}: {g['code']} kept, its bottom compensated along the plunge; error across left "
              f"{g['across_um']:.3g} um")
    if entry.get("lathe_contour_held"):
        print(f"  {len(entry['lathe_contour_held'])} contour point(s) held monotonic: "
              + "; ".join(entry["lathe_contour_held"][:3]))
    if entry["g53_lines"]:
        print(f"  G53 (machine coordinates) on line(s) {', '.join(map(str, entry['g53_lines'][:10]))}: passed "
              "through unchanged, not compensated")
    if "held" in entry:
        h = entry["held"]
        print(f"  {h['points']} point(s) of the moves after them hold {', '.join(h['axes'])} at the G53 value (no word "
              f"written; the other axes compensated): error left along {'it' if len(h['axes']) == 1 else 'them'} max "
              f"{h['along_held_max_um']:.4g} um (model)")
    if "spline_lines" in entry:
        print(f"  splines (G5/G5.1, NURBS G5.2-G5.3) on line(s) {', '.join(map(str, entry['spline_lines'][:10]))}: chords of the "
              f"exact curve within {entry['arc_tolerance_um'] / 2:g} um of it (half --arc-tolerance-um), written as "
              "compensated G1 moves")
    if "cycles" in entry:
        c = entry["cycles"]
        print(f"  canned cycles {c['mode']}: {c['holes']} hole(s)" + (
            f", tilt left along the hole max {c['tilt_max_um']:.3g} um (line {c['tilt_max_line']})"
            if c["mode"] == "keep" else ""))
    if "cutter_radius_bound_um" in entry:
        dyn = entry.get("dynamic_cutter_radii_mm")  # LinuxCNC G41.1/G42.1: radius D/2 from the line
        print(f"  G41/G42{'/G41.1/G42.1' if dyn else ''} cutter radius compensation: the path is compensated as "
              f"programmed; the error it leaves is at most {entry['cutter_radius_bound_um']:.3g} um (field gradient x "
              f"{entry['cutter_radius_arm']})" + (f"; G41.1/G42.1 radius D/2 (mm) at {', '.join(dyn)}" if dyn else ""))


def print_refusals(run: CompensateRun, show: int) -> None:
    """The refused files and their offending points (first ``show``), on stderr."""
    for o in run.refused:
        print(f"volcomp compensate: {o.src}: refused by guard(s) {', '.join(o.guards)}; "
              f"{len(o.listed) + len(o.kept)} offending point(s):", file=sys.stderr)
        for line, reason in o.kept[:show]:
            print(f"  line {line}: {reason}", file=sys.stderr)
        for i, line, reason in o.listed[:show]:
            print(f"  point {i} (line {line}): {reason}", file=sys.stderr)
        if len(o.listed) > show:
            print(f"  ... and {len(o.listed) - show} more", file=sys.stderr)
    print("volcomp compensate: refused files were not written; override explicitly with --allow GUARDS "
          "(or bare --allow for all)", file=sys.stderr)
