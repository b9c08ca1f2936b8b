"""Re-registering a calibrated arm in a new session (``volcomp register``'s fit) on a simulated UR5: the geometric
stage fitted on 200 poses of session A; session B has the tracker 0.9 m away, turned 35° about the vertical and
tilted 4 mrad. Mean measured residual (position norm, mm) on B's poses not used to register, after registering on
6 / 20 / 50 of them, for volcomp's geometric stage and the plain least-squares calibration re-registered the same way;
and the calibration's own held-out error on A. Truths never reach the estimator.

    python benchmarks/bench_arm_register.py [--seeds 3] [--real ../shared/data/serial-arms]

``--real DIR``: the real UR5 and WAM tracker grids: the first 60 % of each grid (file order) calibrate; the rest is a
"new session" — its measured points moved by the same rigid transform as the simulated tracker move (real poses and
noise, a known frame change) — registered on its first 6 / 20 / 50 poses and judged on the others.
"""
from __future__ import annotations

import argparse

import numpy as np

from errormap.arm_calibration import fit_model, fit_plain_lsq
from errormap.arm_register import register_frame
from errormap.arm_simulate import ArmTruth, draw_truth, measure, random_joints
from errormap.machine import load_machine

LO = np.array([-60.0, -150.0, -150.0, -180.0, -120.0, -180.0])
HI = np.array([60.0, -30.0, 150.0, 0.0, 120.0, 180.0])
MOVE = {"base.x_mm": 812.0, "base.y_mm": -305.0, "base.z_mm": 47.0, "base.rz_rad": 0.61, "base.ry_rad": 0.004,
        "base.rx_rad": -0.003}


REGISTER_POSES = (6, 20, 50)


def registered_errors_mm(geo, new) -> dict:
    """{n: mean measured residual (mm) on ``new``'s poses after the first n} with the frame of ``geo``
    registered on ``new``'s first n poses, for n in :data:`REGISTER_POSES`."""
    row = {}
    for n in REGISTER_POSES:
        reg = register_frame(geo.chain, geo.params, new.subset(np.arange(n)))
        rest = new.subset(np.arange(n, len(new)))
        row[n] = np.linalg.norm(rest.xyz_mm - geo.chain.tool_point(rest.q, reg.params), axis=1).mean()
    return row


def run(seed: int, chain) -> dict:
    t = draw_truth(chain, seed)
    cal = measure(chain, t, random_joints(LO, HI, 200, [seed, 0]), 0.02, [seed, 1])
    chk = measure(chain, t, random_joints(LO, HI, 100, [seed, 2]), 0.02, [seed, 3])
    e = t.errors.copy()
    for n, v in MOVE.items():
        e[chain.param_names.index(n)] += v
    new = measure(chain, ArmTruth(e, t.compliance_rad_per_mm), random_joints(LO, HI, 150, [seed, 4]), 0.02, [seed, 5])
    out = {}
    for name, geo in (("volcomp geometric+compliance", fit_model(chain, cal, "dh+compliance")),
                      ("plain geometric LSQ", fit_plain_lsq(chain, cal))):
        own = np.linalg.norm(chk.xyz_mm - geo.predict(chk.q), axis=1).mean()
        out[name] = {"own": own, **registered_errors_mm(geo, new)}
    return out


def run_real(path, machine) -> dict:
    from errormap.arm_poses import read_arm_poses
    from errormap.arm_frames import rot as _rot
    chain = load_machine(machine)
    data = read_arm_poses(path, chain)
    n = int(0.6 * len(data))
    cal, new = data.subset(np.arange(n)), data.subset(np.arange(n, len(data)))
    R = _rot(2, MOVE["base.rz_rad"]) @ _rot(1, MOVE["base.ry_rad"]) @ _rot(0, MOVE["base.rx_rad"])
    new.xyz_mm = new.xyz_mm @ R.T + np.array([MOVE["base.x_mm"], MOVE["base.y_mm"], MOVE["base.z_mm"]])
    out = {}
    for name, geo in (("volcomp geometric+compliance", fit_model(chain, cal, "dh+compliance")),
                      ("plain geometric LSQ", fit_plain_lsq(chain, cal))):
        out[name] = registered_errors_mm(geo, new)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--real", default=None)
    a = ap.parse_args()
    if a.real:
        print("| arm | model | after 6 | after 20 | after 50 |")
        print("|---|---|---:|---:|---:|")
        for f, m in (("ur5_grid.csv", "ur5"), ("wam_grid.csv", "wam")):
            for name, r in run_real(f"{a.real}/{f}", m).items():
                print(f"| {m} | {name} | {r[6]:.4f} | {r[20]:.4f} | {r[50]:.4f} |")
        return
    chain = load_machine("ur5")
    print("| seed | model | own session held-out | after 6 | after 20 | after 50 |")
    print("|---|---|---:|---:|---:|---:|")
    for s in range(a.seeds):
        for name, r in run(s, chain).items():
            print(f"| {s} | {name} | {r['own']:.4f} | {r[6]:.4f} | {r[20]:.4f} | {r[50]:.4f} |")


if __name__ == "__main__":
    main()
