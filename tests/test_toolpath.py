"""The flute path generator (compensation.toolpath)."""
import numpy as np
import pytest

from compensation.toolpath import FLUTE_DEFAULTS, check_in_strokes, flute_path
from errormap.chain_kernel import forward, inverse
from errormap.machine import load_machine

TOL_MM = 1e-9          # geometry round trips
TOL_INTEGRAL_MM = 1e-7  # trapezoidal integration of the axial position


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def test_defaults_are_the_papers_seven_turns(machine):
    f = flute_path()
    assert len(f) == 2800 == FLUTE_DEFAULTS.n_points
    ax = f.axes(machine)
    assert ax[0, 2] == pytest.approx(0.0, abs=TOL_MM)
    assert ax[-1, 2] == pytest.approx(2520.0, abs=1e-6)
    assert np.all(np.diff(ax[:, 2]) > 0)
    assert np.bincount(f.turn_index).tolist() == [400] * 7
    assert np.array_equal(ax, inverse(machine, f.targets_mm, unwrap=True))
    check_in_strokes(machine, ax, "default flute")
    # inside the X/Z strokes even with the full 250 um search ball around every point
    lo, hi = machine.stroke_lo, machine.stroke_hi
    assert np.all(ax[:, :2] - 0.25 >= lo[:2]) and np.all(ax[:, :2] + 0.25 <= hi[:2])


def test_targets_are_nominal_tool_points(machine):
    f = flute_path(turns=2, points_per_turn=50)
    ax = f.axes(machine)
    assert np.abs(forward(machine, ax) - f.targets_mm).max() < TOL_MM
    assert np.allclose(np.hypot(f.targets_mm[:, 1], f.targets_mm[:, 2]), f.radius_mm, atol=TOL_MM)
    assert np.allclose(ax[:, 2], f.theta_deg, atol=1e-9)


def test_axial_position_matches_closed_form():
    """Constant radius, helix linear in θ: ∫ r cot(β0 + kθ) dθ = (r/k) ln(sin β / sin β0)."""
    f = flute_path()
    r, b0 = FLUTE_DEFAULTS.radius_mm, np.deg2rad(FLUTE_DEFAULTS.helix_start_deg)
    k = np.deg2rad(FLUTE_DEFAULTS.helix_end_deg - FLUTE_DEFAULTS.helix_start_deg) / np.deg2rad(7 * 360.0)
    th = np.deg2rad(f.theta_deg)
    axial = r / k * np.log(np.sin(b0 + k * th) / np.sin(b0))
    assert np.abs((FLUTE_DEFAULTS.px_start_mm - f.targets_mm[:, 0]) - axial).max() < TOL_INTEGRAL_MM
    assert f.helix_deg[0] == pytest.approx(30.0) and f.helix_deg[-1] == pytest.approx(40.0)
    assert np.allclose(np.tan(np.deg2rad(f.helix_deg)), 2 * np.pi * f.radius_mm / f.lead_mm)


def test_lead_law_and_hand_and_taper(machine):
    f = flute_path(lead_law="linear-lead", hand="left", radius_end_mm=0.3, turns=3, points_per_turn=100)
    assert np.allclose(np.diff(f.lead_mm, 2), 0.0, atol=1e-12)  # lead linear in u
    assert np.all(np.diff(f.targets_mm[:, 0]) > 0)                # left hand: px grows with A
    assert f.radius_mm[0] == pytest.approx(0.4) and f.radius_mm[-1] == pytest.approx(0.3)
    check_in_strokes(machine, f.axes(machine))


@pytest.mark.parametrize("bad", [{"turns": 0}, {"points_per_turn": 1}, {"radius_mm": -1.0},
                                 {"helix_start_deg": 90.0}, {"lead_law": "cubic"}, {"hand": "up"}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError, match="Expected"):
        flute_path(**bad)


def test_stroke_check_names_points(machine):
    f = flute_path(px_start_mm=1.0, turns=1, points_per_turn=40)  # runs past px = 0 -> X > 200
    with pytest.raises(ValueError, match="point .* x_mm"):
        check_in_strokes(machine, f.axes(machine))
