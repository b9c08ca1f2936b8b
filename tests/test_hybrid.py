"""compensation.hybrid: the physical model + a residual learned from check measurements (issue 28)."""
import json

import numpy as np
import pytest

from compensation.diagnosed_model import load_diagnosed_model
from compensation.hybrid import LEARNED_FAMILIES, TERM_CONSISTENT_Z, TERM_KEEP_Z, HybridField, LearnedResidual, TAPER_FRAC, learned_stage
from compensation.solvers import solve
from errormap.field import JACOBIAN, PREDICT_AND_JACOBIAN, check_field
from errormap.htm import HTMField
from errormap.kinematics import forward
from errormap.machine import load_machine
from errormap.simulator import random_axes, random_truth
from training.residual import GP_KERNELS
from shared_runs import private_copy

SEED = 0
NOISE_UM = 1.0
"""Check noise per component (the simulator's default check noise)."""

BUMP_UM = 8.0
"""Amplitude of the synthetic local bump the learned stage must find (the simulator's 'bump')."""

JAC_TOL_REL = 1e-6
"""Closed-form Jacobian of the hybrid field vs central differences (h = 1e-4 mm/deg on fields
with μm-per-mm slopes): truncation O(h²·f''') and rounding ε·|E|/h ≈ 1e-10 relative; 1e-6 of the
largest entry is far above both and far below any wrong term."""

VALUE_TOL_UM = 1e-9
"""predict_and_jacobian's value vs predict: the HTM model's two compiled kernels sum the chain in
different orders (measured 2.5e-11 μm on ~100 μm errors); 1e-9 μm is round-off, not a model."""

EXACT_MODEL_TOL_UM = 1e-6
"""The issue's figure for the exact solver's model residual on the hybrid field."""

BATCHED_GA_MAX_UM = 0.265
"""The issue's figure for the batched GA's max model residual on the hybrid field."""

BUMP_RECOVERY_REL = 0.35
"""On 480 fitting checks at 1 μm noise the learned bump (8 μm peak, ~2.5 μm RMS over the volume)
leaves < 35 % of its RMS over the volume (measured ~20 %: the GP's error is dominated by the
noise averaged over the ~40 checks under the bump)."""


def _bump(machine, axes):
    """A local bump (μm) of the Y error over a region of X–Z, shape (n, 3)."""
    lo = np.array([machine.strokes["x_mm"][0], machine.strokes["z_mm"][0]])
    rng_ = np.array([np.ptp(machine.strokes["x_mm"]), np.ptp(machine.strokes["z_mm"])])
    u = (axes[:, :2] - lo) / rng_
    g = BUMP_UM * np.exp(-0.5 * ((u[:, 0] - 0.6) / 0.18) ** 2 - 0.5 * ((u[:, 1] - 0.4) / 0.18) ** 2)
    return np.stack([np.zeros_like(g), g, np.zeros_like(g)], axis=1)


@pytest.fixture(scope="module")
def staged(grinder):
    rng = np.random.default_rng(SEED)
    axes = random_axes(grinder, 800, rng)
    r = _bump(grinder, axes) + NOISE_UM * rng.standard_normal(axes.shape)
    learned, stage = learned_stage(grinder, r, axes, np.arange(480), np.arange(480, 800), seed=SEED)
    return axes, learned, stage


@pytest.mark.slow
def test_learned_stage_keeps_a_local_bump_and_recovers_it(grinder, staged):
    axes, learned, stage = staged
    assert learned is not None and stage["learned"]["kept"]
    # one of the Gaussian-process kernels wins a smooth bump, by the stated rule (lowest CV RMS of the eligible)
    tab = stage["learned"]["cv_table"]
    assert stage["learned"]["family"] in GP_KERNELS and tuple(stage["learned"]["families_compared"]) == LEARNED_FAMILIES
    eligible = [f for f in LEARNED_FAMILIES if tab[f]["gain_mean"] > tab[f]["gain_se"] and tab[f]["gain_mean"] > 0]
    assert stage["learned"]["family"] == min(eligible, key=lambda f: tab[f]["cv_rms"])
    assert stage["learned"]["held_out_gain_z"] > 1.0
    P = random_axes(grinder, 3000, np.random.default_rng(7))
    err = learned.predict(P) - _bump(grinder, P)
    assert np.sqrt(np.mean(err**2)) < BUMP_RECOVERY_REL * np.sqrt(np.mean(_bump(grinder, P) ** 2))
    m = stage["learned"]["map"]
    assert np.array(m["norm_um"]).shape == (11, 11) and np.array(m["band95_um"]).min() > 0


@pytest.mark.slow
def test_learned_stage_declines_pure_noise(grinder):
    rng = np.random.default_rng(SEED + 1)
    axes = random_axes(grinder, 400, rng)
    r = NOISE_UM * rng.standard_normal(axes.shape)
    learned, stage = learned_stage(grinder, r, axes, np.arange(240), np.arange(240, 400), seed=SEED)
    assert learned is None and not stage["learned"]["kept"]


@pytest.mark.slow
def test_hybrid_field_value_jacobian_and_taper(grinder, staged):
    axes, learned, _ = staged
    truth = random_truth(grinder, SEED)
    field = check_field(HybridField(HTMField(grinder, truth.elements), learned))
    assert {JACOBIAN, PREDICT_AND_JACOBIAN} <= field.capabilities
    P = random_axes(grinder, 9, np.random.default_rng(3))
    e, J = field.predict_and_jacobian(P)
    np.testing.assert_allclose(e, field.predict(P), rtol=0, atol=VALUE_TOL_UM)
    h = np.array([1e-4, 1e-4, 1e-4])
    Jfd = np.stack([(field.predict(P + h[j] * np.eye(3)[j]) - field.predict(P - h[j] * np.eye(3)[j])) / (2 * h[j])
                    for j in range(3)], -1)
    assert np.abs(J - Jfd).max() <= JAC_TOL_REL * np.abs(J).max()
    # the learned part is exactly zero once a point is TAPER_FRAC of the range outside the checks' box
    out = P.copy()
    out[:, 0] = learned.hi[0] + (TAPER_FRAC + 0.01) * (learned.hi[0] - learned.lo[0])
    assert np.all(learned.predict(out) == 0.0)
    assert np.all(learned.predict_and_jacobian(out)[1] == 0.0)


@pytest.mark.slow
def test_model_json_round_trip_and_solvers(grinder, staged, tmp_path):
    _, learned, _ = staged
    truth = random_truth(grinder, SEED)
    truth.elements.save(tmp_path / "updated_elements.json")
    (tmp_path / "model.json").write_text(json.dumps({
        "format": "volcomp-diagnosed-model/1", "elements": "updated_elements.json", "terms": [],
        "stage": "learned_residual", "learned_residual": learned.to_dict()}))
    cf = load_diagnosed_model(tmp_path / "model.json", grinder)
    assert isinstance(cf.base, HybridField)
    field = HybridField(HTMField(grinder, truth.elements), learned)
    P = random_axes(grinder, 200, np.random.default_rng(4))
    np.testing.assert_array_equal(cf.base.predict(P), field.predict(P))
    targets = forward(grinder, P)
    res = solve("exact", cf.base, targets, grinder)
    assert np.abs(res.residual_um).max() <= EXACT_MODEL_TOL_UM
    res = solve("batched-ga", cf.base, targets[:50], grinder)
    assert np.linalg.norm(res.residual_um, axis=1).max() <= BATCHED_GA_MAX_UM
    # the per-point GA (PyGAD semantics) on the same loaded hybrid: a few points, its own seed; the
    # paper's worst GA residual is the bound (the batched GA's, which is the same figure)
    res = solve("ga", cf.base, targets[:3], grinder, seed=11, progress=False)
    assert res.success.all()
    assert np.linalg.norm(res.residual_um, axis=1).max() <= BATCHED_GA_MAX_UM


def test_bad_learned_residual_is_refused_naming_the_key(grinder, tmp_path):
    from errormap.io import InputError
    truth = random_truth(grinder, SEED)
    truth.elements.save(tmp_path / "updated_elements.json")
    (tmp_path / "model.json").write_text(json.dumps({
        "format": "volcomp-diagnosed-model/1", "elements": "updated_elements.json", "terms": [],
        "learned_residual": {"format": "something"}}))
    with pytest.raises(InputError, match="learned_residual"):
        load_diagnosed_model(tmp_path / "model.json", grinder)


HELD_OUT_FLOOR_FACTOR = 1.25
"""Issue 28: the kept stage's held-out MEASURED RMS within 1.25 × the noise floor √3·σ̂."""


BAND95_COVER_LO, BAND95_COVER_HI = 0.90, 0.98
"""The issue's target for the 95 % band's coverage on held-out checks (960 components here: the
binomial SE at 95 % is 0.7 %, so the range is not met by chance alone)."""


def _user_path(tmp_path, seed: int, effect: str, checks: int = 800) -> dict:
    """sweeps (2 μm, noise seed 7) → simulate (``effect``, ``checks`` checks at 1 μm) → identify (40 bootstrap
    draws) → diagnose into ``tmp_path/d``; → diagnosis.json."""
    from compensation.app.cli import main
    q = ["--seed", str(seed), "--effect", effect]
    assert main(["sweeps", *q, "--noise-um", "2", "--seed-noise", "7", "--out", str(tmp_path / "sw.csv")]) == 0
    assert main(["simulate", *q, "--checks", str(checks), "--noise-um", "1", "--out", str(tmp_path / "sim")]) == 0
    assert main(["identify", str(tmp_path / "sw.csv"), "--out", str(tmp_path / "el.json"), "--bootstrap", "40"]) == 0
    assert main(["diagnose", str(tmp_path / "sim" / "checks.csv"), "--model", str(tmp_path / "el.json"),
                 "--out", str(tmp_path / "d")]) == 0
    return json.loads((tmp_path / "d" / "diagnosis.json").read_text())


@pytest.mark.slow
def test_user_path_learns_an_out_of_catalogue_bump_and_compensates_with_it(bump_user_path, tmp_path):
    """sweeps → simulate (bump) → identify → diagnose (the shared run, tests/shared_runs.py): the learned
    stage is kept and beats the loop on the held-out checks; compensate --model DIR/model.json solves the
    hybrid (exact)."""
    from compensation.app.cli import main
    from errormap.io import read_table, write_csv
    d = bump_user_path.root / "d"
    s = json.loads((d / "diagnosis.json").read_text())
    assert s["kept_stage"] == "learned_residual" and s["learned_residual"]["kept"]
    st = s["stages"]
    assert st["learned_residual"]["held_out"]["rms_um"] < st[s["base_stage"]]["held_out"]["rms_um"]
    assert s["rms_final_um"] <= HELD_OUT_FLOOR_FACTOR * np.sqrt(3) * s["update"]["check_noise_sigma_um"]
    cover = s["learned_residual"]["held_out_band95_cover_total"]   # the hybrid's total band ⊕ noise
    assert BAND95_COVER_LO <= cover <= BAND95_COVER_HI
    assert "band95_total_um" in s["learned_residual"]["map"]
    model = json.loads((d / "model.json").read_text())
    assert model["format"] == "volcomp-diagnosed-model/1" and model["stage"] == "learned_residual"
    P = random_axes(load_machine(), 100, np.random.default_rng(0))
    lo, hi = np.array(model["learned_residual"]["box_lo"]), np.array(model["learned_residual"]["box_hi"])
    P[:, :2] = lo + (P[:, :2] - P[:, :2].min(0)) / np.ptp(P[:, :2], axis=0) * (hi - lo) * 0.99 + 0.005 * (hi - lo)
    write_csv(tmp_path / "pts.csv", dict(zip(("x_mm", "z_mm", "a_deg"), P.T)), float_fmt="%.12g")
    assert main(["compensate", str(tmp_path / "pts.csv"), "--model", str(d / "model.json"),
                 "--method", "exact", "--out", str(tmp_path / "c"), "--temp-c", "20", "--time-s", "0",
                 "--dir-x", "1", "--dir-z", "1", "--dir-a", "1"]) == 0
    summ = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert summ["model_max_um"] <= EXACT_MODEL_TOL_UM
    assert read_table(tmp_path / "c" / "pts.csv").float("x_mm").shape == (100,)


OOC_MIN_RMS_UM = 1.5
"""Each out-of-catalogue effect at its default magnitude moves the volume's error by ≥ 1.5 μm RMS
(measured 2.4-5 μm on seed 1): above the 1 μm check noise, so the checks can see it."""


@pytest.mark.parametrize("family", ["default", "independent"])
def test_out_of_catalogue_effects_are_seeded_and_visible(grinder, family):
    from errormap.simulator import OUT_OF_CATALOGUE
    from errormap.truth_families import make_truth
    P = random_axes(grinder, 500, np.random.default_rng(0))
    base = make_truth(grinder, 1, family=family).spatial_error(P)
    for eff in OUT_OF_CATALOGUE:
        d = make_truth(grinder, 1, effects=[eff], family=family).spatial_error(P) - base
        assert np.sqrt(np.mean(np.sum(d**2, axis=1))) >= OOC_MIN_RMS_UM
        again = make_truth(grinder, 1, effects=[eff], family=family).spatial_error(P) - base
        np.testing.assert_array_equal(d, again)


MIXED_DIFF_RTOL = 1e-9
"""The mixed second difference of squareness_xz over the corners {lo, mid}² of X and Z is exactly
k·(sin(π/2))² = k; 1e-9 relative is round-off of the sines (and of subtracting the same seed's
base squareness), far below any wrong formula."""


def test_squareness_xz_is_not_separable_in_x_and_z(grinder):
    """The designed position-dependent squareness varies over X and Z together: its mixed second
    difference over the corners (x, z) ∈ {lo, mid}² is k·(sin 0 − sin π/2)² = k ≠ 0, which no
    sum of an X profile and a Z profile has."""
    from errormap.htm import IDX
    from errormap.simulator import EFFECT_DEFAULTS
    lo = np.array([grinder.strokes["x_mm"][0], grinder.strokes["z_mm"][0]])
    mid = lo + 0.5 * np.array([np.ptp(grinder.strokes["x_mm"]), np.ptp(grinder.strokes["z_mm"])])
    corners = np.array([[lo[0], lo[1], 0.0], [lo[0], mid[1], 0.0], [mid[0], lo[1], 0.0], [mid[0], mid[1], 0.0]])
    base = random_truth(grinder, SEED)
    with_eff = random_truth(grinder, SEED, effects=["squareness_xz"])
    s = with_eff.element_values(corners)[:, IDX["s_xz"]] - base.element_values(corners)[:, IDX["s_xz"]]
    mixed = s[0] - s[1] - s[2] + s[3]
    np.testing.assert_allclose(mixed, EFFECT_DEFAULTS["squareness_xz"]["k_urad"], rtol=MIXED_DIFF_RTOL)


STATIC_UM = 3.0
"""Amplitude of the static error of X (dz, a smooth arch over the stroke, as a_tilt leaves) that a
condition term imitates in the replacement test: ~2 μm RMS, above the 1 μm check noise."""

THERMAL_UM_PER_MM_C = 0.01
"""A real thermal growth of X (μm per mm per °C: ~8 μm at the end of a 200 mm stroke at +4 °C),
the catalogue's thermal effect: the learned field of the axes must NOT replace its term."""


PARTIAL_GAMMA = 0.35
"""A term only partly real in the replacement test: the data hold 0.35 of the loop's term's
condition-dependence (the judged round-7 tilt machines kept terms at coefficients 0.28–0.39); the
rest stood in for a static error. Significantly non-zero (~6 se) and far from 1 (~10 se): replaced."""

TERM_COEF_SE_TOL = 3.0
"""A real term's coefficient beside the static learned field is 1 (the loop fitted it) up to its
generalised-least-squares standard error; 3 standard errors (two-sided 0.3 %) is the tolerance."""


def _warming_temp(n):
    """The simulator's check temperatures (°C), shape (n,): 20 + 4·(1 − exp(−t/2400 s)), 15 s apart."""
    return 20.0 + 4.0 * (1.0 - np.exp(-np.arange(n) * 15.0 / 2400.0))


def _condition_term_fit(axes, temp, target, fit_idx):
    """A thermal term dz ∝ (T − 20)·x fitted by least squares to ``target``'s dz on the fitting
    checks (as the effect search would): its contribution (n, 3) μm."""
    basis = (temp - 20.0) * axes[:, 0]
    beta = np.dot(basis[fit_idx], target[fit_idx, 2]) / np.dot(basis[fit_idx], basis[fit_idx])
    c = np.zeros_like(target)
    c[:, 2] = beta * basis
    return c


@pytest.mark.slow
@pytest.mark.parametrize("truth", ["static", "thermal", "partial"])
def test_learned_field_replaces_a_condition_term_only_when_it_stood_in_for_a_static_error(grinder, truth):
    rng = np.random.default_rng(SEED + 2)
    n, n_fit = 800, 480
    axes = random_axes(grinder, n, rng)
    temp = _warming_temp(n)
    u = (axes[:, 0] - grinder.strokes["x_mm"][0]) / np.ptp(grinder.strokes["x_mm"])
    err = np.zeros((n, 3))
    thermal = THERMAL_UM_PER_MM_C * (temp - 20.0) * (axes[:, 0] - grinder.strokes["x_mm"][0])
    if truth == "static":
        err[:, 2] = STATIC_UM * np.sin(np.pi * u) - STATIC_UM * 2 / np.pi
    elif truth == "thermal":
        err[:, 2] = thermal
    else:   # the loop's term is the full thermal growth; the data hold PARTIAL_GAMMA of it beside a static arch
        err[:, 2] = STATIC_UM * np.sin(np.pi * u) - STATIC_UM * 2 / np.pi + PARTIAL_GAMMA * thermal
    r_static = err + NOISE_UM * rng.standard_normal((n, 3))   # the stage without its condition term
    fit_idx, hold_idx = np.arange(n_fit), np.arange(n_fit, n)
    if truth == "partial":
        term = np.zeros((n, 3))
        term[:, 2] = thermal
        r_prev = r_static - term
    else:
        r_prev = r_static - _condition_term_fit(axes, temp, r_static, fit_idx)
    learned, stage = learned_stage(grinder, r_prev, axes, fit_idx, hold_idx, seed=SEED, r_static_um=r_static)
    alt = stage["learned"]["condition_terms_vs_static"]
    if truth == "static":
        # the stand-in's coefficient beside a static field of the axes is not above TERM_KEEP_Z standard errors
        assert alt["replaces_condition_terms"] and not alt["term_z"] > TERM_KEEP_Z
        assert learned is not None and stage["learned"]["replaces_condition_terms"]
        # at the reference temperature (20 °C) the hybrid field now holds the static error
        P = random_axes(grinder, 2000, np.random.default_rng(SEED + 3))
        uP = (P[:, 0] - grinder.strokes["x_mm"][0]) / np.ptp(grinder.strokes["x_mm"])
        e = STATIC_UM * np.sin(np.pi * uP) - STATIC_UM * 2 / np.pi
        left = learned.predict(P)[:, 2] - e
        assert np.sqrt(np.mean(left**2)) < BUMP_RECOVERY_REL * np.sqrt(np.mean(e**2))
    elif truth == "thermal":
        assert not alt["replaces_condition_terms"] and alt["term_z"] > TERM_KEEP_Z
        # the real term's coefficient, estimated beside the static field, is the loop's (1) within its error
        assert abs(alt["term_coefficient"] - 1.0) <= TERM_COEF_SE_TOL * alt["term_coefficient_se"]
        assert alt["term_z_from_one"] < TERM_CONSISTENT_Z
        assert not stage["learned"]["replaces_condition_terms"]
    else:
        # significantly non-zero, but PARTIAL_GAMMA within its error, far from 1: the second condition replaces it
        assert alt["term_z"] > TERM_KEEP_Z
        assert abs(alt["term_coefficient"] - PARTIAL_GAMMA) <= TERM_COEF_SE_TOL * alt["term_coefficient_se"]
        assert alt["term_z_from_one"] >= TERM_CONSISTENT_Z
        assert alt["replaces_condition_terms"] and stage["learned"]["replaces_condition_terms"]


def test_hybrid_calibrated_volume_is_the_checks_box_and_the_guard_refuses_outside(grinder):
    """The hybrid's calibrated volume is the base's narrowed to the checks' X–Z box; the volume
    guard refuses a command outside it (and --allow volume would override, recorded by compensate)."""
    from compensation import guards
    from training.residual import ResidualRegressor
    from compensation.hybrid import axis_features
    rng = np.random.default_rng(SEED + 4)
    axes = random_axes(grinder, 60, rng)
    axes[:, 0] = 50.0 + 100.0 * rng.random(60)      # checks only over X 50…150 mm, Z 10…50 mm
    axes[:, 1] = 10.0 + 40.0 * rng.random(60)
    reg = ResidualRegressor(seed=SEED).fit(axis_features(axes)[0], NOISE_UM * rng.standard_normal((60, 3)))
    lo, hi = axes[:, :2].min(0), axes[:, :2].max(0)
    base = HTMField(grinder, random_truth(grinder, SEED).elements)
    hyb = HybridField(base, LearnedResidual(reg, lo, hi))
    vol = hyb.calibrated_volume
    assert vol.lo[:2] == tuple(lo) and vol.hi[:2] == tuple(hi)
    assert (vol.lo[2], vol.hi[2]) == (base.calibrated_volume.lo[2], base.calibrated_volume.hi[2])
    inside = np.array([[100.0, 30.0, 45.0]])
    outside = np.array([[lo[0] - 5.0, 30.0, 45.0], [100.0, hi[1] + 2.0, 45.0]])
    assert len(guards.volume_violations(inside, hyb)[0]) == 0
    assert list(guards.volume_violations(outside, hyb)[0]) == [0, 1]
    assert len(guards.volume_violations(outside, base)[0]) == 0   # the base alone would have accepted them


BAND_TOL_UM = 1e-12
"""The total band's square is the sum of two variances computed by the same code paths: round-off only."""


def test_hybrid_total_band_is_learned_band_plus_element_band(grinder):
    """band_std = sqrt(learned std² + diag(J Σ Jᵀ)); without a covariance, the learned band alone."""
    from compensation.hybrid import axis_features
    from errormap.uncertainty import ElementCovariance, theta_from_elements, theta_layout
    from training.residual import ResidualRegressor
    rng = np.random.default_rng(SEED + 5)
    axes = random_axes(grinder, 80, rng)
    r = _bump(grinder, axes) + NOISE_UM * rng.standard_normal(axes.shape)
    reg = ResidualRegressor(seed=SEED, margin_se=0.0).fit(axis_features(axes)[0], r)
    el = random_truth(grinder, SEED).elements
    p = len(theta_layout(el))
    cov = ElementCovariance(theta_from_elements(el), 0.25 * np.eye(p), el, {})
    hyb = HybridField(HTMField(grinder, el), LearnedResidual(reg, axes[:, :2].min(0), axes[:, :2].max(0)))
    P = random_axes(grinder, 50, np.random.default_rng(SEED + 6))
    _, s_learned = hyb.learned.predict(P, return_std=True)
    el_var = np.diagonal(cov.prediction_cov(grinder, P), axis1=1, axis2=2)
    assert np.all(el_var > 0) and np.all(s_learned > 0)
    np.testing.assert_allclose(hyb.band_std(P), s_learned, atol=BAND_TOL_UM)
    np.testing.assert_allclose(hyb.band_std(P, cov) ** 2, s_learned**2 + el_var, atol=BAND_TOL_UM)


# --- volcomp predict on a diagnosed (hybrid) model.json (issue 28 point 3) -----------------------

PREDICT_TOL_UM = 1e-6
"""predict's CSV vs the field in memory: write_csv's default %.9g keeps 9 significant digits, i.e.
≤ 5e-7 μm on values below 1000 μm; 1e-6 μm is that rounding, not a model."""

BAND_TOL_REL = 1e-8
"""The band column vs Z95·√(learned std² + diag(J Σ Jᵀ)) computed here: the same formula, only the
CSV's 9 significant digits (5e-9 relative) between them."""


def _read(path):
    from errormap.io import read_table
    t = read_table(path)
    return t, t.comments   # the provenance lines (its sidecar)


def _identified(tmp_path):
    """An element set with its covariance, as volcomp identify writes them (small bootstrap)."""
    from compensation.app.cli import main
    sw = tmp_path / "sw.csv"
    assert main(["sweeps", "--seed", "2", "--out", str(sw)]) == 0
    el = tmp_path / "el.json"
    assert main(["identify", str(sw), "--out", str(el), "--bootstrap", "10"]) == 0
    return el


def _points(grinder, lo, hi, path):
    """6 points inside the checks' box (lo, hi: x_mm, z_mm) and 2 outside it in X but inside the strokes
    (half-way between the box's edge and the stroke's end)."""
    rng = np.random.default_rng(11)
    inside = np.c_[rng.uniform(lo[0], hi[0], 6), rng.uniform(lo[1], hi[1], 6), rng.uniform(0, 360, 6)]
    xs = grinder.strokes["x_mm"]
    z_mid = 0.5 * (lo[1] + hi[1])
    outside = np.array([[0.5 * (hi[0] + xs[1]), z_mid, 10.0], [0.5 * (xs[0] + lo[0]), z_mid, 200.0]])
    P = np.r_[inside, outside]
    path.write_text("x_mm,z_mm,a_deg\n" + "\n".join(",".join(f"{v:.9g}" for v in p) for p in P) + "\n")
    return np.array([[float(f"{v:.9g}") for v in p] for p in P])


def test_predict_on_a_diagnosed_model_without_covariance_writes_no_band(grinder, tmp_path, capsys):
    """Elements + no learned part: the prediction is the model's; no covariance beside the elements →
    no band columns (a zero band would be a false claim) and --band is refused naming the file."""
    from compensation.app.cli import main
    truth = random_truth(grinder, SEED)
    truth.elements.save(tmp_path / "updated_elements.json")
    (tmp_path / "model.json").write_text(json.dumps({
        "format": "volcomp-diagnosed-model/1", "elements": "updated_elements.json", "terms": [], "stage": "updated"}))
    pts = tmp_path / "p.csv"
    P = _points(grinder, [0.0, 0.0], [1.0, 1.0], pts)[:6]
    pts.write_text("x_mm,z_mm,a_deg\n" + "\n".join(",".join(f"{v:.9g}" for v in p) for p in P) + "\n")
    out = tmp_path / "o.csv"
    assert main(["predict", str(pts), "--model", str(tmp_path / "model.json"), "--out", str(out)]) == 0
    t, header = _read(out)
    e = np.stack([t.float(c) for c in ("dx_um", "dy_um", "dz_um")], 1)
    np.testing.assert_allclose(e, HTMField(grinder, truth.elements).predict(P), rtol=0, atol=PREDICT_TOL_UM)
    assert "dx_band95_um" not in t.names and "learned_part" not in t.names
    assert "stage: updated" in header and any(h.startswith("band: none") for h in header)
    capsys.readouterr()
    assert main(["predict", str(pts), "--model", str(tmp_path / "model.json"), "--out", str(tmp_path / "o2.csv"),
                 "--band", "95"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "updated_elements.cov.npz" in err[0]


@pytest.mark.slow
def test_predict_on_a_hybrid_model_total_band_and_outside_flag(grinder, staged, tmp_path, capsys):
    """The kept stage's prediction (elements + learned residual), its TOTAL 95 % band (learned ⊕ the
    elements' J Σ Jᵀ), learned_part 'unknown' outside the checks' box; outside refused unless
    --allow volume, which the header records."""
    from compensation.app.cli import main
    from errormap.elements import ElementSet
    from errormap.uncertainty import Z95, ElementCovariance, covariance_path
    _, learned, _ = staged
    el = _identified(tmp_path)
    (tmp_path / "model.json").write_text(json.dumps({
        "format": "volcomp-diagnosed-model/1", "elements": el.name, "terms": [],
        "stage": "learned_residual", "learned_residual": learned.to_dict()}))
    pts = tmp_path / "p.csv"
    xs = grinder.strokes["x_mm"]
    assert xs[0] < learned.lo[0] and learned.hi[0] < xs[1]   # random checks never reach the strokes' ends exactly
    P = _points(grinder, learned.lo, learned.hi, pts)
    model = tmp_path / "model.json"
    capsys.readouterr()
    assert main(["predict", str(pts), "--model", str(model), "--out", str(tmp_path / "refused.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--allow" in err[0] and not (tmp_path / "refused.csv").exists()
    out = tmp_path / "o.csv"
    assert main(["predict", str(pts), "--model", str(model), "--out", str(out), "--allow", "volume"]) == 0
    t, header = _read(out)
    e = np.stack([t.float(c) for c in ("dx_um", "dy_um", "dz_um")], 1)
    field = HybridField(HTMField(grinder, ElementSet.load(el)), learned)
    np.testing.assert_allclose(e, field.predict(P), rtol=0, atol=PREDICT_TOL_UM)
    cov = ElementCovariance.load(covariance_path(el), ElementSet.load(el))
    sd = np.sqrt(learned.predict(P, return_std=True)[1] ** 2
                 + np.diagonal(cov.prediction_cov(grinder, P), axis1=1, axis2=2))
    band = np.stack([t.float(f"{c}_band95_um") for c in ("dx", "dy", "dz")], 1)
    np.testing.assert_allclose(band, Z95 * sd, rtol=BAND_TOL_REL)
    assert list(t.raw("learned_part")) == ["fitted"] * 6 + ["unknown"] * 2
    assert "stage: learned_residual" in header
    assert any(h.startswith("allowed: volume (2 of 8 points") for h in header)
    assert any("Gaussian process" in h or "deep ensemble" in h for h in header)
    # 1-sigma on request: the same band / Z95
    out1 = tmp_path / "o1.csv"
    assert main(["predict", str(pts), "--model", str(model), "--out", str(out1), "--allow", "volume",
                 "--band", "1sigma"]) == 0
    t1, _ = _read(out1)
    np.testing.assert_allclose(t1.float("dy_band1sigma_um"), sd[:, 1], rtol=BAND_TOL_REL)


@pytest.mark.slow
def test_solvers_on_a_hybrid_with_the_ensemble_family(grinder):
    """The deep-ensemble family inside the hybrid field: closed-form Jacobian, so exact and batched-ga
    solve with it to the issue's figures (EXACT_MODEL_TOL_UM, BATCHED_GA_MAX_UM)."""
    from compensation.hybrid import axis_features
    from training.residual import ResidualRegressor
    rng = np.random.default_rng(SEED)
    axes = random_axes(grinder, 480, rng)
    r = _bump(grinder, axes) + NOISE_UM * rng.standard_normal(axes.shape)
    f, _ = axis_features(axes)
    reg = ResidualRegressor(families=("ensemble",), seed=SEED).fit(f, r, groups=np.repeat(np.arange(10), 48))
    assert reg.chosen_ == "ensemble"
    learned = LearnedResidual(reg, axes[:, :2].min(0), axes[:, :2].max(0))
    field = HybridField(HTMField(grinder, random_truth(grinder, SEED).elements), learned)
    check_field(field)
    P = random_axes(grinder, 60, np.random.default_rng(5))
    inside = np.all((P[:, :2] >= learned.lo) & (P[:, :2] <= learned.hi), axis=1)
    P = P[inside][:40]
    targets = forward(grinder, P)
    res = solve("exact", field, targets, grinder)
    assert np.abs(res.residual_um).max() <= EXACT_MODEL_TOL_UM
    res = solve("batched-ga", field, targets[:20], grinder)
    assert np.linalg.norm(res.residual_um, axis=1).max() <= BATCHED_GA_MAX_UM


TERM_COEF_N = 400
"""Checks for the coefficient test's unit case (fitting part only: the test uses no held-out checks)."""


@pytest.mark.slow
def test_condition_term_coefficient_is_estimated_beside_a_static_field(grinder):
    """condition_term_test: r = static arch + γ0·c(T, x) + noise, c a thermal term's contribution; the
    generalised least squares beside the static field's Gaussian prior recovers γ0 within
    TERM_COEF_SE_TOL of its standard error, for γ0 = 0 (a stand-in: no condition-dependence) and 0.5."""
    from compensation.hybrid import axis_features, condition_term_test
    from training.residual import ResidualRegressor
    rng = np.random.default_rng(SEED + 5)
    axes = random_axes(grinder, TERM_COEF_N, rng)
    temp = _warming_temp(TERM_COEF_N)
    x0 = grinder.strokes["x_mm"][0]
    u = (axes[:, 0] - x0) / np.ptp(grinder.strokes["x_mm"])
    c = np.zeros((TERM_COEF_N, 3))
    c[:, 2] = THERMAL_UM_PER_MM_C * (temp - 20.0) * (axes[:, 0] - x0)
    noise = NOISE_UM * rng.standard_normal((TERM_COEF_N, 3))
    f = axis_features(axes)[0]
    groups = np.repeat(np.arange(10), TERM_COEF_N // 10)
    for gamma0 in (0.0, 0.5):
        r = noise.copy()
        r[:, 2] += STATIC_UM * np.sin(np.pi * u) + gamma0 * c[:, 2]
        reg = ResidualRegressor(families=("gp",), seed=SEED).fit(f, r, groups=groups)
        t = condition_term_test(reg, f, r, c)
        assert t["family"] == "gp" and t["coefficient_se"] > 0
        assert abs(t["coefficient"] - gamma0) <= TERM_COEF_SE_TOL * t["coefficient_se"]


def test_condition_terms_stay_only_when_their_coefficient_is_non_zero_and_consistent_with_one():
    """keeps_condition_terms: z > TERM_KEEP_Z and |γ̂ − 1|/se < TERM_CONSISTENT_Z, both strict; no
    coefficient (no linear-smoother family, or no term variation) → the terms are replaced."""
    from compensation.hybrid import keeps_condition_terms

    def term(gamma, se):
        return {"coefficient": gamma, "coefficient_se": se, "z": gamma / se, "family": "gp"}

    assert keeps_condition_terms(term(1.0, 0.06))                  # a real term: z 16.7, 0 se from 1
    assert keeps_condition_terms(term(0.94, 0.06))                 # 1 se below 1
    assert not keeps_condition_terms(term(0.35, 0.1))              # z 3.5 but 6.5 se below 1: partly a stand-in
    assert not keeps_condition_terms(term(0.2, 0.1))               # z 2: not shown to depend on the condition
    assert not keeps_condition_terms(term(1.5, 0.1))               # z 15 but 5 se above 1
    assert not keeps_condition_terms(term(0.9, 0.3))               # z exactly 3: not above TERM_KEEP_Z
    assert keeps_condition_terms(term(1.0 - TERM_CONSISTENT_Z * 0.1 + 1e-9, 0.1))
    assert not keeps_condition_terms(term(1.0 - TERM_CONSISTENT_Z * 0.1, 0.1))
    assert not keeps_condition_terms({"coefficient": None, "coefficient_se": None, "z": None, "family": None})


@pytest.mark.slow
def test_condition_terms_are_tested_one_by_one_a_real_one_stays_beside_a_replaced_stand_in(grinder):
    """Two condition terms (the benchmark's tilt with a real thermal growth: the loop accepted a real
    thermal term of X on dx_x and a stand-in thermal term on dz): tested together their coefficient
    is a mix of 1 and 0; per term (``condition_terms_um``) the real one stays (z > TERM_KEEP_Z, within
    TERM_CONSISTENT_Z of 1) and the stand-in is replaced, the learned field then fitted on the residual
    without the stand-in only (it recovers the static error the stand-in imitated)."""
    rng = np.random.default_rng(SEED + 2)
    n, n_fit = 800, 480
    axes = random_axes(grinder, n, rng)
    temp = _warming_temp(n)
    x0 = grinder.strokes["x_mm"][0]
    u = (axes[:, 0] - x0) / np.ptp(grinder.strokes["x_mm"])
    arch = STATIC_UM * np.sin(np.pi * u) - STATIC_UM * 2 / np.pi
    err = np.zeros((n, 3))
    err[:, 0] = THERMAL_UM_PER_MM_C * (temp - 20.0) * (axes[:, 0] - x0)     # real thermal growth of X
    err[:, 2] = arch                                                       # a static error the loop did not take
    r_static = err + NOISE_UM * rng.standard_normal((n, 3))
    fit_idx, hold_idx = np.arange(n_fit), np.arange(n_fit, n)
    real = np.zeros((n, 3))
    real[:, 0] = err[:, 0]
    stand_in = _condition_term_fit(axes, temp, r_static, fit_idx)           # dz ∝ (T − 20)·x fitted to the arch
    r_prev = r_static - real - stand_in
    learned, stage = learned_stage(grinder, r_prev, axes, fit_idx, hold_idx, seed=SEED, r_static_um=r_static,
                                   condition_terms_um=np.stack([real, stand_in]))
    alt = stage["learned"]["condition_terms_vs_static"]
    t_real, t_stand = alt["per_term"]
    assert t_real["z"] > TERM_KEEP_Z and t_real["z_from_one"] < TERM_CONSISTENT_Z and not t_real["replaced"]
    assert t_stand["replaced"] and not t_stand["z"] > TERM_KEEP_Z
    assert learned is not None and stage["learned"]["replaced_condition_terms"] == [1]
    P = random_axes(grinder, 2000, np.random.default_rng(SEED + 3))
    uP = (P[:, 0] - x0) / np.ptp(grinder.strokes["x_mm"])
    e = STATIC_UM * np.sin(np.pi * uP) - STATIC_UM * 2 / np.pi
    left = learned.predict(P)[:, 2] - e
    assert np.sqrt(np.mean(left**2)) < BUMP_RECOVERY_REL * np.sqrt(np.mean(e**2))


BACKFIT_STEP_REL = 0.05
"""Backfitting with a base that hardly overlaps the learned part settles at once: every round moves the
learned prediction at the checks by under 5 % of its RMS (measured < 1 % here: the toy base's smooth columns
take little of a local bump; what still moves is the hyper-parameters' re-estimation)."""


def _toy_base(grinder, axes, y, ridge=1e-3):
    """A stand-in for the element update: per error component, a ridge fit of a few smooth columns of X and
    Z (constant, slopes, a curvature) — what a base model can take up of an effect. → base_update(replaced,
    offset_um, idx) → residual (n, 3), and the log of its calls (``len(idx)`` per call)."""
    lo = np.array([grinder.strokes["x_mm"][0], grinder.strokes["z_mm"][0]])
    u = (axes[:, :2] - lo) / np.array([np.ptp(grinder.strokes["x_mm"]), np.ptp(grinder.strokes["z_mm"])])
    B = np.stack([np.ones(len(u)), u[:, 0], u[:, 1], u[:, 0] ** 2, u[:, 0] * u[:, 1]], axis=1)
    calls = []

    def base_update(replaced, offset_um, idx):
        calls.append(len(idx))
        t = (y - offset_um)[idx]
        beta = np.linalg.solve(B[idx].T @ B[idx] + ridge * np.eye(B.shape[1]), B[idx].T @ t)
        return y - B @ beta
    return base_update, calls


@pytest.mark.slow  # three learned-stage fits (blocked CV, two frames) and their backfitting
def test_learned_stage_backfits_the_learned_part_with_its_base(grinder):
    from compensation.hybrid import BACKFIT_ROUNDS
    rng = np.random.default_rng(SEED)
    axes = random_axes(grinder, 800, rng)
    y = _bump(grinder, axes) + NOISE_UM * rng.standard_normal(axes.shape)
    fit_idx, hold_idx = np.arange(480), np.arange(480, 800)
    bu, calls = _toy_base(grinder, axes, y)
    r_prev = bu(None, np.zeros_like(y), fit_idx)            # the sequential base: fitted on the whole residual
    calls.clear()
    learned, stage = learned_stage(grinder, r_prev, axes, fit_idx, hold_idx, seed=SEED, families=("gp",),
                                   base_update=bu, refit_residual=lambda replaced: bu(replaced, np.zeros_like(y), None))
    bf = stage["learned"]["backfit"]
    assert learned is not None and bf["rounds"] == BACKFIT_ROUNDS == len(bf["step_rms_um"])
    size = float(np.sqrt(np.mean(np.sum(learned.predict(axes) ** 2, axis=1))))
    assert max(bf["step_rms_um"]) < BACKFIT_STEP_REL * size
    # rounds on the fitting checks, then again on all of them before shipping (the caller ships that base)
    assert calls == [len(fit_idx)] * BACKFIT_ROUNDS + [len(y)] * BACKFIT_ROUNDS
    assert len(bf["shipped_step_rms_um"]) == BACKFIT_ROUNDS
    # the gate and the held-out figures are the backfitted hybrid's; the sequential one is reported beside
    assert stage["held_out"]["rms_um"] != bf["held_out_sequential"]["rms_um"]
    assert np.isfinite(bf["held_out_gain_z_sequential"]) and stage["learned"]["held_out_gain_z"] > 0
    # without base_update nothing is backfitted (the stage as before)
    _, plain = learned_stage(grinder, r_prev, axes, fit_idx, hold_idx, seed=SEED, families=("gp",))
    assert "backfit" not in plain["learned"]
    assert plain["held_out"]["rms_um"] == pytest.approx(bf["held_out_sequential"]["rms_um"], rel=1e-12)


TILT_LOOP_FRACTION = 0.35
"""On the user's path with an A-axis tilt growing with X (seed 0, 800 checks at 1 μm), the backfitted hybrid's
model error over the volume against the hidden truth must be below 0.35 × the loop alone's (measured 0.621 /
2.273 μm = 0.27 on this run; without backfitting the hybrid was 0.849 / 2.249 = 0.38 × the loop on the
benchmark's machine of the same seed (its own sweep noise): the bound lies between the two)."""


@pytest.mark.slow  # the user's path (sweeps → simulate → identify → diagnose), ~3 CPU min
def test_user_path_backfits_the_learned_part_with_the_update_on_an_a_axis_tilt(tmp_path):
    """The learned part and the element update are backfitted (the update no longer takes up, in its element
    profiles, part of the tilt that the learned part would then have to learn minus that part): the stage
    reports it, ships the backfitted base, writes the loop alone's own elements beside it, and the hybrid's
    model error against the hidden truth is a small fraction of the loop alone's."""
    from errormap.truth_families import make_truth
    m = load_machine()
    s = _user_path(tmp_path, 0, "a_tilt")
    lr = s["learned_residual"]
    assert s["kept_stage"] == "learned_residual" and lr["kept"]
    bf = lr["backfit"]
    assert len(bf["step_rms_um"]) == len(bf["shipped_step_rms_um"]) == bf["rounds"]
    assert s["stages"]["learned_residual"]["held_out"]["rms_um"] == s["rms_final_um"]
    assert "backfitted" in (tmp_path / "d" / "report.html").read_text()
    model = json.loads((tmp_path / "d" / "model.json").read_text())
    assert (tmp_path / "d" / model["loop_alone"]["elements"]).is_file()
    alone = {k: v for k, v in model.items() if k not in ("learned_residual", "loop_alone", "base_terms_replaced")}
    alone.update(elements=model["loop_alone"]["elements"], stage=model["base_stage"],
                 terms=model["loop_alone"]["terms"] + model.get("base_terms_replaced", []))
    alone["needs"] = sorted({c for e in alone["terms"] for c in e.get("needs", [])})
    (tmp_path / "d" / "alone.json").write_text(json.dumps(alone))
    truth = make_truth(m, 0, effects=["a_tilt"], family="default")
    P = random_axes(m, 2000, np.random.default_rng(2))
    cond = truth.default_conditions(len(P))
    e_true = truth.spatial_error(P, **cond)
    err = {}
    for label in ("model", "alone"):
        f = load_diagnosed_model(tmp_path / "d" / f"{label}.json", m)
        err[label] = float(np.sqrt(np.mean(np.sum((f.predict(P, **cond, time_s=np.zeros(len(P))) - e_true) ** 2, 1))))
    print("tilt user path, model error vs the truth (μm):", err)
    assert err["model"] < TILT_LOOP_FRACTION * err["alone"], err


CORE_FIELD_TOL_UM = 1e-9
"""The core's in-memory fields against those loaded from the files it wrote: the same doubles (JSON and npz
round-trip a double exactly) evaluated by the same code, so only round-off could differ (VALUE_TOL_UM)."""

ANY_CONDITIONS = {"temp_c": 24.0, "time_s": 7200.0, "dir_x": 1.0, "dir_z": -1.0, "dir_a": 1.0}
"""Conditions at which the diagnosed fields are compared (any values; those of the benchmark's flute path)."""


@pytest.mark.slow
def test_run_closed_loop_writes_what_the_in_memory_core_decides(bump_user_path, tmp_path):
    """`volcomp diagnose`'s closed loop is closed_loop_model (in memory) plus writing: diagnosis.json, model.json
    and the element sets are its result byte for byte (with the MLflow run id of the tracked learned residual
    added, as --track adds it), and its kept and loop-alone fields are those `volcomp compensate` builds from
    model.json and from model.json with loop_alone in place of elements and terms and without the learned part.
    The shared run (tests/shared_runs.py) recorded closed_loop_model's result as diagnose ran."""
    from compensation.diagnosed_model import loop_alone_model
    from errormap.io import write_json
    res = bump_user_path.extra["core"]
    d, mine = private_copy(bump_user_path.root / "d", tmp_path / "d"), tmp_path / "mine"
    assert res.learned is not None and res.loop_alone is not None   # the branch that writes every file
    mine.mkdir()
    shared_d = bump_user_path.root / "d"
    rid = json.loads((d / "model.json").read_text())["mlflow_run_id"]
    write_json(mine / "diagnosis.json", dict(res.summary, updated_elements_file=str(shared_d / "updated_elements.json"),
                                             learned_residual=dict(res.summary["learned_residual"], mlflow_run_id=rid)))
    write_json(mine / "model.json", dict(res.model, mlflow_run_id=rid))
    res.ship_cov.elements.save(mine / "updated_elements.json")
    res.loop_alone[0].elements.save(mine / "loop_elements.json")
    for name in ("diagnosis.json", "model.json", "updated_elements.json", "loop_elements.json"):
        assert (mine / name).read_bytes() == (d / name).read_bytes(), name
    model = json.loads((d / "model.json").read_text())
    alone = {k: v for k, v in model.items() if k not in ("learned_residual", "loop_alone", "base_terms_replaced")}
    alone.update(elements=model["loop_alone"]["elements"], stage=model["base_stage"],
                 terms=model["loop_alone"]["terms"] + model.get("base_terms_replaced", []))
    (d / "alone.json").write_text(json.dumps(alone))
    assert loop_alone_model(model)["terms"] == alone["terms"] and loop_alone_model(model)["stage"] == alone["stage"]
    m = load_machine()
    P = random_axes(m, 500, np.random.default_rng(3))
    cond = {k: np.full(len(P), v) for k, v in ANY_CONDITIONS.items()}
    for in_memory, name in ((res.kept_field(m), "model.json"), (res.loop_alone_field(m), "alone.json")):
        from_file = load_diagnosed_model(d / name, m)
        np.testing.assert_allclose(in_memory.predict(P, **cond), from_file.predict(P, **cond), rtol=0,
                                   atol=CORE_FIELD_TOL_UM, err_msg=name)


def test_loop_alone_model_is_model_json_without_its_learned_part():
    """The loop alone of a model.json: loop_alone's elements and terms plus the replaced condition terms, the
    base stage, no learned key; a model.json without a learned part is its own loop alone."""
    from compensation.diagnosed_model import LEARNED_KEYS, loop_alone_model
    t = {"kind": "thermal", "axis": "z", "element": "dz_z", "needs": ["temp_c"]}
    s = {"kind": "periodic", "axis": "x", "element": "dx_x"}
    plain = {"format": "volcomp-diagnosed-model/1", "elements": "updated_elements.json", "stage": "updated",
             "terms": [s], "needs": []}
    assert loop_alone_model(plain) == plain
    hybrid = dict(plain, stage="learned_residual", base_stage="updated_plus_effects", learned_residual={"family": "gp"},
                  base_terms_replaced=[t], learned_family={"family": "gp"},
                  loop_alone={"elements": "loop_elements.json", "terms": [dict(s, coefficients=[1.0])]})
    alone = loop_alone_model(hybrid)
    assert not set(alone) & set(LEARNED_KEYS)
    assert alone == {"format": "volcomp-diagnosed-model/1", "elements": "loop_elements.json",
                     "stage": "updated_plus_effects", "terms": [dict(s, coefficients=[1.0]), t], "needs": ["temp_c"]}
    no_backfit = {k: v for k, v in hybrid.items() if k != "loop_alone"}   # the base is the loop's own
    assert loop_alone_model(no_backfit)["elements"] == "updated_elements.json"
    assert loop_alone_model(no_backfit)["terms"] == [s, t]
