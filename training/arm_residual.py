"""The learned residual stage of an arm calibration: the project's :class:`training.residual.ResidualRegressor`
on the inputs the physics of a serial chain suggests.

Inputs (derived from the chain, nothing machine-specific), ``inputs``:

``"physics"``
    each revolute joint as sin/cos (prismatic joints: value / stroke), and per joint the gravity
    moment about its axis of unit masses at the downstream joint origins and the tool point, from
    the NOMINAL chain, in m (:func:`errormap.arm_simulate.gravity_moment_mm`) — what a
    joint-stiffness sag or a gear's load-dependent deflection follows;
``"sincos"``
    the joints alone (sin/cos): the plain learner an engineer tries first.

Output: the 3-D position residual (measured − geometric model), mm. Everything else — the GP,
its hyper-parameters by marginal likelihood, the choice against predicting zero by CV inside the fit
set (blocked when ``groups`` are given), the band calibrated on that CV, the closed-form Jacobian,
JSON — is :class:`~training.residual.ResidualRegressor`'s. ``chosen_ == "none"``: the learner did not
beat the geometric stage in CV; nothing is added.
"""
from __future__ import annotations

import numpy as np

from errormap.arm_simulate import gravity_moment_jacobian_mm, gravity_moment_mm

from .residual import ResidualRegressor

FORMAT = "volcomp-arm-residual/2"
INPUTS = ("physics", "sincos")
M_PER_MM = 1e-3


def features(chain, q, inputs: str = "physics") -> np.ndarray:
    """Input features for joint values ``q`` (n, nq), shape (n, d)."""
    q = np.atleast_2d(np.asarray(q, float))
    rev = np.array([j.type == "revolute" for j in chain.joints])
    r = np.radians(q[:, rev])
    span = np.maximum(chain.joint_hi - chain.joint_lo, 1e-9)[~rev]
    base = np.concatenate([np.sin(r), np.cos(r), q[:, ~rev] / span], 1)
    if inputs == "sincos":
        return base
    return np.concatenate([base, gravity_moment_mm(chain, q) * M_PER_MM], 1)


def feature_jacobian(chain, q, inputs: str = "physics") -> np.ndarray:
    """∂features/∂q per pose, shape (n, d, nq) (per joint unit): sin/cos analytic, gravity moments by
    central differences (:func:`errormap.arm_simulate.gravity_moment_jacobian_mm`)."""
    q = np.atleast_2d(np.asarray(q, float))
    n, nq = q.shape
    rev = np.flatnonzero([j.type == "revolute" for j in chain.joints])
    pri = np.flatnonzero([j.type != "revolute" for j in chain.joints])
    nr = len(rev)
    d = 2 * nr + len(pri) + (0 if inputs == "sincos" else nq)
    D = np.zeros((n, d, nq))
    k = np.pi / 180
    for i, j in enumerate(rev):
        D[:, i, j] = np.cos(np.radians(q[:, j])) * k
        D[:, nr + i, j] = -np.sin(np.radians(q[:, j])) * k
    span = np.maximum(chain.joint_hi - chain.joint_lo, 1e-9)
    for i, j in enumerate(pri):
        D[:, 2 * nr + i, j] = 1.0 / span[j]
    if inputs != "sincos":
        o = 2 * nr + len(pri)
        D[:, o:, :] = gravity_moment_jacobian_mm(chain, q) * M_PER_MM
    return D


class ArmResidualRegressor:
    """Learned residual of an arm (scikit-learn style): ``inputs`` (:data:`INPUTS`), ``k_folds`` (2–20)
    CV folds of :class:`ResidualRegressor`, ``n_restarts`` (1–10) marginal-likelihood starts,
    ``margin_se`` (≥ 0) the paired standard errors by which the GP must beat zero, ``seed``.

    After :meth:`fit`: ``regressor_`` (the fitted ResidualRegressor), ``chosen_`` (``"gp"`` or
    ``"none"``), ``cv_table_`` (its CV table), ``coverage_`` (95 % band coverage of the GP's held-out
    CV folds, before the band calibration; the calibrated band holds 95 % there by construction).
    """

    def __init__(self, chain, inputs: str = "physics", k_folds: int = 5, n_restarts: int = 1, margin_se: float = 1.0,
                 seed=0):
        if inputs not in INPUTS:
            raise ValueError(f"inputs must be one of {INPUTS}, got {inputs!r}")
        if not 2 <= int(k_folds) <= 20:
            raise ValueError(f"k_folds must be in [2, 20], got {k_folds}")
        if not 1 <= int(n_restarts) <= 10:
            raise ValueError(f"n_restarts must be in [1, 10], got {n_restarts}")
        self.chain, self.inputs, self.k_folds, self.n_restarts = chain, inputs, int(k_folds), int(n_restarts)
        self.margin_se, self.seed = float(margin_se), seed

    def fit(self, q, residual_mm, groups=None) -> "ArmResidualRegressor":
        """``q`` (n, nq) joint values, ``residual_mm`` (n, 3) = measured − geometric model; ``groups``
        (n,) block labels for blocked CV (default: shuffled k-fold)."""
        q = np.asarray(q, float)
        Y = np.asarray(residual_mm, float)
        if len(q) != len(Y) or Y.shape[1:] != (3,):
            raise ValueError(f"expected q (n, nq) and residual (n, 3), got {q.shape} and {Y.shape}")
        self.regressor_ = ResidualRegressor(("gp",), n_splits=self.k_folds, seed=self.seed, margin_se=self.margin_se,
                                            n_restarts=self.n_restarts).fit(features(self.chain, q, self.inputs), Y, groups)
        return self._fitted()

    def _fitted(self):
        r = self.regressor_
        self.chosen_ = r.chosen_
        self.cv_table_ = r.cv_table_
        self.coverage_ = r.cv_table_.get("gp", {}).get("coverage_95")
        return self

    def predict(self, q, return_std: bool = False):
        """Predicted residual (n, 3) mm [and the std of a new measurement about it (n, 3): the GP's
        latent std and its fitted noise, both calibrated on the CV]."""
        m, s = self.regressor_.predict(features(self.chain, q, self.inputs), return_std=True)
        return (m, np.sqrt(s ** 2 + self.regressor_.noise_std_[None, :] ** 2)) if return_std else m

    def predict_and_jacobian(self, q):
        """(residual (n, 3) mm, ∂residual/∂q (n, 3, nq) per joint unit), the GP part in closed form."""
        m, dX = self.regressor_.predict_and_jacobian(features(self.chain, q, self.inputs))
        return m, np.einsum("nkd,ndj->nkj", dX, feature_jacobian(self.chain, q, self.inputs))

    def to_dict(self) -> dict:
        return {"format": FORMAT, "inputs": self.inputs, "k_folds": self.k_folds, "n_restarts": self.n_restarts,
                "margin_se": self.margin_se, "regressor": self.regressor_.to_dict()}

    @classmethod
    def from_dict(cls, chain, d: dict) -> "ArmResidualRegressor":
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ValueError(f"expected an arm residual (format {FORMAT!r})")
        self = cls(chain, d["inputs"], d["k_folds"], d["n_restarts"], d["margin_se"])
        self.regressor_ = ResidualRegressor.from_dict(d["regressor"])
        return self._fitted()


def cv_pipelines(chain, poses, pipelines: dict, k_folds: int, seed, groups=None, fold_fits=None) -> dict:
    """Inner CV of whole pipelines (geometric stage [+ learned residual]) on the folds of
    :func:`errormap.arm_calibration.cv_labels` (``k_folds``, ``seed``, ``groups``: the geometric CV's folds).

    ``pipelines``: name → ``(model, learner)``, ``model`` a slot set of :data:`errormap.arm_calibration.MODELS`
    or ``"plain"`` (the plain LSQ fit), ``learner`` a fitted :class:`ArmResidualRegressor` or None. Per fold
    the geometric stage is REFITTED on the fold's fit part (taken from ``fold_fits`` of
    :func:`~errormap.arm_calibration.cv_models` where there), and the learner's GP keeps the
    hyper-parameters it chose on all of ``poses`` while its weights are re-solved on that refit's residual
    at the fold's fit part (:meth:`training.residual.ResidualRegressor.with_data`); the held-out fold is
    predicted. Returns name → ``{"cv_mean_mm", "cv_rms_mm", "errors_mm"}`` (``errors_mm`` (n,) held-out
    position error norm per pose)."""
    from errormap.arm_calibration import cv_labels, fit_model, fit_plain_lsq
    lab = cv_labels(len(poses), k_folds, seed, groups)
    fold_fits = {} if fold_fits is None else fold_fits
    err = {k: np.empty(len(poses)) for k in pipelines}
    for f in range(int(lab.max()) + 1):
        itr, ite = np.flatnonzero(lab != f), np.flatnonzero(lab == f)
        tr = poses.subset(itr)
        for name, (model, learner) in pipelines.items():
            if (f, model) not in fold_fits:
                fold_fits[(f, model)] = fit_plain_lsq(chain, tr) if model == "plain" else fit_model(chain, tr, model)
            geo = fold_fits[(f, model)]
            pred = geo.predict(poses.q[ite])
            if learner is not None and learner.chosen_ != "none":
                reg = learner.regressor_.with_data(features(chain, tr.q, learner.inputs), tr.xyz_mm - geo.predict(tr.q))
                pred = pred + reg.predict(features(chain, poses.q[ite], learner.inputs))
            err[name][ite] = np.linalg.norm(poses.xyz_mm[ite] - pred, axis=1)
    return {k: {"cv_mean_mm": float(e.mean()), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2))), "errors_mm": e}
            for k, e in err.items()}
