"""The causal features every drift model is a linear combination of, the linear fits on them, the contract of a
candidate family, and the distance ρ of inputs from fitting data.

A feature is one logged input (``temp_<sensor>_c`` or ``speed_rpm``), optionally raised to a power, passed
through a first-order lag of time constant ``tau_s`` and delayed by ``delay_s`` (docs/explanation/drift.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from ..io import InputError
from .drift import DriftLog

TAU_BANK_S = (0.0, 900.0, 3600.0, 10800.0)       # 15 min, 1 h, 3 h: spans the 0.5–5 h of machine bodies
RANGE_QUANTILE = 0.99   # the fit data's typical range d0: this quantile of its rows' own input distances
SPEED_SCALE_RPM = 1e4                            # speed² features use (speed/1e4)² → documented as power 2 of speed/1e4
COV_FLOOR = 1e-4                    # eigenvalue floor of the inputs' correlation matrix (relative to the largest):
                                    # directions whose spread is below 1 % of the dominant one carry sensor noise
                                    # and offsets, not operating conditions


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


def _inputs(log: DriftLog, rows) -> list:
    """The inputs that vary on ``rows``: every such ``temp_<sensor>_c``, then ``speed_rpm`` where it does."""
    temps = [f"temp_{s}_c" for s, v in log.temps_c.items() if np.ptp(v[rows]) > 0]
    return temps + (["speed_rpm"] if log.speed_rpm is not None and np.ptp(log.speed_rpm[rows]) > 0 else [])


class _Family:
    """A family: ``hypers`` (list of names) and ``fit(log, ch, rows, cache)`` → {hyper: (features, intercept, coef)}."""

    name = ""

def input_matrix(log, rows, cache) -> np.ndarray:
    """The raw inputs (every varying temperature and speed) on ``rows``: (len(rows), k)."""
    return feature_matrix(log, [Feature(i) for i in _inputs(log, rows)], cache)[rows]

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
