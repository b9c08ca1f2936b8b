"""The learned residual stage of an arm calibration: the project's :class:`training.residual.ResidualRegressor`
on the inputs the physics of a serial chain suggests.

Inputs (derived from the chain, nothing machine-specific), ``inputs``:

``"physics"``
    each revolute joint as sin/cos (prismatic joints: value / stroke), and per joint the gravity
    moment about its axis of unit masses at the downstream joint origins and the tool point, from
    the NOMINAL chain, in m (:func:`errormap.arm_simulate.gravity_moment_mm`) — what a
    joint-stiffness sag or a gear's load-dependent deflection follows;
``"sincos"``
    the joints alone (sin/cos): the plain learner an engineer tries first;
``"physics+h2"``
    ``"physics"`` and each revolute joint's second harmonic (sin 2q, cos 2q: a twice-per-turn gear or
    encoder error);
``"physics+wrist"``
    ``"physics"`` and the products of the last three revolute joints' sin/cos in pairs (s_i s_j, s_i c_j,
    c_i s_j, c_i c_j for i < j: a wrist error that depends on two joints together).

Output: the 3-D position residual (measured − geometric model), mm. Everything else — the GP,
its hyper-parameters by marginal likelihood, the choice against predicting zero by CV inside the fit
set (blocked when ``groups`` are given), the band calibrated on that CV, the closed-form Jacobian,
JSON — is :class:`~training.residual.ResidualRegressor`'s. ``chosen_ == "none"``: the learner did not
beat the geometric stage in CV; nothing is added.
"""
from __future__ import annotations

import numpy as np

from errormap.arm_simulate import gravity_moment_jacobian_mm, gravity_moment_mm

from .residual import GP_KERNELS, ResidualRegressor

FORMAT = "volcomp-arm-residual/2"
INPUTS = ("physics", "sincos", "physics+h2", "physics+wrist")
KERNEL_FAMILIES = ("gp", "gp_matern52", "gp_matern32")
"""The Gaussian-process families the command's learned stage cross-validates (squared exponential, Matérn 5/2,
Matérn 3/2, :data:`training.residual.GP_KERNELS`): the one with the lowest CV error inside the fit poses that beats
predicting zero is kept — the kernel is chosen by that CV, never by name or on held-out poses."""
WRIST_JOINTS = 3
"""The last this many revolute joints are the wrist of ``"physics+wrist"``."""
M_PER_MM = 1e-3


def _wrist_pairs(rev):
    """Pairs (a, b), a < b, of indices into the revolute joints: the last :data:`WRIST_JOINTS` of them."""
    w = list(range(max(0, len(rev) - WRIST_JOINTS), len(rev)))
    return [(a, b) for i, a in enumerate(w) for b in w[i + 1:]]


def features(chain, q, inputs: str = "physics") -> np.ndarray:
    """Input features for joint values ``q`` (n, nq), shape (n, d)."""
    q = np.atleast_2d(np.asarray(q, float))
    rev = np.array([j.type == "revolute" for j in chain.joints])
    r = np.radians(q[:, rev])
    span = np.maximum(chain.joint_hi - chain.joint_lo, 1e-9)[~rev]
    base = np.concatenate([np.sin(r), np.cos(r), q[:, ~rev] / span], 1)
    if inputs == "sincos":
        return base
    out = [base, gravity_moment_mm(chain, q) * M_PER_MM]
    if inputs == "physics+h2":
        out += [np.sin(2 * r), np.cos(2 * r)]
    elif inputs == "physics+wrist":
        s, c = np.sin(r), np.cos(r)
        out += [np.stack([s[:, a] * s[:, b], s[:, a] * c[:, b], c[:, a] * s[:, b], c[:, a] * c[:, b]], 1)
                for a, b in _wrist_pairs(np.flatnonzero(rev))]
    return np.concatenate(out, 1)


def feature_jacobian(chain, q, inputs: str = "physics") -> np.ndarray:
    """∂features/∂q per pose, shape (n, d, nq) (per joint unit): sin/cos and their harmonics and products
    analytic, gravity moments by central differences (:func:`errormap.arm_simulate.gravity_moment_jacobian_mm`)."""
    q = np.atleast_2d(np.asarray(q, float))
    n, nq = q.shape
    rev = np.flatnonzero([j.type == "revolute" for j in chain.joints])
    pri = np.flatnonzero([j.type != "revolute" for j in chain.joints])
    nr = len(rev)
    d = features(chain, q[:1], inputs).shape[1]
    D = np.zeros((n, d, nq))
    k = np.pi / 180
    r = np.radians(q[:, rev])
    s, c = np.sin(r), np.cos(r)
    for i, j in enumerate(rev):
        D[:, i, j] = c[:, i] * k
        D[:, nr + i, j] = -s[:, i] * k
    span = np.maximum(chain.joint_hi - chain.joint_lo, 1e-9)
    for i, j in enumerate(pri):
        D[:, 2 * nr + i, j] = 1.0 / span[j]
    if inputs == "sincos":
        return D
    o = 2 * nr + len(pri)
    D[:, o:o + nq, :] = gravity_moment_jacobian_mm(chain, q) * M_PER_MM
    o += nq
    if inputs == "physics+h2":
        for i, j in enumerate(rev):
            D[:, o + i, j] = 2 * np.cos(2 * r[:, i]) * k
            D[:, o + nr + i, j] = -2 * np.sin(2 * r[:, i]) * k
    elif inputs == "physics+wrist":
        for a, b in _wrist_pairs(rev):
            ja, jb = rev[a], rev[b]
            # (s_a s_b, s_a c_b, c_a s_b, c_a c_b): d/dq_a and d/dq_b
            D[:, o, ja], D[:, o, jb] = c[:, a] * s[:, b] * k, s[:, a] * c[:, b] * k
            D[:, o + 1, ja], D[:, o + 1, jb] = c[:, a] * c[:, b] * k, -s[:, a] * s[:, b] * k
            D[:, o + 2, ja], D[:, o + 2, jb] = -s[:, a] * s[:, b] * k, c[:, a] * c[:, b] * k
            D[:, o + 3, ja], D[:, o + 3, jb] = -s[:, a] * c[:, b] * k, -c[:, a] * s[:, b] * k
            o += 4
    return D


class ArmResidualRegressor:
    """Learned residual of an arm (scikit-learn style): ``inputs`` (:data:`INPUTS`), ``k_folds`` (2–20)
    CV folds of :class:`ResidualRegressor`, ``n_restarts`` (1–10) marginal-likelihood starts,
    ``margin_se`` (≥ 0) the paired standard errors by which the GP must beat zero, ``seed``,
    ``families`` the GP families cross-validated (a non-empty subset of :data:`KERNEL_FAMILIES`; default the
    squared exponential alone; the command passes all three: the kernel is then chosen by the CV).

    After :meth:`fit`: ``regressor_`` (the fitted ResidualRegressor), ``chosen_`` (the chosen family of
    ``families`` or ``"none"``), ``cv_table_`` (its CV table), ``coverage_`` (95 % band coverage of the chosen
    GP's held-out CV folds — of the first family where none is chosen —, before the band calibration; the
    calibrated band holds 95 % there by construction).
    """

    def __init__(self, chain, inputs: str = "physics", k_folds: int = 5, n_restarts: int = 1, margin_se: float = 1.0,
                 seed=0, families=("gp",)):
        if inputs not in INPUTS:
            raise ValueError(f"inputs must be one of {INPUTS}, got {inputs!r}")
        families = tuple(families)
        if not families or any(f not in KERNEL_FAMILIES for f in families) or len(set(families)) != len(families):
            raise ValueError(f"families must be distinct members of {KERNEL_FAMILIES}, got {families!r}")
        if not 2 <= int(k_folds) <= 20:
            raise ValueError(f"k_folds must be in [2, 20], got {k_folds}")
        if not 1 <= int(n_restarts) <= 10:
            raise ValueError(f"n_restarts must be in [1, 10], got {n_restarts}")
        self.chain, self.inputs, self.k_folds, self.n_restarts = chain, inputs, int(k_folds), int(n_restarts)
        self.margin_se, self.seed, self.families = float(margin_se), seed, families

    def fit(self, q, residual_mm, groups=None) -> "ArmResidualRegressor":
        """``q`` (n, nq) joint values, ``residual_mm`` (n, 3) = measured − geometric model; ``groups``
        (n,) block labels for blocked CV (default: shuffled k-fold)."""
        q = np.asarray(q, float)
        Y = np.asarray(residual_mm, float)
        if len(q) != len(Y) or Y.shape[1:] != (3,):
            raise ValueError(f"expected q (n, nq) and residual (n, 3), got {q.shape} and {Y.shape}")
        self.regressor_ = ResidualRegressor(self.families, n_splits=self.k_folds, seed=self.seed, margin_se=self.margin_se,
                                            n_restarts=self.n_restarts).fit(features(self.chain, q, self.inputs), Y, groups)
        return self._fitted()

    def _fitted(self):
        r = self.regressor_
        self.chosen_ = r.chosen_
        self.cv_table_ = r.cv_table_
        fam = r.chosen_ if r.chosen_ in GP_KERNELS else self.families[0]
        self.coverage_ = r.cv_table_.get(fam, {}).get("coverage_95")
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
                "margin_se": self.margin_se, "families": list(self.families), "regressor": self.regressor_.to_dict()}

    @classmethod
    def from_dict(cls, chain, d: dict) -> "ArmResidualRegressor":
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ValueError(f"expected an arm residual (format {FORMAT!r})")
        self = cls(chain, d["inputs"], d["k_folds"], d["n_restarts"], d["margin_se"],
                   families=d.get("families", ("gp",)))   # files before the kernel choice: the squared exponential
        self.regressor_ = ResidualRegressor.from_dict(d["regressor"])
        return self._fitted()


HYPER = ("fold", "fit")
"""Where a learner's GP hyper-parameters come from in :func:`cv_pipelines`: ``"fold"`` re-estimated (maximum
marginal likelihood) on each inner fold's fit part, nothing of the held-out fold seen; ``"fit"`` kept from all
fit poses, weights re-solved per fold (the earlier rule: the held-out fold leaks into the hyper-parameters)."""


def cv_pipelines(chain, poses, pipelines: dict, k_folds: int, seed, groups=None, fold_fits=None,
                 hyper: str = "fold") -> dict:
    """Inner CV of whole pipelines (geometric stage [+ learned residual]) on the folds of
    :func:`errormap.arm_calibration.cv_labels` (``k_folds``, ``seed``, ``groups``: the geometric CV's folds).

    ``pipelines``: name → ``(model, learner)``, ``model`` a slot set of :data:`errormap.arm_calibration.MODELS`
    or ``"plain"`` (the plain LSQ fit), ``learner`` a fitted :class:`ArmResidualRegressor` or None. Per fold
    the geometric stage is REFITTED on the fold's fit part (taken from ``fold_fits`` of
    :func:`~errormap.arm_calibration.cv_models` where there), and the learner (its family and inputs as
    chosen) is re-estimated on that refit's residual at the fold's fit part: with ``hyper="fold"`` (default)
    its standardisation and GP hyper-parameters from the fold's fit part alone
    (:meth:`training.residual.ResidualRegressor.refit`), with ``hyper="fit"`` the hyper-parameters of all
    ``poses`` kept and only the weights re-solved (:meth:`~training.residual.ResidualRegressor.with_data`;
    the held-out fold then leaks into them). The held-out fold is predicted. Returns name →
    ``{"cv_mean_mm", "cv_rms_mm", "errors_mm", "pred_mm"}`` (``errors_mm`` (n,) held-out position error norm per
    pose, ``pred_mm`` (n, 3) the held-out prediction)."""
    if hyper not in HYPER:
        raise ValueError(f"hyper must be one of {HYPER}, got {hyper!r}")
    from errormap.arm_calibration import FOLD_LABELS, cv_labels, fit_model, fit_plain_lsq
    lab = cv_labels(len(poses), k_folds, seed, groups)
    fold_fits = {} if fold_fits is None else fold_fits
    if not np.array_equal(fold_fits.setdefault(FOLD_LABELS, lab), lab):
        raise ValueError("fold_fits were fitted on other folds: reusing them would leak the held-out poses")
    err = {k: np.empty(len(poses)) for k in pipelines}
    held = {k: np.empty((len(poses), 3)) for k in pipelines}
    for f in range(int(lab.max()) + 1):
        itr, ite = np.flatnonzero(lab != f), np.flatnonzero(lab == f)
        tr = poses.subset(itr)
        for name, (model, learner) in pipelines.items():
            if (f, model) not in fold_fits:
                fold_fits[(f, model)] = fit_plain_lsq(chain, tr) if model == "plain" else fit_model(chain, tr, model)
            geo = fold_fits[(f, model)]
            pred = geo.predict(poses.q[ite])
            if learner is not None and learner.chosen_ != "none":
                X, Y = features(chain, tr.q, learner.inputs), tr.xyz_mm - geo.predict(tr.q)
                reg = learner.regressor_.refit(X, Y) if hyper == "fold" else learner.regressor_.with_data(X, Y)
                pred = pred + reg.predict(features(chain, poses.q[ite], learner.inputs))
            err[name][ite] = np.linalg.norm(poses.xyz_mm[ite] - pred, axis=1)
            held[name][ite] = pred
    return {k: {"cv_mean_mm": float(e.mean()), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2))), "errors_mm": e,
                "pred_mm": held[k]} for k, e in err.items()}


STACK_WEIGHTS = np.linspace(0.0, 1.0, 21)
"""The stacking rule's grid of weights on volcomp's pipeline (step 0.05)."""
STACK_TIE_REL = 1e-12
"""Weights whose inner mean error is within this (relative) of the lowest tie (round-off of w·a + (1 − w)·a)."""


def stack_weight(y_mm, p_vol_mm, p_pgp_mm):
    """Stacking of two pipelines on their INNER out-of-fold predictions (:func:`cv_pipelines` ``pred_mm``): the
    weight w ∈ :data:`STACK_WEIGHTS` that minimises the mean position error of w·p_vol + (1 − w)·p_pgp against the
    measured ``y_mm`` (all (n, 3) mm; ties to the larger w, i.e. toward volcomp's pipeline). Returns (w, the inner
    mean error (mm) per weight (21,)). Measured in ``benchmarks/bench_arms.py`` (rule ``stack``); the command does
    not yet return a blended model."""
    y, a, b = (np.asarray(v, float) for v in (y_mm, p_vol_mm, p_pgp_mm))
    e = np.array([np.linalg.norm(y - (w * a + (1 - w) * b), axis=1).mean() for w in STACK_WEIGHTS])
    i = int(np.flatnonzero(e <= e.min() * (1 + STACK_TIE_REL))[-1])
    return float(STACK_WEIGHTS[i]), e
