"""The one table of effect kinds: what the simulator can draw, the diagnosis can fit, the report can draw and
the export can write.

An effect is a small physical term the error elements do not carry (thermal growth, backlash, a ball-screw
pitch error, …); its canonical name is the diagnosis's, the simulator's (``pitch``, ``worm``) an alias. Each
entry gives ``acts_on`` (``"linear"``, ``"rotary"``, ``"any"``, ``"pair"``), ``parameters`` (with units,
``{u}``: μm or μrad), ``needs`` (condition columns, ``{axis}`` the axis word), ``simulator``
(``None``: not drawn), ``diagnosed``, ``truth_only`` and ``export`` (``None``: no
controller table carries it). An unknown name is a ``ValueError`` naming the known ones."""
from __future__ import annotations

from dataclasses import dataclass

@dataclass(frozen=True)
class EffectKind:
    """One effect kind (module doc); names of fields as there."""

    name: str
    aliases: tuple
    acts_on: str
    formula: str
    parameters: tuple
    """``((name template, unit template), ...)``; ``{u}``: the element's unit."""
    needs: tuple = ()
    """Condition columns; ``{axis}`` is the axis word (``dir_{axis}`` → ``dir_z``)."""
    simulator: str | None = None
    diagnosed: bool = True
    truth_only: bool = False
    nonlinear: str | None = None
    """The parameter searched outside the linear fit (``period_mm`` by a periodogram, ``order``)."""
    export: str | None = None

    @property
    def n_linear(self) -> int:
        """Linear coefficients of the fitted term (a sinusoid: sin and cos)."""
        return 2 if self.nonlinear else 1

    def needs_on(self, axis: str) -> tuple:
        """The condition columns a term of this kind on ``axis`` needs."""
        return tuple(n.format(axis=axis) for n in self.needs)

    def axes(self, linear=(), rotary=()) -> tuple:
        """The axis words it may act on for a machine whose linear and rotary axis words are
        given (``("x", "z")``, ``("a",)``): pairs as ``"x*z"``."""
        linear, rotary = tuple(linear), tuple(rotary)
        if self.acts_on == "linear":
            return linear
        if self.acts_on == "rotary":
            return rotary
        if self.acts_on == "any":
            return linear + rotary
        return tuple(f"{p}*{q}" for i, p in enumerate(linear) for q in linear[i + 1:])


# The order is the diagnosis's preference between kinds that explain a residual equally well
# (the candidates of errormap/diagnosis/chain_effects.py are searched in this order): do not reorder.
EFFECT_KINDS = (
    EffectKind("thermal", (), "linear", "k·(temp_c − ref_temp_c)·(pos − lo)",
               (("k_{u}_per_mm_c", "{u}/(mm·°C)"),), needs=("temp_c",),
               simulator="thermal"),
    EffectKind("drift", (), "linear", "k·(time_s − ref_time_s)/3600·(pos − lo)",
               (("k_{u}_per_mm_h", "{u}/(mm·h)"),), needs=("time_s",)),
    EffectKind("reversal", ("backlash",), "any", "b/2·dir",
               (("backlash_{u}", "{u}"),), needs=("dir_{axis}",),
               simulator="reversal", export="linuxcnc-backlash"),
    EffectKind("periodic", ("pitch",), "linear", "A·sin(2π·pos/P + φ)",
               (("amplitude_{u}", "{u}"), ("phase_rad", "rad"), ("period_mm", "mm")),
               simulator="pitch", nonlinear="period_mm"),
    EffectKind("harmonic", ("worm",), "rotary", "A·sin(N·a + φ)",
               (("amplitude_{u}", "{u}"), ("phase_rad", "rad"), ("order", "per revolution")),
               simulator="worm", nonlinear="order"),
    EffectKind("interaction", (), "pair", "k·(p − p_lo)(q − q_lo)/(Δp·Δq)",
               (("corner_{u}", "{u}"),), simulator="interaction"),
    EffectKind("bump", (), "pair", "A·exp(−½((p−pc)/wp)² − ½((q−qc)/wq)²)",
               (("amplitude_um", "um"), ("x_frac", "1"), ("z_frac", "1"), ("width_frac", "1")),
               simulator="bump", diagnosed=False, truth_only=True),
    EffectKind("a_tilt", (), "pair", "k·(p − p_lo)/Δp on a rotary axis' tilt",
               (("k_urad", "urad"),), simulator="a_tilt",
               diagnosed=False, truth_only=True),
    EffectKind("squareness", (), "pair", "k·sin(π·(p − p_lo)/Δp) on a squareness",
               (("k_urad", "urad"),), simulator="squareness",
               diagnosed=False, truth_only=True),
    EffectKind("squareness_xz", (), "pair", "k·sin(π·(p − p_lo)/Δp)·sin(π·(q − q_lo)/Δq) on a squareness",
               (("k_urad", "urad"),), simulator="squareness_xz",
               diagnosed=False, truth_only=True),
    EffectKind("a_lobe_x", (), "pair", "A·u·exp(½ − ½u²)·cos(2a + φ), u = ((p − p_lo)/Δp − pc)/w, on a rotary "
               "axis' radial motion",
               (("amplitude_um", "um"), ("x_frac", "1"), ("width_frac", "1"), ("phase_rad", "rad")),
               simulator="a_lobe_x", diagnosed=False, truth_only=True),
    EffectKind("xz_saddle", (), "pair", "A·u·exp(½ − ½u²)·(1 − v²)·exp(−½v²), u = ((p − p_lo)/Δp − pc)/w, "
               "v = ((q − q_lo)/Δq − qc)/w, on the second axis' straightness",
               (("amplitude_um", "um"), ("x_frac", "1"), ("z_frac", "1"), ("width_frac", "1")),
               simulator="xz_saddle", diagnosed=False, truth_only=True),
)

_BY_ALIAS = {a: k for k in EFFECT_KINDS for a in (k.name, *k.aliases)}

DIAGNOSED_KINDS = tuple(k.name for k in EFFECT_KINDS if k.diagnosed)
"""The kinds the diagnosis library fits, in its order of preference."""
TRUTH_ONLY = tuple(k.simulator for k in EFFECT_KINDS if k.truth_only)
"""Simulator effects no kind of the diagnosis represents."""


def effect_kind(name) -> EffectKind:
    """The kind ``name`` (canonical or an alias); ``ValueError`` naming the known ones otherwise."""
    kind = _BY_ALIAS.get(name) if isinstance(name, str) else None
    if kind is None:
        known = ", ".join(f"{k.name}" + (f" ({'/'.join(k.aliases)})" if k.aliases else "") for k in EFFECT_KINDS)
        raise ValueError(f"unknown effect kind {name!r}; expected one of {known}")
    return kind


def diagnosed_kind(name) -> EffectKind:
    """The kind named ``name`` (its canonical name: the diagnosis's vocabulary) if the diagnosis
    fits it; ``ValueError`` naming the diagnosed kinds otherwise (an unknown name, a simulator
    alias such as ``pitch``, or a truth-only kind the diagnosis cannot represent)."""
    kind = _BY_ALIAS.get(name) if isinstance(name, str) else None
    if kind is not None and kind.diagnosed and kind.name == name:
        return kind
    if kind is None:
        why = f"unknown effect kind {name!r}"
    elif kind.name != name:
        why = f"effect kind {name!r} is the simulator's name; the diagnosis calls it {kind.name!r}"
    else:
        why = f"effect kind {name!r} is simulated only (no diagnosis kind represents it)"
    raise ValueError(f"{why}; expected one of {list(DIAGNOSED_KINDS)}")
