"""URDF in and 6-DoF measurements of an arm → printed markdown (pasted into docs/decisions/020-benchmark-notebook.md).

1. URDF: the UR5 / UR10 URDFs of ``tests/data/urdf`` (written from the published DH numbers in ROS-Industrial's
   ur_description layout) against the built-in DH chains: largest tool-point and tool-axis difference over seeded
   random joint vectors in [-360, 360] deg (model residual: two nominal chains, no noise).
2. 6-DoF: a simulated UR5 (built-in chain, random link/base/tool errors of :func:`errormap.arm_simulate.draw_truth`,
   no sag; the truth's slots outside the position-identifiable set set to zero, so that both fits are correctly
   specified), tracker noise 0.02 mm per position component and 0.02/150 rad per rotation component; the same poses
   fitted position-only and 6-DoF on the same slots (``fit_slots``, the position-identifiable set). Figures: RMS
   error of the identified link + tool slots against the truth (mm slots and rad slots apart), and the TRUE held-out
   error (noise-free truth) on 500 other random poses: mean position error, mean orientation error.
3. The realistic case: every slot of the truth drawn, each fit on the slots its data identify (``fit_model``, the
   product's geometric stage, slots ``dh``): identified slots, true held-out position and orientation errors.

Run: ``python benchmarks/bench_arm_6dof.py [--seeds 10] [--poses 30 60 120]``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from errormap.arm_calibration import fit_model, fit_slots, identifiable_slots  # noqa: E402
from errormap.arm_simulate import draw_truth, measure_6dof, random_joints  # noqa: E402
from errormap.machine import load_machine  # noqa: E402

NOISE_MM = 0.02
LEVER_MM = 150.0
LO, HI = np.full(6, -170.0), np.full(6, 170.0)


def urdf_rows(n=1000, seed=7):
    out = []
    for name in ("ur5", "ur10"):
        dh, ur = load_machine(name), load_machine(ROOT / "tests" / "data" / "urdf" / f"{name}-urdf.toml")
        q = np.random.default_rng(seed).uniform(-360, 360, (n, 6))
        a, b = dh.fk(q), ur.fk(q)
        out.append(f"| {name} | {n} | {np.abs(a[:, :3, 3] - b[:, :3, 3]).max():.2g} | "
                   f"{np.abs(a[:, :3, :3] - b[:, :3, :3]).max():.2g} | {ur.param_names == dh.param_names} |")
    return out


def six_dof_rows(chain, seeds, poses):
    qh = random_joints(LO, HI, 500, [99])
    link = np.array([n.startswith(("link", "tool")) for n in chain.param_names])
    mm = np.array([n.endswith("_mm") for n in chain.param_names])
    rows = []
    for n in poses:
        m = []
        for s in range(seeds):
            t = draw_truth(chain, s, compliance_rad_per_mm=np.zeros(chain.n_joints))
            q = random_joints(LO, HI, n, [s, 0])
            free = identifiable_slots(chain, q)[0]
            t.errors[~free] = 0.0
            p6 = measure_6dof(chain, t, q, NOISE_MM, NOISE_MM / LEVER_MM, [s, 1])
            pos = p6.subset(np.arange(n))
            pos.rot = pos.sigma_rad = None
            Ft = chain.fk(qh, t.errors)
            row = []
            for r in (fit_slots(chain, pos, free), fit_slots(chain, p6, free)):
                Fr = chain.fk(qh, r.params)
                dr = Rotation.from_matrix(Fr[:, :3, :3] @ np.swapaxes(Ft[:, :3, :3], 1, 2)).magnitude()
                row += [np.sqrt(np.mean((r.params - t.errors)[link & free & mm] ** 2)),
                        np.sqrt(np.mean((r.params - t.errors)[link & free & ~mm] ** 2)),
                        np.linalg.norm(Fr[:, :3, 3] - Ft[:, :3, 3], axis=1).mean(), dr.mean()]
            m.append(row)
        a = np.mean(m, 0)
        rows.append(f"| {n} | {int(free.sum())} | {a[0]:.3g} / {a[4]:.3g} | {a[1]:.3g} / {a[5]:.3g} | "
                    f"{a[2] * 1000:.1f} / {a[6] * 1000:.1f} | {a[3] * 1e6:.0f} / {a[7] * 1e6:.0f} |")
    return rows


def own_slots_rows(chain, seeds, poses):
    """The realistic case: every slot of the truth drawn, each fit on its own identifiable slot set (``fit_model``:
    6-DoF poses identify more); true held-out position and orientation errors."""
    qh = random_joints(LO, HI, 500, [99])
    rows = []
    for n in poses:
        m = []
        for s in range(seeds):
            t = draw_truth(chain, s, compliance_rad_per_mm=np.zeros(chain.n_joints))
            p6 = measure_6dof(chain, t, random_joints(LO, HI, n, [s, 0]), NOISE_MM, NOISE_MM / LEVER_MM, [s, 1])
            pos = p6.subset(np.arange(n))
            pos.rot = pos.sigma_rad = None
            Ft = chain.fk(qh, t.errors)
            row = []
            for r in (fit_model(chain, pos), fit_model(chain, p6)):
                Fr = chain.fk(qh, r.params)
                dr = Rotation.from_matrix(Fr[:, :3, :3] @ np.swapaxes(Ft[:, :3, :3], 1, 2)).magnitude()
                row += [r.free.sum(), np.linalg.norm(Fr[:, :3, 3] - Ft[:, :3, 3], axis=1).mean(), dr.mean()]
            m.append(row)
        a = np.mean(m, 0)
        rows.append(f"| {n} | {a[0]:.0f} / {a[3]:.0f} | {a[1] * 1000:.1f} / {a[4] * 1000:.1f} | "
                    f"{a[2] * 1e6:.0f} / {a[5] * 1e6:.0f} |")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--poses", type=int, nargs="+", default=[30, 60, 120])
    a = ap.parse_args(argv)
    t0 = time.process_time()
    print("| arm | joint vectors | max tool-point difference (mm) | max tool-axis difference | same slots |")
    print("|---|---|---|---|---|")
    print("\n".join(urdf_rows()))
    print()
    print("| poses | identified slots | link+tool mm slots, RMS error (mm): position-only / 6-DoF | link+tool rad slots, "
          "RMS error (rad) | true held-out position error, mean (µm) | true held-out orientation error, mean (µrad) |")
    print("|---|---|---|---|---|---|")
    print("\n".join(six_dof_rows(load_machine("ur5"), a.seeds, a.poses)))
    print()
    print("| poses | identified slots | true held-out position error, mean (µm) | true held-out orientation error, "
          "mean (µrad) |")
    print("|---|---|---|---|")
    print("\n".join(own_slots_rows(load_machine("ur5"), a.seeds, a.poses)))
    print(f"\nCPU {time.process_time() - t0:.1f} s")


if __name__ == "__main__":
    main()
