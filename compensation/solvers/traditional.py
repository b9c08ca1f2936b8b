"""The traditional one-shot compensation: negate the error at the target.

``p_r = p_d - E(axes(p_d))·1e-3``. Its model residual is ``E(axes(p_r)) - E(axes(p_d))``:
the error at the commanded point differs from the error at the target (the paper's
Fig. 14), which the other solvers remove. Two field evaluations per point.
"""
from __future__ import annotations

import time

import numpy as np

from .base import BALL_RADIUS_UM, SolveResult
from ._common import MM_PER_UM, check_inputs, command_axes, field_error_um, make_result, residual_um


def solve_traditional(field, targets_mm, machine, *, target_axes=None, a_start_deg=None,
                      ball_um: float = BALL_RADIUS_UM) -> SolveResult:
    """Traditional compensation of WCS targets, shape (n, 3) mm.

    ``target_axes`` (n, 3): the targets' own axis commands when the caller has them (their
    A turn is kept); otherwise A is unwrapped along the targets from ``a_start_deg``.
    ``success`` is True where the command is finite and inside the ball (there is no
    iteration to converge).
    """
    t0 = time.perf_counter()
    targets, axes_d = check_inputs(field, targets_mm, machine, target_axes, a_start_deg, ball_um)
    commands = targets - MM_PER_UM * field_error_um(field, axes_d, machine)
    axes = command_axes(machine, commands, axes_d)
    res = residual_um(field, machine, commands, axes, targets)
    return make_result("traditional", targets, commands, axes, res, np.ones(len(targets), bool),
                       2 * len(targets), t0, ball_um)
