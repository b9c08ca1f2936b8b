"""The orientation solve (compensation/tcp_orientation.py) at the A/C table's singularity: with the tool vertical
(A = 0) C turns the tool about itself, so C is held and A turns out the tilt in its own plane. The tip is still
reached, the tool axis is brought nearer and A's value is the least-squares optimum; the part left is what a
C swing of tens of degrees would be needed for (shown, not done)."""
import numpy as np
import pytest

from compensation.tcp_orientation import (ORIENT_POS_TOL_UM, ORIENT_ROTARY_LIMIT_DEG, _gauss_newton,
                                          _pose_residual, solve_orientation, tool_axis)
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.machine import load_machine

A_STEP_DEG = 2e-4
"""A step of A either side of the solve's answer (3.5 μrad of tool axis): the residual there is larger by about
(3.5 μrad)² / (2 · residual), some 0.3 μrad, far above the solve's round-off."""
OPTIMUM_TOL_URAD = 1e-6
"""How much lower than the answer a neighbouring A may come (round-off of the residual's norm)."""
ISSUE_BOUND_URAD = 5.0
"""The tool-axis residual the issue asks for after compensation."""
SWING_MIN_DEG = 10.0
"""The least C turn that brings the tool axis within :data:`ISSUE_BOUND_URAD` of the programmed one: tens of
degrees."""


@pytest.fixture(scope="module")
def vertical():
    """five-axis-ac with a seeded truth as the model, and four vertical-tool points (A = 0) at several C."""
    mt = load_machine("five-axis-ac")
    field_ = ChainField(mt, ChainElementSet.random(mt, 0, 10.0, 11))
    q = np.array([[20.0, -30.0, -300.0, 0.0, c] for c in (0.0, 40.0, 130.0, 250.0)])
    return mt, field_, q, mt.nominal(q), tool_axis(mt, q)


def test_a_vertical_tool_holds_c_and_a_turns_out_its_plane(vertical):
    mt, field_, q, targets, directions = vertical
    qs, solved, partly = solve_orientation(field_, mt, q, targets, directions)
    assert not solved.any() and partly.all()
    r0 = np.linalg.norm(_pose_residual(field_, mt, q, targets, directions)[:, 3:], axis=1)
    r = _pose_residual(field_, mt, qs, targets, directions)
    axis_urad = np.linalg.norm(r[:, 3:], axis=1)
    assert np.linalg.norm(r[:, :3], axis=1).max() <= ORIENT_POS_TOL_UM   # the tip reached
    assert np.all(qs[:, 4] == q[:, 4])                                    # C held exactly
    assert np.all(np.abs(qs[:, 3]) <= ORIENT_ROTARY_LIMIT_DEG) and np.all(qs[:, 3] != 0.0)
    assert np.all(axis_urad < r0)                                         # the tool axis brought nearer
    for step in (-A_STEP_DEG, A_STEP_DEG):                                # and A's value is the optimum
        qa = qs.copy()
        qa[:, 3] += step
        qa, tip, axis_a = _gauss_newton(field_, mt, qa, targets, directions, 8, [0, 1, 2])  # tip again, A fixed
        assert tip.all() and np.all(axis_a >= axis_urad - OPTIMUM_TOL_URAD)


def test_the_part_left_needs_c_to_swing_far(vertical):
    """With C held the tool axis stays over the issue's 5 μrad; over a full turn of C (every 2°, A and the tip
    solved at each) it comes within 5 μrad only tens of degrees away: the swing the solve does not make."""
    mt, field_, q, targets, directions = vertical
    qs, _, _ = solve_orientation(field_, mt, q, targets, directions)
    held = np.linalg.norm(_pose_residual(field_, mt, qs, targets, directions)[:, 3:], axis=1)
    turns = np.arange(0.0, 360.0, 2.0)
    for i in range(len(q)):
        start = np.repeat(q[i:i + 1], len(turns), axis=0)
        start[:, 4] += turns
        _, _, axis_urad = _gauss_newton(field_, mt, start, np.repeat(targets[i:i + 1], len(turns), axis=0),
                                        np.repeat(directions[i:i + 1], len(turns), axis=0), 8, [0, 1, 2, 3])
        within = turns[axis_urad <= ISSUE_BOUND_URAD]
        assert held[i] > ISSUE_BOUND_URAD and within.size
        assert np.minimum(within, 360.0 - within).min() >= SWING_MIN_DEG
