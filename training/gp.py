"""The Gaussian-process families of :class:`training.residual.ResidualRegressor`: kernels (squared exponential,
Matérn 5/2 and 3/2, a long + short sum, an additive kernel over input groups), their hyper-parameters by maximum
marginal likelihood, and :class:`_GP` (one GP per output column; posterior mean, latent std, closed-form
Jacobian)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.linalg.lapack import dpotri
from scipy.optimize import minimize

GP_KERNELS = {"gp": "rbf", "gp_matern52": "matern52", "gp_matern32": "matern32", "gp_sum": "rbf_sum",
              "gp_additive": "additive"}
"""The Gaussian-process families and their kernel (:func:`_kernel`): the squared exponential, Matérn 5/2 and
Matérn 3/2 (the roughest that keeps the closed-form Jacobian), ``rbf_sum`` (a LONG- plus a
SHORT-length-scale ARD squared exponential, :data:`SUM_LOG_LENGTH_BOUNDS`) and ``additive`` (a sum of
squared exponentials on each input group and each pair of groups, :func:`additive_terms`). Which one serves
is decided by the blocked cross-validation; the families: docs/reference/learned-stage.md."""

LOG_LENGTH_BOUNDS = (np.log(0.05), np.log(5.0))
"""Length scales in standardised input units: below 0.05 σ a GP interpolates noise point by point; 5 σ is
nearly flat over the data (±1.7 σ) and keeps the learned part decaying to zero within a few data widths
outside it."""

SUM_LOG_LENGTH_BOUNDS = ((np.log(0.7), np.log(5.0)), (np.log(0.05), np.log(0.7)))
"""The ``rbf_sum`` kernel's two parts, in standardised input units: the LONG part's length scales from 0.7 σ
to 5 σ, the SHORT part's from 0.05 σ to 0.7 σ, so the two parts cannot swap roles."""

LOG_VAR_BOUNDS = (np.log(1e-6), np.log(10.0))
"""Signal and noise variances relative to the output's mean square (outputs are scaled by their
RMS): 1e-6 is 'nothing', 10 is ten times all there is."""

ADDITIVE_MAX_ORDER = 2
"""The additive kernel's terms go up to pairs of input groups (an error of one axis, a coupling of two),
fixed in advance for every input set; a field of three groups at once is left to the full ARD kernels."""

PREDICT_CHUNK = 2048
"""Rows of X predicted at once (the cross-kernel is chunk × n_train × d floats)."""

def _sqdist_by_dim(A, B, inv_l2):
    """Σ_j (A_ij − B_kj)² / l_j²: A (n, d), B (m, d), inv_l2 (d,) → (n, m)."""
    As = A * np.sqrt(inv_l2)
    Bs = B * np.sqrt(inv_l2)
    d2 = (As * As).sum(1)[:, None] + (Bs * Bs).sum(1)[None, :] - 2.0 * As @ Bs.T
    return np.maximum(d2, 0.0)


_SQRT3, _SQRT5 = np.sqrt(3.0), np.sqrt(5.0)


def _kernel(S, sf2, kind="rbf"):
    """Kernel and its radial derivative factor from the scaled squared distance S = Σ_j Δ_j²/l_j².

    S (n, m) → (K (n, m), H (n, m)) with dK/dlog l_j = H ⊙ Δ_j²/l_j² and dK/dx_j = −H ⊙ Δ_j/l_j²
    (one form for every kernel: the marginal-likelihood gradient and the Jacobian use H)."""
    if kind == "rbf":
        K = np.multiply(S, -0.5)
        np.exp(K, out=K)
        K *= sf2
        return K, K
    r = np.sqrt(S)
    if kind == "matern52":
        e = sf2 * np.exp(-_SQRT5 * r)
        return e * (1.0 + _SQRT5 * r + (5.0 / 3.0) * S), (5.0 / 3.0) * e * (1.0 + _SQRT5 * r)
    if kind == "matern32":
        e = sf2 * np.exp(-_SQRT3 * r)
        return e * (1.0 + _SQRT3 * r), 3.0 * e
    raise ValueError(f"Expected a kernel in {sorted(set(GP_KERNELS.values()))}, got {kind!r}")


def check_input_groups(groups, d):
    """``groups`` (None, or a sequence of sequences of column indices) → a tuple of tuples that
    partitions ``range(d)`` (None: each column its own group); ValueError otherwise."""
    if groups is None:
        return tuple((j,) for j in range(d))
    try:
        out = tuple(tuple(int(j) for j in g) for g in groups)
    except (TypeError, ValueError):
        raise ValueError(f"Expected input groups as sequences of column indices, got {groups!r}") from None
    flat = sorted(j for g in out for j in g)
    if any(len(g) == 0 for g in out) or flat != list(range(d)):
        raise ValueError(f"Expected input groups that partition the {d} input columns, got {groups!r}")
    return out


def additive_terms(d, groups=None):
    """The terms of the ``additive`` kernel on d inputs: every input group alone, then every pair of
    groups (:data:`ADDITIVE_MAX_ORDER`), each as a sorted tuple of column indices. ``groups``: see
    :func:`check_input_groups` (e.g. ``((0,), (1,), (2, 3))`` keeps cos a and sin a together: one
    rotary axis)."""
    from itertools import combinations
    groups = check_input_groups(groups, d)
    terms = []
    for order in range(1, min(ADDITIVE_MAX_ORDER, len(groups)) + 1):
        for combo in combinations(groups, order):
            terms.append(tuple(sorted(j for g in combo for j in g)))
    return tuple(terms)


def _n_theta(d, kind, terms=None):
    """Hyper-parameters of a kernel on d inputs: (log l (d), log sf², log sn²), or for
    ``rbf_sum`` (log l_long (d), log l_short (d), log sf²_long, log sf²_short, log sn²), or for
    ``additive`` (log l (d), log sf² per term of ``terms``, log sn²)."""
    if kind == "additive":
        return d + len(terms) + 1
    return 2 * d + 3 if kind == "rbf_sum" else d + 2


def _parts(theta, d, kind, terms=None):
    """θ → ([(inv_l2 (d,), sf², base kind, index slice of its log l, index of its log sf²), …], sn²):
    one part per kernel summand (two for ``rbf_sum``; one per term for ``additive``, whose
    ``inv_l2`` is zero on the inputs outside the term and whose length scales are shared)."""
    if kind == "additive":
        inv_l2 = np.exp(-2.0 * theta[:d])
        parts = []
        for t, dims in enumerate(terms):
            mask = np.zeros(d)
            mask[list(dims)] = 1.0
            parts.append((inv_l2 * mask, float(np.exp(theta[d + t])), "rbf", slice(0, d), d + t))
        return parts, float(np.exp(theta[-1]))
    if kind == "rbf_sum":
        return ([(np.exp(-2.0 * theta[:d]), float(np.exp(theta[2 * d])), "rbf", slice(0, d), 2 * d),
                 (np.exp(-2.0 * theta[d:2 * d]), float(np.exp(theta[2 * d + 1])), "rbf", slice(d, 2 * d), 2 * d + 1)],
                float(np.exp(theta[2 * d + 2])))
    return [(np.exp(-2.0 * theta[:d]), float(np.exp(theta[d])), kind, slice(0, d), d)], float(np.exp(theta[d + 1]))


def _theta_bounds(d, kind, terms=None):
    if kind == "additive":
        return [LOG_LENGTH_BOUNDS] * d + [LOG_VAR_BOUNDS] * (len(terms) + 1)
    if kind == "rbf_sum":
        return [SUM_LOG_LENGTH_BOUNDS[0]] * d + [SUM_LOG_LENGTH_BOUNDS[1]] * d + [LOG_VAR_BOUNDS] * 3
    return [LOG_LENGTH_BOUNDS] * d + [LOG_VAR_BOUNDS] * 2


def _theta_starts(d, kind, var, n_restarts, rng, terms=None):
    """Marginal-likelihood starting points: the first deterministic, the others drawn from ``rng``."""
    if kind == "additive":   # half the variance shared evenly by the terms, half noise (as the single kernel)
        T = len(terms)
        starts = [np.r_[np.zeros(d), np.full(T, np.log(0.5 * var / T)), np.log(0.5 * var)]]
        for _ in range(n_restarts - 1):
            starts.append(np.r_[rng.uniform(-1.0, 1.0, d), np.log(var / T) + rng.uniform(-2, 0, T),
                                np.log(var) + rng.uniform(-2, 0)])
        return starts
    if kind == "rbf_sum":
        starts = [np.r_[np.full(d, np.log(2.0)), np.full(d, np.log(0.3)), np.log(0.4 * var), np.log(0.1 * var),
                        np.log(0.5 * var)]]
        for _ in range(n_restarts - 1):
            starts.append(np.r_[rng.uniform(np.log(0.7), np.log(5.0), d), rng.uniform(np.log(0.05), np.log(0.7), d),
                                np.log(var) + rng.uniform(-2, 0, 3)])
        return starts
    starts = [np.r_[np.zeros(d), np.log(0.5 * var), np.log(0.5 * var)]]
    for _ in range(n_restarts - 1):
        starts.append(np.r_[rng.uniform(-1.0, 1.0, d), np.log(var) + rng.uniform(-2, 0, 2)])
    return starts


class _Pairs:
    """The training points of one fit and their pairs (i, j), i > j: the strict lower triangle of an (n, n) kernel
    matrix, column by column. The marginal likelihood works on them alone (every matrix in it is symmetric and every
    kernel is ``sf²`` on the diagonal, where the differences are zero): half the work of the full matrices.

    ``X`` (n, d) the points; ``i``, ``j`` (m,) the rows and columns of the m = n(n−1)/2 pairs and ``flat_f`` their
    index in a Fortran-ordered (n, n) array (LAPACK's); ``sq`` (d, m) the squared difference of each input over the
    pairs (computed when first asked: only the Matérn kernels read it)."""

    def __init__(self, Xs):
        self.X = np.ascontiguousarray(Xs, dtype=float)
        self.n = n = len(Xs)
        self.j, self.i = np.triu_indices(n, 1)   # column by column: (i, j) = (j + 1, j), (j + 2, j), …
        self.flat_f = self.j * n + self.i
        self._sq = None
        self._t = {}

    def columns_t(self, cols):
        """X's columns ``cols`` (a tuple; repeats allowed), transposed: (len(cols), n) C-ordered."""
        if cols not in self._t:
            self._t[cols] = np.ascontiguousarray(self.X[:, list(cols)].T)
        return self._t[cols]

    @property
    def sq(self):
        if self._sq is None:
            self._sq = np.ascontiguousarray(np.square(self.X[self.i] - self.X[self.j]).T)   # one input per row
        return self._sq


@lru_cache(maxsize=32)
def _se_layout(d, kind, terms):
    """A squared-exponential kernel (``rbf``, ``rbf_sum``, ``additive``) as a sum of terms, each ``sf²_t`` times a
    product of atoms' ``exp(−½ Σ_c Δ_c²/l_c²)`` over virtual input columns c → (columns: the input of each virtual
    column, atom of each virtual column (dv,), term_atoms (T, A) uint8). θ is then (log l (dv), log sf² (T), log sn²)
    for all three: ``rbf`` one atom of every input, one term; ``rbf_sum`` every input twice (the long and the short
    length scales), two atoms, two terms; ``additive`` :func:`_atoms` (shared length scales)."""
    if kind == "rbf":
        return tuple(range(d)), np.zeros(d, dtype=np.int64), np.ones((1, 1), dtype=np.uint8)
    if kind == "rbf_sum":
        return tuple(range(d)) * 2, np.repeat(np.arange(2), d), np.eye(2, dtype=np.uint8)
    atoms, made_of = _atoms(d, terms)
    atom_of = np.empty(d, dtype=np.int64)
    for a, cols in enumerate(atoms):
        atom_of[list(cols)] = a
    term_atoms = np.zeros((len(made_of), len(atoms)), dtype=np.uint8)
    for t, parts in enumerate(made_of):
        term_atoms[t, list(parts)] = 1
    return tuple(range(d)), atom_of, term_atoms


def _factored(K, y):
    """A zero-mean GP with covariance K (n, n), Fortran-ordered, its lower triangle read (and overwritten), at y (n,)
    → (nll, α = K⁻¹y, K⁻¹ (its lower triangle)); None where K is not positive definite."""
    try:
        c = cho_factor(K, lower=True, overwrite_a=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None
    alpha = cho_solve(c, y, check_finite=False)
    nll = 0.5 * y @ alpha + np.log(np.diag(c[0])).sum() + 0.5 * len(y) * np.log(2 * np.pi)
    Kinv, info = dpotri(c[0], lower=1, overwrite_c=1)   # K⁻¹ from its Cholesky factor (lower triangle filled)
    return None if info != 0 else (nll, alpha, Kinv)


def _gp_nll(theta, X, y, pairs, kind="rbf", terms=None):
    """Negative log marginal likelihood and its gradient in θ (:func:`_n_theta` layout).

    X (n, d) standardised, y (n,), ``pairs`` the :class:`_Pairs` of X; ``kind`` the kernel (``terms`` its terms
    for ``additive``). The gradient is −½ tr(W ∂K/∂θ), W = ααᵀ − K⁻¹: off the diagonal each pair stands for two
    equal entries (the factor 2 cancels the ½); on it every kernel is its ``sf²`` and every length scale's
    derivative zero (Δ = 0), which leaves −½ sf² tr W and −½ sn² tr W."""
    if kind in ("matern52", "matern32"):
        return _matern_nll(theta, X, y, pairs, kind)
    from ._gp_kernels import _se_lower, _se_pair_sums   # numba: imported when a fit runs, not with the module
    cols, atom_of, term_atoms = _se_layout(X.shape[1], kind, terms)
    XT = pairs.columns_t(cols)
    dv, (T, A), n = len(cols), term_atoms.shape, len(y)
    inv_l2, sf2, sn2 = np.exp(-2.0 * theta[:dv]), np.exp(theta[dv:dv + T]), np.exp(theta[-1])
    K, E = np.zeros((n, n), order="F"), np.empty((A, n * (n - 1) // 2))
    _se_lower(XT, inv_l2, atom_of, term_atoms, sf2, sf2.sum() + sn2, K, E)
    got = _factored(K, y)
    if got is None:
        return 1e25, np.zeros_like(theta)
    nll, alpha, Kinv = got
    g = np.empty(dv + T)
    _se_pair_sums(XT, atom_of, term_atoms, sf2, E, alpha, Kinv, g)
    w_trace = alpha @ alpha - Kinv.trace()
    return nll, np.r_[-inv_l2 * g[:dv], -g[dv:] - 0.5 * sf2 * w_trace, -0.5 * sn2 * w_trace]


def _matern_nll(theta, X, y, pairs, kind):
    """:func:`_gp_nll` of a Matérn kernel, on the pairs' squared differences (:attr:`_Pairs.sq`)."""
    d, n = X.shape[1], len(y)
    [(inv_l2, sf2, _, _, _)], sn2 = _parts(theta, d, kind)
    Kf, H = _kernel(inv_l2 @ pairs.sq, sf2, kind)
    K = np.zeros((n, n), order="F")
    np.put(K.T, pairs.flat_f, Kf)   # K.T is K's memory read C-ordered: (i, j) at j·n + i
    K[np.diag_indices(n)] = sf2 + sn2
    got = _factored(K, y)
    if got is None:
        return 1e25, np.zeros_like(theta)
    nll, alpha, Kinv = got
    w = alpha[pairs.i] * alpha[pairs.j]
    w -= np.take(Kinv.T.ravel(), pairs.flat_f)
    w_trace = alpha @ alpha - Kinv.trace()
    # dK/dlog l_j = H ⊙ Δ_j²/l_j², dK/dlog sf² = K (sf² on the diagonal)
    return nll, np.r_[-inv_l2 * (pairs.sq @ (w * H)), -(w @ Kf) - 0.5 * sf2 * w_trace, -0.5 * sn2 * w_trace]


@lru_cache(maxsize=32)
def _atoms(d, terms):
    """The finest partition of the d inputs of which every additive term is a union: inputs in the same
    terms are one atom (a rotary axis's cos and sin) → (atoms: tuple of column tuples, per term the atom
    indices it is made of)."""
    sig = {}
    for j in range(d):
        sig.setdefault(tuple(j in t for t in terms), []).append(j)
    atoms = tuple(tuple(v) for v in sig.values())
    return atoms, tuple(tuple(a for a, cols in enumerate(atoms) if cols[0] in t) for t in terms)


class _GP:
    """One zero-mean GP per output column on standardised inputs (see module doc); ``kernel``
    one of the values of :data:`GP_KERNELS`; ``groups`` the input groups of the ``additive`` kernel
    (:func:`additive_terms`; None: one group per input)."""

    def __init__(self, n_restarts: int, rng, kernel: str = "rbf", groups=None):
        self.n_restarts = int(n_restarts)
        self.rng = rng
        self.kernel = kernel
        self.groups = groups

    def _terms(self, d):
        """The additive kernel's terms on d inputs (None for the other kernels)."""
        return additive_terms(d, self.groups) if self.kernel == "additive" else None

    def fit(self, Xs, Ys):
        """Xs (n, d) standardised, Ys (n, 3) scaled → self (theta_ (3, p) with p = :func:`_n_theta`,
        alpha_ (3, n), L_ (3, n, n)): :meth:`hyperparameters`, then :meth:`set_state`."""
        return self.set_state(Xs, Ys, self.hyperparameters(Xs, Ys))

    def hyperparameters(self, Xs, Ys):
        """Xs (n, d) standardised, Ys (n, k) scaled → θ (k, p) of maximum marginal likelihood per output column
        (the best of ``n_restarts`` L-BFGS-B starts), the weights not solved."""
        n, d = Xs.shape
        pairs = _Pairs(Xs)
        terms = self._terms(d)
        bounds = _theta_bounds(d, self.kernel, terms)
        thetas = []
        for k in range(Ys.shape[1]):
            y = Ys[:, k]
            var = max(float(np.mean(y * y)), 1e-12)
            best = None
            for t0 in _theta_starts(d, self.kernel, var, self.n_restarts, self.rng, terms):
                t0 = np.clip(t0, [b[0] for b in bounds], [b[1] for b in bounds])
                r = minimize(_gp_nll, t0, args=(Xs, y, pairs, self.kernel, terms), jac=True, method="L-BFGS-B", bounds=bounds,
                             options={"maxiter": 100})
                if best is None or r.fun < best.fun:
                    best = r
            thetas.append(best.x)
        return np.array(thetas)

    def set_state(self, Xs, Ys, theta):
        """Fix the hyper-parameters ``theta`` (3, p) and solve for the weights on (Xs, Ys)."""
        n, d = Xs.shape
        self.X_ = np.asarray(Xs, dtype=float)
        self.Y_ = np.asarray(Ys, dtype=float)
        self.theta_ = np.asarray(theta, dtype=float)
        p = _n_theta(d, self.kernel, self._terms(d))
        if self.theta_.ndim != 2 or self.theta_.shape[1] != p:
            raise ValueError(f"Expected theta of shape (k, {p}) for kernel {self.kernel!r} "
                             f"on {d} inputs, got {self.theta_.shape}")
        self.alpha_ = np.empty((Ys.shape[1], n))
        self.L_ = np.empty((Ys.shape[1], n, n))
        for k in range(Ys.shape[1]):
            K = self._k(k, self.X_, self.X_)[0] + self._hyp(k)[1] * np.eye(n)
            L = np.linalg.cholesky(K)
            self.L_[k] = L
            self.alpha_[k] = cho_solve((L, True), Ys[:, k], check_finite=False)
        return self

    def _hyp(self, k):
        """Output k's kernel parts and noise variance (:func:`_parts`)."""
        d = self.X_.shape[1]
        return _parts(self.theta_[k], d, self.kernel, self._terms(d))

    def _k(self, k, A, B):
        """Output k's kernel between A (m, d) and B (n, d): (K (m, n), [(H (m, n), inv_l2 (d,)) per part], sf² total)."""
        parts, _ = self._hyp(k)
        K, HS = 0.0, []
        for inv_l2, sf2, base, _, _ in parts:
            Kp, Hp = _kernel(_sqdist_by_dim(A, B, inv_l2), sf2, base)
            K = K + Kp
            HS.append((Hp, inv_l2))
        return K, HS, sum(p[1] for p in parts)

    def noise_var(self):
        """(3,) fitted noise variances (scaled units)."""
        return np.array([self._hyp(k)[1] for k in range(self.theta_.shape[0])])

    def predict(self, Xs, return_std=False, jacobian=False):
        """Mean (m, 3) [, latent std (m, 3)] [, dmean/dXs (m, 3, d)] in scaled units."""
        m, d = Xs.shape
        K3 = self.theta_.shape[0]
        mean = np.empty((m, K3))
        std = np.empty((m, K3)) if return_std else None
        jac = np.empty((m, K3, d)) if jacobian else None
        for s in range(0, m, PREDICT_CHUNK):
            Xc = Xs[s:s + PREDICT_CHUNK]
            for k in range(K3):
                Ks, HS, sf2 = self._k(k, Xc, self.X_)                           # (c, n)
                mean[s:s + len(Xc), k] = Ks @ self.alpha_[k]
                if return_std:
                    v = solve_triangular(self.L_[k], Ks.T, lower=True, check_finite=False)
                    std[s:s + len(Xc), k] = np.sqrt(np.maximum(sf2 - (v * v).sum(0), 0.0))
                if jacobian:
                    J = 0.0
                    for Hs, inv_l2 in HS:
                        w = Hs * self.alpha_[k][None, :]                             # (c, n)
                        # d/dx_j k(x, x_i) = −H (x_j − x_ij)/l_j²
                        J = J - inv_l2[None, :] * (Xc * w.sum(1)[:, None] - w @ self.X_)
                    jac[s:s + len(Xc), k, :] = J
        out = (mean,)
        if return_std:
            out += (std,)
        if jacobian:
            out += (jac,)
        return out if len(out) > 1 else mean


# ---------------------------------------------------------------- the estimator
