"""``volcomp identify``: a machine tool's error elements from laser-tracker sweep files (one method for every
machine tool, :mod:`errormap.identification`; a ``kind = "grinder"`` file through its chain)."""
from __future__ import annotations

import sys

from errormap.estimators import Identification
from errormap.machine import load_machine
from errormap.sweeps import GAUGES, read_sweeps
from errormap.uncertainty import uncertainty_lines

from ..families import family_of, say_read_as
from ..validate import UsageError


def register(sub):
    d = Identification.defaults()   # the command's defaults are the estimator's (errormap.Identification)
    p = sub.add_parser("identify", help="identify the machine's error elements from laser-tracker sweeps",
                       description="Gauss-Newton on every ball of every sweep of one tracker set-up (any machine "
                                   "tool; a kind = \"grinder\" file through its chain), in a chosen gauge, the station "
                                   "values smoothed by the UBRE smoother. See docs/explanation/identification.md.")
    p.add_argument("sweeps", nargs="+", help="sweep file(s) (CSV) of one tracker set-up")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name; default: the built-in grinder")
    p.add_argument("--out", required=True, help="output element-set file (JSON)")
    p.add_argument("--report", default=None,
                   help="identification report (JSON: conditioning, residuals per station); default OUT.report.json")
    p.add_argument("--plot", default=None, metavar="PREFIX",
                   help="write one figure per swept axis W: PREFIX_<W>.png (the grinder: PREFIX_X.png, PREFIX_Z.png, "
                        "PREFIX_A.png)")
    p.add_argument("--truth", default=None, metavar="ELEMENTS", help="truth element set to overlay on the plots")
    p.add_argument("--gauge", choices=GAUGES, default=d["gauge"],
                   help=f"machine-frame gauge (default {d['gauge']}; station-mean: the frame at the root axis' mean "
                        "pose over its stations and a rotary axis' line at its mean over the turn, so that no one "
                        "station's tracker noise is left where smoothing cannot reach it; first-station: elements "
                        "zero at each axis' first station; reference-line: the frame on the fitted root-axis line, "
                        "the paper's). Tool points are the same in every gauge before smoothing; see "
                        "docs/explanation/identification.md")
    p.add_argument("--raw", action="store_true", default=not d["smooth"],
                   help="interpolating splines through the noisy stations (no smoothing); the covariance is still "
                        "written")
    p.add_argument("--noise-um", type=float, default=None,
                   help="known tracker noise σ per coordinate (μm) the covariance is scaled with; default: estimated "
                        "from the ball residuals")
    p.add_argument("--bootstrap", type=int, default=None,
                   help="N >= 2 residual-bootstrap draws for the covariance (default: Gauss-Newton's)")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    p.set_defaults(func=run)


def _bootstrap(args) -> dict:
    """``n_boot``/``seed`` of the residual bootstrap from --bootstrap/--seed (a seed without draws refused)."""
    if args.bootstrap is None:
        if args.seed != 0:
            raise UsageError("--seed seeds the bootstrap; give --bootstrap N with it")
        return {}
    if args.noise_um is not None:   # (N >= 2 draws: checked before run, validate.RULES)
        raise UsageError("--noise-um scales Gauss-Newton's covariance, --bootstrap estimates it from the "
                         "residuals: give one of them")
    return {"n_boot": args.bootstrap, "seed": args.seed}


def _model_file(machine, el_path, cov_path, args):
    """``NAME.model.json`` beside the element set: the model file naming it and its covariance (what every command
    reads as ``--model``; docs/reference/file-formats.md)."""
    from errormap.io import companion_path
    from ...model_file import save_model_file
    return save_model_file(companion_path(el_path, ".model.json"), machine, el_path, cov_path,
                           provenance={"written_by": "volcomp identify", "sweeps": [str(s) for s in args.sweeps]})


def run(args) -> int:
    machine = load_machine(args.machine)   # the built-in grinder unless --machine
    family_of(machine).target("identify")   # an arm or a parallel machine: calibrate (the registry's gap)
    if args.truth and not args.plot:   # never read and ignored
        raise UsageError("--truth is overlaid on the plots: give --plot PREFIX too")
    boot = _bootstrap(args)
    truth = None
    if args.truth:
        from errormap.chain_elements import ChainElementSet
        truth = ChainElementSet.load(args.truth, machine)
    sweeps = read_sweeps(args.sweeps, machine)
    # the inputs are read: the identification's scipy and the figures load now, not for a refusal
    from ..reports.identification import iso_summary_lines, plot_chain_elements
    from ..workflows.identification import identify_chain_files
    from ..workflows.measurement import truth_in_gauge
    say_read_as(machine)   # a kind = "grinder" file read as its chain, said once the inputs are read
    print(f"identifying {machine.name} from {', '.join(args.sweeps)} ...", file=sys.stderr)
    res, el_path, cov_path, report = identify_chain_files(machine, args.sweeps, args.out, report=args.report,
                                                          noise_um=args.noise_um, gauge=args.gauge,
                                                          smooth=not args.raw, sweeps=sweeps, **boot)
    elements = res.elements_
    lines = res.summary_lines() + uncertainty_lines(res) + iso_summary_lines(elements)
    for line in lines:
        print(line)
    print(f"wrote elements: {el_path}")
    print(f"wrote covariance: {cov_path}")
    print(f"wrote report: {report}")
    print(f"wrote model: {_model_file(machine, el_path, cov_path, args)}")
    if args.plot:
        if truth is not None:  # in the identified gauge and squareness split, so like is compared with like
            truth = truth_in_gauge(machine, truth, args.gauge, elements.stations)
        for p in plot_chain_elements(elements, args.plot, truth):
            print(f"wrote plot: {p}")
    return 0
