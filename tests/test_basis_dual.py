"""The basis regression's marginal likelihood in the data space (more columns than points) is the
coefficient-space one (the fit evaluates whichever factorisation is smaller; on a five-axis machine's
1,092 columns against a few hundred checks, the data space)."""
import numpy as np
import pytest

from training.basis import BasisRegression

NLML_RTOL = 1e-10
"""The two forms are the same Gaussian marginal likelihood (Woodbury / the matrix determinant lemma); they
differ by the rounding of a 1,092-column Cholesky against a 150-point one: measured ≤ 2e-14 relative."""


def _five_axis_like(n, seed):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, 7))
    for c, s in ((3, 4), (5, 6)):
        a = rng.uniform(0, 2 * np.pi, n)
        X[:, c], X[:, s] = np.cos(a), np.sin(a)
    y = np.sin(X[:, 0]) * X[:, 3] + 0.3 * X[:, 1] ** 2 + 0.1 * rng.standard_normal(n)
    return X, y


GROUPS = [(0,), (1,), (2,), (3, 4), (5, 6)]


def test_dual_marginal_likelihood_equals_the_coefficient_space_one():
    X, y = _five_axis_like(150, 0)
    b = BasisRegression(GROUPS)
    b._setup(X)
    Phi, _ = b._design(X)
    assert Phi.shape[1] == 1092 > len(y)         # the case the data-space form is for
    G = Phi.T @ Phi
    S = np.stack([Phi[:, b.col_degree_ == d] @ Phi[:, b.col_degree_ == d].T for d in range(b.degree + 1)])
    for theta in ([0.0, np.log(0.3), np.log(0.01)], [-2.0, np.log(0.7), -3.0], [1.0, -4.0, -1.0]):
        theta = np.asarray(theta)
        assert b._nlml_dual(theta, S, y) == pytest.approx(b._nlml(theta, G, Phi.T @ y, y @ y, len(y)), rel=NLML_RTOL)

