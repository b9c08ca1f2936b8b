"""A seeded "truth" grinder: random realistic element profiles plus optional effects
that the 23-element model does NOT represent, and simulated check measurements.

Element magnitudes (1-σ scale of each profile's shape, before the overall scaling) are
those of a small precision machine; the whole set is then scaled so that the maximum
spatial error (vector norm) over the working volume lands on a seeded target drawn in
[165, 215] μm (inside the required 150–230 μm band, every component within ±250 μm).

Undeclared effects (switch on by name; each magnitude is a documented default):

=============  ===================================================================  ===============================
name           what it adds (to an element, so it propagates through the chains)      default magnitude
=============  ===================================================================  ===============================
thermal        X ball-screw growth: ``dx_x += k·(temp_c - 20 °C)·(x - x_lo)``         k = 0.0115 μm/(mm·°C) (11.5 ppm/°C);
                                                                                     the check log warms 20 → 24 °C
reversal       Z backlash: ``dz_z += b/2 · dir_z``                                    b = 8 μm (±4 μm)
pitch          X ball-screw pitch error: ``dx_x += A·sin(2π·x/P + φ)``                A = 4 μm, P = 10 mm (aliased by the
                                                                                     10 mm identification stations)
worm           A worm-gear harmonic: ``ex_a += A·sin(N·a + φ)``                      A = 100 μrad, N = 40 teeth/rev (the
                                                                                     18° stations alias it to a constant)
interaction    X positioning depends on Z (column deflection):                       k = 6 μm at the far corner
               ``dx_x += k·(x - x_lo)(z - z_lo)/(Δx·Δz)``
=============  ===================================================================  ===============================

Out-of-catalogue effects (no kind of the diagnosis effect library can represent them; they are
what the closed loop's learned residual stage is for):

=============  ===================================================================  ===============================
name           what it adds                                                         default magnitude
=============  ===================================================================  ===============================
bump           a local bump of X's straightness over a region of X–Z:               A = 8 μm, centre at 60 % of X and
               ``dy_x += A·exp(−½((x−xc)/wx)² − ½((z−zc)/wz)²)``                     40 % of Z, w = 18 % of each stroke
a_tilt         the A axis's tilt (in its rotating frame) grows as X travels:          k = 120 μrad at the end of X
               ``ey_a += k·(x − x_lo)/Δx`` (couples X and A: a tilt of the A-line
               growing with X alone is X's own angular error, in the 23 elements)
squareness     an X–Z squareness that varies along X:                                k = 100 μrad at mid-X
               ``s_xz += k·sin(π·(x − x_lo)/Δx)``
squareness_xz  an X–Z squareness that varies over X and Z together (not separable:     k = 100 μrad at mid-X, mid-Z
               no element profile of one axis, nor X's angles times the Z lever,
               represents it): ``s_xz += k·sin(π·(x − x_lo)/Δx)·sin(π·(z − z_lo)/Δz)``
a_lobe_x       the A axis's two-lobe (oval) radial error motion, local in X and          A = 6 μm at its peak, centre
               changing sign across the region (X and A jointly: its mean over A is      at 50 % of X, w = 15 % of X,
               zero and its mean over X nearly so, so no one-axis profile takes it up):  φ = 0.4 rad
               ``dy_a += A·u·exp(½ − ½u²)·cos(2a + φ)``, ``u = ((x − x_lo)/Δx − xc)/w``
xz_saddle      a local saddle-shaped warp of Z's straightness (in Y) over a region of   A = 8 μm at its peak, centre
               X–Z: along X it changes sign across the region, along Z it rises in      at 50 % of X and 50 % of Z,
               the middle and falls on either side (X and Z jointly: its means over     w = 15 % of each stroke
               X and over Z are nearly zero, and along Z it is even about its centre,
               so neither a one-axis profile nor X's angles times the Z lever takes it
               up): ``dy_z += A·u·exp(½ − ½u²)·(1 − v²)·exp(−½v²)``,
               ``u = ((x − x_lo)/Δx − xc)/w``, ``v = ((z − z_lo)/Δz − zc)/w``
=============  ===================================================================  ===============================

Check measurements follow docs/reference/file-formats.md: ``x_mm, z_mm, a_deg, dx_um, dy_um, dz_um, time_s,
temp_c, dir_x, dir_z, dir_a, seq``; points uniform over the strokes, taken every
``dt_s`` seconds while the machine warms (``temp_c = 20 + 4·(1 - exp(-t/2400 s))``),
each approached from a random direction per axis, with isotropic Gaussian noise.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .effect_kinds import SIMULATOR_NAMES, TRUTH_ONLY, effect_kind, simulator_name
from .chain_elements import ChainElementSet
from .elements import A_ELEMENTS, CONSTANT_ELEMENTS, IDX, X_ELEMENTS, Z_ELEMENTS, default_stations
from .chain_kernel import forward, spatial_error
from .machine_tool import MachineTool

# 1-σ scale of each element's random profile (μm or μrad) before overall scaling
ELEMENT_SCALE = {
    "dx_x": 15.0, "dy_x": 8.0, "dz_x": 8.0, "ex_x": 20.0, "ey_x": 25.0, "ez_x": 25.0,
    "dx_z": 6.0, "dy_z": 6.0, "dz_z": 10.0, "ex_z": 20.0, "ey_z": 20.0, "ez_z": 20.0,
    "dx_a": 4.0, "dy_a": 5.0, "dz_a": 5.0, "ex_a": 60.0, "ey_a": 20.0, "ez_a": 20.0,
    "dy_oa": 60.0, "dz_oa": 60.0, "ey_oa": 150.0, "ez_oa": 150.0, "s_xz": 80.0,
}
MAX_ERROR_BAND_UM = (150.0, 230.0)
TARGET_MAX_RANGE_UM = (165.0, 215.0)
REF_TEMP_C = 20.0

EFFECT_DEFAULTS = {
    "thermal": {"k_um_per_mm_c": 0.0115},
    "reversal": {"backlash_um": 8.0},
    "pitch": {"amplitude_um": 4.0, "period_mm": 10.0, "phase_rad": 0.7},
    "worm": {"amplitude_urad": 100.0, "teeth": 40, "phase_rad": 1.1},
    "interaction": {"corner_um": 6.0},
    "bump": {"amplitude_um": 8.0, "x_frac": 0.6, "z_frac": 0.4, "width_frac": 0.18},
    "a_tilt": {"k_urad": 120.0},
    "squareness": {"k_urad": 100.0},
    "squareness_xz": {"k_urad": 100.0},
    "a_lobe_x": {"amplitude_um": 6.0, "x_frac": 0.5, "width_frac": 0.15, "phase_rad": 0.4},
    "xz_saddle": {"amplitude_um": 8.0, "x_frac": 0.5, "z_frac": 0.5, "width_frac": 0.15},
}
OUT_OF_CATALOGUE = TRUTH_ONLY
"""Effects no kind of :mod:`errormap.diagnosis.effects` represents (module doc; the registry,
:mod:`errormap.effect_kinds`, marks them truth-only)."""
EFFECT_NAMES = SIMULATOR_NAMES
"""The simulator's effect names, from the registry (:mod:`errormap.effect_kinds`); a kind's
canonical name (``periodic`` for ``pitch``) is accepted too and stored under this name."""
EFFECT_CHOICES = EFFECT_NAMES + tuple(k.name for k in map(effect_kind, SIMULATOR_NAMES) if k.name != k.simulator)
"""What ``--effect`` accepts: the simulator's names and the registry's canonical names of the same kinds
(``periodic`` = ``pitch``, ``harmonic`` = ``worm``)."""
EFFECT_HELP = ", ".join(EFFECT_NAMES) + " (" + ", ".join(
    f"{k} = {effect_kind(k).simulator}" for k in EFFECT_CHOICES[len(EFFECT_NAMES):]) + ")"
"""The ``--effect`` help: the names and the canonical names accepted beside them."""
EFFECT_NEEDS = {"thermal": "temp_c", "reversal": "dir_z"}


def simulator_effects(effects) -> dict:
    """``{simulator name: parameters}`` from names or a name -> parameters mapping, each name
    looked up in the registry (a canonical name such as ``periodic`` becomes ``pitch``);
    ``ValueError`` for an unknown name or a kind the simulator cannot draw."""
    eff = effects if isinstance(effects, dict) else {k: {} for k in effects}
    out = {}
    for name, params in eff.items():
        try:
            key = simulator_name(name)
        except ValueError as exc:
            raise ValueError(f"Expected effects from {list(EFFECT_NAMES)}, got {name!r} ({exc})") from None
        if key in out and (out[key] or {}) != (params or {}):
            raise ValueError(f"effect {name!r} given twice (as {key!r}) with different parameters")
        out[key] = params
    return out


def random_elements(machine: MachineTool, rng: np.random.Generator, n_stations: int = 21) -> ChainElementSet:
    """Smooth random profiles at ``n_stations`` stations, zero at each axis' first station.

    Linear axes: cubic polynomial plus one long-wave sinusoid; A: three harmonics.
    Unscaled: see :func:`random_truth` for the magnitude band.
    """
    st = default_stations(machine, n_stations)
    fun = {}
    for k in X_ELEMENTS + Z_ELEMENTS:
        u = np.linspace(0.0, 1.0, n_stations)
        c = rng.normal(size=3)
        w = rng.uniform(1.0, 2.5)
        v = c[0] * u + c[1] * u**2 + c[2] * u**3 + 0.3 * rng.normal() * np.sin(2 * np.pi * w * u + rng.uniform(0, 2 * np.pi))
        v = v - v[0]
        fun[k] = ELEMENT_SCALE[k] * v / max(np.abs(v).max(), 1e-12) * abs(rng.normal(1.0, 0.3))
    for k in A_ELEMENTS:
        th = np.deg2rad(st["a_deg"] - st["a_deg"][0])
        v = sum(rng.normal() / h * np.cos(h * th) + rng.normal() / h * np.sin(h * th) for h in (1, 2, 3))
        v = v - v[0]
        fun[k] = ELEMENT_SCALE[k] * v / max(np.abs(v).max(), 1e-12) * abs(rng.normal(1.0, 0.3))
    const = {k: ELEMENT_SCALE[k] * rng.uniform(-1.0, 1.0) for k in CONSTANT_ELEMENTS}
    return ChainElementSet(machine, st, fun, const, machine.name, machine.sha256)


def volume_grid(machine: MachineTool, n=(21, 13, 37)) -> np.ndarray:
    """A dense axis grid over the strokes (A over one turn), shape (nx·nz·na, 3)."""
    g = [np.linspace(*machine.strokes[k], m) for k, m in zip(("x_mm", "z_mm", "a_deg"), n)]
    return np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, 3)


def random_axes(machine: MachineTool, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points uniform over the strokes, shape (n, 3)."""
    lo, hi = machine.stroke_lo, machine.stroke_hi
    return lo + (hi - lo) * rng.random((n, 3))


@dataclass
class TruthGrinder:
    """A simulated machine: true elements plus named undeclared effects.

    ``effects`` maps effect name -> parameter dict (defaults: EFFECT_DEFAULTS).
    """

    machine: MachineTool
    elements: ChainElementSet
    effects: dict = field(default_factory=dict)
    seed: int | None = None

    def __post_init__(self):
        self.effects = {k: {**EFFECT_DEFAULTS[k], **(v or {})} for k, v in simulator_effects(self.effects).items()}

    def element_values(self, axes, temp_c=None, dir_x=None, dir_z=None, dir_a=None) -> np.ndarray:
        """True element values including the effects, shape (n, 23)."""
        axes = np.asarray(axes, dtype=float)
        v = self.elements.values(axes)
        m = self.machine
        x_rel = axes[:, 0] - m.strokes["x_mm"][0]
        z_rel = axes[:, 1] - m.strokes["z_mm"][0]
        for name, p in self.effects.items():
            if name == "thermal":
                if temp_c is None:
                    raise ValueError("effect 'thermal' needs temp_c")
                v[:, IDX["dx_x"]] += p["k_um_per_mm_c"] * (np.asarray(temp_c) - REF_TEMP_C) * x_rel
            elif name == "reversal":
                if dir_z is None:
                    raise ValueError("effect 'reversal' needs the approach direction dir_z")
                v[:, IDX["dz_z"]] += 0.5 * p["backlash_um"] * np.asarray(dir_z, dtype=float)
            elif name == "pitch":
                v[:, IDX["dx_x"]] += p["amplitude_um"] * np.sin(2 * np.pi * axes[:, 0] / p["period_mm"] + p["phase_rad"])
            elif name == "worm":
                v[:, IDX["ex_a"]] += p["amplitude_urad"] * np.sin(p["teeth"] * np.deg2rad(axes[:, 2]) + p["phase_rad"])
            elif name == "interaction":
                dx = m.strokes["x_mm"][1] - m.strokes["x_mm"][0]
                dz = m.strokes["z_mm"][1] - m.strokes["z_mm"][0]
                v[:, IDX["dx_x"]] += p["corner_um"] * x_rel * z_rel / (dx * dz)
            elif name in OUT_OF_CATALOGUE:
                dx = m.strokes["x_mm"][1] - m.strokes["x_mm"][0]
                dz = m.strokes["z_mm"][1] - m.strokes["z_mm"][0]
                if name == "bump":
                    w = p["width_frac"]
                    g = np.exp(-0.5 * ((x_rel / dx - p["x_frac"]) / w) ** 2 - 0.5 * ((z_rel / dz - p["z_frac"]) / w) ** 2)
                    v[:, IDX["dy_x"]] += p["amplitude_um"] * g
                elif name == "a_tilt":
                    v[:, IDX["ey_a"]] += p["k_urad"] * x_rel / dx
                elif name == "squareness":
                    v[:, IDX["s_xz"]] += p["k_urad"] * np.sin(np.pi * x_rel / dx)
                elif name == "squareness_xz":
                    v[:, IDX["s_xz"]] += p["k_urad"] * np.sin(np.pi * x_rel / dx) * np.sin(np.pi * z_rel / dz)
                elif name == "a_lobe_x":
                    u = (x_rel / dx - p["x_frac"]) / p["width_frac"]
                    v[:, IDX["dy_a"]] += (p["amplitude_um"] * u * np.exp(0.5 - 0.5 * u * u)
                                          * np.cos(2.0 * np.deg2rad(axes[:, 2]) + p["phase_rad"]))
                elif name == "xz_saddle":
                    u = (x_rel / dx - p["x_frac"]) / p["width_frac"]
                    w = (z_rel / dz - p["z_frac"]) / p["width_frac"]
                    v[:, IDX["dy_z"]] += (p["amplitude_um"] * u * np.exp(0.5 - 0.5 * u * u)
                                          * (1.0 - w * w) * np.exp(-0.5 * w * w))
                else:  # pragma: no cover - a truth-only kind registered without its drawing here
                    raise ValueError(f"the simulator cannot draw the truth-only effect {name!r}")
            else:  # pragma: no cover - a registered simulator kind without its drawing here
                raise ValueError(f"the simulator cannot draw the effect {name!r}")
        return v

    def spatial_error(self, axes, **conditions) -> np.ndarray:
        """True spatial error (μm) at ``axes`` shape (n, 3) under ``conditions``
        (``temp_c``, ``dir_x``, ``dir_z``, ``dir_a`` arrays as needed by the effects)."""
        axes = np.asarray(axes, dtype=float)
        return spatial_error(self.machine, axes, self.element_values(axes, **conditions))

    def tool_point(self, axes, **conditions) -> np.ndarray:
        """Where the tool really lands in the WCS (mm) when commanded to ``axes``, shape (n, 3)."""
        return forward(self.machine, axes) + 1e-3 * self.spatial_error(axes, **conditions)

    def default_conditions(self, n: int) -> dict:
        """Conditions for evaluating paths: reference temperature, positive approach."""
        return {"temp_c": np.full(n, REF_TEMP_C), "dir_x": np.ones(n), "dir_z": np.ones(n), "dir_a": np.ones(n)}

    def check_measurements(self, n: int = 400, noise_um: float = 1.0, seed: int = 0, dt_s: float = 15.0,
                           noise_seed=None) -> dict:
        """Simulated check measurements in the docs/reference/file-formats.md schema: a dict of columns, each shape (n,).
        ``noise_seed``: None (default) draws the measurement noise from the same stream as the layout
        (points, temperatures, directions), after it; a seed draws only the noise from a stream of its own,
        the layout unchanged (a redraw of the instrument's noise on the same machine and program)."""
        rng = np.random.default_rng(seed)
        axes = random_axes(self.machine, n, rng)
        t = np.arange(n) * dt_s
        temp = REF_TEMP_C + 4.0 * (1.0 - np.exp(-t / 2400.0)) + rng.normal(0, 0.02, n)
        dirs = rng.choice([-1, 1], size=(n, 3))
        cond = {"temp_c": temp, "dir_x": dirs[:, 0], "dir_z": dirs[:, 1], "dir_a": dirs[:, 2]}
        r_noise = rng if noise_seed is None else np.random.default_rng(noise_seed)
        e = self.spatial_error(axes, **cond) + r_noise.normal(0.0, noise_um, (n, 3))
        return {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": axes[:, 2],
                "dx_um": e[:, 0], "dy_um": e[:, 1], "dz_um": e[:, 2],
                "time_s": t, "temp_c": temp, "dir_x": dirs[:, 0], "dir_z": dirs[:, 1], "dir_a": dirs[:, 2],
                "seq": np.arange(n)}


def random_truth(machine: MachineTool, seed: int, effects=(), n_stations: int = 21) -> TruthGrinder:
    """A seeded truth grinder whose max spatial error (23 elements, norm over the volume)
    lies in [165, 215] μm; ``effects`` are names or a name -> parameters mapping."""
    rng = np.random.default_rng(seed)
    el = random_elements(machine, rng, n_stations)
    grid = volume_grid(machine)
    e = spatial_error(machine, grid, el.values(grid))
    target = rng.uniform(*TARGET_MAX_RANGE_UM)
    el = el.scaled(target / np.linalg.norm(e, axis=1).max())
    eff = effects if isinstance(effects, dict) else {k: {} for k in effects}
    return TruthGrinder(machine, el, dict(eff), seed)
