"""Traditional compensation on a machine-tool chain (``kind = "machine-tool"``): one first-order step.

Command the target minus the error predicted at the programmed axes ``q_d``, mapped onto the compensated
axes through the chain's nominal axis Jacobian ``J_s = dfwd/dq_s`` (mm per mm or per deg) at ``q_d``::

    Δq_s = −1e-3 · J_s(q_d)⁻¹ · E(q_d)        (mm or deg; q_s the three compensated axes)
    q    = q_d + Δq_s  (the other axes kept as programmed)

The model residual ``(fwd(q) − p_d)·1e3 + E(q)`` (μm) is what the single step leaves (the field's gradient
times the correction). The compensated axes, the 250 μm ball and the rotary continuity guard are the exact
chain solver's; ``success``: finite, inside the ball and not refused. Two field evaluations per point.
docs/explanation/solvers.md ("The traditional baseline on a chain").
"""
from __future__ import annotations

import time

import numpy as np

from ._common import MM_PER_UM, UM_PER_MM, make_result, project_to_ball, wrap180
from .base import BALL_RADIUS_UM
from .chain_exact import (axes_info, check_chain_call, check_rotary_limit, nominal_and_jacobian, rotary_guard,
                          target_axes_of)
from .exact import keep_turn, solve3


def closed_inverse(machine, axes_d):
    """``inverse(points (n, 3) mm) -> axes (n, 3)``: the chain's closed-form nominal inverse, each point's
    rotary axis on the turn of its target's (``axes_d`` (n, 3)); None where the chain has none."""
    from errormap.chain_kernel import closed_form_solver
    try:
        solve = closed_form_solver(machine)
    except ValueError:
        return None
    r = solve.k.rotary

    def inverse(points_mm):
        q = solve(np.ascontiguousarray(points_mm, dtype=float), fold=True)
        q[:, r] = axes_d[:, r] + wrap180(q[:, r] - axes_d[:, r])
        return q
    return inverse


def field_values(field, machine, axes) -> np.ndarray:
    """``E(axes)`` (n, 3) μm, full-turn axes folded into their calibrated turn, as the exact solver evaluates
    a field (:class:`~compensation.solvers.chain_exact._ChainFieldEval`)."""
    from .chain_exact import _ChainFieldEval
    return _ChainFieldEval(field, machine).value(np.asarray(axes, dtype=float))


def solve_traditional_chain(field, targets_mm, machine, *, target_axes=None, ball_um: float = BALL_RADIUS_UM,
                            rotary_limit_deg=None, progress: bool = True):
    """Traditional compensation of WCS targets (n, 3) mm on a machine-tool chain (module docstring).

    ``target_axes`` (n, k): the program's axes of each target (required when the machine has rotary
    axes). ``field``: an error field over ``machine.axis_columns`` (``predict``). ``rotary_limit_deg``: a
    solved rotary axis' limit, as the exact chain solver's. ``progress`` is accepted for the registry's
    common call and unused (one vectorised step). Returns a :class:`~compensation.solvers.base.SolveResult`
    with ``axes`` (n, k); ``info``: ``compensated_axes``, ``kept_axes``, ``note``, ``outside_ball``,
    ``rotary_refused`` / ``rotary_reasons`` where a rotary axis is solved.
    """
    t0 = time.perf_counter()
    compiled, sol, kept, targets = check_chain_call(field, targets_mm, machine, ball_um)
    check_rotary_limit(rotary_limit_deg)
    axes_d = target_axes_of(machine, targets, target_axes, compiled)
    E_d = field_values(field, machine, axes_d)
    inverse = closed_inverse(machine, axes_d)
    if inverse is not None:  # the command p_d - 1e-3·E(q_d) itself, its axes by the closed form
        d_um = project_to_ball(-E_d, ball_um)
        outside = ~(np.linalg.norm(E_d, axis=1) <= ball_um)
        commands = targets + MM_PER_UM * d_um
        q = inverse(commands)
    else:
        P0, J0 = nominal_and_jacobian(machine, axes_d, compiled)
        q = axes_d.copy()
        q[:, sol] += solve3(J0[:, :, sol], targets - P0 - MM_PER_UM * E_d)
        keep_turn(compiled, q, axes_d)
        commands = compiled.forward(q)
        d_um = (commands - targets) * UM_PER_MM
        outside = ~(np.linalg.norm(d_um, axis=1) <= ball_um)
        if outside.any():  # the ball as a hard limit, as the exact solver's: projected onto its surface
            commands[outside] = targets[outside] + MM_PER_UM * project_to_ball(d_um[outside], ball_um)
            qo = axes_d[outside].copy()
            qo[:, sol] += solve3(J0[outside][:, :, sol], commands[outside] - P0[outside])
            q[outside] = qo
            commands[outside] = compiled.forward(qo)
    refused, reasons = rotary_guard(compiled, machine, axes_d, q, sol, ball_um, rotary_limit_deg)
    if refused.any():  # never silently swung: the programmed axes are kept, the point is unsolved
        q[refused] = axes_d[refused]
        commands[refused] = compiled.forward(axes_d[refused])
    res = (commands - targets) * UM_PER_MM + field_values(field, machine, q)
    info = axes_info({"outside_ball": np.flatnonzero(outside)}, compiled, machine, sol, kept, refused, reasons,
                     rotary_limit_deg)
    return make_result("traditional", targets, commands, q, res, ~outside & ~refused, 2 * len(targets), t0, ball_um,
                       info=info)
