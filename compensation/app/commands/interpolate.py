"""``volcomp interpolate PATH --machine FILE [--calibration DIR] --out FILE [--report PAGE]``: PKM leg-command program.

PATH is ``sphere`` or ``hyperboloid`` (the stewart-interpolation paper's test parts) or a waypoint
CSV (see ``compensation.pkm_interpolation.read_waypoints``). Time-division interpolation with the
contour step ``f = feed * period``; with ``--calibration`` the identified parameters are used in
the inverse kinematics (compensated commands). ``--report PAGE`` also writes the program's HTML page
(:mod:`compensation.app.reports.interpolation`).
"""
from __future__ import annotations

import sys
from pathlib import Path

from errormap.io import InputError
from errormap.machine import builtin_machine_path, load_machine

from compensation.app.validate import UsageError

from ..families import family_of


def register(subparsers):
    p = subparsers.add_parser("interpolate", help="hexapod/tripod leg-command program for a tool path")
    p.add_argument("path", nargs="?",
                   help="'sphere', 'hyperboloid' or a waypoint CSV (px_mm py_mm pz_mm [nx ny nz] [move cx_mm ..])")
    p.add_argument("--machine", help="machine file (default: the built-in hexapod)")
    p.add_argument("--calibration", help="calibration folder or model.json (compensated commands)")
    p.add_argument("--out", help="output CSV (required with PATH)")
    p.add_argument("--report", metavar="PAGE", help="also write an HTML page of the program (legs against their "
                   "limits, steps, the calibration's corrections, figures)")
    p.add_argument("--sensitivity-plot", metavar="FILE",
                   help="tripod only: write the error-sensitivity plot (K vs lambda, K over the workspace) as PNG")
    p.add_argument("--feed-mm-min", type=float, default=1000.0, help="feed (mm/min), default 1000")
    p.add_argument("--period-ms", type=float, default=4.0, help="interpolation period (ms), default 4")
    p.add_argument("--allow-out-of-range", action="store_true", help="write even if a leg leaves its range")
    p.set_defaults(func=run)


DEFAULT_MACHINE = "hexapod"
"""The built-in machine interpolated without ``--machine``."""


def _calibrated(given, machine):
    """The identified machine of the calibration ``given`` (a model file, or the folder ``calibrate`` wrote it in)."""
    from compensation.model_file import read_model
    return read_model(given, machine, family="parallel").calibration


def run(args) -> int:
    # the kinematics (scipy) and the figures load to run the command, not to build its parser
    from compensation.pkm_interpolation import builtin_path, contour_step_mm, leg_program, read_waypoints
    from errormap.pkm.hexapod import KinematicsError
    from ..reports.tripod_sensitivity import plot_tripod_sensitivity
    machine = load_machine(args.machine or builtin_machine_path(DEFAULT_MACHINE))
    family = family_of(machine)
    family.target("interpolate")   # a parallel machine's leg commands: refused on other families, naming their path
    family.refuse_unsupported("interpolate", args)
    if args.path is None and args.sensitivity_plot is None:
        raise UsageError("interpolate: give a PATH (with --out) or --sensitivity-plot FILE")
    if args.path is not None and args.out is None:
        raise UsageError("interpolate: --out is required with a PATH")
    if args.report is not None and args.path is None:
        raise UsageError("interpolate: --report needs a PATH")
    if args.sensitivity_plot is not None:
        st = plot_tripod_sensitivity(machine, Path(args.sensitivity_plot))
        print(f"interpolate: wrote {st['path']} (K {st['K_lambda'].min():.3g}..{st['K_lambda'].max():.3g} over "
              f"lambda {st['lambdas'][0]:.3g}..{st['lambdas'][-1]:.3g})")
        if args.path is None:
            return 0
    try:
        step = contour_step_mm(args.feed_mm_min, args.period_ms)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.path in ("sphere", "hyperboloid"):
        path = builtin_path(args.path, step)
    else:
        path = read_waypoints(args.path, step)
    calibrated = _calibrated(args.calibration, machine) if args.calibration else None
    print(f"interpolate: {len(path)} steps of f = {step:.4g} mm ({args.feed_mm_min:g} mm/min x {args.period_ms:g} ms)"
          f"{', compensated' if calibrated is not None else ''}", file=sys.stderr)
    try:
        prog = leg_program(machine, path, calibrated, check_limits=not args.allow_out_of_range)
    except KinematicsError as exc:
        raise InputError(f"{args.path}: {exc} (use --allow-out-of-range to write anyway)") from None
    out = prog.write_csv(Path(args.out))
    print(f"interpolate: wrote {out} ({len(path)} steps)")
    if args.report is not None:
        from ..reports.interpolation import write_interpolation_report
        nominal = (leg_program(machine, path, None, check_limits=False).legs_mm if calibrated is not None else None)
        setting = {"machine": f"{machine.name} ({machine.kind})", "path": args.path, "steps": len(path),
                   "contour step f": f"{step:.4g} mm", "feed": f"{args.feed_mm_min:g} mm/min",
                   "interpolation period": f"{args.period_ms:g} ms",
                   "calibration": args.calibration or "none (nominal kinematics)",
                   "leg limits checked": not args.allow_out_of_range, "program": str(out)}
        page = write_interpolation_report(Path(args.report), prog, machine, setting, nominal,
                                          sensitivity_png=args.sensitivity_plot)
        print(f"interpolate: wrote {page}")
    return 0
