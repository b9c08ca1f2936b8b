"""The parametric model of a PKM's measured poses: the parameter vector's layout, the
registration of the instrument frame, and the poses (and their measured residual) that a
parameter set predicts.

Used by the calibrator (:mod:`errormap.pkm.calibration`), the leg-space loop
(:mod:`errormap.pkm.legspace`) and the pose simulator; it imports none of them (the pose data
are read from the object given: ``q``, ``tip_mm``, ``rotation``).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from .hexapod import forward_kinematics
from .machine_file import PKM


# ---------------------------------------------------------------------------------------------
# parameter layout
# ---------------------------------------------------------------------------------------------

def parameter_names(machine: PKM, scales: bool = True) -> list[str]:
    """Names of the parameters in vector order, e.g. ``b1_x_mm``, ``a3_z_mm``, ``o2_mm``, ``s6``."""
    k = machine.n_legs
    names = [f"b{i + 1}_{c}_mm" for i in range(k) for c in "xyz"]
    names += [f"a{i + 1}_{c}_mm" for i in range(k) for c in "xyz"]
    names += [f"o{i + 1}_mm" for i in range(k)]
    if scales:
        names += [f"s{i + 1}" for i in range(k)]
    return names


def parameter_vector(machine: PKM) -> np.ndarray:
    """Full parameter vector (base, platform, offsets, scales), shape (8k,)."""
    return np.concatenate([machine.base_joints_mm.ravel(), machine.platform_joints_mm.ravel(),
                           machine.leg_offset_mm, machine.leg_scale])


def machine_from_vector(machine: PKM, r: np.ndarray) -> PKM:
    """A copy of ``machine`` with the parameters of ``r`` (shape (7k,) or (8k,))."""
    k = machine.n_legs
    r = np.asarray(r, float)
    return replace(machine, base_joints_mm=r[:3 * k].reshape(k, 3).copy(),
                   platform_joints_mm=r[3 * k:6 * k].reshape(k, 3).copy(),
                   leg_offset_mm=r[6 * k:7 * k].copy(),
                   leg_scale=r[7 * k:8 * k].copy() if r.size >= 8 * k else machine.leg_scale.copy())


def rigid_motion_basis(points_mm: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3k, 6) of the infinitesimal rigid motions of ``points_mm`` (k, 3)."""
    k = len(points_mm)
    cols = [np.tile(e, k) for e in np.eye(3)]
    cols += [np.cross(e, points_mm).ravel() for e in np.eye(3)]
    return np.linalg.qr(np.stack(cols, 1))[0]


# ---------------------------------------------------------------------------------------------
# registration (instrument frame <- machine frame)
# ---------------------------------------------------------------------------------------------

def robust_registration(machine_tip_mm: np.ndarray, measured_tip_mm: np.ndarray, n_iter: int = 5,
                        trim_sigma: float = 3.0):
    """Trimmed Kabsch fit ``measured = R p + t``: returns ``(t_mm (3,), R (3, 3), inlier mask (n,))``.

    Starts from all points; drops points beyond ``trim_sigma`` robust sigmas (MAD) and refits.
    """
    p, m = np.asarray(machine_tip_mm, float), np.asarray(measured_tip_mm, float)
    if len(p) < 3:
        raise ValueError("registration needs at least 3 poses")
    inl = np.ones(len(p), bool)
    for _ in range(n_iter):
        pc, mc = p[inl].mean(0), m[inl].mean(0)
        rot, _ = Rotation.align_vectors(m[inl] - mc, p[inl] - pc)
        R = rot.as_matrix()
        t = mc - R @ pc
        e = np.linalg.norm(m - (p @ R.T + t), axis=1)
        s = 1.4826 * np.median(np.abs(e - np.median(e))) + 1e-12
        new = e <= np.median(e) + trim_sigma * s
        if new.sum() < max(3, len(p) // 2) or np.array_equal(new, inl):
            break
        inl = new
    return t, R, inl


def predict_poses(machine: PKM, frame, q: np.ndarray, leg_terms=None, nominal: PKM | None = None):
    """Measured poses (instrument frame) predicted by ``machine`` (+ ``leg_terms``, whose features use
    ``nominal``) and ``frame`` = (t (3,), R (3, 3)) at drive commands ``q`` (n, k): (tip (n, 3), R (n, 3, 3))."""
    t, R = frame
    legs = machine.drive_to_legs(q)
    if leg_terms:
        legs = legs + leg_terms.correction_mm(nominal if nominal is not None else machine, q)
    fk = forward_kinematics(machine, legs, check_limits=False)
    return fk.x @ R.T + t, np.einsum("ij,njk->nik", R, fk.platform2base)


def pose_errors_um(machine: PKM, frame, data, leg_terms=None, nominal: PKM | None = None) -> dict:
    """Measured residual (measurement minus model) on ``data`` (a
    :class:`errormap.pkm.poses.PoseData`): ``position_um`` (n,) (norm) and, with
    orientations, ``angle_urad`` (n,)."""
    tip, R = predict_poses(machine, frame, data.q, leg_terms, nominal)
    out = {"position_um": 1e3 * np.linalg.norm(data.tip_mm - tip, axis=1)}
    if data.rotation is not None:
        rv = Rotation.from_matrix(np.einsum("nij,nkj->nik", R, data.rotation)).as_rotvec()
        out["angle_urad"] = 1e6 * np.linalg.norm(rv, axis=1)
    return out
