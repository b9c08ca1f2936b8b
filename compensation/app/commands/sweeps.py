"""``volcomp sweeps``: simulated laser-tracker sweeps (the sweep file of docs/reference/file-formats.md) of a truth
machine tool."""
from __future__ import annotations

import sys

from errormap.machine import load_machine
from errormap.seeds import spawn_seeds

from ..families import family_of, say_read_as


def register(sub):
    p = sub.add_parser("sweeps", help="simulate laser-tracker axis sweeps of a truth machine tool (sweep CSV)",
                       description="Three target balls per moving body (machine file [targets]), 21 stations per "
                                   "axis, the tracker at a seeded unknown pose, isotropic noise. Writes one sweep "
                                   "file (one tracker set-up, every axis of the machine, the others parked at the "
                                   "lower ends of their strokes).")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name (mill-xyz, five-axis-ac, ...); "
                                                     "default: the built-in grinder")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--truth", default=None, metavar="ELEMENTS", help="truth element-set file (JSON)")
    src.add_argument("--seed", type=int, default=None, help="seed of a random truth machine (as `volcomp simulate`)")
    p.add_argument("--effect", action="append", default=[],
                   help="undeclared effect in the truth (repeatable): KIND[:AXES] as `volcomp simulate`")
    p.add_argument("--family", choices=("default", "independent"), default="default",
                   help="truth family: default (the simulator) or independent (other shapes, magnitudes, effect "
                        "parameters and check layout; errormap/chain_truth.py)")
    p.add_argument("--out", required=True, help="output sweep CSV")
    p.add_argument("--noise-um", type=float, default=2.0, help="tracker noise σ per coordinate (μm, default 2)")
    p.add_argument("--seed-noise", type=int, default=None,
                   help="seed of the tracker pose and the noise (default: derived from --seed, a child of its "
                        "SeedSequence, printed and written in the file; with --truth: 0)")
    p.add_argument("--bidirectional", action="store_true", help="also sweep each axis back down (direction -1)")
    p.add_argument("--warmup-c", type=float, default=0.0,
                   help="temperature rise over the run (°C; default 0: reference temperature)")
    p.add_argument("--setup", default="setup-1", help="set-up id written as '# setup:' (default setup-1)")
    p.set_defaults(func=run)


NOISE_CHILD = 3
"""The noise seed derived from ``--seed`` is child 3 of ``SeedSequence(seed)`` (:func:`errormap.seeds.spawn_seeds`):
children 0-2 are the simulator's points, environment and check noise of the same seed
(errormap/chain_truth.py), so the sweeps' noise is a stream of its own."""


def noise_seed(args) -> tuple[int, str]:
    """The tracker pose and noise seed and where it came from: ``--seed-noise`` as given; else derived from
    ``--seed`` (:data:`NOISE_CHILD`, as an int that ``--seed-noise`` reproduces); else (``--truth``) 0."""
    if args.seed_noise is not None:
        return args.seed_noise, "--seed-noise"
    if args.seed is not None:
        child = spawn_seeds(args.seed, NOISE_CHILD + 1)[NOISE_CHILD]
        return int(child.generate_state(1)[0]), f"derived from --seed {args.seed}; --seed-noise N reproduces it"
    return 0, "default with --truth"


def run(args) -> int:
    machine = load_machine(args.machine)  # None: the built-in default machine
    target = family_of(machine).target("sweeps")   # machine tools: other families are refused, naming their path
    say_read_as(machine)
    args.seed_noise, noise_from = noise_seed(args)
    print(f"noise seed {args.seed_noise} ({noise_from})")
    return RUNNERS[target](machine, args)


def _run_chain(machine, args) -> int:
    """Every machine tool (a chain file, the built-in grinder, a ``kind = "grinder"`` file read as its chain)."""
    from ..workflows.measurement import parse_effects, sweeps_chain
    parse_effects(machine, args.effect)
    print(f"simulating tracker sweeps of {machine.name} (noise {args.noise_um} um, seed {args.seed_noise}) ...",
          file=sys.stderr)
    path, n, what = sweeps_chain(machine, args.out, seed=args.seed, truth_file=args.truth, effects=args.effect,
                                 family=args.family, noise_um=args.noise_um, seed_noise=args.seed_noise,
                                 bidirectional=args.bidirectional, warmup_c=args.warmup_c, setup=args.setup)
    print(f"wrote {n} ball measurements of {what} to {path}")
    return 0


RUNNERS = {"chain": _run_chain}
"""The runner of each target of ``sweeps`` (:meth:`compensation.app.families.Family.target`)."""
