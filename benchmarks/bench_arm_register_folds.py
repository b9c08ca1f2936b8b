"""Register's choice inside the registration poses: interleaved folds (pose i in fold i mod k) against blocked folds
(k contiguous runs by pose order), over every (calibration, session) pair of the real pseudo-sessions and of simulated
sessions. For each pair and N registration poses (the session's first N), every candidate is registered on the N poses
and judged on the rest of the session (MEASURED residual, mean position norm, mm); each fold kind's choice is looked up
there (TRUE beside it for the simulated sessions).

    python benchmarks/bench_arm_register_folds.py --real ../shared/data/serial-arms --seeds 3
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_arm_register_sessions import HI, LO, MOVES, SESSIONS, calibrate, moved, session_effect_mm  # noqa: E402
from bench_arm_sessions import NOISE_MM, T_CAL_C, thermal_truth  # noqa: E402

from compensation.model_file import read_model
from compensation.app.workflows.arm_register import candidates_of, plain_of
from errormap.arm_poses import read_arm_poses
from errormap.arm_register import FOLD_KINDS, choose_candidate, fit_frame, registered_point
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.machine import load_machine

NS = (10, 20, 50)
DUMP = None


def pair_rows(chain, cal_json, sess, truth=None) -> list:
    m = read_model(cal_json, chain, family="arm")
    (geo, learner), doc = m.calibration.stages, m.doc
    if (doc.get("across_blocks") or {}).get("learned_carried") is False:
        learner = None
    cands = [(n, g.chain, g.params, lr) for n, g, lr in
             candidates_of(geo, learner, plain_of(chain, doc, cal_json), doc["kept_stage"])]
    out = []
    for n in NS:
        fit, rest = sess.subset(np.arange(n)), sess.subset(np.arange(n, len(sess)))
        meas, true = {}, {}
        for name, ch, p, lr in cands:
            x, _, _, R, _, _ = fit_frame(ch, p, fit, lr)
            pred = registered_point(ch, x, lr, R, rest.q)
            meas[name] = float(np.linalg.norm(rest.xyz_mm - pred, axis=1).mean())
            if truth is not None:
                true[name] = float(np.linalg.norm(truth[n:] - pred, axis=1).mean())
        kept = {k: choose_candidate(cands, fit, fold_kind=k)["kept"] for k in FOLD_KINDS}
        out.append({"n": n, "meas": meas, "true": true, "kept": kept, "best": min(meas, key=meas.get)})
    return out


def report(label, rows):
    print(f"\n{label}: {len(rows) // len(NS)} pairs")
    print("| N | plain | interleaved ships | blocked ships | best candidate (oracle) | pairs blocked < interleaved "
          "/ > | TRUE interleaved / blocked | pairs above plain (interleaved / blocked) |")
    print("|---:|---|---|---|---|---|---|---|")
    for n in NS:
        r = [x for x in rows if x["n"] == n]
        f = (lambda k, key="meas": np.mean([x[key][x["kept"][k]] for x in r]))
        pl = np.mean([x["meas"]["plain geometric LSQ"] for x in r])
        best = np.mean([x["meas"][x["best"]] for x in r])
        lo = sum(x["meas"][x["kept"]["blocked"]] < x["meas"][x["kept"]["interleaved"]] for x in r)
        hi = sum(x["meas"][x["kept"]["blocked"]] > x["meas"][x["kept"]["interleaved"]] for x in r)
        tr = (f"{f('interleaved', 'true'):.4f} / {f('blocked', 'true'):.4f}" if r[0]["true"] else "–")
        above = " / ".join(str(sum(x["meas"][x["kept"][k]] > x["meas"]["plain geometric LSQ"] for x in r))
                           for k in FOLD_KINDS)
        print(f"| {n} | {pl:.4f} | {f('interleaved'):.4f} | {f('blocked'):.4f} | {best:.4f} | {lo} / {hi} | {tr} | "
              f"{above} |", flush=True)
    if DUMP:
        import json
        Path(DUMP).with_suffix(f".{label}.json").write_text(json.dumps(rows))


def run_real(folder):
    for f, m, k in (("ur5_grid.csv", "ur5", 4), ("wam_grid.csv", "wam", 3)):
        chain = load_machine(m)
        data = read_arm_poses(f"{folder}/{f}", chain)
        sess = [moved(data.subset(i), MOVES[j]) for j, i in enumerate(np.array_split(np.arange(len(data)), k))]
        rows = []
        for a in range(k):
            with tempfile.TemporaryDirectory() as td:
                c = calibrate(chain, sess[a], Path(td))
                for s in range(k):
                    if s != a:
                        rows += pair_rows(chain, c["json"], sess[s])
        report(m, rows)


def run_sim(seeds, amp_mm):
    from errormap.arm_simulate import ArmPoses  # noqa: F401
    chain = load_machine("ur5")
    rows = []
    for seed in range(seeds):
        t0 = draw_truth(chain, seed)
        ta = thermal_truth(chain, t0, T_CAL_C, {})
        qa = random_joints(LO, HI, 250, [seed, 10])
        cal = measure(chain, ta, qa, NOISE_MM, [seed, 11])
        cal.xyz_mm = cal.xyz_mm + session_effect_mm(qa, amp_mm)
        with tempfile.TemporaryDirectory() as td:
            c = calibrate(chain, cal, Path(td))
            for s, (temp, mv) in SESSIONS.items():
                tr = thermal_truth(chain, t0, temp, {"base." + k: v for k, v in
                                                      zip(("x_mm", "y_mm", "z_mm", "rz_rad", "ry_rad", "rx_rad"), mv)})
                q = random_joints(LO, HI, 150, [seed, 30 + ord(s)])
                rows += pair_rows(chain, c["json"], measure(chain, tr, q, NOISE_MM, [seed, 40 + ord(s)]),
                                  tr.tool_point(chain, q))
    report("simulated", rows)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--real", default=None)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--dump", default=None, help="write each table's rows as JSON beside this path")
    a = ap.parse_args()
    global DUMP
    DUMP = a.dump
    if a.real:
        run_real(a.real)
    if a.seeds:
        run_sim(a.seeds, 0.05)


if __name__ == "__main__":
    main()
