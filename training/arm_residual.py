"""The learned residual stage of an arm calibration: the project's
:class:`training.residual.ResidualRegressor` on the inputs the physics of a serial chain suggests.

Inputs (:data:`INPUTS`, derived from the chain): ``"physics"`` (each revolute joint as sin/cos, prismatic as
value / stroke, and per joint the gravity moment of unit masses from the NOMINAL chain,
:func:`errormap.arm_simulate.gravity_moment_mm`), ``"sincos"`` (the joints alone), ``"physics+h2"`` and
``"physics+wrist"`` (second harmonics, wrist products). Output: the 3-D position residual (measured −
geometric model), mm; ``chosen_ == "none"``: nothing is added. docs/reference/arm-calibration.md."""
from __future__ import annotations

import numpy as np

from errormap.arm_simulate import gravity_moment_jacobian_mm, gravity_moment_mm

from .gp import GP_KERNELS
from .residual import ResidualRegressor

FORMAT = "volcomp-arm-residual/2"
INPUTS = ("physics", "sincos", "physics+h2", "physics+wrist")
KERNEL_FAMILIES = ("gp", "gp_matern52", "gp_matern32")
"""The Gaussian-process families the command's learned stage cross-validates (squared exponential, Matérn 5/2,
Matérn 3/2, :data:`training.gp.GP_KERNELS`): the one with the lowest CV error inside the fit poses that beats
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

    def with_regressor(self, regressor) -> "ArmResidualRegressor":
        """A copy of this learner (chain, inputs, settings) carrying another fitted ``regressor``
        (:class:`ResidualRegressor`, e.g. its :meth:`~ResidualRegressor.refit` on a fold's fit part)."""
        import copy
        out = copy.copy(self)
        out.regressor_ = regressor
        return out._fitted()

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


class RotatedResidual:
    """A fitted learner whose residual is turned into another instrument frame: ``R`` (3, 3) the rotation from the
    frame it was learned in to the new one (a re-registered base, :mod:`errormap.arm_register`); the residual is a
    vector, so its prediction and Jacobian turn with the frame, and each component's band std is that of independent
    components turned (sqrt(R² · s²)). Everything else is the wrapped learner's."""

    def __init__(self, learner, R):
        self.learner, self.R = learner, np.asarray(R, float)

    def __getattr__(self, name):
        return getattr(self.__dict__["learner"], name)

    def predict(self, q, return_std: bool = False):
        if not return_std:
            return self.learner.predict(q) @ self.R.T
        m, s = self.learner.predict(q, return_std=True)
        return m @ self.R.T, np.sqrt((s ** 2) @ (self.R ** 2).T)

    def predict_and_jacobian(self, q):
        m, J = self.learner.predict_and_jacobian(q)
        return m @ self.R.T, np.einsum("ij,njk->nik", self.R, J)


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
    pose, ``pred_mm`` (n, 3) the held-out prediction, ``std_mm`` (n, 3) its band std: :func:`pipeline_std_mm` of the
    fold's refit pipeline)."""
    if hyper not in HYPER:
        raise ValueError(f"hyper must be one of {HYPER}, got {hyper!r}")
    from errormap.arm_calibration import FOLD_LABELS, cv_labels, fit_model, fit_plain_lsq
    lab = cv_labels(len(poses), k_folds, seed, groups)
    fold_fits = {} if fold_fits is None else fold_fits
    if not np.array_equal(fold_fits.setdefault(FOLD_LABELS, lab), lab):
        raise ValueError("fold_fits were fitted on other folds: reusing them would leak the held-out poses")
    err = {k: np.empty(len(poses)) for k in pipelines}
    held = {k: np.empty((len(poses), 3)) for k in pipelines}
    sd = {k: np.empty((len(poses), 3)) for k in pipelines}
    for f in range(int(lab.max()) + 1):
        itr, ite = np.flatnonzero(lab != f), np.flatnonzero(lab == f)
        tr = poses.subset(itr)
        for name, (model, learner) in pipelines.items():
            if (f, model) not in fold_fits:
                fold_fits[(f, model)] = fit_plain_lsq(chain, tr) if model == "plain" else fit_model(chain, tr, model)
            geo = fold_fits[(f, model)]
            pred = geo.predict(poses.q[ite])
            reg_fold = None
            if learner is not None and learner.chosen_ != "none":
                X, Y = features(chain, tr.q, learner.inputs), tr.xyz_mm - geo.predict(tr.q)
                reg = learner.regressor_.refit(X, Y) if hyper == "fold" else learner.regressor_.with_data(X, Y)
                pred = pred + reg.predict(features(chain, poses.q[ite], learner.inputs))
                reg_fold = reg
            err[name][ite] = np.linalg.norm(poses.xyz_mm[ite] - pred, axis=1)
            held[name][ite] = pred
            sd[name][ite] = pipeline_std_mm(geo, None if reg_fold is None else learner.with_regressor(reg_fold),
                                            poses.q[ite])
    return {k: {"cv_mean_mm": float(e.mean()), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2))), "errors_mm": e,
                "pred_mm": held[k], "std_mm": sd[k]} for k, e in err.items()}


STACK_WEIGHTS = np.linspace(0.0, 1.0, 21)
"""The stacking rule's grid of weights on volcomp's pipeline (step 0.05)."""
STACK_TIE_REL = 1e-12
"""Weights whose inner mean error is within this (relative) of the lowest tie (round-off of w·a + (1 − w)·a)."""


def stack_weight(y_mm, p_vol_mm, p_pgp_mm):
    """Stacking of two pipelines on their INNER out-of-fold predictions (:func:`cv_pipelines` ``pred_mm``): the
    weight w ∈ :data:`STACK_WEIGHTS` that minimises the mean position error of w·p_vol + (1 − w)·p_pgp against the
    measured ``y_mm`` (all (n, 3) mm; ties to the larger w, i.e. toward volcomp's pipeline). Returns (w, the inner
    mean error (mm) per weight (21,)). The command's candidate stage ``stacked`` (:class:`StackedResidual`) uses
    this weight; its own CV figure is :func:`stack_cv`'s (the weight chosen without the judged fold)."""
    y, a, b = (np.asarray(v, float) for v in (y_mm, p_vol_mm, p_pgp_mm))
    e = np.array([np.linalg.norm(y - (w * a + (1 - w) * b), axis=1).mean() for w in STACK_WEIGHTS])
    i = int(np.flatnonzero(e <= e.min() * (1 + STACK_TIE_REL))[-1])
    return float(STACK_WEIGHTS[i]), e


def pipeline_std_mm(geo, learner, q) -> np.ndarray:
    """Standard deviation of a new measurement about a pipeline's prediction at ``q`` (n, nq), shape (n, 3) mm — the
    band rule of every arm stage: with a learner (``chosen_ != "none"``) the learner's own (an
    :class:`ArmResidualRegressor`: the GP's CV-calibrated latent std and its noise; a :class:`StackedResidual`: its
    blend rule); else the geometric stage's J Σ Jᵀ and its residual σ (``geo`` a
    :class:`errormap.arm_calibration.GeometricResult`)."""
    if learner is not None and learner.chosen_ != "none":
        return learner.predict(q, return_std=True)[1]
    return np.sqrt(geo.band_std_mm(q) ** 2 + geo.sigma_mm ** 2)


def stack_cv(y_mm, p_a_mm, p_b_mm, labels, s_a_mm=None, s_b_mm=None) -> dict:
    """The CV figure of the stack itself, on the out-of-fold predictions of its two pipelines (:func:`cv_pipelines`
    ``pred_mm``, (n, 3) mm, on the folds ``labels`` (n,)): per fold f the weight is chosen by :func:`stack_weight`
    on the OTHER folds' out-of-fold predictions and applied to fold f, so the judged fold's measurements do not
    choose its weight (an in-sample weight would make the stack's figure the lower envelope of the two by
    construction). Returns ``{"cv_mean_mm", "cv_rms_mm", "errors_mm" (n,), "pred_mm" (n, 3), "std_mm" (n, 3) (the
    band rule of :class:`StackedResidual` on the pipelines' stds ``s_a_mm``, ``s_b_mm``; None without them),
    "fold_weights" (k,)}``."""
    y, a, b = (np.asarray(v, float) for v in (y_mm, p_a_mm, p_b_mm))
    lab = np.asarray(labels)
    pred, sd, ws = np.empty_like(y), None if s_a_mm is None else np.empty_like(y), []
    for f in range(int(lab.max()) + 1):
        te, tr = lab == f, lab != f
        w = stack_weight(y[tr], a[tr], b[tr])[0]
        ws.append(w)
        pred[te] = w * a[te] + (1 - w) * b[te]
        if sd is not None:
            sd[te] = w * np.asarray(s_a_mm)[te] + (1 - w) * np.asarray(s_b_mm)[te]
    e = np.linalg.norm(y - pred, axis=1)
    return {"cv_mean_mm": float(e.mean()), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2))), "errors_mm": e,
            "pred_mm": pred, "std_mm": sd, "fold_weights": ws}


STACK_FORMAT = "volcomp-arm-stack/1"
STACK_BAND_RULE = ("per component, w·s_a + (1 − w)·s_b with s_a, s_b the two pipelines' band stds (each its stage's "
                   "rule: a GP's CV-calibrated latent std ⊕ its noise, a geometric stage's J Σ Jᵀ ⊕ its residual σ): the "
                   "largest std of w·e_a + (1 − w)·e_b whatever the correlation of the two pipelines' errors")
"""The band rule of the stacked stage (conservative: exact for perfectly correlated errors, wider otherwise)."""


class StackedResidual:
    """The stacked stage of an arm calibration: ``weight``·(pipeline a) + (1 − ``weight``)·(pipeline b), each
    pipeline ``(geometric, learner)`` — a :class:`errormap.arm_calibration.GeometricResult` and an
    :class:`ArmResidualRegressor` or None (``chosen_ == "none"`` counts as none).

    It is written as a residual over its PRIMARY pipeline's geometric stage (``primary``: a where
    ``weight`` ≥ 0.5, else b; :attr:`geometric`), so everything that takes a geometric stage and a learner takes
    it unchanged: the model's tool point is ``geometric.predict(q) + predict(q)``, its joint Jacobian
    ``geometric.chain.joint_jacobian(q) + predict_and_jacobian(q)[1]`` = w·J_a + (1 − w)·J_b (the Newton solver
    of :mod:`compensation.arm_compensation`). The tool ORIENTATION is the primary chain's (tracker points carry
    none; it is the fit's gauge choice). ``weight`` 1 (or 0) is pipeline a (b) bit for bit: the other pipeline is
    not evaluated. Band: :data:`STACK_BAND_RULE`."""

    chosen_ = "stacked"

    def __init__(self, weight: float, a, b, names=("a", "b")):
        w = float(weight)
        if not 0.0 <= w <= 1.0:
            raise ValueError(f"weight must be in [0, 1], got {weight}")
        self.weight, self.names = w, tuple(names)
        self.pipelines = tuple((g, None if (l is None or l.chosen_ == "none") else l) for g, l in (a, b))
        self.weights = (w, 1.0 - w)
        self.primary = 0 if w >= 0.5 else 1

    @property
    def geometric(self):
        """The primary pipeline's geometric stage (the chain the residual is written over)."""
        return self.pipelines[self.primary][0]

    def _other(self):
        o = 1 - self.primary
        return (self.weights[o], *self.pipelines[o]) if self.weights[o] > 0 else None

    def predict(self, q, return_std: bool = False):
        """Residual over :attr:`geometric` (n, 3) mm [and the band std (n, 3) of :data:`STACK_BAND_RULE`]."""
        q = np.atleast_2d(np.asarray(q, float))
        w_p, (g_p, l_p) = self.weights[self.primary], self.pipelines[self.primary]
        r = w_p * l_p.predict(q) if l_p is not None else np.zeros((len(q), 3))
        sd = w_p * pipeline_std_mm(g_p, l_p, q) if return_std else None
        other = self._other()
        if other is not None:
            w_o, g_o, l_o = other
            p_o = g_o.predict(q) if l_o is None else g_o.predict(q) + l_o.predict(q)
            r = r + w_o * (p_o - g_p.predict(q))
            if return_std:
                sd = sd + w_o * pipeline_std_mm(g_o, l_o, q)
        return (r, sd) if return_std else r

    def predict_and_jacobian(self, q):
        """(residual over :attr:`geometric` (n, 3) mm, its ∂/∂q (n, 3, nq) per joint unit): w_p·J_lp +
        w_o·(J_go + J_lo − J_gp), so that J_gp + this = w_a·J_a + (1 − w_a)·J_b."""
        q = np.atleast_2d(np.asarray(q, float))
        w_p, (g_p, l_p) = self.weights[self.primary], self.pipelines[self.primary]
        nq = q.shape[1]
        if l_p is not None:
            m, J = l_p.predict_and_jacobian(q)
            r, J = w_p * m, w_p * J
        else:
            r, J = np.zeros((len(q), 3)), np.zeros((len(q), 3, nq))
        other = self._other()
        if other is not None:
            w_o, g_o, l_o = other
            p_o, J_o = g_o.predict(q), g_o.chain.joint_jacobian(q, g_o.params)
            if l_o is not None:
                m, Jl = l_o.predict_and_jacobian(q)
                p_o, J_o = p_o + m, J_o + Jl
            r = r + w_o * (p_o - g_p.predict(q))
            J = J + w_o * (J_o - g_p.chain.joint_jacobian(q, g_p.params))
        return r, J

    def point(self, q) -> np.ndarray:
        """The blended tool point (n, 3) mm."""
        return self.geometric.predict(q) + self.predict(q)

    def to_dict(self) -> dict:
        return {"format": STACK_FORMAT, "weight": self.weight, "names": list(self.names), "band_rule": STACK_BAND_RULE,
                "pipelines": [{"name": n, "weight": w, "geometric": g.to_dict(),
                               "learned": None if l is None else l.to_dict()}
                              for n, w, (g, l) in zip(self.names, self.weights, self.pipelines)]}

    @classmethod
    def from_dict(cls, chain, d: dict) -> "StackedResidual":
        """The stage :meth:`to_dict` wrote, for ``chain`` (the machine's nominal chain); ValueError / KeyError on
        anything else."""
        from errormap.arm_calibration import GeometricResult
        if not isinstance(d, dict) or d.get("format") != STACK_FORMAT:
            raise ValueError(f"expected a stacked arm stage (format {STACK_FORMAT!r})")
        ps = d["pipelines"]
        if not isinstance(ps, list) or len(ps) != 2:
            raise ValueError("a stacked stage holds exactly two pipelines")
        pipes = [(GeometricResult.from_dict(chain, p["geometric"]),
                  None if p["learned"] is None else ArmResidualRegressor.from_dict(chain, p["learned"])) for p in ps]
        return cls(d["weight"], *pipes, names=[p["name"] for p in ps])


BAND_COVERAGE = 0.95
"""The coverage the band calibration asks of the 95 % band on every blocked inner CV (:func:`blocked_band_scale`)."""
BAND_COVERAGE_MAX_INTERLEAVED = 0.98
"""The most the scaled 95 % band may cover on the interleaved inner CV (the pipeline CV's out-of-fold predictions): a
wider band is no longer a 95 % band where the data are dense (the cap of :func:`blocked_band_scale`)."""
BAND_RULE_BLOCKED = ("the kept stage's band std (its own rule) times one factor c = max(1, min(c_blocked, c_cap)): "
                     "c_blocked the largest over the blockings of the fit poses (acquisition-order runs: time_s, else "
                     "file row order; equal-count sectors of the first joint) of q95(|measured − prediction| / std) / "
                     "1.96 over the components of that blocking's out-of-fold predictions (the pipeline refitted per "
                     "block, its GP re-estimated), so that the 95 % band holds 95 % on every blocked inner CV; c_cap "
                     "the factor at which it would hold 98 % on the interleaved inner CV (none where that CV was not "
                     "run): never wider than that where the data are dense, never narrower than the stage's own "
                     "interleaved calibration")
"""The blocked band rule of the arm calibration's kept stage (``model.json`` ``calibration.band_calibration.rule``)."""


def band_z(y_mm, pred_mm, std_mm) -> np.ndarray:
    """|y − pred| / std per component (n, 3) of ``y_mm`` − ``pred_mm`` in units of the band std ``std_mm`` (all (n, 3)
    mm; a zero std counts as 1e-300 mm)."""
    return np.abs(np.asarray(y_mm, float) - pred_mm) / np.maximum(np.asarray(std_mm, float), 1e-300)


def coverage_before_after(z, c: float) -> tuple[float, float]:
    """(the share of the components ``z`` (:func:`band_z`) inside the 95 % band, the same inside the band times ``c``)."""
    from .residual import Z95
    return float(np.mean(z <= Z95)), float(np.mean(z <= Z95 * c))


def band_factor(y_mm, pred_mm, std_mm, coverage: float = BAND_COVERAGE) -> float:
    """The factor c on ``std_mm`` that makes the band ±1.96·c·std hold ``coverage`` of the components of ``y_mm`` −
    ``pred_mm`` (all (n, 3) mm): the ``coverage`` quantile of |y − pred| / std over the components, over 1.96."""
    from .residual import Z95
    return float(np.quantile(band_z(y_mm, pred_mm, std_mm).ravel(), coverage) / Z95)


def combine_band_factors(factors, cap=None) -> tuple[float, float]:
    """(c_blocked, c) of :data:`BAND_RULE_BLOCKED`: c_blocked = max(1, ``factors``), c = max(1, min(c_blocked, ``cap``))
    (``cap`` None: c = c_blocked)."""
    c_blocked = max([1.0] + [float(f) for f in factors])
    return c_blocked, (c_blocked if cap is None else max(1.0, min(c_blocked, float(cap))))


def blocked_band_scale(chain, poses, pipes: dict, blockings: dict, k_folds: int, seed, stacked=None,
                       cap=None, beside=None) -> dict:
    """The band factor of the kept stage from BLOCKED inner CVs (:data:`BAND_RULE_BLOCKED`).

    ``pipes``: the kept stage's pipeline(s), name → ``(model, learner)`` as :func:`cv_pipelines` takes them (one, or
    the two of a stack); ``stacked``: None, or ``(name_a, name_b)``, the stack's pipelines (its weight per block chosen
    on the other blocks, :func:`stack_cv`). ``blockings``: name → block labels (n,) of ``poses``
    (:func:`errormap.arm_calibration.content_blocks`). Per blocking the pipelines are refitted on each block's
    complement (geometric stage refitted, GP re-estimated: ``hyper="fold"``) and predict the block; the factor of that
    blocking is :func:`band_factor` of those out-of-fold predictions and band stds; c_blocked the largest (at least 1).
    ``cap``: None, or the factor at which the band would hold :data:`BAND_COVERAGE_MAX_INTERLEAVED` on the interleaved
    CV; then c = max(1, min(c_blocked, cap)). Returns ``{"factor": c, "factor_blocked", "cap_interleaved", "rule",
    "blockings": {name: {"n_blocks", "factor", "coverage95_before", "coverage95_after", "cv_mean_mm"}}}`` — before:
    the stage's band as it was (its interleaved-CV calibration), after: times c. ``beside``: further pipelines
    (name → ``(model, learner)``) cross-validated on the same blocks (a geometric stage shared with the kept one is
    fitted once per block); their mean errors are ``beside_cv_mean_mm`` per blocking."""
    out = {}
    y = poses.xyz_mm
    beside = dict(beside or {})
    for name, lab in blockings.items():
        cv = cv_pipelines(chain, poses, {**pipes, **beside}, k_folds, seed, groups=lab, fold_fits={})
        extra = {k: cv.pop(k)["cv_mean_mm"] for k in beside}
        if stacked is not None:
            from errormap.arm_calibration import cv_labels
            a, b = cv[stacked[0]], cv[stacked[1]]
            r = stack_cv(y, a["pred_mm"], b["pred_mm"], cv_labels(len(poses), k_folds, seed, lab), a["std_mm"],
                         b["std_mm"])
        else:
            r = next(iter(cv.values()))
        out[name] = {"n_blocks": int(min(k_folds, len(np.unique(lab)))),
                     "factor": band_factor(y, r["pred_mm"], r["std_mm"]), "cv_mean_mm": r["cv_mean_mm"],
                     "_z": band_z(y, r["pred_mm"], r["std_mm"])}
        if beside:
            out[name]["beside_cv_mean_mm"] = extra
    c_blocked, c = combine_band_factors([v["factor"] for v in out.values()], cap)
    for v in out.values():
        v["coverage95_before"], v["coverage95_after"] = coverage_before_after(v.pop("_z"), c)
    return {"factor": c, "factor_blocked": c_blocked, "cap_interleaved": None if cap is None else float(cap),
            "rule": BAND_RULE_BLOCKED, "blockings": out}
