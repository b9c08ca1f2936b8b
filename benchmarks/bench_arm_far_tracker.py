"""A joint program compensated without tracker targets: a simulated UR5 (link + base + tool errors, 150 poses at
20 µm) measured by a tracker 1.8 m away and turned 0.53 rad, its geometric stage written as a model.json,
and `volcomp compensate` of a 40-point joint program with no target columns. TRUE residual: the hidden truth at the
compensated joints against the nominal points, both in the robot's base frame (the truth's base with link 1's offsets
along and about its axis absorbed — the slots calibration holds). Self-contained, so it runs on an earlier revision
too (PYTHONPATH=CHECKOUT).

    python benchmarks/bench_arm_far_tracker.py
"""
import json, sys, tempfile, io, contextlib
from pathlib import Path
import numpy as np
from errormap.arm_calibration import fit_model
from errormap.arm_simulate import ArmTruth, draw_truth, measure, random_joints
from errormap.machine import load_machine
from errormap.io import read_table
from compensation.app.cli import main
from compensation.fields import ARM_FORMAT as MODEL_FORMAT
c = load_machine("ur5")
LO = np.array([-60.0, -150.0, -150.0, -180.0, -120.0, -180.0]); HI = np.array([60.0, -30.0, 150.0, 0.0, 120.0, 180.0])
PL = np.array([-55.0, -115.0, 35.0, -115.0, 45.0, -25.0]); PH = np.array([55.0, -35.0, 135.0, 25.0, 145.0, 25.0])
FAR = {"base.x_mm": 1150.0, "base.y_mm": -420.0, "base.z_mm": -1307.0, "base.rz_rad": -0.53, "base.ry_rad": 0.012, "base.rx_rad": -0.008}
t = draw_truth(c, 5, compliance_rad_per_mm=np.zeros(6)); e = t.errors.copy()
for n, v in FAR.items(): e[c.param_names.index(n)] += v
tf = ArmTruth(e, t.compliance_rad_per_mm)
p = measure(c, tf, random_joints(LO, HI, 150, [5, 0]), 0.02, [5, 1])
geo = fit_model(c, p, "dh")
names = np.array(c.param_names)
print("link1.dd_mm", geo.params[list(names).index("link1.dd_mm")], "link1.dtheta_rad", geo.params[list(names).index("link1.dtheta_rad")],
      "base.z_mm", geo.params[list(names).index("base.z_mm")])
d = Path(tempfile.mkdtemp())
(d / "cal.json").write_text(json.dumps({"format": MODEL_FORMAT, "machine": {"name": c.name, "joints": c.joint_columns},
                                         "kept_stage": "geometric", "geometric": geo.to_dict(), "learned": None}))
qp = random_joints(PL, PH, 40, [5, 9])
(d / "prog.csv").write_text(",".join(c.joint_columns) + "\n" + "\n".join(",".join(f"{v:.10g}" for v in r) for r in qp))
buf = io.StringIO()
with contextlib.redirect_stdout(buf):
    rc = main(["compensate", str(d / "prog.csv"), "--machine", "ur5", "--model", str(d / "cal.json"), "--out", str(d / "o")])
print("compensate exit", rc, buf.getvalue().strip()[-200:])
def rot(axis, a):
    cs, sn = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = cs, -sn, sn, cs
    return R


def base_transform(chain, err):
    v = [err[list(chain.param_names).index(n)] for n in ("base.x_mm", "base.y_mm", "base.z_mm", "base.rz_rad",
                                                         "base.ry_rad", "base.rx_rad")]
    T = np.eye(4)
    T[:3, 3] = v[:3]
    T[:3, :3] = rot(2, v[3]) @ rot(1, v[4]) @ rot(0, v[5])
    return T


G = np.eye(4); G[:3, :3] = rot(2, e[list(names).index("link1.dtheta_rad")]); G[2, 3] = e[list(names).index("link1.dd_mm")]
T = base_transform(c, e) @ G
bf = lambda q: (tf.tool_point(c, q) - T[:3, 3]) @ T[:3, :3]
before = np.linalg.norm(bf(qp) - c.tool_point(qp), axis=1)
print(f"uncompensated TRUE mean {before.mean():.4f} max {before.max():.4f} mm")
if rc == 0:
    o = read_table(d / "o" / "prog.csv"); qn = np.stack([o.float(k) for k in c.joint_columns], 1)
    after = np.linalg.norm(bf(qn) - c.tool_point(qp), axis=1)
    print(f"compensated TRUE mean {after.mean():.4f} max {after.max():.4f} mm")
