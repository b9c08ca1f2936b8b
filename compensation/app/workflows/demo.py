"""The whole pipeline on one machine (``volcomp demo``).

simulate a truth grinder (``DIR/sim``) → its feature points → train the BP network (Levenberg–Marquardt,
tracked in MLflow) → compensate the variable-helix flute path with every method
(:mod:`compensation.app.workflows.compare`) → ``DIR/report.html``, ``DIR/metrics.json``, ``DIR/residuals.csv``
(MODEL and TRUE residual; the per-point ``ga``'s subset in ``DIR/residuals_<method>.csv``), ``DIR/demo.json``
(each stage's wall and CPU seconds); the flute as ``DIR/flute.nc`` and its compensated form
``DIR/compensated/flute.nc`` (machine coordinates). The budget (LM early stopping after ``select_patience``
iterations without improvement off the grid, the ``ga`` points that fit in ``ga_budget_s``) is stated on the
page and in ``metrics.json``. docs/reference/tool-paths.md ("volcomp demo").
"""
from __future__ import annotations

import math
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from errormap.featurepoints import FeaturePoints
from errormap import chain_kernel as htm_kernels  # the HTM model's kernels: the grinder's chain file, compiled
from errormap.io import atomic_write, write_json
from errormap.jit import notice_cold_kernels
from training import DEFAULT_PHYSICS, PHYSICS_MAX_ITER


from compensation.app.validate import UsageError

from ...evaluate import load_truth
from ..reports.methods import print_table, write_report
from .compare import DEMO_GA_BUDGET_S, compare_methods
from .compensate import kernel_modules
from .measurement import simulate_chain
from .simulate import summary_lines


@dataclass
class DemoSettings:
    """What one demo run does. ``flute``: the path (:func:`compensation.toolpath.flute_path`);
    ``hidden``: hidden layer sizes (None: the training package's default); ``train_s``: a
    wall-clock limit on training (None: the iteration count alone decides)."""

    out: Path
    flute: object
    methods: tuple
    sim_seed: int = 0
    seed: int = 0
    tracking_uri: str | None = None
    train_iter: int = PHYSICS_MAX_ITER
    train_s: float | None = None
    physics: str = DEFAULT_PHYSICS   # training's physical part (training.DEFAULT_PHYSICS: the measured best)
    trainer: str = "lm"
    hidden: tuple | None = None
    ga_points: int | None = None
    ga_budget_s: float = DEMO_GA_BUDGET_S
    select_patience: int = 0


class StageClock:
    """Wall and CPU seconds of each stage of a run (``stages``: name -> {wall_s, cpu_s})."""

    def __init__(self):
        self.stages = {}

    @contextmanager
    def stage(self, name: str):
        w0, c0 = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.stages[name] = {"wall_s": round(time.perf_counter() - w0, 3),
                                 "cpu_s": round(time.process_time() - c0, 3)}

    def line(self) -> str:
        return "stage times (wall / CPU s): " + ", ".join(
            f"{k} {v['wall_s']:.1f}/{v['cpu_s']:.1f}" for k, v in self.stages.items())


def train_field(fp_path: Path, s: DemoSettings, log=None):
    """Train the network with ``training.fit_field``, tracked in MLflow; returns ``(field, info dict)``:
    ``info`` has ``run_id``, ``metrics`` and ``model`` (what the report names)."""
    log = sys.stderr if log is None else log
    from training import TrackSettings, TrainSettings, fit_field
    try:
        settings = TrainSettings(trainer=s.trainer, max_iter=s.train_iter, seed=s.seed,
                                 max_time_s=s.train_s if s.train_s is not None else math.inf,
                                 select_patience=s.select_patience, physics=s.physics,
                                 **({"hidden": tuple(s.hidden)} if s.hidden else {}))
    except ValueError as exc:
        raise UsageError(f"training settings: {exc}") from None
    fp = FeaturePoints.load(fp_path)
    print(f"training the BP network on {len(fp.axes)} feature points ({s.trainer}, "
          f"at most {s.train_iter} iterations" + (f", {s.train_s:g} s" if s.train_s else "")
          + (f", stopping when the selection error has not improved in {s.select_patience}"
             if s.select_patience and s.trainer == "lm" else "") + ") ...", file=log)
    res = fit_field(fp, settings, tracking=TrackSettings(tracking_uri=s.tracking_uri or None))
    metrics = dict(res.metrics)
    if res.history.stop_reason:
        metrics["stop_reason"] = res.history.stop_reason
    return res.field, {"run_id": res.run_id, "metrics": metrics, "model": f"runs:/{res.run_id}"}


def log_to_mlflow(run_id, tracking_uri, paths: dict, metrics: dict, log=None) -> None:
    """Log the report files and per-method residual metrics to the training run."""
    log = sys.stderr if log is None else log
    import mlflow
    if tracking_uri is None:  # the store the training run went to (runs/mlflow.db unless overridden)
        from training.tracking import default_tracking_uri
        tracking_uri = default_tracking_uri()
    client = mlflow.tracking.MlflowClient(tracking_uri=tracking_uri)
    for method, m in metrics["methods"].items():
        for key in ("model_max_um", "model_mean_sq_um2", "true_max_um", "true_mean_um", "seconds"):
            if m.get(key) is not None:
                client.log_metric(run_id, f"report.{method}.{key}", float(m[key]))
    for k in ("html", "metrics", *sorted(k for k in paths if k.startswith("residuals"))):
        client.log_artifact(run_id, str(paths[k]), artifact_path="report")
    print(f"logged the report to MLflow run {run_id}", file=log)


def budget_lines(s: DemoSettings, train_info: dict, train_s: float, ga_solved: int | None = None,
                 n_points: int | None = None) -> dict:
    """The work the demo spent, as its page and ``metrics.json`` state it (``budget``)."""
    m = train_info.get("metrics") or {}
    train = (f"LM, at most {s.train_iter} iterations"
             + (f", early stop after {s.select_patience} iterations without improvement on the off-grid "
                "selection points" if s.select_patience and s.trainer == "lm" else "")
             + (f", at most {s.train_s:g} s" if s.train_s else ""))
    if "iterations" in m:
        train += (f": ran {m['iterations']} iterations in {train_s:.0f} s, kept iteration "
                  f"{m.get('selected_iteration', m['iterations'])} ({m.get('stop_reason', 'stopped')})")
    ga = (f"{s.ga_points} evenly spaced points" if s.ga_points is not None
          else f"the evenly spaced points that fit in {s.ga_budget_s:g} s (PyGAD, one point at a time)")
    if ga_solved is not None:
        ga += f": {ga_solved} of {n_points} points solved"
    return {"training": train, "per-point ga": ga}


PROGRAM_NAME = "flute.nc"
"""The demo's own NC program (the flute's nominal axis commands, G-code), written beside the report; its
compensated form is ``compensated/flute.nc`` (``volcomp compensate --method exact --work-offsets machine``
with the demo's model)."""
PROGRAM_DECIMALS = 6
"""Decimals of the nominal program's words: 1 nm in X/Z, 1e-6° in A, far below what compensation changes."""
PROGRAM_FEED = 500.0
"""Feed of the flute's G1 moves (mm/min); compensation keeps it as written."""


PLANES = {frozenset("XY"): "G17", frozenset("XZ"): "G18"}
"""The plane of the flute program's two linear axes (X and the radial one: Z on the grinder)."""


def write_flute_program(path, machine, axes, fl) -> Path:
    """The flute's nominal axis commands ``axes`` (n, 3, the machine's axis columns: X, the radial axis, A) as a
    G-code program in the machine's axis words (absolute mm, the plane of its two linear axes: G18 on the
    grinder), written whole; returns its path."""
    d = PROGRAM_DECIMALS
    plane = PLANES[frozenset(a.word for a in machine.axes if a.kind == "linear")]
    words = [" ".join(f"{a.word}{v:.{d}f}" for a, v in zip(machine.axes, row)) for row in axes]
    lines = ["%", f"(volcomp demo: variable-helix flute, {fl.settings.turns:g} turns, {len(axes)} points, nominal)",
             f"G21 G90 {plane} G94", f"G0 {words[0]}", f"G1 {words[1]} F{PROGRAM_FEED:g}", *words[2:], "M30", "%"]
    path = Path(path)
    with atomic_write(path) as f:
        f.write("\n".join(lines) + "\n")
    return path


def compensate_program(s: DemoSettings, machine, axes, model_spec: str, log=None) -> dict:
    """The demo's program through ``volcomp compensate --method exact`` with its model: ``DIR/flute.nc`` →
    ``DIR/compensated/flute.nc`` and ``DIR/compensated/compensate_summary.json``; returns ``{"program",
    "compensated", "summary"}`` paths (``compensated`` None when the guards refused it: said on ``log``)."""
    from ...nc_state import MACHINE, read_work_offsets
    from .compensate import CompensateSettings, compensate_files
    prog = write_flute_program(Path(s.out) / PROGRAM_NAME, machine, axes, s.flute)
    # the flute program is written in machine coordinates (its axes are the grinder's): said explicitly
    # (--work-offsets machine), as every program's frame must be; the summary and the output record it
    print("compensate: the flute program is in machine coordinates (--work-offsets machine)",
          file=sys.stderr if log is None else log)
    job = compensate_files([prog], machine, CompensateSettings(method="exact", model=model_spec,
                                                               out_dir=Path(s.out) / "compensated", force=True,
                                                               tracking_uri=s.tracking_uri, seed=s.seed,
                                                               work_offsets=read_work_offsets(MACHINE)),
                           on_file=lambda o: None)
    o = job.outcomes[0]
    if o.refused:
        print(f"warning: the compensated program was refused by guard(s) {', '.join(o.guards)}; see "
              f"{job.summary_path}", file=sys.stderr if log is None else log)
    return {"program": prog, "compensated": None if o.refused else o.dst, "summary": job.summary_path}


def run_demo(s: DemoSettings, machine, out=None, log=None) -> dict:
    """Run the demo on ``machine`` (a grinder); progress goes to ``log`` (stderr), the result lines to ``out`` (stdout).
    Returns the paths written (``html``, ``metrics``, ``residuals``)."""
    out = sys.stdout if out is None else out
    log = sys.stderr if log is None else log
    t_start = time.perf_counter()
    clock = StageClock()
    fl = s.flute
    nominal = fl.axes(machine)
    # one line before numba's first compilation after install: the HTM model's kernels (simulate)
    # and every method's (compensate)
    notice_cold_kernels(htm_kernels, *{m for method in s.methods for m in kernel_modules(method)}, log=log)
    print("[1/4] simulate", file=log)
    sim_dir = Path(s.out) / "sim"
    print(f"simulating truth grinder seed={s.sim_seed} effects=none ...", file=log)
    with clock.stage("simulate"):
        sim_info = simulate_chain(machine, s.sim_seed, sim_dir, effects=[], noise_um=1.0, checks=400)
        for line in summary_lines(sim_info, sim_dir):
            print(line, file=out)
        truth = load_truth(sim_dir, machine)

    print("[2/4] feature points: " + str(sim_dir / "featurepoints.csv"), file=log)
    print("[3/4] train", file=log)
    t0 = time.perf_counter()
    with clock.stage("train"):
        field, train_info = train_field(sim_dir / "featurepoints.csv", s, log=log)
    train_s = time.perf_counter() - t0
    print(f"trained in {train_s:.1f} s; model {train_info['model']}", file=log)

    print(f"[4/4] compensate the flute ({len(fl)} points) with {', '.join(s.methods)} and report", file=log)
    with clock.stage("compensate"):
        cmp = compare_methods(field, fl.targets_mm, machine, methods=s.methods, truth=truth, ga_points=s.ga_points,
                              ga_budget_s=s.ga_budget_s, seed=s.seed, nominal_axes=nominal, log=log)
    cmp.info.update({"machine": machine.name, "machine_file": machine.path, "model": train_info["model"],
                     "truth": str(sim_dir), "path": "flute", "flute": fl.settings.to_dict(), "points": len(fl)})
    ga_run = cmp.runs.get("ga")
    budget = budget_lines(s, train_info, train_s, len(ga_run.index) if ga_run is not None else None, len(fl))
    context = {"machine": f"{machine.name} ({machine.path})",
               "model (error field)": f"{train_info['model']}, trained {train_s:.0f} s on "
                                      f"{sim_dir / 'featurepoints.csv'}",
               "truth": f"simulated grinder seed {s.sim_seed} ({sim_dir})",
               "path": f"variable-helix flute: {fl.settings.turns:g} turns × {fl.settings.points_per_turn} points, "
                       f"r = {fl.settings.radius_mm:g} mm, helix {fl.settings.helix_start_deg:g}° → "
                       f"{fl.settings.helix_end_deg:g}°",
               **{f"budget: {k}": v for k, v in budget.items()},
               "seed": s.seed}
    extra = {"training": {"run_id": train_info["run_id"], "seconds": train_s, "metrics": train_info["metrics"]},
             "budget": budget}
    print(f"compensating the flute program {Path(s.out) / PROGRAM_NAME} (exact) ...", file=log)
    with clock.stage("program"):
        program = compensate_program(s, machine, nominal, train_info["model"], log=log)
    if program["compensated"] is not None:
        print(f"compensated program: {program['compensated']}", file=out)
    with clock.stage("report"):
        paths = write_report(cmp, s.out, title="volcomp demo: flute-path compensation", context=context,
                             extra_metrics=extra, kind="demo")
        print_table(cmp, stream=out)
        try:
            log_to_mlflow(train_info["run_id"], s.tracking_uri, paths, cmp.metrics(), log=log)
        except Exception as exc:  # the report is written; tracking trouble must not lose it
            print(f"warning: could not log the report to MLflow: {exc}", file=log)
    print(clock.line(), file=log)
    write_json(Path(s.out) / "demo.json", {"seconds": time.perf_counter() - t_start, "out": str(s.out),
                                           "stages": clock.stages, "budget": budget,
                                           "sim": str(sim_dir), **{k: str(v) for k, v in paths.items()},
                                           **{f"program_{k}": None if v is None else str(v)
                                              for k, v in program.items()},
                                           "run_id": train_info["run_id"], "tracking_uri": s.tracking_uri})
    return paths
