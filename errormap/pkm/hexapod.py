"""Kinematics of the 6-UPS Stewart hexapod (and the shared leg-length machinery of the tripod).

The base (machine) frame holds the base joints; the platform frame the platform joints and the tool tip
(``tool_in_platform_mm``; the hexapod's at ``(0, 0, -lt)``). A tool pose is the tip in the base frame (n, 3)
plus ``platform2base`` rotations (n, 3, 3); leg ``i`` is ``tip + R (a_i - t) - b_i``. Orientation input:
fixed-axis angles ``(rx, ry, rz)`` deg (``R = Rz Ry Rx``), unit quaternions ``(qx, qy, qz, qw)``, or a
tool-axis direction turned into the paper's ``R = Rz(alpha) Rx(beta) Rz(gamma)`` with ``gamma = -alpha``
(no spin about the platform's z). Conventions: ``docs/reference/file-formats.md``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .machine_file import PKM


class KinematicsError(ValueError):
    """Forward/inverse kinematics failed (no convergence, or a leg out of its range)."""


# ---------------------------------------------------------------------------------------------
# orientation helpers
# ---------------------------------------------------------------------------------------------

def angles_to_rotation(angles_deg) -> np.ndarray:
    """Fixed-axis X-Y-Z angles (deg), shape (n, 3) -> ``platform2base`` matrices, shape (n, 3, 3)."""
    return Rotation.from_euler("xyz", np.atleast_2d(angles_deg), degrees=True).as_matrix()


def rotation_to_angles(R) -> np.ndarray:
    """Rotation matrices (n, 3, 3) -> fixed-axis X-Y-Z angles (deg), shape (n, 3)."""
    return Rotation.from_matrix(R).as_euler("xyz", degrees=True)


def quat_to_rotation(q_xyzw) -> np.ndarray:
    """Unit quaternions ``(qx, qy, qz, qw)``, shape (n, 4) -> matrices (n, 3, 3)."""
    q = np.atleast_2d(np.asarray(q_xyzw, float))
    norm = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norm - 1) > 1e-3):
        bad = np.flatnonzero(np.abs(norm - 1) > 1e-3)
        raise ValueError(f"quaternions must be unit (qx qy qz qw); rows {bad.tolist()[:10]} have norms {norm[bad][:10]}")
    return Rotation.from_quat(q).as_matrix()


def tool_axis_euler(axis) -> np.ndarray:
    """The paper's Euler angles (alpha, beta, gamma) in rad from tool-axis vectors, shape (n, 3) -> (n, 3).

    ``R = Rz(alpha) Rx(beta) Rz(gamma)`` has last column ``(sin a sin b, -cos a sin b, cos b)``;
    ``beta = -+theta_z`` and ``alpha = arcsin(n_x / sin beta)``, the sign rule of the paper (minus when
    ``n_y >= 0``), and ``gamma = -alpha`` (no spin about the platform's own z axis).
    """
    n = np.atleast_2d(np.asarray(axis, float))
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    theta_z = np.arccos(np.clip(n[:, 2], -1.0, 1.0))
    beta = np.where(n[:, 1] >= 0, -theta_z, theta_z)
    s = np.sin(beta)
    safe = np.where(np.abs(s) > 1e-15, s, 1.0)
    # = arcsin(n_x / sin beta) (cos alpha >= 0 by the sign rule), in the numerically stable atan2 form
    alpha = np.where(np.abs(s) > 1e-15, np.arctan2(n[:, 0] / safe, -n[:, 1] / safe), 0.0)
    return np.stack([alpha, beta, -alpha], axis=1)


def tool_axis_to_rotation(axis) -> np.ndarray:
    """Tool-axis vectors (n, 3) -> ``platform2base`` matrices (n, 3, 3) by the paper's convention."""
    return Rotation.from_euler("ZXZ", tool_axis_euler(axis)).as_matrix()


# ---------------------------------------------------------------------------------------------
# inverse kinematics (tool pose -> leg lengths), batched
# ---------------------------------------------------------------------------------------------

def _as_rotations(R, n):
    if R is None:
        return np.broadcast_to(np.eye(3), (n, 3, 3))
    R = np.asarray(R, float)
    if R.shape == (3, 3):
        R = np.broadcast_to(R, (n, 3, 3))
    if R.shape != (n, 3, 3):
        raise ValueError(f"expected rotations of shape ({n}, 3, 3), got {R.shape}")
    return R


def leg_vectors(machine: PKM, tool_tip_mm, platform2base=None) -> np.ndarray:
    """Leg vectors (platform joint minus base joint, base frame), shape (n, k, 3).

    ``tool_tip_mm`` shape (n, 3); ``platform2base`` shape (n, 3, 3) (identity when ``None``,
    the tripod's case).
    """
    tip = np.atleast_2d(np.asarray(tool_tip_mm, float))
    R = _as_rotations(platform2base, len(tip))
    rel = machine.platform_joints_mm - machine.tool_in_platform_mm  # (k, 3)
    return tip[:, None, :] + np.einsum("nij,kj->nki", R, rel) - machine.base_joints_mm[None]


def inverse_kinematics(machine: PKM, tool_tip_mm, platform2base=None, check_limits: bool = False) -> np.ndarray:
    """Tool poses -> leg lengths (mm), shape (n, k). ``check_limits`` raises naming the rows out of range."""
    legs = np.linalg.norm(leg_vectors(machine, tool_tip_mm, platform2base), axis=-1)
    if check_limits:
        check_leg_limits(machine, legs)
    return legs


def check_leg_limits(machine: PKM, legs_mm, what: str = "pose") -> None:
    """Raise :class:`KinematicsError` listing the rows whose legs leave ``[leg_min_mm, leg_max_mm]``."""
    legs_mm = np.atleast_2d(legs_mm)
    bad = np.any((legs_mm < machine.leg_min_mm) | (legs_mm > machine.leg_max_mm), axis=1)
    if np.any(bad):
        rows = np.flatnonzero(bad)
        raise KinematicsError(
            f"{rows.size} {what}(s) put a leg outside its range [{machine.leg_min_mm.min():g}, "
            f"{machine.leg_max_mm.max():g}] mm: rows {rows[:20].tolist()}{' ...' if rows.size > 20 else ''}; "
            f"first offending legs {np.round(legs_mm[rows[0]], 3).tolist()}")


# ---------------------------------------------------------------------------------------------
# forward kinematics (leg lengths -> tool pose) by Newton on the inverse, several starts
# ---------------------------------------------------------------------------------------------

@dataclass
class FKResult:
    """Forward-kinematics result (scipy.optimize style).

    ``x``: tool tip, shape (n, 3); ``platform2base``: shape (n, 3, 3); ``success``: shape (n,);
    ``residuals``: leg-length misfit (mm), shape (n, k); ``nfev``: Newton iterations per point (n,).
    """

    x: np.ndarray
    platform2base: np.ndarray
    success: np.ndarray
    message: str
    nfev: np.ndarray
    residuals: np.ndarray

    @property
    def angles_deg(self) -> np.ndarray:
        return rotation_to_angles(self.platform2base)


def _newton(machine: PKM, legs, tip, R, rotate: bool, tol_mm: float, max_iter: int):
    """Vectorised Newton: unknowns tip (3) and, when ``rotate``, a left rotation increment (3)."""
    n = len(legs)
    tip, R = tip.copy(), R.copy()
    nit = np.zeros(n, int)
    active = np.ones(n, bool)
    rel = machine.platform_joints_mm - machine.tool_in_platform_mm
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        Ra = np.einsum("nij,kj->nki", R[idx], rel)  # (m, k, 3)
        v = tip[idx, None, :] + Ra - machine.base_joints_mm[None]
        L = np.linalg.norm(v, axis=-1)
        g = L - legs[idx]
        done = np.max(np.abs(g), axis=1) < tol_mm
        active[idx[done]] = False
        idx, v, L, g, Ra = idx[~done], v[~done], L[~done], g[~done], Ra[~done]
        if idx.size == 0:
            break
        u = v / L[..., None]
        J = np.concatenate([u, np.cross(Ra, u)], axis=-1) if rotate else u  # (m, k, 6|3)
        try:
            step = np.linalg.solve(J, -g[..., None])[..., 0]
        except np.linalg.LinAlgError:  # singular configuration: damped least squares
            JtJ = np.einsum("mki,mkj->mij", J, J) + 1e-9 * np.eye(J.shape[-1])
            step = np.linalg.solve(JtJ, -np.einsum("mki,mk->mi", J, g)[..., None])[..., 0]
        # limit the step to keep Newton in the assembly mode's basin
        scale = np.minimum(1.0, 200.0 / np.maximum(np.linalg.norm(step[:, :3], axis=1), 1e-300))
        if rotate:
            scale = np.minimum(scale, 0.3 / np.maximum(np.linalg.norm(step[:, 3:], axis=1), 1e-300))
        step *= scale[:, None]
        tip[idx] += step[:, :3]
        if rotate:
            R[idx] = Rotation.from_rotvec(step[:, 3:]).as_matrix() @ R[idx]
        nit[idx] += 1
    Ra = np.einsum("nij,kj->nki", R, rel)
    g = np.linalg.norm(tip[:, None, :] + Ra - machine.base_joints_mm[None], axis=-1) - legs
    return tip, R, g, nit


def forward_kinematics(machine: PKM, legs_mm, guess_tip_mm=None, guess_platform2base=None,
                       tol_mm: float = 1e-9, max_iter: int = 50, raise_on_failure: bool = True,
                       check_limits: bool = True) -> FKResult:
    """Leg lengths (n, k) -> tool poses, by Newton on the inverse kinematics with several starts.

    Starts: the given guess (if any), then the machine's home pose and a few poses around it;
    per point the converged solution nearest the first start is kept. Raises
    :class:`KinematicsError` naming the rows that leave the leg range or do not converge
    (unless ``raise_on_failure`` is False, then ``success`` says which).
    """
    legs = np.atleast_2d(np.asarray(legs_mm, float))
    if legs.shape[1] != machine.n_legs:
        raise ValueError(f"expected legs of shape (n, {machine.n_legs}), got {legs.shape}")
    n = len(legs)
    rotate = machine.kind == "hexapod"
    if check_limits:
        check_leg_limits(machine, legs, "leg command")
    home = machine.home_tool_tip_mm
    starts = []
    if guess_tip_mm is not None:
        starts.append((np.broadcast_to(guess_tip_mm, (n, 3)).astype(float),
                       _as_rotations(guess_platform2base, n).astype(float)))
    # mean leg length moves the home height; tilted starts for robustness
    dz = legs.mean(axis=1) - np.linalg.norm(leg_vectors(machine, home[None])[0], axis=-1).mean()
    base_tip = home[None] + np.c_[np.zeros((n, 2)), dz]
    tilts = [(0, 0, 0), (10, 0, 0), (-10, 0, 0), (0, 10, 0), (0, -10, 0)] if rotate else [(0, 0, 0)]
    for k, t in enumerate(tilts):
        off = np.array([0.0, 0.0, 0.0]) if k == 0 else np.array([0.0, 0.0, 50.0 * (-1) ** k])
        starts.append((base_tip + off, np.broadcast_to(angles_to_rotation(np.array(t, float))[0], (n, 3, 3)).copy()))
    tip = np.full((n, 3), np.nan)
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    res = np.full((n, machine.n_legs), np.inf)
    nfev = np.zeros(n, int)
    ok = np.zeros(n, bool)
    for s_tip, s_R in starts:
        todo = np.flatnonzero(~ok)
        if todo.size == 0:
            break
        t, r, g, it = _newton(machine, legs[todo], s_tip[todo], s_R[todo], rotate, tol_mm, max_iter)
        conv = np.max(np.abs(g), axis=1) < max(tol_mm * 10, 1e-8)
        if rotate:  # the working assembly mode: platform above the base, tool axis up
            conv &= (r[:, 2, 2] > 0.2) & (t[:, 2] > 0)
        nfev[todo] += it
        sel = todo[conv]
        tip[sel], R[sel], res[sel] = t[conv], r[conv], g[conv]
        ok[sel] = True
        better = todo[~conv]
        res[better] = np.where(np.isinf(res[better]), g[~conv], res[better])
    msg = "converged" if ok.all() else f"{(~ok).sum()} of {n} points did not converge"
    if raise_on_failure and not ok.all():
        rows = np.flatnonzero(~ok)
        raise KinematicsError(f"forward kinematics did not converge for rows {rows[:20].tolist()}"
                              f"{' ...' if rows.size > 20 else ''} (legs {np.round(legs[rows[0]], 3).tolist()})")
    return FKResult(x=tip, platform2base=R, success=ok, message=msg, nfev=nfev, residuals=res)


def workspace_poses(machine: PKM, n: int, seed, half_width_mm=(150.0, 150.0, 100.0),
                    max_tilt_deg: float = 15.0) -> tuple[np.ndarray, np.ndarray]:
    """Random reachable tool poses around the home tip: tips (n, 3), ``platform2base`` (n, 3, 3).

    Uniform in a box of ``half_width_mm`` about ``home_tool_tip_mm``; tool axis tilted by at most
    ``max_tilt_deg`` (tripod: identity). Poses with a leg out of range are redrawn.
    """
    rng = np.random.default_rng(seed)
    tips, Rs = [], []
    got = 0
    while got < n:
        m = 2 * (n - got) + 8
        tip = machine.home_tool_tip_mm + rng.uniform(-1, 1, (m, 3)) * np.asarray(half_width_mm)
        if machine.kind == "hexapod":
            tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform(0, 1, m))
            az = rng.uniform(0, 2 * np.pi, m)
            axis = np.c_[np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
            R = tool_axis_to_rotation(axis)
        else:
            R = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
        legs = inverse_kinematics(machine, tip, R)
        ok = np.all((legs > machine.leg_min_mm + 5) & (legs < machine.leg_max_mm - 5), axis=1)
        tips.append(tip[ok])
        Rs.append(R[ok])
        got += ok.sum()
    return np.concatenate(tips)[:n], np.concatenate(Rs)[:n]
