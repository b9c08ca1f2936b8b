"""``volcomp demo``: the whole pipeline on the built-in default machine.

simulate a truth grinder (``DIR/sim``) → its 11×11×11 feature points → train the BP network
(Levenberg–Marquardt, tracked in MLflow) → compensate the variable-helix flute path with every
method (the per-point ``ga`` on an evenly spaced subset when the whole path would take too
long, and the report says so) → ``DIR/report.html``, ``DIR/metrics.json``, ``DIR/residuals.csv``
showing the MODEL residual (the trained network's own view) and the TRUE residual (the
simulated machine). The report files are also logged to the training's MLflow run.

Defaults finish in about 3–4 minutes on 2 CPU cores (192 s measured, BENCHMARKS.md):
training stops after ``--train-iter`` LM iterations (a fixed count, so the model is the same on any
machine; ``--train-s`` adds a wall-clock limit), the per-point GA after ``--ga-budget-s``.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from errormap.featurepoints import FeaturePoints
from errormap.htm import HTMField
from errormap.io import write_json
from errormap.machine import load_machine

from ..cli import UsageError
from ...evaluate import load_truth
from ..reports.methods import compare_methods, print_table, write_report
from ...toolpath import check_in_strokes
from . import simulate as simulate_cmd
from .report import add_flute_arguments, add_method_arguments, flute_from_args, parse_methods

DEFAULT_TRAIN_ITER = 1000  # as `volcomp train`; the MSE goal usually stops LM earlier (92 s measured)
DEFAULT_DEMO_GA_BUDGET_S = 90.0


def register(sub):
    p = sub.add_parser(
        "demo", help="the whole pipeline on the default machine: simulate → train → compensate → report",
        description="Simulate a truth grinder, train the BP network on its feature points (MLflow), compensate "
                    "the flute path with every method and write DIR/report.html + DIR/metrics.json.")
    p.add_argument("--out", default="runs/demo", metavar="DIR", help="output folder (default runs/demo)")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--sim-seed", type=int, default=0, help="seed of the simulated truth machine")
    p.add_argument("--tracking-uri", default=None,
                   help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, else runs/mlflow.db under the working folder)")
    p.add_argument("--train-iter", type=int, default=DEFAULT_TRAIN_ITER,
                   help=f"LM iterations (default {DEFAULT_TRAIN_ITER}; the same model on any machine)")
    p.add_argument("--train-s", type=float, default=None,
                   help="also stop training after this many seconds (off by default: it makes the model depend "
                        "on the machine's load)")
    p.add_argument("--trainer", default="lm", help="trainer passed to training.fit_field (default lm)")
    p.add_argument("--hidden", default=None,
                   help="hidden layer sizes, comma-separated (default: the training package's, the paper's 10,15,25,15,10)")
    add_method_arguments(p)
    p.set_defaults(ga_budget_s=DEFAULT_DEMO_GA_BUDGET_S)
    add_flute_arguments(p)
    p.set_defaults(func=run)


def train_field(fp_path: Path, machine, args, log=None):
    """Train the network with ``training.fit_field``; returns ``(field, info dict)``.

    ``info`` has ``run_id`` (or None), ``metrics`` and ``model`` (what the report names).
    """
    log = sys.stderr if log is None else log
    import training
    fit_field = getattr(training, "fit_field", None)
    if fit_field is None:
        return None, None
    kwargs = {"trainer": args.trainer, "max_iter": args.train_iter, "seed": args.seed,
              "max_time_s": args.train_s if args.train_s is not None else math.inf}
    if args.tracking_uri:
        kwargs["tracking_uri"] = args.tracking_uri
    if args.hidden:
        try:
            kwargs["hidden"] = tuple(int(h) for h in args.hidden.split(","))
        except ValueError:
            raise UsageError(f"--hidden: expected comma-separated integers, got {args.hidden!r}") from None
    fp = FeaturePoints.load(fp_path)
    print(f"training the BP network on {len(fp.axes)} feature points ({args.trainer}, "
          f"at most {args.train_iter} iterations" + (f", {args.train_s:g} s" if args.train_s else "") + ") ...",
          file=log)
    res = fit_field(fp, **kwargs)
    run_id = getattr(res, "run_id", None)
    metrics = dict(getattr(res, "metrics", {}) or {})
    return res.field, {"run_id": run_id, "metrics": metrics,
                       "model": f"runs:/{run_id}" if run_id else "trained network (not tracked)"}


def log_to_mlflow(run_id, tracking_uri, paths: dict, metrics: dict, log=None) -> None:
    """Log the report files and per-method residual metrics to the training run."""
    log = sys.stderr if log is None else log
    if not run_id:
        return
    import mlflow
    if tracking_uri is None:  # the store the training run went to (runs/mlflow.db unless overridden)
        from training.tracking import default_tracking_uri
        tracking_uri = default_tracking_uri()
    client = mlflow.tracking.MlflowClient(tracking_uri=tracking_uri)
    for method, m in metrics["methods"].items():
        for key in ("model_max_um", "model_mean_sq_um2", "true_max_um", "true_mean_um", "seconds"):
            if m.get(key) is not None:
                client.log_metric(run_id, f"report.{method}.{key}", float(m[key]))
    for k in ("html", "metrics", "residuals"):
        client.log_artifact(run_id, str(paths[k]), artifact_path="report")
    print(f"logged the report to MLflow run {run_id}", file=log)


def run(args) -> int:
    t_start = time.perf_counter()
    methods = parse_methods(args.methods)
    machine = load_machine(args.machine, expect_kind="grinder")
    out = Path(args.out)
    try:
        fl = flute_from_args(args)
    except ValueError as exc:
        raise UsageError(f"flute settings: {exc}") from None
    nominal = fl.axes(machine)
    try:
        check_in_strokes(machine, nominal, "the flute path")
    except ValueError as exc:
        raise UsageError(str(exc)) from None

    print("[1/4] simulate", file=sys.stderr)
    sim_dir = out / "sim"
    simulate_cmd.run(argparse.Namespace(machine=args.machine, seed=args.sim_seed, out=str(sim_dir), effect=[],
                                        noise_um=1.0, checks=400))
    truth = load_truth(sim_dir, machine)

    print("[2/4] feature points: " + str(sim_dir / "featurepoints.csv"), file=sys.stderr)
    print("[3/4] train", file=sys.stderr)
    t0 = time.perf_counter()
    field, train_info = train_field(sim_dir / "featurepoints.csv", machine, args)
    if field is None:
        print("warning: training.fit_field is not available; the demo uses the 23-element HTM model of the "
              "truth elements as its error field instead of a trained network", file=sys.stderr)
        field = HTMField(machine, truth.elements)
        train_info = {"run_id": None, "metrics": {}, "model": f"HTM model of {sim_dir / 'truth_elements.json'} "
                                                              "(training unavailable)"}
    train_s = time.perf_counter() - t0
    print(f"trained in {train_s:.1f} s; model {train_info['model']}", file=sys.stderr)

    print(f"[4/4] compensate the flute ({len(fl)} points) with {', '.join(methods)} and report", file=sys.stderr)
    cmp = compare_methods(field, fl.targets_mm, machine, methods=methods, truth=truth, ga_points=args.ga_points,
                          ga_budget_s=args.ga_budget_s, seed=args.seed, nominal_axes=nominal)
    cmp.info.update({"machine": machine.name, "machine_file": machine.path, "model": train_info["model"],
                     "truth": str(sim_dir), "path": "flute", "flute": fl.settings.to_dict(), "points": len(fl)})
    context = {"machine": f"{machine.name} ({machine.path})",
               "model (error field)": f"{train_info['model']}, trained {train_s:.0f} s on "
                                      f"{sim_dir / 'featurepoints.csv'}",
               "truth": f"simulated grinder seed {args.sim_seed} ({sim_dir})",
               "path": f"variable-helix flute: {fl.settings.turns:g} turns × {fl.settings.points_per_turn} points, "
                       f"r = {fl.settings.radius_mm:g} mm, helix {fl.settings.helix_start_deg:g}° → "
                       f"{fl.settings.helix_end_deg:g}°",
               "seed": args.seed}
    extra = {"training": {"run_id": train_info["run_id"], "seconds": train_s, "metrics": train_info["metrics"]}}
    paths = write_report(cmp, out, title="volcomp demo: flute-path compensation", context=context,
                         extra_metrics=extra)
    print_table(cmp)
    try:
        log_to_mlflow(train_info["run_id"], args.tracking_uri, paths, cmp.metrics())
    except Exception as exc:  # the report is written; tracking trouble must not lose it
        print(f"warning: could not log the report to MLflow: {exc}", file=sys.stderr)
    write_json(out / "demo.json", {"seconds": time.perf_counter() - t_start, "out": str(out),
                                   "sim": str(sim_dir), **{k: str(v) for k, v in paths.items()},
                                   "run_id": train_info["run_id"], "tracking_uri": args.tracking_uri})
    for k in ("html", "metrics", "residuals"):
        print(f"wrote {k}: {paths[k]}")
    print(f"demo finished in {time.perf_counter() - t_start:.0f} s")
    return 0
