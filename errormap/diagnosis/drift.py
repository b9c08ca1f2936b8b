"""Drift logs (read, validated, repaired) and the sensor-subset + common-lag search on them.

Log schema (CSV): ``time_s`` (increasing), ``temp_<sensor>_c`` columns, displacement columns ``<channel>_um``,
optional ``speed_rpm``. Per channel :class:`DriftModeller` fits ``d(t) = β0 + Σ_{s ∈ S} βs·Ts(t − lag)``
(+ ``speed_rpm``) with one pure delay: temperatures smoothed over ``smooth_s``, every subset of at most
``max_sensors`` regressors at every lag of the grid scored by BIC (the lag counted; correlated sensors grouped
by ``group_r`` only to shrink a too-large search), the smallest size within ``min_delta_bic`` whose regressors
pass a Bonferroni-corrected partial F-test at ``alpha``, alternatives within ``ambiguity_delta_bic`` flagged
``ambiguous``, the lag with a profile-likelihood 95 % interval. Why each step is as it is:
``docs/decisions/009-closed-loop-history.md``, the drift log's sensor search."""
from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..settings import keep_settings
from ..io import InputError, read_table

TEMP_RE = re.compile(r"^temp_(.+)_c$")
DISP_RE = re.compile(r"^(.+)_um$")
MAX_DISP_UM = 1000.0      # a thermal drift beyond 1 mm is not plausible: nanometres written as μm?
MIN_DISP_PTP_UM = 0.05    # a channel moving < 0.05 μm over a whole log carries nothing: millimetres?
TEMP_RANGE_C = (-40.0, 150.0)
SPEED_RANGE_RPM = (-200_000.0, 200_000.0)  # beyond the fastest machine-tool spindles (air-bearing, ~1.5e5 rpm): a typo
# A log whose COOLEST sensor sits above this (its median) is in °F, not °C: a machine tool's log
# carries sensors near the shop's air (the real 46 h log's coolest sensor: median 22 °C, its warmest
# reading 41.9 °C), while the same log in °F puts every sensor above 68 °F. 45 °C = 113 °F.
FAHRENHEIT_COOLEST_MEDIAN_C = 45.0
MAX_STEP_S = 3600.0       # median sampling step beyond 1 h: milliseconds written as seconds?
MAX_GAP_S = 600.0         # missing temperature/speed samples spanning ≤ 10 min are filled, longer: input dropped
STUCK_S = 7200.0          # an input repeating one value exactly for ≥ 2 h is stuck: dropped
MIN_STEP_S = 0.5          # median step below 0.5 s: a thermal log is sampled every seconds to minutes: hours/minutes?
MIN_SPAN_S = 3600.0       # a log to FIT spanning < 1 h cannot show thermal responses of 0.5–5 h: minutes/hours?
TIME_UNITS_S = {"s": 1.0, "min": 60.0, "h": 3600.0}


@dataclass
class DriftLog:
    """``time_s`` (n,), ``temps_c`` {sensor: (n,)}, ``disp_um`` {channel: (n,)}, optional ``speed_rpm`` (n,);
    ``notes`` {"filled": {input: [[first_row, last_row], ...]}, "dropped": {input: reason}} from loading."""

    time_s: np.ndarray
    temps_c: dict
    disp_um: dict
    speed_rpm: np.ndarray | None = None
    path: str = "<log>"
    notes: dict = field(default_factory=dict)


def _missing_or_number(t, name) -> np.ndarray:
    """Column as float with empty / 'nan' cells as NaN; any other non-number raises naming row and column."""
    raw = t.raw(name)
    out = np.empty(len(raw))
    for k, s in enumerate(raw):
        s = s.strip()
        if s == "" or s.lower() in ("nan", "na", "null"):
            out[k] = np.nan
            continue
        try:
            out[k] = float(s)
        except ValueError:
            raise InputError(f"{t.path}: row {t.row_number(k)}, column '{name}': expected a number, got {s!r}") from None
        if not math.isfinite(out[k]):
            raise InputError(f"{t.path}: row {t.row_number(k)}, column '{name}': expected a finite number, got {s!r}")
    return out


def _runs(mask):
    """[(first, last)] index runs where ``mask`` is True."""
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


def repair_input(t, name, v, time, causal: bool, stuck: bool = True):
    """Fill short gaps of an input (interpolated; held at the last value when ``causal``); return
    (values or None when dropped, filled [[row, row]], drop reason or None). ``stuck``: check for a
    value repeated for ``STUCK_S`` (temperatures; a spindle may well stand still for hours)."""
    for a, b in (_runs(np.concatenate([[False], np.diff(v) == 0])) if stuck else []):
        a = max(a - 1, 0)                          # the run of equal values starts one row earlier
        if time[b] - time[a] >= STUCK_S and np.isfinite(v[a]):
            return None, [], (f"stuck at {v[a]:g} from row {t.row_number(a)} to row {t.row_number(b)} "
                              f"({(time[b] - time[a]) / 3600:.3g} h)")
    bad = ~np.isfinite(v)
    if not bad.any():
        return v, [], None
    if bad.all():
        return None, [], "no valid sample"
    filled = []
    for a, b in _runs(bad):
        t0 = time[a - 1] if a > 0 else time[a]
        t1 = time[b + 1] if b + 1 < len(time) else time[b]
        if t1 - t0 > MAX_GAP_S:
            return None, [], (f"missing from row {t.row_number(a)} to row {t.row_number(b)} "
                              f"({(t1 - t0) / 60:.3g} min > {MAX_GAP_S / 60:g} min)")
        filled.append([t.row_number(a), t.row_number(b)])
    ok = np.flatnonzero(~bad)
    out = v.copy()
    if causal:   # last valid value (the first one before any)
        idx = np.maximum.accumulate(np.where(bad, 0, np.arange(len(v))))
        idx[:ok[0]] = ok[0]
        out = v[idx]
    else:
        out[bad] = np.interp(time[bad], time[ok], v[ok])
    return out, filled, None


def check_time_unit(path, t, time_s, fitting: bool = True) -> None:
    """Refuse a ``time_s`` column that looks like minutes or hours (one line: file, row, column, the
    likely unit). Seconds are recognised from the content: the median step between samples is at least
    ``MIN_STEP_S`` and, for a log to fit (``fitting``), the span is at least ``MIN_SPAN_S``. The likely
    unit named is the first of minutes, hours under which step and span both become plausible."""
    d = np.diff(time_s)
    step, span = float(np.median(d)), float(time_s[-1] - time_s[0])
    if step >= MIN_STEP_S and (not fitting or span >= MIN_SPAN_S):
        return
    guess = [u for u, f in TIME_UNITS_S.items() if f > 1 and MIN_STEP_S <= step * f <= MAX_STEP_S
             and span * f >= MIN_SPAN_S]
    why = (f"the median step is {step:.3g} s (below {MIN_STEP_S:g} s)" if step < MIN_STEP_S else
           f"the log spans {span:.3g} s (under {MIN_SPAN_S / 3600:g} h: too short for thermal responses)")
    likely = ({"min": "minutes", "h": "hours"}[guess[0]] + " (as " + guess[0] +
              f": {step * TIME_UNITS_S[guess[0]]:.3g} s steps over {span * TIME_UNITS_S[guess[0]] / 3600:.3g} h)"
              if guess else "minutes or hours")
    row = 1 if step < MIN_STEP_S else len(time_s) - 1
    raise InputError(f"{path}: row {t.row_number(row)}, column 'time_s': units do not fit: {why}; time in "
                     f"{likely}? Convert to seconds or give --time-unit")


def load_drift_log(path, causal: bool = False, require_displacement: bool = True,
                   time_unit: str | None = None, sparse_displacement: bool = False,
                   units: str = "check") -> DriftLog:
    """Read and validate a drift log; errors name the file, row and column.

    Temperatures and ``speed_rpm`` may have missing samples (empty cells or ``nan``): gaps of at
    most ``MAX_GAP_S`` are filled — linearly interpolated, or held at the last value when ``causal``
    (applying a model: no future sample) — longer gaps, and an input stuck at one value for
    ``STUCK_S`` or more, drop that input; ``notes`` says which. Time and displacements must be complete.
    ``time_unit`` (None: seconds, checked from the content by :func:`check_time_unit`; ``"s"``, ``"min"``,
    ``"h"``: the user's statement, no check, converted to seconds and recorded in ``notes["time_unit"]``).
    ``sparse_displacement``: displacement cells may be empty (NaN): on-machine measurements at some rows.
    ``units``: ``"check"`` refuses a log whose coolest sensor's median is above
    :data:`FAHRENHEIT_COOLEST_MEDIAN_C` (°F); ``"as-written"``: the user states °C (recorded in ``notes["units"]``).
    """
    t = read_table(path, "thermal log")
    t.require("time_s")
    temps = [n for n in t.names if TEMP_RE.match(n)]
    disps = [n for n in t.names if DISP_RE.match(n)]
    if not temps:
        raise InputError(f"{path}: missing temperature column(s) 'temp_<sensor>_c'; found columns {t.names}")
    if not disps and require_displacement:
        raise InputError(f"{path}: missing displacement column(s) '<channel>_um'; found columns {t.names}")
    if len(t) < 30:
        raise InputError(f"{path}: expected at least 30 rows in a drift log, got {len(t)}")
    time = _read_time(path, t, time_unit, require_displacement)
    notes = {"filled": {}, "dropped": {}, "last_row": t.row_number(len(t) - 1),
             "time_unit": "s (checked from the content)" if time_unit is None else
             f"{time_unit} (given by the user; converted to seconds)"}
    tc = _read_temperatures(path, t, temps, time, causal, units, notes)
    du = {c[:-3]: _read_displacement(path, t, c, sparse_displacement) for c in disps}
    speed = None
    if "speed_rpm" in t:
        raw_speed = _missing_or_number(t, "speed_rpm")
        bad = np.flatnonzero(~((raw_speed >= SPEED_RANGE_RPM[0]) & (raw_speed <= SPEED_RANGE_RPM[1])) & ~np.isnan(raw_speed))
        if bad.size:
            raise InputError(f"{path}: row {t.row_number(bad[0])}, column 'speed_rpm': {raw_speed[bad[0]]:g} rpm is "
                             f"outside the plausible {SPEED_RANGE_RPM} rpm of a spindle (a typing mistake?)")
        speed, filled, why = repair_input(t, "speed_rpm", raw_speed, time, causal, stuck=False)
        if why:
            notes["dropped"]["speed_rpm"] = why
        elif filled:
            notes["filled"]["speed_rpm"] = filled
    return DriftLog(time, tc, du, speed, str(path), notes)


def _read_time(path, t, time_unit, fitting: bool) -> np.ndarray:
    """``time_s`` (n,) in seconds: increasing, its unit checked (or converted from ``time_unit``)."""
    time = t.float("time_s")
    d = np.diff(time)
    if np.any(d <= 0):
        k = int(np.flatnonzero(d <= 0)[0]) + 1
        what = "duplicated" if d[k - 1] == 0 else "decreasing"
        raise InputError(f"{path}: row {t.row_number(k)}, column 'time_s': {what} time {time[k]:g} "
                         f"(previous row {t.row_number(k - 1)} has {time[k - 1]:g}); expected increasing times")
    if time_unit is None:
        check_time_unit(path, t, time, fitting=fitting)
    else:
        if time_unit not in TIME_UNITS_S:
            raise ValueError(f"Expected time_unit in {list(TIME_UNITS_S)}, got {time_unit!r}")
        time = time * TIME_UNITS_S[time_unit]
        d = np.diff(time)
    if np.median(d) > MAX_STEP_S:
        raise InputError(f"{path}: row {t.row_number(1)}, column 'time_s': units do not fit: the median step is "
                         f"{np.median(d):g} s (more than {MAX_STEP_S:g} s between samples; milliseconds?)")
    return time


def _read_temperatures(path, t, temps, time, causal, units, notes) -> dict:
    """``{sensor: (n,) °C}`` of the usable temperature columns, gaps filled; ``notes`` gets what was filled or
    dropped and how the units were checked."""
    tc = {}
    for c in temps:
        v = _missing_or_number(t, c)
        bad = np.flatnonzero((v < TEMP_RANGE_C[0]) | (v > TEMP_RANGE_C[1]))
        if bad.size:
            raise InputError(f"{path}: row {t.row_number(bad[0])}, column '{c}': units do not fit: {v[bad[0]]:g} "
                             f"is outside {TEMP_RANGE_C} °C (kelvin or fahrenheit?)")
        v, filled, why = repair_input(t, c, v, time, causal)
        if why:
            notes["dropped"][c] = why
            continue
        if filled:
            notes["filled"][c] = filled
        tc[TEMP_RE.match(c).group(1)] = v
    if units == "check" and tc:
        med = {c: float(np.median(v)) for c, v in tc.items()}
        cool = min(med, key=med.get)
        if med[cool] > FAHRENHEIT_COOLEST_MEDIAN_C:
            col = f"temp_{cool}_c"
            raise InputError(f"{path}: row {t.row_number(0)}, column '{col}': units do not fit: even the coolest "
                             f"sensor's median is {med[cool]:g} °C (above {FAHRENHEIT_COOLEST_MEDIAN_C:g} °C): °F? "
                             f"({med[cool]:g} °F = {(med[cool] - 32) / 1.8:.1f} °C); --units as-written if it is °C")
    notes["units"] = "checked from the content" if units == "check" else "as written (given by the user)"
    if not tc:
        raise InputError(f"{path}: column '{temps[0]}': every temperature column was dropped "
                         f"({'; '.join(f'{k}: {v}' for k, v in notes['dropped'].items())})")
    return tc


def _read_displacement(path, t, c, sparse: bool) -> np.ndarray:
    """Displacement column ``c`` (n,) μm, its unit checked (``sparse``: measured at some rows, NaN elsewhere)."""
    v = _missing_or_number(t, c) if sparse else t.float(c)
    bad = np.flatnonzero(np.abs(np.nan_to_num(v)) > MAX_DISP_UM)
    if bad.size:
        raise InputError(f"{path}: row {t.row_number(bad[0])}, column '{c}': units do not fit: {v[bad[0]]:g} μm "
                         f"is beyond the plausible {MAX_DISP_UM:g} μm of thermal drift (nanometres?)")
    if sparse:     # measurements at some rows only: the unit check needs a few of them
        if np.isfinite(v).sum() >= 3 and np.nanmax(v) - np.nanmin(v) < MIN_DISP_PTP_UM:
            k = int(np.nanargmax(np.abs(v)))
            raise InputError(f"{path}: row {t.row_number(k)}, column '{c}': units do not fit: the measurements "
                             f"move by only {np.nanmax(v) - np.nanmin(v):.3g} μm (millimetres?)")
    elif np.ptp(v) < MIN_DISP_PTP_UM:
        k = int(np.argmax(np.abs(v)))
        raise InputError(f"{path}: row {t.row_number(k)}, column '{c}': units do not fit: the channel moves by "
                         f"only {np.ptp(v):.3g} μm over the whole log (less than {MIN_DISP_PTP_UM:g} μm; "
                         "millimetres?)")
    return v


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



LAG_CHI2_95 = 3.84  # χ²₁ 95 % quantile: profile-likelihood interval of the lag
MAX_ALTERNATIVES = 5


def smoothed(time_s, values, window_s: float) -> np.ndarray:
    """Centred moving average over ``window_s`` (time-based, so uneven sampling is fine): (n,).
    Near the ends of the log the window shrinks symmetrically (on an even grid a linear trend passes
    unchanged;
    the first and last values are the readings). ``window_s`` ≤ 0 returns ``values``."""
    if window_s <= 0:
        return values
    area = np.concatenate([[0.0], np.cumsum(0.5 * (values[1:] + values[:-1]) * np.diff(time_s))])
    half = np.minimum.reduce([np.full_like(time_s, window_s / 2), time_s - time_s[0], time_s[-1] - time_s])
    inner = half > 0
    out = np.array(values, dtype=float)
    t, h = time_s[inner], half[inner]
    out[inner] = (np.interp(t + h, time_s, area) - np.interp(t - h, time_s, area)) / (2 * h)
    return out


def smoothed_log(log: DriftLog, window_s: float) -> DriftLog:
    """The log with every temperature smoothed by :func:`smoothed` (displacements and speed as they are)."""
    return DriftLog(log.time_s, {s: smoothed(log.time_s, v, window_s) for s, v in log.temps_c.items()},
                    log.disp_um, log.speed_rpm, log.path, log.notes)


def lagged_stack(time_s, values, lags_s) -> np.ndarray:
    """``values(t − lag)`` for each lag: (L, n), by linear interpolation, held at the first value."""
    lags_s = np.asarray(lags_s, float)
    q = (time_s[None, :] - lags_s[:, None]).ravel()
    return np.interp(q, time_s, values).reshape(len(lags_s), len(time_s))


@dataclass
class ChannelModel:
    """A fitted channel: selected regressors, lag, coefficients (intercept first), and how sure the
    selection is (``runner_up``, ``alternatives`` within ``ambiguity_delta_bic``, ``lag_interval_s``)."""

    channel: str
    sensors: list
    lag_s: float
    coef: np.ndarray
    bic: float
    se: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lag_interval_s: tuple = (0.0, 0.0)
    runner_up: dict | None = None
    alternatives: list = field(default_factory=list)
    closest: dict = field(default_factory=dict)
    search: dict = field(default_factory=dict)
    smooth_s: float = 0.0

    @property
    def ambiguous(self) -> bool:
        return bool(self.alternatives)

    def predict(self, log: DriftLog) -> np.ndarray:
        X = _regressors(smoothed_log(log, self.smooth_s), self.sensors, self.lag_s)
        return X @ self.coef


def _signal(log: DriftLog, name: str, lag_s: float) -> np.ndarray:
    if name == "speed_rpm":
        return lagged(log.time_s, log.speed_rpm, lag_s)
    return lagged(log.time_s, log.temps_c[name], lag_s)


def _raw(log: DriftLog, name: str) -> np.ndarray:
    return log.speed_rpm if name == "speed_rpm" else log.temps_c[name]


def _regressors(log, names, lag_s) -> np.ndarray:
    cols = [np.ones_like(log.time_s)] + [_signal(log, s, lag_s) for s in names]
    return np.stack(cols, axis=1)


def _bic(rss, n, p):
    return n * np.log(np.maximum(rss, 1e-300) / n) + p * np.log(n)


def _subset_rss(G, b, yy, subs) -> np.ndarray:
    """RSS of the centred least-squares fits of every subset at every lag.

    ``G`` (L, k, k) and ``b`` (L, k) are the lagged Gram matrix and cross products of the centred,
    scaled regressors, ``yy`` = Σ y² of the centred target, ``subs`` (s, m) column indices.
    Returns (L, s). Exactly collinear subsets fall back to the pseudo-inverse.
    """
    GS = G[:, subs[:, :, None], subs[:, None, :]]
    bS = b[:, subs]
    try:
        beta = np.linalg.solve(GS, bS[..., None])[..., 0]
    except np.linalg.LinAlgError:
        beta = np.einsum("lsij,lsj->lsi", np.linalg.pinv(GS), bS)
    return np.maximum(yy - np.einsum("lsm,lsm->ls", bS, beta), 0.0)


class DriftModeller:
    """Sensor selection and lag for each displacement channel (see module doc).

    Settings: ``max_lag_s`` (default: 20 % of the fitting span), ``lag_step_s``
    (default: the median sampling interval), ``max_lag_steps`` (coarser grid beyond, then refined),
    ``group_r``, ``alpha``, ``min_delta_bic``, ``max_sensors``, ``ambiguity_delta_bic``,
    ``max_subsets`` (beyond, the search runs over correlation-group representatives plus swaps),
    ``smooth_s`` (centred moving average of the temperatures; 0 = none).
    Learned: ``channels_`` {channel: ChannelModel}, ``groups_`` {sensor: id}.
    """

    def __init__(self, max_lag_s: float | None = None, lag_step_s: float | None = None,
                 group_r: float = 0.98, alpha: float = 0.01, min_delta_bic: float = 10.0, max_sensors: int = 4,
                 ambiguity_delta_bic: float = 10.0, max_subsets: int = 5000, max_lag_steps: int = 400,
                 smooth_s: float = 60.0):
        keep_settings(self, locals())

    # -- the search -------------------------------------------------------------------------
    def _gram(self, log, names, fit, y, lags):
        """Lagged Gram matrices of the centred regressors scaled by their fitting-part std.
        Returns G (L, k, k), b (L, k), yy; computed in chunks of lags to bound memory."""
        n = len(fit)
        scale = np.array([np.std(_raw(log, s)[fit]) for s in names])
        yc = y - y.mean()
        L, k = len(lags), len(names)
        G, b = np.empty((L, k, k)), np.empty((L, k))
        chunk = max(1, int(4e6 // max(n * k, 1)))
        for a in range(0, L, chunk):
            lg = lags[a:a + chunk]
            S = np.stack([lagged_stack(log.time_s, _raw(log, s), lg)[:, fit] for s in names], axis=2) / scale
            S -= S.mean(axis=1, keepdims=True)
            G[a:a + chunk] = np.einsum("lni,lnj->lij", S, S)
            b[a:a + chunk] = np.einsum("lni,n->li", S, yc)
        return G, b, float(yc @ yc)

    def _lag_grid(self, log, fit):
        t = log.time_s[fit]
        step = self.lag_step_s or float(np.median(np.diff(log.time_s)))
        max_lag = self.max_lag_s if self.max_lag_s is not None else 0.2 * (t[-1] - t[0])
        coarse = step * max(1, math.ceil(max_lag / step / max(self.max_lag_steps, 1)))  # a multiple of the step
        return np.arange(0.0, max_lag + coarse / 2, coarse), step, coarse, max_lag

    def _search(self, log, names, fit, y, cand):
        """Exhaustive over subsets of ``cand`` (indices into ``names``) of size 1..max_sensors and the
        lag grid. Returns lags (L,), {m: (subs (s, m), rss (L, s))}, yy."""
        lags, step, coarse, max_lag = self._lag_grid(log, fit)
        sizes = range(1, min(self.max_sensors, len(cand)) + 1)
        subs = {m: np.array(list(itertools.combinations(cand, m)), dtype=int).reshape(-1, m) for m in sizes}
        G, b, yy = self._gram(log, names, fit, y, lags)
        rss = {m: _subset_rss(G, b, yy, s) for m, s in subs.items()}
        if coarse > step:  # refine at the sampling step around the best coarse lag of each size
            centres = [float(lags[np.unravel_index(np.argmin(r), r.shape)[0]]) for r in rss.values()]
            L0 = len(lags)
            lags, G, b = self._refine(log, names, fit, y, lags, G, b, centres)
            rss = {m: np.concatenate([rss[m], _subset_rss(G[L0:], b[L0:], yy, s)]) for m, s in subs.items()}
        return lags, subs, rss, yy, (G, b)

    def _refine(self, log, names, fit, y, lags, G, b, centres):
        """Append the sampling-step lags within one coarse step of each centre (not yet on the grid)."""
        _, step, coarse, max_lag = self._lag_grid(log, fit)
        if coarse <= step:
            return lags, G, b
        fine = np.unique(np.concatenate([step * np.arange(np.ceil(max(0.0, c - coarse) / step),
                                                          np.floor(min(max_lag, c + coarse) / step) + 1)
                                         for c in centres]))
        fine = fine[~np.isin(fine, lags)]
        if not fine.size:
            return lags, G, b
        Gf, bf, _ = self._gram(log, names, fit, y, fine)
        return np.concatenate([lags, fine]), np.concatenate([G, Gf]), np.concatenate([b, bf])

    def _candidates(self, log, names, fit, y):
        """All regressors, or one per correlation group when the subsets would be too many."""
        k = len(names)
        total = sum(math.comb(k, m) for m in range(1, min(self.max_sensors, k) + 1))
        if total <= self.max_subsets:
            return list(range(k)), False
        reps = {}
        for i, s in enumerate(names):
            g = self.groups_.get(s, ("own", s))
            r = abs(np.corrcoef(_raw(log, s)[fit], y)[0, 1])
            if g not in reps or r > reps[g][0]:
                reps[g] = (r, i)
        cand = sorted(i for _, i in reps.values())
        total = sum(math.comb(len(cand), m) for m in range(1, min(self.max_sensors, len(cand)) + 1))
        if total > self.max_subsets:
            raise ValueError(f"{log.path}: {len(cand)} correlation groups give {total} subsets of at most "
                             f"{self.max_sensors} regressors, more than max_subsets = {self.max_subsets}; "
                             "lower max_sensors or group_r, or raise max_subsets")
        return cand, True

    def _swap(self, G, b, yy, n, chosen, k):
        """Replace selected regressors by any other while that lowers the RSS (any lag)."""
        while True:
            trial = [tuple(sorted(chosen[:i] + [j] + chosen[i + 1:])) for i in range(len(chosen))
                     for j in range(k) if j not in chosen]
            if not trial:
                return chosen
            r = _subset_rss(G, b, yy, np.array(trial, dtype=int))
            cur = _subset_rss(G, b, yy, np.array([sorted(chosen)], dtype=int)).min()
            l, s = np.unravel_index(np.argmin(r), r.shape)
            if r[l, s] >= cur * (1 - 1e-12):
                return chosen
            chosen = list(trial[s])

    def _fit_channel(self, log, ch, names, fit):
        y = log.disp_um[ch][fit]
        n = len(fit)
        cand, reduced = self._candidates(log, names, fit, y)
        lags, subs, rss, yy, (G, b) = self._search(log, names, fit, y, cand)
        bic0 = float(_bic(yy, n, 1))
        best = {0: (bic0, 0.0, ())}
        for m, r in rss.items():
            bic = _bic(r, n, m + 2)
            l, s = np.unravel_index(np.argmin(bic), bic.shape)
            best[m] = (float(bic[l, s]), float(lags[l]), tuple(int(i) for i in subs[m][s]))
        if reduced:
            for m in list(best)[1:]:
                chosen = self._swap(G, b, yy, n, list(best[m][2]), len(names))
                r = _subset_rss(G, b, yy, np.array([chosen], dtype=int))[:, 0]
                lags, G, b = self._refine(log, names, fit, y, lags, G, b, [float(lags[int(np.argmin(r))])])
                r = _subset_rss(G, b, yy, np.array([chosen], dtype=int))[:, 0]
                bic = _bic(r, n, m + 2)
                l = int(np.argmin(bic))
                best[m] = (float(bic[l]), float(lags[l]), tuple(chosen))
        bic_min = min(v[0] for v in best.values())
        m = min(mm for mm, v in best.items() if v[0] < bic_min + self.min_delta_bic)
        while m > 0 and not self._all_significant(log, ch, fit, [names[i] for i in best[m][2]], best[m][1], len(cand)):
            m -= 1
        bic, lag, sel = best[m]
        chosen = [names[i] for i in sel]
        X = _regressors(log, chosen, lag)[fit]
        th = np.linalg.lstsq(X, y, rcond=None)[0]
        res = float(np.sum((y - X @ th) ** 2))
        cov = res / max(n - X.shape[1], 1) * np.linalg.pinv(X.T @ X)
        model = ChannelModel(ch, chosen, lag, th, bic, np.sqrt(np.diag(cov)), smooth_s=self.smooth_s,
                             search={"candidates": [names[i] for i in cand], "reduced_to_groups": reduced,
                                     "lags": int(len(lags)), "subsets": int(sum(len(s) for s in subs.values())),
                                     "best_bic_by_size": {int(mm): v[0] for mm, v in best.items()}})
        if m > 0:
            self._uncertainty(model, log, names, fit, lags, subs[m] if not reduced else None, rss.get(m), G, b, yy, sel)
        return model

    def _all_significant(self, log, ch, fit, chosen, lag, n_cand) -> bool:
        """Partial F-test of each selected regressor given the others, Bonferroni over the candidates."""
        y = log.disp_um[ch][fit]
        X = _regressors(log, chosen, lag)[fit]
        n, p = X.shape
        r_full = float(np.sum((y - X @ np.linalg.lstsq(X, y, rcond=None)[0]) ** 2))
        for i in range(1, p):
            Xd = np.delete(X, i, axis=1)
            r_d = float(np.sum((y - Xd @ np.linalg.lstsq(Xd, y, rcond=None)[0]) ** 2))
            F = (r_d - r_full) / max(r_full / (n - p), 1e-300)
            if float(stats.f.sf(F, 1, n - p)) * n_cand >= self.alpha:
                return False
        return True

    def _uncertainty(self, model, log, names, fit, lags, subs, rss, G, b, yy, sel):
        """Lag interval, runner-up subset and alternatives within ``ambiguity_delta_bic``, closest sensors."""
        n, m = len(fit), len(sel)
        own = _subset_rss(G, b, yy, np.array([sel], dtype=int))[:, 0]
        nll = n * np.log(np.maximum(own, 1e-300))
        inside = lags[nll - nll.min() <= LAG_CHI2_95]
        model.lag_interval_s = (float(inside.min()), float(inside.max()))
        if subs is None:  # reduced search: compare with every single swap
            subs = np.array(sorted({tuple(sorted(list(sel[:i]) + [j] + list(sel[i + 1:])))
                                    for i in range(m) for j in range(len(names)) if j not in sel}), dtype=int)
            rss = _subset_rss(G, b, yy, subs) if len(subs) else np.zeros((len(lags), 0))
        bic = _bic(rss, n, m + 2)
        per = bic.min(axis=0)
        per_lag = lags[np.argmin(bic, axis=0)]
        others = [i for i in np.argsort(per) if tuple(int(v) for v in subs[i]) != tuple(sel)]

        def entry(i):
            return {"regressors": [names[j] for j in subs[i]], "lag_s": float(per_lag[i]),
                    "delta_bic": float(per[i] - model.bic)}
        if others:
            model.runner_up = entry(others[0])
            model.alternatives = [entry(i) for i in others[:MAX_ALTERNATIVES]
                                  if per[i] - model.bic < self.ambiguity_delta_bic]
        temps = [s for s in names if s != "speed_rpm"]
        for s in model.sensors:
            if s == "speed_rpm" or len(temps) < 2:
                continue
            r = {o: float(np.corrcoef(log.temps_c[s][fit], log.temps_c[o][fit])[0, 1]) for o in temps if o != s}
            o = max(r, key=lambda v: abs(r[v]))
            model.closest[s] = {"sensor": o, "r": r[o]}

    def fit_rows(self, log: DriftLog, fit) -> "DriftModeller":
        """Fit on the rows ``fit`` (indices, earliest first; a cross-validation fold's training part)."""
        if len(fit) < 20:
            raise ValueError(f"Expected at least 20 fitting rows, got {len(fit)}")
        log = smoothed_log(log, self.smooth_s)
        names = [s for s in log.temps_c if np.ptp(log.temps_c[s][fit]) > 0]
        self.constant_sensors_ = [s for s in log.temps_c if s not in names]
        self.groups_ = correlation_groups(np.stack([log.temps_c[s][fit] for s in names], axis=1), names,
                                          self.group_r) if names else {}
        if log.speed_rpm is not None and np.ptp(log.speed_rpm[fit]) > 0:
            names = names + ["speed_rpm"]
        if not names:
            raise ValueError(f"{log.path}: every temperature sensor is constant on the fitting part")
        self.channels_ = {ch: self._fit_channel(log, ch, names, fit) for ch in log.disp_um}
        return self

    def report_selection(self) -> dict:
        """Per channel: selected ``regressors``, ``lag_s``, ``lag_interval_s``, ``ambiguous``, ``alternatives``."""
        return {ch: {"regressors": list(m.sensors), "lag_s": m.lag_s, "lag_interval_s": list(m.lag_interval_s),
                     "ambiguous": m.ambiguous, "alternatives": m.alternatives, "runner_up": m.runner_up}
                for ch, m in self.channels_.items()}
