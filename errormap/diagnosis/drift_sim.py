"""Drift-log simulators for development, tests and benchmarks: two independent families.

Both return the drift-log columns plus ``"_truth"`` (``{"noise_um": {channel: σ}, "clean_um": {channel: (n,)},
...}``, for evaluation only). :func:`simulate_lumped_log`: a lumped thermal network of a few bodies (0.5–5 h),
spindle and feed-drive heat, ambient swing, 18 surface sensors, five channels with path lags, white noise,
quantisation, dropouts. :func:`simulate_rod_log`: a column conducting heat along 10 segments, machining
cycles, a thermostatic coolant loop, a day-cycle ambient with a door step, 20 sensors, four channels
(elongation, tilt, a delayed second-order path, spindle growth with AR(1) noise)."""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm



def _discrete(A, B, dt_s):
    """Zero-order-hold discretisation of ``dx/dt = A x + B u``: (Ad, Bd)."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt_s)
    return E[:n, :n], E[:n, n:]


def _run(Ad, Bd, U, x0):
    """States (n_steps, n_states) of ``x[k+1] = Ad x[k] + Bd u[k]``."""
    X = np.empty((len(U), len(x0)))
    x = np.array(x0, float)
    for k in range(len(U)):
        X[k] = x
        x = Ad @ x + Bd @ U[k]
    return X


def _first_order(u, dt_s, tau_s):
    """Exact first-order lag of a sampled input (zero-order hold), starting at ``u[0]``."""
    if tau_s <= 0:
        return np.array(u, float)
    a = 1.0 - np.exp(-dt_s / tau_s)
    y = np.empty_like(u, dtype=float)
    acc = u[0]
    for k in range(len(u)):
        acc = acc + a * (u[k] - acc)
        y[k] = acc
    return y


def spindle_profile(rng, t_s, max_rpm=12000.0, run_h=(0.5, 4.0), stop_h=(0.3, 2.0), step_min=(10, 60)):
    """Run/stop cycles with speed steps during runs: ``speed_rpm`` (n,)."""
    speed = np.zeros_like(t_s)
    t, end = 0.0, t_s[-1] + 1
    running = bool(rng.integers(2))
    while t < end:
        if running:
            dur = rng.uniform(*run_h) * 3600
            tt = t
            while tt < min(t + dur, end):
                st = rng.uniform(*step_min) * 60
                sel = (t_s >= tt) & (t_s < min(tt + st, t + dur))
                speed[sel] = rng.choice(np.linspace(0.2, 1.0, 9)) * max_rpm
                tt += st
        else:
            dur = rng.uniform(*stop_h) * 3600
        t += dur
        running = not running
    return speed


def _dropouts(rng, cols, names, n, n_drop, max_rows):
    """Blank ``n_drop`` stretches of 1..max_rows rows in random sensors (NaN: empty cells in the CSV)."""
    out = []
    for _ in range(n_drop):
        s = names[rng.integers(len(names))]
        k = int(rng.integers(10, n - max_rows - 10))
        m = int(rng.integers(1, max_rows + 1))
        cols[f"temp_{s}_c"][k:k + m] = np.nan
        out.append((s, k, m))
    return out


def _shift(t, speed, ambient, shift_at, shift_speed, shift_ambient_c):
    """A later regime the earlier part did not cover: from the fraction ``shift_at`` of the log on, the
    spindle runs ``shift_speed`` times faster and the ambient is ``shift_ambient_c`` warmer (a ramp over
    1 h). ``shift_at`` None: unchanged. Returns (speed, ambient)."""
    if shift_at is None:
        return speed, ambient
    if not 0 < shift_at < 1:
        raise ValueError(f"Expected 0 < shift_at < 1, got {shift_at}")
    t0 = shift_at * t[-1]
    late = t >= t0
    speed = np.where(late, speed * shift_speed, speed)
    ambient = ambient + shift_ambient_c * np.clip((t - t0) / 3600.0, 0.0, 1.0)
    return speed, ambient


SHIFT_SPEED = 1.3       # the later regime's spindle speed factor (heat ∝ speed^1.6…2: ~1.5–1.7× the heat)
SHIFT_AMBIENT_C = 2.0   # and its ambient offset: both leave the fit range of the earlier part


def simulate_lumped_log(seed: int = 0, hours: float = 46.0, dt_s: float = 15.0, n_sensors: int = 18,
                        n_dropouts: int = 3, shift_at: float | None = None, shift_speed: float = SHIFT_SPEED,
                        shift_ambient_c: float = SHIFT_AMBIENT_C) -> dict:
    """A lumped-network drift log (see module doc); 5 channels ``ch1_um … ch5_um``. ``shift_at``: a
    later regime outside the fit range (:func:`_shift`)."""
    if n_sensors < 8:
        raise ValueError(f"Expected n_sensors >= 8, got {n_sensors}")
    rng = np.random.default_rng(seed)
    n = int(round(hours * 3600 / dt_s))
    t = np.arange(n) * dt_s
    speed = spindle_profile(rng, t)
    running = (speed > 0).astype(float)
    feed = running * np.repeat(rng.uniform(0.2, 1.0, n // 40 + 1), 40)[:n]
    day = 24 * 3600.0
    ambient = 20.0 + rng.uniform(0.8, 2.0) * np.sin(2 * np.pi * t / day + rng.uniform(0, 2 * np.pi)) \
        + np.cumsum(rng.normal(0, 0.004, n))
    speed, ambient = _shift(t, speed, ambient, shift_at, shift_speed, shift_ambient_c)
    # bodies: spindle, headstock, column, bed, ball screw; own time constants to ambient (h)
    tau_h = np.array([rng.uniform(0.5, 0.9), rng.uniform(1.2, 2.2), rng.uniform(2.5, 4.0),
                      rng.uniform(4.0, 5.0), rng.uniform(0.6, 1.5)])
    nb = len(tau_h)
    A = -np.diag(1.0 / (tau_h * 3600))
    links = [(0, 1, 0.6), (1, 2, 0.4), (2, 3, 0.3), (4, 3, 0.3), (4, 2, 0.2)]
    for i, j, w in links:
        g = w * rng.uniform(0.5, 1.5) / (3600 * np.sqrt(tau_h[i] * tau_h[j]))
        A[i, j] += g
        A[j, i] += g
        A[i, i] -= g
        A[j, j] -= g
    # inputs: spindle heat, feed heat, ambient (each body leaks to ambient at its own rate)
    B = np.zeros((nb, 3))
    B[0, 0] = rng.uniform(6, 10) / (tau_h[0] * 3600)     # up to ~8 °C steady rise in the spindle
    B[1, 0] = rng.uniform(1, 3) / (tau_h[1] * 3600)
    B[4, 1] = rng.uniform(3, 6) / (tau_h[4] * 3600)
    B[:, 2] = -A.sum(axis=1)                              # uniform ambient → uniform steady state
    U = np.stack([(speed / 12000.0) ** 1.6, feed, ambient], axis=1)
    Ad, Bd = _discrete(A, B, dt_s)
    x0 = np.full(nb, ambient[0])
    X = _run(Ad, Bd, U, x0)                               # (n, nb) body temperatures, °C
    cols = {"time_s": t, "speed_rpm": speed}
    names = [f"s{i + 1}" for i in range(n_sensors)]
    far = set(names[-4:-1])                               # far from any heat path: bed + ambient only
    air = names[-1]
    for s in names:
        if s == air:
            spot = _first_order(ambient, dt_s, 300.0)
        elif s in far:
            w = rng.uniform(0.2, 0.5)
            spot = _first_order(w * X[:, 3] + (1 - w) * ambient, dt_s, rng.uniform(600, 1800))
        else:             # on the surface between two bodies: lags the cores by 10–40 min; the spindle
            near = rng.choice(nb, size=2, replace=False)   # core itself is never read directly
            w = rng.dirichlet([1.0, 0.6])
            w[near == 0] = np.minimum(w[near == 0], 0.3)
            mix = (w[0] * X[:, near[0]] + w[1] * X[:, near[1]] + (1 - w.sum()) * ambient)
            spot = _first_order(mix, dt_s, rng.uniform(600, 2400))
        cols[f"temp_{s}_c"] = np.round(spot + rng.normal(0, 0.02, n), 2)
    dropped = _dropouts(rng, cols, names, n, n_dropouts, 20)
    noise, clean = {}, {}
    frame = _first_order(ambient, dt_s, rng.uniform(1, 3) * 3600) - ambient[0]   # an exposed frame, not sensed
    for c in range(5):
        g = rng.normal(0, 1, nb) * rng.uniform(1.0, 4.0, nb)   # μm/°C per body
        g[c % nb] = rng.choice([-1, 1]) * rng.uniform(5, 10)    # one dominant path: spindle, headstock, ...
        path = _first_order((X - X[0]) @ g + rng.normal(0, 3) * frame, dt_s, rng.uniform(0, 1800))
        sd = float(rng.uniform(0.3, 0.8))
        ch = f"ch{c + 1}"
        clean[ch] = path
        noise[ch] = sd
        cols[f"{ch}_um"] = path + rng.normal(0, sd, n)
    cols["_truth"] = {"family": "lumped", "noise_um": noise, "clean_um": clean, "body_tau_h": tau_h.tolist(),
                      "far_sensors": sorted(far), "air_sensor": air, "dropouts": dropped}
    return cols


def simulate_rod_log(seed: int = 0, hours: float = 40.0, dt_s: float = 20.0, n_sensors: int = 20,
                     n_dropouts: int = 2, shift_at: float | None = None, shift_speed: float = SHIFT_SPEED,
                     shift_ambient_c: float = SHIFT_AMBIENT_C) -> dict:
    """A conducting-column drift log with coolant and door (see module doc); 4 channels
    ``elong_um``, ``tilt_um``, ``delayed_um``, ``growth_um``. ``shift_at``: a later regime outside the
    fit range (:func:`_shift`)."""
    rng = np.random.default_rng(seed)
    n = int(round(hours * 3600 / dt_s))
    t = np.arange(n) * dt_s
    # batches of short machining cycles: on 3–8 min, off 1–3 min, batch 1–5 h, idle 0.5–3 h
    speed = np.zeros(n)
    tt, batch = 0.0, bool(rng.integers(2))
    while tt < t[-1]:
        dur = (rng.uniform(1, 5) if batch else rng.uniform(0.5, 3)) * 3600
        if batch:
            rpm = rng.choice([6000.0, 8000.0, 10000.0, 14000.0])
            c = tt
            while c < tt + dur:
                on, off = rng.uniform(3, 8) * 60, rng.uniform(1, 3) * 60
                speed[(t >= c) & (t < min(c + on, tt + dur))] = rpm
                c += on + off
        tt += dur
        batch = not batch
    heat = (speed / 14000.0) ** 2
    day = 24 * 3600.0
    ambient = 21.0 + rng.uniform(1.0, 2.5) * np.sin(2 * np.pi * t / day + rng.uniform(0, 2 * np.pi))
    door = rng.uniform(0.3, 0.7) * t[-1]
    ambient = ambient - rng.uniform(0.5, 1.5) * (t > door) * np.exp(-np.maximum(t - door, 0) / 5400.0)
    speed, ambient = _shift(t, speed, ambient, shift_at, shift_speed, shift_ambient_c)
    heat = (speed / 14000.0) ** 2
    # column of m segments: diffusion, heated at the top (spindle), losses to ambient and coolant at the top
    m = 10
    k_s = 1.0 / rng.uniform(600, 1500)          # 1/s between neighbours
    h_s = 1.0 / rng.uniform(4, 9) / 3600        # to ambient
    A = np.zeros((m, m))
    for i in range(m - 1):
        A[i, i + 1] += k_s
        A[i + 1, i] += k_s
        A[i, i] -= k_s
        A[i + 1, i + 1] -= k_s
    A -= np.eye(m) * h_s
    coolant_setpoint = 20.5
    coolant = np.empty(n)
    cool_T, chiller = coolant_setpoint, False
    dt = dt_s
    Bh = np.zeros((m, 3))
    Bh[0, 0] = rng.uniform(8, 14) / 3600       # heat, °C/s at full speed
    Bh[:, 1] = h_s                             # ambient
    g_c = 1.0 / rng.uniform(1200, 2400)
    Bh[0, 2] = g_c                             # coolant on the top segment
    A[0, 0] -= g_c
    Ad, Bd = _discrete(A, Bh, dt)
    x = np.full(m, ambient[0])
    X = np.empty((n, m))
    for k in range(n):
        X[k] = x
        # coolant: warmed by the top segment, chiller on/off with ±0.3 °C hysteresis
        cool_T += dt * ((x[0] - cool_T) / 1800.0 - (0.9 / 3600.0 if chiller else 0.0) + (ambient[k] - cool_T) / 7200)
        chiller = cool_T > coolant_setpoint + 0.3 or (chiller and cool_T > coolant_setpoint - 0.3)
        coolant[k] = cool_T
        x = Ad @ x + Bd @ np.array([heat[k], ambient[k], cool_T])
    cols = {"time_s": t, "speed_rpm": speed}
    names = [f"r{i + 1:02d}" for i in range(n_sensors)]
    pos = np.linspace(0, 1, m)
    for i, s in enumerate(names):
        if i < 12:        # along the column
            p = rng.uniform(0, 1)
            w = np.interp(pos, [p - 0.15, p, p + 0.15], [0, 1, 0], left=0, right=0)  # tent between segments
            spot = X @ (w / w.sum())
        elif i < 15:      # coolant line
            spot = _first_order(coolant, dt, rng.uniform(60, 300))
        elif i < 18:      # air near the machine
            spot = _first_order(ambient + rng.uniform(-0.3, 0.3), dt, rng.uniform(300, 900))
        else:             # base, far from heat
            spot = _first_order(0.3 * X[:, -1] + 0.7 * ambient, dt, rng.uniform(1800, 3600))
        sd = rng.uniform(0.01, 0.05) * (1 + 0.5 * (speed > 0))          # noisier while the spindle runs
        cols[f"temp_{s}_c"] = np.round(spot + rng.normal(0, 1, n) * sd, 3)
    dropped = _dropouts(rng, cols, names, n, n_dropouts, 12)
    dX = X - X[0]
    alpha = rng.uniform(8, 14)          # μm/°C over the whole column
    clean = {"elong": alpha * dX.mean(axis=1),
             "tilt": rng.uniform(15, 30) * (dX[:, 0] - dX[:, -1]) * rng.choice([-1, 1]),
             "delayed": np.interp(t - rng.uniform(600, 1800), t,
                                  _first_order(_first_order(dX @ rng.normal(0, 4, m), dt, rng.uniform(900, 2400)),
                                               dt, rng.uniform(900, 2400))),
             "growth": rng.uniform(3, 6) * _first_order(heat, dt, rng.uniform(300, 900)) + 2.0 * dX[:, 0]}
    noise = {}
    for ch, v in clean.items():
        sd = float(rng.uniform(0.3, 0.7))
        if ch == "growth":   # AR(1) noise, φ = 0.8, stationary σ = sd
            e = rng.normal(0, sd * np.sqrt(1 - 0.64), n)
            w = np.empty(n)
            w[0] = rng.normal(0, sd)
            for k in range(1, n):
                w[k] = 0.8 * w[k - 1] + e[k]
        else:
            w = rng.normal(0, sd, n)
        noise[ch] = sd
        cols[f"{ch}_um"] = v + w
    cols["_truth"] = {"family": "rod", "noise_um": noise, "clean_um": clean, "dropouts": dropped}
    return cols


SIMULATORS = {"lumped": simulate_lumped_log, "rod": simulate_rod_log}
