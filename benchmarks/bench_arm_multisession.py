"""One calibration file holding several measurement sessions (a ``session`` column): `calibrate` decides by blocked
cross-validation over the sessions which stages carry to other sessions, then `register` puts the calibration into
new sessions. Per session: the plain geometric calibration against what register ships after 6 / 20 / 50 poses.

Real (``--real DIR``): each grid (UR5 1,000, WAM 216 poses) cut by file order into pseudo-sessions (UR5 4 × 250,
WAM 3 × 72), each moved by a rigid transform of its own (a tracker set up anew), written as ONE file with a
``session`` column and calibrated with `calibrate`'s defaults. The figures are calibrate's own blocked CV over the
sessions (``across_sessions``): each session held out in turn, the others calibrated, the held-out session registered
on its first N poses and judged on the rest (MEASURED residual, mean position norm, mm).

Simulated (``--seeds K``): a UR5 (link + base + tool errors, joint sag, 20 µm noise, links expanding 23e-6 / K)
measured in three calibration sessions A / B / C at 20.0 / 21.9 / 18.1 °C (200 / 150 / 150 poses; A alone also
carries a session-only effect of ``--effect-mm`` amplitude, smooth in the joints), the tracker moved up to 1.4 m and
turned up to 0.6 rad between sessions; calibrated in one file; then two new sessions D / E at 22.0 / 18.6 °C
(150 poses each) registered through `register --fit-poses N`: TRUE residual = the session's noise-free truth at its
held-out joints against the registered model, in the session's tracker frame, mean mm. Beside it: the same new
sessions registered from a calibration on session A alone.

    python benchmarks/bench_arm_multisession.py --real ../shared/data/serial-arms
    python benchmarks/bench_arm_multisession.py --seeds 2
"""
from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_arm_register_sessions import LO, HI, MOVES, moved, session_effect_mm  # noqa: E402
from bench_arm_sessions import NOISE_MM, T_CAL_C, thermal_truth  # noqa: E402

from compensation.app.workflows.arm_calibration import ArmCalibrationSettings
from compensation.model_file import read_model
from compensation.app.workflows.arm_run import run_arm_calibration
from compensation.app.workflows.arm_register import run_arm_register
from errormap.arm_calibration import GeometricResult
from errormap.arm_poses import ArmPoses, read_arm_poses, write_arm_poses
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.machine import load_machine

REGISTER_POSES = (6, 20, 50)
CAL_SESSIONS = {"A": (20.0, MOVES[0], 200), "B": (21.9, MOVES[1], 150), "C": (18.1, MOVES[2], 150)}
NEW_SESSIONS = {"D": (22.0, MOVES[3]), "E": (18.6, (-400.0, -880.0, 120.0, -0.35, 0.003, 0.005))}


def joined(parts) -> ArmPoses:
    """One pose set of several (label, ArmPoses), with a ``session`` column."""
    cat = (lambda f: None if getattr(parts[0][1], f) is None else np.concatenate([getattr(p, f) for _, p in parts]))
    lab = np.concatenate([np.full(len(p), k, dtype=object) for k, p in parts])
    return ArmPoses(cat("q"), cat("xyz_mm"), cat("sigma_mm"), cat("temp_c"), None, np.arange(2, len(lab) + 2),
                    "joined", "schema", session=lab)


def calibrate(chain, poses, d: Path):
    write_arm_poses(d / "cal.csv", chain, poses)
    t0 = time.process_time()
    with contextlib.redirect_stderr(io.StringIO()):
        doc = run_arm_calibration(chain, ArmCalibrationSettings(poses=str(d / "cal.csv")), d / "cal")
    return doc, time.process_time() - t0


def print_sessions(arm, doc, cpu):
    a = doc["across_sessions"]
    print(f"\n{arm}: calibration kept {doc['kept_stage']}; {cpu:.0f} CPU s; carried: "
          + ", ".join(f"{k} {v}" for k, v in a["carried"].items()))
    for k, w in a["why"].items():
        print(f"- {k}: {w}")
    print("\n| held out | its calibration kept | plain after " + " / ".join(map(str, REGISTER_POSES))
          + " | geometric stage | learned stage | temperature | register ships |")
    print("|---|---|---|---|---|---|---|")
    from compensation.app.workflows.arm_sessions import role_mean
    for w in a["sessions"]:
        ns = [n for n in REGISTER_POSES if str(n) in w["by_poses"]]
        f = (lambda r: " / ".join("–" if role_mean(w, n, r) is None else f"{role_mean(w, n, r):.4f}" for n in ns))
        ship = " / ".join(f"{w['by_poses'][str(n)]['shipped_mm']:.4f}" for n in ns)
        print(f"| {w['session']} | {w['kept_stage_without_it']} | {f('plain')} | {f('geometric')} | {f('learned')} | "
              f"{f('temperature')} | **{ship}** |")
    print("\n| N | " + " | ".join(["plain", "geometric", "learned", "temperature", "register ships"]) + " |")
    print("|---:|---|---|---|---|---|")
    for n, r in a["summary_by_poses"].items():
        print(f"| {n} | " + " | ".join("–" if r[k] is None else f"{r[k]:.4f}"
                                        for k in ("plain", "geometric", "learned", "temperature", "register ships"))
              + " |", flush=True)


def run_real(folder):
    for f, m, k in (("ur5_grid.csv", "ur5", 4), ("wam_grid.csv", "wam", 3)):
        chain = load_machine(m)
        data = read_arm_poses(f"{folder}/{f}", chain)
        parts = [("ABCD"[j], moved(data.subset(i), MOVES[j])) for j, i in
                 enumerate(np.array_split(np.arange(len(data)), k))]
        with tempfile.TemporaryDirectory() as td:
            doc, cpu = calibrate(chain, joined(parts), Path(td))
        print_sessions(m, doc, cpu)


def truth_of(chain, t0, temp, mv):
    return thermal_truth(chain, t0, temp, {"base." + k: v for k, v in
                                           zip(("x_mm", "y_mm", "z_mm", "rz_rad", "ry_rad", "rx_rad"), mv)})


def register_true(chain, cal_json, sess, truth_xyz, d: Path) -> dict:
    f = d / "session.csv"
    write_arm_poses(f, chain, sess)
    row = {}
    for n in REGISTER_POSES:
        out = d / f"reg{n}"
        with contextlib.redirect_stderr(io.StringIO()):
            r = run_arm_register(chain, f, cal_json, out, fit_poses=n)
        rest = sess.subset(np.arange(n, len(sess)))
        m = read_model(out / "model.json", chain, family="arm")
        plain = GeometricResult.from_dict(chain, m.doc["plain_geometric"])
        geo, lrn = m.calibration.stages
        kept = geo.predict(rest.q) + (0.0 if lrn is None else lrn.predict(rest.q))
        t = truth_xyz[n:]
        row[n] = {"kept": r["kept"], "plain": float(np.linalg.norm(t - plain.predict(rest.q), axis=1).mean()),
                  "shipped": float(np.linalg.norm(t - kept, axis=1).mean())}
    return row


def run_sim(seed, amp_mm):
    chain = load_machine("ur5")
    t0 = draw_truth(chain, seed)
    parts = []
    for j, (lab, (temp, mv, n)) in enumerate(CAL_SESSIONS.items()):
        q = random_joints(LO, HI, n, [seed, 10 + j])
        p = measure(chain, truth_of(chain, t0, temp, mv), q, NOISE_MM, [seed, 20 + j])
        if lab == "A":
            p.xyz_mm = p.xyz_mm + session_effect_mm(q, amp_mm)
        p.temp_c = temp + np.random.default_rng([seed, 30 + j]).normal(0, 0.1, n)
        parts.append((lab, p))
    with tempfile.TemporaryDirectory() as td:
        doc, cpu = calibrate(chain, joined(parts), Path(td) / "multi")
        print_sessions(f"simulated seed {seed}", doc, cpu)
        single, cpu1 = calibrate(chain, parts[0][1], Path(td) / "single")
        print(f"\nseed {seed}: new sessions (TRUE mean mm after {' / '.join(map(str, REGISTER_POSES))} poses); "
              f"A-only calibration kept {single['kept_stage']}")
        print("| session | plain | register ships (multi-session calibration) | kept by register | register ships "
              "(calibration on A alone) |")
        print("|---|---|---|---|---|")
        for j, (lab, (temp, mv)) in enumerate(NEW_SESSIONS.items()):
            tr = truth_of(chain, t0, temp, mv)
            q = random_joints(LO, HI, 150, [seed, 40 + j])
            new = measure(chain, tr, q, NOISE_MM, [seed, 50 + j])
            new.temp_c = temp + np.random.default_rng([seed, 60 + j]).normal(0, 0.1, len(q))
            rows = {}
            for name in ("multi", "single"):
                d = Path(td) / f"{name}{lab}"
                d.mkdir()
                rows[name] = register_true(chain, Path(td) / name / "cal" / "model.json", new,
                                           tr.tool_point(chain, q), d)
            g = (lambda nm, key: " / ".join(f"{rows[nm][n][key]:.4f}" for n in REGISTER_POSES))
            print(f"| {lab} {temp - T_CAL_C:+.1f} °C | {g('multi', 'plain')} | **{g('multi', 'shipped')}** | "
                  + " / ".join(rows["multi"][n]["kept"] for n in REGISTER_POSES) + f" | {g('single', 'shipped')} |",
                  flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--real", default=None)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--effect-mm", type=float, default=0.05)
    a = ap.parse_args()
    if a.real:
        run_real(a.real)
        return
    for s in range(a.seeds):
        run_sim(s, a.effect_mm)


if __name__ == "__main__":
    main()
