"""The chain batched GA on the grinder's chain with a network field: the network's fused float32 fitness
(``offset_fitness``, :class:`compensation.solvers.chain_ga.FusedChainFitness`) against the generic float64 chain
fitness (the same network with the capability hidden, :class:`~compensation.solvers.chain_ga.ChainAxisFitness`),
same targets and seeds: wall seconds of the solve, and the results (largest model residual of each, largest
difference of the compensated commands).

Usage: ``OMP_NUM_THREADS=1 python benchmarks/bench_fused_fitness.py --turns 7 --seeds 0 1 2`` (targets: the demo's
flute, 400 points a turn; the network: the paper-sized, untrained, seeded one of ``tests/test_batched_ga.py``'s
``make_model``, a ~20 μm field over the grinder's strokes). Residual kind: model (no truth involved).
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


class Hidden:
    """``field`` without the ``offset_fitness`` capability (the generic float64 fitness is used)."""

    def __init__(self, field):
        from errormap.field import OFFSET_FITNESS
        self._f = field
        self.capabilities = field.capabilities - {OFFSET_FITNESS}
        self.calibrated_volume = field.calibrated_volume

    def predict(self, axes, *a, **k):
        return self._f.predict(axes, *a, **k)

    def __getattr__(self, name):
        return getattr(self._f, name)


def network(seed: int = 0):
    """The paper-sized untrained network of tests/test_batched_ga.py (scalers over the grinder's strokes)."""
    from training.model import MLPField
    rng = np.random.default_rng(seed)
    axes = np.column_stack([rng.uniform(0, 200, 300), rng.uniform(0, 60, 300), rng.uniform(0, 360, 300)])
    axes[:2, 2] = [0.0, 360.0]
    m = MLPField((10, 15, 25, 15, 10), "sigmoid", "raw").fit_scalers(axes, rng.normal(0.0, 20.0, (300, 3)))
    m.theta_ = m.init_params(seed)
    return m


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--turns", type=int, default=7)
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    a = p.parse_args()
    from compensation.solvers.chain_ga import solve_batched_ga_chain
    from compensation.toolpath import flute_path
    from errormap.chain_kernel import forward
    from errormap.machine import load_machine
    g = load_machine(None)
    mt = g
    field = network()
    axes = flute_path(turns=a.turns, points_per_turn=400).axes(g)
    targets = forward(g, axes)
    for seed in a.seeds:
        out = {"points": len(targets), "seed": seed}
        res = {}
        for name, f in (("fused32", field), ("float64", Hidden(field))):
            t0 = time.perf_counter()
            res[name] = solve_batched_ga_chain(f, targets, mt, target_axes=axes, seed=seed, progress=False)
            out[f"{name}_s"] = round(time.perf_counter() - t0, 2)
            out[f"{name}_max_model_um"] = float(np.linalg.norm(res[name].residual_um, axis=1).max())
            out[f"{name}_success"] = float(np.mean(res[name].success))
        out["max_command_diff_um"] = float(np.abs(res["fused32"].commands_mm - res["float64"].commands_mm).max() * 1e3)
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
