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

from errormap.arm_simulate import gravity_moment_mm

from .residual import ResidualRegressor

FORMAT = "volcomp-arm-residual/2"
INPUTS = ("physics", "sincos")
MOMENT_FD_STEP_DEG = 1e-3   # central difference of the gravity moments (a smooth trigonometric function of q):
# truncation ~ step² · moment'' ≈ 1e-10 of the moment, far below anything a GP input resolves
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
    central differences (:data:`MOMENT_FD_STEP_DEG`)."""
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
        for j in range(nq):
            qp, qm = q.copy(), q.copy()
            qp[:, j] += MOMENT_FD_STEP_DEG
            qm[:, j] -= MOMENT_FD_STEP_DEG
            D[:, o:, j] = (gravity_moment_mm(chain, qp) - gravity_moment_mm(chain, qm)) * M_PER_MM / (2 * MOMENT_FD_STEP_DEG)
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
