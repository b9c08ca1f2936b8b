"""The G-code reader's axis words from the machine : byte identity and fast-path speed
against a baseline checkout.

Since the reader takes every machine's axis words from its file (the built-in default machine's
where a caller names none), the block-wise reader's letters are arguments of its compiled kernel,
not constants. This script shows that nothing changed for the default machine:

* **bytes**: ``volcomp compensate --method exact`` (element model ``random_truth(grinder, 7)``) on
  every compensated program of ``tests/data/gcode_corpus`` (with the options its ``expect:`` line
  names) and on a ``--lines`` program of ``bench_scale_io.gcode_program``, and on ``mill-xyz`` (its
  ``volcomp simulate --seed 1`` truth elements) on ``tests/data/mill_pocket.nc`` and a generated
  ``--mill-lines`` program, run by this checkout and by ``--baseline-root``; every output file's
  SHA-256 compared.
* **speed**: CPU time of the block-wise read (``parse_program`` with the default machine's words,
  as ``compensate`` passes them) and write (``render_table``, stand-in vertices) of that program, each checkout in its own fresh process, interleaved,
  ``--repeats`` times (median; numba caches warmed by a first run that is not counted).

``python benchmarks/bench_gcode_words.py --baseline-root DIR`` writes
``benchmarks/gcode_words_results.md``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
CORPUS = HERE / "tests" / "data" / "gcode_corpus"

_COMPENSATE = r"""
import json, sys, hashlib
from pathlib import Path
from compensation.app.cli import main
from errormap.machine import load_machine
from errormap.simulator import random_truth
out_dir, jobs = Path(sys.argv[1]), json.loads(sys.argv[2])
el = random_truth(load_machine(), 7).elements.save(out_dir / "el.json")
assert main(["simulate", "--machine", "mill-xyz", "--seed", "1", "--checks", "10", "--out", str(out_dir / "msim")]) == 0
models = {"": [], "mill-xyz": ["--machine", "mill-xyz"]}
digests = {}
for name, src, opts, machine in jobs:
    out = out_dir / name
    model = out_dir / "msim" / "truth_elements.json" if machine else el
    rc = main(["compensate", src, *models[machine], "--model", str(model), "--method", "exact", "--out", str(out),
               "--work-offsets", "machine", *opts])  # every program here is in machine coordinates
    files = sorted(p for p in out.iterdir() if p.name != "compensate_summary.json") if out.exists() else []
    digests[name] = [rc, {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}]
print("RESULT " + json.dumps(digests))
"""

_SPEED = r"""
import json, sys, time
import numpy as np
from compensation.gcode import AxisWords, parse_program, render_table
from errormap.machine import load_machine
prog_path = sys.argv[1]
ax = AxisWords.of(load_machine())  # the machine's words, as the command passes them (not timed)
c0 = time.process_time()
prog = parse_program(prog_path, axis_words=ax)
c1 = time.process_time()
t = prog.table
rows = np.flatnonzero(t.compensate)
axes = t.end[rows] + 1e-3 * np.sin(np.arange(rows.size * 3, dtype=float)).reshape(-1, 3)
c2 = time.process_time()
text, _ = render_table(prog, axes, np.ones(rows.size, np.int64))
c3 = time.process_time()
print("RESULT " + json.dumps({"read_s": c1 - c0, "write_s": c3 - c2, "lines": len(prog.lines), "bulk": t is not None}))
"""


def _run(root: Path, code: str, *args) -> dict:
    env = {**os.environ, "PYTHONPATH": str(root)}
    r = subprocess.run([sys.executable, "-c", code, *args], env=env, cwd=root, capture_output=True, text=True)
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    if r.returncode != 0 or not line:
        raise SystemExit(f"{root}: failed\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}")
    return json.loads(line[-1][len("RESULT "):])


def _corpus_jobs() -> list:
    jobs = []
    for p in sorted(CORPUS.iterdir()):
        if not p.name.startswith("c"):
            continue
        exp = next(ln for ln in p.read_text(encoding="latin-1").splitlines() if "expect:" in ln)
        words = exp.split("expect:", 1)[1].replace(")", " ").split()
        opts = []
        for w in words[1:]:
            k, v = w.split("=", 1)
            if k != "work-offsets":  # every job is given --work-offsets machine (_COMPENSATE)
                opts += [f"--{k}", v] if k != "max-segment" else ["--max-segment-mm", v]
        jobs.append([p.name, str(p), opts, ""])
    return jobs


def mill_program(n_lines: int, seed: int = 0) -> str:
    """A three-axis program of ``n_lines`` plain ``G1 X.. Y.. Z..`` lines (a raster over the mill's table)."""
    import numpy as np
    rng = np.random.default_rng(seed)
    n = n_lines - 6
    k = np.arange(n)
    x = 50.0 + 500.0 * np.abs(((k / 4000.0) % 2.0) - 1.0)
    y = 20.0 + 360.0 * k / n
    z = -200.0 + 5.0 * np.sin(k / 700.0) + rng.uniform(-0.0005, 0.0005, n)
    body = [f"{'G1 ' if i % 2 == 0 else ''}X{a:.4f} Y{b:.4f} Z{c:.4f}" for i, (a, b, c) in
            enumerate(zip(x.tolist(), y.tolist(), z.tolist()))]
    head = ["%", "O2000 (MILL RASTER)", "G21 G90 G17", f"G0 X{x[0]:.4f} Y{y[0]:.4f} Z{z[0] + 5:.4f}", "G1 F500."]
    return "\n".join(head + body + ["M30"]) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline-root", type=Path, required=True, help="a checkout of the code compared against")
    ap.add_argument("--lines", type=int, default=100_000, help="lines of the generated program")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per checkout (median)")
    ap.add_argument("--mill-lines", type=int, default=20_000, help="lines of the generated mill-xyz program")
    ap.add_argument("--out", type=Path, default=HERE / "benchmarks" / "gcode_words_results.md")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE / "benchmarks"))
    from bench_scale_io import gcode_program
    roots = {"baseline": args.baseline_root.resolve(), "this branch": HERE}
    with tempfile.TemporaryDirectory() as d:
        big = Path(d) / "scale.nc"
        big.write_text(gcode_program(args.lines), encoding="latin-1")
        mill = Path(d) / "mill_raster.nc"
        mill.write_text(mill_program(args.mill_lines), encoding="latin-1")
        jobs = _corpus_jobs() + [["scale.nc", str(big), ["--max-segment-mm", "auto"], ""],
                                 ["mill_pocket.nc", str(HERE / "tests" / "data" / "mill_pocket.nc"), [], "mill-xyz"],
                                 ["mill_raster.nc", str(mill), [], "mill-xyz"]]
        digests = {}
        for label, root in roots.items():
            out = Path(d) / label.replace(" ", "_")
            out.mkdir()
            digests[label] = _run(root, _COMPENSATE, str(out), json.dumps(jobs))
        times = {label: [] for label in roots}
        for label, root in roots.items():  # warm the numba caches (not counted)
            _run(root, _SPEED, str(big))
        for _ in range(args.repeats):
            for label, root in roots.items():
                times[label].append(_run(root, _SPEED, str(big)))
    base, this = digests["baseline"], digests["this branch"]
    rows = []
    for name, _, _, machine in jobs:
        same = base[name] == this[name]
        rows.append(f"| {name} | {machine or 'default (grinder)'} | {this[name][0]} | {len(this[name][1])} | "
                    f"{'identical' if same else '**DIFFERENT**'} |")
    med = {label: {k: statistics.median(t[k] for t in ts) for k in ("read_s", "write_s")} for label, ts in times.items()}
    n_same = sum(base[n] == this[n] for n, *_ in jobs)
    for n, *_ in jobs:
        if base[n][0] != 0:
            print(f"note: {n} exited {base[n][0]} on the baseline")
    text = [
        "## G-code reader: axis words from the machine file", "",
        f"`python benchmarks/bench_gcode_words.py --baseline-root {args.baseline_root} --lines {args.lines} "
        f"--repeats {args.repeats}` on this machine (2 cores, shared). Baseline: `{args.baseline_root}`.", "",
        f"**Bytes**: `volcomp compensate --method exact` outputs, this branch vs baseline: {n_same} of {len(jobs)} "
        "programs byte-identical (every output file's SHA-256; exit status compared too).", "",
        "| program | machine | exit | files | outputs |", "|---|---|---|---|---|", *rows, "",
        f"`mill_pocket.nc` is `tests/data/mill_pocket.nc`, `mill_raster.nc` a generated {args.mill_lines:,}-line "
        "`G1 X Y Z` program (`mill_program`), both on `mill-xyz` with the truth element set of `volcomp simulate "
        "--machine mill-xyz --seed 1`: this branch reads them block-wise (three axis words, none kept), the "
        "baseline line by line.", "",
        f"**Speed** (the block-wise fast path, {args.lines:,} lines; CPU s, median of {args.repeats}, fresh process "
        "each, interleaved):", "",
        "| code | read (parse_program) | write (render_table) | read+write |", "|---|---|---|---|",
        *(f"| {label} | {m['read_s']:.3f} | {m['write_s']:.3f} | {m['read_s'] + m['write_s']:.3f} |"
          for label, m in med.items()),
        "", f"Ratio this branch / baseline, read+write: "
            f"{(med['this branch']['read_s'] + med['this branch']['write_s']) / (med['baseline']['read_s'] + med['baseline']['write_s']):.3f}"
            f" (read {med['this branch']['read_s'] / med['baseline']['read_s']:.3f}, "
            f"write {med['this branch']['write_s'] / med['baseline']['write_s']:.3f}).", "",
    ]
    from errormap import io as eio
    with eio.atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(text))
    print("\n".join(text))
    return 0 if n_same == len(jobs) else 1


if __name__ == "__main__":
    raise SystemExit(main())
