"""The lower-variance learned-residual families (issue 28): ``gp_additive`` (additive GP over input groups)
and ``basis`` (empirical-Bayes Legendre × Fourier regression): Jacobian, save/load, band, decay outside the data."""
import json

import numpy as np
import pytest

from training.basis import ENVELOPE_FRAC, BasisRegression, _legendre
from training.gp import additive_terms, check_input_groups
from training.residual import ResidualRegressor

GROUPS = ((0,), (1,), (2, 3))
"""Inputs as the hybrid's ``axes`` set: x, z (linear), and cos a, sin a (one rotary axis)."""

JAC_TOL_REL = 1e-6
"""Closed-form Jacobian vs central differences (h = 1e-5 in standardised-scale inputs): O(h²)·f''' ≈ 1e-9
relative plus rounding ε·|f|/h ≈ 1e-11; 1e-6 of the largest entry is far above both and far below a
wrong term (a missing chain-rule factor is O(1))."""

ROUND_TRIP_RTOL = 1e-9
"""Loading re-solves the weights (Cholesky) from the saved data and hyper-parameters: rounding only."""

FAR_ABS_TOL = 1e-6
"""Far from every training point (50 units in every input, length scales bounded by 5) an additive GP's
every term is at most exp(−0.5·(50/5)²) ≈ 2e-22 of its variance: zero to 1e-6 of the field's scale."""

BAND_TOL_REL = 1e-9
"""The basis band outside the data equals the prior's std at the box's edge, computed the same way: rounding."""

RECOVERY_RMS_MAX = 0.25
"""On 240 points at noise 0.1 of an additive field of RMS ≈ 1.2 (a function of x, one of a, and an x·a
coupling), both families leave < 0.25 RMS off the training points (measured 0.05–0.1); a fit that
failed to learn the field leaves ≈ 1.2."""


def _field(X):
    a = np.arctan2(X[:, 3], X[:, 2])
    return np.c_[np.sin(2 * X[:, 0]) + 0.5 * np.cos(a), X[:, 0] * np.sin(a), 0.6 * X[:, 1] ** 2]


def _data(seed, n=240, noise=0.1):
    rng = np.random.default_rng(seed)
    xz = rng.uniform(-1, 1, (n, 2))
    a = rng.uniform(0, 2 * np.pi, n)
    X = np.c_[xz, np.cos(a), np.sin(a)]
    return X, _field(X) + noise * rng.standard_normal((n, 3))


_FITS = {}


def _fit(family):
    """One fit per family, shared by the tests (the additive GP's takes ~7 CPU s: its tests are slow)."""
    if family not in _FITS:
        X, Y = _data(0)
        _FITS[family] = X, ResidualRegressor(families=(family,), seed=0, margin_se=0.0, input_groups=GROUPS).fit(
            X, Y, groups=np.repeat(np.arange(10), 24))
    return _FITS[family]


PARAMS = [pytest.param("gp_additive", marks=pytest.mark.slow), "basis"]


def test_additive_terms_are_the_groups_and_their_pairs():
    assert additive_terms(4, GROUPS) == ((0,), (1,), (2, 3), (0, 1), (0, 2, 3), (1, 2, 3))
    assert additive_terms(2) == ((0,), (1,), (0, 1))
    with pytest.raises(ValueError, match="partition"):
        check_input_groups(((0,), (2, 3)), 4)
    with pytest.raises(ValueError, match="partition"):
        ResidualRegressor(families=("gp_additive",), input_groups=((0, 1), (1, 2), (3,))).fit(*_data(1, n=40))


def test_legendre_derivative_recurrence():
    """The basis's Legendre values and derivatives against numpy's."""
    u = np.linspace(-1, 1, 11)
    P, dP = _legendre(u, 6)
    for k in range(7):
        c = np.zeros(k + 1)
        c[k] = 1.0
        np.testing.assert_allclose(P[:, k], np.polynomial.legendre.legval(u, c), atol=1e-12)
        np.testing.assert_allclose(dP[:, k], np.polynomial.legendre.legval(u, np.polynomial.legendre.legder(c)), atol=1e-11)


@pytest.mark.parametrize("family", PARAMS)
def test_new_family_learns_jacobian_and_round_trip(family):
    X, r = _fit(family)
    assert r.chosen_ == family
    Xq, _ = _data(7, n=400)
    rms = np.sqrt(np.mean(np.sum((r.predict(Xq) - _field(Xq)) ** 2, 1)))
    assert rms < RECOVERY_RMS_MAX
    Xj = np.vstack([Xq[:6], X[:2]])                     # at training points too
    v, J = r.predict_and_jacobian(Xj)
    h = 1e-5
    Jfd = np.stack([(r.predict(Xj + h * np.eye(4)[j]) - r.predict(Xj - h * np.eye(4)[j])) / (2 * h) for j in range(4)], -1)
    assert np.abs(J - Jfd).max() <= JAC_TOL_REL * np.abs(J).max()
    doc = json.loads(json.dumps(r.to_dict()))
    assert doc["settings"]["input_groups"] == [list(g) for g in GROUPS]
    back = ResidualRegressor.from_dict(doc)
    np.testing.assert_allclose(back.predict(Xq), r.predict(Xq), rtol=ROUND_TRIP_RTOL, atol=1e-12)
    np.testing.assert_allclose(back.predict(Xq, return_std=True)[1], r.predict(Xq, return_std=True)[1],
                               rtol=ROUND_TRIP_RTOL)
    X2, Y2 = _data(3, n=200)
    for again in (r.refit(X2, Y2, seed=1), r.with_data(X2, Y2)):   # the refit on all checks reloads to the same numbers
        assert again.chosen_ == family
        back2 = ResidualRegressor.from_dict(json.loads(json.dumps(again.to_dict())))
        np.testing.assert_allclose(back2.predict(Xq), again.predict(Xq), rtol=ROUND_TRIP_RTOL, atol=1e-12)


@pytest.mark.slow
def test_additive_gp_decays_far_from_the_data_and_its_band_rises_to_the_prior():
    X, r = _fit("gp_additive")
    far = X[:5] + 50.0 * r.x_scale_[None, :]
    m, sd = r.predict(far, return_std=True)
    assert np.abs(m).max() <= FAR_ABS_TOL
    prior_sd = np.array([np.sqrt(sum(p[1] for p in r.model_._hyp(k)[0])) for k in range(3)]) * r.y_scale_ * r.band_scale_
    np.testing.assert_allclose(sd, np.broadcast_to(prior_sd, sd.shape), rtol=BAND_TOL_REL)
    _, sd_in = r.predict(X[:50], return_std=True)
    assert np.all(sd_in < prior_sd[None, :])


def test_basis_is_zero_outside_the_data_range_and_its_band_is_the_prior_there():
    X, r = _fit("basis")
    Xs = (X - r.x_mean_) / r.x_scale_
    hi = Xs[:, 0].max()
    span = Xs[:, 0].max() - Xs[:, 0].min()
    out = Xs[:5].copy()
    out[:, 0] = hi + 1.01 * ENVELOPE_FRAC * span      # past the envelope's fall in x
    pts = out * r.x_scale_ + r.x_mean_
    m, sd = r.predict(pts, return_std=True)
    assert np.all(m == 0.0)
    _, J = r.predict_and_jacobian(pts)
    assert np.all(J == 0.0)
    edge = out.copy()
    edge[:, 0] = hi
    model = r.model_
    Pc, _ = model._design(edge, clip=True)
    prior = np.sqrt(np.stack([(Pc * Pc) @ model._prior_var(model.theta_[k]) for k in range(3)], 1))
    np.testing.assert_allclose(sd, prior * r.y_scale_ * r.band_scale_, rtol=BAND_TOL_REL)
    _, sd_in = r.predict(X[:50], return_std=True)
    assert np.all(sd_in > 0)


def test_basis_refuses_a_group_of_three_and_a_bad_state():
    X, Y = _data(2, n=60)
    with pytest.raises(ValueError, match="one \\(linear\\) or two"):
        BasisRegression(groups=((0, 1, 2), (3,))).fit(X, Y)
    with pytest.raises(ValueError, match="basis regression"):
        BasisRegression.from_state({"groups": [[0]]})
