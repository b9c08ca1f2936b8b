"""What the Python API's notebook example (docs/reference/python-api.md) achieves, and what importing the packages costs.

1. The example exactly as written in docs/reference/python-api.md, then judged with its hidden truth (simulate_truth seed 1,
   never given to the estimator): per point the uncompensated TRUE error and the TRUE residual at the
   compensated commands (the truth's tool point there minus the target), and the MODEL residual.
2. The same with 21 stations per axis (the ``volcomp sweeps`` default) in place of the example's 11.
3. The built-in grinder file through the API (identified and compensated as its chain): the TRUE error before / after
   ``compensate_points`` at 500 seeded points inside the strokes.
4. ``import errormap, compensation, training`` in a fresh interpreter: wall time (median of ``--runs``) and
   whether torch, Ray or MLflow were loaded.

    python benchmarks/bench_api.py [--runs 5]
"""
from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def example(n_stations: int | None = None) -> dict:
    import matplotlib
    matplotlib.use("Agg")
    code = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "reference" / "python-api.md").read_text(encoding="utf-8"), re.S)[0]
    if n_stations is not None:
        code = code.replace("n_stations=11", f"n_stations={n_stations}")
    ns: dict = {}
    t0 = time.process_time()
    exec(compile(code, "docs/reference/python-api.md", "exec"), ns)
    cpu = time.process_time() - t0
    from compensation.app.workflows.compensate_report import true_residual_um
    from compensation.solvers.chain_exact import nominal_and_jacobian
    from errormap import ChainField, simulate_truth
    m, axes, res = ns["machine"], ns["axes"], ns["result"]
    truth = ChainField(m, simulate_truth(m, seed=1).elements)
    targets, _ = nominal_and_jacobian(m, axes)
    before = np.linalg.norm(true_residual_um(truth, m, axes, targets), axis=1)
    after = np.linalg.norm(true_residual_um(truth, m, res.commands, targets), axis=1)
    return {"before": before, "after": after, "model": np.linalg.norm(res.residual_um, axis=1), "cpu_s": cpu,
            "ratio": float(np.sqrt(np.mean(after ** 2) / np.mean(before ** 2)))}


def grinder(n_points: int = 500) -> dict:
    from compensation import compensate_points
    from compensation.app.workflows.compensate_report import true_residual_um
    from compensation.solvers.chain_exact import nominal_and_jacobian
    from errormap import Identification, load_machine, simulate_sweeps, simulate_truth
    from errormap.chain_field import ChainField
    g = load_machine()
    truth = simulate_truth(g, seed=1)
    sweeps = simulate_sweeps(truth, noise_um=1.0, seed=2, n_stations=11)
    ident = Identification(g, gauge="first-station", smooth=False).fit(sweeps)   # the paper's gauge, unsmoothed
    lo, hi = (np.array([g.strokes[k][i] for k in ("x_mm", "z_mm", "a_deg")]) for i in (0, 1))
    axes = lo + (0.1 + 0.8 * np.random.default_rng(5).random((n_points, 3))) * (hi - lo)
    res = compensate_points(ident.field_, g, axes)
    mt = g
    tf = ChainField(mt, truth.elements)
    targets, _ = nominal_and_jacobian(mt, axes)
    before = np.linalg.norm(true_residual_um(tf, mt, axes, targets), axis=1)
    after = np.linalg.norm(true_residual_um(tf, mt, res.commands, targets), axis=1)
    rms = lambda v: float(np.sqrt(np.mean(v ** 2)))  # noqa: E731
    return {"before_rms": rms(before), "after_rms": rms(after),
            "after_max": float(after.max()), "model_max": float(np.abs(res.residual_um).max()),
            "accepted": res.accepted}


def import_cost(runs: int) -> tuple[float, str]:
    code = ("import sys, time; t = time.perf_counter(); import errormap, compensation, training; "
            "d = time.perf_counter() - t; "
            "print(d, sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'ray', 'mlflow'}))")
    out = []
    for _ in range(runs):
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env={"PYTHONPATH": str(ROOT), "PATH": ""}).stdout.split(maxsplit=1)
        out.append((float(r[0]), r[1].strip()))
    return statistics.median(t for t, _ in out), out[0][1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    print("| stations per axis | point | uncompensated TRUE error (μm) | TRUE residual (μm) | MODEL residual (μm) |")
    print("|---|---|---|---|---|")
    rows = {}
    for n in (None, 21):
        r = rows[n] = example(n)
        for k in range(len(r["before"])):
            print(f"| {11 if n is None else n} | {k} | {r['before'][k]:.2f} | {r['after'][k]:.2f} | {r['model'][k]:.1e} |")
    for n, r in rows.items():
        print(f"stations {11 if n is None else n}: TRUE RMS after / before {r['ratio']:.3f}; example CPU {r['cpu_s']:.1f} s")
    gr = grinder()
    print(f"grinder file as its chain at 500 points: TRUE RMS "
          f"{gr['before_rms']:.2f} -> {gr['after_rms']:.2f} um (max {gr['after_max']:.2f}), MODEL max "
          f"{gr['model_max']:.1e} um, accepted {gr['accepted']}")
    t, heavy = import_cost(a.runs)
    print(f"import errormap, compensation, training: median {t * 1e3:.1f} ms over {a.runs} fresh interpreters; "
          f"heavy packages loaded: {heavy}")


if __name__ == "__main__":
    main()
