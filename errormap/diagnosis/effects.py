"""The library of candidate effects: small parametric terms with a physical meaning.

A term acts on one error element ``e`` or on one WCS component (``dx``/``dy``/``dz``):
``Δerror(q, c) = J_e(q) · g(θ; q, c)`` (n, 3) μm, ``J_e`` the element's column of
:func:`errormap.chain_kernel.error_jacobian` (the unit vector for a WCS component), ``g`` linear in θ but for
the period of ``periodic`` (a periodogram; an integer order for ``harmonic``); sinusoids fitted as
``s·sin + c·cos``, reported as amplitude and phase. The kinds, formulas and parameters are the diagnosed
entries of :data:`errormap.effect_kinds.EFFECT_KINDS`; ``pos`` is the axis position, ``lo`` the lower
stroke, Δ the stroke length. The loop that fits them: ``docs/explanation/closed-loop.md``."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..effect_kinds import diagnosed_kind
from ..elements import IDX, element_unit
from ..chain_kernel import error_jacobian

WCS_ELEMENTS = ("dx", "dy", "dz")
AXIS_COL = {"x": 0, "z": 1, "a": 2}
STROKE_KEY = {"x": "x_mm", "z": "z_mm", "a": "a_deg"}
SECONDS_PER_HOUR = 3600.0


def unit_of(element: str) -> str:
    return "um" if element in WCS_ELEMENTS else element_unit(element)


def needs(kind: str, axis: str) -> tuple[str, ...]:
    """Condition columns a term of ``kind`` on ``axis`` needs."""
    return diagnosed_kind(kind).needs_on(axis)


@dataclass(frozen=True)
class Candidate:
    """One (kind, axis, element) of the library."""

    kind: str
    axis: str
    element: str

    def __post_init__(self):
        diagnosed_kind(self.kind)  # an unknown kind is an error here, never a default further on

    @property
    def n_linear(self) -> int:
        return diagnosed_kind(self.kind).n_linear

    @property
    def label(self) -> str:
        return f"{self.kind}({self.axis}) on {self.element}"


@dataclass
class Context:
    """Inputs of the terms at n points: axes (n, 3), conditions {name: (n,)}, the Jacobian
    (n, 3, 23) and the references (strokes, ``ref_temp_c``, ``ref_time_s``)."""

    axes: np.ndarray
    conditions: dict
    jac: np.ndarray
    ref: dict

    @classmethod
    def build(cls, machine, axes, conditions, ref) -> "Context":
        axes = np.asarray(axes, dtype=float)
        return cls(axes, {k: np.asarray(v, dtype=float) for k, v in (conditions or {}).items()},
                   error_jacobian(machine, axes), ref)

    def column(self, element: str) -> np.ndarray:
        """J_e, shape (n, 3)."""
        if element in WCS_ELEMENTS:
            out = np.zeros((self.axes.shape[0], 3))
            out[:, WCS_ELEMENTS.index(element)] = 1.0
            return out
        return self.jac[:, :, IDX[element]]

    def cond(self, name: str) -> np.ndarray:
        if name not in self.conditions:
            raise ValueError(f"this effect needs the condition {name!r}; got only {sorted(self.conditions)}")
        return self.conditions[name]

    def position(self, axis: str) -> np.ndarray:
        """Axis position relative to the lower stroke (mm), or A in rad."""
        if axis == "a":
            return np.deg2rad(self.axes[:, 2])
        return self.axes[:, AXIS_COL[axis]] - self.ref["strokes"][STROKE_KEY[axis]][0]


def basis(cand: Candidate, ctx: Context, period_mm: float | None = None, order: int | None = None) -> np.ndarray:
    """g's basis functions at the context's points, shape (n, n_linear)."""
    k, ax = cand.kind, cand.axis
    if k == "thermal":
        b = (ctx.cond("temp_c") - ctx.ref["ref_temp_c"]) * ctx.position(ax)
    elif k == "drift":
        b = (ctx.cond("time_s") - ctx.ref["ref_time_s"]) / SECONDS_PER_HOUR * ctx.position(ax)
    elif k == "reversal":
        b = 0.5 * ctx.cond(f"dir_{ax}")
    elif k == "interaction":
        (xl, xh), (zl, zh) = ctx.ref["strokes"]["x_mm"], ctx.ref["strokes"]["z_mm"]
        b = ctx.position("x") * ctx.position("z") / ((xh - xl) * (zh - zl))
    elif k == "periodic":
        w = 2 * np.pi / period_mm * (ctx.axes[:, AXIS_COL[ax]])
        return np.stack([np.sin(w), np.cos(w)], axis=1)
    elif k == "harmonic":
        w = order * ctx.position("a")
        return np.stack([np.sin(w), np.cos(w)], axis=1)
    else:  # pragma: no cover
        raise ValueError(f"unknown kind {k!r}")
    return b[:, None]


@dataclass
class EffectTerm:
    """A fitted term: candidate, linear coefficients ``coef`` (n_linear,), nonlinear
    ``period_mm``/``order``, the references, and the covariance ``cov`` of
    ``[coef..., period_mm]`` (period only for ``periodic``)."""

    cand: Candidate
    coef: np.ndarray
    ref: dict
    period_mm: float | None = None
    order: int | None = None
    cov: np.ndarray | None = None
    stats: dict = field(default_factory=dict)

    kind = property(lambda self: self.cand.kind)
    axis = property(lambda self: self.cand.axis)
    element = property(lambda self: self.cand.element)

    @property
    def needs(self) -> tuple[str, ...]:
        return needs(self.cand.kind, self.cand.axis)

    def value(self, ctx: Context) -> np.ndarray:
        """g at the points, shape (n,), μm or μrad (the element's unit)."""
        return basis(self.cand, ctx, self.period_mm, self.order) @ self.coef

    def contribution(self, ctx: Context) -> np.ndarray:
        """The term's spatial error, shape (n, 3) μm."""
        return ctx.column(self.cand.element) * self.value(ctx)[:, None]

    def parameters(self) -> dict:
        """Named parameters ``{name: {"value", "se", "unit"}}`` (se None when not available)."""
        u = unit_of(self.cand.element)
        cov = self.cov if self.cov is not None else np.full((len(self.coef) + 1,) * 2, np.nan)
        se = np.sqrt(np.abs(np.diag(cov)))
        k = self.cand.kind
        spec = diagnosed_kind(k)
        if not spec.nonlinear:
            n, unit = (t.format(u=u) for t in spec.parameters[0])
            return {n: {"value": float(self.coef[0]), "se": float(se[0]), "unit": unit}}
        s, c = self.coef
        amp = float(np.hypot(s, c))
        # A·sin(w + φ) = A cosφ sin w + A sinφ cos w  ->  s = A cosφ, c = A sinφ
        phase = float(np.arctan2(c, s))
        g = np.array([[s / amp, c / amp], [-c / amp**2, s / amp**2]]) if amp > 0 else np.zeros((2, 2))
        cv = g @ cov[:2, :2] @ g.T
        out = {f"amplitude_{u}": {"value": amp, "se": float(np.sqrt(abs(cv[0, 0]))), "unit": u},
               "phase_rad": {"value": phase, "se": float(np.sqrt(abs(cv[1, 1]))), "unit": "rad"}}
        if k == "periodic":
            out["period_mm"] = {"value": float(self.period_mm), "se": float(se[2]) if len(se) > 2 else None, "unit": "mm"}
        else:
            out["order"] = {"value": int(self.order), "se": None, "unit": "per revolution"}
        return out

    def to_dict(self) -> dict:
        return {"kind": self.kind, "axis": self.axis, "element": self.element,
                "parameters": self.parameters(), "coefficients": [float(v) for v in self.coef],
                "period_mm": self.period_mm, "order": self.order, "needs": list(self.needs),
                "reference": {"ref_temp_c": self.ref["ref_temp_c"], "ref_time_s": self.ref["ref_time_s"]}}

