"""The grinder's compensation on its chain against a checkout of main (its own grinder solvers), side by side.

Cases (the grinder's HTM field of a seeded truth, seed 7, or a small seeded network; targets the flute's):

* ``exact-100k``: ``solve("exact", …)`` on 100,000 seeded targets (axes uniform in the middle 90 % of the
  strokes, seed 2026) — the commands of both trees are saved and compared (max |Δ| μm);
* ``compensate-exact``: ``volcomp compensate --method exact`` of the 7-turn flute program (2,800 points);
* ``compensate-traditional``: the same with ``--method traditional``;
* ``compensate-batched-ga-net``: ``--method batched-ga`` with the network on the 1-turn flute (40 points).

Each (tree, case) runs in its own process: one warm-up call, then ``--repeats`` timed calls (wall, median);
the trees alternate case by case in one run. Usage::

    git -C /path/to/main worktree list   # any checkout of main
    python benchmarks/bench_grinder_compensate.py --main /path/to/main --out /tmp/bench_gc
    python benchmarks/bench_grinder_compensate.py --main /path/to/main --out /tmp/bench_gc --alternate --repeats 15 \
        --cases compensate-exact,compensate-traditional,compensate-batched-ga-net   # call by call
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = ("exact-100k", "compensate-exact", "compensate-traditional", "compensate-batched-ga-net")


def make_inputs(d: Path) -> None:
    """The element set, the programs, the network and the 100,000 axes (seeded), once."""
    if (d / "done").exists():
        return
    d.mkdir(parents=True, exist_ok=True)
    from compensation.app.cli import main
    from compensation.app.workflows.demo import write_flute_program
    from compensation.pathio import write_axes_gcode
    from compensation.toolpath import flute_path
    from errormap.machine import load_machine
    from errormap.simulator import random_truth
    g = load_machine()
    random_truth(g, 7).elements.save(d / "el.json")
    write_axes_gcode(d / "flute.nc", flute_path(turns=1, points_per_turn=40).axes(g), header=["flute test"])

    class _Flute:  # what write_flute_program reads of the demo's settings
        class settings:
            turns = 7
    write_flute_program(d / "demo_flute.nc", flute_path(turns=7, points_per_turn=400).axes(g), _Flute)
    assert main(["simulate", "--seed", "1", "--checks", "50", "--out", str(d / "sim")]) == 0
    assert main(["train", str(d / "sim" / "featurepoints.csv"), "--out", str(d / "net"), "--hidden", "8,8",
                 "--max-iter", "60", "--seed", "1", "--no-select"]) == 0
    rng = np.random.default_rng(2026)
    lo, hi = g.stroke_lo, g.stroke_hi
    np.save(d / "axes100k.npy", lo + (hi - lo) * (0.05 + 0.9 * rng.random((100_000, 3))))
    (d / "done").write_text("ok")


def worker(case: str, d: Path, out: Path, repeats: int) -> dict:
    """Time ``case`` in this process (the tree on ``sys.path``): warm-up, then ``repeats`` calls
    (``repeats`` 0: one timed call per line read from stdin, its seconds printed; the parent alternates trees)."""
    import contextlib
    import io
    import shutil
    from compensation.app.cli import main
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.chain_kernel import forward
    from errormap.machine import load_machine
    g = load_machine()
    if case == "exact-100k":
        from compensation.solvers import solve
        field = ChainField(g, ChainElementSet.load(d / "el.json", g))
        q = np.load(d / "axes100k.npy")
        tg = forward(g, q)

        def call():
            return solve("exact", field, tg, g, target_axes=q, progress=False)
    else:
        method = case.split("-", 1)[1].removesuffix("-net")
        model = d / "net" / "model" if case.endswith("-net") else d / "el.json"
        prog = d / ("flute.nc" if case.endswith("-net") else "demo_flute.nc")

        def call():
            shutil.rmtree(out, ignore_errors=True)
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                assert main(["compensate", str(prog), "--model", str(model), "--method", method, "--work-offsets",
                             "machine", "--out", str(out)]) == 0
    r = call()
    if repeats == 0:
        print("ready", flush=True)
        for _ in sys.stdin:
            t0 = time.perf_counter()
            call()
            print(time.perf_counter() - t0, flush=True)
        return {}
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = call()
        times.append(time.perf_counter() - t0)
    if case == "exact-100k":
        np.save(out.with_suffix(".npy"), r.commands_mm)
    return {"times_s": times, "median_s": float(np.median(times))}


def run_tree(tree: Path, case: str, d: Path, out: Path, repeats: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1")
    code = (f"import json, sys; sys.path.insert(0, {str(ROOT / 'benchmarks')!r}); import bench_grinder_compensate as b; "
            f"from pathlib import Path; print(json.dumps(b.worker({case!r}, Path({str(d)!r}), Path({str(out)!r}), "
            f"{repeats})))")
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=str(tree))
    if res.returncode:
        raise SystemExit(f"{tree} {case}: {res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def run_alternated(trees: dict, case: str, d: Path, out: Path, repeats: int) -> dict:
    """``case`` in one persistent process per tree (warm-up first), the trees' calls alternating one by
    one (their order swapped every round), so a change of machine load hits both: ``{tree: result}``."""
    procs = {}
    for name, tree in trees.items():
        env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1")
        code = (f"import sys; sys.path.insert(0, {str(ROOT / 'benchmarks')!r}); import bench_grinder_compensate as b; "
                f"from pathlib import Path; b.worker({case!r}, Path({str(d)!r}), Path({str(out)!r}) / {name!r}, 0)")
        procs[name] = subprocess.Popen([sys.executable, "-c", code], env=env, cwd=str(tree), text=True,
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    for p in procs.values():
        while p.stdout.readline().strip() != "ready":
            if p.poll() is not None:
                raise SystemExit(f"{case}: a worker failed")
    times = {n: [] for n in trees}
    for i in range(repeats):
        for name in (list(trees) if i % 2 == 0 else list(trees)[::-1]):
            procs[name].stdin.write("go\n")
            procs[name].stdin.flush()
            times[name].append(float(procs[name].stdout.readline()))
    for p in procs.values():
        p.stdin.close()
        p.wait()
    return {n: {"times_s": t, "median_s": float(np.median(t))} for n, t in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--main", required=True, help="a checkout of main (its grinder solvers)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--alternate", action="store_true",
                    help="the compensate cases call by call, main and this tree alternating (one process each)")
    args = ap.parse_args()
    out = Path(args.out)
    make_inputs(out / "inputs")
    rows = {}
    for case in args.cases.split(","):
        if args.alternate and case != "exact-100k":
            r = run_alternated({"main": Path(args.main), "new": ROOT}, case, out / "inputs", out / f"alt-{case}",
                               args.repeats)
            m, n = r["main"], r["new"]
        else:
            m = run_tree(Path(args.main), case, out / "inputs", out / f"main-{case}", args.repeats)
            n = run_tree(ROOT, case, out / "inputs", out / f"new-{case}", args.repeats)
        rows[case] = {"main": m, "new": n, "ratio": n["median_s"] / m["median_s"]}
        if case == "exact-100k":
            a, b = np.load(out / f"main-{case}.npy"), np.load(out / f"new-{case}.npy")
            rows[case]["max_diff_um"] = float(np.abs(a - b).max() * 1e3)
        print(case, json.dumps(rows[case]), flush=True)
    (out / "results.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
