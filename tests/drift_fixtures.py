"""A seeded drift log for the drift tests (a dict of columns, as the CSV reader's input), and a simulator's columns as
a DriftLog in memory (the commands read the simulator's CSV instead)."""
from __future__ import annotations

import numpy as np
from scipy import signal

from errormap.diagnosis.drift import DriftLog, lagged


def _lowpass(u, dt_s, tau_s):
    """First-order lag ``τ·dy/dt = u − y`` (forward Euler at ``dt_s``), starting at ``u[0]``: (n,)."""
    a = dt_s / tau_s
    return signal.lfilter([a], [1.0, a - 1.0], u, zi=[(1.0 - a) * u[0]])[0]


def simulate_drift_log(seed: int = 0, n: int = 2160, dt_s: float = 10.0, n_sensors: int = 6,
                       active=("s2", "s5"), lag_s: float = 300.0, noise_um: float = 0.5,
                       channels=("dx", "dz"), sensor_noise_c: float = 0.01, copies=None) -> dict:
    """A seeded drift log (a dict of columns): ``n_sensors`` temperature sensors ``temp_s1_c …``
    and displacement channels ``<ch>_um``, with ``speed_rpm``.

    Three independent heat sources — the spindle (a stepped ``speed_rpm`` profile), a feed-drive
    duty cycle switching at other times, and the ambient (slow sinusoid plus random walk) — reach
    each sensor's spot with its own random weights through first-order lags of its own time
    constants (600–4000 s). A sensor reads its spot's temperature plus N(0, ``sensor_noise_c``).
    Each channel is ``Σ_active k·(T(t − lag_s) − T(0))`` of the spots' TRUE temperatures (the
    structure does not see the sensors' noise), k of 4–8 μm/°C and random sign, plus N(0, noise_um).
    ``copies`` {sensor: other} makes ``sensor`` a second reading of ``other``'s spot (two sensors
    side by side: genuinely ambiguous). The truth is in ``"_truth"``: ``{channel: {sensor: k}}``.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt_s
    speed = np.repeat(rng.choice([0, 3000, 6000, 9000, 12000], size=n // 90 + 1), 90)[:n].astype(float)
    duty = np.repeat(rng.uniform(0.0, 1.0, size=n // 55 + 1), 55)[:n]
    ambient = 0.8 * np.sin(2 * np.pi * t / rng.uniform(20000, 60000) + rng.uniform(0, 2 * np.pi)) \
        + np.cumsum(rng.normal(0, 0.01, n))
    cols = {"time_s": t, "speed_rpm": speed}
    names = [f"s{i + 1}" for i in range(n_sensors)]
    spot, reading_noise = {}, {}
    for s in names:
        w = rng.dirichlet([0.7, 0.7, 0.7])
        spot[s] = 20.0 + w[0] * 4.0 * _lowpass(speed / 12000.0, dt_s, rng.uniform(600, 4000)) \
            + w[1] * 4.0 * _lowpass(duty, dt_s, rng.uniform(600, 4000)) + w[2] * 2.0 * ambient
        reading_noise[s] = rng.normal(0, sensor_noise_c, n)
    for s, other in (copies or {}).items():
        if s not in spot or other not in spot:
            raise ValueError(f"copies: unknown sensor in {s!r}: {other!r}; sensors are {names}")
        spot[s] = spot[other]
    for s in names:
        cols[f"temp_{s}_c"] = spot[s] + reading_noise[s]
    truth = {}
    for ch in channels:
        k = {s: float(rng.uniform(4.0, 8.0) * rng.choice([-1, 1])) for s in active}
        truth[ch] = k
        d = sum(kk * (lagged(t, spot[s], lag_s) - spot[s][0]) for s, kk in k.items())
        cols[f"{ch}_um"] = d + rng.normal(0, noise_um, n)
    cols["_truth"] = truth
    return cols


def drift_log_of(cols: dict, path: str = "<sim>") -> DriftLog:
    """A simulator's columns (``time_s``, ``temp_<sensor>_c``, ``<channel>_um``, optional
    ``speed_rpm``; ``"_truth"`` and other keys ignored) as a :class:`~errormap.diagnosis.drift.DriftLog`
    named ``path``: temperatures by sensor (°C), displacements by channel (μm), arrays as given."""
    return DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                    {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols.get("speed_rpm"), path)
