"""``volcomp drift-predict``: apply a saved drift model (``volcomp.drift_model``) to a new log, causally."""
from __future__ import annotations

import sys


def register(sub):
    p = sub.add_parser(
        "drift-predict", help="apply a saved drift model to a new log (causal compensation series)",
        description="volcomp drift-predict MODEL LOG --out FILE.csv. MODEL is the drift_model.json written by "
                    "`volcomp diagnose --drift`; LOG a drift log with the model's inputs (displacement columns "
                    "optional: when present, RMS before/after is printed). The prediction at each time uses "
                    "samples at or before it only; missing input samples are held at their last value.")
    p.add_argument("model", help="drift_model.json (schema volcomp.drift_model)")
    p.add_argument("log", help="drift log CSV (time_s, temp_<sensor>_c, speed_rpm, ...)")
    p.add_argument("--out", required=True, help="compensation series CSV to write")
    p.add_argument("--time-unit", choices=["s", "min", "h"], default=None,
                   help="the unit of the log's time_s column when it is not seconds (default: seconds, checked "
                        "from the step; recorded in the output's header)")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from compensation.app.workflows.diagnosis import COMPENSATION_COMMENTS, compensation_columns
    from errormap.diagnosis.drift import load_drift_log
    from errormap.diagnosis.drift_models import DriftModel
    from errormap.io import InputError, write_csv

    model = DriftModel.load(args.model)
    log = load_drift_log(args.log, causal=True, require_displacement=False, time_unit=args.time_unit)
    span = float(log.time_s[-1] - log.time_s[0])
    if span < model.max_delay_s:
        raise InputError(f"{args.log}: row {log.notes['last_row']}, column 'time_s': the log spans {span:g} s, shorter "
                         f"than the model's longest lag {model.max_delay_s:g} s ({len(log.time_s)} rows)")
    for c, why in log.notes["dropped"].items():
        print(f"dropped input {c}: {why}", file=sys.stderr)
    for c, rows in log.notes["filled"].items():
        print(f"held last value over missing samples of {c}: rows {', '.join(f'{a}-{b}' for a, b in rows)}",
              file=sys.stderr)
    cols = compensation_columns(log, model)       # raises naming any input the model needs and the log lacks
    for ch in model.channels:
        if ch in log.disp_um:
            d = log.disp_um[ch]
            a = d - cols[f"{ch}_pred_um"]
            print(f"{ch}: RMS {np.sqrt(np.mean(d**2)):.3g} -> {np.sqrt(np.mean(a**2)):.3g} μm over the log")
    write_csv(args.out, cols, header_comments=(f"model: {args.model}", f"log: {args.log}",
                                                f"log time unit: {log.notes['time_unit']}", *COMPENSATION_COMMENTS))
    print(f"wrote {args.out}")
    return 0
