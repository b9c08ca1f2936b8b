"""Nominal grinder kinematics: axes (x_mm, z_mm, a_deg) <-> tool point in the WCS (mm).

Tool chain  ``T_tool(z)   = RotZ(θ1)·Trans(l2,0,l1)·Trans(0,0,z)·Trans(l3,0,l4)·Trans(0,0,-R)``
Work chain  ``T_work(x,a) = Trans(l5,0,l6)·Trans(x,0,0)·Trans(l7,0,l8)·RotX(a)``
Tool point in the WCS: ``p = T_work⁻¹ · T_tool · [0 0 0 1]ᵀ``, nominally
``p = (-(l5 + l7 + x), ρ·sin a, ρ·cos a)`` with ``ρ = l1 + l4 - R - l6 - l8 + z``.

One source for the kinematics: the chains are the grinder's chain file
(:func:`errormap.grinder_file.grinder_chain`, the built-in ``grinder-chain.toml`` with the grinder
file's geometry), compiled once per file. ``forward`` is the chain's compiled nominal forward
kinematics (:class:`errormap.chain_kernel.CompiledNominal`); ``inverse`` is the chain engine's closed
form for its structure (:meth:`errormap.machine_tool.MachineTool.closed_form_inverse`: one rotary axis
next to the workpiece, two linear axes after it), compiled
(:func:`errormap.chain_kernel.closed_form_solver`), with the A unwrap along a path.
"""
from __future__ import annotations

import numpy as np

from .machine import Grinder
from .transforms import check_points


def _chain(machine: Grinder):
    """The machine's chain (a grinder file's compiled once, a chain itself)."""
    from .grinder_file import machine_tool_of
    return machine_tool_of(machine)


def _axes_at_z(z) -> np.ndarray:
    """Axes (0, z, 0) for z shape (n,): the tool side moves with Z only."""
    z = np.atleast_1d(np.asarray(z, dtype=float))
    ax = np.zeros((z.shape[0], 3))
    ax[:, 1] = z
    return ax


def tool_in_machine_nominal(machine: Grinder, z_mm) -> np.ndarray:
    """Nominal tool point in the MCS from the tool chain, shape (n, 3)."""
    return _chain(machine).side_frames("tool", _axes_at_z(z_mm))[1]


def nominal_tool_at_z0(machine: Grinder) -> tuple:
    """The nominal tool point in the MCS at z = 0, ``RotZ(θ1)·(l2 + l3, 0, l1 + l4 - R)``, as
    three floats (:func:`tool_in_machine_nominal` at z = 0, for inner loops)."""
    t = tool_in_machine_nominal(machine, [0.0])[0]
    return (float(t[0]), float(t[1]), float(t[2]))


def forward(machine: Grinder, axes) -> np.ndarray:
    """Nominal tool point in the WCS (mm) for axes (x_mm, z_mm, a_deg), shape (n, 3) -> (n, 3).

    ``T_work⁻¹ · T_tool · origin`` through the grinder's compiled chain
    (:meth:`errormap.chain_kernel.CompiledNominal.tool_points`).
    """
    from .chain_kernel import grinder_nominal
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    return grinder_nominal(machine).tool_points(axes)


def inverse(machine: Grinder, points_mm, unwrap: bool = True, a_start_deg: float | None = None) -> np.ndarray:
    """Axes (x_mm, z_mm, a_deg) for WCS tool points, shape (n, 3) -> (n, 3).

    The chain's closed form (:meth:`errormap.machine_tool.MachineTool.closed_form_inverse`), compiled
    (:func:`errormap.chain_kernel.closed_form_solver`), with its rotary axis put on a turn as
    :meth:`errormap.machine_tool.MachineTool.inverse_closed` does; on the grinder ``x = -(px + l5 + l7 - t_x)``, ``z = sqrt(py² + pz²) - ρ0``, ``a = atan2(py, pz)``.
    With ``unwrap`` the points are a path: A is unwrapped along it (multi-turn paths
    continue past 360°) and the first point is put in ``[a_lo, a_lo + 360)`` of the
    stroke, or nearest to ``a_start_deg`` when given. Without ``unwrap`` each point's A
    lies in ``[a_lo, a_lo + 360)``. On the A axis itself (ρ = 0) A is undefined; 0 is used.
    """
    from .machine_tool import rotary_on_turn
    from .chain_kernel import closed_form_solver
    p = check_points(points_mm, "WCS points (px_mm, py_mm, pz_mm)")
    solve = closed_form_solver(_chain(machine))
    if not unwrap:  # each point's A in [a_lo, a_lo + 360) in the same compiled pass
        return solve(p, fold=True)
    q = solve(p)
    r = solve.k.rotary
    q[:, r] = rotary_on_turn(q[:, r], solve.k.rotary_lo, unwrap=True, a_start_deg=a_start_deg)
    return q
