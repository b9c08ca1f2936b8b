"""``volcomp report``: compare the compensation methods on a tool path; HTML report + metrics.json.

Runs ``traditional``, ``ga``, ``batched-ga`` and ``exact`` (or ``--methods``) with one error
field on one path (``--path FILE``, read as ``compensate`` reads it, or the grinder's built-in ``--flute``)
on any machine tool through its chain (the solvers of ``compensate``), computes the MODEL residual
of each and — with ``--truth`` (a ``volcomp simulate`` folder or an element-set file) — the
TRUE residual on the simulated machine, and writes ``DIR/report.html``, ``DIR/metrics.json``
and ``DIR/residuals.csv`` (see :mod:`compensation.app.reports.methods`).
"""
from __future__ import annotations

import sys
from pathlib import Path

from errormap.machine import load_machine

from compensation.app.validate import UsageError

from ...fields import CHAIN_MODEL_FORMAT, FAILED_VERDICT, MODEL_FORMAT, check_verdict, resolve_model
from ...model_file import read_model
from ...nc_state import read_work_offsets
from ..families import family_of, refuse_model_family
from ..options import add_flute_arguments, add_method_arguments, add_units_option, flute_from_args, parse_methods
from ..workflows.compare import compare_methods
from ...toolpath import check_in_strokes


def register(sub):
    p = sub.add_parser(
        "report", help="compare compensation methods on a path: report.html + metrics.json",
        description="Run the compensation methods on a tool path and write DIR/report.html (self-contained), "
                    "DIR/metrics.json and DIR/residuals.csv. Shows the MODEL residual, and the TRUE residual "
                    "when --truth is given.")
    p.add_argument("run", nargs="?", default=None, metavar="RUN",
                   help="a `volcomp diagnose --machine` output folder (machine-tool chain): write its page "
                        "(RUN/report.html, or --out DIR/report.html) instead of comparing methods")
    p.add_argument("--model", default=None, help="MLflow run id, runs:/ URI, or element-set file (JSON)")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder (with RUN: "
                   "the machine its model.json names)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--path", help="tool-path file (CSV or G-code)")
    src.add_argument("--flute", action="store_true", help="the built-in variable-helix flute path")
    p.add_argument("--truth", default=None,
                   help="simulate folder (or its truth.json) or truth element set, on the machine's chain: adds the TRUE "
                        "residual")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.add_argument("--out", default=None, metavar="DIR", help="output folder (required unless RUN is given)")
    add_units_option(p, "CSV tool-path columns")
    p.add_argument("--work-offsets", default=None, metavar="FILE|machine",
                   help="the controller's work offsets of a --path G-code program, as compensate reads them (a LinuxCNC "
                        ".var or a CSV, by content); 'machine': the program is written in machine coordinates (recorded "
                        "in the report); a G-code program is refused without it (never an assumed machine zero)")
    p.add_argument("--allow", action="append", default=[], choices=(FAILED_VERDICT,),
                   help=f"{FAILED_VERDICT}: compare methods with a model whose diagnosis verdict failed (refused by "
                        "default); recorded in metrics.json and on the page")
    add_method_arguments(p)
    add_flute_arguments(p)
    p.set_defaults(func=run)


def run_chain_diagnosis(args) -> int:
    """``volcomp report RUN``: the page of a chain's diagnose run (:mod:`compensation.app.reports.chain_diagnosis`)."""
    from errormap.io import InputError, read_json_object
    from ..reports.chain_diagnosis import write_chain_diagnosis_page
    bad = [f for f, v in (("--model", args.model), ("--path", args.path), ("--flute", args.flute),
                          ("--truth", args.truth), ("--allow", args.allow)) if v]
    if bad:
        raise UsageError(f"{', '.join(bad)}: with RUN (a diagnose run folder) the page shows that run; the method "
                         "comparison takes --model and --path/--flute without RUN")
    run_dir = Path(args.run)
    if not run_dir.is_dir():
        raise UsageError(f"RUN {run_dir}: not a folder (a volcomp diagnose --machine output folder)")
    head = read_json_object(run_dir / "model.json", "model.json of volcomp diagnose --machine")
    if head.get("family") is not None:    # an arm's or parallel machine's calibrate run: its page is written with it
        raise InputError(f"{run_dir / 'model.json'}: key 'family': {head.get('family')!r}, a calibrate run, whose page "
                         "is report.html beside it; report RUN shows a diagnose --machine run")
    if head.get("format") not in (MODEL_FORMAT, CHAIN_MODEL_FORMAT):
        what = ("a grinder's diagnose run writes its own page (report.html) there"
                if (run_dir / "report.html").is_file() else "not a diagnose --machine run")
        raise InputError(f"{run_dir / 'model.json'}: key 'format': expected {MODEL_FORMAT!r} (or the older "
                         f"{CHAIN_MODEL_FORMAT!r}), got {head.get('format')!r} ({what})")
    machine = load_machine(args.machine if args.machine else str(head.get("machine")))
    if not family_of(machine).runs("report run"):
        raise UsageError(f"--machine {machine.name}: the run is a machine-tool chain's; name that chain's file")
    if args.out:   # --out DIR: owned by cli.main like every --out
        path = write_chain_diagnosis_page(run_dir, machine, Path(args.out) / "report.html")
    else:   # into RUN: under the run folder's lock (refused while a run writes there; Ctrl-C leaves nothing new)
        from ..outputs import owned_folder
        with owned_folder(run_dir, "report", flag="RUN"):
            path = write_chain_diagnosis_page(run_dir, machine, None)
    print(f"wrote html: {path}")
    from ..reports.chain_diagnosis import verdict_failure
    failed = verdict_failure(read_json_object(run_dir / "diagnosis.json", "diagnosis of volcomp diagnose --machine"))
    if failed:   # shown, not refused: the page is how the user sees why
        print(f"report: verdict FAILED ({run_dir / 'diagnosis.json'}): {failed}")
    return 0


def _refuse_out_of_strokes(path, mt, nominal, what: str) -> None:
    """As for the flute: a path the machine cannot reach has no method to compare (every solve fails its guards and
    the page would show residuals of metres): refused, naming the first data row outside a linear axis' stroke
    (a rotary axis may run past one turn)."""
    import numpy as np
    for j, a in enumerate(mt.axes):
        if a.kind != "linear":
            continue
        lo, hi = a.stroke
        out = np.flatnonzero((nominal[:, j] < lo) | (nominal[:, j] > hi))
        if out.size:
            raise UsageError(f"{path}: {what} {out[0] + 1} (of {len(nominal)}; {out.size} outside): its nominal "
                             f"{a.column} = {nominal[out[0], j]:.4f} is outside the stroke [{lo:g}, {hi:g}]; the methods "
                             "are compared on points the machine reaches (a targets CSV in another frame or unit?)")


def _flute(args, machine):
    """``(targets (n, 3), nominal axes (n, 3), path record)`` of the built-in flute (the grinder's part)."""
    try:
        fl = flute_from_args(args)
    except ValueError as exc:
        raise UsageError(f"flute settings: {exc}") from None
    nominal = fl.axes(machine)
    try:
        check_in_strokes(machine, nominal, "the flute path")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return fl.targets_mm, nominal, {"path": "flute", "flute": fl.settings.to_dict(), "points": len(fl)}


def _tool_path(args, mt):
    """``(targets (n, 3), nominal axes (n, k), path record)`` of ``--path`` on the machine tool ``mt``, read as
    ``compensate`` reads it (:func:`compensation.app.workflows.compensate_paths.read_tool_path`: the machine's axis
    columns, WCS targets or G-code in its axis words)."""
    from errormap.chain_kernel import NominalChain
    from ..workflows.compensate import CompensateSettings
    from ..workflows.compensate_paths import read_tool_path
    offsets = read_work_offsets(args.work_offsets) if args.work_offsets is not None else None
    s = CompensateSettings(method="exact", model=str(args.model), out_dir=Path(args.out), units=args.units,
                           work_offsets=offsets, max_segment_mm=None)
    tp = read_tool_path(args.path, mt, s)
    _refuse_out_of_strokes(args.path, mt, tp.axes, "data row" if tp.kind.startswith("csv") else "point")
    targets = tp.targets_mm if tp.targets_mm is not None else NominalChain(mt).forward(tp.axes)
    info = {"path": str(args.path), "format": tp.kind, "points": len(tp), "units": args.units}
    if tp.kind == "gcode":
        info["work_offsets"] = offsets.source if offsets is not None else None
    return targets, tp.axes, info


def run(args) -> int:
    if args.run is not None:
        return run_chain_diagnosis(args)
    missing = [f for f, v in (("--model", args.model), ("--path or --flute", args.path or args.flute),
                              ("--out", args.out)) if not v]
    if missing:
        raise UsageError(f"{', '.join(missing)}: required to compare methods on a path (or give RUN, a diagnose "
                         "--machine folder)")
    from ...evaluate import load_truth  # the chain's kernels (numba) and the report's figures load to run
    from ..reports.methods import print_table, write_report
    methods = parse_methods(args.methods)
    machine = load_machine(args.machine)   # None: the built-in default machine
    family = family_of(machine)
    family.target("report")   # every machine tool, through its chain: other families refused
    family.refuse_unsupported("report", args)
    targets, nominal, path_info = _flute(args, machine) if args.flute else _tool_path(args, machine)
    truth = load_truth(args.truth, machine) if args.truth else None
    source = resolve_model(args.model)  # by content: format key, model folder or MLflow reference
    refuse_model_family("report", source)   # an arm's or a parallel machine's calibration: the registry's gap
    verdict = check_verdict(source.path, FAILED_VERDICT in args.allow)  # a failed diagnosis: refused unless allowed
    print(f"report: model {source.description}", file=sys.stderr)
    model = read_model(args.model, machine, args.tracking_uri, source=source)
    if model.needs:   # the methods are compared on a field of the axes alone
        raise UsageError(f"{args.model}: the model's effect terms need the condition(s) {list(model.needs)}, which "
                         "the method comparison does not take; compare on its element set")
    field = model.field
    cmp = compare_methods(field, targets, machine, methods=methods, truth=truth, ga_points=args.ga_points,
                          ga_budget_s=args.ga_budget_s, seed=args.seed, nominal_axes=nominal)
    cmp.info.update({"machine": machine.name, "machine_file": machine.path, "model": args.model,
                     "model_source": dict(source.to_dict(), holds=model.holds()), "model_verdict": verdict, "truth": args.truth, **path_info})
    context = {"machine": f"{machine.name} ({machine.path})", "model (error field)": args.model,
               "truth": args.truth or "none (model residual only)", "path": path_info["path"],
               "points": path_info["points"], "seed": args.seed}
    if verdict and verdict.get("overridden_by"):
        context["model verdict"] = (f"FAILED ({verdict['file']}), used with --allow {FAILED_VERDICT}: "
                                    + ("; ".join(verdict["reasons"]) or "no reasons recorded"))
    if "work_offsets" in path_info:
        context["work offsets"] = f"{path_info['work_offsets']} (--work-offsets)"
    paths = write_report(cmp, Path(args.out), context=context)
    print_table(cmp)
    for k, path in paths.items():   # html, metrics, residuals (+ residuals_<method> of a method run on a subset)
        print(f"wrote {k}: {path}")
    return 0
