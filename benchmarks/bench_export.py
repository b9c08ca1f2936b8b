"""Export benchmark: what each controller table leaves, against the model and against the truth.

    python benchmarks/bench_export.py [--seeds 1] [--jobs 1] [--check-points 2000]
                                      [--tolerances 4,2,1,0.5] [--out benchmarks/export_results.md]

The user's path, per seed s (truth seed 100 + s):
truth = ``random_truth(default grinder, 100 + s, effects=("reversal", "interaction"))`` (8 μm Z
backlash; X positioning that grows with Z: a coupling no per-axis table and no 23-element model
holds); model = ``identify(simulate_sweeps(truth, noise 2 μm, seed s))`` (the 23 elements from
tracker sweeps); diagnosed backlash = ``diagnose`` on 400 simulated check measurements (noise
1 μm, seed s) against that model. Never the truth's own numbers.

For each table the controller is re-simulated (:func:`compensation.export.check_export`) on the
default flute (2,800 points) and ``--check-points`` random points over the volume, and the
**model residual** (against the identified model) and the **true residual** (against the
simulated truth) are reported as max / p95 of the per-point norm, beside the baselines: no
compensation, and the model's own exact compensation (``volcomp compensate --method exact``).
Table size is the bytes of the files written and the number of values.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from compensation import export as ex  # noqa: E402
from errormap.diagnosis.checks import CheckData  # noqa: E402
from errormap.diagnosis.pipeline import diagnose  # noqa: E402
from errormap.htm import HTMField  # noqa: E402
from errormap.identification import identify  # noqa: E402
from errormap.io import atomic_write, write_json  # noqa: E402
from errormap.machine import load_machine  # noqa: E402
from errormap.simulator import random_truth  # noqa: E402
from errormap.sweeps import simulate_sweeps  # noqa: E402

FLUTE_REGION = {"x_mm": (90.0, 116.0), "z_mm": (0.3, 0.3)}
"""The default flute's axis box (x 90..115.3 mm, z = 0.3 mm): the per-joint fitting region."""


def run_seed(seed: int, tolerances, n_volume: int) -> dict:
    m = load_machine()
    truth = random_truth(m, 100 + seed, effects=("reversal", "interaction"))
    el = identify(simulate_sweeps(truth, noise_um=2.0, seed=seed), m).elements_
    model = ex.ModelError(m, el)
    sets = ex.check_sets(m, n_volume, seed)
    cache = {}
    rows = []

    def one(kind, label, table, sizing, mdl, cch):
        with tempfile.TemporaryDirectory() as tmp:
            files = ex.write_table(table, tmp, m, "bench")
            size = ex.table_bytes(files)
        t0 = time.perf_counter()
        chk = ex.check_export(table, mdl, m, sets, truth, cch)
        rows.append({"seed": seed, "format": kind, "label": label, "sizing": sizing, "bytes": size,
                     "values": table.n_values(), "check": chk, "check_s": time.perf_counter() - t0})

    for tol in tolerances:
        for fmt in ("grid", "iso-tables"):
            table, sizing = ex.build_table(fmt, model, m, tol, sets)
            one(fmt, f"tol {tol:g}", table, sizing, model, cache)
    for label, region in (("whole strokes", None), ("flute region", FLUTE_REGION)):
        table, sizing = ex.build_table("linuxcnc", model, m, 1.0, sets, region=region, seed=seed)
        one("linuxcnc", label, table, sizing, model, cache)
    # the diagnosed backlash: the user's path (check measurements -> diagnose -> diagnosis effects)
    checks = CheckData.from_columns(truth.check_measurements(n=400, noise_um=1.0, seed=seed))
    d = diagnose(m, HTMField(m, el), checks)
    with tempfile.TemporaryDirectory() as tmp:
        p = write_json(Path(tmp) / "diagnosis.json", {"effects": d.effects})
        try:
            back, left = ex.backlash_from_diagnosis(p)
            diag_note = f"diagnosed: {back} (left out: {left})"
        except Exception as exc:  # the refusal itself is a result worth reporting
            back, diag_note = {}, f"diagnosis not usable by a per-joint table: {exc}"
    if back:
        mdl = ex.ModelError(m, el, back)
        table, sizing = ex.build_table("linuxcnc", mdl, m, 1.0, sets, region=FLUTE_REGION, seed=seed)
        one("linuxcnc", "flute region + diagnosed backlash", table, sizing, mdl, {})
    return {"seed": seed, "rows": rows, "diagnosis": diag_note,
            "effects": [f"{e['kind']}({e['axis']}) on {e['element']}" for e in d.effects]}


def fmt_pair(s):
    return f"{s['max_um']:.3g} / {s['p95_um']:.3g}"


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--check-points", type=int, default=2000)
    ap.add_argument("--tolerances", default="4,2,1,0.5")
    ap.add_argument("--out", default=str(Path(__file__).with_name("export_results.md")))
    args = ap.parse_args(argv)
    tols = [float(t) for t in args.tolerances.split(",")]
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(run_seed, range(args.seeds), [tols] * args.seeds, [args.check_points] * args.seeds))
    else:
        results = [run_seed(s, tols, args.check_points) for s in range(args.seeds)]
    wall = time.perf_counter() - t0
    cmd = "python benchmarks/bench_export.py " + " ".join(argv if argv is not None else sys.argv[1:])
    L = ["## Export: controller tables checked against the model and the truth", "",
         f"`{cmd.strip()}` — {platform.machine()}, {os.cpu_count()} cores shared with other jobs, {wall:.0f} s. "
         "Default grinder; truth `random_truth(100 + seed, effects=(reversal, interaction))` (8 μm Z backlash, "
         "6 μm X-with-Z coupling at the far corner); model = the 23 elements identified from simulated tracker "
         "sweeps (2 μm noise); backlash diagnosed from 400 simulated check measurements. Residuals: per-point "
         "norm, **max / p95 μm**; *model* = against the identified model, *true* = against the simulated truth. "
         f"Flute: the default 7-turn path (2,800 points); volume: {args.check_points} uniform random axis points "
         "(points the model itself cannot compensate, outside the 250 μm ball near the A axis, are excluded; "
         "counts below).", ""]
    for res in results:
        s = res["seed"]
        base = res["rows"][0]["check"]
        L += [f"### seed {s}", "",
              "| baseline | flute model | flute true | volume model | volume true |", "|---|---|---|---|---|",
              f"| no compensation | {fmt_pair(base['flute']['baseline_none']['model'])} | "
              f"{fmt_pair(base['flute']['baseline_none']['true'])} | {fmt_pair(base['volume']['baseline_none']['model'])} | "
              f"{fmt_pair(base['volume']['baseline_none']['true'])} |",
              f"| exact compensation with the model | {fmt_pair(base['flute']['baseline_exact']['model'])} | "
              f"{fmt_pair(base['flute']['baseline_exact']['true'])} | {fmt_pair(base['volume']['baseline_exact']['model'])} | "
              f"{fmt_pair(base['volume']['baseline_exact']['true'])} |", "",
              f"Volume points excluded: {base['volume']['excluded']}. Diagnosis selected: {', '.join(res['effects']) or 'nothing'}; "
              f"{res['diagnosis']}.", "",
              "| format | setting | size (files) | values | sizing | flute model | flute true | volume model | volume true |",
              "|---|---|---|---|---|---|---|---|---|"]
        for r in res["rows"]:
            z = r["sizing"]
            if r["format"] == "grid":
                sz = "nodes {} (spacing {:.3g} mm, {:.3g} mm, {:.3g}°)".format("×".join(map(str, z["counts"])), *z["spacing"])
            elif r["format"] == "iso-tables":
                sz = f"{z['rows_per_axis']} rows per axis"
            else:
                sz = f"{z['points_per_joint']} points per joint"
            c = r["check"]
            L.append(f"| {r['format']} | {r['label']} | {r['bytes'] / 1024:.1f} KiB | {r['values']} | {sz} | "
                     f"{fmt_pair(c['flute']['model'])} | {fmt_pair(c['flute']['true'])} | "
                     f"{fmt_pair(c['volume']['model'])} | {fmt_pair(c['volume']['true'])} |")
        L.append("")
    L += ["Reading it: the grid and the ISO component tables (with a controller that rebuilds the rigid-body "
          "model from them) meet their tolerance on the model; their true residual is then dominated by what "
          "the identified 23-element model itself misses (identification noise, the 4 μm half-backlash, the "
          "X-with-Z coupling), the same as the model's own exact compensation. The per-joint (LinuxCNC) tables "
          "hold one function per joint: every coupling between axes is lost — the A correction that the flute "
          "needs depends strongly on Z (ρ = 0.1 mm + z), so a table averaged over the whole strokes is worse "
          "than no compensation, and one fitted over the flute's region leaves the difference between the two "
          "rows 'flute region' and 'exact compensation' on the flute; on the rest of the volume it is "
          "unusable. That difference is the cost of the coupling terms on the flute.", ""]
    text = "\n".join(L) + "\n"
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)
    write_json(Path(args.out).with_suffix(".json"), results)
    print(text)


if __name__ == "__main__":
    main()
