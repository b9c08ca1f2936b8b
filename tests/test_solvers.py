"""Solvers on analytic fields with known answers (issue 4)."""
from __future__ import annotations


import numpy as np

from chain_fixtures import grinder_variant
import pytest

from compensation.solvers import METHODS, SolveResult, get_solver, solve
from compensation.solvers._common import project_to_ball
from compensation.solvers.exact import solve3
from errormap.field import JACOBIAN, CalibratedVolume
from errormap.chain_kernel import NominalChain, forward, inverse
from errormap.machine import load_machine
from errormap.transforms import rot_x

GA_TOL_UM = 0.265          # the paper's worst GA residual (max squared residual 0.07048 μm²)
EXACT_TOL_UM = 1e-6        # exact solver: float precision, with margin
TRAD_MIN_RESIDUAL_UM = 1.0  # the traditional method must leave a visible residual on these fields
JAC_TOL = 1e-6             # analytic vs finite-difference kinematic Jacobian (mm per unit)
CHAIN_POINT_TOL_MM = 1e-12  # the chain's op-by-op tool point vs the closed form: float64 round-off of ~500 mm sums
CHAIN_JAC_TOL = 1e-13      # its geometric axis Jacobian vs the closed form's (entries ≤ ~4 mm/deg; round-off)
CMD_FACTOR = 1.2           # |command error| ≤ CMD_FACTOR·|residual| for the linear field (|(I+1e-3A)^-1| < 1.2)


@pytest.fixture(scope="module")
def machine():
    return load_machine()


class LinearField:
    """``E = A·(fwd(q) - p0) + b`` μm: linear in the WCS, so the answer is known in closed form.

    ``p_r + 1e-3·E(p_r) = p_d``  ⇔  ``p_r = (I + 1e-3·A)⁻¹ (p_d + 1e-3·(A·p0 - b))``.
    """

    def __init__(self, machine, A, b, p0, with_jacobian=False):
        self.machine, self.A, self.b, self.p0 = machine, np.asarray(A), np.asarray(b), np.asarray(p0)
        self.capabilities = frozenset({JACOBIAN}) if with_jacobian else frozenset()
        self.calibrated_volume = CalibratedVolume(machine.stroke_lo, machine.stroke_hi)

    def jacobian(self, axes):
        return self.A @ NominalChain(self.machine).forward_and_jacobian(axes)[1]

    def predict(self, axes):
        return (forward(self.machine, axes) - self.p0) @ self.A.T + self.b

    def answer(self, targets):
        M = np.eye(3) + 1e-3 * self.A
        return np.linalg.solve(M, (targets + 1e-3 * (self.A @ self.p0 - self.b)).T).T


class RotatingField:
    """A constant machine-frame error ``e`` seen in the WCS: ``E = RotX(-a)·e`` μm.

    Steep in WCS coordinates near the A axis (tangential slope ≈ |e|/ρ): the case where a
    WCS fixed-point iteration diverges.
    """

    def __init__(self, e_um):
        self.e = np.asarray(e_um, dtype=float)
        self.capabilities = frozenset()
        self.calibrated_volume = CalibratedVolume([0.0, 0.0, 0.0], [200.0, 60.0, 360.0])

    def predict(self, axes):
        Ra = np.transpose(rot_x(np.deg2rad(np.asarray(axes)[:, 2])), (0, 2, 1))
        return Ra @ self.e


def linear_setup(machine, n, seed):
    rng = np.random.default_rng(seed)
    p0 = np.array([100.0, 0.0, 20.0])
    targets = p0 + rng.uniform(-1.0, 1.0, (n, 3))
    A = rng.uniform(-50.0, 50.0, (3, 3))
    b = rng.uniform(-60.0, 60.0, 3)
    return targets, A, b, p0


def test_dispatcher_knows_every_method():
    for m in METHODS:
        assert callable(get_solver(m))
    with pytest.raises(ValueError, match="Expected method"):
        get_solver("simplex")


def test_forward_jacobian_matches_finite_differences(machine):
    rng = np.random.default_rng(0)
    axes = np.column_stack([rng.uniform(0, 200, 50), rng.uniform(0, 60, 50), rng.uniform(-400, 800, 50)])
    J = NominalChain(machine).forward_and_jacobian(axes)[1]
    h = np.array([1e-5, 1e-5, 1e-5])
    for k in range(3):
        dp = (forward(machine, axes + h * np.eye(3)[k]) - forward(machine, axes - h * np.eye(3)[k])) / (2 * h[k])
        np.testing.assert_allclose(J[:, :, k], dp, atol=JAC_TOL)


def grinder_closed_form(machine, axes):
    """Readable reference (the solvers' former hand-written kinematics, main 0485cf2): the grinder's
    nominal tool point ``p = (t_x - l5 - l7 - x, c·t_y + s·h, c·h - s·t_y)`` with
    ``h = t_z(0) - l6 - l8 + z``, ``t(0) = RotZ(θ1)·(l2 + l3, 0, l1 + l4 - R)``, and its axis Jacobian
    (columns ``(-1, 0, 0)``, ``(0, s, c)``, ``(0, p_z, -p_y)·π/180``)."""
    th = np.deg2rad(machine.geometry["theta1_deg"])
    tx, ty = np.cos(th) * (machine.geometry["l2"] + machine.geometry["l3"]), np.sin(th) * (machine.geometry["l2"] + machine.geometry["l3"])
    tz = machine.geometry["l1"] + machine.geometry["l4"] - machine.geometry["R"]
    h = axes[:, 1] + tz - machine.geometry["l6"] - machine.geometry["l8"]
    a = np.deg2rad(axes[:, 2])
    c, s = np.cos(a), np.sin(a)
    p = np.column_stack([tx - machine.geometry["l5"] - machine.geometry["l7"] - axes[:, 0], c * ty + s * h, c * h - s * ty])
    J = np.zeros((len(axes), 3, 3))
    J[:, 0, 0] = -1.0
    J[:, 1, 1], J[:, 2, 1] = s, c
    J[:, 1, 2], J[:, 2, 2] = p[:, 2] * np.pi / 180, -p[:, 1] * np.pi / 180
    return p, J


@pytest.mark.parametrize("theta1_deg", [None, 7.0])
def test_chain_kinematics_equal_the_closed_form(machine, theta1_deg):
    """The solvers' nominal kinematics come from the grinder's chain (one source, issue 26): equal to
    the closed form written out here and to :func:`errormap.chain_kernel.forward`, on 100,000 points
    (A over several turns), also for a grinder file with other geometry."""
    mach = machine if theta1_deg is None else grinder_variant({"theta1_deg": theta1_deg})
    rng = np.random.default_rng(2)
    n = 100_000
    axes = np.column_stack([rng.uniform(0, 200, n), rng.uniform(0, 60, n), rng.uniform(-400, 800, n)])
    p, J = NominalChain(mach).forward_and_jacobian(axes)
    p_ref, J_ref = grinder_closed_form(mach, axes)
    np.testing.assert_allclose(p, p_ref, rtol=0, atol=CHAIN_POINT_TOL_MM)
    np.testing.assert_allclose(J, J_ref, rtol=0, atol=CHAIN_JAC_TOL)
    np.testing.assert_allclose(p, forward(mach, axes), rtol=0, atol=CHAIN_POINT_TOL_MM)
    p_only, none = NominalChain(mach).forward_and_jacobian(axes[:100], jac=False)
    assert none is None
    np.testing.assert_array_equal(p_only, p[:100])


def test_solve3_matches_numpy():
    rng = np.random.default_rng(1)
    J = rng.normal(size=(100, 3, 3))
    b = rng.normal(size=(100, 3))
    np.testing.assert_allclose(solve3(J, b), np.linalg.solve(J, b[..., None])[..., 0], rtol=1e-9, atol=1e-12)
    assert np.all(solve3(np.zeros((2, 3, 3)), np.ones((2, 3))) == 0.0)


def test_project_to_ball_keeps_inside_and_clips_outside():
    d = np.array([[10.0, 0, 0], [300.0, 400.0, 0.0]])
    out = project_to_ball(d, 250.0)
    np.testing.assert_array_equal(out[0], d[0])
    np.testing.assert_allclose(out[1], [150.0, 200.0, 0.0], rtol=1e-12)


def test_traditional_is_the_negation_and_leaves_a_residual(machine):
    targets, A, b, p0 = linear_setup(machine, 30, seed=2)
    f = LinearField(machine, A, b, p0)
    r = solve("traditional", f, targets, machine)
    assert isinstance(r, SolveResult) and r.method == "traditional"
    axes_d = inverse(machine, targets)
    np.testing.assert_allclose(r.commands_mm, targets - 1e-3 * f.predict(axes_d), rtol=0, atol=1e-12)
    # residual = E(p_r) - E(p_d) = -1e-3·A·E(p_d), known in closed form
    np.testing.assert_allclose(r.residual_um, -1e-3 * f.predict(axes_d) @ A.T, rtol=0, atol=1e-9)
    assert r.residual_norm_um.max() > TRAD_MIN_RESIDUAL_UM
    assert r.success.all() and r.nfev == 2 * len(targets)


@pytest.mark.parametrize("with_jacobian", [False, True])
def test_exact_finds_the_known_answer(machine, with_jacobian):
    targets, A, b, p0 = linear_setup(machine, 200, seed=3)
    f = LinearField(machine, A, b, p0, with_jacobian=with_jacobian)
    r = solve("exact", f, targets, machine, progress=False)
    assert r.success.all()
    assert r.residual_norm_um.max() <= EXACT_TOL_UM
    np.testing.assert_allclose(r.commands_mm, f.answer(targets), rtol=0, atol=EXACT_TOL_UM * 1e-3)
    # the axis commands are the nominal inverse of the commands
    np.testing.assert_allclose(forward(machine, r.axes), r.commands_mm, rtol=0, atol=1e-12)


def test_exact_converges_near_the_a_axis(machine):
    """ρ = 0.3 mm, |e| = 150 μm: the WCS field's slope |e|/ρ is 0.5; axis-space Newton converges."""
    f = RotatingField([20.0, 100.0, -110.0])
    a = np.linspace(0.0, 720.0, 97)
    axes_d = np.column_stack([np.full_like(a, 50.0), np.full_like(a, 0.2), a])
    targets = forward(machine, axes_d)
    trad = solve("traditional", f, targets, machine, target_axes=axes_d)
    r = solve("exact", f, targets, machine, target_axes=axes_d, progress=False)
    assert trad.residual_norm_um.max() > TRAD_MIN_RESIDUAL_UM
    assert r.success.all()
    assert r.residual_norm_um.max() <= EXACT_TOL_UM


def test_exact_reports_unreachable_points(machine):
    """A point closer to the A axis than the tangential error cannot be reached: not a success."""
    f = RotatingField([0.0, 150.0, 0.0])  # 150 μm tangential: nothing closer than 0.15 mm is reachable
    axes_d = np.array([[50.0, 0.0, 30.0], [50.0, 5.0, 30.0]])  # ρ = 0.1 mm and 5.1 mm
    r = solve("exact", f, forward(machine, axes_d), machine, target_axes=axes_d, progress=False)
    assert not r.success[0] and r.success[1]
    assert r.residual_norm_um[1] <= EXACT_TOL_UM


def test_multi_turn_commands_keep_a_continuous(machine):
    """A helix over 3 turns: compensated A follows the targets' turns, never jumping by 360°."""
    f = RotatingField([5.0, 40.0, -30.0])
    a = np.linspace(10.0, 1090.0, 400)
    axes_d = np.column_stack([np.linspace(20, 30, 400), np.full_like(a, 5.0), a])
    targets = forward(machine, axes_d)
    for method in ("traditional", "exact"):
        r = solve(method, f, targets, machine, progress=False) if method == "exact" else solve(method, f, targets, machine)
        assert r.axes[:, 2].max() > 1000.0
        assert np.abs(np.diff(r.axes[:, 2])).max() < 5.0


def test_batched_ga_reaches_the_paper_residual(machine):
    targets, A, b, p0 = linear_setup(machine, 40, seed=4)
    f = LinearField(machine, A, b, p0)
    r = solve("batched-ga", f, targets, machine, seed=7, progress=False)
    assert r.success.all()
    assert r.residual_norm_um.max() <= GA_TOL_UM
    err_um = np.linalg.norm(r.commands_mm - f.answer(targets), axis=1) * 1e3
    assert np.all(err_um <= CMD_FACTOR * r.residual_norm_um + 1e-9)
    assert np.all(r.correction_um <= 250.0)
    again = solve("batched-ga", f, targets, machine, seed=7, progress=False)
    np.testing.assert_array_equal(again.commands_mm, r.commands_mm)


def test_pygad_ga_reaches_the_paper_residual(machine):
    targets, A, b, p0 = linear_setup(machine, 3, seed=5)
    f = LinearField(machine, A, b, p0)
    r = solve("ga", f, targets, machine, seed=11, progress=False)
    assert r.success.all()
    assert r.residual_norm_um.max() <= GA_TOL_UM
    err_um = np.linalg.norm(r.commands_mm - f.answer(targets), axis=1) * 1e3
    assert np.all(err_um <= CMD_FACTOR * r.residual_norm_um + 1e-9)
    # PyGAD evaluates the initial population plus at most 39 offspring per generation
    assert 3 * 40 < r.nfev <= 3 * (40 + 400 * 39)
    again = solve("ga", f, targets[:1], machine, seed=11, progress=False)
    np.testing.assert_array_equal(again.commands_mm[0], r.commands_mm[0])


def test_input_is_validated_before_work(machine):
    f = RotatingField([1.0, 2.0, 3.0])
    for method in METHODS:
        with pytest.raises(ValueError, match="Expected WCS targets"):
            solve(method, f, np.zeros((4, 2)), machine)
        with pytest.raises(TypeError, match="error field"):
            solve(method, object(), np.zeros((4, 3)), machine)
    with pytest.raises(ValueError, match="population"):
        solve("batched-ga", f, np.zeros((1, 3)), machine, population=1)
    with pytest.raises(ValueError, match="crossover_probability"):
        solve("ga", f, np.zeros((1, 3)), machine, crossover_probability=1.5)
    with pytest.raises(TypeError):
        solve("exact", f, np.zeros((1, 3)), machine, no_such_option=1)
