"""Nominal grinder kinematics: axes (x_mm, z_mm, a_deg) <-> tool point in the WCS (mm).

Tool chain  ``T_tool(z)   = RotZ(θ1)·Trans(l2,0,l1)·Trans(0,0,z)·Trans(l3,0,l4)·Trans(0,0,-R)``
Work chain  ``T_work(x,a) = Trans(l5,0,l6)·Trans(x,0,0)·Trans(l7,0,l8)·RotX(a)``
Tool point in the WCS: ``p = T_work⁻¹ · T_tool · [0 0 0 1]ᵀ``, nominally
``p = (-(l5 + l7 + x), ρ·sin a, ρ·cos a)`` with ``ρ = l1 + l4 - R - l6 - l8 + z``.
"""
from __future__ import annotations

import math

import numpy as np

from .machine import Grinder
from .transforms import apply, check_points, rot_z


def tool_in_machine_nominal(machine: Grinder, z_mm) -> np.ndarray:
    """Nominal tool point in the MCS from the tool chain, shape (n, 3)."""
    z = np.atleast_1d(np.asarray(z_mm, dtype=float))
    local = np.stack([np.full_like(z, machine.l2 + machine.l3), np.zeros_like(z),
                      machine.l1 + z + machine.l4 - machine.R], axis=1)
    return apply(rot_z(np.deg2rad(machine.theta1_deg))[0], local)


def nominal_tool_at_z0(machine: Grinder) -> tuple:
    """The nominal tool point in the MCS at z = 0, ``RotZ(θ1)·(l2 + l3, 0, l1 + l4 - R)``, as
    three floats (:func:`tool_in_machine_nominal` without its array set-up, for inner loops)."""
    th = math.radians(machine.theta1_deg)
    r = machine.l2 + machine.l3
    return (math.cos(th) * r, math.sin(th) * r, machine.l1 + machine.l4 - machine.R)


def forward(machine: Grinder, axes) -> np.ndarray:
    """Nominal tool point in the WCS (mm) for axes (x_mm, z_mm, a_deg), shape (n, 3) -> (n, 3).

    Closed form of ``T_work⁻¹ · T_tool · origin`` (tests check it against the chains).
    """
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    x, z, a = axes[:, 0], axes[:, 1], np.deg2rad(axes[:, 2])
    t = tool_in_machine_nominal(machine, z)
    qx = t[:, 0] - machine.l5 - x - machine.l7
    qy = t[:, 1]
    qz = t[:, 2] - machine.l6 - machine.l8
    c, s = np.cos(a), np.sin(a)
    # RotX(a)ᵀ applied to q
    return np.stack([qx, c * qy + s * qz, -s * qy + c * qz], axis=1)


def inverse(machine: Grinder, points_mm, unwrap: bool = True, a_start_deg: float | None = None) -> np.ndarray:
    """Axes (x_mm, z_mm, a_deg) for WCS tool points, shape (n, 3) -> (n, 3).

    ``x = -(px + l5 + l7 - t_x)``, ``z = sqrt(py² + pz²) - ρ0``, ``a = atan2(py, pz)``.
    With ``unwrap`` the points are a path: A is unwrapped along it (multi-turn paths
    continue past 360°) and the first point is put in ``[a_lo, a_lo + 360)`` of the
    stroke, or nearest to ``a_start_deg`` when given. Without ``unwrap`` each point's A
    lies in ``[a_lo, a_lo + 360)``. On the A axis itself (ρ = 0) A is undefined; 0 is used.
    """
    p = check_points(points_mm, "WCS points (px_mm, py_mm, pz_mm)")
    t0 = tool_in_machine_nominal(machine, np.zeros(1))[0]
    x = t0[0] - machine.l5 - machine.l7 - p[:, 0]
    rho = np.hypot(p[:, 1], p[:, 2])
    # before RotX(a) the tool point sits at (·, t_y, h) with h = t_z(0) - l6 - l8 + z;
    # RotX(a)ᵀ turns it by -a, so |(py, pz)| = hypot(t_y, h) and atan2(py, pz) = a + φ0
    ty = t0[1]
    h = np.sqrt(np.maximum(rho**2 - ty**2, 0.0))
    z = h - (t0[2] - machine.l6 - machine.l8)
    phi0 = np.arctan2(ty, h)
    a = np.rad2deg(np.arctan2(p[:, 1], p[:, 2]) - phi0)
    a_lo = machine.strokes["a_deg"][0]
    if unwrap:
        a = np.rad2deg(np.unwrap(np.deg2rad(a)))
        ref = a_lo if a_start_deg is None else a_start_deg
        if a_start_deg is None:
            shift = 360.0 * np.floor((a[0] - a_lo) / 360.0)
        else:
            shift = 360.0 * np.round((a[0] - ref) / 360.0)
        a = a - shift
    else:
        a = a_lo + np.mod(a - a_lo, 360.0)
    return np.stack([x, z, a], axis=1)
