"""Ball, stroke, calibrated-volume and convergence guards refuse and list offending points."""
from __future__ import annotations


import numpy as np

from chain_fixtures import grinder_variant
import pytest

from compensation.guards import GUARDS, calibrated_volume, check, stroke_violations, violations, volume_violations
from compensation.solvers import solve
from compensation.solvers.base import BALL_RADIUS_UM, SolveResult
from errormap.field import CalibratedVolume
from errormap.chain_field import ChainField
from errormap.chain_kernel import forward
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth


@pytest.fixture(scope="module")
def machine():
    return load_machine()


class BoxField:
    """Zero error, calibrated on the box ``lo``..``hi``."""

    capabilities = frozenset()

    def __init__(self, lo, hi):
        self.calibrated_volume = CalibratedVolume(lo, hi)

    def predict(self, axes):
        return np.zeros((len(axes), 3))


def blocked(report):
    """``(guards not allowed that failed, in GUARDS order; their offending points, sorted)`` of a GuardReport."""
    b = report.blocking
    return tuple(g for g in GUARDS if g in b), (np.unique(np.concatenate(list(b.values()))) if b else np.zeros(0, int))


def make_result(axes, machine, correction_um=None, success=None):
    n = len(axes)
    commands = forward(machine, axes)
    return SolveResult(method="test", targets_mm=commands, commands_mm=commands, axes=np.asarray(axes, float),
                       residual_um=np.zeros((n, 3)),
                       correction_um=np.zeros(n) if correction_um is None else np.asarray(correction_um, float),
                       success=np.ones(n, bool) if success is None else np.asarray(success, bool),
                       nfev=0, seconds=0.0, info={"ball_um": BALL_RADIUS_UM})


def test_clean_result_passes(machine):
    axes = np.array([[10.0, 1.0, 30.0], [190.0, 59.0, 359.0]])
    report = check(make_result(axes, machine), machine, BoxField(machine.stroke_lo, machine.stroke_hi))
    assert report.ok and report.indices.size == 0 and not report.blocking


def test_ball_guard_lists_points(machine):
    axes = np.tile([[10.0, 1.0, 30.0]], (4, 1))
    res = make_result(axes, machine, correction_um=[10.0, 250.5, 100.0, 400.0])
    report = check(res, machine, BoxField(machine.stroke_lo, machine.stroke_hi))
    guards, idx = blocked(report)
    assert guards == ("ball",)
    np.testing.assert_array_equal(idx, [1, 3])
    assert "250.500" in report.point_reasons(1)[0] and report.point_reasons(1)[0].startswith("ball")


def test_stroke_guard_lists_points_and_axes(machine):
    axes = np.array([[10.0, 1.0, 30.0], [-0.5, 1.0, 30.0], [10.0, 60.2, 30.0], [10.0, -1e-3, 30.0]])
    idx, reasons = stroke_violations(axes, machine)
    np.testing.assert_array_equal(idx, [1, 2, 3])
    assert "x_mm" in reasons[0] and "z_mm" in reasons[1] and "z_mm" in reasons[2]
    guards, idx = blocked(check(make_result(axes, machine), machine, BoxField([-10, -10, 0], [210, 70, 360])))
    np.testing.assert_array_equal(idx, [1, 2, 3])
    assert guards == ("stroke",)


def test_a_beyond_a_turn_passes_on_a_full_turn_stroke_only(machine):
    """Multi-turn paths: the default A stroke spans 360°, so A = 725° or -30° is allowed."""
    axes = np.array([[10.0, 1.0, 725.0], [10.0, 1.0, -30.0]])
    assert stroke_violations(axes, machine)[0].size == 0
    limited = grinder_variant(edit=lambda d: next(j for j in d["work"] if j.get("axis") == "A").update(stroke=[0.0, 180.0]))
    idx, reasons = stroke_violations(axes, limited)
    np.testing.assert_array_equal(idx, [0, 1])
    assert "a_deg = 725" in reasons[0]


def test_volume_guard_lists_points(machine):
    field = BoxField([5.0, 0.5, 0.0], [150.0, 50.0, 360.0])
    axes = np.array([[10.0, 1.0, 30.0], [160.0, 1.0, 30.0], [10.0, 0.1, 30.0], [10.0, 1.0, 1000.0]])
    idx, reasons = volume_violations(axes, field)
    np.testing.assert_array_equal(idx, [1, 2])  # A over a full calibrated turn is periodic
    assert "calibrated volume" in reasons[0]
    guards, idx = blocked(check(make_result(axes, machine), machine, field))
    assert guards == ("volume",)
    np.testing.assert_array_equal(idx, [1, 2])


def test_volume_guard_folds_a_on_a_partial_calibrated_turn():
    field = BoxField([0.0, 0.0, 10.0], [200.0, 60.0, 100.0])
    axes = np.array([[1.0, 1.0, 380.0], [1.0, 1.0, 470.0]])  # 20° (in) and 110° (out) after folding
    np.testing.assert_array_equal(volume_violations(axes, field)[0], [1])


def test_calibrated_volume_contract(machine):
    """One form: the field's ``calibrated_volume`` (errormap.field.CalibratedVolume) or None."""
    truth = make_chain_truth(machine, 0)
    lo, hi = calibrated_volume(ChainField(machine, truth.elements))  # the element stations' range
    np.testing.assert_allclose(lo, machine.stroke_lo)
    np.testing.assert_allclose(hi, machine.stroke_hi)

    from training.model import MLPField
    axes = np.array([[1.0, 2.0, 0.0], [100.0, 30.0, 360.0], [50.0, 10.0, 90.0]])
    learned = MLPField().fit_scalers(axes, np.zeros((3, 3)))  # the training inputs' range
    np.testing.assert_allclose(calibrated_volume(learned)[0], [1.0, 2.0, 0.0])
    np.testing.assert_allclose(calibrated_volume(learned)[1], [100.0, 30.0, 360.0])
    np.testing.assert_allclose(calibrated_volume(BoxField([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]))[1], [4.0, 5.0, 6.0])

    class Unknown(BoxField):
        def __init__(self):
            self.calibrated_volume = None

    class Pose(BoxField):
        def __init__(self):
            self.calibrated_volume = CalibratedVolume([0.0, 0.0], [1.0, 1.0], ("x_mm", "y_mm"))

    with pytest.raises(TypeError, match="calibrated"):
        calibrated_volume(Unknown())
    with pytest.raises(TypeError, match="calibrated"):
        calibrated_volume(object())
    with pytest.raises(TypeError, match="axes"):  # a volume over other axes (a pose field) is refused
        calibrated_volume(Pose())
    with pytest.raises(ValueError, match="lo ≤ hi"):
        CalibratedVolume([0.0, 0.0, 5.0], [1.0, 1.0, 4.0])
    with pytest.raises(ValueError, match="3 values"):
        CalibratedVolume([0.0, 0.0], [1.0, 1.0])


def test_convergence_guard_and_allow(machine):
    axes = np.tile([[10.0, 1.0, 30.0]], (3, 1))
    res = make_result(axes, machine, correction_um=[1.0, 1.0, 300.0], success=[True, False, False])
    field = BoxField(machine.stroke_lo, machine.stroke_hi)
    report = check(res, machine, field)
    np.testing.assert_array_equal(report.violations["convergence"], [1])  # point 2 fails the ball, not convergence
    np.testing.assert_array_equal(report.violations["ball"], [2])
    assert blocked(check(res, machine, field, allow=("ball",)))[0] == ("convergence",)
    allowed = check(res, machine, field, allow=("ball", "convergence"))
    assert not allowed.blocking
    np.testing.assert_array_equal(allowed.indices, [1, 2])
    assert check(res, machine, field, allow="all").allowed == frozenset(GUARDS)
    with pytest.raises(ValueError, match="guard names"):
        check(res, machine, field, allow=("bal",))


def test_guards_on_a_real_solve_near_the_stroke_edge(machine):
    """Targets at x = 0 compensated by a +x error leave the X stroke and the calibrated volume."""

    class Shift(BoxField):
        def predict(self, axes):
            return np.tile([30.0, 0.0, 0.0], (len(axes), 1))  # +30 μm in WCS x ⇒ command x_mm += 0.03

    field = Shift(machine.stroke_lo, machine.stroke_hi)
    axes_d = np.array([[0.0, 5.0, 10.0], [100.0, 5.0, 10.0], [200.0, 5.0, 10.0]])
    res = solve("exact", field, forward(machine, axes_d), machine, progress=False)
    guards, idx = blocked(check(res, machine, field))
    # WCS px = 200 - x: a +30 μm WCS error needs px - 0.03, i.e. x + 0.03: only x = 200 leaves
    np.testing.assert_array_equal(idx, [2])
    assert set(guards) == {"stroke", "volume"}


def test_violations_list_for_callers(machine):
    axes = np.array([[10.0, 1.0, 30.0], [-1.0, 1.0, 30.0], [10.0, 1.0, 30.0]])
    res = make_result(axes, machine, correction_um=[0.0, 0.0, 260.0])
    listed = violations(res, machine)
    assert [i for i, _ in listed] == [1, 2]
    assert listed[0][1].startswith("stroke:") and listed[1][1].startswith("ball:")
    narrow = BoxField([20.0, 0.0, 0.0], [200.0, 60.0, 360.0])
    assert [i for i, _ in violations(res, machine, narrow)] == [0, 1, 1, 2, 2]


class ConstantField:
    """A constant error (μm) everywhere in the strokes: the correction it needs is ``|error|``."""

    def __init__(self, machine, error_um):
        self.calibrated_volume = CalibratedVolume(machine.stroke_lo, machine.stroke_hi)
        self.capabilities = frozenset()
        self.error_um = np.asarray(error_um, float)

    def predict(self, axes):
        return np.tile(self.error_um, (len(axes), 1))


@pytest.mark.parametrize("method", ["traditional", "exact"])
def test_a_correction_beyond_the_ball_is_reported_as_ball(machine, method):
    axes = np.array([[50.0, 5.0, 10.0], [60.0, 5.0, 20.0]])
    field = ConstantField(machine, [0.0, 300.0, 200.0])  # needs |(0, 300, 200)| = 360.6 μm > 250
    res = solve(method, field, forward(machine, axes), machine, target_axes=axes)
    report = check(res, machine, field)
    assert report.violations["ball"].tolist() == [0, 1]
    assert report.violations["convergence"].size == 0  # not mislabelled as a convergence failure
    assert check(res, machine, field, allow=("ball",)).blocking == {}


def test_targets_outside_the_strokes_are_refused_for_every_method(machine):
    # Z = -0.3 mm is a tool point on the far side of the A axis: its command may fold back into the
    # stroke (z = +0.1 at A + 180°), so only a check of the target itself catches it
    axes = np.array([[50.0, 5.0, 10.0], [60.0, -0.3, 20.0]])
    field = ConstantField(machine, [0.0, 1.0, 1.0])
    for method in ("traditional", "exact"):
        res = solve(method, field, forward(machine, axes), machine, target_axes=axes)
        if method == "traditional":  # its command would fold to z = +0.1 at A - 180°: a swing beyond the
            # rotary continuity bound (asin(ball/r), 90° this near the A axis), so the programmed axes are kept
            assert res.info["rotary_refused"].tolist() == [1] and not res.success[1]
        report = check(res, machine, field, target_axes=axes)
        assert report.violations["stroke"].tolist() == [1]
        assert "target z_mm = -0.3 outside stroke" in report.point_reasons(1)[0]
