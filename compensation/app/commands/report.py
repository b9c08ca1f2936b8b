"""``volcomp report``: compare the compensation methods on a tool path; HTML report + metrics.json.

Runs ``traditional``, ``ga``, ``batched-ga`` and ``exact`` (or ``--methods``) with one error
field on one path (``--path FILE`` or the built-in ``--flute``), computes the MODEL residual
of each and — with ``--truth`` (a ``volcomp simulate`` folder or an element-set file) — the
TRUE residual on the simulated machine, and writes ``DIR/report.html``, ``DIR/metrics.json``
and ``DIR/residuals.csv`` (see :mod:`compensation.app.reports.methods`).
"""
from __future__ import annotations

from pathlib import Path

from errormap.machine import load_machine

from ..cli import UsageError
from ...evaluate import load_truth
from ...fields import load_field
from ...pathio import read_path
from ..reports.methods import DEFAULT_GA_BUDGET_S, compare_methods, print_table, write_report
from ...solvers import METHODS
from ...toolpath import FLUTE_DEFAULTS, LEAD_LAWS, check_in_strokes, flute_path


def add_flute_arguments(p) -> None:
    """The flute settings as options (defaults: :data:`compensation.toolpath.FLUTE_DEFAULTS`)."""
    d = FLUTE_DEFAULTS
    g = p.add_argument_group("flute path (with --flute)")
    g.add_argument("--turns", type=float, default=d.turns, help=f"flute turns (default {d.turns:g})")
    g.add_argument("--points-per-turn", type=int, default=d.points_per_turn,
                   help=f"interpolation points per turn (default {d.points_per_turn})")
    g.add_argument("--radius-mm", type=float, default=d.radius_mm,
                   help=f"flute-bottom radius, mm (default {d.radius_mm:g})")
    g.add_argument("--helix-start-deg", type=float, default=d.helix_start_deg,
                   help=f"helix angle at the flute start (default {d.helix_start_deg:g})")
    g.add_argument("--helix-end-deg", type=float, default=d.helix_end_deg,
                   help=f"helix angle at the flute end (default {d.helix_end_deg:g})")
    g.add_argument("--lead-law", choices=LEAD_LAWS, default=d.lead_law, help=f"what varies linearly (default {d.lead_law})")
    g.add_argument("--px-start-mm", type=float, default=d.px_start_mm,
                   help=f"axial WCS position of the flute start (default {d.px_start_mm:g})")


def flute_from_args(args):
    return flute_path(turns=args.turns, points_per_turn=args.points_per_turn, radius_mm=args.radius_mm,
                      helix_start_deg=args.helix_start_deg, helix_end_deg=args.helix_end_deg,
                      lead_law=args.lead_law, px_start_mm=args.px_start_mm)


def parse_methods(text: str) -> tuple:
    methods = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise UsageError(f"--methods: expected a comma-separated list from {list(METHODS)}, got {text!r}")
    return methods


def add_method_arguments(p) -> None:
    p.add_argument("--methods", default=",".join(METHODS),
                   help=f"comma-separated methods (default {','.join(METHODS)})")
    p.add_argument("--ga-points", type=int, default=None,
                   help="run the per-point GA on this many evenly spaced points (default: as many as "
                        "fit in --ga-budget-s)")
    p.add_argument("--ga-budget-s", type=float, default=DEFAULT_GA_BUDGET_S,
                   help=f"time budget of the per-point GA when --ga-points is not given (default {DEFAULT_GA_BUDGET_S:g} s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the stochastic solvers")


def register(sub):
    p = sub.add_parser(
        "report", help="compare compensation methods on a path: report.html + metrics.json",
        description="Run the compensation methods on a tool path and write DIR/report.html (self-contained), "
                    "DIR/metrics.json and DIR/residuals.csv. Shows the MODEL residual, and the TRUE residual "
                    "when --truth is given.")
    p.add_argument("--model", required=True, help="MLflow run id, runs:/ URI, or element-set file (JSON)")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--path", help="tool-path file (CSV or G-code)")
    src.add_argument("--flute", action="store_true", help="the built-in variable-helix flute path")
    p.add_argument("--truth", default=None,
                   help="simulate folder (truth_elements.json + truth.json) or element-set file: adds the TRUE residual")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.add_argument("--out", required=True, metavar="DIR")
    add_method_arguments(p)
    add_flute_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    if args.ga_points is not None and args.ga_points < 1:
        raise UsageError("--ga-points must be >= 1")
    methods = parse_methods(args.methods)
    machine = load_machine(args.machine, expect_kind="grinder")
    if args.flute:
        try:
            fl = flute_from_args(args)
        except ValueError as exc:
            raise UsageError(f"flute settings: {exc}") from None
        targets, nominal = fl.targets_mm, fl.axes(machine)
        try:
            check_in_strokes(machine, nominal, "the flute path")
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        path_info = {"path": "flute", "flute": fl.settings.to_dict(), "points": len(fl)}
    else:
        tp = read_path(args.path, machine)
        targets, nominal = tp.targets_mm, tp.axes
        path_info = {"path": str(args.path), "format": tp.kind, "points": len(tp)}
    truth = load_truth(args.truth, machine) if args.truth else None
    field = load_field(args.model, machine, args.tracking_uri)
    cmp = compare_methods(field, targets, machine, methods=methods, truth=truth, ga_points=args.ga_points,
                          ga_budget_s=args.ga_budget_s, seed=args.seed, nominal_axes=nominal)
    cmp.info.update({"machine": machine.name, "machine_file": machine.path, "model": args.model,
                     "truth": args.truth, **path_info})
    context = {"machine": f"{machine.name} ({machine.path})", "model (error field)": args.model,
               "truth": args.truth or "none (model residual only)", "path": path_info["path"],
               "points": path_info["points"], "seed": args.seed}
    paths = write_report(cmp, Path(args.out), context=context)
    print_table(cmp)
    for k in ("html", "metrics", "residuals"):
        print(f"wrote {k}: {paths[k]}")
    return 0
