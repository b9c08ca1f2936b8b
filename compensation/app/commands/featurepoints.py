"""``volcomp featurepoints``: the 11×11×11 feature-point dataset from an element set."""
from __future__ import annotations

import sys

from errormap.elements import ElementSet
from errormap.featurepoints import make_feature_points
from errormap.htm import HTMField
from errormap.io import sha256_file
from errormap.machine import load_machine


def register(sub):
    p = sub.add_parser("featurepoints", help="feature points (11x11x11 grid) from an element set")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--elements", required=True, help="element-set file (JSON)")
    p.add_argument("--grid", type=int, default=11, help="points per axis (default 11)")
    p.add_argument("--out", required=True, help="output CSV")
    p.set_defaults(func=run)


def run(args) -> int:
    machine = load_machine(args.machine, expect_kind="grinder")
    el = ElementSet.load(args.elements)  # by content: its format key, whatever the file's name
    print(f"featurepoints: element set (volcomp-elements/1): {args.elements}", file=sys.stderr)
    fp = make_feature_points(machine, HTMField(machine, el), n=args.grid,
                             meta={"elements_file": args.elements, "elements_sha256": sha256_file(args.elements)})
    path = fp.save(args.out)
    print(f"wrote {len(fp.axes)} feature points to {path}")
    return 0
