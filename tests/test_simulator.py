"""Truth simulator: magnitude band, and each undeclared effect changes the check
measurements exactly as its documentation says."""
import numpy as np

from errormap.grinder_file import rho0_mm
import pytest

from errormap.chain_truth import EFFECT_DEFAULTS, SIMULATED_KINDS, make_chain_truth, random_axes, volume_grid

MAX_ERROR_BAND_UM = (150.0, 230.0)
"""The required band of the maximum spatial error (vector norm) over the volume; the draw targets [165, 215]."""

COMPONENT_LIMIT_UM = 250.0
TOL_EFFECT_UM = 0.01     # cross terms with the machine's own errors: effect (≤ 10 μm) × its angles (≤ 1e-3 rad)
TOL_NOISE_REL = 0.1      # σ estimated from 1,200 samples


@pytest.mark.parametrize("seed", range(8))
def test_magnitudes_in_band(grinder, seed):
    truth = make_chain_truth(grinder, seed)
    pts = np.vstack([volume_grid(grinder), random_axes(grinder, 20_000, np.random.default_rng(seed))])
    e = truth.spatial_error(pts)
    norm_max = np.linalg.norm(e, axis=1).max()
    assert MAX_ERROR_BAND_UM[0] <= norm_max <= MAX_ERROR_BAND_UM[1]
    assert np.abs(e).max() <= COMPONENT_LIMIT_UM
    # axis-motion elements are referenced to zero at the first station (the gauge)
    assert all(abs(v[0]) < 1e-12 for v in truth.elements.functions.values())


def test_same_seed_same_numbers(grinder):
    a = make_chain_truth(grinder, 11).check_measurements(n=50, noise_um=1.0, seed=4)
    b = make_chain_truth(grinder, 11).check_measurements(n=50, noise_um=1.0, seed=4)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_check_schema_and_noise(grinder):
    truth = make_chain_truth(grinder, 2)
    ck = truth.check_measurements(n=400, noise_um=2.0, seed=9)
    assert {"x_mm", "z_mm", "a_deg", "dx_um", "dy_um", "dz_um", "time_s", "temp_c",
            "dir_x", "dir_z", "dir_a", "seq"} <= set(ck)
    axes = np.c_[ck["x_mm"], ck["z_mm"], ck["a_deg"]]
    assert np.all(axes >= grinder.stroke_lo) and np.all(axes <= grinder.stroke_hi)
    clean = truth.spatial_error(axes, temp_c=ck["temp_c"], dir_x=ck["dir_x"], dir_z=ck["dir_z"])
    noise = np.c_[ck["dx_um"], ck["dy_um"], ck["dz_um"]] - clean
    assert noise.std() == pytest.approx(2.0, rel=TOL_NOISE_REL)
    assert np.all(np.diff(ck["time_s"]) > 0) and ck["temp_c"][-1] > ck["temp_c"][0] + 3.0


def effect_difference(grinder, name, seed=5):
    with_effect = make_chain_truth(grinder, seed, effects=[name]).check_measurements(n=300, noise_um=0.0, seed=1)
    without = make_chain_truth(grinder, seed).check_measurements(n=300, noise_um=0.0, seed=1)
    d = np.c_[with_effect["dx_um"], with_effect["dy_um"], with_effect["dz_um"]] - \
        np.c_[without["dx_um"], without["dy_um"], without["dz_um"]]
    return with_effect, d


def test_thermal_effect(grinder):
    ck, d = effect_difference(grinder, "thermal")
    k = EFFECT_DEFAULTS["thermal"]["k_um_per_mm_c"]
    expected_dx = -k * (ck["temp_c"] - 20.0) * ck["x_mm"]   # dx_x enters the WCS as -dx
    np.testing.assert_allclose(d[:, 0], expected_dx, atol=TOL_EFFECT_UM)
    assert np.abs(d[:, 1:]).max() < TOL_EFFECT_UM
    assert np.abs(d[:, 0]).max() > 5.0


def test_reversal_effect(grinder):
    ck, d = effect_difference(grinder, "reversal")
    v = 0.5 * EFFECT_DEFAULTS["reversal"]["backlash_um"] * ck["dir_z"]
    a = np.deg2rad(ck["a_deg"])
    np.testing.assert_allclose(d, np.c_[0 * v, np.sin(a) * v, np.cos(a) * v], atol=TOL_EFFECT_UM)


def test_pitch_effect(grinder):
    ck, d = effect_difference(grinder, "pitch")
    p = EFFECT_DEFAULTS["periodic"]
    expected = -p["amplitude_um"] * np.sin(2 * np.pi * ck["x_mm"] / p["period_mm"] + p["phase_rad"])
    np.testing.assert_allclose(d[:, 0], expected, atol=TOL_EFFECT_UM)
    assert np.abs(d[:, 1:]).max() < TOL_EFFECT_UM


def test_worm_effect(grinder):
    ck, d = effect_difference(grinder, "worm")
    p = EFFECT_DEFAULTS["harmonic"]
    v = p["amplitude_urad"] * np.sin(p["teeth"] * np.deg2rad(ck["a_deg"]) + p["phase_rad"])
    rho = rho0_mm(grinder) + ck["z_mm"]
    a = np.deg2rad(ck["a_deg"])
    # ex_a turns the workpiece about X: the tool point moves tangentially by ρ·ε
    expected = 1e-3 * v[:, None] * np.c_[0 * rho, rho * np.cos(a), -rho * np.sin(a)]
    # the lever arm is the ACTUAL tool point, off the nominal one by the spatial error (≤ 230 μm)
    lever_shift_um = 1e-3 * p["amplitude_urad"] * 0.230
    np.testing.assert_allclose(d, expected, atol=TOL_EFFECT_UM + lever_shift_um)
    # the 18° identification stations see the harmonic as a constant (aliasing)
    stations = np.arange(0, 360, 18.0)
    assert np.ptp(np.sin(p["teeth"] * np.deg2rad(stations) + p["phase_rad"])) < 1e-9


def test_interaction_effect(grinder):
    ck, d = effect_difference(grinder, "interaction")
    k = EFFECT_DEFAULTS["interaction"]["corner_um"]
    expected = -k * ck["x_mm"] * ck["z_mm"] / (200.0 * 60.0)
    np.testing.assert_allclose(d[:, 0], expected, atol=TOL_EFFECT_UM)
    # depends on both axes at once: not a sum f(x) + g(z)
    assert np.abs(d[:, 0]).max() > 3.0


def test_effects_need_their_conditions(grinder):
    truth = make_chain_truth(grinder, 0, effects=["thermal"])
    with pytest.raises(ValueError, match="temp_c"):
        truth.spatial_error(np.array([[10.0, 10.0, 10.0]]))
    with pytest.raises(ValueError, match="unknown"):
        make_chain_truth(grinder, 0, effects=["gravity"])
    assert set(SIMULATED_KINDS) == {"thermal", "reversal", "periodic", "harmonic", "interaction",
                                 "bump", "a_tilt", "squareness", "squareness_xz", "a_lobe_x",
                                 "xz_saddle"}  # the last six: out of the effect catalogue
