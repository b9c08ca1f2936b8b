"""Serial arms from real laser-tracker poses: ``volcomp calibrate`` held out, beside the plain baselines.

Real data (shared; the benchmark records no figure where it is absent): a UR5 (1,000 poses) and a WAM (216
poses). Outer folds (random, seeded): every decision of :func:`calibrate_arm` (the command's own code: the
geometric slot set, the learned stage kept or not, its kernel) is made by CV inside the fit part; the held-out
fold only reports. MEASURED residual: position error norm on the held-out poses, pooled mean (mm), of the stage
volcomp keeps beside plain geometric least squares and a plain GP on its residual.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from compensation.app.workflows.arm_calibration import calibrate_arm
from errormap.arm_poses import read_arm_poses
from errormap.machine import load_machine

DATA_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "serial-arms"

TITLE = "Serial arms on real tracker poses: the kept stage held out, beside plain least squares"
DATA = ("real UR5 (1,000 poses) and WAM (216 poses) tracker data; 5 random outer folds for the WAM, 2 for the UR5 "
        "(quick: the WAM, one 80/20 split), 3-fold CV inside each fit part")


def folds(n: int, k: int, seed: int):
    lab = np.random.default_rng(seed).permutation(n) % k
    return [(lab != f, lab == f) for f in range(k)]


def arm_errors(name: str, n_folds: int, seed: int, only_first: bool = False) -> dict:
    chain = load_machine(name)
    data = read_arm_poses(DATA_DIR / f"{name}_grid.csv", chain)
    pooled = {"kept": [], "plain": [], "plain_gp": []}
    for k, (tr, te) in enumerate(folds(len(data.q), n_folds, seed)):
        if only_first and k:
            break
        fit, check = data.subset(np.flatnonzero(tr)), data.subset(np.flatnonzero(te))
        core = calibrate_arm(chain, fit, check, learned=True, k_folds=3, n_restarts=1, seed=seed, log=io.StringIO())
        err = lambda pred: np.linalg.norm(check.xyz_mm - pred, axis=1)  # noqa: E731
        kgeo, kl, pl = core["geometric_model"], core["kept_learner"], core["plain_model"]
        pooled["kept"].append(err(kgeo.predict(check.q) + (0.0 if kl is None else kl.predict(check.q))))
        pooled["plain"].append(err(pl.predict(check.q)))
        pooled["plain_gp"].append(err(pl.predict(check.q) + core["plain_gp"].predict(check.q)))
    return {k: float(np.concatenate(v).mean()) for k, v in pooled.items()}


def run(quick: bool, seed: int) -> dict:
    if not DATA_DIR.is_dir():
        return {"figures": [], "notes": ["The real arm data are absent on this machine: no figure."]}
    arms = {"wam": 5} if quick else {"wam": 5, "ur5": 2}
    figs = []
    for name, k in arms.items():
        e = arm_errors(name, k, seed, only_first=quick)
        figs.append({"what": f"{name.upper()}: kept stage, held-out mean", "value": e["kept"], "unit": "mm",
                     "residual": "measured", "anchor": "plain geometric least squares", "anchor_value": e["plain"]})
        figs.append({"what": f"{name.upper()}: plain GP on the plain residual, held-out mean", "value": e["plain_gp"],
                     "unit": "mm", "residual": "measured", "anchor": "plain geometric least squares",
                     "anchor_value": e["plain"]})
    return {"figures": figs, "notes": []}
