"""The arm's nested decisions: the learned stage's inputs, the pipeline CV without a hyper-parameter leak, and
the rule that picks among whole pipelines."""
import numpy as np
import pytest

from compensation.app.workflows.arm_calibration import PLAIN_GP, choose_pipeline
from errormap.arm_calibration import cv_labels, fit_model
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.machine import load_machine
from training.arm_residual import INPUTS, ArmResidualRegressor, cv_pipelines, feature_jacobian, features

# a UR5-like workspace box (deg), the real grid's ranges
UR5_LO = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0])
UR5_HI = np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
NOISE_MM = 0.02           # tracker noise per component
# a soft arm (10x draw_truth's default compliance): the DH fit leaves a smooth sag residual far above the noise,
# which the GP learns (so the learner is kept and the pipeline CV re-estimates it per fold)
SOFT_COMPLIANCE_RAD_PER_MM = 3e-7
# features' analytic Jacobian against central differences, step 1e-4 deg: truncation ~ (1.7e-6 rad)² ≈ 3e-12,
# rounding ~ 1e-16 / 1e-4 deg ≈ 1e-12 per deg; the gravity moments' own differences (m, per deg) are the loosest
FEATURE_FD_STEP_DEG = 1e-4
FEATURE_JAC_ATOL = 1e-8
# with the hyper-parameters re-estimated inside each fold the CV figure cannot depend on what the learner saw
# outside the fold's fit part: the same operations on the same numbers give the same result to round-off
NO_LEAK_ATOL_MM = 1e-12
# the held-out residual moved on one fold: large against the 0.02 mm noise so that all-poses hyper-parameters move
LEAK_SHIFT_MM = 0.5


@pytest.fixture(scope="module")
def ur5():
    return load_machine("ur5")


@pytest.mark.parametrize("inputs", INPUTS)
def test_feature_jacobian_matches_differences(ur5, inputs):
    q = random_joints(UR5_LO, UR5_HI, 6, [4, 0])
    D = feature_jacobian(ur5, q, inputs)
    assert D.shape == (6, features(ur5, q[:1], inputs).shape[1], 6)
    for j in range(6):
        e = np.zeros(6)
        e[j] = FEATURE_FD_STEP_DEG
        fd = (features(ur5, q + e, inputs) - features(ur5, q - e, inputs)) / (2 * FEATURE_FD_STEP_DEG)
        assert np.abs(D[:, :, j] - fd).max() <= FEATURE_JAC_ATOL


def test_new_inputs_extend_the_physics_inputs(ur5):
    q = random_joints(UR5_LO, UR5_HI, 5, [5, 0])
    phys = features(ur5, q, "physics")
    r = np.radians(q)
    h2 = features(ur5, q, "physics+h2")
    assert np.array_equal(h2[:, :phys.shape[1]], phys)
    assert np.allclose(h2[:, phys.shape[1]:], np.c_[np.sin(2 * r), np.cos(2 * r)], rtol=0, atol=1e-15)
    w = features(ur5, q, "physics+wrist")
    assert np.array_equal(w[:, :phys.shape[1]], phys)
    assert w.shape[1] == phys.shape[1] + 3 * 4          # 3 wrist pairs of the last 3 joints, 4 products each
    # first pair (q4, q5): s4 s5
    assert np.allclose(w[:, phys.shape[1]], np.sin(r[:, 3]) * np.sin(r[:, 4]), rtol=0, atol=1e-15)


def _cv(gain_mean, gain_sd, n=200, seed=0):
    """Pipeline CV figures: the plain GP's per-pose errors and volcomp's, lower by a given paired gain."""
    rng = np.random.default_rng(seed)
    e_gp = rng.uniform(0.05, 0.15, n)
    g = rng.normal(0, 1, n)
    g = (g - g.mean()) / g.std(ddof=1) * gain_sd + gain_mean
    e_v = e_gp - g
    return {"learned": {"cv_mean_mm": float(e_v.mean()), "errors_mm": e_v},
            "plain geometric LSQ": {"cv_mean_mm": 1.0, "errors_mm": np.ones(n)},
            PLAIN_GP: {"cv_mean_mm": float(e_gp.mean()), "errors_mm": e_gp}}


def test_one_se_rule_leaves_the_plain_gp_only_on_evidence():
    n, sd = 200, 0.01
    se = sd / np.sqrt(n)
    small, large = _cv(0.5 * se, sd, n), _cv(3 * se, sd, n)
    assert choose_pipeline(small, "learned", "lowest") == "learned"       # lower, but within one standard error
    assert choose_pipeline(small, "learned", "one-se") == PLAIN_GP
    assert choose_pipeline(large, "learned", "one-se") == "learned"
    worse = _cv(-3 * se, sd, n)
    assert choose_pipeline(worse, "learned", "lowest") == choose_pipeline(worse, "learned", "one-se") == PLAIN_GP
    with pytest.raises(ValueError, match="pipeline rule"):
        choose_pipeline(small, "learned", "best")


@pytest.mark.slow
def test_pipeline_cv_hyper_parameters_see_no_held_out_fold(ur5):
    """hyper="fold": the learner's hyper-parameters are re-estimated on each inner fold's fit part, so a learner
    fitted on all poses with one fold's residual shifted gives the SAME CV figures; with the all-poses
    hyper-parameters kept (hyper="fit", the earlier rule) that fold leaks in and the figures move."""
    t = draw_truth(ur5, 21, compliance_rad_per_mm=np.full(ur5.n_joints, SOFT_COMPLIANCE_RAD_PER_MM))
    p = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 90, [21, 0]), NOISE_MM, [21, 1])
    geo = fit_model(ur5, p, "dh")
    res = p.xyz_mm - geo.predict(p.q)
    lab = cv_labels(len(p), 3, 7)
    shifted = res + np.where(lab[:, None] == 0, LEAK_SHIFT_MM, 0.0)
    a = ArmResidualRegressor(ur5, margin_se=0.0, k_folds=3).fit(p.q, res)
    b = ArmResidualRegressor(ur5, margin_se=0.0, k_folds=3).fit(p.q, shifted)
    assert a.chosen_ == b.chosen_ == "gp"
    assert not np.allclose(a.regressor_.model_.theta_, b.regressor_.model_.theta_)
    ff = {}
    cvs = [cv_pipelines(ur5, p, {"learned": ("dh", lr)}, 3, 7, fold_fits=ff)["learned"] for lr in (a, b)]
    fold = [c["errors_mm"] for c in cvs]
    assert np.allclose(fold[0], fold[1], rtol=0, atol=NO_LEAK_ATOL_MM)
    # the held-out predictions handed back are the ones the errors were measured on
    assert np.allclose(np.linalg.norm(p.xyz_mm - cvs[0]["pred_mm"], axis=1), fold[0], rtol=0, atol=NO_LEAK_ATOL_MM)
    fit = [cv_pipelines(ur5, p, {"learned": ("dh", lr)}, 3, 7, fold_fits=ff, hyper="fit")["learned"]["errors_mm"]
           for lr in (a, b)]
    assert np.abs(fit[0] - fit[1]).max() > 1e3 * NO_LEAK_ATOL_MM


# --- the folds of the pipeline CV are the geometric CV's (also for a SeedSequence seed) ------------------------
# the plain LSQ pipeline of the pipeline CV and the geometric CV's "plain" row are the same fits on the same folds
# handed over (fold_fits): identical operations, identical figures to round-off
SAME_FOLDS_ATOL_MM = 1e-12


def test_cv_labels_same_for_the_same_seed_sequence():
    """calibrate_arm hands one SeedSequence to the geometric CV and then to the pipeline CV: spawning from it
    advances it, and the second CV drew other folds while reusing the first CV's fold fits (fits that had seen
    the poses they were then judged on). The labels are drawn from a copy: same folds every call."""
    ss = np.random.SeedSequence(0).spawn(3)[0]
    first = cv_labels(200, 3, ss)
    assert np.array_equal(cv_labels(200, 3, ss), first)
    assert np.array_equal(cv_labels(200, 3, np.random.SeedSequence(0).spawn(3)[0]), first)
    assert not np.array_equal(cv_labels(200, 3, np.random.SeedSequence(0).spawn(3)[1]), first)


def test_fold_fits_of_other_folds_are_refused(ur5):
    t = draw_truth(ur5, 22)
    p = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 60, [22, 0]), NOISE_MM, [22, 1])
    ff = {}
    cv_pipelines(ur5, p, {"geometric": ("dh", None)}, 3, 1, fold_fits=ff)
    with pytest.raises(ValueError, match="other folds"):
        cv_pipelines(ur5, p, {"geometric": ("dh", None)}, 3, 2, fold_fits=ff)


@pytest.mark.slow
def test_calibrate_arm_pipeline_cv_is_on_the_geometric_cv_folds(ur5):
    """Through calibrate_arm (seeds as SeedSequence children): the plain LSQ pipeline's pipeline-CV figure is the
    geometric CV's plain figure, and volcomp's geometric pipeline (the learner declined or not) is judged on the
    same folds as its slot set was chosen on."""
    from compensation.app.workflows.arm_calibration import calibrate_arm
    t = draw_truth(ur5, 23)
    fit = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 120, [23, 0]), NOISE_MM, [23, 1])
    check = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 30, [23, 2]), NOISE_MM, [23, 3])
    core = calibrate_arm(ur5, fit, check, learned=True, k_folds=3)
    geo_cv = {r["model"]: r["cv_mean_mm"] for r in core["cv_geometric"]}
    pcv = core["pipeline_cv_errors"]
    assert abs(pcv["plain geometric LSQ"]["cv_mean_mm"] - geo_cv["plain"]) <= SAME_FOLDS_ATOL_MM
    vol = core["pipeline_volcomp"]
    if vol != "learned":
        model = core["volcomp_geometric_model"].model
        assert abs(pcv[vol]["cv_mean_mm"] - geo_cv[model]) <= SAME_FOLDS_ATOL_MM


# --- the learned stage's GP kernel, chosen by its own CV ---------------------------------------------------------
# the same GP (family, data, single deterministic start) estimated twice: equal to the optimiser's round-off
REFIT_SAME_ATOL_MM = 1e-9

def test_kernel_chosen_by_cv_and_kept_in_json(ur5):
    """families=KERNEL_FAMILIES: every kernel is cross-validated against zero; the kept one is the lowest CV RMS of
    those that beat zero by the margin; the JSON keeps the families and predicts identically; a file from before
    the kernel choice (no "families") reads as the squared exponential alone."""
    import json
    from training.arm_residual import KERNEL_FAMILIES
    from training.gp import GP_KERNELS
    t = draw_truth(ur5, 24, compliance_rad_per_mm=np.full(ur5.n_joints, SOFT_COMPLIANCE_RAD_PER_MM))
    p = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 90, [24, 0]), NOISE_MM, [24, 1])
    res = p.xyz_mm - fit_model(ur5, p, "dh").predict(p.q)
    lr = ArmResidualRegressor(ur5, k_folds=3, families=KERNEL_FAMILIES).fit(p.q, res)
    tab = lr.cv_table_
    assert set(KERNEL_FAMILIES) <= set(tab)
    eligible = [f for f in KERNEL_FAMILIES if tab[f]["gain_mean"] > max(lr.margin_se * tab[f]["gain_se"], 0)]
    assert eligible, "the soft arm's sag residual is far above the noise: some kernel must beat zero"
    assert lr.chosen_ == min(eligible, key=lambda f: tab[f]["cv_rms"])
    assert lr.regressor_.model_.kernel == GP_KERNELS[lr.chosen_]
    d = json.loads(json.dumps(lr.to_dict()))
    back = ArmResidualRegressor.from_dict(ur5, d)
    qt = random_joints(UR5_LO, UR5_HI, 5, [24, 2])
    assert back.families == KERNEL_FAMILIES and np.array_equal(back.predict(qt), lr.predict(qt))
    # refit(family=): any cross-validated kernel re-estimated on given data (the benchmark's per-kernel outer figure);
    # the chosen one reproduces the fitted learner (same data, same deterministic single start)
    X = features(ur5, p.q, "physics")
    same = lr.regressor_.refit(X, res, family=lr.chosen_)
    assert np.allclose(same.predict(features(ur5, qt, "physics")), lr.predict(qt), rtol=0, atol=REFIT_SAME_ATOL_MM)
    other = next(f for f in KERNEL_FAMILIES if f != lr.chosen_)
    assert lr.regressor_.refit(X, res, family=other).model_.kernel == GP_KERNELS[other]
    with pytest.raises(ValueError, match="cross-validated family"):
        lr.regressor_.refit(X, res, family="zero")
    old = ArmResidualRegressor(ur5, k_folds=3).fit(p.q, res).to_dict()
    del old["families"]
    assert ArmResidualRegressor.from_dict(ur5, old).families == ("gp",)
    for bad in ((), ("ensemble",), ("gp", "gp")):
        with pytest.raises(ValueError, match="families"):
            ArmResidualRegressor(ur5, families=bad)


def test_stack_weight_from_inner_predictions():
    """The stacking rule's weight: errors of opposite sign cancel at w = 0.5; a perfect volcomp pipeline gets w = 1,
    a perfect plain GP w = 0; equal predictions tie toward volcomp (w = 1)."""
    from training.arm_residual import stack_weight
    rng = np.random.default_rng(3)
    y = rng.normal(0, 1, (50, 3))
    e = rng.normal(0, 0.1, (50, 3))
    assert stack_weight(y, y + e, y - e)[0] == 0.5
    assert stack_weight(y, y, y + e)[0] == 1.0
    assert stack_weight(y, y + e, y)[0] == 0.0
    w, curve = stack_weight(y, y + e, y + e)
    assert w == 1.0 and np.ptp(curve) <= 1e-12 * curve.min()   # equal up to round-off: STACK_TIE_REL
