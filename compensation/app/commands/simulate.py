"""``volcomp simulate``: a seeded truth grinder, its feature points and check measurements."""
from __future__ import annotations

import sys

from errormap.machine import load_machine
from errormap.simulator import EFFECT_CHOICES, EFFECT_HELP


from ..workflows.simulate import simulate_truth, summary_lines


def register(sub):
    p = sub.add_parser("simulate", help="simulate a truth grinder: elements, feature points, check measurements",
                       description="Write DIR/truth_elements.json, DIR/featurepoints.csv, DIR/checks.csv and DIR/truth.json.")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--family", choices=("default", "independent"), default="default",
                   help="truth family: default (the simulator) or independent (other shapes, magnitudes, effect "
                        "parameters and check layout; errormap/truth_families.py)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--effect", action="append", default=[], choices=EFFECT_CHOICES,
                   help="add an undeclared effect (repeatable): " + EFFECT_HELP)
    p.add_argument("--noise-um", type=float, default=1.0, help="check-measurement noise σ per axis (μm)")
    p.add_argument("--checks", type=int, default=400, help="number of check measurements")
    p.set_defaults(func=run)


def run(args) -> int:
    machine = load_machine(args.machine, expect_kind="grinder")
    print(f"simulating truth grinder seed={args.seed} effects={args.effect or 'none'} ...", file=sys.stderr)
    info = simulate_truth(machine, args.seed, args.out, effects=args.effect, noise_um=args.noise_um,
                          checks=args.checks, family=getattr(args, "family", "default"))
    for line in summary_lines(info, args.out):
        print(line)
    return 0
