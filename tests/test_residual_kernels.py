"""The Matérn kernels of training.residual: marginal-likelihood gradient, Jacobian, round trip, choice by CV."""
import json

import numpy as np
import pytest

from training.gp import GP_KERNELS, _gp_nll, _kernel, _n_theta, _Pairs, _parts, _sqdist_by_dim, additive_terms
from training.residual import ResidualRegressor

GRAD_TOL_REL = 1e-5
"""Analytic marginal-likelihood gradient vs central differences (h = 1e-6 in log units): the
difference is O(h²)·f''' plus rounding ε·|nll|/h ≈ 1e-10·|nll|; 1e-5 of the largest gradient entry
is far above both and far below any wrong term (a missing factor is O(1))."""

JAC_TOL_REL = 1e-6
"""Closed-form Jacobian vs central differences (h = 1e-5): O(h²)·f''' ≈ 1e-9 relative plus ε/h;
both Matérn kernels used here are at least once continuously differentiable, so the closed form
holds also at the training points."""

ROUND_TRIP_RTOL = 1e-9
"""Loading re-solves the weights by Cholesky: rounding only (see test_residual)."""


def _data(seed, n=60):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, (n, 2))
    Y = np.c_[np.sin(2 * X[:, 0]), X[:, 0] * X[:, 1], np.exp(-4 * X[:, 1] ** 2)] + 0.05 * rng.standard_normal((n, 3))
    return X, Y


@pytest.mark.parametrize("kind", sorted(set(GP_KERNELS.values())))
def test_nll_gradient_matches_finite_differences(kind):
    X, Y = _data(0, n=40)
    P = _Pairs(X)
    theta = np.array([np.log(0.7), np.log(1.3), np.log(0.8), np.log(0.01)])
    terms = None
    if kind == "rbf_sum":   # long (1.5, 2.0) and short (0.3, 0.2) length scales, their variances, the noise
        theta = np.log([1.5, 2.0, 0.3, 0.2, 0.6, 0.2, 0.01])
    if kind == "additive":  # shared length scales (0.7, 1.3), the variances of x0, x1, x0·x1, the noise
        terms = additive_terms(2)
        theta = np.log([0.7, 1.3, 0.5, 0.3, 0.2, 0.01])
    assert len(theta) == _n_theta(2, kind, terms)
    f0, g = _gp_nll(theta, X, Y[:, 0], P, kind, terms)
    h = 1e-6
    gfd = np.array([(_gp_nll(theta + h * e, X, Y[:, 0], P, kind, terms)[0]
                     - _gp_nll(theta - h * e, X, Y[:, 0], P, kind, terms)[0]) / (2 * h) for e in np.eye(len(theta))])
    assert np.abs(g - gfd).max() <= GRAD_TOL_REL * np.abs(g).max()
    # the value: the full (n, n) matrices, every entry computed (the pairs hold the lower triangle only)
    assert f0 == pytest.approx(_full_nll(theta, X, Y[:, 0], kind, terms), rel=ASSEMBLY_RTOL)


def _full_nll(theta, X, y, kind, terms):
    """The marginal likelihood from the whole (n, n) covariance (:func:`_sqdist_by_dim` on every pair, both ways)."""
    from scipy.linalg import cho_factor, cho_solve
    parts, sn2 = _parts(theta, X.shape[1], kind, terms)
    K = sum(_kernel(_sqdist_by_dim(X, X, inv_l2), sf2, base)[0] for inv_l2, sf2, base, _, _ in parts)
    K = K + sn2 * np.eye(len(y))
    c = cho_factor(K, lower=True)
    return 0.5 * y @ cho_solve(c, y) + np.log(np.diag(c[0])).sum() + 0.5 * len(y) * np.log(2 * np.pi)


@pytest.mark.parametrize("family", ["gp_matern52", "gp_matern32", "gp_sum"])
def test_matern_family_jacobian_and_round_trip(family):
    X, Y = _data(1)
    r = ResidualRegressor(families=(family,), seed=0, margin_se=0.0).fit(X, Y)
    assert r.chosen_ == family
    Xq = np.random.default_rng(2).uniform(-1, 1, (6, 2))
    Xq[0] = X[3]                                  # at a training point too
    v, J = r.predict_and_jacobian(Xq)
    h = 1e-5
    Jfd = np.stack([(r.predict(Xq + h * np.eye(2)[j]) - r.predict(Xq - h * np.eye(2)[j])) / (2 * h) for j in range(2)], -1)
    assert np.abs(J - Jfd).max() <= JAC_TOL_REL * np.abs(J).max()
    back = ResidualRegressor.from_dict(json.loads(json.dumps(r.to_dict())))
    np.testing.assert_allclose(back.predict(Xq), v, rtol=ROUND_TRIP_RTOL, atol=0)
    assert back.model_.kernel == GP_KERNELS[family]
    # re-estimated on other data (the refit on all checks): the same kernel, and it reloads to the same numbers
    X2, Y2 = _data(4)
    for again in (r.refit(X2, Y2, seed=1), r.with_data(X2, Y2)):
        assert again.model_.kernel == GP_KERNELS[family]
        back2 = ResidualRegressor.from_dict(json.loads(json.dumps(again.to_dict())))
        np.testing.assert_allclose(back2.predict(Xq), again.predict(Xq), rtol=ROUND_TRIP_RTOL, atol=0)
    doc = r.to_dict()
    doc["gp"]["kernel"] = "rbf"                   # a file whose kernel contradicts its family is refused
    with pytest.raises(ValueError, match="kernel"):
        ResidualRegressor.from_dict(doc)


def test_choice_among_kernels_is_the_lowest_cv_rms():
    X, Y = _data(3)
    fams = ("gp", "gp_matern52", "gp_matern32")
    r = ResidualRegressor(families=fams, seed=0).fit(X, Y)
    eligible = [f for f in fams if r.cv_table_[f]["gain_mean"] > r.cv_table_[f]["gain_se"]]
    assert r.chosen_ == min(eligible, key=lambda f: r.cv_table_[f]["cv_rms"])
    assert r.model_.kernel == GP_KERNELS[r.chosen_]


ASSEMBLY_RTOL = 1e-12
"""The additive kernel assembled per atom (products of the atoms' exponentials) against the per-term form
(one exponential of each term's summed distance): the same function, differing by rounding only (a few ulp of
each kernel entry, summed over a 40-point Cholesky): measured 3e-15 (value) and 7e-15 of the largest entry
(gradient); 1e-12 is far above rounding and far below any wrong term (a missing product is O(1))."""


def _per_term_nll(theta, y, D, terms):
    """The additive marginal likelihood and gradient term by term (each term's own exponential and its own
    length-scale gradient): the reference the per-atom assembly must equal."""
    from scipy.linalg import cho_factor, cho_solve
    d, n = D.shape[0], len(y)
    inv_l2 = np.exp(-2.0 * theta[:d])
    Ks = []
    for t, dims in enumerate(terms):
        m = np.zeros(d)
        m[list(dims)] = 1.0
        Ks.append(np.exp(theta[d + t]) * np.exp(-0.5 * np.tensordot(inv_l2 * m, D, axes=1)))
    K = sum(Ks) + np.exp(theta[-1]) * np.eye(n)
    c = cho_factor(K, lower=True)
    alpha = cho_solve(c, y)
    nll = 0.5 * y @ alpha + np.log(np.diag(c[0])).sum() + 0.5 * n * np.log(2 * np.pi)
    W = np.outer(alpha, alpha) - cho_solve(c, np.eye(n))
    g = np.zeros_like(theta)
    for t, dims in enumerate(terms):
        for j in dims:
            g[j] += -0.5 * inv_l2[j] * np.sum(D[j] * W * Ks[t])
        g[d + t] = -0.5 * np.sum(W * Ks[t])
    g[-1] = -0.5 * np.exp(theta[-1]) * np.trace(W)
    return nll, g


def test_additive_per_atom_assembly_equals_the_per_term_form():
    """Five inputs in three groups, one of them a rotary pair (cos, sin): the pair is one atom, every term a
    union of atoms."""
    rng = np.random.default_rng(4)
    X = rng.uniform(-1, 1, (40, 5))
    a = rng.uniform(0, 2 * np.pi, 40)
    X[:, 3], X[:, 4] = np.cos(a), np.sin(a)
    y = np.sin(2 * X[:, 0]) * X[:, 3] + 0.05 * rng.standard_normal(40)
    D = np.moveaxis((X[:, None, :] - X[None, :, :]) ** 2, 2, 0).copy()
    terms = additive_terms(5, ((0,), (1, 2), (3, 4)))
    assert terms == ((0,), (1, 2), (3, 4), (0, 1, 2), (0, 3, 4), (1, 2, 3, 4))
    theta = np.r_[np.log([0.7, 1.3, 0.9, 1.1, 0.6]), np.log([0.5, 0.3, 0.2, 0.1, 0.05, 0.02]), np.log(0.01)]
    f, g = _gp_nll(theta, X, y, _Pairs(X), "additive", terms)
    f_ref, g_ref = _per_term_nll(theta, y, D, terms)
    assert f == pytest.approx(f_ref, rel=ASSEMBLY_RTOL)
    assert np.abs(g - g_ref).max() <= ASSEMBLY_RTOL * np.abs(g_ref).max()


def test_progress_hook_is_called_once_per_family_in_order():
    X, Y = _data(3)
    seen = []
    ResidualRegressor(families=("gp", "gp_matern52"), seed=0, progress=seen.append).fit(X, Y)
    assert seen == ["gp", "gp_matern52"]
