"""``volcomp demo``: the whole pipeline on the built-in default machine (:mod:`compensation.app.workflows.demo`).

Options only: the pipeline, its outputs and its budget (``--train-patience``, ``--train-iter``, ``--train-s``,
``--ga-budget-s``; defaults aim at 90 s on 2 quiet CPU cores) are the workflow's; docs/reference/tool-paths.md
("volcomp demo").
"""
from __future__ import annotations

import time
from pathlib import Path

from errormap.machine import load_machine
from training import DEFAULT_PHYSICS, default_max_iter

from compensation.app.validate import UsageError

from ..families import family_of
from ..options import add_flute_arguments, add_method_arguments, flute_from_args, parse_methods
from ..workflows.compare import DEMO_GA_BUDGET_S
from ...toolpath import check_in_strokes

DEFAULT_TRAIN_ITER = default_max_iter(DEFAULT_PHYSICS)  # as `volcomp train`'s default (training.DEFAULT_PHYSICS)
# LM iterations without a better max |error| on the 5,000 off-grid selection points before the demo stops
# training (the kept iterate is the best one, as in `volcomp train`; measured in docs/decisions/020-benchmark-notebook.md)
DEFAULT_DEMO_TRAIN_PATIENCE = 100
DEFAULT_DEMO_GA_BUDGET_S = DEMO_GA_BUDGET_S  # one constant, the workflow's settings' default


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
    p.add_argument("--train-patience", type=int, default=DEFAULT_DEMO_TRAIN_PATIENCE, metavar="N",
                   help=f"stop training when the error on the off-grid selection points has not improved in N LM "
                        f"iterations (default {DEFAULT_DEMO_TRAIN_PATIENCE}; 0: run to --train-iter)")
    p.add_argument("--train-s", type=float, default=None,
                   help="also stop training after this many seconds (off by default: it makes the model depend "
                        "on the machine's load)")
    p.add_argument("--trainer", default="lm", help="trainer passed to training.fit_field (default lm)")
    p.add_argument("--hidden", default=None,
                   help="hidden layer sizes, comma-separated (default: the training package's, the paper's 10,15,25,15,10)")
    add_method_arguments(p, ga_budget_s=DEFAULT_DEMO_GA_BUDGET_S)  # the help states the default used
    add_flute_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..workflows.demo import DemoSettings, run_demo  # the pipeline's libraries (numba, MLflow) load to run it
    t_start = time.perf_counter()
    methods = parse_methods(args.methods)
    machine = load_machine(args.machine)   # None: the built-in default machine
    family_of(machine).target("demo")   # the demo's part is the flute: machines it does not run on refused
    try:
        fl = flute_from_args(args)
    except ValueError as exc:
        raise UsageError(f"flute settings: {exc}") from None
    try:
        check_in_strokes(machine, fl.axes(machine), "the flute path")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    hidden = tuple(int(h) for h in args.hidden.split(",")) if args.hidden else None   # checked: validate.Widths
    settings = DemoSettings(out=Path(args.out), flute=fl, methods=methods,
                            sim_seed=args.sim_seed, seed=args.seed, tracking_uri=args.tracking_uri,
                            train_iter=args.train_iter, train_s=args.train_s, trainer=args.trainer, hidden=hidden,
                            ga_points=args.ga_points, ga_budget_s=args.ga_budget_s,
                            select_patience=args.train_patience)
    paths = run_demo(settings, machine)
    for k, path in paths.items():   # html, metrics, residuals (+ residuals_<method> of a method run on a subset)
        print(f"wrote {k}: {path}")
    print(f"demo finished in {time.perf_counter() - t_start:.0f} s")
    return 0
