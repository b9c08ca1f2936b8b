"""A second, independent family of truth grinders, for testing estimators on machines the
default simulator (:mod:`errormap.simulator`) did not shape.

What differs from the default family (same interfaces: an :class:`~errormap.chain_elements.ChainElementSet`
inside a :class:`~errormap.simulator.TruthGrinder`, the same effect names):

* **Element shapes**: linear axes — a sum of 2–5 Gaussian bumps (centre anywhere on the
  stroke, width 8–35 % of it) plus Chebyshev terms T1…T4 with decaying coefficients; A — a
  Fourier series of harmonics 1…6 with amplitudes decaying as ``h^-1.5``, random phases. The
  default family is a cubic plus one sinusoid (linear axes) and harmonics 1–3 (A).
* **Resolution**: the truth is stored on 81 stations per axis (a cubic spline through them),
  so between the identification's 21 stations the truth is not a 21-knot spline.
* **Magnitudes**: each element's scale is drawn log-uniformly from its own range
  (:data:`SCALE_RANGE`, not the default table), and the whole set is scaled to a maximum
  spatial error drawn in [120, 260] μm (default: [165, 215]).
* **Effects**: the same five names with other parameters, drawn per seed
  (:func:`independent_effect_parameters`): pitch period 6–14 mm, backlash 5–10 μm, thermal
  8–14 ppm/°C, worm 30–50 teeth and 60–140 μrad, interaction corner 4–9 μm.
* **Checks**: a scrambled Sobol layout over the strokes (not uniform random points), a
  warm-up of 3–5 °C with a 1500–3500 s time constant and a slow ±0.15 °C ambient wobble.

Randomness comes from the seed only (``numpy.random.SeedSequence`` sub-streams).
"""
from __future__ import annotations

import numpy as np
from numpy.polynomial import chebyshev
from scipy.stats import qmc

from .chain_elements import ChainElementSet
from .elements import A_ELEMENTS, CONSTANT_ELEMENTS, X_ELEMENTS, Z_ELEMENTS, default_stations
from .chain_kernel import spatial_error
from .machine_tool import MachineTool
from .seeds import spawn_rngs
from .simulator import REF_TEMP_C, TruthGrinder, random_truth, simulator_effects, volume_grid

FAMILIES = ("default", "independent")
TRUTH_STATIONS = 81
"""Stations the independent truth is stored on (a spline through 81 points, not 21)."""

# per-element (low, high) scale, μm or μrad, drawn log-uniformly
SCALE_RANGE = {
    "dx_x": (3.0, 25.0), "dy_x": (2.0, 15.0), "dz_x": (2.0, 15.0),
    "ex_x": (5.0, 40.0), "ey_x": (5.0, 40.0), "ez_x": (5.0, 40.0),
    "dx_z": (2.0, 15.0), "dy_z": (2.0, 15.0), "dz_z": (3.0, 20.0),
    "ex_z": (5.0, 35.0), "ey_z": (5.0, 35.0), "ez_z": (5.0, 35.0),
    "dx_a": (1.0, 8.0), "dy_a": (2.0, 10.0), "dz_a": (2.0, 10.0),
    "ex_a": (10.0, 80.0), "ey_a": (5.0, 40.0), "ez_a": (5.0, 40.0),
    "dy_oa": (10.0, 100.0), "dz_oa": (10.0, 100.0), "ey_oa": (20.0, 200.0), "ez_oa": (20.0, 200.0),
    "s_xz": (10.0, 120.0),
}
TARGET_MAX_RANGE_UM = (120.0, 260.0)


def _bumps_and_chebyshev(u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A smooth random curve on u ∈ [0, 1], shape (m,), zero at u = 0, max |.| = 1."""
    v = np.zeros_like(u)
    for _ in range(int(rng.integers(2, 6))):
        c, w = rng.uniform(-0.1, 1.1), rng.uniform(0.08, 0.35)
        v += rng.normal() * np.exp(-0.5 * ((u - c) / w) ** 2)
    coef = np.r_[0.0, rng.normal(size=4) / np.arange(1, 5) ** 1.2]
    v += chebyshev.chebval(2 * u - 1, coef)
    v -= v[0]
    return v / max(np.abs(v).max(), 1e-12)


def _fourier(theta: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random periodic curve (harmonics 1..6, amplitudes ∝ h^-1.5), zero at θ = θ0, max |.| = 1."""
    h = np.arange(1, 7)
    amp = rng.normal(size=6) / h**1.5
    ph = rng.uniform(0, 2 * np.pi, 6)
    v = (amp[None] * np.cos(h[None] * theta[:, None] + ph[None])).sum(axis=1)
    v -= v[0]
    return v / max(np.abs(v).max(), 1e-12)


def independent_elements(machine: MachineTool, rng: np.random.Generator, n_stations: int = TRUTH_STATIONS) -> ChainElementSet:
    """Unscaled independent-family elements on ``n_stations`` stations per axis (see module doc)."""
    st = default_stations(machine, n_stations)
    u = np.linspace(0.0, 1.0, n_stations)
    theta = np.deg2rad(st["a_deg"] - st["a_deg"][0])
    scale = {k: float(np.exp(rng.uniform(*np.log(SCALE_RANGE[k])))) for k in SCALE_RANGE}
    fun = {k: scale[k] * _bumps_and_chebyshev(u, rng) for k in X_ELEMENTS + Z_ELEMENTS}
    for k in A_ELEMENTS:
        fun[k] = scale[k] * _fourier(theta, rng)
        fun[k][-1] = fun[k][0]
    const = {k: scale[k] * rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 1.0) for k in CONSTANT_ELEMENTS}
    return ChainElementSet(machine, st, fun, const, machine.name, machine.sha256)


def independent_effect_parameters(rng: np.random.Generator) -> dict:
    """Per-seed parameters of the effects (differ from the simulator's defaults)."""
    return {
        "thermal": {"k_um_per_mm_c": rng.uniform(0.008, 0.014)},
        "reversal": {"backlash_um": rng.uniform(5.0, 10.0)},
        "pitch": {"amplitude_um": rng.uniform(2.5, 5.0), "period_mm": rng.uniform(6.0, 14.0),
                  "phase_rad": rng.uniform(0, 2 * np.pi)},
        "worm": {"amplitude_urad": rng.uniform(60.0, 140.0), "teeth": int(rng.integers(30, 51)),
                 "phase_rad": rng.uniform(0, 2 * np.pi)},
        "interaction": {"corner_um": rng.uniform(4.0, 9.0) * rng.choice([-1.0, 1.0])},
        # out-of-catalogue effects (drawn after the five, so their draws leave those unchanged)
        "bump": {"amplitude_um": rng.uniform(6.0, 10.0) * rng.choice([-1.0, 1.0]), "x_frac": rng.uniform(0.3, 0.7),
                 "z_frac": rng.uniform(0.3, 0.7), "width_frac": rng.uniform(0.14, 0.22)},
        "a_tilt": {"k_urad": rng.uniform(80.0, 160.0) * rng.choice([-1.0, 1.0])},
        "squareness": {"k_urad": rng.uniform(70.0, 130.0) * rng.choice([-1.0, 1.0])},
        # drawn after the three above, so every draw above is unchanged
        "squareness_xz": {"k_urad": rng.uniform(70.0, 130.0) * rng.choice([-1.0, 1.0])},
        # drawn after squareness_xz, so every draw above is unchanged
        "a_lobe_x": {"amplitude_um": rng.uniform(4.5, 7.5) * rng.choice([-1.0, 1.0]), "x_frac": rng.uniform(0.35, 0.65),
                     "width_frac": rng.uniform(0.12, 0.18), "phase_rad": rng.uniform(0.0, 2 * np.pi)},
        # drawn last, after a_lobe_x, so every draw above is unchanged
        "xz_saddle": {"amplitude_um": rng.uniform(6.0, 10.0) * rng.choice([-1.0, 1.0]), "x_frac": rng.uniform(0.35, 0.65),
                      "z_frac": rng.uniform(0.4, 0.6), "width_frac": rng.uniform(0.12, 0.18)},
    }


class IndependentTruth(TruthGrinder):
    """A truth grinder of the independent family; its checks use a Sobol layout and another
    warm-up (see module doc). Same interface as :class:`TruthGrinder`."""

    family = "independent"

    def check_measurements(self, n: int = 400, noise_um: float = 1.0, seed: int = 0, dt_s: float = 15.0,
                           noise_seed=None) -> dict:
        """Check measurements (DESIGN.md schema), a dict of columns each shape (n,). ``noise_seed``: None
        (default) the noise stream of ``seed``; a seed: only the noise redrawn, the layout unchanged."""
        r_pts, r_env, r_noise = spawn_rngs(seed, 3)
        if noise_seed is not None:
            r_noise = np.random.default_rng(noise_seed)
        lo, hi = self.machine.stroke_lo, self.machine.stroke_hi
        u = qmc.Sobol(3, scramble=True, seed=r_pts).random_base2(int(np.ceil(np.log2(max(n, 2)))))
        u = u[r_pts.permutation(u.shape[0])[:n]]  # Sobol order is structured: measure n of them in random order
        axes = lo + (hi - lo) * u
        t = np.arange(n) * dt_s
        rise, tau = r_env.uniform(3.0, 5.0), r_env.uniform(1500.0, 3500.0)
        temp = (REF_TEMP_C + rise * (1.0 - np.exp(-t / tau)) + 0.15 * np.sin(2 * np.pi * t / 5400.0 + r_env.uniform(0, 6.3))
                + r_env.normal(0, 0.02, n))
        dirs = r_env.choice([-1, 1], size=(n, 3))
        cond = {"temp_c": temp, "dir_x": dirs[:, 0], "dir_z": dirs[:, 1], "dir_a": dirs[:, 2]}
        e = self.spatial_error(axes, **cond) + r_noise.normal(0.0, noise_um, (n, 3))
        return {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": axes[:, 2],
                "dx_um": e[:, 0], "dy_um": e[:, 1], "dz_um": e[:, 2],
                "time_s": t, "temp_c": temp, "dir_x": dirs[:, 0], "dir_z": dirs[:, 1], "dir_a": dirs[:, 2],
                "seq": np.arange(n)}


def independent_truth(machine: MachineTool, seed: int, effects=()) -> IndependentTruth:
    """A seeded independent-family truth; ``effects`` are names (parameters drawn per seed) or
    a name -> parameters mapping (overrides the drawn ones)."""
    ss = np.random.SeedSequence([seed, 0x1D3])
    r_el, r_scale, r_eff = (np.random.default_rng(s) for s in ss.spawn(3))
    el = independent_elements(machine, r_el)
    grid = volume_grid(machine)
    e = spatial_error(machine, grid, el.values(grid))
    el = el.scaled(r_scale.uniform(*TARGET_MAX_RANGE_UM) / np.linalg.norm(e, axis=1).max())
    drawn = independent_effect_parameters(r_eff)
    params = {k: {**drawn[k], **(v or {})} for k, v in simulator_effects(effects).items()}
    return IndependentTruth(machine, el, params, seed)


def make_truth(machine: MachineTool, seed: int, effects=(), family: str = "default") -> TruthGrinder:
    """A seeded truth grinder of ``family`` (``"default"``: :func:`errormap.simulator.random_truth`;
    ``"independent"``: :func:`independent_truth`)."""
    if family == "default":
        return random_truth(machine, seed, effects=effects)
    if family == "independent":
        return independent_truth(machine, seed, effects=effects)
    raise ValueError(f"Expected family in {FAMILIES}, got {family!r}")
