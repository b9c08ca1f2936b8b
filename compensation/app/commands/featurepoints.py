"""``volcomp featurepoints``: the feature-point dataset (a grid over the machine's axes) from an element set."""
from __future__ import annotations

import sys

from errormap.featurepoints import DEFAULT_GRID, make_feature_points
from errormap.io import InputError, sha256_file
from errormap.machine import load_machine

from ..families import family_of


def register(sub):
    p = sub.add_parser("featurepoints", help="feature points (a grid over the machine's axes) from an element set")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name (mill-xyz, five-axis-ac, ...); "
                   "default: the built-in grinder; the grid is over the machine's own axes")
    p.add_argument("--elements", required=True, help="element-set file (JSON)")
    p.add_argument("--grid", type=int, default=None,
                   help=f"points per axis (default {DEFAULT_GRID} on up to three axes, a node at every element station "
                        f"of the simulated truth; on more axes the largest grid of at most {DEFAULT_GRID}³ points)")
    p.add_argument("--out", required=True, help="output CSV")
    p.set_defaults(func=run)


def run(args) -> int:
    machine = load_machine(args.machine)
    field = FIELDS[family_of(machine).target("featurepoints")](machine, args)
    print(f"featurepoints: element set (volcomp-elements/1): {args.elements}", file=sys.stderr)
    fp = make_feature_points(machine, field, n=args.grid,
                             meta={"elements_file": args.elements, "elements_sha256": sha256_file(args.elements)})
    path = fp.save(args.out)
    print(f"wrote {len(fp.axes)} feature points to {path}")
    return 0


def _chain_field(machine, args):
    """A machine tool (a chain file, the built-in grinder, a ``kind = "grinder"`` file read as its chain): its
    element set; the grid over its own axes, sized before any work."""
    from compensation.app.validate import UsageError
    from compensation.app.validate import MAX_GRID_POINTS
    k = len(machine.axes)
    if args.grid is not None and args.grid ** k > MAX_GRID_POINTS:   # None: errormap.featurepoints.default_grid fits
        raise UsageError(f"--grid {args.grid}: {args.grid}^{k} = {args.grid ** k} points over the {k} axes of "
                         f"{machine.name!r} exceeds {MAX_GRID_POINTS}; the largest that fits is "
                         f"{int(MAX_GRID_POINTS ** (1 / k) + 1e-9)}")
    from compensation.model_file import read_model
    model = read_model(args.elements, machine)
    if not model.elements_only:
        raise InputError(f"{args.elements}: feature points are placed from an element set; this model holds "
                         f"{', '.join(model.holds())}")
    return model.field


FIELDS = {"chain": _chain_field}
"""The error field of each target of ``featurepoints`` (:meth:`compensation.app.families.Family.target`)."""
