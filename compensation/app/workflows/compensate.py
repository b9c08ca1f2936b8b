"""Compensating tool-path files (``volcomp compensate``): plan, solve, guard, render, write.

Order of work, so that the output folder only ever holds whole files of one run:

1. every input is parsed and validated (a bad one fails the batch, naming file, line, column
   and word) before the field is loaded or anything is written;
2. a folder that already holds files is refused unless ``force``; with ``force`` the files a
   previous run listed in its ``compensate_summary.json`` and any file at the output path of
   an input this run refuses are removed;
3. every file is solved — in chunks with a seed each (:mod:`compensation.batch`), in local
   threads or on Ray (:mod:`compensation.app.workflows.cluster`), the same bytes either way —
   then guarded and rendered in memory (:func:`compensate_one`); a cluster that cannot finish
   fails the batch before any write;
4. the accepted files are written as one set (each in full to a temporary file, then all
   renamed into place); ``compensate_summary.json`` last.

Guards: :mod:`compensation.guards`; a refused file is not written. The residual reported per
file is the MODEL residual (the solver's own field).
"""
from __future__ import annotations

import json
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import InputError, write_json
from errormap.jit import notice_cold_kernels
from errormap.progress import Progress

from compensation.app.outputs import is_lock
from compensation.app.validate import UsageError

from ... import guards
from ...batch import CHUNK_POINTS, GA_METHODS, LocalExecutor, solve_batch
from ...diagnosed_model import (ConditionedField, load_path_field, path_conditions, replanned_conditions,
                                solve_with_conditions)
from ...fields import FAILED_VERDICT, check_verdict, resolve_model, verdict_notes
from ...gcode import DEFAULT_RAPIDS
from ...nc_expand import source_line
from ...pathio import DEFAULT_ARC_TOLERANCE_UM, align_turns, read_path, render_compensated, replan, write_outputs
from ...solvers import solver_spec
from ...solvers.threads import small_batch_threads

SUMMARY_NAME = "compensate_summary.json"


@dataclass
class CompensateSettings:
    """One compensation job. ``allow``: guard names overridden (``("all",)``: every guard);
    ``max_segment_mm``: ``"auto"``, None (no splitting) or a length in mm; ``conditions``: the
    constant conditions a diagnosed model's terms need (``temp_c``, ``time_s``, ``dir_x`` ...)."""

    method: str
    model: str
    out_dir: Path
    force: bool = False
    tracking_uri: str | None = None
    seed: int = 0
    allow: tuple = ()
    rapids: str = DEFAULT_RAPIDS
    block_delete: str | None = None
    arc_tolerance_um: float = DEFAULT_ARC_TOLERANCE_UM
    max_segment_mm: object = "auto"
    conditions: dict = field(default_factory=dict)
    chunk_points: int = CHUNK_POINTS
    units: str = "check"   # errormap/units.py: "as-written" skips the likely-unit-mistake tests (recorded)
    work_offsets: object = None  # compensation.nc_state.WorkOffsets: only MACHINE on the grinder (or None)
    dialect: str | None = None   # compensation.dialects: a name, "auto" or None


@dataclass
class FileOutcome:
    """One input's result. ``entry``: its ``compensate_summary.json`` record; ``text``: the
    rendered output (None: refused); ``violations``: (point, line, reasons) of every guard
    violation; ``kept_violations``: how many rapids kept as written leave the strokes;
    ``blocking``: (point, line, reasons) of the violations that refuse the file; ``guards``:
    the refusing guards' names; ``kept``: (line, reason) of refusing kept rapids."""

    src: Path
    dst: Path
    entry: dict
    text: str | None
    violations: list
    kept_violations: int = 0
    blocking: list = field(default_factory=list)
    guards: list = field(default_factory=list)
    kept: list = field(default_factory=list)

    @property
    def refused(self) -> bool:
        return self.text is None


@dataclass
class CompensateRun:
    """All files of one job, the summary written, and the stale outputs removed."""

    outcomes: list
    summary_path: Path
    removed: list

    @property
    def refused(self) -> list:
        return [o for o in self.outcomes if o.refused]


def plan_outputs(files, out_dir: Path) -> list:
    """Output path per input; refuses duplicates and outputs that would overwrite an input."""
    inputs = [Path(f) for f in files]
    for p in inputs:
        if not p.is_file():
            raise InputError(f"{p}: no such file")
    outs = [out_dir / p.name for p in inputs]
    seen = {}
    for p, o in zip(inputs, outs):
        if o.name in seen:
            raise UsageError(f"two inputs would both be written to {o}: {seen[o.name]} and {p}")
        seen[o.name] = p
    resolved_inputs = {p.resolve() for p in inputs}
    for o in outs:
        if o.resolve() in resolved_inputs:
            raise UsageError(f"--out {out_dir} would overwrite the input {o}; choose another folder")
    return list(zip(inputs, outs))


def check_out_dir(out_dir: Path, force: bool) -> list:
    """Refuse a DIR holding files unless ``force``; return the previous run's outputs (to remove)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"--out {out_dir} is not a folder")
    held = sorted(p.name for p in out_dir.iterdir() if not is_lock(p)) if out_dir.is_dir() else []
    if held and not force:
        raise UsageError(f"--out {out_dir} already holds {len(held)} file(s) ({', '.join(held[:3])}"
                         f"{', ...' if len(held) > 3 else ''}); choose an empty folder or pass --force "
                         "(which removes the previous run's outputs)")
    old = []
    summary = out_dir / SUMMARY_NAME
    if held and summary.is_file():
        try:
            doc = json.loads(summary.read_text(encoding="utf-8"))
            old = [out_dir / Path(e["output"]).name for e in doc.get("files", []) if e.get("output")]
        except (ValueError, KeyError, TypeError, AttributeError):
            old = []
    return old


def kept_stroke_violations(tp, machine) -> list:
    """(line, reason) of rapids kept as written whose nominal end is outside the strokes."""
    job = tp.source if tp.kind == "gcode" else None
    if job is None or not len(job.kept_axes):
        return []
    ax = np.where(np.isfinite(job.kept_axes), job.kept_axes, 0.5 * (machine.stroke_lo + machine.stroke_hi))
    idx, reasons = guards.stroke_violations(ax, machine)
    return [(source_line(job.program, int(job.kept_lines[i])), f"stroke: kept rapid {r}") for i, r in zip(idx, reasons)]


def override_note(s: CompensateSettings, entry) -> str:
    """The line an output carries when guards were overridden."""
    counts = ", ".join(f"{g} {n}" for g, n in entry["guard_violations"].items() if n)
    return (f"volcomp compensate: GUARDS OVERRIDDEN (--allow {','.join(entry['allowed_guards'])}): "
            f"{counts} point(s) violate; method={s.method} model={s.model}")


def solve_paths(paths, field_, machine, s: CompensateSettings, conds, executor=None, progress=None) -> list:
    """One :class:`SolveResult` per parsed path. Without conditions every path is solved through
    the chunk plan of :mod:`compensation.batch` (fixed chunks and seeds: a Ray run and a local one
    give the same bytes) on ``executor``; a diagnosed model's per-point conditions are solved file
    by file in this process (:func:`solve_with_conditions`)."""
    if not any(c is not None for c in conds):
        return solve_batch(s.method, field_, machine, paths, seed=s.seed, chunk_points=s.chunk_points,
                           executor=executor, progress=progress)
    opts = {"seed": s.seed} if s.method in GA_METHODS else {}
    out = []
    for tp, cond in zip(paths, conds):
        with small_batch_threads(s.method, len(tp)):
            res = solve_with_conditions(s.method, field_, tp.targets_mm, machine, cond, target_axes=tp.axes, **opts)
        res.info = dict(res.info or {}, chunks=1)
        out.append(res)
        if progress is not None:
            progress(len(tp))
    return out


WORK_OFFSETS_MACHINE_NOTE = "volcomp: work offsets taken as machine zero (--work-offsets machine)"


def compensate_one(tp, src, dst, field_, machine, s: CompensateSettings, res, cond=None, notes=()) -> FileOutcome:
    """Guard and render one parsed tool path ``tp`` read from ``src``, solved as ``res``, to be
    written to ``dst`` (in memory; nothing is written). ``cond``: per-point conditions
    {name: (n,)} of a diagnosed model whose terms need them (:func:`path_conditions`), else None;
    ``notes``: comment lines every written program carries (a failed verdict used on request)."""
    res.axes = np.array(res.axes, dtype=float)
    res.axes[:, 2] = align_turns(res.axes[:, 2], tp.axes[:, 2])
    guard_field = field_.corrected.base if cond is not None else field_  # where it is calibrated: the axes-only part
    try:
        report = guards.check(res, machine, guard_field, allow=s.allow, target_axes=tp.axes)
    except TypeError as exc:  # a field that cannot say where it is calibrated
        raise UsageError(f"{s.model}: {exc}") from None
    program = getattr(tp.source, "program", None) if tp.kind == "gcode" else None
    viol = [(int(i), source_line(program, int(tp.lines[i])), "; ".join(report.point_reasons(int(i))))
            for i in report.indices]
    blocking = set(np.concatenate(list(report.blocking.values())).tolist()) if report.blocking else set()
    kept = kept_stroke_violations(tp, machine)
    kept_blocking = bool(kept) and "stroke" not in report.allowed
    norm = np.linalg.norm(res.residual_um, axis=1)
    violations = {g: int(len(v)) for g, v in report.violations.items()}
    violations["stroke"] += len(kept)
    entry = {"input": str(src), "output": None, "format": tp.kind, "points": len(tp),
             "residual": "model", "model_max_um": float(norm.max()), "model_mean_um": float(norm.mean()),
             "max_correction_um": float(np.max(res.correction_um)),
             "failures": int(np.count_nonzero(~np.asarray(res.success, bool))),
             "guard_violations": violations, "allowed_guards": sorted(report.allowed),
             "overridden": {g: n for g, n in violations.items() if n and g in report.allowed},
             "seconds": float(res.seconds), "chunks": (res.info or {}).get("chunks", 1)}
    if "retry" in (res.info or {}):  # GA points retried / Newton-polished after the paper's generations
        entry["ga_retry"] = dict(res.info["retry"])
    if tp.kind == "gcode":
        job = tp.source
        entry.update({"lines": len(job.program.lines),
                      "moves_compensated": len(job.params), "moves_kept": int(len(job.kept_lines)),
                      "rapids": s.rapids, "block_delete": s.block_delete,
                      "arc_tolerance_um": job.arc_tolerance_um, "max_segment_mm": job.max_segment_mm,
                      "field_curvature_um_per_mm2": job.curvature_um_per_mm2})
        if s.work_offsets is not None:
            entry["work_offsets"] = s.work_offsets.source
        entry["dialect"], entry["dialect_evidence"] = job.program.dialect, job.program.dialect_evidence
    outcome = FileOutcome(src, dst, entry, None, viol, kept_violations=len(kept))
    if blocking or kept_blocking:
        entry["refused"] = True
        outcome.blocking = [v for v in viol if v[0] in blocking]
        outcome.guards = sorted(report.blocking) or ["stroke"]
        outcome.kept = kept if kept_blocking else []
    else:
        comments = [f"compensated by volcomp: method={s.method} model={s.model}",
                    f"model residual max {entry['model_max_um']:.4g} um"]
        if entry["overridden"]:
            comments.insert(0, override_note(s, entry))
        elif tp.kind == "gcode":
            comments = []  # a clean G-code output gets no added lines ...
        if tp.kind == "gcode" and s.work_offsets is not None:  # ... but the one the user said about its frame
            comments.insert(0, WORK_OFFSETS_MACHINE_NOTE)
        comments[:0] = list(notes)
        outcome.text = render_compensated(tp, res.axes, res.commands_mm, comments=comments)
    return outcome


def progress_callback(points: int, method: str):
    """``advance(k)``: a progress bar over ``points`` that worker threads may advance by ``k`` points."""
    bar = Progress(points, f"compensate ({method}, points)", every_s=1.0)
    lock = threading.Lock()

    def advance(k):
        with lock:
            bar.update(k)

    return advance


def kernel_modules(method: str) -> list:
    """The modules whose numba kernels a ``compensate`` run with ``method`` compiles on first use:
    the G-code planner's and the solver's own (the batched GA's generation step, the exact
    solver's Newton kernels)."""
    import importlib
    names = ["compensation.gcode_kernels", *solver_spec(method).kernels]
    return [importlib.import_module(n) for n in names]


def compensate_files(files, machine, s: CompensateSettings, on_file=None, executor=None) -> CompensateRun:
    """Compensate ``files`` into ``s.out_dir`` in the order of work above; ``on_file(outcome)``
    is called after each file is guarded and rendered (before anything is written).
    ``executor``: where the chunks are solved (:class:`compensation.batch.LocalExecutor` by
    default; a Ray executor from :mod:`compensation.app.workflows.cluster`); a
    :class:`~compensation.app.workflows.cluster.ClusterError` it raises leaves nothing written."""
    out_dir = Path(s.out_dir)
    plan = plan_outputs(files, out_dir)
    old_outputs = check_out_dir(out_dir, s.force)
    notice_cold_kernels(*kernel_modules(s.method))  # one line before numba's first compilation after install
    # parse and validate every input first: a bad file fails the batch before any work or output
    read_opts = {"rapids": s.rapids, "block_delete": s.block_delete, "arc_tolerance_um": s.arc_tolerance_um,
                 "units": s.units, "units_option": "--units", "work_offsets": s.work_offsets,
                 "dialect": s.dialect}
    paths = [read_path(src, machine, **read_opts) for src, _ in plan]
    source = resolve_model(s.model)  # by content (format key), printed and recorded in the summary
    verdict = check_verdict(source.path, FAILED_VERDICT in s.allow)  # a failed diagnosis: refused unless allowed
    print(f"compensate: model {source.description}", file=sys.stderr)
    field_ = load_path_field(s.model, machine, s.tracking_uri, s.conditions)
    # a diagnosed model whose terms need conditions: per point from the path's columns, else the options
    # (taken and checked once, before any work: a missing condition or a bad cell fails the batch here)
    needs = field_.needs if isinstance(field_, ConditionedField) else ()
    conds = [path_conditions(tp, needs, field_.conditions, s.units, "--units") if needs else None for tp in paths]
    plan_field = field_.corrected.base if needs else field_  # axes-only part
    paths = [replan(tp, machine, max_segment_mm=s.max_segment_mm, field=plan_field) for tp in paths]
    conds = [replanned_conditions(c, tp) for c, tp in zip(conds, paths)]
    # solve everything first (nothing is written before all results are back)
    advance = progress_callback(sum(len(tp) for tp in paths), s.method)
    results = solve_paths(paths, field_, machine, s, conds, executor=executor, progress=advance)
    outcomes = []
    for (src, dst), tp, cond, res in zip(plan, paths, conds, results):
        o = compensate_one(tp, src, dst, field_, machine, s, res, cond, notes=verdict_notes(verdict))
        outcomes.append(o)
        if on_file is not None:
            on_file(o)
    # write: remove what a previous run left, then the accepted files, the summary last
    written = {o.dst.name for o in outcomes if not o.refused}
    stale = set(old_outputs) | {o.dst for o in outcomes if o.refused}
    removed = []
    for p in sorted(stale):
        if p.is_file() and p.name not in written:
            p.unlink()
            removed.append(str(p))
    write_outputs([(tp, o.dst, o.text) for o, tp in zip(outcomes, paths) if not o.refused])
    for o in outcomes:
        if not o.refused:
            o.entry["output"] = str(o.dst)
    summary_path = write_json(out_dir / SUMMARY_NAME, {
        "method": s.method, "model": s.model, "model_source": source.to_dict(), "model_verdict": verdict,
        "units": s.units,
        "machine": machine.path, "allow": list(s.allow),
        "residual": "model: p_r + E(axes(p_r)) - p_d (um)", "seed": s.seed, "chunk_points": s.chunk_points,
        "solved_on": executor.describe() if executor is not None else LocalExecutor().describe(),
        "files": [o.entry for o in outcomes],
        "removed_stale": removed})
    return CompensateRun(outcomes, summary_path, removed)
