"""A calibration carried across simulated measurement sessions at ±2 °C: what `register` + the calibration give.

A simulated UR5 (link + base + tool errors, joint sag under gravity, 20 µm tracker noise) whose links expand with
temperature (aluminium, 23e-6 / K on every nominal length, the tool included) is measured in four sessions: A at
20.0 °C (300 poses, the calibration), B / C / D at 21.9 / 18.1 / 22.0 °C (150 poses each) with the tracker set up
anew each time (moved by up to 1.3 m and turned by up to 0.6 rad). Each pose file carries its ``temp_c``.

Fitted on A alone: volcomp's geometric stage (``dh+compliance``), the plain least-squares calibration, and volcomp's
learned residual on the geometric stage's residual, decided twice — by the default shuffled 5-fold CV and by a
BLOCKED CV that holds out whole sectors of joint 1 (a region of the workspace the learner has not seen). Then each
other session is registered (`register_frame`: base only) on its first 6 / 20 / 50 poses and judged:

- TRUE residual: the hidden truth at 100 joint-program points of that session (its temperature, its sag) against the
  registered model, both in the robot's base frame (the truth's base with link 1's offsets absorbed, the gauge the
  calibration uses), mean position norm, mm;
- MEASURED residual: the session's poses after the first 50, in the session's tracker frame, mean, mm.

    python benchmarks/bench_arm_sessions.py [--seeds 2]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from errormap.arm_calibration import content_blocks, fit_model, fit_plain_lsq
from errormap.arm_frames import to_base_frame
from errormap.arm_poses import ArmPoses
from errormap.arm_register import register_frame
from errormap.arm_simulate import ArmTruth, draw_truth, measure, random_joints
from errormap.machine import load_machine

LO = np.array([-60.0, -150.0, -150.0, -180.0, -120.0, -180.0])
HI = np.array([60.0, -30.0, 150.0, 0.0, 120.0, 180.0])
PROG_LO = np.array([-55.0, -115.0, 35.0, -115.0, 45.0, -25.0])
PROG_HI = np.array([55.0, -35.0, 135.0, 25.0, 145.0, 25.0])
ALPHA_PER_K = 23e-6
NOISE_MM = 0.02
T_CAL_C = 20.0
SESSIONS = {"B": (21.9, {"base.x_mm": 812.0, "base.y_mm": -305.0, "base.z_mm": 47.0, "base.rz_rad": 0.61,
                         "base.ry_rad": 0.004, "base.rx_rad": -0.003}),
            "C": (18.1, {"base.x_mm": -1300.0, "base.y_mm": 420.0, "base.z_mm": -210.0, "base.rz_rad": -0.53,
                         "base.ry_rad": -0.006, "base.rx_rad": 0.002}),
            "D": (22.0, {"base.x_mm": 150.0, "base.y_mm": 990.0, "base.z_mm": 380.0, "base.rz_rad": 0.21,
                         "base.ry_rad": 0.001, "base.rx_rad": 0.007})}
REGISTER_POSES = (6, 20, 50)


def thermal_truth(chain, truth: ArmTruth, temp_c: float, move=None) -> ArmTruth:
    """``truth`` at ``temp_c`` (every nominal length × (1 + α ΔT), as an error on its slot) with the tracker moved."""
    e = truth.errors.copy()
    names = list(chain.param_names)
    for et in chain.ets:
        if et.kind == "t" and et.slot is not None and et.joint is None and not et.slot.startswith("base."):
            e[names.index(et.slot)] += ALPHA_PER_K * (temp_c - T_CAL_C) * et.value
    for n, v in (move or {}).items():
        e[names.index(n)] += v
    return ArmTruth(e, truth.compliance_rad_per_mm)


def session(chain, truth, n, temp_c, seed) -> ArmPoses:
    p = measure(chain, truth, random_joints(LO, HI, n, [seed, 0]), NOISE_MM, [seed, 1])
    p.temp_c = temp_c + np.random.default_rng([seed, 2]).normal(0, 0.1, n)     # the logged temperature
    return p


def learners(chain, cal, geo, seed):
    from training.arm_residual import KERNEL_FAMILIES, ArmResidualRegressor
    r = cal.xyz_mm - geo.predict(cal.q)
    out = {}
    for name, groups in (("shuffled 5-fold", None), ("blocked by joint-1 sector", content_blocks(cal, 5)["sector"])):
        t0 = time.process_time()
        out[name] = ArmResidualRegressor(chain, inputs="physics", k_folds=5, seed=seed,
                                         families=KERNEL_FAMILIES).fit(cal.q, r, groups)
        out[name].cpu_s = time.process_time() - t0
    return out


def model_base_points(chain, geo, params, learner, R, q):
    p = geo.chain.tool_point(q, params) + (0.0 if learner is None else learner.predict(q) @ R.T)
    return to_base_frame(chain, params, p)


def run(seed: int, chain) -> list[dict]:
    t0 = draw_truth(chain, seed)
    cal_truth = thermal_truth(chain, t0, T_CAL_C)
    cal = session(chain, cal_truth, 300, T_CAL_C, [seed, 10])
    models = {"volcomp geometric+compliance": fit_model(chain, cal, "dh+compliance"),
              "plain geometric LSQ": fit_plain_lsq(chain, cal)}
    geo = models["volcomp geometric+compliance"]
    lrn = learners(chain, cal, geo, seed)
    rows = [{"what": "learned stage decision", **{k: f"{v.chosen_} ({v.cpu_s:.0f} s)" for k, v in lrn.items()}}]
    pipes = [(n, m, None) for n, m in models.items()]
    for k, v in lrn.items():
        if v.chosen_ != "none":
            pipes.append((f"volcomp + learned (kept by {k} CV)", geo, v))
    qp = random_joints(PROG_LO, PROG_HI, 100, [seed, 20])
    own = {n: np.linalg.norm(cal_truth.base_frame_point(chain, qp)
                             - model_base_points(chain, m, m.params, L, np.eye(3), qp), axis=1).mean()
           for n, m, L in pipes}
    rows.append({"what": "A (own session, 20.0 °C)", **{n: {"true": own[n]} for n in own}})
    for s, (temp, move) in SESSIONS.items():
        tr = thermal_truth(chain, t0, temp, move)
        new = session(chain, tr, 150, temp, [seed, 30 + ord(s)])
        rest = new.subset(np.arange(50, len(new)))
        row = {"what": f"{s} ({temp:.1f} °C, mean logged {new.temp_c.mean():.2f})"}
        for n, m, L in pipes:
            cell = {}
            for k in REGISTER_POSES:
                reg = register_frame(m.chain, m.params, new.subset(np.arange(k)), L)
                R = reg.learned_rotation
                cell[f"true{k}"] = np.linalg.norm(tr.base_frame_point(chain, qp)
                                                  - model_base_points(chain, m, reg.params, L, R, qp), axis=1).mean()
                pm = m.chain.tool_point(rest.q, reg.params) + (0.0 if L is None else L.predict(rest.q) @ R.T)
                cell[f"meas{k}"] = np.linalg.norm(rest.xyz_mm - pm, axis=1).mean()
            row[n] = cell
        rows.append(row)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=2)
    a = ap.parse_args()
    chain = load_machine("ur5")
    for seed in range(a.seeds):
        print(f"\nseed {seed}")
        for row in run(seed, chain):
            what = row.pop("what")
            if what == "learned stage decision":
                print(f"learned stage chosen: " + "; ".join(f"{k}: {v}" for k, v in row.items()))
                print("| session | model | own TRUE | TRUE after 6 / 20 / 50 | MEASURED after 6 / 20 / 50 |")
                print("|---|---|---:|---|---|")
                continue
            for n, c in row.items():
                if "true" in c:
                    print(f"| {what} | {n} | {c['true']:.4f} | | |")
                else:
                    tru = " / ".join(format(c["true%d" % k], ".4f") for k in REGISTER_POSES)
                    mea = " / ".join(format(c["meas%d" % k], ".4f") for k in REGISTER_POSES)
                    print(f"| {what} | {n} | | {tru} | {mea} |", flush=True)


if __name__ == "__main__":
    main()
