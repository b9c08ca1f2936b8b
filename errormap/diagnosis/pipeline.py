"""The diagnosis of check measurements against a model, start to end (no files).

1. measured residual = measurement − model prediction (:func:`.checks.measured_residual`);
2. split by ``seq``: the first ``fit_fraction`` is the fitting part, the rest the held-out
   part (forward in time: time effects must extrapolate);
3. :class:`.selection.EffectSelector` on the fitting part; the selected terms are fitted
   (jointly) on the fitting part only;
4. the corrected model (:class:`.corrected.CorrectedField`) gives the residual after;
   statistics before/after on the held-out part; each effect's ``rms_reduction_um`` is the
   held-out RMS drop it brings when added in rank order;
5. :func:`.localize.locate` on the held-out residual before and after says where whatever
   is left lives (output axis, input, period).

RMS and max are of the per-point residual vector norm ``|r|`` (μm); per-axis statistics are
given beside them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..stats import residual_stats
from .checks import ERROR_COLUMNS, CheckData, measured_residual
from .corrected import CorrectedField
from .effects import Context, reference
from .localize import locate
from .selection import EffectSelector


@dataclass
class DiagnosisSettings:
    """``fit_fraction`` of the checks (by seq) used for fitting; the selector's settings;
    ``ref_temp_c`` the temperature at which the base model holds."""

    fit_fraction: float = 0.6
    alpha: float = 0.01
    max_effects: int = 4
    inner_fraction: float = 2 / 3
    period_min_mm: float = 1.0
    max_order: int = 120
    ref_temp_c: float = 20.0
    noise_um: float | None = None
    """The checks' known noise σ per axis (μm): the held-out noise floor √3·σ and the σ the verdict compares the
    update's estimate with (:func:`errormap.diagnosis.plausibility.noise_record`); None: estimated by the update."""

    def validate(self, n: int) -> None:
        if not 0 < self.fit_fraction < 1:
            raise ValueError(f"Expected 0 < fit_fraction < 1, got {self.fit_fraction}")
        if self.noise_um is not None and not (np.isfinite(self.noise_um) and self.noise_um > 0):
            raise ValueError(f"Expected a positive, finite noise σ in μm, got {self.noise_um}")
        n_fit = int(round(self.fit_fraction * n))
        if n_fit < 20 or n - n_fit < 10:
            raise ValueError(f"Expected at least 20 fitting and 10 held-out checks, got {n_fit} and {n - n_fit} "
                             f"of {n} (fit_fraction {self.fit_fraction})")


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`: arrays (all in seq order) and the summary."""

    checks: CheckData
    prediction_um: np.ndarray
    residual_before_um: np.ndarray
    residual_after_um: np.ndarray
    fit_idx: np.ndarray
    hold_idx: np.ndarray
    selector: EffectSelector
    corrected: CorrectedField
    effects: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)


def _inputs(checks: CheckData) -> dict:
    d = {"x_mm": checks.axes[:, 0], "z_mm": checks.axes[:, 1], "a_deg": checks.axes[:, 2]}
    d.update(checks.conditions)
    return d


def diagnose(machine, field_, checks: CheckData, settings: DiagnosisSettings | None = None) -> Diagnosis:
    """Run the diagnosis of ``checks`` against the error field ``field_`` (see module doc)."""
    s = settings or DiagnosisSettings()
    n = len(checks)
    s.validate(n)
    r0, pred = measured_residual(checks, field_)
    n_fit = int(round(s.fit_fraction * n))
    fit_idx, hold_idx = np.arange(n_fit), np.arange(n_fit, n)
    ctx = Context.build(machine, checks.axes, checks.conditions, reference(machine, checks.conditions, s.ref_temp_c))
    sel = EffectSelector(alpha=s.alpha, max_effects=s.max_effects, inner_fraction=s.inner_fraction,
                         period_min_mm=s.period_min_mm, max_order=s.max_order)
    sel.fit(ctx.subset(fit_idx), r0[fit_idx])
    corrected = CorrectedField(machine, field_, sel.terms_)
    contrib = [t.contribution(ctx) for t in sel.terms_]
    r_after = r0 - sum(contrib) if contrib else r0.copy()
    effects, r_k = [], r0[hold_idx]
    for t, c in zip(sel.terms_, contrib):
        rms_prev = residual_stats(r_k)["rms_um"]
        r_k = r_k - c[hold_idx]
        d = t.to_dict()
        d["rms_reduction_um"] = rms_prev - residual_stats(r_k)["rms_um"]
        d["selection"] = dict(t.stats)
        effects.append(d)
    before, after = residual_stats(r0[hold_idx], ERROR_COLUMNS), residual_stats(r_after[hold_idx], ERROR_COLUMNS)
    inputs = _inputs(checks)
    hold_inputs = {k: v[hold_idx] for k, v in inputs.items()}
    top = []
    for sc in (sel.steps_[-1][:8] if sel.steps_ else []):
        c = sc["cand"]
        top.append({"kind": c.kind, "axis": c.axis, "element": c.element,
                    **{k: sc[k] for k in ("period_mm", "order", "p_adjusted", "delta_bic", "validation_gain_um2", "passes")}})
    summary = {
        "residual": "measured (measurement − model prediction)",
        "n_checks": n, "n_fit": int(n_fit), "n_held_out": int(n - n_fit),
        "split": f"by seq: first {n_fit} fit, last {n - n_fit} held out",
        "effects": effects,
        "rms_before_um": before["rms_um"], "rms_after_um": after["rms_um"],
        "max_before_um": before["max_um"], "max_after_um": after["max_um"],
        "held_out_before": before, "held_out_after": after,
        "fitting_before": residual_stats(r0[fit_idx], ERROR_COLUMNS), "fitting_after": residual_stats(r_after[fit_idx], ERROR_COLUMNS),
        "all_before": residual_stats(r0, ERROR_COLUMNS),
        "noise_sigma_um": sel.sigma_um_,
        "n_candidates": sel.n_candidates_,
        "unexplained_before": locate(r0[hold_idx], hold_inputs, s.alpha, s.period_min_mm, s.max_order),
        "unexplained_after": locate(r_after[hold_idx], hold_inputs, s.alpha, s.period_min_mm, s.max_order),
        "next_candidates": top,
        "settings": {k: getattr(s, k) for k in s.__dataclass_fields__},
    }
    return Diagnosis(checks, pred, r0, r_after, fit_idx, hold_idx, sel, corrected, effects, summary)
