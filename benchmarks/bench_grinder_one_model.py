"""The built-in grinder as its chain file against the tree before it (one model of the grinder).

Runs the same seeded work in two source trees, each in its own process (``PYTHONPATH`` = the tree):
the built-in grinder (``load_machine()``), the seeded simulator truth (``random_truth(machine, 0)``,
23 elements, max error 165–215 μm), ``--points`` random axes over the strokes (seed 1, A over one turn),
and then

* the nominal tool points of those axes (``forward``);
* the exact error field of the truth's element set there (value and axis Jacobian);
* the exact solve (``solve("exact", field, targets, machine)``) of the targets: commanded axes, model
  residual, and where the commanded axes put the tool (nominal + field, μm);
* μs per point of the field's value + Jacobian (median of 3, warm).

and compares them: the largest absolute differences (mm, μm, deg) and the two timings. The baseline tree
is a checkout of main before the built-in grinder became a chain file (its ``HTMField`` and
``errormap.kinematics``); this tree's are :class:`errormap.chain_field.ChainField` and
:mod:`errormap.chain_kernel`.

Reproduce (from the repository root, one core)::

    OMP_NUM_THREADS=1 PYTHONPATH=$PWD python benchmarks/bench_grinder_one_model.py --baseline-root /work/main \\
        --points 100000
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
TRUTH_SEED, AXES_SEED, REPEATS = 0, 1, 3


def _grinder_tools():
    """(machine, field of an element set, forward, solve) from whichever tree is on the path."""
    from compensation.solvers import solve
    from errormap.machine import load_machine
    from errormap import machine
    m = load_machine()
    if hasattr(machine, "Grinder"):   # the tree before: the grinder's own field and kinematics modules
        from errormap.chain_field import ChainField as Field
        from errormap.chain_kernel import forward
    else:
        from errormap.chain_field import ChainField as Field
        from errormap.chain_kernel import forward
    return m, Field, forward, solve


def worker(out: Path, n_points: int) -> None:
    """The seeded work of one tree, written to ``out`` (npz + timings)."""
    from errormap.simulator import random_truth
    m, Field, forward, solve = _grinder_tools()
    field = Field(m, random_truth(m, TRUTH_SEED).elements)
    rng = np.random.default_rng(AXES_SEED)
    lo, hi = (np.array([m.strokes[k][i] for k in ("x_mm", "z_mm", "a_deg")]) for i in (0, 1))
    axes = lo + (hi - lo) * rng.random((n_points, 3))
    targets = forward(m, axes)
    E, J = field.predict_and_jacobian(axes)
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        field.predict_and_jacobian(axes)
        times.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    res = solve("exact", field, targets, m, progress=False)
    solve_s = time.perf_counter() - t0
    landed = forward(m, res.axes) + 1e-3 * field.predict(res.axes)
    np.savez(out, targets=targets, E=E, J=J, axes=res.axes, residual=res.residual_um, landed=landed,
             success=res.success, us_per_point=1e6 * np.median(times) / n_points, solve_s=solve_s)


def run_tree(root: Path, n_points: int, folder: Path) -> dict:
    out = folder / f"{root.name or 'tree'}-{abs(hash(str(root)))}.npz"
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    subprocess.run([sys.executable, __file__, "--worker", str(out), "--points", str(n_points)], env=env, check=True,
                   cwd=str(root))
    with np.load(out) as d:
        return {k: d[k] for k in d.files}


def compare(base: dict, new: dict) -> dict:
    """Largest absolute differences between the two trees' results, and both timings."""
    d = lambda k: float(np.abs(new[k] - base[k]).max())  # noqa: E731
    return {"targets_mm": d("targets"), "field_um": d("E"), "field_jacobian": d("J"), "solved_axes": d("axes"),
            "model_residual_um": d("residual"), "landed_tool_um": 1e3 * d("landed"),
            "success_same": bool(np.array_equal(base["success"], new["success"])),
            "successes": int(new["success"].sum()), "max_model_residual_um": float(np.abs(new["residual"]).max()),
            "us_per_point_value_jacobian": {"baseline": float(base["us_per_point"]), "this tree": float(new["us_per_point"])},
            "solve_s": {"baseline": float(base["solve_s"]), "this tree": float(new["solve_s"])}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-root", type=Path, help="a checkout of main before the grinder became its chain file")
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help="write the comparison as JSON here too")
    args = ap.parse_args(argv)
    if args.worker:
        worker(args.worker, args.points)
        return 0
    if args.baseline_root is None:
        ap.error("--baseline-root is required")
    with tempfile.TemporaryDirectory() as tmp:
        base = run_tree(args.baseline_root.resolve(), args.points, Path(tmp))
        new = run_tree(HERE.parent, args.points, Path(tmp))
    result = {"points": args.points, "truth_seed": TRUTH_SEED, "axes_seed": AXES_SEED, **compare(base, new)}
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
