"""Command-line options shared by several commands or turned into a library call's arguments:
the flute path and the method comparison (``report``, ``demo``), the constant conditions of a
diagnosed model (``compensate``), where the work runs (``compensate``, ``fleet``)."""
from __future__ import annotations

from compensation.app.validate import UsageError

from ..conditions import CONDITIONS
from ..solvers import METHODS
from ..toolpath import FLUTE_DEFAULTS, LEAD_LAWS, flute_path
from .workflows.cluster import CLUSTERS, ClusterSettings
from .workflows.compare import DEFAULT_GA_BUDGET_S


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


def add_method_arguments(p, ga_budget_s: float = DEFAULT_GA_BUDGET_S) -> None:
    """``--methods``, ``--ga-points``, ``--ga-budget-s`` (default ``ga_budget_s``: the help states the
    value the command uses), ``--seed``."""
    p.add_argument("--methods", default=",".join(METHODS),
                   help=f"comma-separated methods (default {','.join(METHODS)})")
    p.add_argument("--ga-points", type=int, default=None,
                   help="run the per-point GA on this many evenly spaced points (default: as many as "
                        "fit in --ga-budget-s)")
    p.add_argument("--ga-budget-s", type=float, default=ga_budget_s,
                   help=f"time budget of the per-point GA when --ga-points is not given (default {ga_budget_s:g} s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the stochastic solvers")


def add_condition_options(p) -> None:
    """The constant-condition options of ``volcomp compensate`` (for a diagnosed model)."""
    p.add_argument("--temp-c", type=float, default=None, help="temperature for a diagnosed model's thermal term (°C), "
                   "for the whole path; a CSV path's column temp_c takes precedence")
    p.add_argument("--time-s", type=float, default=None, help="time for a diagnosed model's drift term (s), for the "
                   "whole path; a CSV path's column time_s takes precedence")
    for ax in ("x", "z", "a"):
        p.add_argument(f"--dir-{ax}", type=int, choices=(-1, 1), default=None,
                       help=f"approach direction of {ax.upper()} for a diagnosed model's reversal term, for the whole "
                            f"path; a CSV path's column dir_{ax} takes precedence")


def conditions_from_args(args) -> dict:
    """``{condition: value or None}`` for :data:`compensation.conditions.CONDITIONS`."""
    return {c: getattr(args, c, None) for c in CONDITIONS}


def add_units_option(p, what: str = "columns") -> None:
    """``--units check|as-written`` (errormap/units.py): the one override of the shared unit check."""
    from errormap.units import UNITS_CHECK, UNITS_CHOICES
    p.add_argument("--units", choices=UNITS_CHOICES, default=UNITS_CHECK,
                   help=f"check (default): refuse {what} whose numbers fit another unit better (metres for mm, "
                        "radians for degrees, °F or kelvin for °C); as-written: they are in the units they name "
                        "(recorded in the output)")


def add_cluster_options(p, chunks: bool = True) -> None:
    """``--cluster``, ``--address``, ``--workers`` (and ``--chunk-points``) on a command: :class:`ClusterSettings`."""
    d = ClusterSettings()
    p.add_argument("--cluster", choices=CLUSTERS, default=d.cluster,
                   help="run the work on Ray (pip install 'volcomp[cluster]'); default: in this process")
    p.add_argument("--address", default=d.address, metavar="HOST:PORT",
                   help="with --cluster ray: join this running Ray cluster ('auto': the one on this node); "
                        "default: start a local one")
    p.add_argument("--workers", type=int, default=d.workers,
                   help="workers: threads in this process, or the CPUs of the local Ray instance "
                        "(default: this machine's cores; a joined cluster: all its CPUs)")
    if chunks:
        p.add_argument("--chunk-points", type=int, default=d.chunk_points,
                       help=f"points per chunk (default {d.chunk_points:,}): the unit of work handed to a worker, "
                            "fixed whatever the number of workers, so results do not depend on it")


def cluster_settings(args) -> ClusterSettings:
    """The options of :func:`add_cluster_options` as :class:`ClusterSettings`, checked (one UsageError line)."""
    s = ClusterSettings(cluster=args.cluster, address=args.address, workers=args.workers,
                        chunk_points=getattr(args, "chunk_points", ClusterSettings.chunk_points))
    s.check()
    return s
