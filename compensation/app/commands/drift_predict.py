"""``volcomp drift-predict``: apply a saved drift model (``volcomp.drift_model``) to a new log, causally;
with ``--update``, re-fit its parameters as on-machine measurements arrive."""
from __future__ import annotations

import sys

from compensation.app.validate import UsageError, allowed_verdict


def register(sub):
    p = sub.add_parser(
        "drift-predict", help="apply a saved drift model to a new log (causal compensation series)",
        description="volcomp drift-predict MODEL LOG --out FILE.csv [--update]. MODEL is the drift_model.json written "
                    "by `volcomp diagnose --drift`; LOG a drift log with the model's inputs (displacement columns "
                    "optional: when present, RMS before/after is printed). The prediction at each time uses "
                    "samples at or before it only; missing input samples are held at their last value. With "
                    "--update, the log's displacement cells are on-machine measurements (empty where none was "
                    "taken) and each channel's intercept and gains are re-fitted by a Kalman filter on the "
                    "parameters as they arrive (the prediction at a row uses measurements strictly before it).")
    p.add_argument("model", help="drift_model.json (schema volcomp.drift_model)")
    p.add_argument("log", help="drift log CSV (time_s, temp_<sensor>_c, speed_rpm, ...)")
    p.add_argument("--out", required=True, help="compensation series CSV to write")
    p.add_argument("--time-unit", choices=["s", "min", "h"], default=None,
                   help="the unit of the log's time_s column when it is not seconds (default: seconds, checked "
                        "from the step; recorded in the output's header)")
    from ..options import add_units_option
    add_units_option(p, "temperature columns")
    p.add_argument("--update", action="store_true",
                   help="re-fit the model's parameters online from the log's displacement measurements")
    p.add_argument("--save-model", default=None, metavar="FILE.json",
                   help="--update: write the updated drift model (same schema; export it with --format drift)")
    p.add_argument("--drift-per-h", type=float, default=None,
                   help="--update: how fast the parameters may wander: fraction of the prior variance per hour "
                        "(default 0.01)")
    p.add_argument("--noise-um", type=float, default=None,
                   help="--update: σ of one measurement in μm (default: half the model's band)")
    from ...fields import FAILED_VERDICT
    p.add_argument("--allow", action="append", default=[], choices=(FAILED_VERDICT,),
                   help=f"{FAILED_VERDICT}: apply a model whose diagnosis verdict failed (refused by default); "
                        "recorded in the output's header (and in --save-model's file)")
    p.set_defaults(func=run)


def _check_args(args):
    if not args.update:
        given = [k for k, v in {"--save-model": args.save_model, "--drift-per-h": args.drift_per_h,
                                "--noise-um": args.noise_um}.items() if v is not None]
        if given:
            raise UsageError(f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} with --update only")


def save_updated(model, path, verdict):
    """Write the updated drift model; one updated from a model whose verdict failed keeps that verdict (key
    ``verdict``: it is refused downstream as its source was, unless ``--allow failed-verdict``)."""
    from errormap.io import write_json
    doc = model.to_json()
    if verdict and verdict["status"] == "failed":
        doc["verdict"] = {"status": "failed", "reasons": [*verdict["reasons"], f"updated online from {verdict['model']}, "
                                                                             "whose verdict failed"]}
    return write_json(path, doc)


def run(args) -> int:
    import numpy as np

    from compensation.app.workflows.drift import COMPENSATION_COMMENTS, band_columns, compensation_columns
    from errormap.diagnosis.drift import load_drift_log
    from errormap.diagnosis.drift_models import input_novelty
    from errormap.diagnosis.drift_models import DriftModel
    from errormap.diagnosis.drift_update import DRIFT_PER_H, DriftUpdater
    from errormap.io import InputError, write_csv

    from ...fields import FAILED_VERDICT, check_verdict
    _check_args(args)
    verdict = check_verdict(args.model, FAILED_VERDICT in args.allow)   # a failed diagnosis: refused unless allowed
    model = DriftModel.load(args.model)
    log = load_drift_log(args.log, causal=True, require_displacement=False, time_unit=args.time_unit,
                         sparse_displacement=args.update, units=args.units)
    span = float(log.time_s[-1] - log.time_s[0])
    if span < model.max_delay_s:
        raise InputError(f"{args.log}: row {log.notes['last_row']}, column 'time_s': the log spans {span:g} s, shorter "
                         f"than the model's longest lag {model.max_delay_s:g} s ({len(log.time_s)} rows)")
    for c, why in log.notes["dropped"].items():
        print(f"dropped input {c}: {why}", file=sys.stderr)
    for c, rows in log.notes["filled"].items():
        print(f"held last value over missing samples of {c}: rows {', '.join(f'{a}-{b}' for a, b in rows)}",
              file=sys.stderr)
    head = [f"model: {args.model}", f"log: {args.log}", f"log time unit: {log.notes['time_unit']}",
            f"log temperature units: {log.notes['units']}"]
    if allowed_verdict(verdict):
        head.append(f"allowed: {allowed_verdict(verdict)}")
    cols = compensation_columns(log, model)       # raises naming any input the model needs and the log lacks
    d = input_novelty(model, log)
    if d is not None:
        cols["input_distance"] = d
        lim = model.meta["novelty"].get("validated_distance")
        if lim:
            out = float(np.mean(d > lim))
            print(f"inputs beyond the validated range (Mahalanobis distance > {lim:.3g} from the fitting data): "
                  f"{out:.0%} of the rows (max distance {d.max():.3g})"
                  + ("; the model extrapolates there: check it with on-machine measurements (--update)"
                     if out > 0.05 else ""))
        head.append("input_distance: Mahalanobis distance of the row's inputs from the model's fitting data")
        rho = model.rho(log)
        shr = [ch for ch, c in model.channels.items() if c.base is not None and np.isfinite(c.shrink_scale)]
        if rho is not None:
            print(f"inputs beyond the fitting data's range (rho > 1): {np.mean(rho > 1):.0%} of the rows; there the band "
                  "grows as max(1, rho)" + (f" and {', '.join(shr)} shrink toward their OLS baseline"
                                             + (" (in the --update predictions rho is measured from the fitting "
                                                "data and the measured rows before each row)" if args.update else "")
                                             if shr else ""))
            head.append("<ch>_lo_um / <ch>_hi_um grow as max(1, rho), rho = input_distance / the fitting data's range "
                        "distance" + (f"; {', '.join(shr)}: prediction shrunk toward OLS beyond rho = 1" if shr else ""))
    if args.update:
        missing = [ch for ch in model.channels if ch not in log.disp_um]
        if len(missing) == len(model.channels):
            raise InputError(f"{args.log}: column '{missing[0]}_um': --update needs on-machine measurements of the "
                             f"model's channels ({', '.join(c + '_um' for c in model.channels)}); the log has none")
        upd = DriftUpdater(noise_um=args.noise_um,
                           drift_per_h=DRIFT_PER_H if args.drift_per_h is None else args.drift_per_h)
        res = upd.run(model, log, log.disp_um)
        for ch in model.channels:   # the saved model's prediction beside the updated one and its band
            cols[f"{ch}_fixed_pred_um"] = res.fixed_um[ch]
            cols.update(band_columns({ch: res.pred_um[ch]}, res.band_um))
        print("online update (Kalman filter on the parameters): a-priori error at the measurements, "
              "RMS μm, updated vs the saved model")
        for ch, rows in res.evolution().items():
            if not rows:
                print(f"{ch}: no measurement: the saved model is kept")
                continue
            for a, b, ru, rf, m in rows:
                print(f"{ch}: rows {a + 2}-{b + 2} ({m} measurements): updated {ru:.3g}  saved model {rf:.3g}")
        head += [f"online update: Kalman filter on the parameters, drift_per_h {upd.drift_per_h:g}, "
                 f"noise_um {args.noise_um if args.noise_um else 'half the band'}; <ch>_pred_um uses measurements "
                 "strictly before each row; <ch>_fixed_pred_um is the saved model"]
        if args.save_model:
            print(f"wrote {save_updated(res.model, args.save_model, verdict)}")
    else:
        for ch in model.channels:
            if ch in log.disp_um:
                d = log.disp_um[ch]
                a = d - cols[f"{ch}_pred_um"]
                print(f"{ch}: RMS {np.sqrt(np.mean(d**2)):.3g} -> {np.sqrt(np.mean(a**2)):.3g} μm over the log")
    write_csv(args.out, cols, header_comments=(*head, *COMPENSATION_COMMENTS))
    print(f"wrote {args.out}")
    return 0
