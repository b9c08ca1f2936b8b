"""The 3-TPT translational tripod: kinematics and the error transfer matrices of the tripod paper.

Leg ``i`` is ``p + a_i - b_i`` (platform centre ``p``, moving hinge ``a_i``, fixed hinge ``b_i``) of length
``l_i``; differentiating gives ``A dp = dl + U_B(dB) - U_A(dA)`` (``A`` rows ``u_iᵀ``, (3, 3)), so
``f_l = A⁻¹``, ``f_B_i = A⁻¹ e_i u_iᵀ``, ``f_A_i = −f_B_i`` (the paper's eqs (4)-(12)); sensitivity
``K = ||A⁻¹||_inf``, size ratio ``lambda = l / c`` with ``c = R - r``
(``docs/explanation/parallel-kinematics.md``)."""
from __future__ import annotations

import numpy as np

from .hexapod import inverse_kinematics, leg_vectors
from .machine_file import PKM

__all__ = ["transfer_matrices", "leg_error_norm", "sensitivity_vs_lambda", "sensitivity_study"]


def transfer_matrices(machine: PKM, tool_tip_mm) -> dict:
    """Error transfer matrices at platform positions (n, 3).

    Returns ``f_l`` shape (n, 3, 3) (leg-length errors -> position error), ``f_B`` shape (n, 3, 3, 3)
    (``f_B[:, i]`` maps hinge ``i``'s fixed-platform position error to position error) and ``f_A``
    (same for the moving-platform hinges), and ``A`` shape (n, 3, 3).
    """
    v = leg_vectors(machine, tool_tip_mm)
    u = v / np.linalg.norm(v, axis=-1, keepdims=True)  # (n, 3 legs, 3)
    Ainv = np.linalg.inv(u)
    # f_B_i = A^-1 e_i u_i^T : column i of A^-1 times u_i^T
    f_B = np.einsum("nji,nik->nijk", Ainv, u)
    return {"A": u, "f_l": Ainv, "f_B": f_B, "f_A": -f_B}


def leg_error_norm(machine: PKM, tool_tip_mm) -> np.ndarray:
    """``K = ||A^-1||_inf`` (max absolute row sum of the leg-length transfer matrix), shape (n,)."""
    return np.abs(transfer_matrices(machine, tool_tip_mm)["f_l"]).sum(axis=2).max(axis=1)


def sensitivity_vs_lambda(machine: PKM, lambdas, offset_xy_mm=(0.0, 0.0)) -> np.ndarray:
    """``K`` against the size ratio ``lambda = l / c`` (leg length over ``c = R - r``), shape (m,).

    For each ``lambda`` the platform is placed at ``offset_xy_mm`` with the height at which the
    mean leg length equals ``lambda * c`` (``c`` from the machine's radii).
    """
    R = np.linalg.norm(machine.base_joints_mm[0, :2])
    r = np.linalg.norm(machine.platform_joints_mm[0, :2])
    c = R - r
    lam = np.asarray(lambdas, float)
    target = lam * c
    off = np.asarray(offset_xy_mm, float)
    horiz = leg_vectors(machine, np.array([[off[0], off[1], 0.0]]))[0]  # leg vectors at z = 0
    # mean over legs of sqrt(h_i^2 + z^2) = target: solve by Newton in z
    z = np.sqrt(np.maximum(target ** 2 - (horiz[:, :2] ** 2).sum(1).mean(), 1.0))
    h2 = (horiz[:, :2] ** 2).sum(1)
    for _ in range(30):
        L = np.sqrt(h2[None] + z[:, None] ** 2)
        f = L.mean(1) - target
        z = z - f / (z[:, None] / L).mean(1)
    p = np.c_[np.full_like(z, off[0]), np.full_like(z, off[1]), z]
    return leg_error_norm(machine, p)


def sensitivity_study(machine: PKM, lambdas=None, offsets_xy_mm=((0.0, 0.0), (80.0, -60.0)), radial_mm=None,
                      heights_mm=None, azimuth_deg: float = 0.0) -> dict:
    """The tripod paper's findings as data: ``K`` against ``lambda`` and over the workspace.

    ``lambdas`` (m,) (default: 40 values spanning the leg range, ``leg_min / c .. leg_max / c``);
    ``K_lambda`` (len(offsets_xy_mm), m): :func:`sensitivity_vs_lambda` at each horizontal offset.
    The map is a vertical section through the fixed platform's axis at ``azimuth_deg``:
    ``radial_mm`` (nr,) horizontal distance from the axis, ``heights_mm`` (nh,) distance of the moving
    platform (tool point) from the fixed platform's hinge plane; ``K_map`` (nr, nh), NaN where a leg
    leaves its range. Returns those arrays plus ``c_mm`` and ``base_plane_z_mm``.
    """
    R = np.linalg.norm(machine.base_joints_mm[0, :2])
    r = np.linalg.norm(machine.platform_joints_mm[0, :2])
    c = R - r
    if lambdas is None:
        lambdas = np.linspace(machine.leg_min_mm.max() / c, machine.leg_max_mm.min() / c, 40)
    lambdas = np.asarray(lambdas, float)
    K_lambda = np.stack([sensitivity_vs_lambda(machine, lambdas, off) for off in offsets_xy_mm])
    z0 = float(machine.base_joints_mm[:, 2].mean())
    if heights_mm is None:
        heights_mm = np.linspace(machine.leg_min_mm.max() * 0.8, machine.leg_max_mm.min(), 60)
    if radial_mm is None:
        radial_mm = np.linspace(0.0, 0.5 * c + r, 40)
    heights_mm, radial_mm = np.asarray(heights_mm, float), np.asarray(radial_mm, float)
    az = np.radians(azimuth_deg)
    Rg, Hg = np.meshgrid(radial_mm, heights_mm, indexing="ij")
    p = np.stack([Rg.ravel() * np.cos(az), Rg.ravel() * np.sin(az), z0 + Hg.ravel()], axis=1)
    K = leg_error_norm(machine, p)
    legs = inverse_kinematics(machine, p)
    K[np.any((legs < machine.leg_min_mm) | (legs > machine.leg_max_mm), axis=1)] = np.nan
    return {"lambdas": lambdas, "offsets_xy_mm": np.asarray(offsets_xy_mm, float), "K_lambda": K_lambda,
            "radial_mm": radial_mm, "heights_mm": heights_mm, "K_map": K.reshape(Rg.shape), "c_mm": c,
            "base_plane_z_mm": z0, "azimuth_deg": azimuth_deg}
