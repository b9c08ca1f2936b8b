"""Compensation of an arm's joint commands: the joint values that make the calibrated model reach a target.

For each target tool point (and, where the chain has at least 6 joints, the tool orientation the
nominal chain gives at the commanded joints — kept), Newton's method on the calibrated chain
(geometric error slots + the learned residual when kept) from the commanded joints: position (and
orientation) rows of the chain's joint Jacobian, the minimum-norm joint change (pseudo-inverse) for a
redundant chain such as a 7-joint arm. The learned residual's slope enters the Jacobian in closed
form (:meth:`training.arm_residual.ArmResidualRegressor.predict_and_jacobian`). ``chain`` is the
calibrated model's chain (``GeometricResult.chain``: with compliance / harmonic joint slots where
the geometric stage has them). Shapes: ``q`` (n, nq) in the joints' units, targets (n, 3) mm.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEWTON_MAX_ITER = 30
NEWTON_TOL_MM = 1e-6      # position residual at which a point has converged
NEWTON_TOL_RAD = 1e-9     # orientation residual likewise
LEVER_MM = 100.0          # orientation rows weighted as a 100 mm lever: comparable to position in mm


@dataclass
class ArmSolution:
    """``q`` (n, nq) compensated commands; ``residual_mm`` (n,) MODEL residual |target − model(q)|;
    ``angle_rad`` (n,) orientation residual (0 where not kept); ``converged`` (n,) bool."""

    q: np.ndarray
    residual_mm: np.ndarray
    angle_rad: np.ndarray
    converged: np.ndarray
    orientation_kept: bool


def _rotvec(R):
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_rotvec()


def model_point(chain, params, learner, q) -> np.ndarray:
    """Calibrated model's tool point, mm, (n, 3)."""
    p = chain.tool_point(q, params)
    return p if learner is None else p + learner.predict(q)


def solve_joints(chain, params, learner, target_mm, q_cmd, keep_orientation: bool = True,
                 target_R=None) -> ArmSolution:
    """Joint commands that make the calibrated chain reach ``target_mm`` (n, 3), Newton from ``q_cmd``.

    ``target_R`` (n, 3, 3): tool orientations to keep (default: the CALIBRATED chain's at ``q_cmd``: the
    tool keeps the orientation it has at the programmed joints and only its point moves; tracker points
    carry no orientation, so the calibrated roll of the tool about its own axis is a gauge choice of the
    fit — a nominal-orientation target would turn the wrist by that arbitrary angle);
    orientation is kept when ``keep_orientation`` and the chain has ≥ 6 joints.
    """
    q = np.array(q_cmd, float)
    target = np.asarray(target_mm, float)
    orient = keep_orientation and chain.n_joints >= 6
    if orient and target_R is None:
        target_R = chain.frames(q, params)[:, -1, :3, :3]
    lo, hi = chain.joint_lo, chain.joint_hi
    for _ in range(NEWTON_MAX_ITER):
        F = chain.frames(q, params)
        J = chain.joint_jacobian(q, params, orientation=orient, frames=F)
        if learner is None:
            dp = target - F[:, -1, :3, 3]
        else:
            m, Jl = learner.predict_and_jacobian(q)
            dp = target - F[:, -1, :3, 3] - m
            J[:, :3] += Jl
        if orient:
            dr = _rotvec(target_R @ np.swapaxes(F[:, -1, :3, :3], 1, 2))
            r = np.concatenate([dp, LEVER_MM * dr], 1)
            J = np.concatenate([J[:, :3], LEVER_MM * J[:, 3:]], 1)
        else:
            r, dr = dp, np.zeros_like(dp)
        done = (np.linalg.norm(dp, axis=1) < NEWTON_TOL_MM) & (np.linalg.norm(dr, axis=1) < NEWTON_TOL_RAD)
        if done.all():
            break
        q = q + np.einsum("nij,nj->ni", np.linalg.pinv(J), r)
    F = chain.frames(q, params)
    dp = target - (F[:, -1, :3, 3] if learner is None else F[:, -1, :3, 3] + learner.predict(q))
    ang = np.linalg.norm(_rotvec(target_R @ np.swapaxes(F[:, -1, :3, :3], 1, 2)), axis=1) if orient \
        else np.zeros(len(q))
    res = np.linalg.norm(dp, axis=1)
    ok = (res < 10 * NEWTON_TOL_MM) & (ang < 10 * NEWTON_TOL_RAD + (0 if orient else np.inf)) \
        & np.all((q >= lo) & (q <= hi), axis=1)
    return ArmSolution(q, res, ang, ok, orient)
