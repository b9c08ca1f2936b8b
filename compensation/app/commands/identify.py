"""``volcomp identify``: the 23 error elements from laser-tracker sweep files (grinder paper §2.1)."""
from __future__ import annotations

import sys

from errormap.elements import ElementSet
from errormap.identification import GAUGES
from errormap.machine import check_machine_kind, load_machine
from errormap.sweeps import read_sweeps
from compensation.app.validate import UsageError


from ..reports.identification import iso_summary_lines, plot_elements
from ..validate import UsageError
from ..workflows.identification import identify_elements, truth_in_gauge


def register(sub):
    p = sub.add_parser("identify", help="identify the machine's error elements from laser-tracker sweeps",
                       description="The grinder paper's method (section 2.1): reference lines/circles, the 9x6 "
                                   "least-squares system per station, squareness from the X and Z lines, the A-axis "
                                   "line from the rotary body's initial state, B-spline elements. See "
                                   "docs/identification.md.")
    p.add_argument("sweeps", nargs="+", help="sweep file(s) (CSV) of one tracker set-up")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name; default: the built-in grinder. "
                                                     "A machine-tool chain (mill-xyz, five-axis-ac, ...) is identified "
                                                     "by Gauss-Newton on all balls (errormap/mt_identify.py)")
    p.add_argument("--out", required=True, help="output element-set file (JSON)")
    p.add_argument("--report", default=None,
                   help="identification report (JSON: conditioning, residuals per station); default OUT.report.json")
    p.add_argument("--plot", default=None, metavar="PREFIX",
                   help="write one figure per axis: PREFIX_X.png, PREFIX_Z.png, PREFIX_A.png (a chain: PREFIX_<W>.png "
                        "per swept axis)")
    p.add_argument("--truth", default=None, metavar="ELEMENTS", help="truth element set to overlay on the plots")
    p.add_argument("--gauge", choices=GAUGES, default="station-mean",
                   help="machine-frame gauge (default station-mean: the frame at the X carriage's mean pose over "
                        "its stations and the A line at its mean over the turn, so that no one station's tracker "
                        "noise is left where smoothing cannot reach it; first-station: elements zero at each axis' "
                        "first station; reference-line: the paper's frame). Tool points are the same in every "
                        "gauge before smoothing; see docs/identification.md")
    p.add_argument("--raw", action="store_true",
                   help="interpolating splines through the noisy stations (the paper's method, no smoothing); "
                        "the covariance is still written. A machine-tool chain's element set is always this form")
    p.add_argument("--noise-um", type=float, default=None,
                   help="known tracker noise σ per coordinate (μm) the covariance is scaled with (every machine tool); "
                        "default: estimated from the ball residuals")
    p.add_argument("--bootstrap", type=int, default=None,
                   help="bootstrap draws for the covariance (default 100; a machine-tool chain: none, its covariance "
                        "is Gauss-Newton's unless N >= 2 residual-bootstrap draws are asked for)")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    p.set_defaults(func=run)


GRINDER_BOOT_DRAWS = 100
"""The grinder's bootstrap draws when --bootstrap is not given (its smoothing needs the covariance)."""


def _chain_bootstrap(args) -> dict:
    """``n_boot``/``seed`` of a chain's residual bootstrap from --bootstrap/--seed (a seed without draws refused)."""
    if args.bootstrap is None:
        if args.seed != 0:
            raise UsageError("--seed seeds the bootstrap of a machine-tool chain; give --bootstrap N with it")
        return {}
    return {"n_boot": args.bootstrap, "seed": args.seed}


def run(args) -> int:
    machine = load_machine(args.machine, expect_kind=None if args.machine else "grinder")
    if args.truth and not args.plot:   # never read and ignored
        raise UsageError("--truth is overlaid on the plots: give --plot PREFIX too")
    if machine.kind == "machine-tool":
        from ..workflows.mt_loop import identify_chain_files, refuse_options
        # --raw is the chain's one form (interpolating splines through the stations): accepted, nothing to change
        refuse_options(args, {"gauge": "station-mean"},
                       "identify on a machine-tool chain (Gauss-Newton, first-station gauge)")
        boot = _chain_bootstrap(args)
        if boot and args.noise_um is not None:
            raise UsageError("--noise-um scales Gauss-Newton's covariance, --bootstrap estimates it from the "
                             "residuals: give one of them on a machine-tool chain")
        print(f"identifying {machine.name} from {', '.join(args.sweeps)} ...", file=sys.stderr)
        res, el_path, cov_path, report = identify_chain_files(machine, args.sweeps, args.out, report=args.report,
                                                              noise_um=args.noise_um, **boot)
        for line in res.summary_lines():
            print(line)
        print(f"wrote elements: {el_path}")
        print(f"wrote covariance: {cov_path}")
        print(f"wrote report: {report}")
        if args.plot:
            from ..reports.identification import plot_chain_elements
            from ..workflows.mt_loop import chain_truth_in_gauge
            truth = chain_truth_in_gauge(machine, args.truth) if args.truth else None
            for p in plot_chain_elements(res.elements_, args.plot, truth):
                print(f"wrote plot: {p}")
        return 0
    check_machine_kind(machine.path, machine.kind, "grinder")
    truth = ElementSet.load(args.truth) if args.truth else None
    sweeps = read_sweeps(args.sweeps)
    print(f"identifying from {', '.join(args.sweeps)} ...", file=sys.stderr)
    ident = identify_elements(machine, args.sweeps, args.out, report=args.report, noise_um=args.noise_um,
                              n_boot=GRINDER_BOOT_DRAWS if args.bootstrap is None else args.bootstrap, seed=args.seed, smooth=not args.raw, gauge=args.gauge,
                              sweeps=sweeps)
    elements = ident.result.elements_
    for line in ident.summary_lines():
        print(line)
    for line in iso_summary_lines(elements):
        print(line)
    print(f"wrote elements: {ident.elements_path}")
    print(f"wrote covariance: {ident.covariance_path}")
    print(f"wrote report: {ident.report_path}")
    if args.plot:
        if truth is not None:  # in the identified gauge and squareness split, so like is compared with like
            truth = truth_in_gauge(truth, elements, machine, args.gauge)
        for p in plot_elements(elements, args.plot, truth):
            print(f"wrote plot: {p}")
    return 0
