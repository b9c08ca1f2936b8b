"""``volcomp simulate``: a seeded truth grinder, its feature points and check measurements."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from errormap.featurepoints import make_feature_points
from errormap.htm import HTMField
from errormap.io import write_csv, write_json
from errormap.machine import load_machine
from errormap.simulator import EFFECT_DEFAULTS, EFFECT_NAMES, volume_grid


def register(sub):
    p = sub.add_parser("simulate", help="simulate a truth grinder: elements, feature points, check measurements",
                       description="Write DIR/truth_elements.json, DIR/featurepoints.csv, DIR/checks.csv and DIR/truth.json.")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--family", choices=("default", "independent"), default="default",
                   help="truth family: default (the simulator) or independent (other shapes, magnitudes, effect "
                        "parameters and check layout; errormap/truth_families.py)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--effect", action="append", default=[], choices=EFFECT_NAMES,
                   help="add an undeclared effect (repeatable): " + ", ".join(EFFECT_NAMES))
    p.add_argument("--noise-um", type=float, default=1.0, help="check-measurement noise σ per axis (μm)")
    p.add_argument("--checks", type=int, default=400, help="number of check measurements")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..cli import UsageError
    if not args.noise_um >= 0:
        raise UsageError(f"--noise-um: expected a number >= 0, got {args.noise_um}")
    if args.checks < 1:
        raise UsageError(f"--checks: expected at least 1, got {args.checks}")
    machine = load_machine(args.machine, expect_kind="grinder")
    out = Path(args.out)
    print(f"simulating truth grinder seed={args.seed} effects={args.effect or 'none'} ...", file=sys.stderr)
    from errormap.truth_families import make_truth
    truth = make_truth(machine, args.seed, effects=args.effect, family=getattr(args, "family", "default"))
    el_path = truth.elements.save(out / "truth_elements.json")
    fp = make_feature_points(machine, HTMField(machine, truth.elements),
                             meta={"elements_file": str(el_path), "source": f"simulate seed={args.seed}"})
    from errormap.io import sha256_file
    fp.meta["elements_sha256"] = sha256_file(el_path)
    fp_path = fp.save(out / "featurepoints.csv")
    checks = truth.check_measurements(n=args.checks, noise_um=args.noise_um, seed=args.seed + 1)
    ck_path = write_csv(out / "checks.csv", checks, header_comments=[
        "format: volcomp-checks/1", f"machine: {machine.name}", f"noise_um: {args.noise_um}",
        f"effects: {','.join(args.effect) or 'none'}"])
    grid = volume_grid(machine)
    e = np.linalg.norm(truth.spatial_error(grid, **truth.default_conditions(len(grid))), axis=1)
    info = {"seed": args.seed, "machine": machine.name, "machine_file": machine.path,
            "family": getattr(args, "family", "default"), "effects": {k: EFFECT_DEFAULTS[k] | truth.effects[k] for k in truth.effects},
            "noise_um": args.noise_um, "max_spatial_error_um": float(e.max()),
            "files": {"elements": str(el_path), "featurepoints": str(fp_path), "checks": str(ck_path)}}
    write_json(out / "truth.json", info)
    print(f"max spatial error {e.max():.1f} μm over the volume (reference temperature, positive approach)")
    for k, v in info["files"].items():
        print(f"wrote {k}: {v}")
    print(f"wrote truth: {out / 'truth.json'}")
    return 0
