"""A Bayesian regression on a tensor-product basis: a learned-residual family of few effective parameters.

:class:`BasisRegression` is the ``"basis"`` family of :class:`training.residual.ResidualRegressor` (the GP's
interface: ``fit(Xs, Ys)``, ``predict(Xs, return_std, jacobian)``, ``noise_var()``): per input group
Legendre polynomials of one input or the Fourier harmonics of a two-input group's angle, products of total
degree at most :data:`DEGREE`, independent Gaussian coefficients of variance ``σ² · q^degree`` (``σ²``,
``q`` and the noise by maximum marginal likelihood), a C¹ envelope outside the training range of a linear
input (:data:`ENVELOPE_FRAC`); closed-form Jacobian, numpy/scipy only. docs/reference/learned-stage.md."""
from __future__ import annotations

from itertools import product

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import minimize

__all__ = ["BasisRegression", "DEGREE", "ENVELOPE_FRAC"]

DEGREE = 6
"""Largest total degree of a basis column (Legendre degree of each linear input plus the harmonic
order of each rotary one): 140 columns on (X, Z, A). Fixed in advance for every input set, not
chosen from any effect: a polynomial of degree 6 bends three times over a stroke, a harmonic of
order up to 6 resolves features of a sixth of a turn; the decaying prior (``q``, fitted) lets the
data decide how much of the higher orders is used."""

ENVELOPE_FRAC = 0.1
"""Outside the training range of a linear input the basis falls to zero over 10 % of that range
(a cubic smoothstep: value and slope continuous), as the hybrid's taper (compensation.hybrid.TAPER_FRAC)."""

LOG_Q_BOUNDS = (np.log(0.01), 0.0)
"""The prior's decay per degree, ``q`` in [0.01, 1]: from 'each degree a hundred times smaller in
variance' to 'every degree alike' (plain ridge)."""

LOG_VAR_BOUNDS = (np.log(1e-6), np.log(10.0))
"""Signal and noise variances relative to the output's mean square (as the GP's)."""


def _legendre(u, p):
    """P_0..P_p at u (n,) and their derivatives → (n, p+1), (n, p+1) (Bonnet's recurrence)."""
    n = len(u)
    P = np.zeros((n, p + 1))
    dP = np.zeros((n, p + 1))
    P[:, 0] = 1.0
    if p >= 1:
        P[:, 1] = u
        dP[:, 1] = 1.0
    for k in range(1, p):
        P[:, k + 1] = ((2 * k + 1) * u * P[:, k] - k * P[:, k - 1]) / (k + 1)
        dP[:, k + 1] = dP[:, k - 1] + (2 * k + 1) * P[:, k]
    return P, dP


def _envelope(u):
    """Envelope (n,) and its derivative in u: 1 on [−1, 1], cubic fall to 0 over 2·ENVELOPE_FRAC outside."""
    margin = 2.0 * ENVELOPE_FRAC
    d = np.maximum(np.abs(u) - 1.0, 0.0)
    t = np.clip(d / margin, 0.0, 1.0)
    w = 1.0 - (3 * t**2 - 2 * t**3)
    dw = -(6 * t - 6 * t**2) / margin * np.sign(u) * (d > 0)
    return w, dw


class BasisRegression:
    """Empirical-Bayes regression on a tensor-product Legendre × Fourier basis (module doc).

    ``groups``: the input groups (a partition of the columns; a group of 2 is a rotary axis as
    (cos, sin), of 1 a linear input; None: every column linear); ``degree`` the total degree."""

    def __init__(self, groups=None, degree: int = DEGREE):
        self.groups = groups
        self.degree = int(degree)

    # -- the basis
    def _setup(self, Xs):
        d = Xs.shape[1]
        groups = [tuple(g) for g in (self.groups if self.groups is not None else [(j,) for j in range(d)])]
        if any(len(g) > 2 for g in groups):
            raise ValueError(f"Expected input groups of one (linear) or two (cos, sin) columns, got {groups}")
        self.groups_ = groups
        lin = [g[0] for g in groups if len(g) == 1]
        self.lo_ = {j: float(Xs[:, j].min()) for j in lin}
        self.hi_ = {j: float(Xs[:, j].max()) for j in lin}
        self.multi_ = np.array([m for m in product(range(self.degree + 1), repeat=len(groups))
                                if sum(m) <= self.degree], dtype=int)      # (T, G) degree per group
        cols = []
        for t, m in enumerate(self.multi_):
            for sc in product(*[(0, 1) if len(g) == 2 and k > 0 else (0,) for g, k in zip(groups, m)]):
                cols.append((t, sc))
        self.cols_ = cols
        self.col_degree_ = np.array([self.multi_[t].sum() for t, _ in cols], dtype=float)

    def _design(self, Xs, jacobian=False, clip=False):
        """Φ (m, p) [, dΦ/dXs (m, p, d)] and the envelope (m,) at Xs (m, d) standardised; ``clip``: the
        basis at the point clipped to the training box, without the envelope (the band's 'inside' part)."""
        m, d = Xs.shape
        per = []          # per group: (values (m, K), derivs (m, K, d)) indexed [degree][sin/cos]
        env = np.ones(m)
        denv = np.zeros((m, d))
        for g in self.groups_:
            D = self.degree
            if len(g) == 1:
                j = g[0]
                half = max(self.hi_[j] - self.lo_[j], 1e-12) / 2.0
                u = (Xs[:, j] - (self.hi_[j] + self.lo_[j]) / 2.0) / half
                w, dw = _envelope(u)
                if clip:
                    u = np.clip(u, -1.0, 1.0)
                P, dP = _legendre(u, D)
                vals = {(k, 0): P[:, k] for k in range(D + 1)}
                ders = {}
                for k in range(D + 1):
                    g_ = np.zeros((m, d))
                    g_[:, j] = dP[:, k] / half
                    ders[(k, 0)] = g_
                denv = denv * w[:, None]
                denv[:, j] += env * dw / half
                env = env * w
            else:
                c, s = Xs[:, g[0]], Xs[:, g[1]]
                r2 = np.maximum(c * c + s * s, 1e-300)
                th = np.arctan2(s, c)
                dth = np.zeros((m, d))
                dth[:, g[0]] = -s / r2
                dth[:, g[1]] = c / r2
                vals, ders = {(0, 0): np.ones(m)}, {(0, 0): np.zeros((m, d))}
                for k in range(1, D + 1):
                    vals[(k, 0)], vals[(k, 1)] = np.cos(k * th), np.sin(k * th)
                    ders[(k, 0)] = (-k * np.sin(k * th))[:, None] * dth
                    ders[(k, 1)] = (k * np.cos(k * th))[:, None] * dth
            per.append((vals, ders))
        p = len(self.cols_)
        Phi = np.empty((m, p))
        dPhi = np.empty((m, p, d)) if jacobian else None
        for i, (t, sc) in enumerate(self.cols_):
            mdeg = self.multi_[t]
            keys = [(int(k), int(b)) for k, b in zip(mdeg, sc)]
            v = np.ones(m)
            for (vals, _), key in zip(per, keys):
                v = v * vals[key]
            Phi[:, i] = v
            if jacobian:
                dv = np.zeros((m, d))
                for gi, ((vals, ders), key) in enumerate(zip(per, keys)):
                    other = np.ones(m)
                    for gj, ((vals2, _), key2) in enumerate(zip(per, keys)):
                        if gj != gi:
                            other = other * vals2[key2]
                    dv += ders[key] * other[:, None]
                dPhi[:, i, :] = dv
        if clip:
            return Phi, env
        if jacobian:
            dPhi = dPhi * env[:, None, None] + Phi[:, :, None] * denv[:, None, :]
        Phi = Phi * env[:, None]
        return (Phi, dPhi, env) if jacobian else (Phi, env)

    # -- empirical Bayes
    def _prior_var(self, theta):
        return np.exp(theta[0] + theta[1] * self.col_degree_)

    def _nlml(self, theta, G, b, yy, n):
        """Negative log marginal likelihood of one output, θ = (log σ², log q, log sn²); G = ΦᵀΦ, b = Φᵀy."""
        v = self._prior_var(theta)
        sn2 = np.exp(theta[2])
        A = G / sn2 + np.diag(1.0 / v)
        try:
            c = cho_factor(A, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            return 1e25
        mu = cho_solve(c, b, check_finite=False) / sn2
        quad = (yy - b @ mu) / sn2
        logdet = n * np.log(sn2) + 2 * np.log(np.diag(c[0])).sum() + np.log(v).sum()
        return 0.5 * (quad + logdet + n * np.log(2 * np.pi))

    def _nlml_dual(self, theta, S, y):
        """:meth:`_nlml` in the data space, for more columns than points: the same marginal likelihood with the
        (n, n) covariance ``K = σ² Σ_d q^d S_d + sn² I``; ``S`` (D+1, n, n) the per-degree Gram blocks
        ``S_d = Φ_d Φ_dᵀ`` (``Φ_d`` the columns of total degree d)."""
        n = len(y)
        K = np.tensordot(np.exp(theta[0] + theta[1] * np.arange(len(S))), S, axes=1)
        K[np.diag_indices(n)] += np.exp(theta[2])
        try:
            c = cho_factor(K, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            return 1e25
        alpha = cho_solve(c, y, check_finite=False)
        return 0.5 * (y @ alpha + 2 * np.log(np.diag(c[0])).sum() + n * np.log(2 * np.pi))

    def fit(self, Xs, Ys):
        """Xs (n, d) standardised, Ys (n, k) scaled → self (hyper-parameters per output by maximum marginal
        likelihood, then the posterior). The marginal likelihood is evaluated in the coefficient space (p × p)
        when there are fewer columns p than points n, in the data space (n × n, :meth:`_nlml_dual`) otherwise:
        the same function, the smaller factorisation (a five-axis machine's basis has 1,092 columns for a few
        hundred checks)."""
        Xs, Ys = np.asarray(Xs, dtype=float), np.asarray(Ys, dtype=float)
        self._setup(Xs)
        Phi, _ = self._design(Xs)
        dual = Phi.shape[1] > Phi.shape[0]
        if dual:
            blocks = (Phi[:, self.col_degree_ == d] for d in range(self.degree + 1))
            S = np.stack([B @ B.T for B in blocks])
        else:
            G = Phi.T @ Phi
        thetas = []
        bounds = [LOG_VAR_BOUNDS, LOG_Q_BOUNDS, LOG_VAR_BOUNDS]
        for k in range(Ys.shape[1]):
            y = Ys[:, k]
            var = max(float(np.mean(y * y)), 1e-12)
            if dual:
                fun, args = self._nlml_dual, (S, y)
            else:
                fun, args = self._nlml, (G, Phi.T @ y, float(y @ y), len(y))
            best = None
            for t0 in ([np.log(0.5 * var), np.log(0.3), np.log(0.5 * var)],
                       [np.log(0.1 * var), np.log(0.7), np.log(0.8 * var)]):
                r = minimize(fun, np.clip(t0, [b_[0] for b_ in bounds], [b_[1] for b_ in bounds]),
                             args=args, method="L-BFGS-B", bounds=bounds, options={"maxiter": 200})
                if best is None or r.fun < best.fun:
                    best = r
            thetas.append(best.x)
        return self.set_state(Xs, Ys, np.array(thetas))

    def set_state(self, Xs, Ys, theta, lo=None, hi=None):
        """Fix the hyper-parameters ``theta`` (k, 3) (and the training box ``lo``/``hi`` per linear input, as
        saved; None: from Xs) and solve for the posterior on (Xs, Ys)."""
        Xs, Ys = np.asarray(Xs, dtype=float), np.asarray(Ys, dtype=float)
        self._setup(Xs)
        if lo is not None:
            self.lo_ = {int(j): float(v) for j, v in lo.items()}
            self.hi_ = {int(j): float(v) for j, v in hi.items()}
        self.X_, self.Y_ = Xs, Ys
        self.theta_ = np.asarray(theta, dtype=float)
        if self.theta_.shape != (Ys.shape[1], 3):
            raise ValueError(f"Expected theta of shape ({Ys.shape[1]}, 3), got {self.theta_.shape}")
        Phi, _ = self._design(Xs)
        G = Phi.T @ Phi
        p = Phi.shape[1]
        self.coef_ = np.empty((Ys.shape[1], p))
        self.cov_ = np.empty((Ys.shape[1], p, p))
        for k in range(Ys.shape[1]):
            v = self._prior_var(self.theta_[k])
            sn2 = np.exp(self.theta_[k, 2])
            A = G / sn2 + np.diag(1.0 / v)
            c = cho_factor(A, lower=True, check_finite=False)
            self.coef_[k] = cho_solve(c, Phi.T @ Ys[:, k], check_finite=False) / sn2
            self.cov_[k] = cho_solve(c, np.eye(p), check_finite=False)
        return self

    def noise_var(self):
        """(k,) fitted noise variances (scaled units)."""
        return np.exp(self.theta_[:, 2])

    def predict(self, Xs, return_std=False, jacobian=False):
        """Mean (m, k) [, latent std (m, k)] [, dmean/dXs (m, k, d)] in scaled units. Outside the training
        range the mean falls to zero with the envelope and the std rises to the prior's at the box's edge."""
        Xs = np.asarray(Xs, dtype=float)
        if jacobian:
            Phi, dPhi, env = self._design(Xs, jacobian=True)
        else:
            Phi, env = self._design(Xs)
        mean = Phi @ self.coef_.T
        out = (mean,)
        if return_std:
            Pc, _ = self._design(Xs, clip=True)
            std = np.empty_like(mean)
            for k in range(mean.shape[1]):
                post = np.einsum("mp,pq,mq->m", Pc, self.cov_[k], Pc)
                prior = (Pc * Pc) @ self._prior_var(self.theta_[k])
                std[:, k] = np.sqrt(np.maximum(env**2 * post + (1.0 - env**2) * prior, 0.0))
            out += (std,)
        if jacobian:
            out += (np.einsum("mpd,kp->mkd", dPhi, self.coef_),)
        return out if len(out) > 1 else mean

    # -- persistence
    def state(self) -> dict:
        """JSON-able state (training data, box, hyper-parameters; the posterior is re-solved on load)."""
        return {"groups": [list(g) for g in self.groups_], "degree": self.degree, "X": self.X_.tolist(),
                "Y": self.Y_.tolist(), "theta": self.theta_.tolist(),
                "lo": {str(j): v for j, v in self.lo_.items()}, "hi": {str(j): v for j, v in self.hi_.items()}}

    @classmethod
    def from_state(cls, doc: dict) -> "BasisRegression":
        try:
            self = cls(groups=[tuple(int(j) for j in g) for g in doc["groups"]], degree=int(doc["degree"]))
            return self.set_state(np.asarray(doc["X"], dtype=float), np.asarray(doc["Y"], dtype=float),
                                  np.asarray(doc["theta"], dtype=float), doc["lo"], doc["hi"])
        except (KeyError, TypeError) as exc:
            raise ValueError(f"Expected a complete basis regression, missing or bad {exc}") from None
