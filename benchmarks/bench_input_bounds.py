"""CPU time and peak memory of the commands that read a user table, at two sizes each: the measured runs the input
bounds scale their estimates from (errormap/input_bounds.py; docs/decisions/020-benchmark-notebook.md "Bounded inputs per command").

    python benchmarks/bench_input_bounds.py OUT_DIR [CASE ...]

CASE: diagnose, calibrate, identify, identify-chain, drift (default: all). Each run is a ``volcomp`` process timed
by GNU time (``/usr/bin/time``: user + system CPU, peak resident memory); one BLAS thread.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SIZES = {"diagnose": (1_200, 20_000), "calibrate": (1_200, 5_000), "identify": (201, 401),
         "identify-chain": (201, 401), "drift": (46.0, 460.0)}
"""Per case: checks, poses, stations per axis, stations per axis, log hours."""


def cli(*args) -> list:
    return [sys.executable, "-m", "compensation.app.cli", *map(str, args)]


def timed(label: str, argv: list, rows_file: Path) -> str:
    rows = sum(1 for line in open(rows_file) if line.strip() and not line.startswith("#")) - 1
    r = subprocess.run(["/usr/bin/time", "-f", "%U %S %M", *argv], capture_output=True, text=True)
    user, system, rss_kb = r.stderr.strip().splitlines()[-1].split()
    return (f"| {label} | {rows:,} | {float(user) + float(system):.1f} | {int(rss_kb) / 1e6:.2f} | "
            f"{'ok' if r.returncode in (0, 1) else r.returncode} |")


def make_input(case: str, size, d: Path) -> tuple[list, Path]:
    """The command line of one run and the table it reads."""
    from errormap.io import write_csv
    from errormap.machine import load_machine
    if case in ("diagnose", "calibrate"):
        sim = d / f"{case}{size}"
        extra = ["--checks", size] if case == "diagnose" else ["--machine", "ur5", "--poses", size]
        subprocess.run(cli("simulate", "--seed", 1, "--out", sim, *extra), check=True, capture_output=True)
        if case == "diagnose":
            return cli("diagnose", sim / "checks.csv", "--model", sim / "truth_elements.json", "--out", d / f"o{size}"), \
                sim / "checks.csv"
        return cli("calibrate", sim / "poses.csv", "--machine", "ur5", "--out", d / f"c{size}"), sim / "poses.csv"
    if case == "identify":
        from errormap.chain_sweeps import simulate_mt_sweeps
        from errormap.sweeps import write_sweeps
        from errormap.truth_families import make_truth
        p = write_sweeps(d / f"gsw{size}.csv", simulate_mt_sweeps(make_truth(load_machine(None), 3), n_stations=size))
        return cli("identify", p, "--out", d / f"gE{size}.json"), p
    if case == "identify-chain":
        from errormap.chain_truth import make_mt_truth
        from errormap.chain_sweeps import simulate_mt_sweeps
        from errormap.sweeps import write_sweeps
        mill = load_machine("mill-xyz")
        p = write_sweeps(d / f"msw{size}.csv", simulate_mt_sweeps(make_mt_truth(mill, 3), n_stations=size, seed=1))
        return cli("identify", p, "--machine", "mill-xyz", "--out", d / f"mE{size}.json"), p
    import numpy as np
    from errormap.diagnosis.drift_sim import simulate_lumped_log
    cols = simulate_lumped_log(seed=0, hours=size)
    n = len(cols["time_s"])
    p = write_csv(d / f"log{size:g}.csv", {k: v for k, v in cols.items() if np.ndim(v) == 1 and len(v) == n})
    return cli("diagnose", "--drift", p, "--out", d / f"dr{size:g}"), p


def main(argv) -> None:
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    print("| run | rows | CPU s | peak GB | exit |\n|---|---|---|---|---|")
    for case in argv[1:] or list(SIZES):
        for size in SIZES[case]:
            cmd, table = make_input(case, size, out)
            print(timed(f"{case} {size:g}", cmd, table), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
