"""``volcomp diagnose``: trace the measured residual to the effects the model lacks, or model a drift log."""
from __future__ import annotations

import math
import sys

from errormap.machine import load_machine
from training import DEFAULT_MAX_ITER
from compensation.app.validate import EXIT_FAILED_VERDICT, UsageError

from ..options import add_units_option


def register(sub):
    p = sub.add_parser(
        "diagnose", help="measured residual -> effects the model lacks, before/after report; or a drift log",
        description="volcomp diagnose CHECKS --model (ELEMENTS|RUN_ID) --out DIR   or   volcomp diagnose --drift LOG --out DIR. "
                    "Writes DIR/diagnosis.json and DIR/report.html.")
    p.add_argument("checks", nargs="?", help="check-measurement CSV (x_mm, z_mm, a_deg, dx_um, dy_um, dz_um, ...)")
    p.add_argument("--drift", default=None, metavar="LOG", help="drift log CSV (time_s, temp_<sensor>_c, <channel>_um)")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name; default: the built-in grinder. "
                                                     "A machine-tool chain (mill-xyz, ...) runs the generic loop "
                                                     "(errormap/diagnosis/chain_loop.py)")
    p.add_argument("--noise-um", type=float, default=None,
                   help="the checks' stated noise σ per axis (μm; default: the file's '# noise_um: σ' line): a "
                        "noise estimated from the checks above 2σ fails the verdict; also the held-out noise floor "
                        "√3·σ (default: the σ the model update estimates)")
    p.add_argument("--model", default=None, help="element-set file (JSON) or MLflow run id of a learned field")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--tracking-uri", default=None)
    p.add_argument("--track", action="store_true",
                   help="closed loop: log a kept learned residual as an MLflow run (its CV table, chosen family, "
                        "JSON; store: --tracking-uri, else $MLFLOW_TRACKING_URI, else runs/mlflow.db)")
    p.add_argument("--featurepoints", default=None, help="feature points of a learned model (for the retrain)")
    p.add_argument("--fit-fraction", type=float, default=0.6, help="first part (by seq / time) used for fitting")
    p.add_argument("--deploy", action="store_true",
                   help="--drift: validate on the --fit-fraction split, then refit the chosen model on every row of "
                        "the log; drift_model.json and drift_compensation.csv are the refitted model, diagnosis.json "
                        "keeps the split's validation figures and records the refit (rows, candidates, settings)")
    p.add_argument("--time-unit", choices=["s", "min", "h"], default=None,
                   help="--drift: the unit of the log's time_s column when it is not seconds (default: seconds, "
                        "checked from the step and the span; a log that looks like minutes or hours is refused); "
                        "recorded in diagnosis.json and drift_model.json")
    p.add_argument("--alpha", type=float, default=0.01, help="family-wise significance level")
    p.add_argument("--max-effects", type=int, default=4)
    p.add_argument("--retrain-iter", type=int, default=DEFAULT_MAX_ITER,
                   help=f"LM iterations of the learned-field retrain (default {DEFAULT_MAX_ITER}; the same model "
                        "on any machine)")
    p.add_argument("--retrain-time-s", type=float, default=None,
                   help="also stop the retrain after this many seconds (off by default: it makes the model depend "
                        "on the machine's load; the retrain records the iterations reached)")
    p.add_argument("--seed", type=int, default=0, help="seed of the retrain")
    p.add_argument("--no-learned", action="store_true",
                   help="closed loop: skip the learned-residual stage (a Gaussian process on what the physical "
                        "model leaves at the checks, kept only if it beats the loop on the held-out checks)")
    p.add_argument("--no-update", action="store_true",
                   help="skip the model update even when the element set's covariance (NAME.cov.npz) is beside it")
    add_units_option(p, "check-measurement columns")
    p.set_defaults(func=run)


def band_label(c: dict) -> str:
    """The printed band, labelled with the coverage it was CHECKED to have on the held-out part (the band is
    the 95th percentile of validation residuals inside the fitting part; on a later part that leaves the
    fit range it may cover much less, and then it is not called a 95 % band)."""
    cov = c["band_coverage_heldout"]
    g = c.get("band_gamma", 1.0)
    grow = "max(1, ρ)" if g == 1.0 else f"max(1, ρ)^{g:g}"
    txt = (f"band ±{c['band95_um']:.3g} μm (× {grow} with the inputs' distance ρ from the fit data) covers "
           f"{cov:.0%} of the held-out part")
    if cov < BAND_CLAIM_COVERAGE:
        txt += " (NOT a 95 % band here: 95 % of the validation residuals only)"
    return txt


BAND_CLAIM_COVERAGE = 0.9   # below this held-out coverage the band is flagged as not holding its 95 %


def _retrain_settings(args):
    """The retrain's :class:`training.TrainSettings` from the options (their ranges are checked before
    run by compensation/app/validate.py)."""
    from training import TrainSettings
    return TrainSettings(max_iter=args.retrain_iter, seed=args.seed,
                         max_time_s=math.inf if args.retrain_time_s is None else args.retrain_time_s)


def _run_checks(args) -> int:
    """CHECKS against an element set on a machine tool (a chain file, or a grinder file through its chain):
    the closed loop (:func:`compensation.app.workflows.measurement.diagnose_chain`) and its page."""
    from compensation.app.families import family_of, say_read_as
    from compensation.fields import resolve_model
    if args.model is None:
        raise UsageError("CHECKS needs --model (the element set of `volcomp identify`, or a trained network)")
    machine = load_machine(args.machine)  # None: the built-in default machine
    fam = family_of(machine)
    fam.target("diagnose")   # an arm or a parallel machine: calibrate --check (the registry's gap)
    fam.refuse_unsupported("diagnose", args)
    src = resolve_model(args.model)
    # the model is there: the loop's libraries (scipy, numba, MLflow) load now, not for a refusal
    from compensation.app.workflows.measurement import diagnose_chain, diagnosis_lines
    from compensation.app.reports.chain_diagnosis import write_chain_diagnosis_page
    from compensation.model_file import read_model
    model = read_model(args.model, machine, args.tracking_uri, source=src)   # the one reader: what the model holds
    if model.network is not None and model.elements is None:   # a network: identified + effects, the retrain
        src = resolve_model(model.network) if model.network != src.spec else src
        if args.track:
            raise UsageError("--track: logs a kept learned residual; the loop on a trained network has no such stage "
                             "(its retrain is tracked as a child run with --tracking-uri): leave it out")
        print(f"diagnosing {args.checks} against {args.model} on {machine.name} ...", file=sys.stderr)
        from errormap.diagnosis.chain_loop import load_chain_checks
        from compensation.app.workflows.network_diagnosis import diagnose_network
        summary, paths = diagnose_network(load_chain_checks(args.checks, machine, units=args.units), machine, src, args.out,
                                          base=model.field,
                                          fit_fraction=args.fit_fraction, noise_um=args.noise_um,
                                          max_effects=args.max_effects, units=args.units,
                                          tracking_uri=args.tracking_uri, featurepoints=args.featurepoints,
                                          retrain=_retrain_settings(args))
    else:
        if not model.elements_only:
            raise UsageError(f"{args.model}: the closed loop starts from an element set (identify's, with its "
                             f"covariance) or a trained network; this model holds {', '.join(model.holds())}")
        retrain = [o for o, v, d in (("--featurepoints", args.featurepoints, None), ("--seed", args.seed, 0),
                                     ("--retrain-iter", args.retrain_iter, DEFAULT_MAX_ITER),
                                     ("--retrain-time-s", args.retrain_time_s, None)) if v != d]
        if retrain:
            raise UsageError(f"{', '.join(retrain)}: for the retrain of a trained network (--model a folder or run "
                             f"id); {args.model} is an element set: leave {'it' if len(retrain) == 1 else 'them'} out")
        print(f"diagnosing {args.checks} against {args.model} on {machine.name} ...", file=sys.stderr)
        summary, paths = diagnose_chain(args.checks, machine, model.elements_path, args.out, fit_fraction=args.fit_fraction,
                                        noise_um=args.noise_um, max_effects=args.max_effects,
                                        update=not args.no_update, units=args.units, learn=not args.no_learned,
                                        track=args.track, tracking_uri=args.tracking_uri)
        paths.append(write_chain_diagnosis_page(args.out, machine))  # the page of the run
    say_read_as(machine)   # a kind = "grinder" file read as its chain, said once the inputs are read (a refusal
    # above stays one line)
    if summary.get("update"):
        how = f"covariance {summary['covariance']}: closed loop (update, then effects)"
    else:
        from errormap.io import companion_path
        cov = companion_path(model.elements_path, ".cov.npz") if model.elements is not None else None
        why = ("--no-update" if cov is not None and cov.is_file() else
               f"no covariance {cov} beside it, written by `volcomp identify`" if cov is not None else "a trained network")
        how = f"no model update ({why}): effects on the model as it is"
    print(f"diagnose: model {src.description}; {how}", file=sys.stderr)
    for line in diagnosis_lines(summary):
        print(line)
    rid = (summary.get("learned_residual") or {}).get("mlflow_run_id")
    if rid:
        print(f"learned residual logged as MLflow run {rid}")
    rt = summary.get("learned_retrain")
    if rt:
        print(f"learned retrain: skipped: {rt['skipped']}" if "skipped" in rt else
              f"learned retrain: run {rt['run_id']}, held-out RMS {rt['rms_after_um']:.3g} um")
    for p in paths:
        print(f"wrote {p}")
    return EXIT_FAILED_VERDICT if summary["verdict"]["status"] == "failed" else 0


def run(args) -> int:
    if (args.checks is None) == (args.drift is None):
        raise UsageError("give either CHECKS (with --model) or --drift LOG")
    if args.drift is not None:
        given = [o for o, v in (("--machine", args.machine), ("--model", args.model), ("--noise-um", args.noise_um))
                 if v is not None]
        if given:   # never ignored silently: a drift log is channels over time, no machine or model is involved
            raise UsageError(f"{', '.join(given)}: not used by --drift (a drift log's channels need no machine "
                             "or model); leave it out")
        from compensation.app.workflows.drift import run_drift
        from errormap.diagnosis.drift_models import DriftSelector
        print(f"modelling drift log {args.drift} ...", file=sys.stderr)
        sel = DriftSelector(fit_fraction=args.fit_fraction, subset_kw={"alpha": args.alpha}, deploy=args.deploy)
        summary, paths = run_drift(args.drift, args.out, sel, time_unit=args.time_unit, units=args.units)
        print(f"time unit of time_s: {summary['time_unit']}")
        for c, why in summary["inputs_dropped"].items():
            print(f"dropped input {c}: {why}")
        for c, rows in summary["inputs_filled"].items():
            print(f"filled missing samples of {c} (interpolated): rows {', '.join(f'{a}-{b}' for a, b in rows)}")
        for ch, c in summary["channels"].items():
            print(f"{ch}: {c['model']}: held-out RMS {c['rms_before_um']:.3g} -> {c['rms_after_um']:.3g} μm "
                  f"(OLS baseline {c['rms_ols_um']:.3g} μm, constant offset {c['rms_constant_um']:.3g} μm), "
                  f"{band_label(c)}")
            if c.get("refused_by_constant"):
                print(f"{ch}: refused, not better than the constant offset in the paired test over the folds: "
                      f"{', '.join(c['refused_by_constant'])}")
        v = summary["verdict"]
        print("verdict: passed" if v["status"] == "passed" else "verdict: FAILED: " + "; ".join(v["reasons"]))
    else:
        return _run_checks(args)
    for p in paths:
        print(f"wrote {p}")
    failed = (summary.get("verdict") or {}).get("status") == "failed"
    return EXIT_FAILED_VERDICT if failed else 0
