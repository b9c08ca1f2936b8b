"""The learned residual stage of an arm calibration: a regressor on what the geometric model leaves.

Inputs the physics suggests, derived from the chain (nothing machine-specific): each joint as
sin/cos, and per revolute joint the gravity moment about its axis of unit masses at the downstream
joint origins and the tool point (``axis_k · ((o_j − o_k) × ẑ)``, summed) — what a joint-stiffness
sag or a gear's load-dependent deflection follows. Output: the 3-D position residual, mm.

Candidate families (chosen by k-fold CV inside the fit set, never by name):
``gp_sincos`` (Gaussian process, ARD RBF + white noise on sin/cos), ``gp_physics`` (the same on
sin/cos + gravity moments) and ``ridge_physics`` (ridge regression on the same features, α by CV).
Kernel hyper-parameters by maximum marginal likelihood on (up to :data:`HYPER_POSES` poses of) the fit
set (``n_restarts`` restarts), ridge α by generalised CV;
the CV folds reuse them (the held-out fold never tunes them). The CV also checks the 95 % band:
``coverage_`` is the share of held-out fold residual components within 1.96 σ (σ = predictive
standard deviation including the noise).
"""
from __future__ import annotations

import numpy as np

from errormap.arm_simulate import gravity_moment_mm
from errormap.threads import limit_threads

FAMILIES = ("gp_sincos", "gp_physics", "ridge_physics")
Z95 = 1.959963984540054
RIDGE_ALPHAS = np.logspace(-4, 2, 13)
MAX_FIT_POSES = 5000  # a dense GP is O(n³); beyond this the caller should subsample
HYPER_POSES = 200     # kernel hyper-parameters from at most this many fit poses (random subset by seed): the
# marginal likelihood's O(n³) per step; the model itself then uses every fit pose with that kernel


def gravity_moments(chain, q, errors=None) -> np.ndarray:
    """Per joint the gravity moment (mm per unit mass, gravity along −z of the base) of unit masses at
    the downstream joint origins and the tool point, shape (n, nq)."""
    return gravity_moment_mm(chain, q, errors)


def features(chain, q, family: str, errors=None) -> np.ndarray:
    """Input features of ``family`` for joint values ``q`` (n, nq), shape (n, d)."""
    q = np.asarray(q, float)
    rev = np.array([j.type == "revolute" for j in chain.joints])
    r = np.radians(q[:, rev])
    span = np.maximum(chain.joint_hi - chain.joint_lo, 1e-9)[~rev]
    base = np.concatenate([np.sin(r), np.cos(r), q[:, ~rev] / span], 1)  # prismatic joints: value / stroke
    if family == "gp_sincos":
        return base
    return np.concatenate([base, gravity_moments(chain, q, errors) / 1000.0], 1)  # moments in m


def _gp(d: int):
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    k = ConstantKernel(1.0, (1e-3, 1e3)) * RBF(np.ones(d), (1e-2, 1e3)) + WhiteKernel(0.1, (1e-5, 1e1))
    return k


class _Model:
    """One fitted family: predict mean and predictive std (mm), shape (n, 3) each."""

    def __init__(self, family, X, Y, seed, n_restarts, kernel=None, alpha=None):
        self.family = family
        self.mu = X.mean(0)
        self.sd = np.where(X.std(0) > 0, X.std(0), 1.0)
        Xs = (X - self.mu) / self.sd
        if family.startswith("gp"):
            from sklearn.gaussian_process import GaussianProcessRegressor
            self.model = GaussianProcessRegressor(kernel=kernel if kernel is not None else _gp(X.shape[1]),
                                                  normalize_y=True, n_restarts_optimizer=n_restarts,
                                                  optimizer=None if kernel is not None else "fmin_l_bfgs_b",
                                                  random_state=int(np.random.default_rng(seed).integers(2 ** 31)))
            import warnings
            from sklearn.exceptions import ConvergenceWarning
            # one BLAS thread: matrices a few hundred wide, and several threads spin against each other on a
            # busy machine; a length scale at its bound means "this input does not matter" (no warning)
            with warnings.catch_warnings(), limit_threads(1, ("blas",)):
                warnings.simplefilter("ignore", ConvergenceWarning)
                self.model.fit(Xs, Y)
            self.kernel = self.model.kernel_
        else:
            from sklearn.linear_model import RidgeCV
            self.model = RidgeCV(alphas=RIDGE_ALPHAS).fit(Xs, Y) if alpha is None else None
            if alpha is not None:
                from sklearn.linear_model import Ridge
                self.model = Ridge(alpha=alpha).fit(Xs, Y)
            self.kernel = None
            r = Y - self.model.predict(Xs)
            self.noise = np.sqrt(np.mean(r ** 2, axis=0))

    @property
    def alpha(self):
        return getattr(self.model, "alpha_", getattr(self.model, "alpha", None))

    def predict(self, X):
        Xs = (X - self.mu) / self.sd
        if self.family.startswith("gp"):
            with limit_threads(1, ("blas",)):
                m, s = self.model.predict(Xs, return_std=True)
            s = s if s.ndim == 2 else np.repeat(s[:, None], 3, 1)
            return m, s
        m = self.model.predict(Xs)
        return m, np.broadcast_to(self.noise, m.shape).copy()


class ArmResidualRegressor:
    """Learned residual of an arm (scikit-learn style). ``families``: candidates; ``k_folds`` (2–20)
    folds of the family choice; ``n_restarts`` (0–10) marginal-likelihood restarts; ``seed``.

    After :meth:`fit`: ``chosen_`` (family), ``cv_table_`` (per family: CV mean / RMS error of the
    residual after the learner, beside the residual itself), ``coverage_`` (95 % band coverage in CV).
    """

    def __init__(self, chain, families=FAMILIES, k_folds: int = 5, n_restarts: int = 1, seed=0):
        unknown = [f for f in families if f not in FAMILIES]
        if unknown or not families:
            raise ValueError(f"unknown families {unknown}; choose from {FAMILIES}")
        if not 2 <= int(k_folds) <= 20:
            raise ValueError(f"k_folds must be in [2, 20], got {k_folds}")
        if not 0 <= int(n_restarts) <= 10:
            raise ValueError(f"n_restarts must be in [0, 10], got {n_restarts}")
        self.chain, self.families, self.k_folds, self.n_restarts, self.seed = chain, tuple(families), int(k_folds), \
            int(n_restarts), seed

    def fit(self, q, residual_mm, groups=None, errors=None) -> "ArmResidualRegressor":
        """``q`` (n, nq) joint values, ``residual_mm`` (n, 3) = measured − geometric model;
        ``groups`` (n,) fold labels for the family choice (default: random folds by ``seed``)."""
        q = np.asarray(q, float)
        Y = np.asarray(residual_mm, float)
        if len(q) != len(Y) or Y.shape[1:] != (3,):
            raise ValueError(f"expected q (n, nq) and residual (n, 3), got {q.shape} and {Y.shape}")
        if len(q) > MAX_FIT_POSES:
            raise ValueError(f"{len(q)} poses: above {MAX_FIT_POSES} a dense GP is too slow; subsample")
        self.errors = None if errors is None else np.asarray(errors, float)
        rng = np.random.default_rng(self.seed)
        folds = (rng.permutation(len(q)) % self.k_folds) if groups is None else np.unique(groups, return_inverse=True)[1]
        base = np.linalg.norm(Y, axis=1)
        self.cv_table_ = [{"family": "none (geometric only)", "cv_mean_mm": float(base.mean()),
                           "cv_rms_mm": float(np.sqrt(np.mean(base ** 2))), "coverage95": None}]
        fitted = {}
        for fam in self.families:
            X = features(self.chain, q, fam, self.errors)
            sub = rng.permutation(len(q))[:HYPER_POSES]
            tuned = _Model(fam, X[sub], Y[sub], self.seed, self.n_restarts)
            full = _Model(fam, X, Y, self.seed, 0, kernel=tuned.kernel, alpha=tuned.alpha)
            pred = np.zeros_like(Y)
            sd = np.zeros_like(Y)
            for f in np.unique(folds):
                tr, te = folds != f, folds == f
                m = _Model(fam, X[tr], Y[tr], self.seed, 0, kernel=full.kernel, alpha=full.alpha)
                pred[te], sd[te] = m.predict(X[te])
            e = np.linalg.norm(Y - pred, axis=1)
            cov = float(np.mean(np.abs(Y - pred) <= Z95 * sd))
            self.cv_table_.append({"family": fam, "cv_mean_mm": float(e.mean()), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2))),
                                   "coverage95": cov})
            fitted[fam] = full
        best = min(self.cv_table_[1:], key=lambda r: r["cv_mean_mm"])
        self.chosen_ = best["family"]
        self.coverage_ = best["coverage95"]
        self.beats_geometric_in_cv_ = best["cv_mean_mm"] < self.cv_table_[0]["cv_mean_mm"]
        self.model_ = fitted[self.chosen_]
        self.q_fit_, self.y_fit_ = q, Y
        return self

    def predict(self, q, return_std: bool = False):
        """Predicted residual (n, 3) mm [and its predictive std (n, 3)]."""
        m, s = self.model_.predict(features(self.chain, np.asarray(q, float), self.chosen_, self.errors))
        return (m, s) if return_std else m

    def to_dict(self) -> dict:
        """JSON-able: family, fitted hyper-parameters and the fit data (a GP is rebuilt from them exactly)."""
        d = {"chosen": self.chosen_, "cv_table": self.cv_table_, "coverage95_cv": self.coverage_,
             "k_folds": self.k_folds, "seed": self.seed if isinstance(self.seed, int) else None,
             "q_fit": self.q_fit_.tolist(), "residual_fit_mm": self.y_fit_.tolist(),
             "errors": None if self.errors is None else self.errors.tolist()}
        if self.model_.kernel is not None:
            d["kernel_params"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                  for k, v in self.model_.kernel.get_params().items()
                                  if isinstance(v, (float, int, np.ndarray)) and not isinstance(v, bool)}
        else:
            d["ridge_alpha"] = float(self.model_.alpha)
        return d

    @classmethod
    def from_dict(cls, chain, d: dict) -> "ArmResidualRegressor":
        self = cls(chain, families=(d["chosen"],), k_folds=d["k_folds"], seed=d.get("seed") or 0)
        self.chosen_, self.cv_table_, self.coverage_ = d["chosen"], d["cv_table"], d["coverage95_cv"]
        self.errors = None if d["errors"] is None else np.asarray(d["errors"])
        q, Y = np.asarray(d["q_fit"]), np.asarray(d["residual_fit_mm"])
        X = features(chain, q, self.chosen_, self.errors)
        if "kernel_params" in d:
            k = _gp(X.shape[1])
            k.set_params(**{kk: (np.asarray(v) if isinstance(v, list) else v) for kk, v in d["kernel_params"].items()
                            if not kk.endswith("_bounds")})
            self.model_ = _Model(self.chosen_, X, Y, 0, 0, kernel=k)
        else:
            self.model_ = _Model(self.chosen_, X, Y, 0, 0, alpha=d["ridge_alpha"])
        self.q_fit_, self.y_fit_ = q, Y
        return self
