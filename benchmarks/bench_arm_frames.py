"""Frames kept apart on the real arm grids: volcomp's geometric stage and the plain least-squares calibration fitted
on each grid's first 60 % (file order) and on the same poses seen by a tracker set up elsewhere (the measured points
moved by a rigid transform of 1.3 m and 0.53 rad, the size reported on a real UR10 cell), judged on the last 40 %
(measured residual, mean position norm, mm; the held-out poses moved the same way). Reported beside: the largest
identified link deviation (mm and mrad) and the base frame's identified slots — physical link parameters do not
depend on where the tracker stands.

    python benchmarks/bench_arm_frames.py DATA/serial-arms
"""
from __future__ import annotations

import sys
import time

import numpy as np

from errormap.arm_calibration import fit_model, fit_plain_lsq
from errormap.arm_poses import read_arm_poses
from errormap.machine import load_machine

FAR = {"x": 1150.0, "y": -420.0, "z": -1307.0, "rz": -0.53, "ry": 0.012, "rx": -0.008}


def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def moved(p, far):
    R = _rot(2, far["rz"]) @ _rot(1, far["ry"]) @ _rot(0, far["rx"])
    q = p.subset(np.arange(len(p)))
    q.xyz_mm = p.xyz_mm @ R.T + np.array([far["x"], far["y"], far["z"]])
    return q


def link_summary(res) -> dict:
    names = np.array(res.chain.param_names)
    link = np.array([n.startswith("link") for n in names])
    mm = link & np.array([n.endswith("_mm") for n in names])
    rad = link & np.array([n.endswith("_rad") for n in names])
    k_mm = np.flatnonzero(mm)[np.argmax(np.abs(res.params[mm]))]
    k_rad = np.flatnonzero(rad)[np.argmax(np.abs(res.params[rad]))]
    return {"max_link_mm": (names[k_mm], res.params[k_mm]), "max_link_mrad": (names[k_rad], 1e3 * res.params[k_rad])}


def main(folder):
    print("| arm | tracker | model | held-out mean mm | largest link length dev. | largest link angle dev. | s |")
    print("|---|---|---|---:|---|---|---:|")
    for f, m in (("ur5_grid.csv", "ur5"), ("wam_grid.csv", "wam")):
        chain = load_machine(m)
        data = read_arm_poses(f"{folder}/{f}", chain)
        n = int(0.6 * len(data))
        for tag, d in (("as given", data), ("moved 1.3 m / 0.53 rad", moved(data, FAR))):
            cal, chk = d.subset(np.arange(n)), d.subset(np.arange(n, len(d)))
            for name, fit in (("volcomp dh", lambda c, p: fit_model(c, p, "dh")),
                              ("volcomp dh+compliance", lambda c, p: fit_model(c, p, "dh+compliance")),
                              ("plain LSQ", fit_plain_lsq)):
                t0 = time.process_time()
                r = fit(chain, cal)
                e = np.linalg.norm(chk.xyz_mm - r.predict(chk.q), axis=1).mean()
                s = link_summary(r)
                (a, va), (b, vb) = s["max_link_mm"], s["max_link_mrad"]
                print(f"| {m} | {tag} | {name} | {e:.4f} | {a} {va:+.3f} mm | {b} {vb:+.3f} mrad | "
                      f"{time.process_time() - t0:.1f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
