"""The element GP of benchmarks/bench_hybrid_oracle.py (a diagnostic, not the product): its marginal
likelihood's analytic gradient and its posterior mean, checked against plain formulas."""
import importlib.util
from pathlib import Path

import numpy as np

SPEC = importlib.util.spec_from_file_location(
    "bench_hybrid_oracle", Path(__file__).resolve().parents[1] / "benchmarks" / "bench_hybrid_oracle.py")
oracle = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(oracle)

GRAD_RTOL = 1e-5
"""Central differences with step 1e-6 in log-parameters on a 36-observation problem agree with the closed-form
gradient to ~1e-8 relative; 1e-5 leaves room for round-off in the Cholesky and still fails any wrong term
(a missing factor 2 or a dropped kernel part is an O(1) error)."""

MEAN_ATOL = 1e-9
"""The posterior mean against the dense formula K*ᵀ K⁻¹ y on the same 36 observations (round-off only)."""


def _problem(seed=0, n=12, d=2, E=3):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d))
    J = rng.normal(size=(n, 3, E))
    y = rng.normal(size=(n, 3))
    theta = np.r_[rng.normal(0, 0.3, d), rng.normal(-1, 0.3, E), np.log(0.3)]
    return X, J, y, theta


def test_element_gp_gradient_matches_central_differences():
    X, J, y, theta = _problem()
    f, g = oracle._element_gp_nll(theta, X, J, y)
    h = 1e-6
    num = np.array([(oracle._element_gp_nll(theta + h * e, X, J, y)[0]
                     - oracle._element_gp_nll(theta - h * e, X, J, y)[0]) / (2 * h) for e in np.eye(len(theta))])
    assert np.isfinite(f)
    np.testing.assert_allclose(g, num, rtol=GRAD_RTOL, atol=GRAD_RTOL * np.abs(num).max())


def test_element_gp_mean_is_the_dense_posterior_mean():
    X, J, y, theta = _problem(seed=1)
    Xs, Js = X[:5] + 0.1, J[:5] * 1.1
    d, E = X.shape[1], J.shape[2]
    ell, s2, sn2 = np.exp(theta[:d]), np.exp(theta[d:d + E]), np.exp(theta[-1])

    def cov(Xa, Ja, Xb, Jb):   # (na·3, nb·3): Σ_k s_k² J_k(a) J_k(b)ᵀ k(a, b), written point by point
        out = np.zeros((3 * len(Xa), 3 * len(Xb)))
        for i in range(len(Xa)):
            for j in range(len(Xb)):
                kab = np.exp(-0.5 * np.sum(((Xa[i] - Xb[j]) / ell) ** 2))
                out[3 * i:3 * i + 3, 3 * j:3 * j + 3] = kab * (Ja[i] * s2) @ Jb[j].T
        return out

    K = cov(X, J, X, J) + sn2 * np.eye(3 * len(X))
    want = (cov(Xs, Js, X, J) @ np.linalg.solve(K, y.reshape(-1))).reshape(-1, 3)
    got = oracle.element_gp_predict(theta, X, J, y, Xs, Js)
    np.testing.assert_allclose(got, want, atol=MEAN_ATOL)

