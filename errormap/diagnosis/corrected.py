"""The corrected model: a base error field plus the selected effect terms."""
from __future__ import annotations

import numpy as np

from ..transforms import check_points
from .effects import Context, EffectTerm


class CorrectedField:
    """``base`` (an :class:`errormap.field.ErrorField`) plus fitted :class:`EffectTerm` s.

    ``predict(axes, **conditions)``: axes (x_mm, z_mm, a_deg) shape (n, 3) -> (n, 3) μm;
    ``conditions`` are arrays shape (n,) named ``temp_c``, ``time_s``, ``dir_x``, ``dir_z``,
    ``dir_a`` as the terms need (:attr:`needs`); a missing one raises ValueError naming it.
    With axis-only terms (periodic, harmonic, interaction) it is a plain error field.
    """

    kind = "corrected"
    capabilities = frozenset()
    """No optional error-field methods (:mod:`errormap.field`)."""

    def __init__(self, machine, base, terms: list[EffectTerm]):
        self.machine = machine
        self.base = base
        self.terms = list(terms)

    @property
    def calibrated_volume(self):
        """The base field's calibrated volume (the terms are fitted inside it)."""
        return self.base.calibrated_volume

    @property
    def needs(self) -> tuple[str, ...]:
        return tuple(sorted({c for t in self.terms for c in t.needs}))

    def terms_only(self, axes, **conditions) -> np.ndarray:
        """The terms' contribution alone, shape (n, 3) μm."""
        axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
        missing = [c for c in self.needs if conditions.get(c) is None]
        if missing:
            raise ValueError(f"the corrected model needs the condition(s) {missing} "
                             f"(terms: {[t.cand.label for t in self.terms]})")
        cond = {k: np.broadcast_to(np.asarray(v, dtype=float), (axes.shape[0],))
                for k, v in conditions.items() if v is not None}
        out = np.zeros((axes.shape[0], 3))
        if not self.terms:
            return out
        ctx = Context.build(self.machine, axes, cond, self.terms[0].ref)
        for t in self.terms:
            out += t.contribution(ctx)
        return out

    def predict(self, axes, **conditions) -> np.ndarray:
        axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
        extra = self.terms_only(axes, **conditions)
        return np.asarray(self.base.predict(axes), dtype=float) + extra

    __call__ = predict
