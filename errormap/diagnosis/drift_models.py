"""Causal drift models chosen on held-out time, and their controller form (``volcomp.drift_model`` v1).

Every model here is a linear combination of **features**; a feature is one logged input
(``temp_<sensor>_c`` or ``speed_rpm``), optionally raised to a power, passed through a first-order
lag of time constant ``tau_s`` and delayed by ``delay_s``::

    v[k] = u[k] ** power
    y[0] = v[0];  y[k] = y[k-1] + (1 − exp(−(t[k] − t[k-1]) / tau_s)) · (v[k] − y[k-1])   (tau_s = 0: y = v)
    f(t) = y(t − delay_s)   (linear interpolation between logged samples; before the first: y[0])

    prediction_um(t) = intercept_um + Σ_j coef_j · f_j(t)

The filter is the exact response of ``tau·dy/dt = v − y`` to an input that holds ``v[k]`` over
``(t[k-1], t[k]]`` (each sample acts at once, no added half-step delay), so uneven sampling is handled; the prediction at ``t`` uses samples at or before ``t`` only (causal).

Model families (per displacement channel; :class:`DriftSelector`):

* ``ols`` — the baseline: ordinary least squares on every temperature and ``speed_rpm`` as logged
  (no filter, no delay). Always a candidate, always reported.
* ``subset_lag`` — :class:`~errormap.diagnosis.drift.DriftModeller`'s sensor-subset + common-lag
  search (BIC), its selected regressors refitted causally (first-order smoothing of ``smooth_s``/2
  in place of its centred window, then the lag).
* ``ridge_bank`` — ridge on every input through a bank of first-order filters (``TAU_BANK_S``:
  a distributed lag whose weights are one time constant per sensor or any mix of them); the
  penalty λ is a hyper-parameter chosen by the same cross-validation.
* ``pls_bank`` — partial least squares on the same bank; the number of components is chosen by
  cross-validation.
* ``transfer`` — a physically motivated transfer-function model: the spindle as heat source
  (``speed_rpm`` and ``speed_rpm²``, heat ∝ speed^1…2) through two first-order paths whose time
  constants are fitted (grid of ``TAU_GRID_S`` pairs), plus every temperature as logged, ridge-
  stabilised.

Selection (issue 29 added novelty folds, shrinkage toward OLS and three constrained families from
the section below; :class:`DriftSelector` states the rule):
**cross-validation on the fitting part only**, three fold sets. The *ranking folds* (train on the first ``cv_start`` of the fitting part, validate on the next
block, grow, repeat; ``n_folds`` blocks) score every candidate by the RMS over all their validation
rows. The *horizon folds* (:func:`horizon_folds`) validate on blocks as long, relative to their
training, as the deployment's held-out part is to the fitting part. The chosen candidate is the
best-ranked one that beats OLS on the horizon folds by more than one standard error of the
fold-to-fold scatter (:func:`horizon_gate`); if none does, OLS. It is refitted on the whole fitting
part. The returned model therefore never loses to OLS in validation; the report gives both. The 95 %
band is the 95th percentile of the chosen candidate's |validation residual| on the horizon and novelty
folds, grown at prediction by max(1, ρ) with the distance ρ of the inputs from the fit data
(:meth:`DriftModel.band_um`); beyond ρ = 1 a channel's prediction shrinks toward its OLS baseline per
sample (:meth:`DriftModel.predict`, :func:`distance_weight`).

``ridge_ols`` / ``pls_ols`` (:class:`RidgeTowardOLSFamily`, :class:`PLSTowardOLSFamily`): the filter
bank fitted to the OLS baseline's residual, so that the penalty (ridge λ, or fewer PLS components)
pulls toward the baseline rather than toward zero; the largest λ is the baseline itself. They replace
``ridge_bank`` / ``pls_bank`` among the default families (:func:`default_families`): on development
seeds 100–109 (both simulators, both splits, 180 cases) the swap raised the held-out wins over OLS
from 113 to 146 at the same 14 losses and cut the worst loss from 1.97× to 1.33×
(``benchmarks/drift_rule_dev.md``). ``ridge_bank`` / ``pls_bank`` stay available.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.optimize import nnls

from ..estimators import Estimator
from ..io import InputError, read_document_text
from .drift import DriftLog, DriftModeller

SCHEMA = "volcomp.drift_model"
SCHEMA_VERSION = 1
TAU_BANK_S = (0.0, 900.0, 3600.0, 10800.0)       # 15 min, 1 h, 3 h: spans the 0.5–5 h of machine bodies
TAU_GRID_S = (300.0, 900.0, 1800.0, 3600.0, 7200.0, 14400.0, 28800.0)
RIDGE_LAMBDAS = (1e-5, 1e-4, 1e-3, 1e-2, 1e-1)   # λ·n added to the standardised Gram matrix
GATE_SE = 1.0    # one-standard-error rule: a candidate must beat OLS over the deployment horizon by > 1 SE of the folds
MAX_FOLD_LOSS = 1.05   # and lose to OLS by no more than 5 % on ANY horizon or novelty fold (the bound, per fold)
MIN_GAIN = float(np.log(1.05))   # and be better than OLS by at least 5 % on average (mean log-gain) on the horizon and
                                 # on the novelty folds: an advantage smaller than the tolerated loss is not worth its risk
RIDGE_OLS_LAMBDAS = (1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)   # toward OLS: the large end is the baseline
PLS_MAX_COMPONENTS = 12
TRANSFER_LAMBDA = 1e-4
BAND_QUANTILE = 0.95
BAND_RULE = "fold_residual"   # band95_um = the split-conformal BAND_QUANTILE of |residual| on the horizon and novelty
#   folds (times max(1, ρ) at prediction: conservative). "rho_scaled": of |residual| / max(1, ρ_fold) — calibrated to
#   cover BAND_QUANTILE of the fold rows exactly, but measured to cover 1–90 % of the real log's pseudo-futures
#   (the future's errors outgrow the folds'); both are computed and reported (``band_alt_``), one is the model's
SUBSET_SEARCH_STEP_S = 60.0                      # the subset search runs on rows ≥ 60 s apart
SHRINK_WEIGHTS = (1.0, 0.875, 0.75, 0.625, 0.5, 0.375, 0.25, 0.125)   # candidate weight w in a blend
#   w·candidate + (1 − w)·OLS (w = 0: OLS itself, the fallback). Steps of 1/8 since issue 29's fourth round, decided
#   by a rule written before the figures (docs/drift_model.md) on development seeds 100–104 and inside the real log's
#   fitting parts against the earlier grid SHRINK_WEIGHTS_COARSE: 5 → 4 cases above 1.05× OLS of 45 (worst 3.05× →
#   2.12×), geometric-mean ratio 0.818 → 0.796, no regime change 1 → 1 (1.55× → 1.18×); real fitting parts 0 above /
#   6 below either way, but one case's gain smaller (ch1 at 38.4 %: 0.37× → 0.72× OLS)
SHRINK_WEIGHTS_COARSE = (1.0, 0.75, 0.5, 0.25)   # the grid before issue 29's fourth round (a setting)
HEDGE_WEIGHT = 1.0   # a weight above HEDGE_WEIGHT only where every fold's RMS ratio to OLS is ≤ CONFIDENT_WORST_FOLD;
CONFIDENT_WORST_FOLD = 0.5   # 1.0: no hedge (the default). The hedge (0.5: at most half a candidate unless it beat
#   OLS by 2× on every fold: the blend's error is at most the mean of the two) with SELECTION = "worst_fold" was
#   decided on development seeds 100–104 (both simulators, regime change; 45 channel cases;
#   benchmarks/drift_dev_results.md): 4 → 1 case above 1.05× (worst 3.05× → 1.051×), 32 → 35 below OLS. It is NOT
#   the default: on the real machine-tool log (fit 0–48 %, judged on 48–60 %) it turned ch1 from 0.41× OLS
#   (thermal_nn at full weight, worst fold 0.94×) into 1.15× (transfer~ols(w=0.5): the eligible worst folds were
#   0.87–0.98×, too close to rank by, and the transfer model extrapolated furthest) and ch2 from 0.35× into 0.67×
SELECTION = "mean_gain"   # among the eligible, the candidate of largest mean log-gain over OLS; "worst_fold": the one
#   whose WORST validation fold (ranking, horizon, novelty: RMS ratio to OLS) is best (development seeds as above:
#   4 → 2 cases above 1.05× alone, 1 with the hedge; not the default for the real log's sake, see HEDGE_WEIGHT)
FEATURE_DISTANCE = False   # ρ also on each candidate's own features (filtered inputs, states, selected sensors), the
#   larger of the two: a setting, not the default. On the benchmark's simulated logs (13 of 20 run) it fixed the case
#   it was made for (lumped seed 1 ch2, greybox τ = 3 h: 1.83× → 0.76× OLS; the default now gets 0.76× there too, by
#   RANKING_FOLD_LOSS) but made others worse (lumped seed 0 ch3
#   0.89× → 1.06×, seed 4 ch4 1.00× → 1.0497×; the 120 s test log lumped seed 0 ch4: ridge_ols, 1.19×): a candidate's
#   features are farther out on the folds (small or novel training sets) than on the deployment's held-out part, so
#   the validation credits the shrinkage more than the deployment gets it (docs/drift_model.md)
RANKING_FOLD_LOSS = True   # the per-fold loss bound MAX_FOLD_LOSS on the ranking folds too (the last one is the stretch
#   nearest the future): benchmark rod seed 6 tilt, subset_lag~ols(w=0.25), had every horizon and novelty fold ≤ 1.01×
#   OLS and its last ranking fold 1.10×; it lost 1.06× on the future
RANGE_QUANTILE = 0.99   # the fit data's typical range d0: this quantile of its rows' own input distances
SHRINK_SCALES = (np.inf, 2.0, 1.0, 0.5, 0.25)   # per-sample shrinkage g(ρ) = exp(−(ρ − 1)/s) beyond ρ = d/d0 = 1
                                                # (inf: none); s chosen per candidate on the novelty folds
SPEED_SCALE_RPM = 1e4                            # speed² features use (speed/1e4)² → documented as power 2 of speed/1e4


@dataclass(frozen=True)
class Feature:
    """One input through ``power`` (of ``input / scale``), a first-order lag ``tau_s`` and a delay ``delay_s``."""

    input: str
    tau_s: float = 0.0
    delay_s: float = 0.0
    power: int = 1
    scale: float = 1.0

    @property
    def key(self) -> str:
        p = "" if self.power == 1 and self.scale == 1.0 else f"^{self.power}/{self.scale:g}"
        return f"{self.input}{p}|tau={self.tau_s:g}|delay={self.delay_s:g}"

    def unit(self) -> str:
        """Unit of the coefficient of this feature."""
        base = "um_per_c" if self.input.startswith("temp_") else "um_per_rpm"
        if self.power != 1 or self.scale != 1.0:
            base = f"um_per_(rpm/{self.scale:g})^{self.power}"
        return base


def first_order(time_s, u, tau_s: float) -> np.ndarray:
    """Causal first-order lag of ``u`` (n,) sampled at ``time_s`` (exact for a zero-order-held input): (n,)."""
    u = np.asarray(u, float)
    if tau_s <= 0:
        return u.copy()
    dt = np.diff(time_s)
    if dt.size and np.allclose(dt, dt[0], rtol=1e-9, atol=0):
        a = 1.0 - np.exp(-dt[0] / tau_s)
        return signal.lfilter([a], [1.0, a - 1.0], u, zi=[(1.0 - a) * u[0]])[0]
    a = 1.0 - np.exp(-dt / tau_s)
    y = np.empty_like(u)
    y[0] = u[0]
    for k in range(1, len(u)):
        y[k] = y[k - 1] + a[k - 1] * (u[k] - y[k - 1])
    return y


def input_values(log: DriftLog, name: str) -> np.ndarray:
    if name == "speed_rpm":
        if log.speed_rpm is None:
            why = log.notes.get("dropped", {}).get(name)
            raise InputError(f"{log.path}: column 'speed_rpm': the model needs this input and the log "
                             + (f"cannot give it: {why}" if why else "has no such column"))
        return log.speed_rpm
    s = name[5:-2] if name.startswith("temp_") and name.endswith("_c") else name
    if s not in log.temps_c:
        why = log.notes.get("dropped", {}).get(name)
        raise InputError(f"{log.path}: column '{name}': the model needs this input and the log "
                         + (f"cannot give it: {why}" if why else "has no such column"))
    return log.temps_c[s]


def feature_matrix(log: DriftLog, features, cache: dict | None = None) -> np.ndarray:
    """Features evaluated causally on the log: (n, len(features))."""
    cache = {} if cache is None else cache
    cols = []
    for f in features:
        k = f.key
        if k not in cache:
            fk = (f.input, f.tau_s, f.power, f.scale)
            if fk not in cache:
                v = input_values(log, f.input)
                if f.power != 1 or f.scale != 1.0:
                    v = (v / f.scale) ** f.power
                cache[fk] = first_order(log.time_s, v, f.tau_s)
            y = cache[fk]
            cache[k] = y if f.delay_s == 0 else np.interp(log.time_s - f.delay_s, log.time_s, y)
        cols.append(cache[k])
    return np.stack(cols, axis=1) if cols else np.zeros((len(log.time_s), 0))


# -- linear fits on raw features (intercept, coef) ----------------------------------------------
def _standardise(X):
    mu = X.mean(axis=0)
    sd = X.std(axis=0)
    sd[sd == 0] = 1.0
    return mu, sd


def fit_ols(X, y):
    """Ordinary least squares with intercept: (intercept, coef (p,))."""
    A = np.column_stack([np.ones(len(y)), X])
    th = np.linalg.lstsq(A, y, rcond=None)[0]
    return float(th[0]), th[1:]


def fit_ridge_path(X, Y, lambdas):
    """Ridge on standardised columns for each λ (penalty λ·n), for each column of ``Y`` (n,) or (n, c):
    [[(intercept, coef (p,)) per λ] per column of Y] (a single list per λ when Y is (n,))."""
    one = np.ndim(Y) == 1
    Y = np.asarray(Y, float).reshape(len(X), -1)
    mu, sd = _standardise(X)
    Z = (X - mu) / sd
    ym = Y.mean(axis=0)
    G = Z.T @ Z
    ev, V = np.linalg.eigh(G)
    ev = np.maximum(ev, 0.0)
    VtZy = V.T @ (Z.T @ (Y - ym))                      # (p, c)
    out = []
    for j in range(Y.shape[1]):
        path = []
        for lam in lambdas:
            b = V @ (VtZy[:, j] / (ev + lam * len(Y))) / sd
            path.append((float(ym[j] - mu @ b), b))
        out.append(path)
    return out[0] if one else out


def fit_pls_path(X, y, max_components):
    """PLS1 (NIPALS) on standardised columns: [(intercept, coef)] for 1..max_components components."""
    mu, sd = _standardise(X)
    Z = (X - mu) / sd
    ym = y.mean()
    yr = y - ym
    E = Z.copy()
    W, P, q = [], [], []
    out = []
    for _ in range(min(max_components, Z.shape[1])):
        w = E.T @ yr
        nw = np.linalg.norm(w)
        if nw < 1e-12:
            break
        w /= nw
        tt = E @ w
        tn = tt @ tt
        if tn < 1e-12:
            break
        p = E.T @ tt / tn
        qq = yr @ tt / tn
        E = E - np.outer(tt, p)
        yr = yr - qq * tt
        W.append(w)
        P.append(p)
        q.append(qq)
        Wm, Pm = np.array(W).T, np.array(P).T
        b = Wm @ np.linalg.solve(Pm.T @ Wm, np.array(q)) / sd
        out.append((float(ym - mu @ b), b))
    return out


# -- candidate families ---------------------------------------------------------------------
def _inputs(log: DriftLog, rows) -> tuple[list, bool]:
    temps = [f"temp_{s}_c" for s, v in log.temps_c.items() if np.ptp(v[rows]) > 0]
    speed = log.speed_rpm is not None and np.ptp(log.speed_rpm[rows]) > 0
    return temps, speed


class _Family:
    """A family: ``hypers`` (list of names) and ``fit(log, ch, rows, cache)`` → {hyper: (features, intercept, coef)}."""

    name = ""


class OLSFamily(_Family):
    name = "ols"

    def fit(self, log, channels, rows, cache):
        temps, speed = _inputs(log, rows)
        feats = [Feature(i) for i in temps + (["speed_rpm"] if speed else [])]
        X = feature_matrix(log, feats, cache)[rows]
        return {ch: {"": (feats, *fit_ols(X, log.disp_um[ch][rows]))} for ch in channels}


class RidgeBankFamily(_Family):
    name = "ridge_bank"

    def __init__(self, taus=TAU_BANK_S, lambdas=RIDGE_LAMBDAS):
        self.taus, self.lambdas = taus, lambdas

    def features(self, log, rows):
        temps, speed = _inputs(log, rows)
        return [Feature(i, tau) for i in temps + (["speed_rpm"] if speed else []) for tau in self.taus]

    def fit(self, log, channels, rows, cache):
        feats = self.features(log, rows)
        X = feature_matrix(log, feats, cache)[rows]
        paths = fit_ridge_path(X, np.stack([log.disp_um[ch][rows] for ch in channels], axis=1), self.lambdas)
        return {ch: {f"lambda={lam:g}": (feats, a, b) for lam, (a, b) in zip(self.lambdas, path)}
                for ch, path in zip(channels, paths)}


class PLSBankFamily(RidgeBankFamily):
    name = "pls_bank"

    def __init__(self, taus=TAU_BANK_S, max_components=PLS_MAX_COMPONENTS):
        super().__init__(taus)
        self.max_components = max_components

    def fit(self, log, channels, rows, cache):
        feats = self.features(log, rows)
        X = feature_matrix(log, feats, cache)[rows]
        out = {}
        for ch in channels:
            path = fit_pls_path(X, log.disp_um[ch][rows], self.max_components)
            out[ch] = {f"components={i + 1}": (feats, a, b) for i, (a, b) in enumerate(path)}
        return out


def _ols_in_bank(X, feats, Y):
    """OLS on the bank's unfiltered columns (the baseline's inputs): (intercept (c,), coef (p, c) embedded in
    the bank with zeros on the filtered columns, residual (n, c))."""
    raw = np.array([f.tau_s == 0 and f.delay_s == 0 for f in feats])
    A = np.column_stack([np.ones(len(X)), X[:, raw]])
    th = np.linalg.lstsq(A, Y, rcond=None)[0]
    B = np.zeros((X.shape[1], Y.shape[1]))
    B[raw] = th[1:]
    return th[0], B, Y - A @ th


class RidgeTowardOLSFamily(RidgeBankFamily):
    """Ridge on the filter bank, shrunk toward the OLS baseline instead of toward zero:
    minimise ‖y − Xβ‖² + λ·n·‖S(β − β_ols)‖² (S: column scales; β_ols the baseline's coefficients on the
    unfiltered columns, zero on the filtered). Large λ gives the baseline back; small λ the full bank."""

    name = "ridge_ols"

    def __init__(self, taus=TAU_BANK_S, lambdas=RIDGE_OLS_LAMBDAS):
        super().__init__(taus, lambdas)

    def fit(self, log, channels, rows, cache):
        feats = self.features(log, rows)
        X = feature_matrix(log, feats, cache)[rows]
        Y = np.stack([log.disp_um[ch][rows] for ch in channels], axis=1)
        a0, B0, R = _ols_in_bank(X, feats, Y)
        paths = fit_ridge_path(X, R, self.lambdas)
        return {ch: {f"lambda={lam:g}": (feats, float(a0[j] + a), B0[:, j] + b)
                     for lam, (a, b) in zip(self.lambdas, path)}
                for j, (ch, path) in enumerate(zip(channels, paths))}


class PLSTowardOLSFamily(PLSBankFamily):
    """PLS components of the filter bank added to the OLS baseline (fitted on its residual); 0 components
    would be the baseline itself."""

    name = "pls_ols"

    def fit(self, log, channels, rows, cache):
        feats = self.features(log, rows)
        X = feature_matrix(log, feats, cache)[rows]
        Y = np.stack([log.disp_um[ch][rows] for ch in channels], axis=1)
        a0, B0, R = _ols_in_bank(X, feats, Y)
        out = {}
        for j, ch in enumerate(channels):
            path = fit_pls_path(X, R[:, j], self.max_components)
            out[ch] = {f"components={i + 1}": (feats, float(a0[j] + a), B0[:, j] + b) for i, (a, b) in enumerate(path)}
        return out


class TransferFamily(_Family):
    """Spindle heat (speed, speed²) through two first-order paths of fitted time constants + temperatures."""

    name = "transfer"

    def __init__(self, taus=TAU_GRID_S, lam=TRANSFER_LAMBDA):
        self.taus, self.lam = taus, lam

    def fit(self, log, channels, rows, cache):
        temps, speed = _inputs(log, rows)
        tfe = [Feature(i) for i in temps]
        XT = feature_matrix(log, tfe, cache)[rows]
        if not speed:
            return {ch: {"": (tfe, *fit_ridge_path(XT, log.disp_um[ch][rows], [self.lam])[0])} for ch in channels}
        pairs = [(a, b) for i, a in enumerate(self.taus) for b in self.taus[i + 1:]]
        Y = np.stack([log.disp_um[ch][rows] for ch in channels], axis=1)
        best = {}
        for t1, t2 in pairs:
            sf = [Feature("speed_rpm", t) for t in (t1, t2)] + \
                 [Feature("speed_rpm", t, power=2, scale=SPEED_SCALE_RPM) for t in (t1, t2)]
            X = np.column_stack([feature_matrix(log, sf, cache)[rows], XT])
            paths = fit_ridge_path(X, Y, [self.lam])
            for j, ch in enumerate(channels):
                a, b = paths[j][0]
                rss = float(np.sum((Y[:, j] - a - X @ b) ** 2))
                if ch not in best or rss < best[ch][0]:
                    best[ch] = (rss, sf + tfe, a, b)
        return {ch: {"": best[ch][1:4]} for ch in channels}


class SubsetLagFamily(_Family):
    """The sensor-subset + lag search of :class:`DriftModeller`, refitted causally."""

    name = "subset_lag"

    def __init__(self, **modeller_kw):
        self.kw = {"max_sensors": 3, "max_lag_steps": 60, **modeller_kw}
        self.last_modeller_ = None

    def fit(self, log, channels, rows, cache):
        # the search runs on rows at least ``search_step_s`` apart (thermal signals change over minutes)
        dt = float(np.median(np.diff(log.time_s)))
        q = max(1, int(round(SUBSET_SEARCH_STEP_S / dt)))
        keep = rows[::q]                   # (rows may skip a validation block: it is not searched on)
        dec = DriftLog(log.time_s[keep], {s: v[keep] for s, v in log.temps_c.items()},
                       {c: v[keep] for c, v in log.disp_um.items()},
                       None if log.speed_rpm is None else log.speed_rpm[keep], log.path)
        m = DriftModeller(**self.kw).fit_rows(dec, np.arange(len(keep)))
        self.last_modeller_ = m
        out = {}
        tau = m.smooth_s / 2
        for ch in channels:
            cm = m.channels_[ch]
            feats = [Feature("speed_rpm" if s == "speed_rpm" else f"temp_{s}_c", 0.0 if s == "speed_rpm" else tau,
                             cm.lag_s) for s in cm.sensors]
            X = feature_matrix(log, feats, cache)[rows]
            out[ch] = {"": (feats, *fit_ols(X, log.disp_um[ch][rows]))}
        return out


def default_families(subset_kw=None):
    """OLS (the baseline), the subset/lag search, the transfer model, the filter bank shrunk toward OLS by
    ridge (chosen on development seeds 100–109, ``benchmarks/drift_rule_dev.md``), and the physically
    constrained families of issue 29. The PLS bank toward OLS (``pls_ols``) is left out since issue 29: on
    simulated logs whose later part leaves the fit range (development seeds: lumped 100–104, rod 100–102;
    38 channel cases) it was the choice in 2 of the 4 cases worse than OLS by more than 5 % (1.33×,
    1.15×); without it those became 1.01× and 0.81×, no case got worse, and the other two (1.06×,
    1.23×, grey-box choices) stayed as they were. It stays available."""
    return [OLSFamily(), SubsetLagFamily(**(subset_kw or {})), TransferFamily(), RidgeTowardOLSFamily(),
            ThermalNNFamily(), GreyBoxFamily(), StableOLSFamily()]


def measured_families():
    """The constrained families of issue 29's third round — temperature differences (``gradient``), temperature
    modes (``modes``), a grey-box state on the modes (``greybox_modes``), stably selected sensors through one lag
    each (``ols_stable_lag``): available, measured, NOT among the defaults. Added to the defaults one at a time
    (development seeds 100–104 and the real log inside its fitting parts, ``benchmarks/drift_dev_results.md``),
    none changed a real-log case (the three ties at the 36 % split stay: no candidate of theirs passes the
    gates there), and two made development cases worse than OLS (``ols_stable_lag`` rod seed 103 growth 3.55×,
    ``greybox_modes`` rod seed 102 growth 1.51×); ``gradient`` changed one case, for the worse (0.86× → 0.96×),
    ``modes`` none. Pass them as ``DriftSelector(families=default_families() + measured_families())``."""
    return [GradientFamily(), ModesFamily(), GreyBoxModesFamily(), StableLagOLSFamily()]


# -- the model ------------------------------------------------------------------------------
# other volcomp files a user may hand over in place of a drift model, recognised by their ``format`` key
OTHER_FORMATS = {"volcomp-elements/": "an element set",
                 "volcomp-identification/": "an identification result",
                 "volcomp-diagnosed-model/": "a diagnosed volumetric model (from `volcomp diagnose CHECKS`)",
                 "volcomp-sweeps/": "a sweeps file", "volcomp-fleet/": "a fleet file",
                 "volcomp-report/": "a comparison report"}


def _kind_of(fmt) -> str:
    """What a file with ``format`` = ``fmt`` is, in words."""
    for k, v in OTHER_FORMATS.items():
        if isinstance(fmt, str) and fmt.startswith(k):
            return f"{v} ({fmt})"
    return f"a file of format {fmt!r}"


@dataclass
class ChannelFit:
    family: str
    hyper: str
    features: list
    intercept_um: float
    coef: np.ndarray
    band95_um: float = float("nan")
    base: tuple | None = None          # (features, intercept, coef) of the OLS baseline the prediction shrinks toward
    shrink_scale: float = float("inf")  # g(ρ) = exp(−(ρ − 1)/shrink_scale) beyond ρ = 1; inf: no per-sample shrinkage
    novelty: dict | None = None         # the distance on the channel's OWN features (:func:`feature_novelty`): ρ of the
                                        # channel = max(ρ of the raw inputs, ρ of these features)
    band_gamma: float = 1.0             # the band grows as band95_um · max(1, ρ)^band_gamma (:func:`rho_power_band`)


class DriftModel:
    """A fitted causal drift model: ``channels`` {channel: ChannelFit}. ``predict`` → {channel: (n,)} μm."""

    def __init__(self, channels: dict, meta: dict | None = None):
        self.channels = channels
        self.meta = meta or {}

    @property
    def features(self) -> list:
        seen = {}
        for c in self.channels.values():
            for f in list(c.features) + (list(c.base[0]) if c.base is not None else []) + \
                    (list(c.novelty["features"]) if c.novelty else []):
                seen.setdefault(f.key, f)
        return list(seen.values())

    def rho(self, log) -> np.ndarray | None:
        """ρ (n,) of every row of ``log`` (distance of its raw inputs from the fit data / d0), or None."""
        return input_rho(self, log)

    def channel_rho(self, log, cache: dict | None = None) -> dict:
        """{channel: ρ (n,) or None}: the larger of the raw inputs' ρ (:meth:`rho`) and the ρ of the channel's own
        features (``ChannelFit.novelty``: its filtered inputs / states, its selected sensors), row by row (causal)."""
        raw = self.rho(log)
        cache = {} if cache is None else cache
        out = {}
        for ch, c in self.channels.items():
            r = raw
            if c.novelty:
                rf = novelty_rho(c.novelty, feature_matrix(log, c.novelty["features"], cache))
                r = rf if r is None else np.maximum(r, rf)
            out[ch] = r
        return out

    @property
    def inputs(self) -> list:
        return sorted({f.input for f in self.features})

    @property
    def max_delay_s(self) -> float:
        return max([f.delay_s for f in self.features], default=0.0)

    def predict(self, log: DriftLog, cache: dict | None = None, distance_shrink: bool = True) -> dict:
        """{channel: (n,) μm}. With ``distance_shrink`` (default), a channel that has a baseline and a finite
        ``shrink_scale`` predicts ``base + g(ρ)·(model − base)`` per sample (ρ: :meth:`rho`; g: :func:`distance_weight`),
        which equals the fixed linear model wherever ρ ≤ 1. ``distance_shrink=False``: the fixed linear model (what
        the exported controller gains run). Causal: the rule at a row uses that row's inputs (and the causal
        features) only."""
        cache = {} if cache is None else cache
        out = {ch: c.intercept_um + feature_matrix(log, c.features, cache) @ c.coef for ch, c in self.channels.items()}
        if not distance_shrink:
            return out
        rhos = self.channel_rho(log, cache) \
            if any(c.base is not None and np.isfinite(c.shrink_scale) for c in self.channels.values()) else {}
        for ch, c in self.channels.items():
            if c.base is None or rhos.get(ch) is None or not np.isfinite(c.shrink_scale):
                continue
            bf, ba, bc = c.base
            b = ba + feature_matrix(log, bf, cache) @ np.asarray(bc)
            out[ch] = b + distance_weight(rhos[ch], c.shrink_scale) * (out[ch] - b)
        return out

    def band_um(self, log, cache: dict | None = None) -> dict:
        """The 95 % band half-width per row {channel: (n,) μm}: ``band95_um · max(1, ρ)^band_gamma`` with the
        channel's ρ (:meth:`channel_rho`; constant where the model records no distance)."""
        rhos = self.channel_rho(log, cache)
        one = np.ones(len(log.time_s))
        return {ch: c.band95_um * (one if rhos[ch] is None else np.maximum(1.0, rhos[ch]) ** c.band_gamma)
                for ch, c in self.channels.items()}

    # -- controller form --------------------------------------------------------------------
    def to_json(self) -> dict:
        feats = self.features
        ids = {f.key: f"f{i}" for i, f in enumerate(feats)}
        units = {"temp": "degC", "speed_rpm": "rpm"}
        return {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION,
            "description": "Causal thermal-drift model: prediction_um(t) = intercept_um + sum(coef * feature(t)); "
                           "the controller compensates by subtracting the prediction.",
            "units": {"time": "s", "temperature": "degC", "speed": "rpm", "displacement": "um"},
            "filter": "v[k] = (u[k]/scale)**power; y[0] = v[0]; y[k] = y[k-1] + (1 - exp(-(t[k]-t[k-1])/tau_s)) * "
                      "(v[k] - y[k-1]); tau_s = 0: y = v (exact for v held at v[k] over (t[k-1], t[k]]; "
                      "run from power-on, at every logged sample)",
            "delay": "feature(t) = y(t - delay_s), linear interpolation between samples at or before t; "
                     "before the first sample: y[0]",
            "missing_samples": "hold the last valid value of the input",
            "inputs": [{"name": i, "unit": units["temp"] if i.startswith("temp_") else units.get(i, "")}
                       for i in self.inputs],
            "features": [{"id": ids[f.key], "input": f.input, "power": f.power, "scale": f.scale,
                          "tau_s": f.tau_s, "delay_s": f.delay_s} for f in feats],
            "channels": {ch: self._channel_json(c, ids, ch) for ch, c in self.channels.items()},
            "fitted_on": self.meta,
        }

    @staticmethod
    def _channel_json(c, ids, ch) -> dict:
        out = {"output": f"{ch}_um", "family": c.family, "hyper": c.hyper, "intercept_um": c.intercept_um,
               "terms": [{"feature": ids[f.key], "coef": float(b), "unit": f.unit()} for f, b in zip(c.features, c.coef)],
               "band95_um": c.band95_um, "band_gamma": float(c.band_gamma),
               "band_rule": "band(t) = band95_um * max(1, rho(t)) ** band_gamma; rho = Mahalanobis distance of the inputs at t "
                            "from the fitting data (fitted_on.novelty) / fitted_on.novelty.range_distance; where the "
                            "channel has feature_distance, rho = max(that, the same distance of its listed features)"}
        if c.novelty:
            nv = c.novelty
            out["feature_distance"] = {
                "rule": "rho_features(t) = norm((f(t) - mean) @ whiten) / range_distance over the listed features f "
                        "(the channel's own filtered inputs); the channel's rho = max(rho_inputs, rho_features)",
                "features": [ids[f.key] for f in nv["features"]], "mean": np.asarray(nv["mean"], float).tolist(),
                "whiten": np.asarray(nv["whiten"], float).tolist(), "range_distance": float(nv["range_distance"])}
        if c.base is not None and np.isfinite(c.shrink_scale):
            bf, ba, bc = c.base
            out["distance_shrink"] = {
                "rule": "prediction_um(t) = base(t) + g(rho(t)) * (model(t) - base(t)); g = 1 for rho <= 1, "
                        "exp(-(rho - 1) / scale) beyond; model: intercept_um + terms; base: the OLS baseline below",
                "scale": c.shrink_scale,
                "base": {"intercept_um": float(ba), "terms": [{"feature": ids[f.key], "coef": float(b), "unit": f.unit()}
                                                            for f, b in zip(bf, bc)]}}
        return out

    @classmethod
    def from_json(cls, obj, path="<model>") -> "DriftModel":
        """Read the controller form back; errors name the file and the key."""
        def need(d, k, where):
            if not isinstance(d, dict) or k not in d:
                raise InputError(f"{path}: key '{where}{k}': missing")
            return d[k]
        if not isinstance(obj, dict):
            raise InputError(f"{path}: not a drift model: expected a JSON object with schema {SCHEMA!r}, "
                             f"got a JSON {type(obj).__name__}")
        if "schema" not in obj and "format" in obj:   # another volcomp file, recognised by its own key
            raise InputError(f"{path}: key 'format': {_kind_of(obj['format'])}, not a drift model "
                             "(drift_model.json from `volcomp diagnose --drift`)")
        if need(obj, "schema", "") != SCHEMA:
            raise InputError(f"{path}: key 'schema': expected {SCHEMA!r}, got {obj.get('schema')!r}")
        if need(obj, "schema_version", "") != SCHEMA_VERSION:
            raise InputError(f"{path}: key 'schema_version': expected {SCHEMA_VERSION}, got {obj['schema_version']!r}")
        feats = {}
        for i, f in enumerate(need(obj, "features", "")):
            try:
                feats[f["id"]] = Feature(str(f["input"]), float(f["tau_s"]), float(f["delay_s"]), int(f["power"]),
                                         float(f["scale"]))
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(f"{path}: key 'features[{i}]': expected id, input, power, scale, tau_s, delay_s "
                                 f"({exc})") from None
            if feats[f["id"]].tau_s < 0 or feats[f["id"]].delay_s < 0:
                raise InputError(f"{path}: key 'features[{i}]': expected tau_s >= 0 and delay_s >= 0")
        _refuse_withdrawn(obj, path)
        chans = {}
        for ch, c in need(obj, "channels", "").items():
            try:
                terms = c["terms"]
                fl = [feats[t["feature"]] for t in terms]
                base, scale = None, float("inf")
                if c.get("distance_shrink") is not None:
                    ds = c["distance_shrink"]
                    scale = float(ds["scale"])
                    if not scale > 0:
                        raise ValueError(f"distance_shrink.scale must be > 0, got {scale}")
                    base = ([feats[t["feature"]] for t in ds["base"]["terms"]], float(ds["base"]["intercept_um"]),
                            np.array([float(t["coef"]) for t in ds["base"]["terms"]]))
                nv = None
                if c.get("feature_distance") is not None:
                    fd = c["feature_distance"]
                    nf = [feats[i] for i in fd["features"]]
                    Wf = np.array(fd["whiten"], float).reshape(len(nf), -1)
                    mf = np.array(fd["mean"], float)
                    d0 = float(fd["range_distance"])
                    if mf.shape != (len(nf),) or not d0 > 0:
                        raise ValueError("feature_distance: expected one mean per feature and range_distance > 0")
                    nv = {"features": nf, "mean": mf, "whiten": Wf, "range_distance": d0}
                gamma = float(c.get("band_gamma", 1.0))     # files before the ρ-power band: γ = 1
                if not 0 <= gamma <= 10:
                    raise ValueError(f"band_gamma must be in [0, 10], got {gamma}")
                chans[ch] = ChannelFit(c.get("family", ""), c.get("hyper", ""), fl, float(c["intercept_um"]),
                                       np.array([float(t["coef"]) for t in terms]), float(c.get("band95_um") or "nan"),
                                       base, scale, nv, gamma)
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(f"{path}: key 'channels.{ch}': expected intercept_um and terms "
                                 f"[{{feature, coef}}] naming listed features ({exc!r})") from None
        return cls(chans, obj.get("fitted_on", {}))

    def save(self, path):
        from ..io import write_json
        return write_json(path, self.to_json())

    @classmethod
    def load(cls, path) -> "DriftModel":
        try:
            obj = json.loads(read_document_text(path, "a drift model"))
        except FileNotFoundError:
            raise InputError(f"{path}: no such file") from None
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: line {exc.lineno}, column {exc.colno}: not JSON ({exc.msg})") from None
        return cls.from_json(obj, path)


def _refuse_withdrawn(obj: dict, path) -> None:
    """Refuse a model file that uses a prediction rule no longer applied (the disagreement gate, the per-input range
    term of ρ; docs/decisions): predicting without it would silently differ from what the file describes."""
    if "input_range" in ((obj.get("fitted_on") or {}).get("novelty") or {}):
        raise InputError(f"{path}: key 'fitted_on.novelty.input_range': the per-input range term of the distance is no "
                         "longer applied; refit the model with `volcomp diagnose --drift LOG --out DIR`")
    for ch, c in (obj.get("channels") or {}).items():
        if isinstance(c, dict) and c.get("disagreement_gate") is not None:
            raise InputError(f"{path}: key 'channels.{ch}.disagreement_gate': the disagreement gate is no longer "
                             "applied; refit the model with `volcomp diagnose --drift LOG --out DIR`")


# -- selection ------------------------------------------------------------------------------
def _merge(feats, intercept, coef):
    """Sum the coefficients of repeated features: (features, intercept, coef)."""
    keys, out_f, out_c = {}, [], []
    for f, c in zip(feats, coef):
        if f.key in keys:
            out_c[keys[f.key]] += float(c)
        else:
            keys[f.key] = len(out_f)
            out_f.append(f)
            out_c.append(float(c))
    return out_f, float(intercept), np.array(out_c)


def candidate_name(family: str, hyper: str, w: float) -> str:
    """The name a candidate is reported by: ``family[hyper]``, with ``~ols(w=…)`` when it is blended toward OLS."""
    return f"{family}{'[' + hyper + ']' if hyper else ''}" + ("" if w == 1.0 else f"~ols(w={w:g})")


def blend_with_ols(cand, ols, w: float):
    """(features, intercept, coef) of the blend ``w``·cand + (1 − ``w``)·ols of two linear models on causal features
    (each a (features, intercept, coef) triple): again one such model, the coefficients of a feature both use summed.
    ``w`` = 0 returns ``ols`` itself, ``w`` = 1 ``cand`` itself (exactly: no arithmetic on either)."""
    if not 0.0 <= w <= 1.0:
        raise ValueError(f"Expected a blend weight in [0, 1], got {w}")
    if w == 0.0:
        return ols
    if w == 1.0:
        return cand
    (feats, a, b), (fo, ao, bo) = cand, ols
    return _merge(list(feats) + list(fo), w * a + (1 - w) * ao,
                  np.concatenate([w * np.asarray(b), (1 - w) * np.asarray(bo)]))


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _blend_residuals(w: float, cand, ols, rhos, scale: float) -> list:
    """Per fold, the residual of OLS + w·g(ρ)·(candidate − OLS) (residuals are target − prediction, so the blend's is
    the same blend of the two residuals): lists of (n_i,) arrays; ``scale`` = inf: g = 1 (a fixed blend)."""
    if not np.isfinite(scale):
        return [y + w * (x - y) for x, y in zip(cand, ols)]
    return [y + w * distance_weight(q, scale) * (x - y) for x, y, q in zip(cand, ols, rhos)]


def blend_statistics(w: float, scale: float, cand: tuple, ols: tuple, rhos: tuple, gate_se: float = GATE_SE,
                     ranking_fold_loss: bool = RANKING_FOLD_LOSS) -> tuple[dict, tuple]:
    """Validation statistics of a candidate blended with OLS at weight ``w`` (per-sample scale ``scale``).

    ``cand``, ``ols``, ``rhos``: (ranking, horizon, novelty) lists of per-fold (n_i,) arrays — the candidate's and
    OLS's validation residuals (μm) and each row's ρ from its fold's training rows; an empty novelty list: no
    novelty folds. Returns (stats, gate): ``stats`` as in ``DriftSelector.candidates_`` (RMS on each set, the
    worst fold's RMS ratio to OLS under the per-fold bound (``ranking_fold_loss``: the ranking folds count) and
    over all folds, per-fold ratios, band quantiles, the mean log-gain over OLS), ``gate`` = (horizon, novelty)
    :func:`horizon_gate` results."""
    (res_r, res_h, res_n), (r0, h0, n0), (rho_r, rho_h, rho_n) = cand, ols, rhos
    nfolds = len(n0) > 0
    rl = _blend_residuals(w, res_r, r0, rho_r, scale)
    hl = _blend_residuals(w, res_h, h0, rho_h, scale)
    nl = _blend_residuals(w, res_n, n0, rho_n, scale)
    r = np.concatenate(rl)
    gh = horizon_gate([_rms(x) for x in h0], [_rms(x) for x in hl], gate_se)
    gn = horizon_gate([_rms(x) for x in n0], [_rms(x) for x in nl], gate_se) if nfolds else (True, 0.0, 0.0)
    # the per-fold loss bound: on every horizon and novelty fold, and (``ranking_fold_loss``) on every
    # ranking fold too — the last ranking fold is the stretch nearest the future
    lr, l0 = (rl + hl + nl, r0 + h0 + n0) if ranking_fold_loss else (hl + nl, h0 + n0)
    worst = max(_rms(x) / max(_rms(y), 1e-300) for x, y in zip(lr, l0))
    worst_all = max(_rms(x) / max(_rms(y), 1e-300) for x, y in zip(rl + hl + nl, r0 + h0 + n0))
    rank = _rms(r)
    # band: calibrated on the horizon and novelty folds alone (held-out stretches as long as the
    # deployment's, and the most novel ones), as a split-conformal quantile of |residual|
    # ("fold_residual") or of |residual| / max(1, ρ) ("rho_scaled": the same growth max(1, ρ) the
    # band has at prediction, so it covers BAND_QUANTILE of the fold rows by construction)
    zb = np.concatenate([np.abs(x) / np.maximum(1.0, q) for x, q in zip(hl + nl, rho_h + rho_n)])
    stats = {"ranking": rank, "horizon": _rms(np.concatenate(hl)),
             "novelty": _rms(np.concatenate(nl)) if nfolds else 0.0,
             "band_rho_scaled": conformal_quantile(zb, BAND_QUANTILE),
             "band_fold_residual": conformal_quantile(np.abs(np.concatenate(hl + nl)), BAND_QUANTILE),
             "scale": scale, "worst_fold": worst, "worst_all": worst_all,
             "fold_rho": float(np.quantile(np.concatenate(rho_h + rho_n), 0.95)),
             "fold_rho_each": ([float(np.median(q)) for q in rho_r], [float(np.median(q)) for q in rho_h],
                               [float(np.median(q)) for q in rho_n]),
             "band_rho_power": rho_power_band(np.abs(np.concatenate(hl + nl)), np.concatenate(rho_h + rho_n)),
             "fold_ratios": ([_rms(x) / max(_rms(y), 1e-300) for x, y in zip(rl, r0)],
                             [_rms(x) / max(_rms(y), 1e-300) for x, y in zip(hl, h0)],
                             [_rms(x) / max(_rms(y), 1e-300) for x, y in zip(nl, n0)]),
             "gain": (np.log(_rms(np.concatenate(r0)) / rank) + gh[1] + gn[1]) / (3 if nfolds else 2)}
    return stats, (gh, gn)


def rolling_origin_folds(n_fit: int, n_folds: int = 4, start: float = 0.5):
    """Forward-chaining folds on rows 0..n_fit-1: [(train (a,), validate (b,))], training always earlier."""
    first = int(round(start * n_fit))
    edges = np.linspace(first, n_fit, n_folds + 1).round().astype(int)
    return [(np.arange(edges[i]), np.arange(edges[i], edges[i + 1])) for i in range(n_folds) if edges[i + 1] > edges[i]]


def horizon_folds(n_fit: int, horizon: float, n_folds: int = 4, start: float = 0.5):
    """Forward-chaining folds whose validation block is as long, relative to its training block, as the
    deployment's: fold i trains on rows [0, m_i) and validates on [m_i, m_i·(1 + horizon)); the
    validation ends are evenly spaced from ``start``·n_fit to n_fit (blocks may overlap).
    ``horizon`` = held-out length / fitting length of the deployment ((1 − f)/f for a fit fraction f).
    Returns [(train (m_i,), validate (b_i,))], training always earlier."""
    if horizon <= 0:
        raise ValueError(f"Expected horizon > 0, got {horizon}")
    ends = np.linspace(start * n_fit, n_fit, n_folds).round().astype(int)
    out = []
    for e in ends:
        m = int(round(e / (1.0 + horizon)))
        if 0 < m < e:
            out.append((np.arange(m), np.arange(m, e)))
    return out


def cv_residuals(log: DriftLog, families, channels, folds, cache: dict, errors: list | None = None,
                 features: dict | None = None) -> dict:
    """Validation residuals of every candidate on every fold: {(channel, family, hyper): [(len(va),) per fold]}.
    ``features`` (a dict, filled when given): {(channel, family, hyper): [the candidate's features per fold]}.

    A family that cannot fit a fold (``ValueError``) drops out of it (its message goes to ``errors``);
    a candidate missing from any fold is incomplete and must not be scored."""
    resid = {}
    for tr, va in folds:
        for fam in families:
            try:
                res = fam.fit(log, channels, tr, cache)
            except ValueError as exc:
                if errors is not None:
                    errors.append(f"{fam.name}: {exc}")
                continue
            for ch, hyp in res.items():
                y = log.disp_um[ch][va]
                for h, (feats, a, b) in hyp.items():
                    resid.setdefault((ch, fam.name, h), []).append(y - a - feature_matrix(log, feats, cache)[va] @ b)
                    if features is not None:
                        features.setdefault((ch, fam.name, h), []).append(list(feats))
    return resid


def horizon_gate(rms_ols, rms_cand, k_se: float = GATE_SE) -> tuple[bool, float, float]:
    """The one-standard-error rule on the horizon folds: per fold d_i = ln(RMS_ols,i / RMS_cand,i); the
    candidate passes when mean(d) > ``k_se`` · sd(d)/√K. Returns (passes, mean(d), se(d))."""
    d = np.log(np.asarray(rms_ols, float)) - np.log(np.asarray(rms_cand, float))
    se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
    return bool(d.mean() > k_se * se), float(d.mean()), se


class DriftSelector(Estimator):
    """Per channel, a family (and hyper-parameter) chosen on the fitting part only, refitted on all of it.

    Two sets of forward-chaining folds on the fitting part:

    * **ranking folds** (``n_folds`` blocks after the first ``cv_start`` of the fitting part,
      :func:`rolling_origin_folds`): every candidate is scored by its RMS over all their validation rows;
    * **horizon folds** (``n_horizon_folds``, :func:`horizon_folds`): validation blocks as long, relative
      to their training part, as the deployment's held-out part is to the fitting part (``horizon``,
      default (1 − fit_fraction)/fit_fraction).

    * **novelty folds** (``n_novelty_folds`` of ``n_novelty_blocks`` blocks,
      :func:`novelty_folds`): the blocks of the fitting part whose
      inputs are farthest (Mahalanobis) from the rest, held out.

    Candidates are every family × hyper-parameter and each shrunk toward OLS (``shrink_weights`` w0; above
    ``hedge_weight`` only where the worst fold's RMS ratio to OLS is ≤ ``confident_worst_fold``, a hedge that
    is off by default), predicting per sample OLS + w0·g(ρ)·(candidate − OLS): ρ = the larger of the distance
    of the sample's raw inputs and of the candidate's own features from the training data, each over that
    data's ``RANGE_QUANTILE`` distance, g = :func:`distance_weight` with the
    scale of ``shrink_scales`` of lowest RMS on the novelty folds. A candidate is eligible when it
    (a) scores below OLS on the ranking folds and passes :func:`horizon_gate` against OLS (b) on the
    horizon folds and (c) on the novelty folds, (d) with a mean log-gain ≥ ``min_gain`` on each of (b)
    and (c), and (e) no fold (horizon, novelty, and with ``ranking_fold_loss`` ranking) worse than OLS by
    more than ``max_fold_loss``; the eligible one of largest mean log-gain over OLS (over the three sets)
    is returned (``selection="mean_gain"``; ``"worst_fold"``: the one whose worst fold, the largest RMS
    ratio to OLS over all three sets, is smallest), else the OLS baseline itself. A model that loses to OLS in any of its validations is never returned. Learned
    too: ``scale_`` {channel: s of the chosen}, ``worst_fold_`` {channel: {candidate: worst RMS ratio to
    OLS over the horizon and novelty folds}}.

    Settings: ``fit_fraction``, ``n_folds``, ``cv_start``, ``horizon``, ``n_horizon_folds``, ``gate_se``,
    ``feature_distance`` (ρ also on the candidate's own features), ``ranking_fold_loss``, ``selection``,
    ``hedge_weight``, ``confident_worst_fold``, ``band_rule`` (``BAND_RULE``; the other rule's scale: ``band_alt_``),
    ``n_novelty_folds`` (0: none), ``n_novelty_blocks``, ``shrink_weights``, ``families`` (default
    :func:`default_families`). Also learned: ``cv_novelty_`` {channel: {candidate: RMS μm}}, ``gain_``
    {channel: {candidate: mean log-gain over OLS}}, ``score_`` {channel: {candidate: the number ``selection`` ranks
    the eligible by (:func:`fold_gain_score`)}}, ``eligible_`` {channel: [candidates passing every gate]},
    ``shrink_`` {channel: w}, ``novelty_`` (n_novelty_blocks,) median distance of each block.
    Learned: ``model_`` (:class:`DriftModel`), ``cv_`` {channel: {candidate: RMS μm}} (ranking folds),
    ``cv_horizon_`` {channel: {candidate: RMS μm}} (horizon folds), ``gate_`` {channel: {candidate:
    (passes, mean log gain, its se)}}, ``chosen_`` {channel: candidate}, ``baseline_`` (the OLS
    :class:`DriftModel`), ``subset_modeller_``, ``candidates_`` {channel: {(family, hyper, w0): every
    validation statistic of the candidate}}.

    ``deploy`` (False): also refit each channel's chosen candidate — the same family, hyper-parameter, weight, distance
    scale and band — on EVERY row of the log, ``deployed_`` (:class:`DriftModel`; its meta ``fit_rows`` all rows,
    ``validated_on_rows`` the fitting part); ``deployed_`` is None without it. The selection, ``model_`` and every
    validation figure are the same with or without it (they read the fitting part only).
    """

    def __init__(self, fit_fraction: float = 0.6, n_folds: int = 4, cv_start: float = 0.5, families=None,
                 subset_kw: dict | None = None, horizon: float | None = None, n_horizon_folds: int = 4,
                 gate_se: float = GATE_SE, n_novelty_folds: int = 3, n_novelty_blocks: int = 8,
                 shrink_weights=SHRINK_WEIGHTS, shrink_scales=SHRINK_SCALES, max_fold_loss: float = MAX_FOLD_LOSS,
                 min_gain: float = MIN_GAIN, feature_distance: bool = FEATURE_DISTANCE,
                 ranking_fold_loss: bool = RANKING_FOLD_LOSS,
                 selection: str = SELECTION, hedge_weight: float = HEDGE_WEIGHT, band_rule: str = BAND_RULE,
                 confident_worst_fold: float = CONFIDENT_WORST_FOLD, deploy: bool = False):
        self.fit_fraction = fit_fraction
        self.n_folds = n_folds
        self.cv_start = cv_start
        self.families = families
        self.subset_kw = subset_kw
        self.horizon = horizon
        self.n_horizon_folds = n_horizon_folds
        self.gate_se = gate_se
        self.n_novelty_folds = n_novelty_folds
        self.n_novelty_blocks = n_novelty_blocks
        self.shrink_weights = shrink_weights
        self.shrink_scales = shrink_scales
        self.max_fold_loss = max_fold_loss
        self.min_gain = min_gain
        self.feature_distance = feature_distance
        self.ranking_fold_loss = ranking_fold_loss
        self.selection = selection
        self.hedge_weight = hedge_weight
        self.band_rule = band_rule
        self.confident_worst_fold = confident_worst_fold
        self.deploy = deploy

    def eligible(self, stats: dict, gate: tuple, w: float, ranking_ols: float, novelty: bool = True) -> bool:
        """Whether a candidate blended at weight ``w`` (its :func:`blend_statistics` ``stats`` and ``gate``) passes
        every gate of the rule in force against OLS, whose ranking-fold RMS is ``ranking_ols``: below it on the
        ranking folds, > ``gate_se`` SE and a mean log-gain ≥ ``min_gain`` on the horizon and (``novelty``) the
        novelty folds, no fold above ``max_fold_loss``× OLS, the hedge, and the selection's own floor."""
        (ok_h, gain_h, _), (ok_n, gain_n, _) = gate
        return bool(stats["ranking"] < ranking_ols and ok_h and ok_n and stats["worst_fold"] <= self.max_fold_loss
                    and (w <= self.hedge_weight or stats["worst_all"] <= self.confident_worst_fold)
                    and gain_h >= self.min_gain and (not novelty or gain_n >= self.min_gain)
                    # "lcb": the lower confidence bound must itself be above OLS; "trimmed_fold": the gain without
                    # its best fold must still be worth its risk
                    and (self.selection != "lcb" or fold_gain_score(stats, "lcb") > 0)
                    and (self.selection != "trimmed_fold" or fold_gain_score(stats, "trimmed_fold") >= self.min_gain))

    def split(self, log):
        n = len(log.time_s)
        n_fit = int(round(self.fit_fraction * n))
        return np.arange(n_fit), np.arange(n_fit, n)

    def fit(self, log: DriftLog) -> "DriftSelector":
        if not 0 < self.fit_fraction < 1:
            raise ValueError(f"Expected 0 < fit_fraction < 1, got {self.fit_fraction}")
        if not self.shrink_scales or not all(sc > 0 for sc in self.shrink_scales):
            raise ValueError(f"Expected shrink_scales > 0 (inf: no per-sample shrinkage), got {self.shrink_scales}")
        if not self.max_fold_loss >= 1.0:
            raise ValueError(f"Expected max_fold_loss >= 1, got {self.max_fold_loss}")
        if np.isnan(self.min_gain):
            raise ValueError("Expected a number for min_gain, got nan")
        if self.band_rule not in BAND_RULES:
            raise ValueError(f"Expected band_rule in {BAND_RULES}, got {self.band_rule!r}")
        if self.selection not in SELECTIONS:
            raise ValueError(f"Expected selection in {SELECTIONS}, got {self.selection!r}")
        if not self.shrink_weights or not all(0 < w <= 1 for w in self.shrink_weights):
            raise ValueError(f"Expected shrink_weights in (0, 1], got {self.shrink_weights}")
        if not 0 < self.hedge_weight <= 1 or not 0 < self.confident_worst_fold <= 1:
            raise ValueError(f"Expected hedge_weight and confident_worst_fold in (0, 1], got {self.hedge_weight}, "
                             f"{self.confident_worst_fold}")
        fams = self.families or default_families(self.subset_kw)
        fit, _ = self.split(log)
        chans = list(log.disp_um)
        cache = {}
        folds = rolling_origin_folds(len(fit), self.n_folds, self.cv_start)
        h = (1 - self.fit_fraction) / self.fit_fraction if self.horizon is None else self.horizon
        hfolds = horizon_folds(len(fit), h, self.n_horizon_folds, self.cv_start)
        U = input_matrix(log, fit, cache)
        nfolds, self.novelty_ = novelty_folds(U, self.n_novelty_blocks, self.n_novelty_folds) \
            if self.n_novelty_folds else ([], np.zeros(0))
        self.fold_errors_ = []
        fr, fh, fn = {}, {}, {}
        resid = cv_residuals(log, fams, chans, folds, cache, self.fold_errors_, fr)
        hresid = cv_residuals(log, fams, chans, hfolds, cache, self.fold_errors_, fh)
        nresid = cv_residuals(log, fams, chans, nfolds, cache, self.fold_errors_, fn)
        # ρ of every validation row from its fold's training rows (the per-sample shrinkage and the band grow with it):
        # the raw inputs' ρ, and per candidate the larger of it and the ρ of the candidate's OWN features (its filtered
        # inputs / states, its selected sensors): a model extrapolates in what it computes from, not only in the raw inputs
        raw_rho = {id(fs): [relative_distance(U[tr], U[va]) for tr, va in fs]
                   for fs in (folds, hfolds, nfolds)}
        frho_cache = {}

        def cand_rho(fs, featlists):
            out = []
            for i, ((tr, va), feats) in enumerate(zip(fs, featlists)):
                r = raw_rho[id(fs)][i]
                if self.feature_distance and feats:
                    key = (id(fs), i, tuple(f.key for f in feats))
                    if key not in frho_cache:
                        F = feature_matrix(log, feats, cache)
                        frho_cache[key] = np.maximum(r, relative_distance(F[tr], F[va]))
                    r = frho_cache[key]
                out.append(r)
            return out
        self.cv_, self.cv_horizon_, self.cv_novelty_, self.gate_, self.chosen_ = {}, {}, {}, {}, {}
        self.band_, self.band_ols_, self.shrink_, self.gain_, self.eligible_ = {}, {}, {}, {}, {}
        self.scale_, self.worst_fold_, self.fold_ratios_, self.fold_rho_, self.candidates_ = {}, {}, {}, {}, {}
        self.band_alt_, self.score_ = {}, {}
        for ch in chans:
            base = ("ols", "")
            full = {k[1:]: v for k, v in resid.items() if k[0] == ch and len(v) == len(folds)
                    and len(hresid.get(k, [])) == len(hfolds) and len(nresid.get(k, [])) == len(nfolds)}
            if base not in full:
                raise ValueError(f"{log.path}: the OLS baseline could not be fitted on the cross-validation folds")
            r0, h0, n0 = resid[(ch, *base)], hresid[(ch, *base)], nresid[(ch, *base)]
            scores, gate, rhos = {}, {}, {}
            for k in full:
                rho_r = cand_rho(folds, fr[(ch, *k)])
                rho_h = cand_rho(hfolds, fh[(ch, *k)])
                rho_n = cand_rho(nfolds, fn[(ch, *k)])
                rhos[k] = (rho_r, rho_h, rho_n)
                for w in ((1.0,) if k == base else self.shrink_weights):
                    # g's scale: the one of lowest RMS on the novelty folds (ties: the least shrinkage)
                    sc = np.inf
                    if nfolds and k != base:
                        sres, s0, srho = nresid[(ch, *k)], n0, rho_n
                        sc = min(self.shrink_scales, key=lambda s: (round(_rms(np.concatenate(
                            _blend_residuals(w, sres, s0, srho, s))), 12), -s))
                    key = (k[0], k[1], w)
                    scores[key], gate[key] = blend_statistics(
                        w, sc, (resid[(ch, *k)], hresid[(ch, *k)], nresid[(ch, *k)]), (r0, h0, n0),
                        rhos[k], self.gate_se, self.ranking_fold_loss)
            r_ols = scores[(*base, 1.0)]["ranking"]
            ok = [k for k in scores if k[0] != "ols" and self.eligible(scores[k], gate[k], k[2], r_ols, bool(nfolds))]
            # the largest score (ties: the larger mean gain); "worst_fold": the best worst fold
            best = max(ok, key=lambda k: (fold_gain_score(scores[k], self.selection), scores[k]["gain"])) \
                if ok else (*base, 1.0)

            def name(k):
                return candidate_name(*k)
            self.cv_[ch] = {name(k): s["ranking"] for k, s in scores.items()}
            self.cv_horizon_[ch] = {name(k): s["horizon"] for k, s in scores.items()}
            self.cv_novelty_[ch] = {name(k): s["novelty"] for k, s in scores.items()}
            self.gate_[ch] = {name(k): (g[0][0] and g[1][0], g[0][1], g[0][2], g[1][1], g[1][2])
                              for k, g in gate.items()}
            self.gain_[ch] = {name(k): float(s["gain"]) for k, s in scores.items()}
            self.score_[ch] = {name(k): fold_gain_score(s, self.selection) for k, s in scores.items()}
            self.worst_fold_[ch] = {name(k): float(s["worst_fold"]) for k, s in scores.items()}
            self.fold_ratios_[ch] = {name(k): s["fold_ratios"] for k, s in scores.items()}
            self.fold_rho_[ch] = {name(k): s["fold_rho"] for k, s in scores.items()}
            self.candidates_[ch] = {k: dict(s, gate=gate[k]) for k, s in scores.items()}
            self.eligible_[ch] = sorted(name(k) for k in ok)
            self.chosen_[ch] = best[:2]
            self.shrink_[ch] = best[2]
            self.scale_[ch] = scores[best]["scale"]
            self.band_[ch] = band_of(scores[best], self.band_rule)
            self.band_alt_[ch] = {r: band_of(scores[best], r) for r in BAND_RULES if r != self.band_rule}
            self.band_ols_[ch] = band_of(scores[(*base, 1.0)], self.band_rule)
        self.model_, self.baseline_ = self._final_models(log, fams, chans, fit, cache, U, nfolds, folds, hfolds, h)
        self.deployed_ = None
        if self.deploy:
            sub = getattr(self, "subset_modeller_", None)   # the validated fit's sensor selection stays the one reported
            # the chosen candidates (family, hyper-parameter, weight, scale, band) refitted on every row
            rows = np.arange(len(log.time_s))
            self.deployed_, _ = self._final_models(log, fams, chans, rows, cache, input_matrix(log, rows, cache),
                                                   nfolds, folds, hfolds, h)
            self.deployed_.meta["validated_on_rows"] = int(len(fit))
            if sub is not None:
                self.subset_modeller_ = sub
        self.cache_ = cache
        return self

    def _final_models(self, log, fams, chans, fit, cache, U, nfolds, folds, hfolds, h):
        """The chosen candidates of every channel (``chosen_``, ``shrink_``, ``scale_``, ``band_``) and the OLS
        baseline fitted on the rows ``fit`` (the fitting part, or with ``deploy`` every row): (model, baseline)."""
        final = {}
        for fam in fams:
            need = [ch for ch in chans if self.chosen_[ch][0] == fam.name or fam.name == "ols"]
            if need:
                final[fam.name] = fam.fit(log, need, fit, cache)
                if fam.name == "subset_lag":
                    self.subset_modeller_ = fam.last_modeller_
        mu, W = whitener(U)
        dval = [mahalanobis(U[va], *whitener(U[tr])) for tr, va in nfolds]
        temps, speed = _inputs(log, fit)
        meta = {"log": str(log.path), "fit_rows": int(len(fit)), "fit_until_s": float(log.time_s[fit[-1]]),
                "selection": f"rolling-origin CV on the fitting part: the candidate (a family blended with OLS, "
                             f"weight {', '.join(f'{w:g}' for w in self.shrink_weights)}; above "
                             f"{self.hedge_weight:g} only where every fold's RMS is ≤ {self.confident_worst_fold:g}× "
                             f"OLS's) "
                             + {"worst_fold": "whose worst fold (RMS ratio to OLS) is smallest",
                                "mean_gain": "of largest mean log-gain over OLS",
                                "lcb": f"of largest one-sided {LCB_LEVEL:.0%} lower confidence bound on its horizon "
                                       "and novelty fold log-gains (Student's t), itself above 0",
                                "median_fold": "of largest median horizon/novelty fold log-gain",
                                "trimmed_fold": "of largest mean horizon/novelty fold log-gain without its best fold "
                                                f"(itself at least {self.min_gain:.3g})",
                                "rho_weighted": "of largest horizon/novelty fold log-gain weighted by the folds' "
                                                "median distance"}[self.selection]
                             + f" among those below OLS on {len(folds)} ranking "
                             f"folds that beat OLS by > {self.gate_se:g} SE on {len(hfolds)} horizon folds (horizon "
                             f"{h:.3g}) and on {len(nfolds)} novelty folds (the most novel blocks of the fitting "
                             f"part, held out), with no fold worse than OLS by more than {self.max_fold_loss:g}×; "
                             "else OLS",
                "novelty": {"inputs": temps + (["speed_rpm"] if speed else []), "mean": mu.tolist(),
                            "whiten": W.tolist(),
                            "validated_distance": float(np.quantile(np.concatenate(dval), 0.9)) if dval else None,
                            "fit_distance_q99": float(np.quantile(mahalanobis(U, mu, W), 0.99)),
                            "range_distance": float(np.quantile(mahalanobis(U, mu, W), RANGE_QUANTILE))}}
        chosen = {}
        for ch in chans:
            f, hy = self.chosen_[ch]
            feats, a, b = final[f][ch][hy]
            w = self.shrink_[ch]
            feats, a, b = blend_with_ols((feats, a, b), final["ols"][ch][""], w)
            sc = self.scale_[ch]
            own = final[f][ch][hy][0]
            nv = feature_novelty(own, feature_matrix(log, own, cache)[fit]) \
                if self.feature_distance and f != "ols" and own else None
            chosen[ch] = ChannelFit(f, hy if w == 1.0 else f"{hy}{';' if hy else ''}shrink_to_ols_w={w:g}", feats, a,
                                    np.asarray(b), self.band_[ch][0],
                                    base=final["ols"][ch][""] if np.isfinite(sc) else None,
                                    shrink_scale=float(sc), novelty=nv, band_gamma=self.band_[ch][1])
        return DriftModel(chosen, meta), DriftModel({ch: ChannelFit("ols", "", *final["ols"][ch][""], self.band_ols_[ch][0],
                                                    band_gamma=self.band_ols_[ch][1]) for ch in chans}, meta)

    def predict(self, log: DriftLog) -> dict:
        """The chosen model's drift {channel: (n,)} μm at every row of ``log`` (causal: row i uses rows ≤ i)."""
        self._check_fitted("model_")
        return self.model_.predict(log)

    def family_best(self, ch) -> dict:
        """Best CV RMS of each family for channel ``ch`` (over its hyper-parameters): {family: (candidate, RMS)}."""
        out = {}
        for k, v in self.cv_[ch].items():
            f = k.split("[")[0].split("~")[0]
            if f not in out or v < out[f][1]:
                out[f] = (k, v)
        return out

    def report(self, log: DriftLog) -> dict:
        """Per channel: chosen candidate, CV scores per family, held-out before / volcomp / OLS, band coverage."""
        _, hold = self.split(log)
        pred = self.model_.predict(log, self.cache_)
        base = self.baseline_.predict(log, self.cache_)
        bands = self.model_.band_um(log, self.cache_)
        rhos = self.model_.channel_rho(log, self.cache_)
        out = {}
        for ch in self.model_.channels:
            d = log.disp_um[ch][hold]
            a = d - pred[ch][hold]
            b = d - base[ch][hold]
            f, h = self.chosen_[ch]
            w = self.shrink_[ch]
            name = candidate_name(f, h, w)
            band = self.model_.channels[ch].band95_um
            grow = np.ones(len(log.time_s)) if rhos[ch] is None else np.maximum(1.0, rhos[ch])
            alt = {r: qg[0] * grow ** qg[1] for r, qg in self.band_alt_[ch].items()}
            alt_rule = next(iter(alt))

            def rms(v):
                return float(np.sqrt(np.mean(v**2)))
            out[ch] = {"model": name, "family": f, "shrink_weight": w,
                       "cv_rms_um": {k: v[1] for k, v in self.family_best(ch).items()},
                       "cv_rms_ols_um": self.cv_[ch]["ols"],
                       "cv_ranking_rms_um": self.cv_[ch][name],
                       "cv_horizon_rms_um": self.cv_horizon_[ch][name],
                       "cv_horizon_rms_ols_um": self.cv_horizon_[ch]["ols"],
                       "cv_novelty_rms_um": self.cv_novelty_[ch][name],
                       "cv_novelty_rms_ols_um": self.cv_novelty_[ch]["ols"],
                       "best_ranked": min(self.cv_[ch], key=self.cv_[ch].get),
                       "refused_by_gate": sorted(k for k, v in self.cv_[ch].items()
                                                 if v < self.cv_[ch]["ols"] and not self.gate_[ch][k][0]),
                       "worst_fold_ratio": self.worst_fold_[ch][name],
                       "selection_score": self.score_[ch][name],
                       "rms_before_um": rms(d), "rms_after_um": rms(a), "rms_ols_um": rms(b),
                       "max_before_um": float(np.abs(d).max()), "max_after_um": float(np.abs(a).max()),
                       "distance_scale": self.scale_[ch] if np.isfinite(self.scale_[ch]) else None,
                       "heldout_rho_median": None if rhos[ch] is None else float(np.median(rhos[ch][hold])),
                       "band95_um": band, "band_coverage_heldout": float(np.mean(np.abs(a) <= bands[ch][hold])),
                       "band_halfwidth_heldout_median_um": float(np.median(bands[ch][hold])),
                       "band_gamma": self.model_.channels[ch].band_gamma,
                       "band_rule": self.band_rule, "band_alt_rule": alt_rule,
                       "band_alt95_um": self.band_alt_[ch][alt_rule][0],
                       "band_alt_coverage_heldout": float(np.mean(np.abs(a) <= alt[alt_rule][hold])),
                       "band_alt_halfwidth_heldout_median_um": float(np.median(alt[alt_rule][hold])),
                       # every band rule on the same held-out part: {rule: {q_um, gamma, coverage, halfwidth_median_um}}
                       "bands_heldout": {self.band_rule: {
                           "q_um": band, "gamma": self.model_.channels[ch].band_gamma,
                           "coverage": float(np.mean(np.abs(a) <= bands[ch][hold])),
                           "halfwidth_median_um": float(np.median(bands[ch][hold]))}} | {
                           r: {"q_um": self.band_alt_[ch][r][0], "gamma": self.band_alt_[ch][r][1],
                               "coverage": float(np.mean(np.abs(a) <= v[hold])),
                               "halfwidth_median_um": float(np.median(v[hold]))} for r, v in alt.items()}}
        return out


# -- physically constrained families and novelty folds (issue 29) -------------------------------
# Physically constrained drift families and the novelty folds of the selection (issue 29).
#
# Families (each a :class:`~errormap.diagnosis.drift_models._Family`: ``fit(log, channels, rows, cache)``
# → {channel: {hyper: (features, intercept, coef)}}):
#
# * ``thermal_nn`` — **first-order thermal responses with non-negative gains**: every input (each
#   temperature, ``speed_rpm``) through first-order lags of ``TAU_BANK_S``; each input is oriented by
#   the sign of its plain least-squares coefficient on the training rows, and the gains of its lags
#   are then constrained ≥ 0 (non-negative least squares, a small ridge λ as the hyper-parameter).
#   So each input's step response is a sum of first-order responses of ONE sign: monotone, no
#   overshoot, no cancelling pair of large opposite gains — what a body heated through conduction
#   does, and what extrapolates without the see-saw of unconstrained filter banks.
# * ``greybox`` — **a one-state grey-box state-space model per channel**: ``d = c + Σ D_i u_i + x``,
#   ``τ·dx/dt = −x + Σ g_i u_i`` (direct feed-through of every input as logged, plus one thermal state
#   of time constant τ driven by all inputs); τ is the hyper-parameter (``GREYBOX_TAUS_S``), the
#   gains are identified by ridge-stabilised least squares (``GREYBOX_LAMBDA``).
# * ``ols_stable`` — **OLS with sensor selection by stability across folds**: forward stepwise
#   selection (BIC) is run on ``STABLE_SUBSAMPLES`` contiguous-block subsamples of the training rows
#   (each leaves one block out); the inputs selected in at least ``STABLE_FREQ`` of them are kept
#   and fitted by plain least squares. A sensor that enters only on some stretches of the log is
#   left out: it is what made OLS on all sensors swing when a later stretch differs.
#
# Measured in issue 29's third round and NOT defaults (:func:`measured_families`; docs/drift_model.md):
# ``gradient`` (temperature differences to the coolest sensor; ``sum0`` without any absolute temperature),
# ``modes`` (OLS on the first k principal components of the temperatures in °C), ``greybox_modes`` (the
# grey-box state on those modes), ``ols_stable_lag`` (stably selected inputs through one lag each).
#
# Novelty folds (:func:`novelty_folds`): the fitting part is cut into ``n_blocks`` contiguous blocks;
# each block's inputs are scored by their Mahalanobis distance from the OTHER rows (mean and covariance
# of the inputs outside the block and its guard rows, whitened on the principal axes, eigenvalues
# floored at ``COV_FLOOR`` of the largest); the ``n_folds`` blocks of largest median distance are the
# validation blocks, each trained on every row outside it and its guard (``guard`` blocks' worth of
# rows on each side are left out of training: the drift is autocorrelated over hours). These are the
# conditions where a model must extrapolate, as it must on a future that leaves the fit range.


NN_LAMBDAS = (1e-4, 1e-2)           # ridge λ·n on standardised columns of the non-negative fit
GREYBOX_TAUS_S = (900.0, 3600.0, 10800.0)   # the state's time constant: 15 min, 1 h, 3 h
GREYBOX_LAMBDA = 1e-4
STABLE_SUBSAMPLES = 5
STABLE_FREQ = 0.8                   # kept when selected in ≥ 4 of 5 subsamples
STABLE_MAX_INPUTS = 8
COV_FLOOR = 1e-4                    # eigenvalue floor of the inputs' correlation matrix (relative to the largest):
                                    # directions whose spread is below 1 % of the dominant one carry sensor noise
                                    # and offsets, not operating conditions



def _oriented_nnls(X, y, lam):
    """Non-negative least squares on standardised columns with a ridge λ·n: (intercept, coef (p,)).
    Columns whose sign must be free are passed twice by the caller (± copies) — here all are ≥ 0."""
    mu, sd = _standardise(X)
    Z = (X - mu) / sd
    ym = y.mean()
    n, p = Z.shape
    A = np.vstack([Z, np.sqrt(lam * n) * np.eye(p)])
    b = np.concatenate([y - ym, np.zeros(p)])
    w, _ = nnls(A, b, maxiter=50 * p)
    coef = w / sd
    return float(ym - mu @ coef), coef


class ThermalNNFamily(_Family):
    """First-order responses of every input with non-negative (sign-oriented) gains; hyper: ridge λ."""

    name = "thermal_nn"

    def __init__(self, taus=TAU_BANK_S, lambdas=NN_LAMBDAS):
        self.taus, self.lambdas = taus, lambdas

    def fit(self, log, channels, rows, cache):
        temps, speed = _inputs(log, rows)
        ins = temps + (["speed_rpm"] if speed else [])
        raw = feature_matrix(log, [Feature(i) for i in ins], cache)[rows]
        feats = [Feature(i, tau) for i in ins for tau in self.taus]
        X = feature_matrix(log, feats, cache)[rows]
        out = {}
        for ch in channels:
            y = log.disp_um[ch][rows]
            _, b_ols = fit_ols(raw, y)
            sign = np.repeat(np.where(b_ols >= 0, 1.0, -1.0), len(self.taus))
            hyp = {}
            for lam in self.lambdas:
                a, c = _oriented_nnls(X * sign, y, lam)
                hyp[f"lambda={lam:g}"] = (feats, a, c * sign)
            out[ch] = hyp
        return out


class GreyBoxFamily(_Family):
    """One thermal state per channel driven by every input, plus direct feed-through; hyper: τ."""

    name = "greybox"

    def __init__(self, taus=GREYBOX_TAUS_S, lam=GREYBOX_LAMBDA):
        self.taus, self.lam = taus, lam

    def fit(self, log, channels, rows, cache):
        temps, speed = _inputs(log, rows)
        ins = temps + (["speed_rpm"] if speed else [])
        Y = np.stack([log.disp_um[ch][rows] for ch in channels], axis=1)
        out = {ch: {} for ch in channels}
        for tau in self.taus:
            feats = [Feature(i) for i in ins] + [Feature(i, tau) for i in ins]
            X = feature_matrix(log, feats, cache)[rows]
            paths = fit_ridge_path(X, Y, [self.lam])
            for j, ch in enumerate(channels):
                a, b = paths[j][0]
                out[ch][f"tau={tau:g}"] = (feats, a, b)
        return out


def _forward_bic(X, y, max_inputs):
    """Forward stepwise least squares (with intercept) by BIC, from the centred Gram matrix: the
    selected column indices."""
    n = len(y)
    Xc = X - X.mean(axis=0)
    yc = y - y.mean()
    G, b, yy = Xc.T @ Xc, Xc.T @ yc, float(yc @ yc)
    chosen = []
    bic = n * np.log(max(yy, 1e-300) / n) + np.log(n)
    while len(chosen) < min(max_inputs, X.shape[1]):
        best = None
        for j in range(X.shape[1]):
            if j in chosen:
                continue
            S = chosen + [j]
            try:
                r = yy - float(b[S] @ np.linalg.solve(G[np.ix_(S, S)], b[S]))
            except np.linalg.LinAlgError:
                continue
            if best is None or r < best[0]:
                best = (r, j)
        if best is None:
            break
        r, j = best
        bb = n * np.log(max(r, 1e-300) / n) + (len(chosen) + 2) * np.log(n)
        if bb >= bic:
            break
        bic = bb
        chosen.append(j)
    return chosen


def _stable_selection(X, y, edges, max_inputs, group=None):
    """Forward BIC on each leave-one-block-out subsample of the rows (``edges``: block bounds): per column,
    how often it was selected (count (p,)), and per group of columns (``group`` (p,) ints, default one
    per column) in how many subsamples any of its columns was (presence (g,)), each for the first k
    selected, for every k of ``max_inputs``: {k: (count (p,), presence (g,))}."""
    group = np.arange(X.shape[1]) if group is None else np.asarray(group)
    ng = int(group.max()) + 1 if group.size else 0
    out = {k: (np.zeros(X.shape[1]), np.zeros(ng)) for k in max_inputs}
    n = edges[-1]
    for j in range(len(edges) - 1):
        keep = np.r_[0:edges[j], edges[j + 1]:n]
        sel = _forward_bic(X[keep], y[keep], max(max_inputs))
        for k in max_inputs:
            cnt, pres = out[k]
            cnt[sel[:k]] += 1
            pres[np.unique(group[sel[:k]])] += 1
    return out


class StableOLSFamily(_Family):
    """OLS on the inputs that forward selection picks in ≥ ``freq`` of the block subsamples."""

    name = "ols_stable"

    def __init__(self, n_sub=STABLE_SUBSAMPLES, freq=STABLE_FREQ, max_inputs=STABLE_MAX_INPUTS):
        self.n_sub, self.freq, self.max_inputs = n_sub, freq, max_inputs

    def fit(self, log, channels, rows, cache):
        temps, speed = _inputs(log, rows)
        ins = temps + (["speed_rpm"] if speed else [])
        feats = [Feature(i) for i in ins]
        X = feature_matrix(log, feats, cache)[rows]
        edges = np.linspace(0, len(rows), self.n_sub + 1).round().astype(int)
        out = {}
        for ch in channels:
            y = log.disp_um[ch][rows]
            count, _ = _stable_selection(X, y, edges, (self.max_inputs,))[self.max_inputs]
            sel = np.flatnonzero(count >= self.freq * self.n_sub)
            fs = [feats[i] for i in sel]
            out[ch] = {"": (fs, *fit_ols(X[:, sel], y))}
        return out


STABLE_LAG_MAX_INPUTS = (3, 6)      # "a few" inputs: the hyper-parameter (forward selection is nested, one run gives both)


class StableLagOLSFamily(_Family):
    """OLS on a few inputs, each through ONE first-order lag, the inputs and their time constants both chosen by
    stability across leave-one-block-out subsamples of the training rows: forward BIC over every input × lag of
    ``taus``; an input is kept when some lag of it was selected in ≥ ``freq`` of the subsamples, at the time
    constant selected most often (ties: the shorter). Hyper: the number of inputs forward selection may take
    (``k=3``, ``k=6``)."""

    name = "ols_stable_lag"

    def __init__(self, taus=TAU_BANK_S, max_inputs=STABLE_LAG_MAX_INPUTS, n_sub=STABLE_SUBSAMPLES,
                 freq=STABLE_FREQ):
        self.taus, self.max_inputs, self.n_sub, self.freq = taus, tuple(max_inputs), n_sub, freq

    def fit(self, log, channels, rows, cache):
        temps, speed = _inputs(log, rows)
        ins = temps + (["speed_rpm"] if speed else [])
        nt = len(self.taus)
        feats = [Feature(i, tau) for i in ins for tau in self.taus]
        X = feature_matrix(log, feats, cache)[rows]
        group = np.repeat(np.arange(len(ins)), nt)
        edges = np.linspace(0, len(rows), self.n_sub + 1).round().astype(int)
        out = {}
        for ch in channels:
            y = log.disp_um[ch][rows]
            stab = _stable_selection(X, y, edges, self.max_inputs, group)
            hyp = {}
            for k in self.max_inputs:
                cnt, pres = stab[k]
                keep = np.flatnonzero(pres >= self.freq * self.n_sub)
                cols = [i * nt + int(np.argmax(cnt[i * nt:(i + 1) * nt])) for i in keep]
                fs = [feats[c] for c in cols]
                hyp[f"k={k}"] = (fs, *fit_ols(X[:, cols], y))
            out[ch] = hyp
        return out


class GradientFamily(_Family):
    """Temperature DIFFERENCES as inputs: each temperature minus the coolest sensor's (the reference nearest the
    shop air, by median over the training rows), plus the spindle speed.

    * ``sum0``: OLS on every difference + speed, no absolute temperature — the temperature gains sum to zero, so
      a uniform shift of every temperature (a warmer shop, the whole machine warmer by the same amount) moves
      nothing; only gradients across the structure do;
    * ``stable``: OLS on the differences, the reference's own temperature and the speed that forward BIC selects
      in ≥ ``freq`` of the leave-one-block-out subsamples (the absolute temperature enters only where it is
      stably needed).

    Returned in the raw inputs (a difference's gain is the sensor's gain, minus on the reference), so the
    controller form is the OLS baseline's features with constrained coefficients."""

    name = "gradient"

    def __init__(self, n_sub=STABLE_SUBSAMPLES, freq=STABLE_FREQ, max_inputs=STABLE_MAX_INPUTS):
        self.n_sub, self.freq, self.max_inputs = n_sub, freq, max_inputs

    def fit(self, log, channels, rows, cache):
        temps, speed = _inputs(log, rows)
        if len(temps) < 2:
            raise ValueError("gradient: fewer than two temperatures vary on the training rows")
        ins = temps + (["speed_rpm"] if speed else [])
        feats = [Feature(i) for i in ins]
        X = feature_matrix(log, feats, cache)[rows]                      # (n, p): temperatures, then speed
        nt = len(temps)
        ref = int(np.argmin(np.median(X[:, :nt], axis=0)))
        others = [i for i in range(nt) if i != ref]
        # Z = X @ M: [T_i − T_ref for i ≠ ref] + [T_ref] + [speed]
        M = np.zeros((len(ins), len(others) + 1 + int(speed)))
        for j, i in enumerate(others):
            M[i, j], M[ref, j] = 1.0, -1.0
        M[ref, len(others)] = 1.0
        if speed:
            M[nt, -1] = 1.0
        Z = X @ M
        sum0 = [j for j in range(M.shape[1]) if j != len(others)]       # every column but the absolute reference
        edges = np.linspace(0, len(rows), self.n_sub + 1).round().astype(int)
        out = {}
        for ch in channels:
            y = log.disp_um[ch][rows]
            hyp = {}
            a, c = fit_ols(Z[:, sum0], y)
            hyp["sum0"] = (feats, a, M[:, sum0] @ c)
            cnt, _ = _stable_selection(Z, y, edges, (self.max_inputs,))[self.max_inputs]
            sel = np.flatnonzero(cnt >= self.freq * self.n_sub)
            a, c = fit_ols(Z[:, sel], y)
            hyp["stable"] = (feats, a, M[:, sel] @ c)
            out[ch] = hyp
        return out


MODE_COUNTS = (1, 2, 3, 5)           # temperature modes kept (the hyper-parameter)


def _mode_maps(X, nt: int, speed: bool, counts) -> dict:
    """The maps raw inputs → (first k temperature modes, speed) for each k of ``counts`` that the ``nt``
    temperatures allow: {k: M (p, k + speed)}. ``X`` (n, p): the training rows' temperatures (first ``nt``
    columns, °C) then the speed; the modes are the principal directions of the temperatures centred on
    these rows, not scaled."""
    T = X[:, :nt]
    _, _, Vt = np.linalg.svd(T - T.mean(axis=0), full_matrices=False)
    out = {}
    for k in counts:
        if k > nt:
            continue
        M = np.zeros((X.shape[1], k + int(speed)))
        M[:nt, :k] = Vt[:k].T
        if speed:
            M[nt, k] = 1.0
        out[k] = M
    return out


def _mode_inputs(log, channels, rows, cache, counts):
    """What the mode families fit on: (raw input names (temperatures, then the speed where it varies), their
    matrix X (n, p) on ``rows``, :func:`_mode_maps` of X for ``counts``, the displacements Y (n, channels))."""
    temps, speed = _inputs(log, rows)
    ins = temps + (["speed_rpm"] if speed else [])
    X = feature_matrix(log, [Feature(i) for i in ins], cache)[rows]
    Y = np.stack([log.disp_um[ch][rows] for ch in channels], axis=1)
    return ins, X, _mode_maps(X, len(temps), speed, counts), Y


class ModesFamily(_Family):
    """OLS on the first k MODES of the temperature field + the spindle speed: the principal components of the
    temperatures in °C (centred on the training rows, not scaled: a mode is a pattern of kelvins across the
    structure — the first is close to a uniform warming, the next are the main gradients), k ∈ ``counts``.
    Directions of the temperature field the training rows barely excite (sensor offsets, noise) get no gain,
    so a later temperature field that moves along them is not extrapolated with the large opposite gains
    least squares gives to nearly collinear sensors. Returned in the raw temperatures (gain = mode loadings ×
    mode gains): the controller form is the OLS baseline's features with constrained coefficients."""

    name = "modes"

    def __init__(self, counts=MODE_COUNTS):
        self.counts = tuple(counts)

    def fit(self, log, channels, rows, cache):
        ins, X, modes, Y = _mode_inputs(log, channels, rows, cache, self.counts)
        feats = [Feature(i) for i in ins]
        out = {ch: {} for ch in channels}
        for k, M in modes.items():
            A = np.column_stack([np.ones(len(rows)), X @ M])
            th = np.linalg.lstsq(A, Y, rcond=None)[0]
            for j, ch in enumerate(channels):
                out[ch][f"k={k}"] = (feats, float(th[0, j]), M @ th[1:, j])
        return out


GREYBOX_MODE_COUNTS = (1, 2)         # temperature modes driving the grey-box state


class GreyBoxModesFamily(_Family):
    """A one-state grey-box model per channel on the temperature field's first k MODES (:class:`ModesFamily`) and
    the spindle speed: ``d = c + Σ D_j m_j + x``, ``τ·dx/dt = −x + Σ g_j m_j`` with m = (modes, speed) — the
    feed-through and the slow thermal state of :class:`GreyBoxFamily`, with 2·(k + 1) gains instead of two per
    sensor. Least squares; hyper: k ∈ ``counts`` and τ ∈ ``taus``. Returned in the raw inputs and their lags."""

    name = "greybox_modes"

    def __init__(self, counts=GREYBOX_MODE_COUNTS, taus=GREYBOX_TAUS_S):
        self.counts, self.taus = tuple(counts), tuple(taus)

    def fit(self, log, channels, rows, cache):
        ins, X, modes, Y = _mode_inputs(log, channels, rows, cache, self.counts)
        raw = [Feature(i) for i in ins]
        out = {ch: {} for ch in channels}
        for tau in self.taus:
            lag = [Feature(i, tau) for i in ins]
            XL = feature_matrix(log, lag, cache)[rows]
            for k, M in modes.items():
                q = M.shape[1]
                A = np.column_stack([np.ones(len(rows)), X @ M, XL @ M])
                th = np.linalg.lstsq(A, Y, rcond=None)[0]
                for j, ch in enumerate(channels):
                    out[ch][f"k={k};tau={tau:g}"] = (raw + lag, float(th[0, j]),
                                                     np.concatenate([M @ th[1:1 + q, j], M @ th[1 + q:, j]]))
        return out


def whitener(U):
    """Mean (k,) and whitening matrix W (k, r) of the rows of ``U`` (n, k): ‖(u − mean)·W‖ is the
    Mahalanobis distance on the principal axes of the CORRELATION matrix (each input first divided by
    its spread, so that speed in rpm does not outweigh temperatures in °C) with eigenvalues above
    ``COV_FLOOR`` of the largest."""
    mu = U.mean(axis=0)
    sd = U.std(axis=0)
    sd = np.where(sd > 0, sd, 1.0)
    C = np.cov((U - mu) / sd, rowvar=False).reshape(U.shape[1], U.shape[1])
    ev, V = np.linalg.eigh(C)
    keep = ev > COV_FLOOR * max(ev.max(), 1e-300)
    return mu, (V[:, keep] / np.sqrt(ev[keep])) / sd[:, None]


def mahalanobis(U, mu, W) -> np.ndarray:
    """Distances (n,) of the rows of ``U`` (n, k) from the reference of :func:`whitener`."""
    return np.linalg.norm((U - mu) @ W, axis=1)


BAND_GAMMAS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)   # exponents γ tried for the ρ-power band q·max(1, ρ)^γ
BAND_SUBSET_SE = 1.0   # a subset's coverage counts as reaching the level within one binomial standard error of it
LCB_LEVEL = 0.95   # one-sided level of the lower confidence bound on the fold log-gains ("lcb" selection)


BAND_RULES = ("fold_residual", "rho_scaled", "rho_power", "fold_flat")


def band_of(stats: dict, rule: str) -> tuple[float, float]:
    """(q μm, γ) of a candidate's band under ``rule`` (band(ρ) = q·max(1, ρ)^γ) from its validation statistics:
    ``fold_residual`` and ``rho_scaled`` grow with γ = 1, ``rho_power`` with its fitted γ; ``fold_flat`` is the
    split-conformal quantile of ``fold_residual`` without growth (γ = 0: the folds' far rows are in it already)."""
    if rule == "rho_power":
        q, g = stats["band_rho_power"]
        return float(q), float(g)
    if rule == "fold_flat":
        return float(stats["band_fold_residual"]), 0.0
    return float(stats[f"band_{rule}"]), 1.0


def rho_power_band(abs_resid, rho, level: float = BAND_QUANTILE, gammas=BAND_GAMMAS) -> tuple[float, float]:
    """The ρ-power band of validation residuals: (q, γ) with band(ρ) = q·max(1, ρ)^γ.

    ``abs_resid`` (n,) |residual| μm and ``rho`` (n,) of the fold rows. For each γ, q is the split-conformal
    ``level`` quantile of |r| / max(1, ρ)^γ (so the fold rows are covered at ``level`` whatever γ); γ is the
    smallest of ``gammas`` for which the band ALSO covers ``level`` of the out-of-range rows (ρ > 1) and of
    the farther half of them (each within ``BAND_SUBSET_SE`` binomial standard errors of it): the band's growth with ρ is fitted on how the folds' errors grew with it,
    not assumed. No row with ρ > 1: γ = 1 (the conservative growth of the default band); no γ enough: the
    largest."""
    r = np.asarray(abs_resid, float)
    q_rho = np.maximum(1.0, np.asarray(rho, float))
    out = q_rho > 1.0
    if not out.any():
        return conformal_quantile(r, level), 1.0
    far = out & (q_rho >= np.median(q_rho[out]))
    for g in gammas:
        grow = q_rho ** g
        q = conformal_quantile(r / grow, level)
        if all(np.mean(r[m] <= q * grow[m]) >= level - BAND_SUBSET_SE * np.sqrt(level * (1 - level) / m.sum())
               for m in (out, far)):
            return q, float(g)
    return q, float(gammas[-1])


def fold_gain_score(stats: dict, selection: str) -> float:
    """The number by which an eligible candidate is ranked (larger is better) under ``selection``, from its
    validation statistics (``DriftSelector.candidates_`` values: ``gain``, ``fold_ratios`` = (ranking,
    horizon, novelty) RMS ratios to OLS per fold, ``fold_rho_each`` = the folds' median ρ).

    d_i = −ln(ratio_i) on the horizon and novelty folds (K of them). ``mean_gain``: the mean log-gain over the
    ranking, horizon and novelty sets; ``worst_fold``: −ln of the worst ratio over every fold; ``lcb``: the
    one-sided ``LCB_LEVEL`` lower confidence bound mean(d) − t·sd(d)/√K (t of Student's law, K − 1 degrees);
    ``median_fold``: the median d; ``rho_weighted``: the mean of d weighted by each fold's median ρ (folds
    farther out count more, as the deployment's future is farther out than most folds); ``trimmed_fold``: the
    mean d without the largest one (a gain one lucky fold carries does not count; the selector also requires it
    ≥ ``min_gain``)."""
    if selection == "mean_gain":
        return float(stats["gain"])
    fr = stats["fold_ratios"]
    if selection == "worst_fold":
        return -float(np.log(max(max(x) for x in fr)))
    d = -np.log(np.asarray(list(fr[1]) + list(fr[2]), float))
    if selection == "median_fold":
        return float(np.median(d))
    if selection == "rho_weighted":
        w = np.maximum(np.asarray(list(stats["fold_rho_each"][1]) + list(stats["fold_rho_each"][2]), float), 1e-12)
        return float(np.sum(w * d) / np.sum(w))
    if selection == "trimmed_fold":
        return float(np.sort(d)[:-1].mean()) if len(d) > 1 else float(d.mean()) if len(d) else 0.0
    if selection == "lcb":
        from scipy.stats import t as student_t
        k = len(d)
        if k < 2:
            return float(d.mean()) if k else 0.0
        return float(d.mean() - student_t.ppf(LCB_LEVEL, k - 1) * d.std(ddof=1) / np.sqrt(k))
    raise ValueError(f"Expected selection in {SELECTIONS}, got {selection!r}")


SELECTIONS = ("mean_gain", "worst_fold", "lcb", "median_fold", "rho_weighted", "trimmed_fold")


def conformal_quantile(scores, level: float) -> float:
    """Split-conformal quantile of ``scores`` (n,): the ⌈(n + 1)·level⌉-th smallest (the largest when that
    exceeds n), so that a new exchangeable score falls at or below it with probability ≥ ``level``."""
    z = np.sort(np.asarray(scores, float).ravel())
    if not z.size:
        return float("nan")
    k = int(np.ceil((z.size + 1) * level))
    return float(z[min(k, z.size) - 1])


def distance_weight(rho, scale: float) -> np.ndarray:
    """g(ρ) (n,) of the per-sample shrinkage toward OLS: 1 for ρ = d/d0 ≤ 1 (inside the fit data's typical
    range), exp(−(ρ − 1)/scale) beyond; ``scale`` = inf keeps 1 everywhere. Monotone non-increasing in ρ."""
    rho = np.asarray(rho, float)
    if not np.isfinite(scale):
        return np.ones_like(rho)
    return np.exp(-np.maximum(rho - 1.0, 0.0) / scale)


def relative_distance(U_train, U_new) -> np.ndarray:
    """ρ (m,) = Mahalanobis distance of the rows of ``U_new`` (m, k) from ``U_train`` (n, k), divided by the
    ``RANGE_QUANTILE`` of the training rows' own distances (ρ ≤ 1: inside the training data's typical range)."""
    mu, W = whitener(U_train)
    d0 = float(np.quantile(mahalanobis(U_train, mu, W), RANGE_QUANTILE))
    rho = mahalanobis(U_new, mu, W) / max(d0, 1e-12)
    return rho


def feature_novelty(features, F_fit) -> dict:
    """The distance reference of a channel's own ``features`` from their values on the fit rows ``F_fit`` (n, p):
    {"features", "mean" (p,), "whiten" (p, r), "range_distance"} (:func:`whitener`, d0 = the ``RANGE_QUANTILE``
    of the fit rows' own distances)."""
    mu, W = whitener(F_fit)
    return {"features": list(features), "mean": mu, "whiten": W,
            "range_distance": max(float(np.quantile(mahalanobis(F_fit, mu, W), RANGE_QUANTILE)), 1e-12)}


def novelty_rho(nov: dict, F) -> np.ndarray:
    """ρ (n,) of the rows of ``F`` (n, p) (the features of ``nov``) from the reference of :func:`feature_novelty`."""
    return mahalanobis(F, np.asarray(nov["mean"], float), np.asarray(nov["whiten"], float)) / nov["range_distance"]


def input_matrix(log, rows, cache) -> np.ndarray:
    """The raw inputs (every varying temperature and speed) on ``rows``: (len(rows), k)."""
    temps, speed = _inputs(log, rows)
    return feature_matrix(log, [Feature(i) for i in temps + (["speed_rpm"] if speed else [])], cache)[rows]


def novelty_folds(U, n_blocks: int = 8, n_folds: int = 3, guard: float = 0.25):
    """Leave-block-out folds on the most novel blocks of the fitting part's inputs ``U`` (n, k).

    Returns ([(train (a,), validate (b,))], novelty (n_blocks,) median Mahalanobis distance of each
    block from the rows outside it and its guard)."""
    n = len(U)
    edges = np.linspace(0, n, n_blocks + 1).round().astype(int)
    g = int(round(guard * n / n_blocks))
    score, folds = [], []
    for i in range(n_blocks):
        a, b = edges[i], edges[i + 1]
        tr = np.r_[0:max(a - g, 0), min(b + g, n):n]
        mu, W = whitener(U[tr])
        score.append(float(np.median(mahalanobis(U[a:b], mu, W))))
        folds.append((tr, np.arange(a, b)))
    order = np.argsort(score)[::-1][:n_folds]
    return [folds[i] for i in sorted(order)], np.array(score)


def input_novelty(model, log) -> np.ndarray | None:
    """Mahalanobis distance (n,) of each row's inputs from the model's fitting data (``fitted_on.novelty``
    in drift_model.json), or None when the model records none. Causal: row by row."""
    nov = (model.meta or {}).get("novelty")
    if not nov:
        return None
    try:
        U = np.stack([input_values(log, name) for name in nov["inputs"]], axis=1)
    except InputError:          # an input the model does not need is missing: no distance, the prediction stands
        return None
    return mahalanobis(U, np.asarray(nov["mean"], float), np.asarray(nov["whiten"], float).reshape(len(nov["inputs"]), -1))


def input_rho(model, log) -> np.ndarray | None:
    """ρ (n,) = :func:`input_novelty` / the fit data's range distance d0 (``fitted_on.novelty.range_distance``),
    or None when the model records no distance."""
    nov = (model.meta or {}).get("novelty") or {}
    d0 = nov.get("range_distance")
    if not d0:
        return None
    d = input_novelty(model, log)
    if d is None:
        return None
    return d / float(d0)
