"""The learned part's input sets (axes / the tool point in the work frame / both) and the
out-of-catalogue effects designed for the learned stage: ``a_lobe_x`` (round 5) and ``xz_saddle``
(round 13) (issue 28)."""
import json

import numpy as np
import pytest

from compensation.hybrid import (INPUT_SETS, LearnedResidual, input_features, input_set_features, work_features,
                                 work_radius)
from compensation.hybrid.stage import _fit_inputs
from errormap.chain_kernel import forward
from errormap.field import GRINDER_AXES
from errormap.grinder_file import rho0_mm
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes
from training.residual import ResidualRegressor

SEED = 0

WORK_POINT_TOL_MM = 1e-9
"""The work-frame features vs the chain's forward kinematics (py, pz): the same closed form
evaluated by two code paths on values up to ~60 mm, round-off only (ε·60 mm ≈ 1e-14 mm)."""

JAC_TOL_REL = 1e-6
"""Closed-form Jacobian vs central differences (h = 1e-4 mm/deg): truncation O(h²·f''') and rounding
ε·|f|/h ≈ 1e-10 relative; 1e-6 of the largest entry is far above both and far below a wrong term."""

ROUND_TRIP_RTOL = 1e-9
"""Loading re-solves the GP weights by Cholesky: rounding only."""

MEAN_OVER_A_TOL = 1e-12
"""a_lobe_x's mean over a full turn of A (72 equally spaced positions) is exactly zero for
cos(2a + φ): what is left is round-off on values of a few μm."""

ADDITIVE_SHARE_MAX = 0.01
"""The share of a_lobe_x's (default parameters) mean square that the best sum of one-axis profiles
f(x) + g(a) takes up on a full X × A grid: the effect's mean over A is zero and its mean over X
is the odd profile's tail beyond ±3.3 widths (about 1e-3 of the peak); 1 % bounds that with room
and is far below any effect a one-axis element profile could represent."""

LINEAR_SPAN_SHARE_MAX = 0.01
"""The share of xz_saddle's (default parameters) mean square spatial error that the linearised
element model takes up — every element a free profile of its own axis (the element set's splines
on its 21 stations) and every constant, through the error-transfer Jacobian at nominal
(:func:`errormap.diagnosis.chain_update.parameter_matrix`) — on a symmetric X × Z × A grid: the effect is
orthogonal to that span up to
the odd X profile's tail beyond ±3.3 widths and the Z wavelet's beyond ±3.3 (measured 2e-5);
1 % bounds that with room."""
LINEAR_SPAN_SQUARENESS_MIN = 0.99
"""The same projection takes up squareness (a squareness varying along X: a constant squareness
plus X's angular errors times the lever) wholly (measured 1 − 2e-9): the check can see absorption."""


def test_work_radius_is_read_from_the_machine_file(grinder):
    """ρ0 of the work-frame sets comes from the machine's chain: the grinder's geometry l1 + l4 − R − l6 − l8
    to the bit; a machine without a rotary axis turning the work about its first linear axis has none."""
    assert work_radius(grinder) == rho0_mm(grinder)
    for name in ("mill-xyz", "five-axis-ac", "lathe-xzc"):
        assert work_radius(load_machine(name)) is None
    with pytest.raises(ValueError, match="only 'axes' exists here"):
        input_features(np.zeros((1, 3)), "work", 0.1, ("x_mm", "y_mm", "z_mm"))


def test_work_features_are_the_tool_point_in_the_work_frame(grinder):
    axes = random_axes(grinder, 200, np.random.default_rng(SEED))
    f, J = work_features(axes, work_radius(grinder))
    p = forward(grinder, axes)
    np.testing.assert_allclose(f[:, 1:], p[:, 1:], atol=WORK_POINT_TOL_MM, rtol=0)
    np.testing.assert_allclose(f[:, 0], axes[:, 0], atol=0, rtol=0)
    h = 1e-4
    for name in INPUT_SETS:
        f, J = input_features(axes, name, work_radius(grinder), GRINDER_AXES)
        d = len(input_set_features(name, GRINDER_AXES))
        assert f.shape == (200, d) and J.shape == (200, d, 3)
        Jfd = np.stack([(input_features(axes + h * e, name, work_radius(grinder), GRINDER_AXES)[0]
                         - input_features(axes - h * e, name, work_radius(grinder), GRINDER_AXES)[0]) / (2 * h)
                        for e in np.eye(3)], -1)
        assert np.abs(J - Jfd).max() <= JAC_TOL_REL * np.abs(J).max()
    with pytest.raises(ValueError, match="rho0_mm"):
        input_features(axes, "work", None, GRINDER_AXES)
    with pytest.raises(ValueError, match="inputs"):
        input_features(axes, "joints", work_radius(grinder), GRINDER_AXES)


@pytest.mark.parametrize("inputs", ["work", "axes+work"])
def test_learned_residual_on_work_inputs_jacobian_and_round_trip(grinder, inputs):
    rng = np.random.default_rng(SEED + 1)
    axes = random_axes(grinder, 80, rng)
    f, _ = input_features(axes, inputs, work_radius(grinder), GRINDER_AXES)
    r = np.c_[np.sin(axes[:, 0] / 40.0), 0.05 * axes[:, 1] * np.cos(np.deg2rad(axes[:, 2])), np.zeros(80)]
    reg = ResidualRegressor(seed=SEED, margin_se=0.0).fit(f, r + 0.05 * rng.standard_normal(r.shape))
    lr = LearnedResidual(reg, axes[:, :2].min(0), axes[:, :2].max(0), inputs, work_radius(grinder))
    P = random_axes(grinder, 12, np.random.default_rng(SEED + 2))
    P[0, :2] = axes[:, :2].max(0) + 3.0                     # in the taper outside the box too
    v, J = lr.predict_and_jacobian(P)
    h = 1e-4
    Jfd = np.stack([(lr.predict(P + h * e) - lr.predict(P - h * e)) / (2 * h) for e in np.eye(3)], -1)
    assert np.abs(J - Jfd).max() <= JAC_TOL_REL * np.abs(J).max()
    doc = json.loads(json.dumps(lr.to_dict()))
    assert doc["inputs"] == inputs and doc["features"] == list(input_set_features(inputs, GRINDER_AXES))
    back = LearnedResidual.from_dict(doc)
    np.testing.assert_allclose(back.predict(P), v, rtol=ROUND_TRIP_RTOL, atol=0)
    for key, bad, msg in (("rho0_mm", None, "rho0_mm"), ("inputs", "joints", "inputs"),
                          ("features", ["x_mm"], "features")):
        d2 = dict(doc)
        if bad is None:
            del d2[key]
        else:
            d2[key] = bad
        with pytest.raises(ValueError, match=msg):
            LearnedResidual.from_dict(d2)


def test_learned_residual_file_without_inputs_is_the_axes_set(grinder):
    """A model.json written before the input sets (no ``inputs`` key) loads with the axes features."""
    rng = np.random.default_rng(SEED + 3)
    axes = random_axes(grinder, 40, rng)
    f, _ = input_features(axes, "axes", None, GRINDER_AXES)
    reg = ResidualRegressor(seed=SEED, margin_se=0.0).fit(f, rng.standard_normal((40, 3)))
    doc = LearnedResidual(reg, axes[:, :2].min(0), axes[:, :2].max(0)).to_dict()
    del doc["inputs"]
    back = LearnedResidual.from_dict(doc)
    assert back.inputs == "axes" and back.rho0_mm is None


def test_input_set_choice_is_the_lowest_cv_rms_on_the_same_folds(grinder):
    """_fit_inputs cross-validates every input set on the same blocked folds and keeps the one whose
    chosen family has the lowest CV RMS."""
    rng = np.random.default_rng(SEED + 4)
    axes = random_axes(grinder, 120, rng)
    wz = (work_radius(grinder) + axes[:, 1]) * np.cos(np.deg2rad(axes[:, 2]))
    r = np.c_[0.1 * axes[:, 0] / 200.0 * wz, np.zeros(120), np.zeros(120)] + 0.3 * rng.standard_normal((120, 3))
    feats = {n: input_features(axes, n, work_radius(grinder), GRINDER_AXES)[0] for n in INPUT_SETS}
    groups = np.repeat(np.arange(10), 12)
    best, reg, table = _fit_inputs(feats, r, np.arange(120), groups, ("gp",), SEED, GRINDER_AXES)
    reg = reg.fit_chosen()   # cross-validated only: its chosen family fitted on all the data
    fitted = [n for n in INPUT_SETS if table[n]["family"] != "none"]
    assert fitted and best == min(fitted, key=lambda n: table[n]["cv_rms"])
    assert reg.n_features_in_ == len(input_set_features(best, GRINDER_AXES))
    # the folds are the same for every input set: predicting zero has the same CV RMS on each
    assert len({round(table[n]["cv_rms_zero"], 12) for n in INPUT_SETS}) == 1


def test_a_lobe_x_is_not_a_sum_of_one_axis_profiles(grinder):
    """The round-5 effect: zero mean over A, and no f(x) + g(a) takes up more than 1 % of it."""
    from errormap.elements import IDX
    with_ = make_chain_truth(grinder, SEED, effects=["a_lobe_x"])
    without = make_chain_truth(grinder, SEED)
    xs = np.linspace(*grinder.strokes["x_mm"], 81)
    a_s = np.arange(72) * 5.0
    X, A = np.meshgrid(xs, a_s, indexing="ij")
    P = np.stack([X.ravel(), np.full(X.size, 30.0), A.ravel()], axis=1)
    d = (with_.element_values(P) - without.element_values(P))[:, IDX["dy_a"]].reshape(X.shape)
    others = np.delete(with_.element_values(P) - without.element_values(P), IDX["dy_a"], axis=1)
    assert np.all(others == 0.0)
    assert np.abs(d).max() > 5.0                                  # A = 6 μm at its peak (sampled grid)
    assert np.abs(d.mean(axis=1)).max() <= MEAN_OVER_A_TOL
    additive = d.mean(axis=1, keepdims=True) + d.mean(axis=0, keepdims=True) - d.mean()
    assert np.mean(additive**2) <= ADDITIVE_SHARE_MAX * np.mean(d**2)


def test_xz_saddle_is_outside_the_linearised_element_model(grinder):
    """The round-13 effect: only Z's straightness in Y changes, and no element profile of one axis
    (nor any constant) takes it up, through the chain's error transfer; squareness, which the loop
    absorbs, is taken up wholly by the same projection."""
    from errormap.elements import IDX
    from errormap.chain_kernel import error_jacobian
    from errormap.diagnosis.chain_update import parameter_matrix
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.chain_effects import full_parameters
    xs = np.linspace(*grinder.strokes["x_mm"], 21)
    zs = np.linspace(*grinder.strokes["z_mm"], 21)
    X, Z, A = np.meshgrid(xs, zs, np.arange(24) * 15.0, indexing="ij")
    P = np.stack([X.ravel(), Z.ravel(), A.ravel()], axis=1)
    J = error_jacobian(grinder, P)
    truth = make_chain_truth(grinder, SEED)
    nominal = ChainElementSet.zeros(grinder, truth.elements.stations["x_mm"].size)   # linearised at nominal
    slots, stations = full_parameters(nominal)
    M = parameter_matrix(grinder, nominal, P, slots, stations).reshape(3 * P.shape[0], -1)
    MtM = M.T @ M
    without = truth.element_values(P)
    shares = {}
    for name in ("xz_saddle", "squareness"):
        dv = make_chain_truth(grinder, SEED, effects=[name]).element_values(P) - without
        if name == "xz_saddle":
            assert np.all(np.delete(dv, IDX["dy_z"], axis=1) == 0.0)
            assert np.abs(dv[:, IDX["dy_z"]]).max() > 7.0            # A = 8 μm at its peak (sampled grid)
        d = np.einsum("nie,ne->ni", J, dv).ravel()
        r = d - M @ np.linalg.lstsq(MtM, M.T @ d, rcond=None)[0]       # the normal equations: 377 columns
        shares[name] = 1.0 - (r @ r) / (d @ d)
    assert shares["xz_saddle"] <= LINEAR_SPAN_SHARE_MAX
    assert shares["squareness"] >= LINEAR_SPAN_SQUARENESS_MIN
