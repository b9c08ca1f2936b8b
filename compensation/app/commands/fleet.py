"""``volcomp fleet``: identify → train → diagnose for every machine of a fleet file (docs/how-to/scale-out.md)."""
from __future__ import annotations

import sys
from pathlib import Path

from errormap.io import write_json
from training import DEFAULT_PHYSICS, default_max_iter

from ..outputs import is_lock
from ..validate import UsageError, one_line
from ..options import add_cluster_options, cluster_settings
from ..workflows.cluster import EXIT_CLUSTER, ClusterError

DEFAULT_TRAIN_ITER = default_max_iter(DEFAULT_PHYSICS)  # as `volcomp train`'s default (training.DEFAULT_PHYSICS)


def register(sub):
    p = sub.add_parser(
        "fleet", help="identify → train → diagnose every machine of a fleet file, one task per machine (Ray)",
        description="For each [[machine]] of FLEET (TOML, docs/reference/file-formats.md): identify the elements from its sweeps, "
                    "train the network on their feature points (an MLflow run), diagnose its checks (measured "
                    "residual). Writes DIR/<name>/ per machine and DIR/fleet_summary.json. Exit status 4 when a "
                    "machine failed, else 1 when a machine's diagnosis verdict failed (marked, never a pass).")
    p.add_argument("fleet", metavar="FLEET", help="fleet file (TOML, format volcomp-fleet/1)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (one sub-folder per machine)")
    p.add_argument("--force", action="store_true", help="write into a DIR that already holds files")
    p.add_argument("--tracking-uri", default=None,
                   help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, else runs/mlflow.db); with --cluster ray "
                        "and several machines it must be a tracking server (http://HOST:PORT)")
    p.add_argument("--train-iter", type=int, default=DEFAULT_TRAIN_ITER,
                   help=f"LM iterations per machine (default {DEFAULT_TRAIN_ITER})")
    p.add_argument("--hidden", default="10,15,25,15,10", help="hidden layer widths, comma-separated")
    p.add_argument("--grid", type=int, default=11, help="feature points per axis (default 11)")
    p.add_argument("--bootstrap", type=int, default=None,
                   help="N >= 2 residual-bootstrap draws for the identification's covariance (default: Gauss-Newton's)")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap and of the training")
    p.add_argument("--no-learned", action="store_true",
                   help="diagnose without the learned-residual stage (as `volcomp diagnose --no-learned`: the loop "
                        "stops at the physical model's stages)")
    add_cluster_options(p, chunks=False)
    p.set_defaults(func=run)


def run(args) -> int:
    from training.tracking import check_tracking_uri as open_store, default_tracking_uri

    from ..workflows.cluster import RayExecutor
    from ..workflows.fleet import (SUMMARY_NAME, check_tracking_uri, fleet_counts, read_fleet, run_fleet,
                                   validate_inputs)
    cluster_settings(args)
    hidden = [int(h) for h in args.hidden.split(",")]   # integers >= 1, checked before run (validate.Widths)
    machines = read_fleet(args.fleet)
    uri = args.tracking_uri or default_tracking_uri()
    check_tracking_uri(uri, len(machines), args.cluster == "ray")
    open_store(args.tracking_uri)   # a store MLflow cannot open, refused before the work (validate: not for fleet)
    out = Path(args.out)   # a folder (a file there is refused before run: validate.OUT_DIR)
    if out.is_dir() and any(not is_lock(p) for p in out.iterdir()) and not args.force:
        raise UsageError(f"--out {out} already holds files; choose an empty folder or pass --force")
    print(f"fleet: checking the inputs of {len(machines)} machine(s) ...", file=sys.stderr)
    validate_inputs(machines)
    settings = {"tracking_uri": uri, "train_iter": args.train_iter, "hidden": hidden, "grid": args.grid,
                "bootstrap": args.bootstrap, "seed": args.seed, "learned": not args.no_learned, "threads": 1,
                "fleet": str(Path(args.fleet).resolve())}
    try:
        if args.cluster == "ray":
            with RayExecutor(address=args.address, workers=args.workers) as ex:
                where = ex.describe()
                results = run_fleet(machines, out, settings, executor=ex)
        else:
            where = "this process, one machine after another"
            results = run_fleet(machines, out, settings)
    except ClusterError as exc:
        print(one_line(f"volcomp fleet: error: {exc}"), file=sys.stderr)
        return EXIT_CLUSTER
    counts = fleet_counts(results)
    summary_path = write_json(out / SUMMARY_NAME, {
        "fleet": str(args.fleet), "tracking_uri": uri, "ran_on": where,
        "settings": {k: v for k, v in settings.items() if k not in ("tracking_uri", "fleet")},
        "residual": "diagnosis: measured (check measurement − model prediction) on held-out checks",
        "counts": counts, "machines": results})
    status = print_results(results)
    print(f"wrote summary: {summary_path}")
    return status


def print_results(results) -> int:
    """One line per machine (a failed verdict marked as such, never as a pass) and the exit status: 4 when a
    machine failed, else 1 when a verdict failed, else 0."""
    from ..validate import EXIT_FAILED_VERDICT
    from ..workflows.fleet import STATUS_FAILED, STATUS_OK, STATUS_VERDICT_FAILED, fleet_counts
    for r in results:
        if r.get("status") in (STATUS_OK, STATUS_VERDICT_FAILED):
            d = r["diagnosis"]
            mark = "" if r["status"] == STATUS_OK else "VERDICT FAILED: "
            print(one_line(f"{r['name']}: {mark}run {r['run_id']}, train max "
                           f"{r['train'].get('train_max_um', float('nan')):.3g} um; held-out measured RMS identified "
                           f"{d['diagnose_heldout_rms_identified_um']:.3g} -> final "
                           f"{d['diagnose_heldout_rms_final_um']:.3g} um"
                           + (f" ({'; '.join(r['verdict']['reasons'])})" if mark else "")))
    for r in results:
        if r.get("status") not in (STATUS_OK, STATUS_VERDICT_FAILED):
            print(one_line(f"volcomp fleet: {r['name']}: {STATUS_FAILED}: {r.get('error')}"), file=sys.stderr)
    c = fleet_counts(results)
    print(f"fleet: {len(c['passed'])} passed, {len(c['verdict_failed'])} verdict failed, {len(c['failed'])} failed")
    return EXIT_CLUSTER if c["failed"] else EXIT_FAILED_VERDICT if c["verdict_failed"] else 0
