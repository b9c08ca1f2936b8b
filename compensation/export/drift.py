"""``drift``: a thermal-drift model (``volcomp.drift_model`` JSON from ``volcomp diagnose --drift``) as the
discrete-time coefficients a controller runs at a fixed sample period (``drift_coefficients.csv``: one row per
first-order filter — input, a = exp(−dt/τ), b = 1 − a, delay in samples, a gain per channel — and an offset
row, with pseudo-code in the header). Its check (:func:`check_drift_export`) re-simulates that recursion from
the file alone on a log and compares it with ``DriftModel.predict`` (model residual) and, on a simulated log,
with the noise-free displacement (true residual). No machine is involved.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.io import InputError, read_table, write_csv
from errormap.stats import residual_stats

from .common import meta_format as _meta_format

# -- drift model: coefficient form for a controller's fixed sample period ------------------------
DRIFT_FORMAT = "volcomp-drift-coefficients/1"
DRIFT_FILE = "drift_coefficients.csv"
DRIFT_CONST = "const"
"""Input name of the offset row: a constant 1 through a pass-through filter, gains = intercepts."""
DRIFT_TICK_EPS_S = 1e-3
"""A logged sample counts as available at a controller tick when its time is at most 1 ms after
the tick (log times are written with finite digits; without this a tick equal to a sample time
could miss it by rounding)."""
DRIFT_MAX_PERIOD_S = 3600.0
DRIFT_PSEUDO_CODE = (
    "pseudo-code (run once per sample period dt; every row r is one filter, the last row the offset):",
    "  at power-on (k = 0): v_r = (u_r / scale_r) ** power_r; y_r = v_r; fill buf_r with y_r",
    "  every tick k:  v_r = (u_r / scale_r) ** power_r      # u_r = latest valid reading of input_r",
    "                 y_r = a_r * y_r + b_r * v_r           # first-order lag, a = exp(-dt/tau_s), b = 1 - a",
    "                 push y_r into buf_r (ring of delay_samples_r + 2 values)",
    "                 f_r = (1 - delay_frac_r) * buf_r[k - delay_samples_r] + delay_frac_r * buf_r[k - delay_samples_r - 1]",
    "                 pred_<ch>_um = sum over rows r of gain_<ch>_r * f_r",
    "                 axis command -= pred_<ch>_um          # compensate by subtracting the prediction",
    "  input_r = const: u = 1 (a = 0, b = 1, no delay): its gains are the channels' offsets in um",
    "  a missed or invalid reading: use the last valid value of that input and still run the tick",
    "  a tick period dt' other than dt: a = exp(-dt'/tau_s), b = 1 - a for that tick (tau_s = 0: a = 0);",
    "  delay_samples/delay_frac hold for dt only",
    "updating the gains (how these coefficients change on the machine): the gains are fixed between exports;",
    "  `volcomp drift-predict MODEL LOG --update --save-model NEW.json` re-fits each channel's offset and gains",
    "  from on-machine measurements of <ch>_um by a Kalman filter on the parameters (random walk, opened up on",
    "  a 3-sigma innovation); `volcomp export NEW.json --format drift` then writes the new gain_<ch> columns.",
    "  The filter rows (input, scale, power, tau_s, a, b, delay) do not change in an update: only gain_<ch>.",
    "distance rule (export.json controller.distance_shrink, where a channel has one): the gains above are the model",
    "  inside the fitting data's range. Per tick, rho = |(u - mean) . W| / range_distance over the raw inputs listed",
    "  there; beyond rho = 1 the controller blends toward the baseline gains: pred = base + g * (pred - base),",
    "  g = exp(-(rho - 1) / scale); base = sum over rows r of base_gain_<ch>_r * f_r. The 95 % band grows as",
    "  band95_um * max(1, rho) ** band_gamma. Where a channel lists feature_distance, rho is the larger of that and the same",
    "  distance over the filter outputs f_r of its listed rows (its own filtered inputs: a slow state can leave its",
    "  range while every raw input stays inside). A controller that does not run the rule runs the gains as written.",
)


def _base_gains(c, keys) -> list:
    """A channel's OLS baseline (``ChannelFit.base``) in the coefficient file's rows: one gain per feature ``keys``
    (the model's features, in order) and the offset last."""
    bf, ba, bc = c.base
    g = np.zeros(len(keys) + 1)
    for f, b in zip(bf, bc):
        g[keys.index(f.key)] += float(b)
    g[-1] = float(ba)
    return g.tolist()


def drift_distance_rule(model, coef: DriftCoefficients) -> dict | None:
    """The per-sample shrinkage toward the baseline, in the coefficient file's rows: {"inputs", "mean", "whiten",
    "range_distance", "rule", "channels": {ch: {"scale", "base_gains" (m,), "band95_um", "band_gamma"}}}, or None when no
    channel has one."""
    nov = (model.meta or {}).get("novelty") or {}
    chans = {ch: c for ch, c in model.channels.items() if c.base is not None and np.isfinite(c.shrink_scale)}
    if not chans or not nov.get("range_distance"):
        return None
    keys = [f.key for f in model.features]
    out = {}
    for ch, c in chans.items():
        out[ch] = {"scale": float(c.shrink_scale), "base_gains": _base_gains(c, keys), "band95_um": float(c.band95_um),
                   "band_gamma": float(c.band_gamma)}
        if c.novelty:       # the distance on the channel's own filtered features (rows of the coefficient file)
            nv = c.novelty
            out[ch]["feature_distance"] = {"rows": [keys.index(f.key) for f in nv["features"]],
                                           "mean": np.asarray(nv["mean"], float).tolist(),
                                           "whiten": np.asarray(nv["whiten"], float).tolist(),
                                           "range_distance": float(nv["range_distance"])}
    return {"inputs": list(nov["inputs"]), "mean": list(nov["mean"]), "whiten": nov["whiten"],
            "range_distance": float(nov["range_distance"]),
            "rule": "rho = norm((u - mean) @ whiten) / range_distance on the latest raw inputs; g = 1 for rho <= 1, "
                    "exp(-(rho - 1) / scale) beyond; pred = base + g * (gains . f - base), base = base_gains . f "
                    "(same rows as the coefficient file); band = band95_um * max(1, rho) ** band_gamma; where a channel has "
                    "feature_distance: rho = max(rho, norm((f[rows] - mean) @ whiten) / range_distance) over the filter "
                    "outputs f of those coefficient rows",
            "channels": out}


@dataclass
class DriftCoefficients:
    """A drift model as a controller runs it at a fixed sample period ``sample_period_s``.

    One row per filter (``m`` rows, the last the offset row): ``inputs`` (m,) log column names
    (``const`` for the offset), ``scale``, ``power``, ``tau_s``, ``a``, ``b`` (m,) — the recursion
    ``y ← a·y + b·v`` with ``a = exp(−dt/τ)``, ``b = 1 − a`` — ``delay_samples`` (m,) int and
    ``delay_frac`` (m,) in [0, 1): the delay ``delay_s/dt = n + frac`` read from the ring buffer as
    ``(1 − frac)·y[k−n] + frac·y[k−n−1]``; ``gains`` {channel: (m,)} (gain units ``gain_unit``).
    """

    sample_period_s: float
    inputs: list
    scale: np.ndarray
    power: np.ndarray
    tau_s: np.ndarray
    a: np.ndarray
    b: np.ndarray
    delay_samples: np.ndarray
    delay_frac: np.ndarray
    gains: dict
    gain_unit: list
    kind = "drift"

    def n_values(self) -> int:
        return int(len(self.inputs) * (7 + len(self.gains)))   # scale, power, tau_s, a, b, delay (2), gains


def drift_coefficients(model, sample_period_s: float) -> DriftCoefficients:
    """The controller coefficient form of a :class:`~errormap.diagnosis.drift_models.DriftModel`."""
    dt = float(sample_period_s)
    if not (np.isfinite(dt) and 0 < dt <= DRIFT_MAX_PERIOD_S):
        raise ValueError(f"Expected a sample period in (0, {DRIFT_MAX_PERIOD_S:g}] s, got {sample_period_s}")
    feats = model.features
    keys = [f.key for f in feats]
    tau = np.array([f.tau_s for f in feats] + [0.0])
    a = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    d = np.array([f.delay_s for f in feats] + [0.0]) / dt
    n = np.floor(d + 1e-9).astype(int)
    frac = d - n
    frac[np.abs(frac) < 1e-9] = 0.0
    gains = {}
    for ch, c in model.channels.items():
        g = np.zeros(len(feats) + 1)
        for f, coef in zip(c.features, c.coef):
            g[keys.index(f.key)] += float(coef)
        g[-1] = c.intercept_um
        gains[ch] = g
    return DriftCoefficients(dt, [f.input for f in feats] + [DRIFT_CONST],
                             np.array([f.scale for f in feats] + [1.0]), np.array([f.power for f in feats] + [1]),
                             tau, a, 1.0 - a, n, np.clip(frac, 0.0, 1.0), gains,
                             [f.unit() for f in feats] + ["um"])


def _input_unit(name: str) -> str:
    return "degC" if name.startswith("temp_") else "rpm" if name == "speed_rpm" else "1"


def write_drift_coefficients(coef: DriftCoefficients, folder, model_desc: str) -> Path:
    """``drift_coefficients.csv``: one row per filter, a ``gain_<ch>`` column per channel."""
    cols = {"row": np.array([f"f{i}" for i in range(len(coef.inputs) - 1)] + ["offset"]),
            "input": np.array(coef.inputs), "input_unit": np.array([_input_unit(i) for i in coef.inputs]),
            "scale": coef.scale.astype(float), "power": np.array([str(int(p)) for p in coef.power]),
            "tau_s": coef.tau_s, "a": coef.a, "b": coef.b,
            "delay_samples": np.array([str(int(k)) for k in coef.delay_samples]), "delay_frac": coef.delay_frac,
            "gain_unit": np.array(coef.gain_unit)}
    for ch, g in coef.gains.items():
        cols[f"gain_{ch}"] = g
    head = [f"format: {DRIFT_FORMAT}",
            f"sample_period_s: {coef.sample_period_s:.15g}",
            "channels: " + " ".join(coef.gains),
            "outputs: pred_<ch>_um = predicted thermal displacement of channel <ch>, um (subtract it)",
            "units: time s, temperature degC, speed rpm, displacement um; gain_unit per row",
            *DRIFT_PSEUDO_CODE,
            f"model: {model_desc}"]
    return write_csv(Path(folder) / DRIFT_FILE, cols, head, "%.15g")


def read_drift_coefficients(path) -> DriftCoefficients:
    """Read ``drift_coefficients.csv``; errors name the file, row and column."""
    t = read_table(path)
    _meta_format(t, DRIFT_FORMAT)
    try:
        dt = float(t.meta().get("sample_period_s", ""))
    except ValueError:
        dt = float("nan")
    if not (np.isfinite(dt) and 0 < dt <= DRIFT_MAX_PERIOD_S):
        raise InputError(f"{t.path}: provenance line 'sample_period_s' (its sidecar): expected a period in (0, {DRIFT_MAX_PERIOD_S:g}] s, "
                         f"got {t.meta().get('sample_period_s')!r}")
    t.require("input", "scale", "power", "tau_s", "a", "b", "delay_samples", "delay_frac", "gain_unit")
    chans = [n[5:] for n in t.names if n.startswith("gain_") and n != "gain_unit"]
    if not chans or len(t) < 1:
        raise InputError(f"{t.path}: expected at least one 'gain_<channel>' column and one row")
    a, b, frac, tau = t.float("a"), t.float("b"), t.float("delay_frac"), t.float("tau_s")
    scale = t.float("scale")
    for name, v, ok in (("scale", scale, scale > 0), ("a", a, (a >= 0) & (a < 1)), ("b", b, np.abs(a + b - 1) <= 1e-12),
                        ("delay_frac", frac, (frac >= 0) & (frac < 1)), ("tau_s", tau, tau >= 0)):
        bad = np.flatnonzero(~ok)
        if bad.size:
            want = {"scale": "scale > 0", "a": "0 <= a < 1", "b": "b = 1 - a", "delay_frac": "0 <= delay_frac < 1",
                    "tau_s": "tau_s >= 0"}
            raise InputError(f"{t.path}: row {t.row_number(int(bad[0]))}, column '{name}': expected {want[name]}, "
                             f"got {v[bad[0]]:.15g}")
    inputs = t.raw("input")
    if inputs[-1] != DRIFT_CONST:
        raise InputError(f"{t.path}: row {t.row_number(len(t) - 1)}, column 'input': expected the offset row "
                         f"{DRIFT_CONST!r} last, got {inputs[-1]!r}")
    return DriftCoefficients(dt, inputs, scale, t.int("power"), tau, a, b,
                             t.int("delay_samples"), frac, {ch: t.float(f"gain_{ch}") for ch in chans},
                             t.raw("gain_unit"))


def controller_drift(coef: DriftCoefficients, time_s, inputs: dict) -> tuple[np.ndarray, dict]:
    """Run the coefficients as a controller does, deliberately plainly: one tick every
    ``sample_period_s`` from ``time_s[0]``, each tick reading the latest logged value at or before it
    (sample and hold), the recursion, the delay ring buffer, the gains.

    ``time_s`` (n,) log times; ``inputs`` {input name: (n,)} logged values (gaps already held).
    Returns ``(ticks_s (K,), {channel: (K,) prediction um})``. Independent of
    :func:`errormap.diagnosis.drift_models.feature_matrix` on purpose: it uses the file's numbers only.
    """
    time_s = np.asarray(time_s, float)
    dt = coef.sample_period_s
    n_ticks = int(np.floor((time_s[-1] - time_s[0]) / dt + 1e-9)) + 1
    ticks = time_s[0] + dt * np.arange(n_ticks)
    src = np.searchsorted(time_s, ticks + DRIFT_TICK_EPS_S, side="right") - 1
    U = np.stack([np.ones(len(time_s)) if name == DRIFT_CONST else np.asarray(inputs[name], float)
                  for name in coef.inputs], axis=1)
    V = (U / coef.scale) ** coef.power                             # (n, m)
    G = np.stack([coef.gains[ch] for ch in coef.gains], axis=1)    # (m, c)
    n, fr = coef.delay_samples.astype(int), coef.delay_frac
    L = int(n.max()) + 2
    cols = np.arange(len(coef.inputs))
    y = V[src[0]].copy()
    buf = np.tile(y, (L, 1))
    out = np.empty((n_ticks, G.shape[1]))
    for k in range(n_ticks):
        y = coef.a * y + coef.b * V[src[k]]
        buf[k % L] = y
        f = (1.0 - fr) * buf[(k - n) % L, cols] + fr * buf[(k - n - 1) % L, cols]
        out[k] = f @ G
    return ticks, {ch: out[:, j] for j, ch in enumerate(coef.gains)}


def controller_drift_at(coef: DriftCoefficients, log) -> dict:
    """The controller's prediction in force at each log time (its latest tick at or before it): {ch: (n,)}."""
    from errormap.diagnosis.drift_models import input_values
    inputs = {name: input_values(log, name) for name in set(coef.inputs) - {DRIFT_CONST}}
    ticks, pred = controller_drift(coef, log.time_s, inputs)
    j = np.searchsorted(ticks, log.time_s + DRIFT_TICK_EPS_S, side="right") - 1
    return {ch: p[j] for ch, p in pred.items()}


def check_drift_export(coef: DriftCoefficients, model, log, clean_um: dict | None = None) -> dict:
    """Re-simulate the controller from ``coef`` on ``log`` and compare, per channel:

    ``model`` — controller − ``model.predict(log)`` (the discretisation error of the export);
    ``measured`` (when the log has the channel) — displacement − controller, beside ``before``
    (the displacement itself), ``volcomp`` (displacement − the fixed model the gains run) and
    ``volcomp_distance_rule`` (displacement − model.predict with the per-sample shrinkage toward OLS);
    ``true`` (``clean_um`` of a simulated log) — the same three against the noise-free displacement.
    Returns ``{channel: {...}}``; statistics are max |·| and RMS over the log's samples (μm).
    """
    ctrl = controller_drift_at(coef, log)
    fixed = model.predict(log, distance_shrink=False)     # what the gains run (the rule beyond d0 is the controller's)
    pred = model.predict(log)
    out = {}
    for ch in model.channels:
        rec = {"model": residual_stats(ctrl[ch] - fixed[ch]), "measured": None, "true": None}
        for key, d in (("measured", log.disp_um.get(ch)), ("true", (clean_um or {}).get(ch))):
            if d is not None:
                rec[key] = {"controller": residual_stats(d - ctrl[ch]), "before": residual_stats(d),
                            "volcomp": residual_stats(d - fixed[ch]),
                            "volcomp_distance_rule": residual_stats(d - pred[ch])}
        out[ch] = rec
    return out


def worst_drift_model_um(check: dict) -> float:
    return max(r["model"]["max_um"] for r in check.values())


def export_drift_coefficients(model, folder, sample_period_s: float, log, model_desc: str,
                              tolerance_um: float, clean_um: dict | None = None, force: bool = False) -> dict:
    """Write ``drift_coefficients.csv`` into ``folder`` (a staging folder), read it back, re-simulate the
    controller from the file alone on ``log`` and check it; returns ``{"check", "worst_model_residual_um",
    "tolerance_met", "file"}``. Raises :class:`ValueError` when the tolerance is not met and not ``force``
    (the caller discards the staging folder: nothing is written)."""
    coef = drift_coefficients(model, sample_period_s)
    path = write_drift_coefficients(coef, folder, model_desc)
    back = read_drift_coefficients(path)
    check = check_drift_export(back, model, log, clean_um)
    worst = worst_drift_model_um(check)
    met = worst <= tolerance_um
    if not met and not force:
        raise ValueError(f"tolerance not met: at a sample period of {sample_period_s:g} s the drift coefficients leave "
                         f"a model residual up to {worst:.4g} um > --tolerance-um {tolerance_um:g}; nothing written "
                         "(--force writes anyway, recorded in export.json)")
    return {"check": check, "worst_model_residual_um": worst, "tolerance_met": bool(met), "file": path,
            "coefficients": back}
