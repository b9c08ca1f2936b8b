"""Physically constrained drift families (each a :class:`~errormap.diagnosis.drift_features._Family`).

* ``thermal_nn`` — each input (oriented by the sign of its least-squares coefficient) through first-order
  lags of ``TAU_BANK_S`` with gains ≥ 0 (non-negative least squares, a small ridge λ the hyper-parameter):
  monotone step responses, no cancelling pair of opposite gains;
* ``greybox`` — ``d = c + Σ D_i u_i + x``, ``τ·dx/dt = −x + Σ g_i u_i``, τ from ``GREYBOX_TAUS_S``, the gains
  by ridge-stabilised least squares (``GREYBOX_LAMBDA``);
* ``ols_stable`` — OLS on the inputs a forward stepwise selection (BIC) picks in at least ``STABLE_FREQ`` of
  ``STABLE_SUBSAMPLES`` block subsamples of the training rows.

The families side by side: ``docs/explanation/drift.md``."""
from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from .drift_features import TAU_BANK_S, Feature, _Family, _inputs, _standardise, feature_matrix, fit_ols, fit_ridge_path

NN_LAMBDAS = (1e-4, 1e-2)           # ridge λ·n on standardised columns of the non-negative fit
GREYBOX_TAUS_S = (900.0, 3600.0, 10800.0)   # the state's time constant: 15 min, 1 h, 3 h
GREYBOX_LAMBDA = 1e-4
STABLE_SUBSAMPLES = 5
STABLE_FREQ = 0.8                   # kept when selected in ≥ 4 of 5 subsamples
STABLE_MAX_INPUTS = 8


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
        ins = _inputs(log, rows)
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
        ins = _inputs(log, rows)
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


def _stable_selection(X, y, n_sub, max_inputs, group=None):
    """Forward BIC on each leave-one-block-out subsample of the rows (``n_sub`` equal blocks): per column,
    how often it was selected (count (p,)), and per group of columns (``group`` (p,) ints, default one
    per column) in how many subsamples any of its columns was (presence (g,)), each for the first k
    selected, for every k of ``max_inputs``: {k: (count (p,), presence (g,))}."""
    group = np.arange(X.shape[1]) if group is None else np.asarray(group)
    ng = int(group.max()) + 1 if group.size else 0
    out = {k: (np.zeros(X.shape[1]), np.zeros(ng)) for k in max_inputs}
    edges = np.linspace(0, len(X), n_sub + 1).round().astype(int)
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
        ins = _inputs(log, rows)
        feats = [Feature(i) for i in ins]
        X = feature_matrix(log, feats, cache)[rows]
        out = {}
        for ch in channels:
            y = log.disp_um[ch][rows]
            count, _ = _stable_selection(X, y, self.n_sub, (self.max_inputs,))[self.max_inputs]
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
        ins = _inputs(log, rows)
        nt = len(self.taus)
        feats = [Feature(i, tau) for i in ins for tau in self.taus]
        X = feature_matrix(log, feats, cache)[rows]
        group = np.repeat(np.arange(len(ins)), nt)
        out = {}
        for ch in channels:
            y = log.disp_um[ch][rows]
            stab = _stable_selection(X, y, self.n_sub, self.max_inputs, group)
            hyp = {}
            for k in self.max_inputs:
                cnt, pres = stab[k]
                keep = np.flatnonzero(pres >= self.freq * self.n_sub)
                cols = [i * nt + int(np.argmax(cnt[i * nt:(i + 1) * nt])) for i in keep]
                fs = [feats[c] for c in cols]
                hyp[f"k={k}"] = (fs, *fit_ols(X[:, cols], y))
            out[ch] = hyp
        return out


class GradientFamily(StableOLSFamily):
    """Temperature DIFFERENCES as inputs: each temperature minus the coolest sensor's (the reference nearest the
    shop air, by median over the training rows), plus the spindle speed.

    * ``sum0``: OLS on every difference + speed, no absolute temperature — the temperature gains sum to zero, so
      a uniform shift of every temperature (a warmer shop, the whole machine warmer by the same amount) moves
      nothing; only gradients across the structure do;
    * ``stable``: OLS on the differences, the reference's own temperature and the speed that forward BIC selects
      in ≥ ``freq`` of the leave-one-block-out subsamples (the absolute temperature enters only where it is
      stably needed).

    Returned in the raw inputs (a difference's gain is the sensor's gain, minus on the reference), so the
    controller form is the OLS baseline's features with constrained coefficients. Settings: those of
    :class:`StableOLSFamily`."""

    name = "gradient"

    def fit(self, log, channels, rows, cache):
        ins = _inputs(log, rows)
        speed = "speed_rpm" in ins
        nt = len(ins) - speed                                            # the temperatures
        if nt < 2:
            raise ValueError("gradient: fewer than two temperatures vary on the training rows")
        feats = [Feature(i) for i in ins]
        X = feature_matrix(log, feats, cache)[rows]                      # (n, p): temperatures, then speed
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
        out = {}
        for ch in channels:
            y = log.disp_um[ch][rows]
            hyp = {}
            a, c = fit_ols(Z[:, sum0], y)
            hyp["sum0"] = (feats, a, M[:, sum0] @ c)
            cnt, _ = _stable_selection(Z, y, self.n_sub, (self.max_inputs,))[self.max_inputs]
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
    ins = _inputs(log, rows)
    X = feature_matrix(log, [Feature(i) for i in ins], cache)[rows]
    Y = np.stack([log.disp_um[ch][rows] for ch in channels], axis=1)
    speed = "speed_rpm" in ins
    return ins, X, _mode_maps(X, len(ins) - speed, speed, counts), Y


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
