"""Physically constrained drift families and the novelty folds of the selection (issue 29).

Families (each a :class:`~errormap.diagnosis.drift_models._Family`: ``fit(log, channels, rows, cache)``
→ {channel: {hyper: (features, intercept, coef)}}):

* ``thermal_nn`` — **first-order thermal responses with non-negative gains**: every input (each
  temperature, ``speed_rpm``) through first-order lags of ``TAU_BANK_S``; each input is oriented by
  the sign of its plain least-squares coefficient on the training rows, and the gains of its lags
  are then constrained ≥ 0 (non-negative least squares, a small ridge λ as the hyper-parameter).
  So each input's step response is a sum of first-order responses of ONE sign: monotone, no
  overshoot, no cancelling pair of large opposite gains — what a body heated through conduction
  does, and what extrapolates without the see-saw of unconstrained filter banks.
* ``greybox`` — **a one-state grey-box state-space model per channel**: ``d = c + Σ D_i u_i + x``,
  ``τ·dx/dt = −x + Σ g_i u_i`` (direct feed-through of every input as logged, plus one thermal state
  of time constant τ driven by all inputs); τ is the hyper-parameter (``GREYBOX_TAUS_S``), the
  gains are identified by ridge-stabilised least squares (``GREYBOX_LAMBDA``).
* ``ols_stable`` — **OLS with sensor selection by stability across folds**: forward stepwise
  selection (BIC) is run on ``STABLE_SUBSAMPLES`` contiguous-block subsamples of the training rows
  (each leaves one block out); the inputs selected in at least ``STABLE_FREQ`` of them are kept
  and fitted by plain least squares. A sensor that enters only on some stretches of the log is
  left out: it is what made OLS on all sensors swing when a later stretch differs.

Novelty folds (:func:`novelty_folds`): the fitting part is cut into ``n_blocks`` contiguous blocks;
each block's inputs are scored by their Mahalanobis distance from the OTHER rows (mean and covariance
of the inputs outside the block and its guard rows, whitened on the principal axes, eigenvalues
floored at ``COV_FLOOR`` of the largest); the ``n_folds`` blocks of largest median distance are the
validation blocks, each trained on every row outside it and its guard (``guard`` blocks' worth of
rows on each side are left out of training: the drift is autocorrelated over hours). These are the
conditions where a model must extrapolate, as it must on a future that leaves the fit range.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from ..io import InputError

from .drift_models import (TAU_BANK_S, Feature, _Family, _inputs, _standardise, feature_matrix, fit_ols,
                           fit_ridge_path)

NN_LAMBDAS = (1e-4, 1e-2)           # ridge λ·n on standardised columns of the non-negative fit
GREYBOX_TAUS_S = (900.0, 3600.0, 10800.0)   # the state's time constant: 15 min, 1 h, 3 h
GREYBOX_LAMBDA = 1e-4
STABLE_SUBSAMPLES = 5
STABLE_FREQ = 0.8                   # kept when selected in ≥ 4 of 5 subsamples
STABLE_MAX_INPUTS = 8
COV_FLOOR = 1e-6                    # eigenvalue floor of the input covariance (relative to the largest)


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
            count = np.zeros(len(feats))
            for k in range(self.n_sub):
                keep = np.r_[0:edges[k], edges[k + 1]:len(rows)]
                count[_forward_bic(X[keep], y[keep], self.max_inputs)] += 1
            sel = np.flatnonzero(count >= self.freq * self.n_sub)
            fs = [feats[i] for i in sel]
            out[ch] = {"": (fs, *fit_ols(X[:, sel], y))}
        return out


def whitener(U):
    """Mean (k,) and whitening matrix W (k, r) of the rows of ``U`` (n, k): ‖(u − mean)·W‖ is the
    Mahalanobis distance on the principal axes with eigenvalues above ``COV_FLOOR`` of the largest."""
    mu = U.mean(axis=0)
    C = np.cov(U - mu, rowvar=False).reshape(U.shape[1], U.shape[1])
    ev, V = np.linalg.eigh(C)
    keep = ev > COV_FLOOR * max(ev.max(), 1e-300)
    return mu, V[:, keep] / np.sqrt(ev[keep])


def mahalanobis(U, mu, W) -> np.ndarray:
    """Distances (n,) of the rows of ``U`` (n, k) from the reference of :func:`whitener`."""
    return np.linalg.norm((U - mu) @ W, axis=1)


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
    from .drift_models import input_values
    nov = (model.meta or {}).get("novelty")
    if not nov:
        return None
    try:
        U = np.stack([input_values(log, name) for name in nov["inputs"]], axis=1)
    except InputError:          # an input the model does not need is missing: no distance, the prediction stands
        return None
    return mahalanobis(U, np.asarray(nov["mean"], float), np.asarray(nov["whiten"], float).reshape(len(nov["inputs"]), -1))
