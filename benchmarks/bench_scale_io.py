"""Benchmark : reading a large CSV tool path, the pyarrow fast path of
``errormap.io.read_table`` against the per-row reader, side by side in one run.

The file: ``--rows`` rows of ``x_mm,z_mm,a_deg`` (random over the strokes, 9 significant
digits, as ``write_csv`` writes them) with a comment header. Timed: ``read_table`` plus
``Table.float`` of the three columns (what ``volcomp compensate`` does with a CSV path);
median of ``--repeats`` runs each, alternating. The per-row reader is forced by raising
``FAST_MIN_ROWS`` above the row count. Values are checked equal bit for bit.

    python benchmarks/bench_scale_io.py --rows 1000000 --repeats 3

``--lines N`` : a N-line G-code program through ``volcomp compensate --method exact``
end to end, with an element-set (HTM) model and with a learned model. The program
(:func:`gcode_program`) is CAM-style: ``N.. G1 X.. Z.. A..`` and modal ``N.. X.. Z.. A..``
lines (4 decimals), an F word every 1,000 lines, a comment line every 5,000, a header
(``%``, ``O`` line, ``G21 G90 G18 G94``, a kept ``G0``) and ``M5 M30 %``; X sweeps the stroke
back and forth 0.02 mm a line, Z a slow sine, A 0.05° a line (unwrapped): about 0.035 mm a
move, one vertex each under the default ``--max-segment-mm auto``. Two runs per model, each a
fresh process: (1) the command itself (``python -m compensation.cli compensate``): wall time
and peak RSS (``os.wait4``); (2) the same steps as the command, timed stage by stage
(:func:`stage_run`: the functions ``compensate`` calls, in its order). With
``--baseline-root DIR`` the stage run is repeated on another checkout (e.g. main before this
work) at ``--baseline-lines`` lines, side by side. The learned model is fitted here (the
paper's network, ``--train-iters`` LM iterations on an 11³ grid of the element set's field;
timing only, its accuracy is not the subject) unless ``--learned DIR`` names a saved one.

    python benchmarks/bench_scale_io.py --rows 0 --lines 1000000 --baseline-root /work/main --baseline-lines 100000
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import errormap.io as eio
from errormap.machine import load_machine
from errormap.simulator import random_axes

COLS = ("x_mm", "z_mm", "a_deg")


def read(path, fast: bool):
    eio.FAST_MIN_ROWS = 2000 if fast else 10**12
    t0, c0 = time.perf_counter(), time.process_time()
    t = eio.read_table(path)
    v = np.stack([t.float(c) for c in COLS], axis=1)
    return time.perf_counter() - t0, time.process_time() - c0, v


def gcode_program(n_lines: int, seed: int = 0) -> str:
    """The benchmark's G-code program, ``n_lines`` lines (see the module docstring)."""
    rng = np.random.default_rng(seed)
    n = n_lines - 8
    k = np.arange(n)
    period = 8000
    ph = (k % (2 * period)) / period
    x = 20.0 + 160.0 * np.where(ph < 1, ph, 2 - ph)
    z = 30.0 + 20.0 * np.sin(2 * np.pi * k / 50000.0) + rng.uniform(-0.0005, 0.0005, n)
    a = 0.05 * k
    body = [f"N{10 * (i + 1)} G1 X{xx:.4f} Z{zz:.4f} A{aa:.4f}" if i % 2 == 0 else f"N{10 * (i + 1)} X{xx:.4f} Z{zz:.4f} A{aa:.4f}"
            for i, (xx, zz, aa) in enumerate(zip(x.tolist(), z.tolist(), a.tolist()))]
    for i in range(0, n, 1000):
        body[i] += f" F{200 + (i // 1000) % 7 * 10}."
    for i in range(500, n, 5000):
        body[i] = f"(pass {i // 5000})"
    head = ["%", "O1000 (SCALE BENCH)", "G21 G90 G18 G94", f"G0 X{x[0]:.4f} Z{z[0] + 5:.4f} A0.", "G1 F200."]
    return "\n".join(head + body + ["M5", "M30", "%"]) + "\n"


STAGES = ("startup", "read+parse+plan", "field load", "replan auto", "solve", "guards", "render", "write")


def stage_run(prog, model, out_dir) -> dict:
    """The steps of ``volcomp compensate --method exact`` on one file (compensation/app/workflows/
    compensate.py, in its order; the solve through ``compensation.batch.solve_batch`` where the
    checkout has it), timed; seconds per stage, points, peak RSS (MB)."""
    import resource
    t0, c0 = time.perf_counter(), time.process_time()
    try:  # the application wing; a checkout from before it (--baseline-root) has the old places
        from compensation.app.commands import compensate  # noqa: F401  (what the command loads)
    except ImportError:
        from compensation.commands import compensate  # noqa: F401
    try:  # the command solves through the chunk plan (compensation.batch) since the cluster work
        from compensation.batch import solve_batch
    except ImportError:
        solve_batch = None
    for where in ("compensation.solvers.threads", "compensation.app.reports.methods", "compensation.report"):
        try:
            small_batch_threads = __import__(where, fromlist=["small_batch_threads"]).small_batch_threads
            break
        except (ImportError, AttributeError):
            continue
    from compensation import guards
    from compensation.compensate import load_model
    from compensation.pathio import align_turns, read_path, render_compensated, replan, write_outputs
    from compensation.solvers import solve
    from errormap.machine import load_machine
    t = {"startup": time.perf_counter() - t0}
    cpu = {"startup": time.process_time() - c0}
    last_cpu = [time.process_time()]

    def lap(name, since):
        now, c = time.perf_counter(), time.process_time()
        t[name], cpu[name] = now - since, c - last_cpu[0]
        last_cpu[0] = c
        return now

    now = time.perf_counter()
    machine = load_machine(None, expect_kind="grinder")
    try:  # the generated programs are in machine coordinates (said so where the checkout takes it)
        from compensation.nc_state import MACHINE, read_work_offsets
        frame = {"work_offsets": read_work_offsets(MACHINE)}
    except ImportError:  # a checkout from before work offsets (--baseline-root)
        frame = {}
    tp = read_path(prog, machine, rapids="keep", block_delete=None, arc_tolerance_um=0.5, **frame)
    now = lap("read+parse+plan", now)
    field = load_model(model, machine)
    now = lap("field load", now)
    tp = replan(tp, machine, max_segment_mm="auto", field=field)
    now = lap("replan auto", now)
    if solve_batch is not None:
        res = solve_batch("exact", field, machine, [tp], seed=0)[0]
    else:
        with small_batch_threads("exact", len(tp)):
            res = solve("exact", field, tp.targets_mm, machine, target_axes=tp.axes)
    now = lap("solve", now)
    res.axes = np.array(res.axes, dtype=float)
    res.axes[:, 2] = align_turns(res.axes[:, 2], tp.axes[:, 2])
    report = guards.check(res, machine, field, allow=(), target_axes=tp.axes)
    now = lap("guards", now)
    text = render_compensated(tp, res.axes, res.commands_mm, comments=[])
    now = lap("render", now)
    write_outputs([(tp, Path(out_dir) / Path(prog).name, text)])
    lap("write", now)
    return {"stages_s": t, "stages_cpu_s": cpu, "points": len(tp), "blocking": sorted(report.blocking),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _child(cmd, root=None):
    """Run ``cmd`` (a list) in a fresh process with ``root`` first on PYTHONPATH; wall s and stdout."""
    env = dict(os.environ)
    if root:
        env["PYTHONPATH"] = str(root)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{cmd} exited {p.returncode}: {p.stderr[-2000:]}")
    return wall, p.stdout


def _cli_run(prog, model, out_dir, root):
    """``volcomp compensate`` itself: wall s and peak RSS MB (``os.wait4``, as /usr/bin/time -v)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(root)
    cli = "compensation.app.cli" if (Path(root) / "compensation" / "app" / "cli.py").is_file() else "compensation.cli"
    cmd = [sys.executable, "-m", cli, "compensate", str(prog), "--model", str(model),
           "--method", "exact", "--out", str(out_dir), "--force"]
    if (Path(root) / "compensation" / "nc_state.py").is_file():  # a revision that takes the program's frame
        cmd += ["--work-offsets", "machine"]  # the generated programs are in machine coordinates
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    out = p.stdout.read()
    p.stdout.close()
    code = os.waitstatus_to_exitcode(status)
    if code not in (0, 3):
        raise RuntimeError(f"{' '.join(cmd)} exited {code}")
    return {"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "peak_rss_mb": ru.ru_maxrss / 1024, "exit": code,
            "stdout": out.strip().splitlines()[:1]}


def _stage_child(prog, model, out_dir, root):
    cmd = [sys.executable, os.path.abspath(__file__), "--_stage", str(prog), str(model), str(out_dir)]
    wall, out = _child(cmd, root)
    res = json.loads(out.strip().splitlines()[-1])
    res["wall_s"] = wall
    return res


def _learned_model(tmp, elements_path, iters):
    from errormap.chain_elements import ChainElementSet
    from errormap.featurepoints import FeaturePoints
    from errormap.chain_field import ChainField
    from errormap.simulator import volume_grid
    from training.trainers import fit_field
    m = load_machine()
    f = ChainField(m, ChainElementSet.load(elements_path, m))
    grid = volume_grid(m, (11, 11, 11))
    val = random_axes(m, 2000, np.random.default_rng(1))
    fit = fit_field(FeaturePoints(grid, f.predict(grid), {}), trainer="lm", max_iter=iters, track=False,
                    validation=(val, f.predict(val)), quiet=True, select_best=False)
    out = Path(tmp) / "learned"
    fit.field.save(out)
    return out, fit.metrics.get("val_max_um")


def gcode_section(args, tmp) -> str:
    from errormap.simulator import random_truth
    here = Path(__file__).resolve().parent.parent
    m = load_machine()
    el_path = Path(tmp) / "elements.json"
    random_truth(m, 0).elements.save(el_path)
    if args.learned:
        learned, val_um = Path(args.learned), None
    else:
        learned, val_um = _learned_model(tmp, el_path, args.train_iters)
    models = [("element set (HTM)", el_path), ("learned (paper MLP 10-15-25-15-10)", learned)]
    sizes = [(args.lines, here)]
    if args.baseline_root:
        sizes.insert(0, (args.baseline_lines, Path(args.baseline_root)))
        sizes.insert(1, (args.baseline_lines, here))
    rows = []
    load = os.getloadavg()
    for n, root in sizes:
        prog = Path(tmp) / f"prog{n}.nc"
        if not prog.exists():
            prog.write_text(gcode_program(n), encoding="latin-1")
        for name, model in models:
            out = Path(tmp) / f"out_{len(rows)}"
            out.mkdir()
            st = _stage_child(prog, model, out, root)
            top = n == args.lines and root == here  # the command itself: at --lines, this checkout
            cli = _cli_run(prog, model, Path(tmp) / f"cli_{len(rows)}", root) if args.cli and top else None
            rows.append({"lines": n, "root": str(root), "model": name, "stage": st, "cli": cli,
                         "mb": prog.stat().st_size / 1e6})
            print(json.dumps(rows[-1]), flush=True)
    load_end = os.getloadavg()
    cmdline = "python benchmarks/bench_scale_io.py " + " ".join(sys.argv[1:])
    lines = ["## G-code end to end: `volcomp compensate --method exact`", "",
             f"`{cmdline}` on this machine ({os.cpu_count()} cores, shared; load average "
             f"{load[0]:.1f} at the start, {load_end[0]:.1f} at the end). Program: `gcode_program` of the script "
             "(CAM-style `N.. G1 X.. Z.. A..` lines, ~0.035 mm moves, one vertex each under `--max-segment-mm auto`); "
             "models: the element set `random_truth(0)` and "
             + (f"a learned field fitted to it ({args.train_iters} LM iterations, validation max {val_um:.3g} um; "
                "timing only)" if val_um is not None else f"the learned model {learned}")
             + ". Each run is a fresh process; stages are the command's own steps in its order "
             "(`stage_run`), the end-to-end row is the command itself (`python -m compensation.app.cli compensate`), "
             "wall time, CPU time (user + system) and peak RSS from `os.wait4`. Each cell: wall s (CPU s); on a "
             "shared machine wall time waits for the cores, so CPU time is the steadier figure. One run each "
             "(no repeats: the load varies by more than the repeat spread).", "",
             "| code | lines | model | " + " | ".join(STAGES) + " | stages total | peak RSS (MB) | command: wall (CPU) s | command peak RSS (MB) |",
             "|---" * (len(STAGES) + 7) + "|"]
    for r in rows:
        st, cp = r["stage"]["stages_s"], r["stage"]["stages_cpu_s"]
        code = "this branch" if Path(r["root"]).resolve() == here else f"`{r['root']}`"
        cli = r["cli"]
        lines.append(f"| {code} | {r['lines']:,} | {r['model']} | " + " | ".join(f"{st[s]:.2f} ({cp[s]:.2f})" for s in STAGES)
                     + f" | {sum(st.values()):.1f} ({sum(cp.values()):.1f}) | {r['stage']['peak_rss_mb']:.0f} | "
                     + (f"{cli['wall_s']:.1f} ({cli['cpu_s']:.1f}) | {cli['peak_rss_mb']:.0f} |" if cli else "— | — |"))
    lines += ["", f"Points solved: {', '.join(sorted({str(r['stage']['points']) for r in rows}))}; "
              f"guards blocking: {sorted({g for r in rows for g in r['stage']['blocking']}) or 'none'}."]
    return "\n".join(lines) + "\n"


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "--_stage":
        print(json.dumps(stage_run(*sys.argv[2:5])))
        return
    ap = argparse.ArgumentParser()
    ap.add_argument("--lines", type=int, default=0, help="G-code lines (0: skip the G-code section)")
    ap.add_argument("--baseline-root", default=None, help="another checkout to time at --baseline-lines")
    ap.add_argument("--baseline-lines", type=int, default=100_000)
    ap.add_argument("--learned", default=None, help="a saved learned model folder (default: fit one)")
    ap.add_argument("--train-iters", type=int, default=20)
    ap.add_argument("--no-cli", dest="cli", action="store_false", help="stage runs only")
    ap.add_argument("--gcode-out", default=os.path.join(os.path.dirname(__file__), "scale_gcode_results.md"))
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=1, help="files (one per seed), each timed")
    ap.add_argument("--jobs", type=int, default=1, help="unused: the reads are timed one at a time")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "scale_io_results.md"))
    args = ap.parse_args()
    if args.lines:
        with tempfile.TemporaryDirectory() as tmp:
            text = gcode_section(args, tmp)
        print(text)
        with eio.atomic_write(args.gcode_out, "w", encoding="utf-8") as fh:
            fh.write(text)
    if not args.rows:
        return
    m = load_machine()
    rows = []
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            axes = random_axes(m, args.rows, np.random.default_rng(seed))
            path = os.path.join(tmp, f"path{seed}.csv")
            eio.write_csv(path, dict(zip(COLS, axes.T)), header_comments=["machine: default grinder"])
            size_mb = os.path.getsize(path) / 1e6
            fast, slow, fast_cpu, slow_cpu = [], [], [], []
            for _ in range(args.repeats):
                tf, cf, vf = read(path, True)
                ts, cs, vs = read(path, False)
                fast.append(tf), slow.append(ts), fast_cpu.append(cf), slow_cpu.append(cs)
            assert np.array_equal(vf, vs), "fast and per-row readers disagree"
            rows.append((seed, size_mb, statistics.median(slow), statistics.median(fast), np.array_equal(vf, vs),
                         statistics.median(slow_cpu), statistics.median(fast_cpu)))
            print(rows[-1])
    lines = ["## CSV read, pyarrow fast path vs per-row reader", "",
             f"`python benchmarks/bench_scale_io.py --rows {args.rows} --repeats {args.repeats} --seeds {args.seeds}` — "
             f"{args.rows:,} rows x_mm,z_mm,a_deg written by write_csv (%.9g); read_table + Table.float of the 3 columns; "
             f"median of {args.repeats} runs each, alternating in one process; {os.cpu_count()} cores shared with other work "
             f"(load average {load[0]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end). Wall s (CPU s: user + "
             "system of this process, pyarrow's threads included).", "",
             "| seed | file (MB) | per-row reader (s) | pyarrow path (s) | speed-up (wall) | values equal |", "|---|---|---|---|---|---|"]
    for seed, mb, ts, tf, eq, cs, cf in rows:
        lines.append(f"| {seed} | {mb:.0f} | {ts:.2f} ({cs:.2f}) | {tf:.2f} ({cf:.2f}) | {ts / tf:.1f}× | "
                     f"{'bit for bit' if eq else 'NO'} |")
    text = "\n".join(lines) + "\n"
    print(text)
    with eio.atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)


if __name__ == "__main__":
    main()
