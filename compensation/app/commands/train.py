"""``volcomp train``: fit the BP network to feature points; every fit is an MLflow run."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from errormap.io import InputError, read_table
# Training stops on iterations (or the MSE goal) by default, so that the same command and seed
# give the same model on any machine; a wall-clock budget is an explicit option. (The package
# module ``training`` is light: these constants do not load torch.)
from training import DEFAULT_MAX_ITER, DEFAULT_PHYSICS, PHYSICS_MAX_ITER, QUICK_MAX_ITER, default_max_iter
from compensation.app.validate import UsageError

from ..families import family_of



def register(sub):
    p = sub.add_parser(
        "train", help="train the error-field network (LM by default) on feature points, tracked in MLflow",
        description="Fit the paper's BP network (3 → 10-15-25-15-10 → 3, sigmoid) to FEATUREPOINTS, "
                    "measure max/RMS fit error (μm) on the feature points and on off-grid validation points, "
                    "record the run in MLflow and write DIR/metrics.json and DIR/model/.")
    p.add_argument("featurepoints", help="feature-point CSV (volcomp simulate / featurepoints); a machine-tool "
                   "chain's (its header names axis_columns and the machine): the network takes that machine's axes")
    p.add_argument("--out", required=True, help="output folder (metrics.json, model/, plots)")
    p.add_argument("--trainer", choices=("lm", "adam", "lbfgs"), default="lm")
    p.add_argument("--max-time", type=float, default=None,
                   help="also stop after this many seconds (off by default: a wall-clock budget makes the model "
                        "depend on the machine's load; the run records the iterations reached, and --max-iter "
                        "with that number reproduces it)")
    p.add_argument("--quick", action="store_true",
                   help=f"demo setting: at most {QUICK_MAX_ITER} iterations with --physics none (unless --max-iter "
                        f"is given; with a physical part the default {PHYSICS_MAX_ITER} already is)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--a-encoding", choices=("raw", "periodic"), default=None,
                   help="A as one scaled input (the paper's, the default) or as (cos a, sin a); on a machine-tool "
                        "chain: every rotary axis short of a full turn (a full-turn one is always (cos, sin); refused "
                        "on a chain without such an axis)")
    p.add_argument("--hidden", default="10,15,25,15,10", help="hidden layer widths, comma-separated")
    p.add_argument("--activation", choices=("sigmoid", "tanh", "softplus"), default="sigmoid")
    p.add_argument("--mse-goal", type=float, default=2.5e-10, help="MSE goal on the scaled outputs")
    p.add_argument("--max-iter", type=int, default=None,
                   help=f"stop after this many LM iterations (default {PHYSICS_MAX_ITER} with --physics first-order; "
                        f"with --physics none {DEFAULT_MAX_ITER}, with --quick {QUICK_MAX_ITER})")
    p.add_argument("--validation", default=None,
                   help="CSV x_mm,z_mm,a_deg,dx_um,dy_um,dz_um (default: 10,000 random points from the "
                        "HTM model named in the feature points' elements_file)")
    p.add_argument("--tracking-uri", default=None,
                   help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, else runs/mlflow.db)")
    p.add_argument("--run-name", default=None)
    p.add_argument("--threads", type=int, default=None, help="torch threads while training")
    p.add_argument("--no-select", dest="select_best", action="store_false",
                   help="return the last LM iterate (the paper's rule) instead of the iterate that is best on "
                        "5,000 off-grid selection points of the HTM model (default; disjoint from validation)")
    p.add_argument("--physics", choices=("none", "first-order"), default=DEFAULT_PHYSICS,
                   help="first-order (the default, the measured best): the network learns what an element set fitted "
                        "to the SAME feature points leaves (one linear least-squares solve, stations at the grid's "
                        "nodes; the field is that HTM model plus the network); none: the network learns the feature "
                        "points (the paper's); on a machine-tool chain the element set is the chain's own (its "
                        "machine file's slots)")
    p.add_argument("--physics-stations", type=int, default=None,
                   help="--physics first-order: stations per axis of the fitted element set (default: the "
                        "feature-point grid's points per axis)")
    p.set_defaults(func=run)


def _read_validation(path, axis_columns=("x_mm", "z_mm", "a_deg")):
    t = read_table(path, "featurepoints")
    cols = tuple(axis_columns) + ("dx_um", "dy_um", "dz_um")
    t.require(*cols)
    d = np.stack([t.float(c) for c in cols], axis=1)
    if len(d) < 1:
        raise InputError(f"{path}: no validation points")
    k = len(axis_columns)
    return d[:, :k], d[:, k:]


def run(args) -> int:
    from errormap.featurepoints import FeaturePoints

    hidden = tuple(int(h) for h in args.hidden.split(","))   # checked before run (validate.Widths)
    max_time = args.max_time if args.max_time is not None else math.inf
    max_iter = args.max_iter if args.max_iter is not None else default_max_iter(args.physics, args.quick)
    from training.trainers import TrackSettings, TrainSettings, a_encoding_applies, fit_field, network_for
    try:
        settings = TrainSettings(trainer=args.trainer, max_iter=max_iter, max_time_s=max_time, seed=args.seed,
                                 hidden=hidden, activation=args.activation, a_encoding=args.a_encoding or "raw",
                                 mse_goal=args.mse_goal, threads=args.threads, select_best=args.select_best,
                                 physics=args.physics, physics_stations=args.physics_stations)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    fp = FeaturePoints.load(args.featurepoints)
    machine = _machine(fp)
    fp.check_units(machine)
    if args.a_encoding is not None and not a_encoding_applies(machine):  # refused, never silently ignored
        raise UsageError(f"--a-encoding: the machine-tool chain {machine.name!r} has no rotary axis short of a full "
                         "turn to encode (a full-turn rotary axis is always (cos, sin), a linear axis one scaled input)")
    if args.trainer == "lm":
        from ..validate import check_lm_size
        check_lm_size(len(fp.axes), network_for(machine, settings).n_params)
    validation = _read_validation(args.validation, machine.axis_columns) if args.validation else None
    out = Path(args.out)
    print(f"training {args.trainer} on {len(fp.axes)} feature points of the machine tool {machine.name!r} "
          f"({', '.join(machine.axis_columns)}) from {args.featurepoints} (at most {max_iter} iterations"
          + (f", {max_time:g} s" if math.isfinite(max_time) else "") + ") ...", file=sys.stderr)
    tracking = TrackSettings(tracking_uri=args.tracking_uri, run_name=args.run_name,
                             tags={"featurepoints_file": str(Path(args.featurepoints).resolve())})
    res = fit_field(fp, settings, machine=machine, validation=validation, tracking=tracking, out_dir=out)
    m = res.metrics
    print(f"stopped after {res.history.iterations} iterations, {res.seconds:.1f} s "
          f"({m['train_cpu_seconds']:.1f} CPU s): {res.history.stop_reason}")
    if res.history.stop_reason.startswith("time budget"):
        print(f"the wall-clock budget decided where training stopped; --max-iter {res.history.iterations} "
              "(without --max-time) reproduces this model")
    _print_fit(args, res, "the chain's element set", " (kept alone: the network did not improve it)"
               if m.get("physics_alone_kept") else "")
    print(f"{'baseline (OLS)':<16}{m['baseline_ols_val_max_um']:>10.4f}{m['baseline_ols_val_rms_um']:>10.4f}"
          "   (affine least squares on the axes, same validation points)")
    print(f"wrote model: {out / 'model'} (inputs {', '.join(machine.axis_columns)}; machine {machine.name})")
    print(f"wrote model file: {_model_file(out, machine, args, res.run_id)}")
    print(f"wrote plots: {out / 'fit_error_xz.png'}, {out / 'fit_featurepoints.png'}")
    print(f"wrote metrics: {out / 'metrics.json'}")
    from training.tracking import default_tracking_uri
    uri = args.tracking_uri or default_tracking_uri()   # the store fit_field recorded the run in
    print(f"run id: {res.run_id}")
    print(f"use it with: --machine {machine.path or machine.name} --model runs:/{res.run_id}/model --tracking-uri {uri}")
    print(f"use it with: --machine {machine.path or machine.name} --model {out / 'model'}")
    return 0


def _print_fit(args, res, physics: str, kept: str) -> None:
    """The fit-error table: the physical part alone (``physics`` fitted to the feature points, ``kept``
    appended), then max / RMS / per-component max on the training and the validation points (μm)."""
    m = res.metrics
    print(f"{'fit error (μm)':<16}{'max':>10}{'rms':>10}{'max dx':>10}{'max dy':>10}{'max dz':>10}")
    if args.physics != "none":
        n = res.params["physics_stations"]
        print(f"physical part alone ({physics} fitted to the feature points, {n} stations per axis): "
              f"train max {m['physics_train_max_um']:.4f} μm, val max {m['physics_val_max_um']:.4f} μm{kept}")
    for p in ("train", "val"):
        print(f"{p + ' (' + str(res.params['n_' + p]) + ' pts)':<16}" + "".join(
            f"{m[k]:>10.4f}" for k in (f"{p}_max_um", f"{p}_rms_um", f"{p}_max_dx_um", f"{p}_max_dy_um",
                                       f"{p}_max_dz_um")))


def _machine(fp):
    """The machine tool the feature points were made on: the recorded machine file, else the built-in machine of
    the recorded name (the built-in default where the recorded SHA-256 is its file's, or the file has no
    ``axis_columns``: an older grinder's, said in one line); its family must train, its SHA-256 be the recorded one
    and its axis columns the file's."""
    from errormap.machine import load_machine, made_on
    src = fp.source or "feature points"
    mf, name = fp.meta.get("machine_file"), fp.meta.get("machine")
    named = "axis_columns" in fp.meta
    if not named:
        print(f"{src}: no header key 'axis_columns': read as {', '.join(fp.axis_columns)} (the grinder's columns, "
              "which a feature-point file without it holds)", file=sys.stderr)
    if named and not (mf and Path(mf).is_file()) and not name:
        raise InputError(f"{src}: header key 'machine': the feature points name no machine (nor a readable "
                         "machine_file)")
    sha = fp.meta.get("machine_sha256")
    by_name = named and not (sha and made_on(load_machine(), sha))   # the default grinder is found by its SHA-256
    machine = load_machine(mf if mf and Path(mf).is_file() else (name if by_name else None))
    family_of(machine).target("train")   # feature points of a machine tool only
    if sha and machine.sha256 and not made_on(machine, sha):
        raise InputError(f"{src}: header key 'machine_sha256': the feature points were made on another version of "
                         f"the machine file {machine.path}")
    if tuple(fp.axis_columns) != tuple(machine.axis_columns):
        raise InputError(f"{src}: header key 'axis_columns': {', '.join(fp.axis_columns)}"
                         f"{'' if named else ' (missing: read as the default)'}; the machine "
                         f"{machine.name!r} has {', '.join(machine.axis_columns)}")
    return machine


def _model_file(out, machine, args, run_id):
    """``OUT/model.json``: the model file naming the trained network folder ``OUT/model`` (what every command reads
    as ``--model``; docs/reference/file-formats.md)."""
    from ...model_file import save_model_file
    prov = {"written_by": "volcomp train", "featurepoints": str(args.featurepoints)}
    if run_id:
        prov["mlflow_run_id"] = str(run_id)
    return save_model_file(Path(out) / "model.json", machine, network_folder=Path(out) / "model", kept_stage="network",
                           provenance=prov)
