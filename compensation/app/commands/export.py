"""``volcomp export``: controller compensation tables from a model, each checked before it is written.

Formats and the controller each is simulated for: :mod:`compensation.export` and docs/how-to/export-to-controller.md.
Before writing, the controller's use of the table is re-simulated on the flute path and on
random points over the volume; the MODEL residual (and, with ``--truth``, the TRUE residual)
is printed beside the no-compensation and exact-compensation baselines. When the worst model
residual exceeds ``--tolerance-um`` nothing is written and the command exits with status 2,
unless ``--force`` (the override is recorded in ``export.json``).

``--format drift`` takes a drift model (``volcomp.drift_model``) instead: its coefficients at a
fixed controller sample period, the controller re-simulated from the written file on a log
(``--log``, or a simulated one) and compared with the model's own prediction (:func:`run_drift`).
The work itself: :mod:`compensation.app.workflows.controller_tables`.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from errormap.machine import load_machine

from compensation.app.validate import UsageError

from ..families import family_of, refuse_model_family, say_read_as
from ..workflows.controller_tables import DriftSettings, TableSettings, export_drift, export_table
from ... import export as ex
from ...fields import FAILED_VERDICT

DEFAULT_TOLERANCE_UM = 1.0


def register(sub):
    p = sub.add_parser("export", help="write controller compensation tables (ISO 230-1 per-axis, 3D grid, "
                                      "LinuxCNC per-joint, drift coefficients), checked against the model first",
                       description="Export MODEL as controller compensation tables. Before writing, the "
                                   "controller's use of the table is re-simulated on the flute path and on random "
                                   "points; the model residual (and with --truth the true residual) is reported. "
                                   "Refused (exit 2, nothing written) when the tolerance is not met, unless --force. "
                                   "See docs/how-to/export-to-controller.md.")
    p.add_argument("model", metavar="MODEL", help="element-set file (JSON); grid and linuxcnc also take an MLflow "
                                                  "run id / runs:/ URI of a trained network; --format drift: a "
                                                  "drift_model.json from `volcomp diagnose --drift`")
    p.add_argument("--format", required=True, choices=ex.ALL_FORMATS, dest="fmt", help="table format")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name; default: the built-in "
                   "grinder; any machine tool (mill-xyz, five-axis-ac, lathe-xzc, a chain file): every format over its "
                   "own axes")
    p.add_argument("--tolerance-um", type=float, default=DEFAULT_TOLERANCE_UM,
                   help=f"largest model residual the table may leave (um; default {DEFAULT_TOLERANCE_UM:g}); "
                        "sizes the iso-tables rows and the grid spacing")
    p.add_argument("--truth", default=None, metavar="SIM",
                   help="simulated truth machine (a volcomp simulate folder or element-set JSON) for the true residual")
    p.add_argument("--diagnosis", default=None, metavar="JSON",
                   help="diagnosis.json: its reversal terms become the LinuxCNC forward/reverse difference")
    p.add_argument("--points", type=int, default=ex.LINUXCNC_MAX_POINTS,
                   help=f"linuxcnc: lines per joint file (2..{ex.LINUXCNC_MAX_POINTS}; default {ex.LINUXCNC_MAX_POINTS})")
    p.add_argument("--region", default=None, metavar="X0:X1,Z0:Z1",
                   help="linuxcnc: one LO:HI range (mm) per linear axis of the machine (the grinder X0:X1,Z0:Z1, a mill "
                        "X0:X1,Y0:Y1,Z0:Z1) over which each joint's correction is averaged (default: the calibrated "
                        "volume), e.g. the part's working region")
    p.add_argument("--check-points", type=int, default=2000,
                   help="random points over the volume for the check (default 2000), besides the flute")
    p.add_argument("--seed", type=int, default=0, help="seed of the check points and the per-joint sampling")
    p.add_argument("--sample-period-s", type=float, default=None,
                   help="drift: the controller's fixed sample period (s) the coefficients are for (default: the "
                        "check log's median sampling step, where the controller reproduces the model exactly)")
    p.add_argument("--log", default=None, metavar="LOG.csv",
                   help="drift: the log the controller is re-simulated on (default: the model's own fitting log, "
                        "recorded in drift_model.json; refused in one line when it is gone or changed)")
    p.add_argument("--sim", default=None, choices=("lumped", "rod"),
                   help="drift without --log: check on a simulated log of this family instead of the fitting log")
    p.add_argument("--sim-seed", type=int, default=None, help="drift without --log: check on a simulated log of this seed (family lumped unless --sim)")
    p.add_argument("--force", action="store_true",
                   help="write even when the tolerance is not met (recorded in export.json)")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.add_argument("--allow", action="append", default=[], choices=(FAILED_VERDICT,),
                   help=f"{FAILED_VERDICT}: export a model (or --diagnosis) whose diagnosis verdict failed (refused by "
                        "default); the override is recorded in export.json")
    p.set_defaults(func=run)


def region_strokes(machine) -> dict:
    """``{column: (lo, hi)}`` of the machine's linear axes in its axis order: the axes ``--region`` restricts
    (rotary axes are averaged over their whole range on every machine)."""
    return {a.column: tuple(a.stroke) for a in machine.axes if a.kind == "linear"}


def parse_region(text, machine):
    """``"LO:HI,..."``, one range per linear axis of ``machine`` in its order (the grinder ``X0:X1,Z0:Z1``, a
    mill ``X0:X1,Y0:Y1,Z0:Z1``) -> ``{column: (lo, hi)}``; UsageError on anything else or a range leaving a
    stroke. None -> None."""
    if text is None:
        return None
    strokes = region_strokes(machine)
    words = [c.split("_")[0].upper() for c in strokes]
    try:
        parts = [tuple(float(v) for v in p.split(":")) for p in text.split(",")]
        if len(parts) != len(strokes) or any(len(p) != 2 or not p[0] <= p[1] or not np.all(np.isfinite(p))
                                             for p in parts):
            raise ValueError
    except ValueError:
        raise UsageError(f"--region: expected {','.join(f'{w}0:{w}1' for w in words)} (mm, lo <= hi, one range per "
                         f"linear axis of {machine.name}), got {text!r}") from None
    for w, (c, (lo, hi)), (a, b) in zip(words, strokes.items(), parts):
        if a < lo or b > hi:
            raise UsageError(f"--region: {w} {a:g}:{b:g} leaves the stroke {lo:g}:{hi:g} of {machine.name}")
    return dict(zip(strokes, parts))


def format_check(check: dict, has_truth: bool) -> list[str]:
    lines = ["check (controller re-simulated; residual norm, um: max / p95 / mean)"]
    for name, r in check.items():
        def f(s):
            return f"{s['max_um']:9.4g} / {s['p95_um']:9.4g} / {s['mean_um']:9.4g}"
        lines.append(f"  {name} ({r['model']['n']} points{', %d excluded' % r['excluded'] if r['excluded'] else ''}):")
        for label, b in (("table         ", r), ("no compensation", r["baseline_none"]),
                         ("exact (model) ", r["baseline_exact"])):
            lines.append(f"    {label} model {f(b['model'])}" + (f"   true {f(b['true'])}" if has_truth else ""))
        if r["model"]["max_um"] > r["baseline_none"]["model"]["max_um"]:
            lines.append(f"    warning: on the {name} points this table leaves MORE error than no compensation")
    return lines


def model_verdict(args) -> dict | None:
    """The diagnosis verdict of MODEL and of ``--diagnosis``: a failed one is refused (exit 2) naming the
    file and its reasons unless ``--allow failed-verdict``; the record written into export.json."""
    from ...fields import check_verdict, resolve_model
    allowed = FAILED_VERDICT in (getattr(args, "allow", None) or [])
    verdict = check_verdict(resolve_model(args.model).path, allowed)
    if getattr(args, "diagnosis", None):
        d = check_verdict(Path(args.diagnosis), allowed)
        if d is not None and (verdict is None or d["status"] == "failed"):
            verdict = d
    return verdict


def run(args) -> int:
    machine = None if args.fmt == "drift" else load_machine(args.machine)
    if machine is not None:   # an arm or a parallel machine: no controller table (the registry's gap), nothing read
        family_of(machine).target("export")
        say_read_as(machine)
    if args.fmt != "drift":   # an arm's or a parallel machine's calibration: the registry's gap, in one line
        from ...fields import resolve_model
        refuse_model_family("export", resolve_model(args.model))
    args.model_verdict = model_verdict(args)   # before any work: a failed diagnosis is refused unless allowed
    drift_only = {"--sample-period-s": args.sample_period_s, "--log": args.log, "--sim": args.sim,
                  "--sim-seed": args.sim_seed}
    if args.fmt == "drift":
        return run_drift(args)
    given = [k for k, v in drift_only.items() if v is not None]
    if given:
        raise UsageError(f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} to --format drift only")
    if args.fmt != "linuxcnc" and (args.diagnosis or args.region):
        raise UsageError("--diagnosis and --region apply to --format linuxcnc only (the other formats carry no "
                         "reversal and are not averaged)")
    if not 2 <= args.points <= ex.LINUXCNC_MAX_POINTS:
        raise UsageError(f"--points: expected 2..{ex.LINUXCNC_MAX_POINTS}, got {args.points}")
    settings = TableSettings(
        model=args.model, fmt=args.fmt, out=args.out, tolerance_um=args.tolerance_um, check_points=args.check_points,
        seed=args.seed, truth=args.truth, diagnosis=args.diagnosis, points=args.points,
        region=parse_region(args.region, machine), force=args.force, tracking_uri=args.tracking_uri,
        model_verdict=args.model_verdict)
    info = export_table(settings, machine, on_note=print,
                        on_check=lambda check, truth: print(*format_check(check, truth), sep="\n"))
    _print_written(Path(args.out), list(info["files"]), info, args.tolerance_um)
    return 0


def _print_written(out: Path, names, info, tolerance_um) -> None:
    for name in list(names) + ["export.json"]:
        print(f"wrote: {out / name}")
    if not info["tolerance_met"]:
        print(f"warning: tolerance NOT met ({info['worst_model_residual_um']:.4g} um > {tolerance_um:g} um); "
              "written because of --force", file=sys.stderr)


def run_drift(args) -> int:
    """``--format drift``: coefficients at a fixed sample period, checked on a log before writing."""
    bad = [k for k, v in {"--machine": args.machine, "--truth": args.truth, "--diagnosis": args.diagnosis,
                          "--region": args.region}.items() if v is not None]
    if bad:
        verb = "does" if len(bad) == 1 else "do"
        raise UsageError(f"{', '.join(bad)} {verb} not apply to --format drift (a drift model needs no machine; "
                         "its truth is a simulated log: --sim/--sim-seed)")
    dt = args.sample_period_s
    if dt is not None and not (np.isfinite(dt) and 0 < dt <= ex.DRIFT_MAX_PERIOD_S):
        raise UsageError(f"--sample-period-s: expected a period in (0, {ex.DRIFT_MAX_PERIOD_S:g}] s, got {dt}")
    settings = DriftSettings(model=args.model, out=args.out, tolerance_um=args.tolerance_um,
                             sample_period_s=args.sample_period_s, log=args.log, sim=args.sim, sim_seed=args.sim_seed,
                             force=args.force, model_verdict=args.model_verdict)
    info = export_drift(settings, on_check=lambda check: print(*format_drift_check(check), sep="\n"))
    _print_written(Path(args.out), [ex.DRIFT_FILE], info, args.tolerance_um)
    return 0


def format_drift_check(check: dict) -> list[str]:
    lines = ["check (controller re-simulated from the coefficients alone; max / RMS over the log, um)"]
    for ch, r in check.items():
        m = r["model"]
        lines.append(f"  {ch}: model residual (controller - DriftModel.predict) {m['max_um']:9.3g} / {m['rms_um']:9.3g}")
        for key in ("true", "measured"):
            if r[key] is not None:
                q = r[key]
                lines.append(f"      {key:8s} before {q['before']['max_um']:7.3g} / {q['before']['rms_um']:7.3g}   "
                             f"volcomp {q['volcomp']['max_um']:7.3g} / {q['volcomp']['rms_um']:7.3g}   "
                             f"controller {q['controller']['max_um']:7.3g} / {q['controller']['rms_um']:7.3g}")
                if q.get("volcomp_distance_rule") and q["volcomp_distance_rule"] != q["volcomp"]:
                    v = q["volcomp_distance_rule"]
                    lines.append(f"      {'':8s} volcomp with the per-sample rule (export.json controller.distance_shrink) "
                                 f"{v['max_um']:7.3g} / {v['rms_um']:7.3g}")
    return lines

