"""A learned residual: what a physical model leaves at measured points, learned, or declined.

:class:`ResidualRegressor` learns a smooth field ``Y(X)`` (``X`` (n, d) inputs, ``Y`` (n, 3) the measured
residual of a physical model, e.g. μm), safe as an *addition* to that model: every family is zero-mean (it
predicts zero away from its data, never extrapolating a fit); each is cross-validated against predicting zero
(blocked folds with ``groups``, else shuffled k-fold) and one is kept only if its mean paired gain exceeds
``margin_se`` standard errors (else ``chosen_ = "none"`` and :meth:`ResidualRegressor.predict` returns zeros);
:meth:`ResidualRegressor.predict_and_jacobian` gives dY/dX in closed form. Families: :data:`FAMILIES`, each
described in :data:`FAMILY_NAMES` (Gaussian processes of several kernels, :class:`training.ensemble.MLPEnsemble`,
a basis); their bands are calibrated on the held-out folds (``band_scale_``). JSON-able (:meth:`ResidualRegressor.to_dict` /
:meth:`ResidualRegressor.from_dict`, :data:`FORMAT`): a saved regressor predicts bit-for-bit like the fitted one.
The rule and its options: docs/reference/learned-stage.md ("The learned residual").
"""
from __future__ import annotations

import numpy as np

from errormap.seeds import spawn_rngs
from errormap.threads import limit_threads

from .gp import GP_KERNELS, _GP, check_input_groups

__all__ = ["ResidualRegressor", "FAMILIES", "FORMAT", "check_residual_data"]

FORMAT = "volcomp-residual-regressor/1"
"""The ``format`` key of :meth:`ResidualRegressor.to_dict`."""

FAMILIES = ("gp", "ensemble", "gp_matern52", "gp_matern32", "gp_sum", "gp_additive", "basis")
"""The regressor families :class:`ResidualRegressor` can cross-validate."""

FAMILY_NAMES = {"gp": "Gaussian process (zero mean, ARD squared-exponential kernel + white noise, per output)",
                "gp_matern52": "Gaussian process (zero mean, ARD Matérn 5/2 kernel + white noise, per output)",
                "gp_matern32": "Gaussian process (zero mean, ARD Matérn 3/2 kernel + white noise, per output)",
                "gp_sum": ("Gaussian process (zero mean, sum of a long- and a short-length-scale ARD "
                           "squared-exponential kernel + white noise, per output)"),
                "gp_additive": ("Gaussian process (zero mean, additive kernel: squared exponentials on each input group and "
                                "each pair of groups, one variance per term + white noise, per output)"),
                "basis": ("Bayesian regression on a tensor-product basis (Legendre in each linear input × Fourier in each "
                          "rotary one, total degree ≤ 6, prior variance decaying with degree, by marginal likelihood)"),
                "ensemble": "deep ensemble (5 tanh MLPs 2×16, weight decay; mean and spread)",
                "none": "none (the physical model alone)"}
"""What each family is, in words (diagnosis.json / model.json / the report name the chosen one)."""

Z95 = 1.959963984540054
"""Two-sided 95 % normal quantile: the band of ``cv_table_``'s coverage."""

MAX_TRAIN_POINTS = 4000
"""A GP's cost grows as n³; beyond this many training points refuse rather than stall."""


def check_residual_data(X, Y=None, groups=None):
    """Validate ``X`` (n, d) finite, ``Y`` (n, 3) finite, ``groups`` (n,) → float arrays (+ groups).

    Raises ValueError naming what is wrong (shape, non-finite entries)."""
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[0] < 1 or X.shape[1] < 1:
        raise ValueError(f"Expected X of shape (n, d), got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"Expected finite X, got non-finite values in row(s) "
                         f"{np.flatnonzero(~np.all(np.isfinite(X), axis=1))[:5].tolist()}")
    if Y is None:
        return X
    Y = np.asarray(Y, dtype=float)
    if Y.shape != (X.shape[0], 3):
        raise ValueError(f"Expected Y of shape ({X.shape[0]}, 3), got {Y.shape}")
    if not np.all(np.isfinite(Y)):
        raise ValueError("Expected finite Y")
    if groups is not None:
        groups = np.asarray(groups)
        if groups.shape != (X.shape[0],):
            raise ValueError(f"Expected groups of shape ({X.shape[0]},), got {groups.shape}")
    return X, Y, groups


# ---------------------------------------------------------------- the Gaussian process family

class ResidualRegressor:
    """Learn a physical model's measured residual, or decline to (module doc).

    Parameters
    ----------
    families : tuple of str from :data:`FAMILIES`
        The candidates cross-validated against predicting zero.
    n_splits : int ≥ 2
        CV folds (with ``groups``: at most one fold per distinct group).
    seed : int or SeedSequence
        Fold shuffling and the hyper-parameter restarts.
    margin_se : float ≥ 0
        A family must beat zero by more than this many paired standard errors of its mean CV gain.
    n_restarts : int ≥ 1
        Marginal-likelihood starts per output (the first from unit length scales).
    input_groups : None or sequence of sequences of column indices
        The inputs that belong together (one physical axis, e.g. the cos and sin of a rotary
        axis): the terms of the ``gp_additive`` family (:func:`training.gp.additive_terms`); a partition of
        the columns, checked at :meth:`fit`. None: each column its own group. The other families
        ignore it.
    progress : None or callable
        Called with each family's name once its cross-validation is done (a progress bar's hook;
        not part of the fitted state).

    Attributes after :meth:`fit`
    ----------------------------
    chosen_ : str — the family used, or ``"none"``;
    cv_table_ : dict — per family and ``"zero"``: ``cv_rms`` (RMS of the held-out vector
        residual norm), ``cv_rms_se`` (its standard error, delta method), ``gain_mean`` /
        ``gain_se`` (mean paired drop of the squared norm against zero, and its standard error),
        ``coverage_95`` (fraction of held-out components within the family's 95 % band, latent
        std and fitted noise together), ``n`` (held-out points);
    cv_held_idx_ : (n,) int — the CV's held-out points in the order of ``cv_sq_err_`` (every point once);
    cv_sq_err_ : dict — per family and ``"zero"``: (n,) held-out squared error norm of each point
        (for paired comparisons between fits on the same folds; not saved by :meth:`to_dict`);
    noise_std_ : (3,) fitted measurement noise of the chosen family (zeros for ``"none"``), times
        ``band_scale_``;
    band_scale_ : float — the band calibration from the cross-validation: the factor that makes the
        CV's 95 % band (latent std and noise together) hold 95 % of the held-out components
        (``cv_table_[family]["band_scale"]``); the std :meth:`predict` returns is multiplied by it.
    """

    def __init__(self, families=("gp",), n_splits: int = 5, seed=0, margin_se: float = 1.0, n_restarts: int = 1,
                 input_groups=None, progress=None):
        self.families = families
        self.n_splits = n_splits
        self.seed = seed
        self.margin_se = margin_se
        self.n_restarts = n_restarts
        self.input_groups = input_groups
        self.progress = progress

    # -- validation
    def _check_settings(self):
        fams = tuple(self.families)
        bad = [f for f in fams if f not in FAMILIES]
        if not fams or bad:
            raise ValueError(f"Expected families from {list(FAMILIES)}, got {list(fams)}")
        if int(self.n_splits) != self.n_splits or self.n_splits < 2:
            raise ValueError(f"Expected n_splits an integer ≥ 2, got {self.n_splits}")
        if not (np.isfinite(self.margin_se) and self.margin_se >= 0):
            raise ValueError(f"Expected margin_se ≥ 0, got {self.margin_se}")
        if int(self.n_restarts) != self.n_restarts or self.n_restarts < 1:
            raise ValueError(f"Expected n_restarts an integer ≥ 1, got {self.n_restarts}")
        return fams

    def _folds(self, n, groups, rng):
        """List of held-out index arrays."""
        if groups is None:
            perm = rng.permutation(n)
            return [np.sort(f) for f in np.array_split(perm, min(self.n_splits, n))]
        _, first, inv = np.unique(groups, return_index=True, return_inverse=True)
        order = np.argsort(first)                 # groups in order of first appearance
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        g_rank = rank[inv]
        k = min(self.n_splits, len(order))
        if k < 2:
            raise ValueError("Expected at least 2 distinct groups for blocked cross-validation")
        bounds = np.array_split(np.arange(len(order)), k)
        return [np.flatnonzero(np.isin(g_rank, b)) for b in bounds]

    def _groups(self):
        """The checked input groups as lists (None when not set)."""
        if self.input_groups is None:
            return None
        return [list(g) for g in check_input_groups(self.input_groups, self.n_features_in_)]

    def _new(self, family, rng):
        if family in GP_KERNELS:
            return _GP(self.n_restarts, rng, GP_KERNELS[family], self._groups())
        if family == "ensemble":
            from .ensemble import MLPEnsemble
            return MLPEnsemble(seed=int(rng.integers(0, 2**63 - 1)))
        if family == "basis":
            from .basis import BasisRegression
            return BasisRegression(groups=self._groups())
        raise ValueError(family)

    # -- fit
    def fit(self, X, Y, groups=None):
        """Cross-validate every family against zero, keep the winner (or none), refit it on all
        data. ``X`` (n, d), ``Y`` (n, 3), ``groups`` (n,) block labels or None → self.

        Runs on one BLAS thread (:func:`errormap.threads.limit_threads`): the matrices are a few
        hundred wide, and several threads spin against each other on a busy machine (measured:
        one marginal-likelihood evaluation at n = 400 took 0.89 s CPU on the default threads of a
        loaded 2-core machine, 6 ms on one)."""
        with limit_threads(1, ("blas",)):
            return self._fit(X, Y, groups)._fit_chosen()

    def cross_validate(self, X, Y, groups=None):
        """:meth:`fit` up to the choice: the cross-validation, ``chosen_`` and the standardisation, the chosen family
        not yet fitted on all data (``model_`` None) → self; :meth:`fit_chosen` then completes it into :meth:`fit`'s
        result, bit for bit. For a choice among several candidates of which one is kept: only its final fit runs."""
        with limit_threads(1, ("blas",)):
            return self._fit(X, Y, groups)

    def fit_chosen(self):
        """The chosen family fitted on all the data :meth:`cross_validate` had (with the generator it drew for
        this) → self, as :meth:`fit` leaves it; once: a regressor so fitted already is returned as it is."""
        if "_final" not in vars(self):
            if not hasattr(self, "chosen_"):
                raise RuntimeError("fit_chosen before cross_validate: nothing chosen to fit")
            return self
        with limit_threads(1, ("blas",)):
            return self._fit_chosen()

    def _fit(self, X, Y, groups):
        fams = self._check_settings()
        X, Y, groups = check_residual_data(X, Y, groups)
        n, d = X.shape
        if n > MAX_TRAIN_POINTS:
            raise ValueError(f"Expected at most {MAX_TRAIN_POINTS} training points, got {n}")
        if n < 2 * self.n_splits:
            raise ValueError(f"Expected at least {2 * self.n_splits} points for {self.n_splits}-fold CV, got {n}")
        rng_folds, rng_cv, rng_final = spawn_rngs(self.seed, 3)
        self.n_features_in_ = d
        self._groups()   # ValueError now, before any fit, unless the input groups partition the d columns
        self.x_mean_ = X.mean(0)
        sd = X.std(0)
        self.x_scale_ = np.where(sd > 0, sd, 1.0)
        self.y_scale_ = float(np.sqrt(np.mean(Y * Y))) or 1.0
        Xs, Ys = (X - self.x_mean_) / self.x_scale_, Y / self.y_scale_
        folds = self._folds(n, groups, rng_folds)
        held = np.concatenate(folds)
        e_zero = (Y[held] ** 2).sum(1)
        table = {"zero": self._row(e_zero, e_zero, None)}
        cv_err = {"zero": e_zero}
        for fam in fams:
            pred = np.empty((n, 3))
            band = np.empty((n, 3))
            for hold in folds:
                fit = np.setdiff1d(np.arange(n), hold)
                # standardisation of the fit folds only, so nothing of the held-out fold leaks in
                mu, s = X[fit].mean(0), X[fit].std(0)
                s = np.where(s > 0, s, 1.0)
                ys = float(np.sqrt(np.mean(Y[fit] ** 2))) or 1.0
                m = self._new(fam, rng_cv).fit((X[fit] - mu) / s, Y[fit] / ys)
                mean, std = m.predict((X[hold] - mu) / s, return_std=True)
                pred[hold] = mean * ys
                band[hold] = Z95 * np.sqrt(std ** 2 + m.noise_var()[None, :]) * ys
            e_fam = ((Y[held] - pred[held]) ** 2).sum(1)
            cover = float(np.mean(np.abs(Y[held] - pred[held]) <= band[held]))
            table[fam] = self._row(e_fam, e_zero, cover)
            cv_err[fam] = e_fam
            # band calibration: the factor that makes the CV's 95 % band hold 95 % of the held-out components
            zs = np.abs(Y[held] - pred[held]) / np.maximum(band[held] / Z95, 1e-300)
            table[fam]["band_scale"] = float(np.quantile(zs, 0.95) / Z95)
            if self.progress is not None:
                self.progress(fam)
        eligible = [f for f in fams if table[f]["gain_mean"] > self.margin_se * table[f]["gain_se"]
                    and table[f]["gain_mean"] > 0]
        self.cv_table_ = table
        self.cv_held_idx_ = held
        self.cv_sq_err_ = cv_err
        self.chosen_ = min(eligible, key=lambda f: table[f]["cv_rms"]) if eligible else "none"
        self.model_ = None
        self.noise_std_ = np.zeros(3)
        self.band_scale_ = 1.0
        self._final = (Xs, Ys, rng_final)   # what _fit_chosen fits on (rng_final: its own stream, drawn here)
        return self

    def _fit_chosen(self):
        """The final fit of :meth:`_fit`'s choice on its standardised data (the ``_final`` it left) → self."""
        Xs, Ys, rng_final = self.__dict__.pop("_final")
        if self.chosen_ != "none":
            self.model_ = self._new(self.chosen_, rng_final).fit(Xs, Ys)
            self.band_scale_ = self.cv_table_[self.chosen_]["band_scale"]
            self.noise_std_ = np.sqrt(self.model_.noise_var()) * self.y_scale_ * self.band_scale_
        return self

    @staticmethod
    def _row(e, e_zero, coverage):
        n = len(e)
        rms = float(np.sqrt(e.mean()))
        se_ms = float(e.std(ddof=1) / np.sqrt(n)) if n > 1 else float("inf")
        gain = e_zero - e
        return {"cv_rms": rms, "cv_rms_se": se_ms / (2 * rms) if rms > 0 else 0.0,
                "gain_mean": float(gain.mean()),
                "gain_se": float(gain.std(ddof=1) / np.sqrt(n)) if n > 1 else float("inf"),
                "coverage_95": coverage, "n": int(n)}

    # -- predict
    def _check_fitted(self, X):
        if not hasattr(self, "chosen_"):
            raise RuntimeError("ResidualRegressor is not fitted")
        X = check_residual_data(X)
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"Expected X with {self.n_features_in_} columns, got {X.shape[1]}")
        return X

    def predict(self, X, return_std=False):
        """``X`` (m, d) → learned residual (m, 3) [, latent std (m, 3)] in Y's units.

        ``"none"`` → zeros (and zero std: nothing learned, nothing added)."""
        X = self._check_fitted(X)
        m = len(X)
        if self.model_ is None:
            z = np.zeros((m, 3))
            return (z, z.copy()) if return_std else z
        with limit_threads(1, ("blas",)):
            out = self.model_.predict((X - self.x_mean_) / self.x_scale_, return_std=return_std)
        if return_std:
            return out[0] * self.y_scale_, out[1] * self.y_scale_ * self.band_scale_
        return out * self.y_scale_

    def predict_and_jacobian(self, X):
        """``X`` (m, d) → (value (m, 3), dvalue/dX (m, 3, d)), closed form."""
        X = self._check_fitted(X)
        m, d = X.shape
        if self.model_ is None:
            return np.zeros((m, 3)), np.zeros((m, 3, d))
        with limit_threads(1, ("blas",)):
            mean, jac = self.model_.predict((X - self.x_mean_) / self.x_scale_, jacobian=True)
        return mean * self.y_scale_, jac * (self.y_scale_ / self.x_scale_)[None, None, :]

    def with_data(self, X, Y) -> "ResidualRegressor":
        """A copy conditioned on (``X`` (m, d), ``Y`` (m, 3)) with this fit's chosen family,
        hyper-parameters and standardisation kept (no new selection): e.g. hyper-parameters
        chosen on a fitting part, weights re-solved on all data. ``"none"`` stays none."""
        import copy
        X = self._check_fitted(X)
        X, Y, _ = check_residual_data(X, Y)
        out = copy.copy(self)
        if isinstance(self.model_, _GP):
            out.model_ = _GP(1, None, self.model_.kernel, self.model_.groups).set_state((X - self.x_mean_) / self.x_scale_,
                                                                    Y / self.y_scale_, self.model_.theta_)
        elif self.chosen_ == "basis":   # its hyper-parameters kept, the posterior re-solved
            from .basis import BasisRegression
            out.model_ = BasisRegression(self.model_.groups, self.model_.degree).set_state(
                (X - self.x_mean_) / self.x_scale_, Y / self.y_scale_, self.model_.theta_)
        elif self.model_ is not None:   # an ensemble has no hyper-parameters fitted: its members are retrained
            from .ensemble import MLPEnsemble
            m = self.model_
            with limit_threads(1, ("blas",)):
                out.model_ = MLPEnsemble(seed=int(spawn_rngs(self.seed, 5)[4].integers(0, 2**63 - 1)), n_members=m.n_members,
                                         hidden=m.hidden, weight_decay=m.weight_decay, max_iter=m.max_iter).fit(
                    (X - self.x_mean_) / self.x_scale_, Y / self.y_scale_)
        return out

    def refit(self, X, Y, seed=None, family=None) -> "ResidualRegressor":
        """A copy with the CHOSEN family re-estimated on (``X`` (m, d), ``Y`` (m, 3)): the
        standardisation and the hyper-parameters (maximum marginal likelihood, as in :meth:`fit`)
        from these data, no new selection — the validation chose the family and whether to keep
        it; this is the chosen model estimated on all the data. The band calibration
        (``band_scale_``) and ``cv_table_`` stay the cross-validation's (they are what was
        validated). ``"none"`` stays none. ``seed``: the restarts' seed (default: this fit's).
        ``family``: re-estimate this cross-validated family instead of the chosen one (default: the chosen one;
        for comparing the candidates on other data; its CV band calibration is used)."""
        import copy
        X = self._check_fitted(X)
        X, Y, _ = check_residual_data(X, Y)
        out = copy.copy(self)
        if family is not None:
            if family not in self.cv_table_ or family == "zero":
                raise ValueError(f"Expected a cross-validated family of {sorted(self.cv_table_)}, got {family!r}")
            out.chosen_, out.band_scale_ = family, self.cv_table_[family]["band_scale"]
        elif self.model_ is None:
            return out
        with limit_threads(1, ("blas",)):
            out.x_mean_ = X.mean(0)
            sd = X.std(0)
            out.x_scale_ = np.where(sd > 0, sd, 1.0)
            out.y_scale_ = float(np.sqrt(np.mean(Y * Y))) or 1.0
            rng = spawn_rngs(self.seed if seed is None else seed, 4)[3]
            Xs, Ys = (X - out.x_mean_) / out.x_scale_, Y / out.y_scale_
            new = self._new(out.chosen_, rng)
            if isinstance(new, _GP):
                theta = new.hyperparameters(Xs, Ys)
            else:
                out.model_ = new.fit(Xs, Ys)
        if isinstance(new, _GP):   # the weights solved once, as from_dict solves them (same BLAS threads):
            out.model_ = _GP(1, None, new.kernel, new.groups).set_state(Xs, Ys, theta)   # shipped == reloaded
        out.noise_std_ = np.sqrt(out.model_.noise_var()) * out.y_scale_ * out.band_scale_
        return out

    # -- persistence
    def to_dict(self) -> dict:
        """JSON-able state (format :data:`FORMAT`)."""
        if not hasattr(self, "chosen_"):
            raise RuntimeError("ResidualRegressor is not fitted")
        out = {"format": FORMAT,
               "settings": {"families": list(self.families), "n_splits": int(self.n_splits),
                            "margin_se": float(self.margin_se), "n_restarts": int(self.n_restarts),
                            "seed": self.seed if isinstance(self.seed, int) else None},
               "chosen": self.chosen_, "cv_table": self.cv_table_,
               "n_features_in": int(self.n_features_in_),
               "x_mean": self.x_mean_.tolist(), "x_scale": self.x_scale_.tolist(), "y_scale": self.y_scale_,
               "noise_std": self.noise_std_.tolist(), "band_scale": float(self.band_scale_)}
        if isinstance(self.model_, _GP):
            out["gp"] = {"theta": self.model_.theta_.tolist(), "X": self.model_.X_.tolist(),
                         "Y": self.model_.Y_.tolist(), "kernel": self.model_.kernel}
            if self.model_.kernel == "additive":   # its terms follow from the groups (None: one per input)
                out["gp"]["groups"] = self.model_.groups
        elif self.chosen_ == "basis":
            out["basis"] = self.model_.state()
        elif self.model_ is not None:
            out["ensemble"] = self.model_.state()
        if self.input_groups is not None:
            out["settings"]["input_groups"] = self._groups()
        return out

    @classmethod
    def from_dict(cls, doc: dict) -> "ResidualRegressor":
        """The regressor :meth:`to_dict` wrote; ValueError on anything else."""
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise ValueError(f"Expected a residual regressor (format {FORMAT!r})")
        try:
            st = doc["settings"]
            self = cls(families=tuple(st["families"]), n_splits=st["n_splits"],
                       seed=st["seed"] if st["seed"] is not None else 0,
                       margin_se=st["margin_se"], n_restarts=st["n_restarts"],
                       input_groups=st.get("input_groups"))
            self._check_settings()
            self.chosen_ = str(doc["chosen"])
            self.cv_table_ = doc["cv_table"]
            self.n_features_in_ = int(doc["n_features_in"])
            self._groups()   # ValueError unless the saved input groups partition the columns
            self.x_mean_ = np.asarray(doc["x_mean"], dtype=float)
            self.x_scale_ = np.asarray(doc["x_scale"], dtype=float)
            self.y_scale_ = float(doc["y_scale"])
            self.noise_std_ = np.asarray(doc["noise_std"], dtype=float)
            self.band_scale_ = float(doc["band_scale"])
            self.model_ = None
            if self.chosen_ in GP_KERNELS:
                g = doc["gp"]
                if g.get("kernel", "rbf") != GP_KERNELS[self.chosen_]:   # files before the kernels: rbf
                    raise ValueError(f"Expected the kernel {GP_KERNELS[self.chosen_]!r} of family {self.chosen_!r}, "
                                     f"got {g.get('kernel', 'rbf')!r}")
                groups = g.get("groups") if self.chosen_ == "gp_additive" else None
                if groups is not None:
                    groups = [list(x) for x in check_input_groups(groups, self.n_features_in_)]
                self.model_ = _GP(1, None, GP_KERNELS[self.chosen_], groups).set_state(np.asarray(g["X"], dtype=float), np.asarray(g["Y"], dtype=float),
                                                     np.asarray(g["theta"], dtype=float))
            elif self.chosen_ == "basis":
                from .basis import BasisRegression
                self.model_ = BasisRegression.from_state(doc["basis"])
                if (self.model_.X_.shape[1], self.model_.Y_.shape[1]) != (self.n_features_in_, 3):
                    raise ValueError("Expected a basis regression of n_features_in inputs and 3 outputs")
            elif self.chosen_ == "ensemble":
                from .ensemble import MLPEnsemble
                self.model_ = MLPEnsemble.from_state(doc["ensemble"])
                if (self.model_.d_, self.model_.k_) != (self.n_features_in_, 3):
                    raise ValueError("Expected an ensemble of n_features_in inputs and 3 outputs")
            elif self.chosen_ != "none":
                raise ValueError(f"unknown family {self.chosen_!r}")
        except (KeyError, TypeError) as exc:
            raise ValueError(f"Expected a complete residual regressor, missing or bad {exc}") from exc
        if self.x_mean_.shape != (self.n_features_in_,) or self.x_scale_.shape != (self.n_features_in_,):
            raise ValueError("Expected x_mean and x_scale of n_features_in values")
        return self
