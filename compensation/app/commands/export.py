"""``volcomp export``: controller compensation tables from a model, each checked before it is written.

Formats and the controller each is simulated for: :mod:`compensation.export` and docs/export.md.
Before writing, the controller's use of the table is re-simulated on the flute path and on
random points over the volume; the MODEL residual (and, with ``--truth``, the TRUE residual)
is printed beside the no-compensation and exact-compensation baselines. When the worst model
residual exceeds ``--tolerance-um`` nothing is written and the command exits with status 2,
unless ``--force`` (the override is recorded in ``export.json``).

``--format drift`` takes a drift model (``volcomp.drift_model``) instead: its coefficients at a
fixed controller sample period, the controller re-simulated from the written file on a log
(``--log``, or a simulated one) and compared with the model's own prediction (:func:`run_drift`).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from errormap.elements import ElementSet
from errormap.io import InputError, sha256_file
from errormap.iso230 import ISO_NAME
from errormap.machine import load_machine

from ..cli import UsageError
from ... import export as ex

DEFAULT_TOLERANCE_UM = 1.0
READ_BACK_TOL_UM = 1e-5
"""Read-back check (μm; joint units × 1000 for LinuxCNC, i.e. μm and millidegrees): the CSV files
hold 12 significant digits and the LinuxCNC files 9 decimals of mm/deg (rounding ≤ 5e-7 μm per
value, three values per command), so the table read back must agree to 1e-5."""


def register(sub):
    p = sub.add_parser("export", help="write controller compensation tables (ISO 230-1 per-axis, 3D grid, "
                                      "LinuxCNC per-joint, drift coefficients), checked against the model first",
                       description="Export MODEL as controller compensation tables. Before writing, the "
                                   "controller's use of the table is re-simulated on the flute path and on random "
                                   "points; the model residual (and with --truth the true residual) is reported. "
                                   "Refused (exit 2, nothing written) when the tolerance is not met, unless --force. "
                                   "See docs/export.md.")
    p.add_argument("model", metavar="MODEL", help="element-set file (JSON); grid and linuxcnc also take an MLflow "
                                                  "run id / runs:/ URI of a trained network; --format drift: a "
                                                  "drift_model.json from `volcomp diagnose --drift`")
    p.add_argument("--format", required=True, choices=ex.ALL_FORMATS, dest="fmt", help="table format")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
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
                   help="linuxcnc: axis region (mm) over which each joint's correction is averaged "
                        "(default: the whole strokes), e.g. the part's working region")
    p.add_argument("--check-points", type=int, default=2000,
                   help="random points over the volume for the check (default 2000), besides the flute")
    p.add_argument("--seed", type=int, default=0, help="seed of the check points and the per-joint sampling")
    p.add_argument("--sample-period-s", type=float, default=None,
                   help="drift: the controller's fixed sample period (s) the coefficients are for (default: the "
                        "check log's median sampling step, where the controller reproduces the model exactly)")
    p.add_argument("--log", default=None, metavar="LOG.csv",
                   help="drift: the log the controller is re-simulated on (default: a simulated log, --sim)")
    p.add_argument("--sim", default=None, choices=("lumped", "rod"),
                   help="drift without --log: the simulator family of the check log (default lumped)")
    p.add_argument("--sim-seed", type=int, default=None, help="drift without --log: the simulator seed (default 0)")
    p.add_argument("--force", action="store_true",
                   help="write even when the tolerance is not met (recorded in export.json)")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.set_defaults(func=run)


def parse_region(text):
    """``"X0:X1,Z0:Z1"`` -> ``{"x_mm": (x0, x1), "z_mm": (z0, z1)}``; UsageError on anything else."""
    if text is None:
        return None
    try:
        parts = [tuple(float(v) for v in p.split(":")) for p in text.split(",")]
        if len(parts) != 2 or any(len(p) != 2 or not p[0] <= p[1] or not np.all(np.isfinite(p)) for p in parts):
            raise ValueError
    except ValueError:
        raise UsageError(f"--region: expected X0:X1,Z0:Z1 (mm, lo <= hi), got {text!r}") from None
    return {"x_mm": parts[0], "z_mm": parts[1]}


def _load_model(args, machine):
    p = Path(args.model)
    if p.suffix.lower() == ".json" or p.is_file():
        el = ElementSet.load(p)
        if el.machine_sha256 and el.machine_sha256 != machine.sha256:
            raise InputError(f"{p}: key 'machine_sha256': the model was made for machine file sha256 "
                             f"{el.machine_sha256[:12]}…, but the machine given is {machine.sha256[:12]}… "
                             f"({machine.path}); pass the model's --machine")
        return ex.ModelError(machine, el), f"{p} (element set, sha256 {sha256_file(p)})"
    if args.fmt == "iso-tables":
        raise UsageError("--format iso-tables needs an element-set model (JSON): ISO component tables are the 23 "
                         "elements' components")
    from ...fields import load_field
    return ex.ModelError(machine, field=load_field(args.model, machine, args.tracking_uri)), f"{args.model} (learned field)"


def format_check(check: dict, has_truth: bool) -> list[str]:
    lines = ["check (controller re-simulated; residual norm, um: max / p95 / mean)"]
    for name, r in check.items():
        def f(s):
            return f"{s['max_um']:9.4g} / {s['p95_um']:9.4g} / {s['mean_um']:9.4g}"
        lines.append(f"  {name} ({r['model']['n']} points{', %d excluded' % r['excluded'] if r['excluded'] else ''}):")
        lines.append(f"    table          model {f(r['model'])}" + (f"   true {f(r['true'])}" if has_truth else ""))
        lines.append(f"    no compensation model {f(r['baseline_none']['model'])}"
                     + (f"   true {f(r['baseline_none']['true'])}" if has_truth else ""))
        lines.append(f"    exact (model)  model {f(r['baseline_exact']['model'])}"
                     + (f"   true {f(r['baseline_exact']['true'])}" if has_truth else ""))
        if r["model"]["max_um"] > r["baseline_none"]["model"]["max_um"]:
            lines.append(f"    warning: on the {name} points this table leaves MORE error than no compensation")
    return lines


def run(args) -> int:
    drift_only = {"--sample-period-s": args.sample_period_s, "--log": args.log, "--sim": args.sim,
                  "--sim-seed": args.sim_seed}
    if args.fmt == "drift":
        return run_drift(args)
    given = [k for k, v in drift_only.items() if v is not None]
    if given:
        raise UsageError(f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} to --format drift only")
    machine = load_machine(args.machine, expect_kind="grinder")
    if not (np.isfinite(args.tolerance_um) and args.tolerance_um > 0):
        raise UsageError(f"--tolerance-um: expected a positive number, got {args.tolerance_um}")
    if args.check_points < 1:
        raise UsageError(f"--check-points: expected >= 1, got {args.check_points}")
    if args.fmt != "linuxcnc" and (args.diagnosis or args.region):
        raise UsageError("--diagnosis and --region apply to --format linuxcnc only (the other formats carry no "
                         "reversal and are not averaged)")
    if not 2 <= args.points <= ex.LINUXCNC_MAX_POINTS:
        raise UsageError(f"--points: expected 2..{ex.LINUXCNC_MAX_POINTS}, got {args.points}")
    region = parse_region(args.region)
    model, model_desc = _load_model(args, machine)
    left_out = []
    if args.diagnosis:
        back, left_out = ex.backlash_from_diagnosis(args.diagnosis)
        if model.elements is None:
            raise UsageError("--diagnosis needs an element-set model (the reversal is added to an element)")
        model.backlash = back
    truth = None
    if args.truth:
        from ...evaluate import load_truth
        truth = load_truth(args.truth, machine)
    sets = ex.check_sets(machine, args.check_points, args.seed)
    say = lambda s: print(s, file=sys.stderr)  # noqa: E731
    say("sizing the table and re-simulating the controller on the flute and the volume ...")
    try:
        table, sizing, check = ex.build_checked_table(args.fmt, model, machine, args.tolerance_um, sets, truth,
                                                      {}, n_points=args.points, region=region, seed=args.seed,
                                                      log=say)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    for line in format_check(check, truth is not None):
        print(line)
    worst = ex.worst_model_um(check)
    met = worst <= args.tolerance_um
    if not met and not args.force:
        raise UsageError(f"tolerance not met: the {args.fmt} table leaves a model residual up to {worst:.4g} um > "
                         f"--tolerance-um {args.tolerance_um:g}; nothing written (--force writes anyway, recorded "
                         "in export.json)")
    info = {"format": "volcomp-export/1", "table_format": args.fmt, "model": model_desc,
            "machine": {"name": machine.name, "file": machine.path, "sha256": machine.sha256},
            "tolerance_um": args.tolerance_um, "tolerance_met": bool(met), "worst_model_residual_um": worst,
            "override": None if met else {"forced": True, "reason": f"worst model residual {worst:.6g} um exceeds "
                                                                    f"the tolerance {args.tolerance_um:g} um"},
            "sizing": sizing, "check": check,
            "check_points": {"flute": "default flute path (compensation.toolpath.flute_path)",
                             "volume": f"{args.check_points} uniform random axis points, seed {args.seed}"},
            "residuals": {"model": "fwd(q_c) + E_model(q_c) - p_d (um), q_c = the controller's command with the table",
                          "true": "truth.tool_point(q_c) - p_d (um)" if truth is not None else "no --truth given"},
            "truth": args.truth, "iso230_names": dict(ISO_NAME)}
    if args.fmt == "linuxcnc":
        info["backlash_joint_units"] = dict(table.backlash)
        info["diagnosis"] = args.diagnosis
        info["diagnosed_effects_not_exported"] = left_out
        info["linuxcnc"] = {"columns": "nominal forward reverse (mm for x, z; deg for a)",
                            "meaning": "forward/reverse: actual joint position when commanded to nominal moving +/-; "
                                       "the controller commands nominal + (nominal - actual)",
                            "a": "one turn; the controller folds A into it (wrapped rotary joint)"}
    with ex.staged_folder(args.out) as tmp:
        files = ex.write_table(table, tmp, machine, model_desc)
        back = ex.read_back(args.fmt, tmp)
        diff = _read_back_difference(table, back, machine, sets)
        if diff > READ_BACK_TOL_UM:
            raise RuntimeError(f"read-back check failed: the written {args.fmt} table differs from the built one by "
                               f"{diff:.3g} um")
        info["read_back_difference_um"] = diff
        info["files"] = {p.name: p.stat().st_size for p in files}
        info["table_values"] = table.n_values()
        ex.write_manifest(tmp, info)
    out = Path(args.out)
    for name in list(info["files"]) + ["export.json"]:
        print(f"wrote: {out / name}")
    if not met:
        print(f"warning: tolerance NOT met ({worst:.4g} um > {args.tolerance_um:g} um); written because of --force",
              file=sys.stderr)
    return 0


def _read_back_difference(table, back, machine, sets) -> float:
    """Largest difference (μm, or μm-equivalent of the joint commands) between the built and the
    read-back table, as the controller uses them, at the check axes."""
    worst = 0.0
    for targets, axes, dirs in sets.values():
        if table.kind == "linuxcnc":
            d = (table.command(axes, dirs) - back.command(axes, dirs)) * np.array([1e3, 1e3, 1e3])
        else:
            d = table.field(machine)(axes) - back.field(machine)(axes)
        worst = max(worst, float(np.abs(d).max()))
    return worst


def _drift_check_log(args):
    """The log the controller is re-simulated on, its description, and the noise-free displacement
    when it is simulated (``{channel: (n,)}``, else None)."""
    from errormap.diagnosis.drift import DriftLog, load_drift_log
    if args.log is not None:
        if args.sim is not None or args.sim_seed is not None:
            raise UsageError("--sim and --sim-seed choose a simulated log: give them or --log, not both")
        log = load_drift_log(args.log, causal=True, require_displacement=False)
        for c, why in log.notes["dropped"].items():
            print(f"dropped input {c}: {why}", file=sys.stderr)
        return log, f"{args.log} (sha256 {sha256_file(args.log)})", None
    from errormap.diagnosis.drift_sim import SIMULATORS
    fam, seed = args.sim or "lumped", 0 if args.sim_seed is None else args.sim_seed
    cols = SIMULATORS[fam](seed, n_dropouts=0)
    truth = cols.pop("_truth")
    name = f"<simulated {fam} log, seed {seed}>"
    log = DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                   {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols.get("speed_rpm"), name)
    return log, f"simulated: errormap.diagnosis.drift_sim {fam}, seed {seed}, no dropouts", truth["clean_um"]


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
    return lines


def run_drift(args) -> int:
    """``--format drift``: coefficients at a fixed sample period, checked on a log before writing."""
    from errormap.diagnosis.drift_models import DriftModel
    bad = [k for k, v in {"--machine": args.machine, "--truth": args.truth, "--diagnosis": args.diagnosis,
                          "--region": args.region}.items() if v is not None]
    if bad:
        verb = "does" if len(bad) == 1 else "do"
        raise UsageError(f"{', '.join(bad)} {verb} not apply to --format drift (a drift model needs no machine; "
                         "its truth is a simulated log: --sim/--sim-seed)")
    if not (np.isfinite(args.tolerance_um) and args.tolerance_um > 0):
        raise UsageError(f"--tolerance-um: expected a positive number, got {args.tolerance_um}")
    dt = args.sample_period_s
    if dt is not None and not (np.isfinite(dt) and 0 < dt <= ex.DRIFT_MAX_PERIOD_S):
        raise UsageError(f"--sample-period-s: expected a period in (0, {ex.DRIFT_MAX_PERIOD_S:g}] s, got {dt}")
    model = DriftModel.load(args.model)
    model_desc = f"{args.model} (drift model, sha256 {sha256_file(args.model)})"
    log, log_desc, clean = _drift_check_log(args)
    step = float(np.median(np.diff(log.time_s)))
    if dt is None:
        dt = step
    print(f"re-simulating the controller at dt = {dt:g} s on {log_desc} (median sampling step {step:g} s) ...",
          file=sys.stderr)
    with ex.staged_folder(args.out) as tmp:
        # force=True here: the check is printed first, then refused below (the staging folder is discarded)
        res = ex.export_drift_coefficients(model, tmp, dt, log, model_desc, args.tolerance_um, clean, force=True)
        for line in format_drift_check(res["check"]):
            print(line)
        worst, met = res["worst_model_residual_um"], res["tolerance_met"]
        if not met and not args.force:
            raise UsageError(f"tolerance not met: at a sample period of {dt:g} s the drift coefficients leave a model "
                             f"residual up to {worst:.4g} um > --tolerance-um {args.tolerance_um:g}; nothing written "
                             "(--force writes anyway, recorded in export.json)")
        coef = res["coefficients"]
        info = {"format": "volcomp-export/1", "table_format": "drift", "model": model_desc,
                "sample_period_s": dt, "sample_period_given": args.sample_period_s is not None,
                "check_log_median_step_s": step, "tolerance_um": args.tolerance_um, "tolerance_met": met,
                "worst_model_residual_um": worst,
                "override": None if met else {"forced": True, "reason": f"worst model residual {worst:.6g} um "
                                                                        f"exceeds the tolerance {args.tolerance_um:g} um"},
                "check_log": log_desc, "check": res["check"],
                "residuals": {"model": "controller(coefficients) - DriftModel.predict at each log time (um)",
                              "measured": "log displacement - prediction (um); before = the displacement itself",
                              "true": "noise-free simulated displacement - prediction (um)" if clean is not None
                                      else "no simulated log (--log given)"},
                "controller": {"ticks": f"every {dt:g} s from the log's first time; each tick reads the latest "
                                        f"logged value at or before it (within {ex.DRIFT_TICK_EPS_S:g} s)",
                               "output": "the prediction of the latest tick at or before each log time"},
                "files": {ex.DRIFT_FILE: res["file"].stat().st_size},
                "table_values": coef.n_values()}
        ex.write_manifest(tmp, info)
    out = Path(args.out)
    for name in (ex.DRIFT_FILE, "export.json"):
        print(f"wrote: {out / name}")
    if not met:
        print(f"warning: tolerance NOT met ({worst:.4g} um > {args.tolerance_um:g} um); written because of --force",
              file=sys.stderr)
    return 0
