"""``volcomp simulate``: a seeded truth machine and its measurements (a machine tool: its elements, feature points and
check measurements; an arm or a parallel machine: measured poses)."""
from __future__ import annotations

import sys
from pathlib import Path

from errormap.machine import load_machine
from ..families import family_of, say_read_as

from ..workflows.simulate import summary_lines


def register(sub):
    p = sub.add_parser("simulate", help="simulate a truth machine and its measurements (a machine tool: elements, feature points, "
                                        "checks; a serial arm or a hexapod/tripod: measured poses)",
                       description="A machine tool: write DIR/truth_elements.json, DIR/featurepoints.csv, DIR/checks.csv "
                                   "and DIR/truth.json. A serial arm (--machine ur5|ur10|wam|FILE): write DIR/poses.csv, "
                                   "DIR/checks.csv, DIR/program.csv and DIR/truth.json (docs/explanation/serial-arms.md). A hexapod or "
                                   "tripod: DIR/poses.csv, DIR/checks.csv and DIR/truth.json (docs/explanation/parallel-kinematics.md).")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name (mill-xyz, five-axis-ac, ...); "
                                                     "default: the built-in grinder")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--family", choices=("default", "independent"), default="default",
                   help="truth family: default (the simulator) or independent (other shapes, magnitudes, effect "
                        "parameters and check layout; errormap/chain_truth.py)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--effect", action="append", default=[],
                   help="add an undeclared effect (repeatable): a machine tool KIND[:AXES] with KIND thermal, "
                        "reversal (backlash), periodic (pitch), harmonic (worm), interaction, or the truth-only bump, "
                        "xz_saddle, squareness, squareness_xz on two linear axes or a_tilt, a_lobe_x on a rotary and a "
                        "linear axis, e.g. periodic:Y, harmonic:C, bump:X*Y, a_tilt:C*X (without AXES: thermal and "
                        "periodic on the first linear axis, reversal on the last, harmonic on the first rotary axis, "
                        "a pair on the first and last linear axes, a_tilt and a_lobe_x on the first rotary and first "
                        "linear axis); a serial arm: sag, backlash")
    p.add_argument("--noise-um", type=float, default=None,
                   help="measurement noise σ per axis (μm); default 1 for machine tools, 20 for a serial arm's tracker, "
                        "5 for a parallel machine's instrument")
    p.add_argument("--checks", type=int, default=None,
                   help="number of check measurements (default 400; a serial arm: 100 held-out poses)")
    p.add_argument("--seed-check-noise", type=int, default=None,
                   help="redraw only the check measurements' noise from this seed (the same machine, points or poses "
                        "and conditions; every family); default: the noise of --seed's own stream")
    p.add_argument("--poses", type=int, default=None,
                   help="a serial arm or a hexapod/tripod: number of fitting poses (default 200; a parallel machine 100)")
    p.set_defaults(func=run)


def run(args) -> int:
    machine = load_machine(args.machine)   # None: the built-in default machine
    family = family_of(machine)
    family.refuse_unsupported("simulate", args)
    say_read_as(machine)
    return RUNNERS[family.target("simulate")](machine, args)


def _print_written(info, out, note: str) -> int:
    """The files a simulation wrote, the truth last (``note`` after its path); exit status 0."""
    for k, v in info["files"].items():
        print(f"wrote {k}: {v}")
    print(f"wrote truth: {Path(out) / 'truth.json'}{note}")
    return 0


def _run_arm(machine, args) -> int:
    from ..workflows.simulate_serial import DEFAULT_ARM_NOISE_UM, simulate_serial
    noise = DEFAULT_ARM_NOISE_UM if args.noise_um is None else args.noise_um
    print(f"simulating truth arm {machine.name} seed={args.seed} effects={args.effect or 'none'} ...", file=sys.stderr)
    info = simulate_serial(machine, args.seed, args.out, effects=args.effect, noise_um=noise,
                           poses=200 if args.poses is None else args.poses,
                           checks=100 if args.checks is None else args.checks,
                           check_noise_seed=args.seed_check_noise)
    print(f"tool point error of the truth at the fitting poses: {info['uncompensated_rms_mm']:.3f} mm RMS")
    return _print_written(info, args.out, " (the judge's; never an input of calibrate)")


def _run_parallel(machine, args) -> int:
    from ..workflows.simulate_pkm import DEFAULT_PKM_NOISE_UM, DEFAULT_PKM_POSES, simulate_pkm
    print(f"simulating truth {machine.kind} {machine.name} seed={args.seed} ...", file=sys.stderr)
    info = simulate_pkm(machine, args.seed, args.out,
                        noise_um=DEFAULT_PKM_NOISE_UM if args.noise_um is None else args.noise_um,
                        poses=DEFAULT_PKM_POSES if args.poses is None else args.poses,
                        checks=100 if args.checks is None else args.checks, check_noise_seed=args.seed_check_noise)
    return _print_written(info, args.out, " (the judge's; never an input of calibrate)")


def _run_chain(machine, args) -> int:
    """Every machine tool (a chain file, the built-in grinder, a ``kind = "grinder"`` file read as its chain)."""
    from ..workflows.measurement import parse_effects, simulate_chain
    parse_effects(machine, args.effect)
    print(f"simulating truth {machine.name} seed={args.seed} effects={args.effect or 'none'} ...", file=sys.stderr)
    info = simulate_chain(machine, args.seed, args.out, effects=args.effect,   # noise 1 μm, 400 checks: the defaults
                          noise_um=1.0 if args.noise_um is None else args.noise_um,
                          checks=400 if args.checks is None else args.checks, family=args.family,
                          check_noise_seed=args.seed_check_noise)
    for line in summary_lines(info, args.out):
        print(line)
    return 0


RUNNERS = {"chain": _run_chain, "arm": _run_arm, "parallel": _run_parallel}
"""The runner of each target of ``simulate`` (:meth:`compensation.app.families.Family.target`)."""
