"""Per session: the plain geometric calibration against what `volcomp register` ships, after registering on 6 / 20 / 50
of the session's poses — through the product's own path (`calibrate` defaults on one session, `register --fit-poses N`
on each other one), on real tracker data split into pseudo-sessions and on simulated multi-session arms.

Real (``--real DIR``, the UR5 and WAM grids): each grid is cut by file order into pseudo-sessions (UR5 4 × 250 poses,
WAM 3 × 72); every session's measured points are moved by a known rigid transform of its own (a tracker set up anew;
the first session's too); each session in turn is calibrated (defaults: 20 % held out, learned stage on) and every
other session registered on its first N poses, judged on the rest of it: MEASURED residual (measured − model), mean
position norm, mm. The rows over all (calibration, session) pairs are the blocked CV over sessions.

Simulated (``--seeds K``): a UR5 (link + base + tool errors, joint sag, 20 µm tracker noise, links expanding
23e-6 / K) measured in four sessions at 20.0 / 21.9 / 18.1 / 22.0 °C, the tracker moved up to 1.3 m and turned up to
0.6 rad between them; session A alone also carries a session-specific effect (a smooth joint-dependent displacement
of ``--effect-mm`` amplitude: a tracker warm-up / fixture effect absent on other days). A is calibrated; B, C, D
registered: TRUE residual = the session's noise-free truth at its held-out joints against the registered model, both
in the session's tracker frame, mean position norm, mm (MEASURED beside it).

    python benchmarks/bench_arm_register_sessions.py --real ../shared/data/serial-arms
    python benchmarks/bench_arm_register_sessions.py --seeds 3
"""
from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numpy as np

from compensation.app.workflows.arm_calibration import ArmCalibrationSettings
from compensation.model_file import read_model
from compensation.app.workflows.arm_run import run_arm_calibration
from compensation.app.workflows.arm_register import run_arm_register
from errormap.arm_calibration import GeometricResult
from errormap.arm_frames import rot as _rot
from errormap.arm_poses import ArmPoses, read_arm_poses, write_arm_poses
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.machine import load_machine

REGISTER_POSES = (6, 20, 50)
MOVES = [(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (812.0, -305.0, 47.0, 0.61, 0.004, -0.003),
         (-1300.0, 420.0, -210.0, -0.53, -0.006, 0.002), (150.0, 990.0, 380.0, 0.21, 0.001, 0.007)]
"""Tracker → base moves per (pseudo-)session: x y z mm, rz ry rx rad."""


def moved(p: ArmPoses, move) -> ArmPoses:
    x, y, z, rz, ry, rx = move
    R = _rot(2, rz) @ _rot(1, ry) @ _rot(0, rx)
    out = p.subset(np.arange(len(p)))
    out.xyz_mm = p.xyz_mm @ R.T + np.array([x, y, z])
    return out


def register_row(chain, cal_json, sess: ArmPoses, d: Path, truth_xyz=None) -> dict:
    """{n: registration figures} of ``cal_json`` registered on ``sess``'s first n poses (the product's path)."""
    f = d / "session.csv"
    write_arm_poses(f, chain, sess)
    row = {}
    for n in REGISTER_POSES:
        out = d / f"reg{n}"
        with contextlib.redirect_stderr(io.StringIO()):
            r = run_arm_register(chain, f, cal_json, out, fit_poses=n)
        cell = {"kept": r["kept"], "meas": {k: v["mean_mm"] for k, v in r["heldout_by_candidate"].items()}}
        if truth_xyz is not None:
            rest = sess.subset(np.arange(n, len(sess)))
            m = read_model(out / "model.json", chain, family="arm")
            plain = GeometricResult.from_dict(chain, m.doc["plain_geometric"])
            geo, lrn = m.calibration.stages
            kept = geo.predict(rest.q) + (0.0 if lrn is None else lrn.predict(rest.q))
            t = truth_xyz[n:]
            cell["true_plain"] = float(np.linalg.norm(t - plain.predict(rest.q), axis=1).mean())
            cell["true_kept"] = float(np.linalg.norm(t - kept, axis=1).mean())
        row[n] = cell
    return row


def calibrate(chain, cal: ArmPoses, d: Path) -> dict:
    write_arm_poses(d / "cal.csv", chain, cal)
    with contextlib.redirect_stderr(io.StringIO()):
        doc = run_arm_calibration(chain, ArmCalibrationSettings(poses=str(d / "cal.csv")), d / "cal")
    own = {s["name"]: s["mean_mm"] for s in doc["stages"] + doc["baselines"]}
    return {"json": d / "cal" / "model.json", "kept": doc["kept_stage"], "own_kept": own[doc["kept_stage"]],
            "own_plain": own["plain geometric LSQ"],
            "carried": (doc.get("across_blocks") or {}).get("learned_carried")}


def fmt(row, key) -> str:
    return " / ".join(format(row[n]["meas"].get(key, float("nan")), ".4f") for n in REGISTER_POSES)


def print_real_rows(arm, a, s, c, row):
    kept = " / ".join(f"{row[n]['kept']}" for n in REGISTER_POSES)
    shipped = " / ".join(format(row[n]["meas"][row[n]["kept"]], ".4f") for n in REGISTER_POSES)
    cand = [k for k in row[REGISTER_POSES[-1]]["meas"] if k != "plain geometric LSQ"]
    print(f"| {arm} | {a} | {s} | {c['kept']} (own {c['own_kept']:.4f}, plain {c['own_plain']:.4f}) | "
          f"{fmt(row, 'plain geometric LSQ')} | " + "; ".join(f"{k}: {fmt(row, k)}" for k in cand)
          + f" | **{shipped}** | {kept} |", flush=True)


def role(name: str) -> str:
    if name in ("plain geometric LSQ", "plain GP on plain LSQ residual", "learned"):
        return {"learned": "geometric + learned stage"}.get(name, name)
    return "volcomp geometric stage alone"


def summary(rows, key="meas"):
    """Blocked CV over sessions: per stage, its mean over every (calibration, session) pair where it is a candidate,
    beside plain's and register's on the same pairs, and on how many pairs it beat plain."""
    print(f"\n| stage ({key}) | pairs | its mean after 6 / 20 / 50 | plain on the same pairs | register ships | "
          "pairs it beat plain (6 / 20 / 50) |")
    print("|---|---:|---|---|---|---|")
    roles = sorted({role(k) for r in rows for k in r[REGISTER_POSES[-1]][key]})
    for ro in roles:
        sel = [(r, next(k for k in r[REGISTER_POSES[-1]][key] if role(k) == ro)) for r in rows
               if any(role(k) == ro for k in r[REGISTER_POSES[-1]][key])]
        m = [np.mean([r[n][key][k] for r, k in sel]) for n in REGISTER_POSES]
        p = [np.mean([r[n][key]["plain geometric LSQ"] for r, _ in sel]) for n in REGISTER_POSES]
        sh = [np.mean([r[n][key][r[n]["kept"]] for r, _ in sel]) for n in REGISTER_POSES]
        w = [sum(r[n][key][k] < r[n][key]["plain geometric LSQ"] for r, k in sel) for n in REGISTER_POSES]
        print(f"| {ro} | {len(sel)} | " + " / ".join(f"{x:.4f}" for x in m) + " | " + " / ".join(f"{x:.4f}" for x in p)
              + " | " + " / ".join(f"{x:.4f}" for x in sh) + " | " + " / ".join(map(str, w)) + " |", flush=True)


def run_real(folder, rotate: bool):
    print("| arm | calibrated on | session | kept stage (own held-out, plain) | plain after 6 / 20 / 50 | "
          "candidates after 6 / 20 / 50 | register ships | kept by register |")
    print("|---|---|---|---|---|---|---|---|")
    for f, m, k in (("ur5_grid.csv", "ur5", 4), ("wam_grid.csv", "wam", 3)):
        rows = []
        chain = load_machine(m)
        data = read_arm_poses(f"{folder}/{f}", chain)
        cut = np.array_split(np.arange(len(data)), k)
        sess = [moved(data.subset(i), MOVES[j]) for j, i in enumerate(cut)]
        for a in range(k if rotate else 1):
            with tempfile.TemporaryDirectory() as td:
                t0 = time.process_time()
                c = calibrate(chain, sess[a], Path(td))
                for s in range(k):
                    if s != a:
                        sd = Path(td) / f"s{s}"
                        sd.mkdir()
                        rows.append(register_row(chain, c["json"], sess[s], sd))
                        print_real_rows(m, "ABCD"[a], "ABCD"[s], c, rows[-1])
                print(f"<!-- {m} calibrated on {'ABCD'[a]}: learned carried {c['carried']}, "
                      f"{time.process_time() - t0:.0f} CPU s -->", flush=True)
        print(f"\n{m}:")
        summary(rows)
        print()


SESSIONS = {"B": (21.9, MOVES[1]), "C": (18.1, MOVES[2]), "D": (22.0, MOVES[3])}
LO = np.array([-60.0, -150.0, -150.0, -180.0, -120.0, -180.0])
HI = np.array([60.0, -30.0, 150.0, 0.0, 120.0, 180.0])


def session_effect_mm(q, amp_mm) -> np.ndarray:
    """A smooth joint-dependent displacement (n, 3) mm, present in one session only."""
    r = np.radians(q)
    return amp_mm * np.stack([np.sin(2 * r[:, 0]), np.cos(r[:, 1] + r[:, 2]), np.sin(r[:, 3] + r[:, 4])], 1)


def run_sim(seed, amp_mm, rows):
    import sys
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_arm_sessions import NOISE_MM, T_CAL_C, thermal_truth
    chain = load_machine("ur5")
    t0 = draw_truth(chain, seed)
    move_of = {"base." + k: v for k, v in zip(("x_mm", "y_mm", "z_mm", "rz_rad", "ry_rad", "rx_rad"), MOVES[0])}
    ta = thermal_truth(chain, t0, T_CAL_C, move_of)
    qa = random_joints(LO, HI, 250, [seed, 10])
    cal = measure(chain, ta, qa, NOISE_MM, [seed, 11])
    cal.xyz_mm = cal.xyz_mm + session_effect_mm(qa, amp_mm)
    cal.temp_c = T_CAL_C + np.random.default_rng([seed, 12]).normal(0, 0.1, len(qa))
    with tempfile.TemporaryDirectory() as td:
        c = calibrate(chain, cal, Path(td))
        for s, (temp, mv) in SESSIONS.items():
            tr = thermal_truth(chain, t0, temp, {"base." + k: v for k, v in
                                                  zip(("x_mm", "y_mm", "z_mm", "rz_rad", "ry_rad", "rx_rad"), mv)})
            q = random_joints(LO, HI, 150, [seed, 30 + ord(s)])
            new = measure(chain, tr, q, NOISE_MM, [seed, 40 + ord(s)])
            new.temp_c = temp + np.random.default_rng([seed, 50 + ord(s)]).normal(0, 0.1, len(q))
            sd = Path(td) / s
            sd.mkdir()
            row = register_row(chain, c["json"], new, sd, tr.tool_point(chain, q))
            rows.append(row)
            tp = " / ".join(format(row[n]["true_plain"], ".4f") for n in REGISTER_POSES)
            tk = " / ".join(format(row[n]["true_kept"], ".4f") for n in REGISTER_POSES)
            kept = " / ".join(row[n]["kept"] for n in REGISTER_POSES)
            cand = [k for k in row[REGISTER_POSES[-1]]["meas"] if k != "plain geometric LSQ"]
            print(f"| {seed} | {s} {temp - T_CAL_C:+.1f} °C | {c['kept']} (carried {c['carried']}) | {tp} | **{tk}** | "
                  f"{kept} | {fmt(row, 'plain geometric LSQ')}; " + "; ".join(f"{k}: {fmt(row, k)}" for k in cand)
                  + " |", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--real", default=None)
    ap.add_argument("--rotate", action="store_true", help="real: calibrate on every pseudo-session in turn")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--effect-mm", type=float, default=0.05)
    a = ap.parse_args()
    if a.real:
        run_real(a.real, a.rotate)
        return
    print("| seed | session | calibration kept (learned carried) | plain TRUE after 6 / 20 / 50 | register TRUE after "
          "6 / 20 / 50 | kept by register | MEASURED: plain; candidates after 6 / 20 / 50 |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for s in range(a.seeds):
        run_sim(s, a.effect_mm, rows)
    summary(rows)


if __name__ == "__main__":
    main()
