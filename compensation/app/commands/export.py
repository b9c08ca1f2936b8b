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
The work itself: :mod:`compensation.app.workflows.controller_tables`.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from errormap.machine import check_machine_kind, load_machine

from compensation.app.validate import UsageError

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
                                   "See docs/export.md.")
    p.add_argument("model", metavar="MODEL", help="element-set file (JSON); grid and linuxcnc also take an MLflow "
                                                  "run id / runs:/ URI of a trained network; --format drift: a "
                                                  "drift_model.json from `volcomp diagnose --drift`")
    p.add_argument("--format", required=True, choices=ex.ALL_FORMATS, dest="fmt", help="table format")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name; default: the built-in "
                   "grinder; a machine-tool chain (mill-xyz ...): --format iso-tables, grid or linuxcnc over its own axes")
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
    axes = getattr(machine, "axes", None)
    if axes is None:   # the grinder's own file: X and Z are its linear axes
        return {k: tuple(machine.strokes[k]) for k in ("x_mm", "z_mm")}
    return {a.column: tuple(a.stroke) for a in axes if a.kind == "linear"}


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
        lines.append(f"    table          model {f(r['model'])}" + (f"   true {f(r['true'])}" if has_truth else ""))
        lines.append(f"    no compensation model {f(r['baseline_none']['model'])}"
                     + (f"   true {f(r['baseline_none']['true'])}" if has_truth else ""))
        lines.append(f"    exact (model)  model {f(r['baseline_exact']['model'])}"
                     + (f"   true {f(r['baseline_exact']['true'])}" if has_truth else ""))
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
    args.model_verdict = model_verdict(args)   # before any work: a failed diagnosis is refused unless allowed
    drift_only = {"--sample-period-s": args.sample_period_s, "--log": args.log, "--sim": args.sim,
                  "--sim-seed": args.sim_seed}
    if args.fmt == "drift":
        return run_drift(args)
    given = [k for k, v in drift_only.items() if v is not None]
    if given:
        raise UsageError(f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} to --format drift only")
    machine = load_machine(args.machine)
    if args.fmt != "linuxcnc" and (args.diagnosis or args.region):
        raise UsageError("--diagnosis and --region apply to --format linuxcnc only (the other formats carry no "
                         "reversal and are not averaged)")
    if machine.kind == "machine-tool":  # a chain file: ISO tables per axis of its own axes
        return run_chain_export(args, machine)
    check_machine_kind(machine.path, machine.kind, "grinder")
    if not 2 <= args.points <= ex.LINUXCNC_MAX_POINTS:
        raise UsageError(f"--points: expected 2..{ex.LINUXCNC_MAX_POINTS}, got {args.points}")
    settings = TableSettings(
        model=args.model, fmt=args.fmt, out=args.out, tolerance_um=args.tolerance_um, check_points=args.check_points,
        seed=args.seed, truth=args.truth, diagnosis=args.diagnosis, points=args.points,
        region=parse_region(args.region, machine), force=args.force, tracking_uri=args.tracking_uri,
        model_verdict=args.model_verdict)
    info = export_table(settings, machine, on_check=_print_check)
    _print_written(Path(args.out), list(info["files"]), info, args.tolerance_um)
    return 0


def _print_check(check, has_truth) -> None:
    for line in format_check(check, has_truth):
        print(line)


def _print_drift_check(check) -> None:
    for line in format_drift_check(check):
        print(line)


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
    info = export_drift(settings, on_check=_print_drift_check)
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




def run_chain_export(args, machine) -> int:
    """``--format iso-tables`` (per-axis ISO tables, linear between rows) or ``grid`` (a 3-D grid over
    an all-linear machine's axes, trilinear) on a machine-tool chain (:mod:`compensation.mt_export`),
    checked before writing."""
    from errormap.io import write_json
    from ...fields import require_kind, resolve_model
    from ... import mt_export
    from errormap.mt_elements import ChainElementSet
    if args.fmt == "linuxcnc":
        return run_chain_linuxcnc(args, machine)
    if args.fmt not in ("iso-tables", "grid"):
        raise UsageError(f"--format {args.fmt}: on the machine-tool chain {machine.name!r} the formats are "
                         "iso-tables, grid and linuxcnc")
    if args.fmt == "grid":
        try:
            mt_export.linear_only(machine)
        except ValueError as exc:
            raise UsageError(f"--format grid: {exc}") from None
    src = require_kind(resolve_model(args.model), ("elements",), f"on the machine-tool chain {machine.name!r} export "
                                                                 "takes")
    el = ChainElementSet.load(src.path, machine)
    truth = ChainElementSet.load(args.truth, machine) if args.truth else None
    pts = mt_export.check_points(el, args.check_points, args.seed)
    if args.fmt == "grid":
        from errormap.mt_field import ChainField
        ticks, vals, n_rows, check = mt_export.build_chain_grid(
            el, ChainField(machine, el), args.tolerance_um, pts, ChainField(machine, truth) if truth else None)
    else:
        tables, n_rows, check = mt_export.build_chain_tables(el, args.tolerance_um, pts, truth)
    what = "grid ticks per axis" if args.fmt == "grid" else "rows per axis"

    def f(q):
        return f"{q['max_um']:9.4g} / {q['p95_um']:9.4g} / {q['mean_um']:9.4g}"
    interp = "trilinear between grid nodes" if args.fmt == "grid" else "table rows linear"
    print(f"check ({check['model']['n']} random points over the calibrated volume; {interp}; residual norm, "
          "um: max / p95 / mean)")
    print(f"  table ({n_rows} {what}) model {f(check['model'])}" + (f"   true {f(check['true'])}" if truth else ""))
    print(f"  no compensation          model {f(check['baseline_none']['model'])}"
          + (f"   true {f(check['baseline_none']['true'])}" if truth else ""))
    if truth is not None:
        print(f"  exact (model)                                               true {f(check['baseline_exact']['true'])}")
    met = check["model"]["max_um"] <= args.tolerance_um
    if not met and not args.force:
        raise UsageError(f"--tolerance-um {args.tolerance_um:g}: the {args.fmt} leaves {check['model']['max_um']:.4g} "
                         f"um with {n_rows} {what} (at the size limit); nothing written (--force writes anyway)")
    out = Path(args.out)
    if args.fmt == "grid":
        files = mt_export.write_chain_grid(ticks, vals, machine, out, src.description)
    else:
        files = mt_export.write_chain_tables(tables, el, out, src.description)
    write_json(out / "export.json", {"format": args.fmt, "machine": machine.name, "machine_file": machine.path,
                                     "model": src.to_dict(), "model_verdict": args.model_verdict,
                                     what.replace(" ", "_"): n_rows,
                                     "tolerance_um": args.tolerance_um,
                                     "tolerance_met": bool(met), "forced": bool(args.force and not met),
                                     "check": check, "files": [p.name for p in files],
                                     "residual": f"model: {args.fmt}-rebuilt spatial error - the model's (um)"
                                                 + (f"; true: {args.fmt}-rebuilt - the truth's (um)" if truth else "")})
    for p in files + [out / "export.json"]:
        print(f"wrote: {p}")
    return 0


def _chain_truth(path, machine):
    """``truth(axes, dirs) -> (n, 3)`` μm of ``--truth`` on a chain (truth.json of ``simulate --machine``: its
    effects at the given approach directions and the tables' reference temperature; or a truth element set)."""
    from ..workflows.mt_loop import load_chain_truth
    from ... import mt_export
    t = load_chain_truth(path, machine)
    if not hasattr(t, "truth"):
        return lambda q, dirs: t.predict(q)
    sim = t.truth

    def at(q, dirs):
        cond = {f"dir_{a.word.lower()}": dirs[:, j] for j, a in enumerate(machine.axes)}
        return sim.spatial_error(q, temp_c=np.full(len(q), mt_export.TABLE_TEMP_C), **cond)
    return at


def run_chain_linuxcnc(args, machine) -> int:
    """``--format linuxcnc`` on a machine-tool chain: one pitch table per joint the exact solver moves
    (``joint_<w>.comp``: a mill's X, Y, Z; a lathe's X, Z and C, the rotary one in degrees), that joint's exact
    correction averaged over the other axes, forward/reverse from a reversal term of a chain ``model.json``;
    checked before writing (:mod:`compensation.mt_export`)."""
    from errormap.io import write_json
    from errormap.seeds import spawn_seeds
    from ...fields import load_chain_field, require_kind, resolve_model
    from ... import mt_export
    from ...solvers.chain_exact import solved_and_kept
    region = parse_region(args.region, machine)
    if not 2 <= args.points <= ex.LINUXCNC_MAX_POINTS:
        raise UsageError(f"--points: expected 2..{ex.LINUXCNC_MAX_POINTS}, got {args.points}")
    try:
        _, rot = solved_and_kept(machine)
    except ValueError as exc:
        raise UsageError(f"--format linuxcnc: {exc}") from None
    src = require_kind(resolve_model(args.model), ("elements", "chain-model"),
                       f"on the machine-tool chain {machine.name!r} --format linuxcnc takes")
    if src.kind == "chain-model":
        if args.diagnosis:
            raise UsageError("--diagnosis: MODEL is a chain model.json, which carries its diagnosed terms already; "
                             "give it alone, or its element set with --diagnosis")
        from errormap.diagnosis.mt_model import load_chain_model_file
        field_ = load_chain_model_file(src.path, machine)
        el = field_.elements
    else:
        field_ = load_chain_field(src.path, machine, src.kind)
        el = field_.elements
    left = []
    if args.diagnosis:   # its reversal terms on the element set, as the grinder's backlash from diagnosis.json
        from errormap.diagnosis.mt_model import ChainModelField
        terms, left = mt_export.reversal_terms_from_diagnosis(args.diagnosis, machine)
        field_ = ChainModelField(machine, el, terms)
        left = [f"effect {e} in {args.diagnosis}: not carried by a per-joint table" for e in left]
    print(f"export: model {src.description}", file=sys.stderr)
    left += [f"rotary joint {machine.axes[k].word}: no file (LinuxCNC takes one pitch table per joint; volcomp "
            f"compensates the tool tip with the linear joints and keeps rotary joints as programmed, so what the "
            f"rotary axis' own errors do is left in the residual below)" for k in rot]
    terms = [f"{t.kind}:{'*'.join(t.axes)}" for t in getattr(field_, "terms", ())]
    left += [f"effect term {t}: no temperature input in a pitch table; tabulated at {mt_export.TABLE_TEMP_C:g} C"
             for t in terms if t.startswith("thermal:")]
    for line in left:
        print(f"note: {line}")
    s_tab, s_pts, s_dir = spawn_seeds(args.seed, 3)
    try:
        tables = mt_export.chain_joint_tables(field_, el, args.points, seed=s_tab, region=region)
    except ValueError as exc:
        raise UsageError(f"--region: {exc}" if region else f"--format linuxcnc: {exc}") from None
    pts = mt_export.check_points(el, args.check_points, s_pts)
    dirs = np.random.default_rng(s_dir).choice([-1.0, 1.0], pts.shape)
    truth = _chain_truth(args.truth, machine) if args.truth else None
    check = mt_export.check_chain_joint_tables(tables, field_, machine, pts, dirs, truth)

    def f(q):
        return f"{q['max_um']:9.4g} / {q['p95_um']:9.4g} / {q['mean_um']:9.4g}"
    rotary = [j for j, u in tables.units.items() if u != "mm"]
    for j in rotary:
        print(f"note: rotary joint {j.upper()}: table in degrees, its correction averaged over the other axes weighted "
              f"by r^2 (r the tool point's distance from its axis: the least-squares angle)"
              + (f"; one turn from {tables.turns[j]:g} deg, read with the position folded into it (modulo 360)"
                 if j in tables.turns else ""))
    print(f"check ({check['model']['n']} random points over the calibrated volume, random approach directions; "
          f"controller: each {'tabulated' if rotary else 'linear'} joint commanded q + (q - actual), linear between "
          "lines; residual norm, um: max / p95 / mean)")
    for name, q in (("table", check), ("no compensation", check["baseline_none"]),
                    ("exact (model)", check["baseline_exact"])):
        print(f"  {name:16s} model {f(q['model'])}" + (f"   true {f(q['true'])}" if truth else ""))
    if check["model"]["max_um"] > check["baseline_none"]["model"]["max_um"]:
        print("  warning: these tables leave MORE error than no compensation at the worst point")
    met = check["model"]["max_um"] <= args.tolerance_um
    if not met and not args.force:
        raise UsageError(f"--tolerance-um {args.tolerance_um:g}: the per-joint tables leave a model residual up to "
                         f"{check['model']['max_um']:.4g} um (a joint's table cannot carry what depends on the other "
                         "axes); nothing written (--force writes anyway, recorded)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    files = ex.write_joint_tables(tables, out)
    reversal = {j: float(np.max(np.abs(tables.forward[j] - tables.reverse[j]))) * 1e3 for j in tables.nominal}
    write_json(out / "export.json", {
        "format": "linuxcnc", "machine": machine.name, "machine_file": machine.path, "model": src.to_dict(),
        "model_verdict": args.model_verdict,
        "points_per_joint": args.points, "region": region or "calibrated volume",
        **({"diagnosis": str(args.diagnosis)} if args.diagnosis else {}), "joints": {j: machine.axis_columns[k] for j, k in tables.joints.items()},
        "max_forward_minus_reverse_um": reversal, "left_out": left, "tolerance_um": args.tolerance_um,
        "tolerance_met": bool(met), "forced": bool(args.force and not met), "check": check,
        "files": [p.name for p in files],
        **({"joint_units": dict(tables.units), "joint_turns_from_deg": dict(tables.turns)} if rotary else {}),
        "linuxcnc": {"columns": "nominal forward reverse (mm)" if not rotary else
                     "nominal forward reverse (the joint's unit: mm, deg for a rotary joint)",
                     "controller": "command = q + (q - actual(q)), actual = forward (moving +) or reverse (moving -), "
                                   "linear between lines"},
        "residual": "model: the model machine's tool point with the table's commands - the target (um)"
                    + ("; true: the truth machine's (um)" if truth else "")})
    for p in files + [out / "export.json"]:
        print(f"wrote: {p}")
    return 0
