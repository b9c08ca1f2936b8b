"""The common solver interface: ``solve(field, targets) -> SolveResult``.

Problem (the grinder paper's method): for each WCS target ``p_d`` find the commanded
target ``p_r`` inside the 250 μm ball around ``p_d`` such that the machine, commanded to
the axes of ``p_r`` (nominal inverse kinematics), lands on ``p_d``::

    minimise |p_r + E(axes(p_r))·1e-3 - p_d|²   subject to |p_r - p_d| ≤ 250 μm

The *model residual* of a solution is ``p_r + E(axes(p_r)) - p_d`` in μm (docs/explanation/kinematics.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BALL_RADIUS_UM = 250.0


@dataclass
class SolveResult:
    """One result object per solver call (scipy.optimize style), batched over n targets.

    Attributes
    ----------
    method : str
    targets_mm : shape (n, 3)      WCS targets p_d
    commands_mm : shape (n, 3)     compensated WCS targets p_r
    axes : shape (n, 3)            axis commands (x_mm, z_mm, a_deg) of p_r (A unwrapped along the path)
    residual_um : shape (n, 3)     model residual p_r + E(axes(p_r)) - p_d
    correction_um : shape (n,)     |p_r - p_d|
    success : shape (n,) bool      converged and inside the ball
    nfev : int                     field evaluations (points × calls)
    seconds : float                wall time
    message : str
    """

    method: str
    targets_mm: np.ndarray
    commands_mm: np.ndarray
    axes: np.ndarray
    residual_um: np.ndarray
    correction_um: np.ndarray
    success: np.ndarray
    nfev: int
    seconds: float
    message: str = ""
    info: dict = field(default_factory=dict)

    @property
    def residual_norm_um(self) -> np.ndarray:
        """|model residual| per point, shape (n,)."""
        return np.linalg.norm(self.residual_um, axis=1)
