"""Reference results of the exact solvers, generated from main's code before the solvers moved onto
the chain (issue 26: one source for the kinematics), for ``tests/test_exact_reference.py``.

The cases are seeded and built here; the file ``tests/data/exact_reference.npz`` holds, per case,
the commands (n, 3) mm and the success flags the solver of the code on PYTHONPATH returned. It was
written by main at 0485cf2 (the grinder's hand-written kinematics)::

    git archive 0485cf2 | tar -x -C /tmp/main0485
    PYTHONPATH=/tmp/main0485:tests python tests/exact_reference.py tests/data/exact_reference.npz

Run with this checkout's code instead (``PYTHONPATH=.:tests``) to see the same figures.
"""
from __future__ import annotations

import sys

import numpy as np

SEED = 20261124
CASES = {"grinder": 4000, "mill-xyz": 2000, "five-axis-ac": 2000}
"""Points per case: the grinder (HTM field, ``solve_exact``) and two chain files (``ChainField``,
``solve_exact_chain``, rotary axes kept)."""
ELEMENT_SCALE_UM = 20.0  # chain element values ±20 μm / μrad


def chain_elements(mt, seed, scale=ELEMENT_SCALE_UM, n_stations=11):
    """A seeded smooth chain element set (full-turn axes periodic)."""
    from errormap.chain_elements import ChainElementSet
    return ChainElementSet.random(mt, seed, scale, n_stations)


def case(name):
    """``(solve() -> SolveResult, targets (n, 3), axes (n, k))`` of one case, seeded."""
    from errormap.machine import load_machine
    from errormap.seeds import spawn_rngs
    rng_axes, rng_field = spawn_rngs(SEED, 2)
    n = CASES[name]
    m = load_machine(name)
    field_seed = int(rng_field.integers(2**31))
    if name == "grinder":
        from compensation.solvers import solve
        from errormap.chain_field import ChainField
        from errormap.chain_kernel import forward
        from errormap.chain_truth import make_chain_truth
        field = ChainField(m, make_chain_truth(m, field_seed).elements)
        axes = rng_axes.uniform(m.stroke_lo, m.stroke_hi, (n, 3))
        targets = forward(m, axes)
        return (lambda: solve("exact", field, targets, m, target_axes=axes, progress=False)), targets, axes
    from compensation.solvers.chain_exact import solve_exact_chain
    from errormap.chain_field import ChainField
    field = ChainField(m, chain_elements(m, field_seed))
    axes = rng_axes.uniform(m.stroke_lo, m.stroke_hi, (n, len(m.axes)))
    targets = m.nominal(axes)
    return (lambda: solve_exact_chain(field, targets, m, target_axes=axes, progress=False)), targets, axes


def main(out):
    from errormap.io import atomic_write
    arrays = {}
    for name in CASES:
        solve, _, _ = case(name)
        r = solve()
        arrays[f"{name}/commands_mm"] = r.commands_mm
        arrays[f"{name}/success"] = r.success
        print(f"{name}: {int(r.success.sum())}/{len(r.success)} solved, max |residual| "
              f"{np.linalg.norm(r.residual_um, axis=1).max():.3g} μm")
    with atomic_write(out, "wb") as fh:
        np.savez_compressed(fh, **arrays)


if __name__ == "__main__":
    main(sys.argv[1])
