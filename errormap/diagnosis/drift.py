"""Thermal error modelling on drift logs: which temperature sensors explain each displacement.

Log schema (CSV): ``time_s`` (increasing), any number of ``temp_<sensor>_c`` columns, any number
of displacement columns ``<channel>_um``, optional ``speed_rpm``.

Per displacement channel, on the earlier ``fit_fraction`` of the log (by time):

1. **correlation grouping** — sensors whose temperatures correlate with |r| ≥ ``group_r`` on the
   fitting part form one group (single linkage); at most one sensor per group enters a model
   (collinear sensors would make the coefficients meaningless);
2. **lag** — the sensors' signals are delayed by a common lag ``lag_s`` (``T(t − lag)``, held
   at the first value before the log starts), searched on a grid from 0 to ``max_lag_s``;
3. **stepwise regression** (for each lag; forward entry, then backward removal of any
   earlier entry whose removal lowers the BIC) — ``d(t) = β0 + Σ βs·Ts(t − lag)``
   (+ ``β·speed_rpm`` as a candidate regressor when logged): the sensor lowering the BIC most
   enters while it lowers the BIC by more than ``min_delta_bic`` and its partial F-test
   passes ``alpha`` (Bonferroni over the candidates of the step);
   then a replacement step swaps a chosen regressor for any other (its own group's members
   included) while that lowers the BIC — so grouping never locks out the true sensor;
4. the lag whose stepwise model has the lowest BIC wins.

Before/after on the later part: "before" is the displacement itself (no compensation),
"after" the displacement minus the model's prediction.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..io import InputError, read_table

TEMP_RE = re.compile(r"^temp_(.+)_c$")
DISP_RE = re.compile(r"^(.+)_um$")
MAX_DISP_UM = 5000.0
TEMP_RANGE_C = (-40.0, 150.0)


@dataclass
class DriftLog:
    """``time_s`` (n,), ``temps_c`` {sensor: (n,)}, ``disp_um`` {channel: (n,)}, optional ``speed_rpm`` (n,)."""

    time_s: np.ndarray
    temps_c: dict
    disp_um: dict
    speed_rpm: np.ndarray | None = None
    path: str = "<log>"


def load_drift_log(path) -> DriftLog:
    """Read and validate a drift log; errors name the file, row and column."""
    t = read_table(path)
    t.require("time_s")
    temps = [n for n in t.names if TEMP_RE.match(n)]
    disps = [n for n in t.names if DISP_RE.match(n)]
    if not temps:
        raise InputError(f"{path}: missing temperature column(s) 'temp_<sensor>_c'; found columns {t.names}")
    if not disps:
        raise InputError(f"{path}: missing displacement column(s) '<channel>_um'; found columns {t.names}")
    if len(t) < 30:
        raise InputError(f"{path}: expected at least 30 rows in a drift log, got {len(t)}")
    time = t.float("time_s")
    d = np.diff(time)
    if np.any(d <= 0):
        k = int(np.flatnonzero(d <= 0)[0]) + 1
        what = "duplicated" if d[k - 1] == 0 else "decreasing"
        raise InputError(f"{path}: row {t.row_number(k)}, column 'time_s': {what} time {time[k]:g} "
                         f"(previous row {t.row_number(k - 1)} has {time[k - 1]:g}); expected increasing times")
    tc = {}
    for c in temps:
        v = t.float(c)
        bad = np.flatnonzero((v < TEMP_RANGE_C[0]) | (v > TEMP_RANGE_C[1]))
        if bad.size:
            raise InputError(f"{path}: row {t.row_number(bad[0])}, column '{c}': units do not fit: {v[bad[0]]:g} "
                             f"is outside {TEMP_RANGE_C} °C (kelvin or fahrenheit?)")
        tc[TEMP_RE.match(c).group(1)] = v
    du = {}
    for c in disps:
        v = t.float(c)
        bad = np.flatnonzero(np.abs(v) > MAX_DISP_UM)
        if bad.size:
            raise InputError(f"{path}: row {t.row_number(bad[0])}, column '{c}': units do not fit: {v[bad[0]]:g} μm "
                             f"is beyond the plausible {MAX_DISP_UM:g} μm")
        du[c[:-3]] = v
    speed = t.float("speed_rpm") if "speed_rpm" in t else None
    return DriftLog(time, tc, du, speed, str(path))


def lagged(time_s, values, lag_s: float) -> np.ndarray:
    """``values(t − lag)`` by linear interpolation, held at the first value before the start."""
    return np.interp(time_s - lag_s, time_s, values)


def correlation_groups(X: np.ndarray, names, group_r: float) -> dict:
    """Single-linkage groups of columns of X (n, k) with |corr| ≥ group_r: {name: group id}."""
    k = X.shape[1]
    C = np.corrcoef(X, rowvar=False) if k > 1 else np.ones((1, 1))
    C = np.nan_to_num(C)
    gid = list(range(k))
    for i in range(k):
        for j in range(i + 1, k):
            if abs(C[i, j]) >= group_r:
                a, b = gid[i], gid[j]
                gid = [a if g == b else g for g in gid]
    return {n: gid[i] for i, n in enumerate(names)}


@dataclass
class ChannelModel:
    """A fitted channel: selected regressors, lag, coefficients (intercept first)."""

    channel: str
    sensors: list
    lag_s: float
    coef: np.ndarray
    bic: float
    se: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def predict(self, log: DriftLog) -> np.ndarray:
        X = _regressors(log, self.sensors, self.lag_s)
        return X @ self.coef


def _signal(log: DriftLog, name: str, lag_s: float) -> np.ndarray:
    if name == "speed_rpm":
        return lagged(log.time_s, log.speed_rpm, lag_s)
    return lagged(log.time_s, log.temps_c[name], lag_s)


def _regressors(log, names, lag_s) -> np.ndarray:
    cols = [np.ones_like(log.time_s)] + [_signal(log, s, lag_s) for s in names]
    return np.stack(cols, axis=1)


def _bic(rss, n, p):
    return n * np.log(max(rss, 1e-300) / n) + p * np.log(n)


class DriftModeller:
    """Sensor selection and lag for each displacement channel (see module doc).

    Settings: ``fit_fraction``, ``max_lag_s`` (default: 20 % of the fitting span), ``lag_step_s``
    (default: the median sampling interval; searched coarse at ``coarse_factor`` steps, then
    refined around the best coarse lag), ``group_r``, ``alpha``, ``min_delta_bic``,
    ``max_sensors``. Learned: ``channels_`` {channel: ChannelModel}, ``groups_`` {sensor: id}.
    """

    def __init__(self, fit_fraction: float = 0.6, max_lag_s: float | None = None, lag_step_s: float | None = None,
                 group_r: float = 0.98, alpha: float = 0.01, min_delta_bic: float = 10.0, max_sensors: int = 4,
                 coarse_factor: int = 4):
        self.coarse_factor = coarse_factor
        self.fit_fraction = fit_fraction
        self.max_lag_s = max_lag_s
        self.lag_step_s = lag_step_s
        self.group_r = group_r
        self.alpha = alpha
        self.min_delta_bic = min_delta_bic
        self.max_sensors = max_sensors

    def split(self, log: DriftLog):
        n = len(log.time_s)
        n_fit = int(round(self.fit_fraction * n))
        return np.arange(n_fit), np.arange(n_fit, n)

    def _backward(self, y, chosen, X, rss, bic, n):
        """Drop entries whose removal costs less than ``min_delta_bic`` (they would not enter now)."""
        chosen = list(chosen)
        while chosen:
            trials = []
            for i in range(len(chosen)):
                Xd = np.delete(X, i + 1, axis=1)
                rd = float(np.sum((y - Xd @ np.linalg.lstsq(Xd, y, rcond=None)[0]) ** 2))
                trials.append((_bic(rd, n, Xd.shape[1]), i, Xd, rd))
            bd, i, Xd, rd = min(trials, key=lambda v: v[0])
            if bd - bic >= self.min_delta_bic:
                break
            del chosen[i]
            X, rss, bic = Xd, rd, bd
        return chosen, X, rss, bic

    def _stepwise(self, log, y, fit, lag, names, groups):
        n = len(fit)
        sig = {s: _signal(log, s, lag)[fit] for s in names}
        chosen = []
        X = np.ones((n, 1))
        rss = float(np.sum((y - y.mean()) ** 2))
        bic = _bic(rss, n, 1)
        while len(chosen) < self.max_sensors:
            used = {groups.get(s) for s in chosen if s in groups}
            cand = [s for s in names if s not in chosen and (s not in groups or groups[s] not in used)]
            if not cand:
                break
            best = None
            for s in cand:
                Xs = np.hstack([X, sig[s][:, None]])
                th = np.linalg.lstsq(Xs, y, rcond=None)[0]
                r1 = float(np.sum((y - Xs @ th) ** 2))
                if best is None or r1 < best[1]:
                    best = (s, r1, Xs)
            s, r1, Xs = best
            dof = n - Xs.shape[1]
            F = (rss - r1) / max(r1 / dof, 1e-300)
            p_adj = float(stats.f.sf(F, 1, dof)) * len(cand) if F > 0 else 1.0
            b1 = _bic(r1, n, Xs.shape[1])
            if not (bic - b1 > self.min_delta_bic and p_adj < self.alpha):
                break
            chosen.append(s)
            X, rss, bic = Xs, r1, b1
            chosen, X, rss, bic = self._backward(y, chosen, X, rss, bic, n)
        # replacement step: swap a chosen regressor for another one (a member of its own
        # correlation group included) while that lowers the BIC
        improved = True
        while improved and chosen:
            improved = False
            best = (bic, None, None)
            for i, old in enumerate(chosen):
                others = {groups.get(c) for j, c in enumerate(chosen) if j != i and c in groups}
                for s in names:
                    if s in chosen or (s in groups and groups[s] in others):
                        continue
                    Xs = X.copy()
                    Xs[:, i + 1] = sig[s]
                    r1 = float(np.sum((y - Xs @ np.linalg.lstsq(Xs, y, rcond=None)[0]) ** 2))
                    b1 = _bic(r1, n, Xs.shape[1])
                    if b1 < best[0] - 1e-9:
                        best = (b1, i, s, Xs, r1)
            if best[1] is not None:
                bic, i, s, X, rss = best
                chosen[i] = s
                improved = True
        chosen, X, rss, bic = self._backward(y, chosen, X, rss, bic, n)
        th = np.linalg.lstsq(X, y, rcond=None)[0]
        return chosen, th, bic, X, rss

    def fit(self, log: DriftLog) -> "DriftModeller":
        if not 0 < self.fit_fraction < 1:
            raise ValueError(f"Expected 0 < fit_fraction < 1, got {self.fit_fraction}")
        fit, _ = self.split(log)
        if len(fit) < 20:
            raise ValueError(f"Expected at least 20 fitting rows, got {len(fit)}")
        t = log.time_s[fit]
        step = self.lag_step_s or float(np.median(np.diff(log.time_s)))
        max_lag = self.max_lag_s if self.max_lag_s is not None else 0.2 * (t[-1] - t[0])
        coarse = np.arange(0.0, max_lag + step / 2, self.coarse_factor * step)
        names = list(log.temps_c)
        self.groups_ = correlation_groups(np.stack([log.temps_c[s][fit] for s in names], axis=1), names, self.group_r)
        if log.speed_rpm is not None and np.ptp(log.speed_rpm[fit]) > 0:
            names = names + ["speed_rpm"]
        self.channels_ = {}
        for ch, d in log.disp_um.items():
            y = d[fit]
            best = None
            for lags in (coarse, None):
                if lags is None:  # refine around the coarse optimum at the sampling step
                    c = best[3]
                    lags = np.arange(max(0.0, c - self.coarse_factor * step), min(max_lag, c + self.coarse_factor * step) + step / 2, step)
                for lag in lags:
                    chosen, th, bic, X, rss = self._stepwise(log, y, fit, lag, names, self.groups_)
                    if best is None or bic < best[2] - 1e-9:
                        best = (chosen, th, bic, lag, X, rss)
            chosen, th, bic, lag, X, rss = best
            cov = rss / max(len(y) - X.shape[1], 1) * np.linalg.pinv(X.T @ X)
            self.channels_[ch] = ChannelModel(ch, chosen, float(lag), th, float(bic), np.sqrt(np.diag(cov)))
        return self

    def report(self, log: DriftLog) -> dict:
        """``channels`` mapping in the diagnosis.json form (held-out before/after)."""
        _, hold = self.split(log)
        out = {}
        for ch, m in self.channels_.items():
            d = log.disp_um[ch]
            after = d - m.predict(log)
            b, a = d[hold], after[hold]
            out[ch] = {"sensors": [s for s in m.sensors if s != "speed_rpm"],
                       "regressors": list(m.sensors), "lag_s": m.lag_s,
                       "coefficients": {"intercept_um": float(m.coef[0]),
                                        **{(f"{s}_um_per_rpm" if s == "speed_rpm" else f"{s}_um_per_c"): float(c)
                                           for s, c in zip(m.sensors, m.coef[1:])}},
                       "standard_errors": {"intercept_um": float(m.se[0]),
                                           **{(f"{s}_um_per_rpm" if s == "speed_rpm" else f"{s}_um_per_c"): float(c)
                                              for s, c in zip(m.sensors, m.se[1:])}},
                       "rms_before_um": float(np.sqrt(np.mean(b**2))), "rms_after_um": float(np.sqrt(np.mean(a**2))),
                       "max_before_um": float(np.abs(b).max()), "max_after_um": float(np.abs(a).max())}
        return out


def _lowpass(u, dt_s, tau_s):
    a = dt_s / tau_s
    out = np.empty_like(u)
    out[0] = u[0]
    for k in range(1, len(u)):
        out[k] = out[k - 1] + a * (u[k] - out[k - 1])
    return out


def simulate_drift_log(seed: int = 0, n: int = 2160, dt_s: float = 10.0, n_sensors: int = 6,
                       active=("s2", "s5"), lag_s: float = 300.0, noise_um: float = 0.5,
                       channels=("dx", "dz")) -> dict:
    """A seeded drift log (a dict of columns): ``n_sensors`` temperature sensors ``temp_s1_c …``
    and displacement channels ``<ch>_um``, with ``speed_rpm``.

    Three independent heat sources — the spindle (a stepped ``speed_rpm`` profile), a feed-drive
    duty cycle switching at other times, and the ambient (slow sinusoid plus random walk) — reach
    each sensor with its own random weights through first-order lags of its own time constants
    (600–4000 s), plus 0.01 °C noise. Each channel is ``Σ_active k·(T(t − lag_s) − T(0))`` with
    k of 4–8 μm/°C and random sign, plus N(0, noise_um). The truth is in ``"_truth"``:
    ``{channel: {sensor: k}}``.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt_s
    speed = np.repeat(rng.choice([0, 3000, 6000, 9000, 12000], size=n // 90 + 1), 90)[:n].astype(float)
    duty = np.repeat(rng.uniform(0.0, 1.0, size=n // 55 + 1), 55)[:n]
    ambient = 0.8 * np.sin(2 * np.pi * t / rng.uniform(20000, 60000) + rng.uniform(0, 2 * np.pi)) \
        + np.cumsum(rng.normal(0, 0.01, n))
    cols = {"time_s": t, "speed_rpm": speed}
    names = [f"s{i + 1}" for i in range(n_sensors)]
    for s in names:
        w = rng.dirichlet([0.7, 0.7, 0.7])
        T = 20.0 + w[0] * 4.0 * _lowpass(speed / 12000.0, dt_s, rng.uniform(600, 4000)) \
            + w[1] * 4.0 * _lowpass(duty, dt_s, rng.uniform(600, 4000)) + w[2] * 2.0 * ambient
        cols[f"temp_{s}_c"] = T + rng.normal(0, 0.01, n)
    truth = {}
    for ch in channels:
        k = {s: float(rng.uniform(4.0, 8.0) * rng.choice([-1, 1])) for s in active}
        truth[ch] = k
        d = sum(kk * (lagged(t, cols[f"temp_{s}_c"], lag_s) - cols[f"temp_{s}_c"][0]) for s, kk in k.items())
        cols[f"{ch}_um"] = d + rng.normal(0, noise_um, n)
    cols["_truth"] = truth
    return cols
