"""``volcomp diagnose``: trace the measured residual to the effects the model lacks, or model a drift log."""
from __future__ import annotations

import math
import sys

from errormap.diagnosis.pipeline import DiagnosisSettings
from errormap.machine import check_machine_kind, load_machine
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


def _retrain_settings(args):
    """The retrain's :class:`training.TrainSettings` from the options (their ranges are checked before
    run by compensation/app/validate.py)."""
    from training import TrainSettings
    return TrainSettings(max_iter=args.retrain_iter, seed=args.seed,
                         max_time_s=math.inf if args.retrain_time_s is None else args.retrain_time_s)


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


def run(args) -> int:
    from compensation.app.workflows.diagnosis import run_checks, run_drift
    from errormap.diagnosis.drift_models import DriftSelector
    if (args.checks is None) == (args.drift is None):
        raise UsageError("give either CHECKS (with --model) or --drift LOG")
    if args.drift is not None:
        given = [o for o, v in (("--machine", args.machine), ("--model", args.model), ("--noise-um", args.noise_um))
                 if v is not None]
        if given:   # never ignored silently: a drift log is channels over time, no machine or model is involved
            raise UsageError(f"{', '.join(given)}: not used by --drift (a drift log's channels need no machine "
                             "or model); leave it out")
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
        v = summary["verdict"]
        print("verdict: passed" if v["status"] == "passed" else "verdict: FAILED: " + "; ".join(v["reasons"]))
    else:
        if args.model is None:
            raise UsageError("CHECKS needs --model (element-set file or run id)")
        machine = load_machine(args.machine)  # None: the built-in default machine
        if machine.kind == "machine-tool":
            from compensation.app.workflows.measurement import diagnose_chain, diagnosis_lines, refuse_options
            refuse_options(args, {"featurepoints": None, "tracking_uri": None, "alpha": 0.01, "track": False,
                                  "retrain_iter": DEFAULT_MAX_ITER, "retrain_time_s": None, "seed": 0},
                           "diagnose on a machine-tool chain (element-set models; effects gated on held-out z)")
            print(f"diagnosing {args.checks} against {args.model} on {machine.name} ...", file=sys.stderr)
            summary, paths = diagnose_chain(args.checks, machine, args.model, args.out, fit_fraction=args.fit_fraction,
                                            noise_um=args.noise_um, max_effects=args.max_effects,
                                            update=not args.no_update, units=args.units,
                                            learn=not args.no_learned)
            from compensation.app.reports.chain_diagnosis import write_chain_diagnosis_page
            paths.append(write_chain_diagnosis_page(args.out, machine))  # the page of the run, as the grinder's
            for line in diagnosis_lines(summary):
                print(line)
            for p in paths:
                print(f"wrote {p}")
            return EXIT_FAILED_VERDICT if summary["verdict"]["status"] == "failed" else 0
        check_machine_kind(machine.path, machine.kind, "grinder")
        settings = DiagnosisSettings(fit_fraction=args.fit_fraction, alpha=args.alpha, max_effects=args.max_effects,
                                     noise_um=args.noise_um)
        retrain = _retrain_settings(args)
        print(f"diagnosing {args.checks} against {args.model} ...", file=sys.stderr)
        summary, paths = run_checks(args.checks, machine, args.model, args.out, settings, args.tracking_uri,
                                    args.featurepoints, retrain, update=not args.no_update, units=args.units,
                                    units_option="--units", learn=not args.no_learned, track=args.track,
                                    noise_um=args.noise_um)
        if "stages" in summary:
            st = summary["stages"]
            print("held-out RMS: identified {:.3g} -> updated {:.3g} -> updated + effects {:.3g} um".format(
                st["identified"]["held_out"]["rms_um"], st["updated"]["held_out"]["rms_um"],
                st["updated_plus_effects"]["held_out"]["rms_um"]))
            for c in summary["update"]["contradicted_by_sweeps"]:
                print(f"update of {c['element']} contradicted by the sweeps (p = {c['p_adjusted']:.2g}): "
                      "evidence of an effect the model lacks")
            for c in summary["update"]["not_updated"]:
                print(f"not updated by the checks: {c['element']}: {c['why']}")
            for e in summary.get("effects_rejected", []):
                print(f"rejected: {e['kind']} axis {e['axis']} ({summary.get('effects_rejected_why', '')})")
        rid = (summary.get("learned_residual") or {}).get("mlflow_run_id")
        if rid:
            print(f"learned residual logged as MLflow run {rid}")
        for i, e in enumerate(summary["effects"], 1):
            print(f"{i}. {e['kind']} axis {e['axis']} on {e['element']}: held-out RMS -{e['rms_reduction_um']:.3g} μm")
        if not summary["effects"]:
            print("no effect found")
        print(f"held-out RMS {summary['rms_before_um']:.3g} -> {summary['rms_after_um']:.3g} μm, "
              f"max {summary['max_before_um']:.3g} -> {summary['max_after_um']:.3g} μm")
        v = summary.get("verdict")
        if v is not None:   # the closed loop's verdict (errormap.diagnosis.plausibility.diagnosis_verdict)
            print("verdict: passed" if v["status"] == "passed" else "verdict: FAILED: " + "; ".join(v["reasons"]))
    for p in paths:
        print(f"wrote {p}")
    failed = (summary.get("verdict") or {}).get("status") == "failed"
    return EXIT_FAILED_VERDICT if failed else 0
