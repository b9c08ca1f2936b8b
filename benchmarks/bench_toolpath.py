"""True residual ALONG long moves, with and without segment splitting.

What the controller runs between two written vertices is a straight line in the axes; the
compensation is exact only at the vertices. This benchmark drives a simulated truth
machine along every written move, densely (``--samples`` points per written segment),
and measures the TRUE residual against the target at the same parameter of the nominal
move (the program's own path: linear in the axes between its points).

The error field given to the solver is the truth's own error (its 23 elements plus the
undeclared effects ``pitch``, ``worm`` and ``interaction``, evaluated at 20 °C with positive
approach), so every μm left is the linearisation between vertices, which is what splitting
addresses; the model's own error is another benchmark's subject (``benchmarks/suite/solvers.py``).
Two truth shapes per seed: the element profiles alone, and with the three effects
(harmonics along X and A the element profiles do not have).

Paths:

* **flute** — the paper's variable-helix flute (7 turns) written as G-code at
  400 (the default), 40 and 10 points per turn: the coarser, the longer each G1 move;
* **straight** — single 20 mm G1 moves across the X stroke (X = x0 → x0 + 20 for
  x0 = 0, 20, …, 180) at Z = 5 mm and A = 0°, 90°.

Per condition: uncompensated (the nominal program on the truth), compensated at the
program's points only (``--max-segment-mm none``: the plain approach), compensated with
the default ``auto`` segments (chord tolerance 0.5 μm), and with fixed 1 mm segments.

    python benchmarks/bench_toolpath.py --seeds 3 --jobs 2
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from errormap.field import CalibratedVolume
from errormap.io import atomic_write, write_json

HERE = Path(__file__).resolve().parent
SPLITS = (("none", None), ("auto", "auto"), ("1 mm", 1.0))
EFFECTS = ("pitch", "worm", "interaction")


class TruthField:
    """The truth machine's error as a field (predict μm), calibrated over the strokes."""

    def __init__(self, truth):
        self.truth = truth
        self.calibrated_volume = CalibratedVolume(truth.machine.stroke_lo, truth.machine.stroke_hi)
        self.capabilities = frozenset()

    def predict(self, axes):
        axes = np.asarray(axes, dtype=float)
        return self.truth.spatial_error(axes, **self.truth.default_conditions(len(axes)))


def _programs(machine):
    from compensation.pathio import write_axes_gcode
    from compensation.toolpath import flute_path
    out = {}
    tmp = Path(tempfile.mkdtemp(prefix="bench_toolpath_"))
    for ppt in (400, 40, 10):
        out[f"flute, {ppt} pts/turn"] = write_axes_gcode(tmp / f"flute{ppt}.nc",
                                                        flute_path(points_per_turn=ppt).axes(machine))
    for a in (0.0, 90.0):
        lines = ["G21 G90 G94"]
        for x0 in range(0, 200, 20):
            lines += [f"G0 X{x0} Z5 A{a:g}", f"G1 X{x0 + 20} F300"]
        lines.append("M30")
        p = tmp / f"straight_a{a:g}.nc"
        p.write_text("\n".join(lines) + "\n")
        out[f"straight 20 mm, A {a:g}°"] = p
    return out


def along_moves_um(truth, tp, command_axes, samples: int) -> np.ndarray:
    """|true residual| (μm) at ``samples`` points along every written segment, flattened.

    ``tp``: the planned G-code tool path; ``command_axes`` (n, 3) what is written at its
    vertices (the nominal axes for the uncompensated program). A segment runs from the
    previous vertex of the same move (or the move's nominal start) to the vertex.
    """
    from compensation.gcode import move_points
    job = tp.source
    s = np.linspace(0.0, 1.0, samples)[1:]
    res, k = [], 0
    prev_cmd = None
    for m, t in zip(job.compensated_moves, job.params):
        t_prev = np.concatenate([[0.0], t[:-1]])
        cmds = command_axes[k:k + len(t)]
        k += len(t)
        if not m.start_known or prev_cmd is None:
            prev_cmd = cmds[-1]
            continue
        starts = np.vstack([prev_cmd[None], cmds[:-1]])
        cmd = starts[:, None, :] + s[None, :, None] * (cmds - starts)[:, None, :]
        tt = t_prev[:, None] + s[None, :] * (t - t_prev)[:, None]
        target = move_points(m, tt.ravel())
        from errormap.chain_kernel import forward
        reached = truth.tool_point(cmd.reshape(-1, 3), **truth.default_conditions(cmd.shape[0] * cmd.shape[1]))
        res.append(1e3 * np.linalg.norm(reached - forward(truth.machine, target), axis=1))
        prev_cmd = cmds[-1]
    return np.concatenate(res)


def run_seed(seed: int, samples: int) -> list:
    from compensation.pathio import read_path, replan
    from compensation.nc_state import MACHINE, read_work_offsets
    from compensation.solvers import solve
    from errormap.machine import load_machine
    from errormap.simulator import random_truth
    machine = load_machine()
    rows = []
    for shape, effects in (("elements", ()), ("elements + pitch, worm, interaction", EFFECTS)):
        truth = random_truth(machine, seed, effects=effects)
        field = TruthField(truth)
        for name, path in _programs(machine).items():
            base = read_path(path, machine, work_offsets=read_work_offsets(MACHINE))  # machine coordinates
            r0 = along_moves_um(truth, base, base.axes, samples)
            rows.append({"seed": seed, "truth": shape, "path": name, "split": "uncompensated",
                         "vertices": len(base), "max_um": float(r0.max()), "mean_um": float(r0.mean()),
                         "p99_um": float(np.percentile(r0, 99)), "max_segment_mm": None, "seconds": 0.0})
            for label, seg in SPLITS:
                t0 = time.perf_counter()
                tp = replan(base, machine, max_segment_mm=seg, field=field)
                sol = solve("exact", field, tp.targets_mm, machine, target_axes=tp.axes)
                secs = time.perf_counter() - t0
                q = np.round(sol.axes, 6)
                r = along_moves_um(truth, tp, q, samples)
                rows.append({"seed": seed, "truth": shape, "path": name, "split": label, "vertices": len(tp),
                             "max_um": float(r.max()), "mean_um": float(r.mean()),
                             "p99_um": float(np.percentile(r, 99)),
                             "max_segment_mm": tp.source.max_segment_mm, "seconds": secs})
    return rows


def _table(rows, truth_shape):
    paths = list(dict.fromkeys(r["path"] for r in rows))
    splits = ["uncompensated"] + [s for s, _ in SPLITS]
    out = [f"**Truth: {truth_shape}** (medians over seeds; max / mean μm of the TRUE residual along the moves; "
           "vertices written; auto segment length)", "",
           "| path | " + " | ".join(splits) + " | auto max, worst seed | vertices none / auto / 1 mm | auto segment mm |",
           "|---|" + "---:|" * (len(splits) + 3)]
    for p in paths:
        sel = [r for r in rows if r["path"] == p and r["truth"] == truth_shape]
        cells = []
        for s in splits:
            rs = [r for r in sel if r["split"] == s]
            cells.append(f"{np.median([r['max_um'] for r in rs]):.3g} / {np.median([r['mean_um'] for r in rs]):.3g}")
        verts = " / ".join(f"{int(np.median([r['vertices'] for r in sel if r['split'] == s]))}" for s, _ in SPLITS)
        auto = np.median([r["max_segment_mm"] for r in sel if r["split"] == "auto"])
        worst = max(r["max_um"] for r in sel if r["split"] == "auto")
        out.append(f"| {p} | " + " | ".join(cells) + f" | {worst:.3g} | {verts} | {auto:.3g} |")
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="truth seeds 0..N-1 (default 3)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--samples", type=int, default=17, help="samples per written segment, ends included (default 17)")
    ap.add_argument("--out", default=str(HERE / "toolpath_results"), help="output stem (.md and .json)")
    ap.add_argument("--report-only", action="store_true", help="rewrite the .md from the .json of a previous run")
    args = ap.parse_args(argv)
    stem = Path(args.out)
    if args.report_only:
        doc = json.loads(stem.with_suffix(".json").read_text())
        write_md(stem, doc["rows"], doc["seeds"], doc.get("jobs", args.jobs), doc["samples"], doc["wall_s"])
        return
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as ex:
            parts = list(ex.map(run_seed, range(args.seeds), [args.samples] * args.seeds))
    else:
        parts = [run_seed(s, args.samples) for s in range(args.seeds)]
    rows = [r for p in parts for r in p]
    wall = time.perf_counter() - t0
    write_json(stem.with_suffix(".json"), {"seeds": args.seeds, "jobs": args.jobs, "samples": args.samples,
                                           "wall_s": wall, "rows": rows})
    write_md(stem, rows, args.seeds, args.jobs, args.samples, wall)


def write_md(stem, rows, seeds, jobs, samples, wall):
    shapes = list(dict.fromkeys(r["truth"] for r in rows))
    md = ["# Tool paths: true residual along long moves", "",
          f"`python benchmarks/bench_toolpath.py --seeds {seeds} --jobs {jobs} --samples {samples}` "
          f"({wall:.0f} s on this machine). Truths `random_truth(default grinder, seed)`, seeds 0–{seeds - 1}; "
          "the solver (`exact`) is given the truth's own error, so the residual left is the linearisation "
          "between written vertices alone. Residual: TRUE, sampled at "
          f"{samples} points along every written segment (not only at the vertices) and taken against the "
          "target at the same parameter of the program's own move. Columns: uncompensated program; "
          "compensated at the program's points only (`--max-segment-mm none`, the plain approach); "
          "`auto` segments (the default; chord tolerance 0.5 μm: half for the arc sagitta, half for the "
          "field's curvature, `L = sqrt(8·0.25 μm / κ)`); fixed 1 mm segments.", ""]
    for s in shapes:
        md += [_table(rows, s), ""]

    def worst(path_prefix, split):
        return max(r["max_um"] for r in rows if r["path"].startswith(path_prefix) and r["split"] == split)
    md += ["**Reading.** Compensating only the program's points leaves the error's curvature between them: "
           f"up to {worst('straight', 'none'):.3g} μm along a 20 mm move and {worst('flute, 10', 'none'):.3g} μm "
           "on the flute written at 10 points per turn (worst seed, either truth). With the default `auto` "
           f"segments the worst is {worst('straight', 'auto'):.3g} μm (straight) and "
           f"{max(worst('flute', 'auto'), 0):.3g} μm (flute), inside the 0.25 μm half of the 0.5 μm tolerance "
           "budgeted for it, with far fewer vertices than a fixed 1 mm on the straight moves where the field "
           "is smooth. At the default 400 points per turn the flute's moves are already short (10–13 μm of WCS path), so "
           "splitting changes nothing there.", ""]
    with atomic_write(stem.with_suffix(".md"), "w", encoding="utf-8") as fh:
        fh.write("\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
