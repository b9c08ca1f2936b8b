"""Where a residual lives, without a model of its cause.

For each output axis (dx, dy, dz) and each input (axis positions, directions, time,
temperature) one test asks whether the residual depends on that input:

* ``offset``: the mean differs from zero (t-test, 1 dof);
* ``trend`` over x_mm, z_mm, time_s, temp_c: a cubic polynomial beyond the mean (3 dof);
* ``harmonics`` over a_deg: orders 1–3 (6 dof);
* ``step`` over dir_x, dir_z, dir_a: the two approach directions differ (1 dof);
* ``periodic`` over x_mm, z_mm, a_deg, time_s: the best sinusoid of a least-squares
  (Lomb–Scargle type) periodogram after removing the mean (2 dof, Bonferroni-corrected for
  the number of independent frequencies searched); reports the period.

Each F-test's p-value is Bonferroni-corrected over all tests run; findings with
``p_adjusted < alpha`` are returned, the largest explained variance first.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from .effects import projected_periodogram

OUTPUTS = ("dx", "dy", "dz")
PERIOD_UNITS = {"x_mm": "mm", "z_mm": "mm", "a_deg": "deg", "time_s": "s"}


def _ftest(y, X):
    """F-test of columns X beyond the mean for y; returns (p, RSS reduction)."""
    yc = y - y.mean()
    Xc = X - X.mean(axis=0)
    theta, *_ = np.linalg.lstsq(Xc, yc, rcond=None)
    rss0 = float(yc @ yc)
    rss1 = float(np.sum((yc - Xc @ theta) ** 2))
    p = X.shape[1]
    dof = len(y) - p - 1
    if dof <= 0 or rss1 <= 0:
        return 1.0, 0.0
    F = ((rss0 - rss1) / p) / (rss1 / dof)
    return float(stats.f.sf(F, p, dof)), rss0 - rss1


def locate(residual_um, inputs: dict, alpha: float = 0.01, period_min_mm: float = 1.0,
           max_order: int = 120, oversample: float = 5.0) -> list[dict]:
    """Significant dependences of ``residual_um`` (n, 3) on ``inputs`` ({name: (n,)}; names
    x_mm, z_mm, a_deg, time_s, temp_c, dir_x, dir_z, dir_a). See module doc."""
    r = np.asarray(residual_um, dtype=float)
    n = r.shape[0]
    tests = []
    for j, out in enumerate(OUTPUTS):
        y = r[:, j]
        sd = y.std(ddof=1)
        t = y.mean() / (sd / np.sqrt(n)) if sd > 0 else 0.0
        tests.append({"output": out, "input": "none", "pattern": "offset", "p": float(2 * stats.t.sf(abs(t), n - 1)),
                      "gain": float(n * y.mean() ** 2), "M": 1.0, "rss0": float(y @ y)})
        for name, v in inputs.items():
            v = np.asarray(v, dtype=float)
            if np.ptp(v) == 0:
                continue
            base = {"output": out, "input": name, "rss0": float(((y - y.mean()) ** 2).sum())}
            if name.startswith("dir_"):
                p, g = _ftest(y, v[:, None])
                tests.append({**base, "pattern": "step", "p": p, "gain": g, "M": 1.0})
                continue
            if name == "a_deg":
                a = np.deg2rad(v)
                X = np.stack([f(h * a) for h in (1, 2, 3) for f in (np.sin, np.cos)], axis=1)
                p, g = _ftest(y, X)
                tests.append({**base, "pattern": "harmonics", "p": p, "gain": g, "M": 1.0})
            else:
                u = (v - v.mean()) / v.std()
                p, g = _ftest(y, np.stack([u, u**2, u**3], axis=1))
                tests.append({**base, "pattern": "trend", "p": p, "gain": g, "M": 1.0})
            if name in PERIOD_UNITS:
                yc = y - y.mean()
                if name == "a_deg":
                    om, M, pos = np.arange(1.0, max_order + 1), float(max_order), np.deg2rad(v)
                else:
                    span = np.ptp(v)
                    pmin = period_min_mm if name != "time_s" else 4 * np.median(np.diff(np.sort(v)))
                    f = np.arange(2.0 / span, 1.0 / pmin, 1.0 / (oversample * span))
                    if f.size == 0:
                        continue
                    om, M, pos = 2 * np.pi * f, max(1.0, span * (1.0 / pmin - 2.0 / span)), v
                gain, _ = projected_periodogram(yc[:, None] * np.array([[1.0, 0, 0]]), np.tile([1.0, 0, 0], (n, 1)), pos, om)
                k = int(np.argmax(gain))
                rss1 = base["rss0"] - gain[k]
                F = (gain[k] / 2) / max(rss1 / (n - 3), 1e-300)
                period = (360.0 / om[k]) if name == "a_deg" else 2 * np.pi / om[k]
                tests.append({**base, "pattern": "periodic", "p": float(stats.f.sf(F, 2, n - 3)), "gain": float(gain[k]),
                              "M": M, "period": float(period), "period_unit": PERIOD_UNITS[name],
                              **({"order": int(round(om[k]))} if name == "a_deg" else {})})
    n_tests = len(tests)
    found = []
    for t in tests:
        p_adj = min(1.0, t["p"] * t["M"] * n_tests)
        if p_adj < alpha:
            d = {"output": t["output"], "input": t["input"], "pattern": t["pattern"], "p_adjusted": p_adj,
                 "explained_fraction": float(t["gain"] / t["rss0"]) if t["rss0"] > 0 else 0.0,
                 "rms_um": float(np.sqrt(t["gain"] / n))}
            for k in ("period", "period_unit", "order"):
                if k in t:
                    d[k] = t[k]
            found.append(d)
    found.sort(key=lambda d: -d["rms_um"])
    return found
