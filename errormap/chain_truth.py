"""Seeded truth machines for ANY machine-tool chain file (:class:`errormap.machine_tool.MachineTool`).

Two families (default, independent) over the machine's element slots:

* **component errors** (functions of their own axis, zero at the axis' first station — the
  gauge of :class:`errormap.chain_elements.ChainElementSet`): default family — a cubic plus one
  long-wave sinusoid on a linear axis or a rotary axis short of a full turn, harmonics 1–3 on
  a full-turn rotary axis (periodic, closed at 360°), on 21 stations; independent family —
  2–5 Gaussian bumps plus Chebyshev T1…T4 (harmonics 1…6 with amplitudes ∝ h^-1.5 on a full
  turn), stored on 81 stations, so between the identification's stations the truth is no
  21-knot spline;
* **constants** (location errors of rotary axes, squareness): uniform in ±scale (default) or
  ±(0.3…1)·scale (independent);
* **magnitudes**: each slot's 1-σ scale by its kind (:data:`SCALE`, the grinder's band:
  positioning 15 μm, straightness 8 μm, angular 20–25 μrad on linear axes; 4–5 μm and
  20–60 μrad on rotary axes; location 60 μm / 150 μrad; squareness 80 μrad) — the
  independent family draws each log-uniformly from :data:`SCALE_RANGE`; then the whole set
  is scaled so the maximum spatial error over the volume is drawn in [165, 215] μm (default)
  or [120, 260] μm (independent), over :func:`volume_grid`.

How a family draws (the seed's streams, the draw order, per-slot scales) is its :class:`Recipe`; a machine
file's ``[truth]`` table overrides it per family and sets the grid (``docs/how-to/machine-file.md``; the
built-in grinder's keeps its seeded truths as they always were). Spatial errors are the compiled kernel's
(:func:`errormap.chain_kernel.spatial_error`).

Effects (canonical kind names of the project's effect table; ``KIND:AXES``, e.g.
``periodic:X``, ``harmonic:C``, ``interaction:X*Z``; the older simulator names ``pitch``
and ``worm`` are aliases; without axes: periodic and thermal on the first
linear axis, reversal on the last linear axis, harmonic on the first rotary axis, interaction
between the first and last linear axes):

==============  ======================================================  ===========================
kind            adds (to an element, so it goes through the chain)        default (independent: drawn)
==============  ======================================================  ===========================
thermal         linear axis W: ``d{along}_w += k·(temp_c − 20)·(w − lo)``  k = 0.0115 μm/(mm·°C)
                                                                          (0.008–0.014)
reversal        any axis W: ``d{along}_w`` (linear) or ``e{along}_w``      b = 8 μm / 8 μrad (5–10)
                (rotary) ``+= b/2·dir_w``
periodic        linear axis W: ``d{along}_w += A·sin(2π·w/P + φ)``          A = 4 μm, P = 10 mm
                                                                          (2.5–5 μm, 6–14 mm)
harmonic        rotary axis W: ``e{along}_w += A·sin(N·w + φ)``             A = 100 μrad, N = 40
                                                                          (60–140 μrad, 30–50)
interaction     linear axes V*W: ``d{along}_v += k·(v−lo)(w−lo)/(Δv·Δw)``   k = 6 μm (±4–9 μm)
==============  ======================================================  ===========================

Out-of-catalogue (truth-only) kinds, the grinder's forms on any pair of linear axes ``V*W``, ``third`` the
direction neither moves along (the grinder's ``bump`` and ``xz_saddle`` are ``bump:X*Z``, ``xz_saddle:X*Z``
on its chain, the same element values); ``u``, ``v`` the positions as fractions of the strokes:

==============  ======================================================  ===========================
bump            ``d{third}_v += A·exp(−½((u−p)/w)² − ½((v'−q)/w)²)``        A = 8 μm, p = 0.6, q = 0.4,
                (``u`` along V, ``v'`` along W)                            w = 0.18
xz_saddle       ``d{third}_w += A·s·exp(½−½s²)·(1−t²)·exp(−½t²)``,         A = 8 μm, p = q = 0.5,
                ``s = (u−p)/w`` along V, ``t = (v'−q)/w`` along W          w = 0.15
squareness      the V–W squareness ``s_vw += k·sin(π·u)``                    k = 100 μrad
squareness_xz   ``s_vw += k·sin(π·u)·sin(π·v')``                            k = 100 μrad
a_tilt          rotary W, linear V (``a_tilt:W*V``): ``e{c}_w += k·u``,      k = 120 μrad
                ``c`` the first direction across W, ``u`` along V
a_lobe_x        ``d{c}_w += A·s·exp(½−½s²)·cos(2w + φ)``, ``s = (u−p)/w``    A = 6 μm, p = 0.5,
                                                                          w = 0.15, φ = 0.4
==============  ======================================================  ===========================

Check measurements: columns ``<axis columns>, dx_um, dy_um, dz_um, time_s, temp_c, dir_<w>…,
seq`` (``docs/reference/file-formats.md``); uniform random points (default) or a scrambled Sobol layout
(independent) over the strokes, the warm-up of the grinder's families, a random approach
direction per axis, isotropic Gaussian noise. Randomness from the seed only
(:func:`errormap.seeds.spawn_rngs`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.polynomial import chebyshev
from scipy.stats import qmc

from .effect_kinds import EFFECT_KINDS as _REGISTRY
from .effect_kinds import TRUTH_ONLY as CHAIN_TRUTH_ONLY
from .effect_kinds import effect_kind
from .machine_checks import MachineFileError, check_known_keys, short_repr
from .machine_tool import COMPONENTS, MachineTool
from .chain_elements import ChainElementSet
from .chain_kernel import forward
from .chain_kernel import spatial_error as kernel_spatial_error
from .seeds import spawn_rngs

FAMILIES = ("default", "independent")
REF_TEMP_C = 20.0
DEFAULT_STATIONS = 21
TRUTH_STATIONS = 81
"""Stations the independent truth is stored on (a spline through 81 points, not 21)."""
TARGET_MAX_RANGE_UM = {"default": (165.0, 215.0), "independent": (120.0, 260.0)}
"""Maximum spatial error over the volume (μm), drawn per seed: the grinder families' bands."""
GRID_POINTS = 20_000
"""About this many points in the volume grid the maximum error is taken over (per-axis count
``round(GRID_POINTS ** (1/k))``, at least 5)."""

# 1-σ scale (μm or μrad) of a slot by (axis kind, component) or slot kind: the grinder's band
SCALE = {("linear", "d_along"): 15.0, ("linear", "d_across"): 8.0, ("linear", "e"): 22.0,
         ("rotary", "d"): 4.5, ("rotary", "e_along"): 60.0, ("rotary", "e_across"): 20.0,
         "location_d": 60.0, "location_e": 150.0, "squareness": 80.0}
SCALE_RANGE = {("linear", "d_along"): (3.0, 25.0), ("linear", "d_across"): (2.0, 15.0), ("linear", "e"): (5.0, 40.0),
               ("rotary", "d"): (1.0, 10.0), ("rotary", "e_along"): (10.0, 80.0), ("rotary", "e_across"): (5.0, 40.0),
               "location_d": (10.0, 100.0), "location_e": (20.0, 200.0), "squareness": (10.0, 120.0)}

@dataclass(frozen=True)
class Recipe:
    """How a family draws a truth (module doc); a machine file's ``[truth.FAMILY]`` overrides its fields.
    ``entropy``: ints after the seed (``SeedSequence([seed, *entropy])``); ``one_stream``: every draw of the
    truth and of its checks from one generator (else three children: elements, scale, effects / points,
    environment, noise); ``order``: per slot ``"scale-profile"`` or ``"profile-scale"``, or
    ``"scales-first"`` (every slot's scale, then the profiles and constants); ``scale``: per-slot 1-σ
    (default) or ``[lo, hi]`` (independent) overriding :data:`SCALE` / :data:`SCALE_RANGE`;
    ``draw_truth_only``: the independent family's drawn parameters apply to the truth-only kinds too."""

    entropy: tuple
    one_stream: bool = False
    order: str = "scale-profile"
    scale: dict = field(default_factory=dict)
    draw_truth_only: bool = False


RECIPES = {"default": Recipe((0x3A7, 0)), "independent": Recipe((0x3A7, 1))}
ORDERS = ("scale-profile", "profile-scale", "scales-first")


def _truth_table(machine) -> dict:
    """The machine file's ``[truth]`` table, its keys and ``grid`` checked."""
    t = getattr(machine, "truth", None) or {}
    check_known_keys(t, ("grid",) + FAMILIES, "truth", machine.path)
    g = t.get("grid")
    if g is not None and (not isinstance(g, list) or len(g) != len(machine.axes)
                          or not all(isinstance(c, int) and c >= 2 for c in g)):
        raise MachineFileError(f"{machine.path}: key 'truth.grid': expected {len(machine.axes)} point counts "
                               f"(integers >= 2, one per axis in {[a.word for a in machine.axes]}), "
                               f"got {short_repr(g)}")
    return t


def recipe(machine: MachineTool, family: str) -> Recipe:
    """The family's :class:`Recipe` on ``machine`` (its file's ``[truth.FAMILY]`` over :data:`RECIPES`);
    ``MachineFileError`` naming the key for a malformed one."""
    if family not in FAMILIES:
        raise ValueError(f"Expected family in {FAMILIES}, got {family!r}")
    t = _truth_table(machine).get(family, {})
    where = f"{machine.path}: key 'truth.{family}"
    check_known_keys(t, ("entropy", "one_stream", "order", "scale", "draw_truth_only"), f"truth.{family}",
                     machine.path)
    if t.get("order", ORDERS[0]) not in ORDERS:
        raise MachineFileError(f"{where}.order': expected one of {ORDERS}, got {short_repr(t['order'])}")
    bad = sorted(set(t.get("scale", {})) - set(machine.slot_names))
    if bad:
        raise MachineFileError(f"{where}.scale.{bad[0]}': not an error slot of the machine")
    entropy = tuple(t.get("entropy", RECIPES[family].entropy))
    return Recipe(**{**RECIPES[family].__dict__, **t, "entropy": entropy})


def truth_rngs(seed, rec: Recipe, n: int = 3) -> list:
    """``n`` generators of ``seed`` (an int or a SeedSequence) under ``rec`` (one shared, or ``n``
    children)."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence([seed, *rec.entropy])
    return [np.random.default_rng(ss)] * n if rec.one_stream else spawn_rngs(ss, n)


CHAIN_SIMULATED = ("thermal", "reversal", "periodic", "harmonic", "interaction")
"""The registry's kinds this simulator draws on a chain (:meth:`ChainTruth.element_values` dispatches on
them; ``tests/test_chain_model.py`` checks the table against the registry)."""
EFFECT_KINDS = tuple(k.name for k in _REGISTRY if k.name in CHAIN_SIMULATED)
"""Canonical names (the registry's, :mod:`errormap.effect_kinds`), in the registry's order."""
EFFECT_ALIASES = {a: k.name for k in _REGISTRY if k.name in EFFECT_KINDS for a in k.aliases}
"""The registry's aliases of those kinds (``pitch`` → ``periodic``, ``worm`` → ``harmonic``,
``backlash`` → ``reversal``)."""
SIMULATED_KINDS = EFFECT_KINDS + CHAIN_TRUTH_ONLY
"""Every kind ``simulate --effect`` takes on a chain: :data:`EFFECT_KINDS` and the registry's truth-only kinds
(``CHAIN_TRUTH_ONLY``, :data:`errormap.effect_kinds.TRUTH_ONLY`: no diagnosis kind represents them, so a chain
model's terms never have them)."""
EFFECT_DEFAULTS = {
    "bump": {"amplitude_um": 8.0, "p_frac": 0.6, "q_frac": 0.4, "width_frac": 0.18},
    "xz_saddle": {"amplitude_um": 8.0, "p_frac": 0.5, "q_frac": 0.5, "width_frac": 0.15},
    "squareness": {"k_urad": 100.0},
    "squareness_xz": {"k_urad": 100.0},
    "thermal": {"k_um_per_mm_c": 0.0115},
    "reversal": {"backlash_um": 8.0},
    "periodic": {"amplitude_um": 4.0, "period_mm": 10.0, "phase_rad": 0.7},
    "harmonic": {"amplitude_urad": 100.0, "teeth": 40, "phase_rad": 1.1},
    "interaction": {"corner_um": 6.0},
    "a_tilt": {"k_urad": 120.0},
    "a_lobe_x": {"amplitude_um": 6.0, "p_frac": 0.5, "width_frac": 0.15, "phase_rad": 0.4},
}
ROTARY_BY_LINEAR = ("a_tilt", "a_lobe_x")
"""Truth-only kinds on a rotary axis W, local in a linear axis V (``KIND:W*V``, module doc)."""


def _scale_key(machine: MachineTool, slot) -> object:
    if slot.kind == "location":
        return "location_d" if slot.unit == "um" else "location_e"
    if slot.kind == "squareness":
        return "squareness"
    ax = next(a for a in machine.axes if a.word == slot.axis)
    comp = slot.name.split("_")[0]
    along = "xyz"[ax.along]
    if ax.kind == "linear":
        return ("linear", "e") if comp[0] == "e" else ("linear", "d_along" if comp[1] == along else "d_across")
    if comp[0] == "d":
        return ("rotary", "d")
    return ("rotary", "e_along" if comp[1] == along else "e_across")


def _default_profile(u, theta, rng):
    """Default family: cubic + one sinusoid on ``u`` in [0, 1], or harmonics 1–3 of ``theta`` (rad, a full
    turn; None otherwise); zero at the first station, unnormalised."""
    if theta is not None:
        v = sum(rng.normal() / h * np.cos(h * theta) + rng.normal() / h * np.sin(h * theta) for h in (1, 2, 3))
    else:
        c = rng.normal(size=3)
        w = rng.uniform(1.0, 2.5)
        v = c[0] * u + c[1] * u**2 + c[2] * u**3 + 0.3 * rng.normal() * np.sin(2 * np.pi * w * u + rng.uniform(0, 2 * np.pi))
    return v - v[0]


def _independent_profile(u, theta, rng):
    """Independent family: bumps + Chebyshev on ``u``, or harmonics 1…6 (amplitudes ∝ h^-1.5) of ``theta``;
    zero at the first station, unnormalised."""
    if theta is not None:
        h = np.arange(1, 7)
        amp = rng.normal(size=6) / h**1.5
        ph = rng.uniform(0, 2 * np.pi, 6)
        v = (amp[None] * np.cos(h[None] * theta[:, None] + ph[None])).sum(axis=1)
    else:
        v = np.zeros_like(u)
        for _ in range(int(rng.integers(2, 6))):
            c, w = rng.uniform(-0.1, 1.1), rng.uniform(0.08, 0.35)
            v += rng.normal() * np.exp(-0.5 * ((u - c) / w) ** 2)
        v += chebyshev.chebval(2 * u - 1, np.r_[0.0, rng.normal(size=4) / np.arange(1, 5) ** 1.2])
    return v - v[0]


def random_chain_elements(machine: MachineTool, rng: np.random.Generator, family: str = "default",
                          n_stations: int | None = None) -> ChainElementSet:
    """Unscaled random elements of ``family`` (module doc; drawn in :func:`recipe`'s order) on ``n_stations``
    per axis."""
    rec = recipe(machine, family)
    n = n_stations or (DEFAULT_STATIONS if family == "default" else TRUTH_STATIONS)
    u = np.linspace(0.0, 1.0, n)
    stations = {a.column: np.linspace(*a.stroke, n) for a in machine.axes if machine.slots_of(a.word)}
    profile = _default_profile if family == "default" else _independent_profile
    fun, const = {}, {}

    def draw_scale(s, multiplier=True):
        key = _scale_key(machine, s)
        if family == "default":
            return rec.scale.get(s.name, SCALE[key]) * (abs(rng.normal(1.0, 0.3)) if multiplier else 1.0)
        return float(np.exp(rng.uniform(*np.log(rec.scale.get(s.name, SCALE_RANGE[key])))))

    first = ({s.name: draw_scale(s, s.is_function) for s in machine.slots} if rec.order == "scales-first"
             else {})
    for s in machine.slots:
        later = rec.order == "profile-scale" and s.is_function
        scale = first[s.name] if first else draw_scale(s, s.is_function and not later)
        if s.is_function:
            ax = next(a for a in machine.axes if a.word == s.axis)
            st = stations[ax.column]
            v = profile(u, np.deg2rad(st - st[0]) if ax.full_turn else None, rng)
            m = max(np.abs(v).max(), 1e-12)
            fun[s.name] = scale * v / m * abs(rng.normal(1.0, 0.3)) if later else scale * (v / m)
            if ax.full_turn:
                fun[s.name][-1] = fun[s.name][0]
        else:
            const[s.name] = scale * (rng.uniform(-1.0, 1.0) if family == "default"
                                     else rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 1.0))
    return ChainElementSet(machine, stations, fun, const, machine.name, machine.sha256)


def volume_grid(machine: MachineTool, n_points=None) -> np.ndarray:
    """A product grid over the strokes, shape (N, k): ``n_points`` a count per axis or about that many points
    in all; by default the machine file's ``truth.grid`` counts, or about :data:`GRID_POINTS` points."""
    k = len(machine.axes)
    m = max(5, int(round((n_points if np.isscalar(n_points) else GRID_POINTS) ** (1.0 / k))))
    counts = ((n_points if n_points is not None and not np.isscalar(n_points) else None)
              or (n_points is None and _truth_table(machine).get("grid")) or [m] * k)
    g = [np.linspace(*a.stroke, c) for a, c in zip(machine.axes, counts)]
    return np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, k)


def random_axes(machine: MachineTool, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points uniform over the strokes, shape (n, k)."""
    return machine.stroke_lo + (machine.stroke_hi - machine.stroke_lo) * rng.random((n, len(machine.axes)))


# -- effects -----------------------------------------------------------------------------------
def parse_effect(machine: MachineTool, text: str) -> tuple[str, tuple]:
    """``"KIND[:AXES]"`` -> ``(kind, axis words)``; an unknown kind or axis is a ValueError naming
    the known ones (module doc for the defaults)."""
    name, _, axes = str(text).partition(":")
    try:
        kind = effect_kind(name.strip()).name          # the registry: canonical name or alias
    except ValueError:
        kind = None
    if kind not in SIMULATED_KINDS:
        what = "unknown effect kind" if kind is None else "effect kind not simulated on a machine-tool chain:"
        raise ValueError(f"{what} {name!r} (known: {', '.join(SIMULATED_KINDS)}; aliases "
                         f"{', '.join(f'{a}={k}' for a, k in EFFECT_ALIASES.items())})")
    lin = [a.word for a in machine.axes if a.kind == "linear"]
    rot = [a.word for a in machine.axes if a.kind == "rotary"]
    words = tuple(w.strip().upper() for w in axes.replace("*", ",").split(",") if w.strip()) if axes else ()
    if not words:
        pair = (lin[0], lin[-1]) if len(lin) >= 2 else ()
        words = {"thermal": lin[:1], "periodic": lin[:1], "reversal": lin[-1:], "harmonic": rot[:1],
                 "interaction": pair, **{k: pair for k in CHAIN_TRUTH_ONLY},
                 **{k: (rot[:1] + lin[:1]) if rot and lin else () for k in ROTARY_BY_LINEAR}}[kind]
        words = tuple(words)
    want = {"thermal": (lin, 1), "periodic": (lin, 1), "reversal": (lin + rot, 1), "harmonic": (rot, 1),
            "interaction": (lin, 2), **{k: (lin, 2) for k in CHAIN_TRUTH_ONLY},
            **{k: (rot + lin, 2) for k in ROTARY_BY_LINEAR}}[kind]
    mixed = kind in ROTARY_BY_LINEAR and (words[:1] != tuple(w for w in words[:1] if w in rot)
                                          or words[1:] != tuple(w for w in words[1:] if w in lin))
    if (len(words) != want[1] or any(w not in want[0] for w in words) or len(set(words)) != len(words)
            or mixed):
        if kind in ROTARY_BY_LINEAR:
            example = f"{kind}:{(rot or ['C'])[0]}*{(lin or ['X'])[0]}"
            raise ValueError(f"effect {text!r}: {kind} acts on a rotary axis of {rot or 'none on this machine'}"
                             f" and a linear axis of {lin} (e.g. {example})")
        raise ValueError(f"effect {text!r}: {kind} acts on {want[1]} {'distinct ' if want[1] > 1 else ''}"
                         f"axis word(s) of {want[0] or 'none on this machine'} (e.g. {kind}:"
                         f"{'*'.join(want[0][:want[1]]) if want[0] else 'W'}), got {list(words) or 'none'}")
    return kind, words


def effect_key(kind: str, words) -> str:
    return f"{kind}:{'*'.join(words)}"


def independent_effect_parameters(rng: np.random.Generator) -> dict:
    """Per-seed parameters of the independent family's effects (module doc)."""
    return {
        "thermal": {"k_um_per_mm_c": rng.uniform(0.008, 0.014)},
        "reversal": {"backlash_um": rng.uniform(5.0, 10.0)},
        "periodic": {"amplitude_um": rng.uniform(2.5, 5.0), "period_mm": rng.uniform(6.0, 14.0),
                     "phase_rad": rng.uniform(0, 2 * np.pi)},
        "harmonic": {"amplitude_urad": rng.uniform(60.0, 140.0), "teeth": int(rng.integers(30, 51)),
                     "phase_rad": rng.uniform(0, 2 * np.pi)},
        "interaction": {"corner_um": rng.uniform(4.0, 9.0) * rng.choice([-1.0, 1.0])},
        # the truth-only kinds after the five (their draws leave those unchanged), used where the recipe says
        "bump": {"amplitude_um": rng.uniform(6.0, 10.0) * rng.choice([-1.0, 1.0]),
                 "p_frac": rng.uniform(0.3, 0.7), "q_frac": rng.uniform(0.3, 0.7),
                 "width_frac": rng.uniform(0.14, 0.22)},
        "a_tilt": {"k_urad": rng.uniform(80.0, 160.0) * rng.choice([-1.0, 1.0])},
        "squareness": {"k_urad": rng.uniform(70.0, 130.0) * rng.choice([-1.0, 1.0])},
        "squareness_xz": {"k_urad": rng.uniform(70.0, 130.0) * rng.choice([-1.0, 1.0])},
        "a_lobe_x": {"amplitude_um": rng.uniform(4.5, 7.5) * rng.choice([-1.0, 1.0]),
                     "p_frac": rng.uniform(0.35, 0.65), "width_frac": rng.uniform(0.12, 0.18),
                     "phase_rad": rng.uniform(0.0, 2 * np.pi)},
        "xz_saddle": {"amplitude_um": rng.uniform(6.0, 10.0) * rng.choice([-1.0, 1.0]),
                      "p_frac": rng.uniform(0.35, 0.65), "q_frac": rng.uniform(0.4, 0.6),
                      "width_frac": rng.uniform(0.12, 0.18)},
    }


@dataclass
class ChainTruth:
    """A simulated machine tool: true elements plus effects ``{"KIND:AXES": parameters}``."""

    machine: MachineTool
    elements: ChainElementSet
    effects: dict = field(default_factory=dict)
    seed: int | None = None
    family: str = "default"

    def __post_init__(self):
        eff = {}
        for key, p in self.effects.items():
            kind, words = parse_effect(self.machine, key)
            eff[effect_key(kind, words)] = {**EFFECT_DEFAULTS[kind], **(p or {})}
        self.effects = eff

    def _ax(self, word):
        j = [a.word for a in self.machine.axes].index(word)
        return j, self.machine.axes[j]

    def parameters(self, name: str) -> dict:
        """The parameters of the one effect of kind ``name`` (canonical or an alias: ``pitch``); KeyError
        if the truth has none or several."""
        kind = effect_kind(name).name
        found = [p for key, p in self.effects.items() if key.split(":")[0] == kind]
        if len(found) != 1:
            raise KeyError(f"{len(found)} effects of kind {kind!r} in this truth (keys {list(self.effects)})")
        return found[0]

    def needs(self) -> set:
        """Condition columns the effects need (``temp_c``, ``dir_z`` ...)."""
        out = set()
        for key in self.effects:
            kind, words = key.split(":")[0], key.split(":")[1].split("*")
            if kind == "thermal":
                out.add("temp_c")
            if kind == "reversal":
                out.add(f"dir_{words[0].lower()}")
        return out

    def element_values(self, axes, **conditions) -> np.ndarray:
        """True element values including the effects, shape (n, P); ``conditions``: ``temp_c``,
        ``dir_<w>`` arrays (n,) as the effects need."""
        axes = np.atleast_2d(np.asarray(axes, dtype=float))
        v = self.elements.values(axes)
        idx = {n: j for j, n in enumerate(self.machine.slot_names)}
        for key, p in self.effects.items():
            kind, words = key.split(":")[0], key.split(":")[1].split("*")
            j, ax = self._ax(words[0])
            pos = axes[:, j]
            rel = pos - ax.stroke[0]
            comp = ("d" if ax.kind == "linear" else "e") + "xyz"[ax.along]
            slot = f"{comp}_{ax.word.lower()}"
            if slot not in idx:
                raise ValueError(f"effect {key}: the machine has no element {slot} to carry it")
            if kind == "thermal":
                if "temp_c" not in conditions:
                    raise ValueError(f"effect {key} needs temp_c")
                v[:, idx[slot]] += p["k_um_per_mm_c"] * (np.asarray(conditions["temp_c"]) - REF_TEMP_C) * rel
            elif kind == "reversal":
                d = f"dir_{ax.word.lower()}"
                if d not in conditions:
                    raise ValueError(f"effect {key} needs the approach direction {d}")
                v[:, idx[slot]] += 0.5 * p["backlash_um"] * np.asarray(conditions[d], dtype=float)
            elif kind == "periodic":
                v[:, idx[slot]] += p["amplitude_um"] * np.sin(2 * np.pi * pos / p["period_mm"] + p["phase_rad"])
            elif kind == "harmonic":
                v[:, idx[slot]] += p["amplitude_urad"] * np.sin(p["teeth"] * np.deg2rad(pos) + p["phase_rad"])
            elif kind == "interaction":
                j2, ax2 = self._ax(words[1])
                span = (ax.stroke[1] - ax.stroke[0]) * (ax2.stroke[1] - ax2.stroke[0])
                v[:, idx[slot]] += p["corner_um"] * rel * (axes[:, j2] - ax2.stroke[0]) / span
            elif kind in ROTARY_BY_LINEAR:
                j2, ax2 = self._ax(words[1])
                name, val = self._rotary_by_linear(kind, p, ax, pos, axes[:, j2] - ax2.stroke[0],
                                                   ax2.stroke[1] - ax2.stroke[0])
                v[:, idx[name]] += val
            elif kind in CHAIN_TRUTH_ONLY:
                j2, ax2 = self._ax(words[1])
                name, val = self._truth_only(kind, p, ax, ax2, rel, axes[:, j2] - ax2.stroke[0])
                if name not in idx:
                    raise ValueError(f"effect {key}: the machine has no element {name} to carry it")
                v[:, idx[name]] += val
            else:  # never a default
                raise ValueError(f"effect {key}: kind {kind!r} is not simulated on a machine-tool chain")
        return v

    @staticmethod
    def _rotary_by_linear(kind, p, ax, pos_deg, rel, span) -> tuple:
        """``(element name, values (n,))`` of ``a_tilt`` / ``a_lobe_x`` on rotary axis ``ax`` at ``pos_deg``,
        the linear axis at ``rel`` of its ``span`` (mm): the tilt or radial motion towards the first direction
        across it."""
        c, w = "xyz"[min({0, 1, 2} - {ax.along})], ax.word.lower()
        if kind == "a_tilt":
            return f"e{c}_{w}", p["k_urad"] * rel / span
        s = (rel / span - p["p_frac"]) / p["width_frac"]
        lobe = np.cos(2.0 * np.deg2rad(pos_deg) + p["phase_rad"])
        return f"d{c}_{w}", p["amplitude_um"] * s * np.exp(0.5 - 0.5 * s * s) * lobe

    @staticmethod
    def _truth_only(kind, p, ax, ax2, rel, rel2) -> tuple:
        """``(element name, values (n,))`` of a truth-only kind on linear axes ``ax``, ``ax2`` at ``rel``,
        ``rel2`` mm from their strokes' starts (module doc)."""
        span, span2 = ax.stroke[1] - ax.stroke[0], ax2.stroke[1] - ax2.stroke[0]
        u, w = rel / span, rel2 / span2
        if kind in ("squareness", "squareness_xz"):
            f = p["k_urad"] * np.sin(np.pi * rel / span)
            f = f * np.sin(np.pi * rel2 / span2) if kind == "squareness_xz" else f
            return f"s_{''.join(sorted((ax.word.lower(), ax2.word.lower())))}", f
        third = {0, 1, 2} - {ax.along, ax2.along}
        if len(third) != 1:
            raise ValueError(f"effect {kind}:{ax.word}*{ax2.word}: the two axes move along the same direction")
        c = "xyz"[third.pop()]
        if kind == "bump":
            g = np.exp(-0.5 * ((u - p["p_frac"]) / p["width_frac"]) ** 2 - 0.5 * ((w - p["q_frac"]) / p["width_frac"]) ** 2)
            return f"d{c}_{ax.word.lower()}", p["amplitude_um"] * g
        s, t = (u - p["p_frac"]) / p["width_frac"], (w - p["q_frac"]) / p["width_frac"]
        return f"d{c}_{ax2.word.lower()}", p["amplitude_um"] * s * np.exp(0.5 - 0.5 * s * s) * (1.0 - t * t) * np.exp(-0.5 * t * t)

    def spatial_error(self, axes, **conditions) -> np.ndarray:
        """True spatial error (μm) of the tool point in the workpiece frame, (n, k) -> (n, 3)."""
        axes = np.atleast_2d(np.asarray(axes, dtype=float))
        return kernel_spatial_error(self.machine, axes, self.element_values(axes, **conditions))

    def tool_point(self, axes, **conditions) -> np.ndarray:
        """Where the tool really lands in the workpiece frame (mm) when commanded to ``axes``,
        (n, k) -> (n, 3)."""
        axes = np.atleast_2d(np.asarray(axes, dtype=float))
        return forward(self.machine, axes) + 1e-3 * self.spatial_error(axes, **conditions)

    def default_conditions(self, n: int) -> dict:
        """Reference temperature, positive approach on every axis."""
        return {"temp_c": np.full(n, REF_TEMP_C), **{f"dir_{a.word.lower()}": np.ones(n) for a in self.machine.axes}}

    def check_measurements(self, n: int = 400, noise_um: float = 1.0, seed=0, dt_s: float = 15.0,
                           noise_seed=None) -> dict:
        """Simulated check measurements (module doc): a dict of columns, each shape (n,). ``noise_seed``: None
        (default) the noise stream of ``seed``; a seed: only the noise redrawn, the layout unchanged."""
        m = self.machine
        k = len(m.axes)
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        r_pts, r_env, r_noise = truth_rngs(ss, recipe(m, self.family))
        if noise_seed is not None:
            r_noise = np.random.default_rng(noise_seed)
        lo, hi = m.stroke_lo, m.stroke_hi
        t = np.arange(n) * dt_s
        if self.family == "independent":
            u = qmc.Sobol(k, scramble=True, seed=r_pts).random_base2(int(np.ceil(np.log2(max(n, 2)))))
            u = u[r_pts.permutation(u.shape[0])[:n]]
            rise, tau = r_env.uniform(3.0, 5.0), r_env.uniform(1500.0, 3500.0)
            temp = (REF_TEMP_C + rise * (1.0 - np.exp(-t / tau))
                    + 0.15 * np.sin(2 * np.pi * t / 5400.0 + r_env.uniform(0, 6.3)) + r_env.normal(0, 0.02, n))
        else:
            u = r_pts.random((n, k))  # as random_axes
            temp = REF_TEMP_C + 4.0 * (1.0 - np.exp(-t / 2400.0)) + r_env.normal(0, 0.02, n)
        axes = lo + (hi - lo) * u
        dirs = r_env.choice([-1, 1], size=(n, k)).astype(float)
        cond = {"temp_c": temp, **{f"dir_{a.word.lower()}": dirs[:, j] for j, a in enumerate(m.axes)}}
        e = self.spatial_error(axes, **cond) + r_noise.normal(0.0, noise_um, (n, 3))
        out = {c: axes[:, j] for j, c in enumerate(m.axis_columns)}
        out.update({"dx_um": e[:, 0], "dy_um": e[:, 1], "dz_um": e[:, 2], "time_s": t})
        out.update(cond)
        out["seq"] = np.arange(n)
        return out


def make_chain_truth(machine: MachineTool, seed: int, effects=(), family: str = "default",
                     n_stations: int | None = None) -> ChainTruth:
    """A seeded truth of ``family`` for ``machine`` (module doc) on ``n_stations`` per axis (None: the
    family's); ``effects``: ``KIND[:AXES]`` strings, or a mapping of them to parameter overrides."""
    rec = recipe(machine, family)
    r_el, r_scale, r_eff = truth_rngs(seed, rec)
    el = random_chain_elements(machine, r_el, family, n_stations)
    grid = volume_grid(machine)
    e = kernel_spatial_error(machine, grid, el.values(grid))
    el = el.scaled(r_scale.uniform(*TARGET_MAX_RANGE_UM[family]) / np.linalg.norm(e, axis=1).max())
    eff = effects if isinstance(effects, dict) else {k: {} for k in effects}
    drawn = independent_effect_parameters(r_eff) if family == "independent" else {}
    params = {}
    for key, over in eff.items():
        kind, words = parse_effect(machine, key)
        use = kind in EFFECT_KINDS or rec.draw_truth_only
        params[effect_key(kind, words)] = {**(drawn.get(kind, {}) if use else {}), **(over or {})}
    return ChainTruth(machine, el, params, seed, family)


__all__ = ["ChainTruth", "make_chain_truth", "random_chain_elements", "volume_grid", "parse_effect", "EFFECT_KINDS",
           "SIMULATED_KINDS", "CHAIN_TRUTH_ONLY",
           "FAMILIES", "COMPONENTS"]
