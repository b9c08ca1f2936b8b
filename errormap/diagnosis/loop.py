"""The closed loop on an identified model: update what the model has, then name what it lacks.

Three stages, each judged on the same held-out checks (the last ``1 − fit_fraction`` by seq):

1. **identified** — the sweep identification as it is;
2. **updated** — the 23 elements re-estimated from the fitting checks with the sweep estimate
   as prior (:func:`.update.update_elements`);
3. **updated + effects** — the effect search (:func:`.pipeline.diagnose`) on what the update
   leaves. In rank order, an effect is accepted only if it beats "update alone" (plus the
   effects accepted before it) on the held-out checks, significantly (:data:`HELD_OUT_Z`);
   the first that does not, and all after it, are reported as rejected.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..htm import HTMField
from ..stats import residual_stats
from .checks import ERROR_COLUMNS, CheckData, measured_residual
from .corrected import CorrectedField
from .effects import Context, reference
from .pipeline import Diagnosis, DiagnosisSettings, diagnose
from .update import ModelUpdate, update_elements


HELD_OUT_Z = 3.0
"""An effect is accepted when it lowers the held-out squared residual norm, paired per point,
by more than 3 standard errors (one-sided, p ≈ 0.001; a few candidates are tried in rank
order, so this keeps the family-wise false acceptance near the selector's alpha)."""


@dataclass
class ClosedLoop:
    """``update``: :class:`ModelUpdate`; ``diagnosis``: the effect search on the updated model;
    ``model``: the final :class:`CorrectedField` (updated elements + accepted terms);
    ``accepted``: whether the effects were kept; ``summary``: the three stages and findings."""

    update: ModelUpdate
    diagnosis: Diagnosis
    model: CorrectedField
    accepted: bool
    summary: dict


def closed_loop(machine, covariance, checks: CheckData, settings: DiagnosisSettings | None = None,
                rounds: int = 2) -> ClosedLoop:
    """Identified → updated → updated + effects on ``checks`` (see module doc);
    ``covariance``: the identification's :class:`~errormap.uncertainty.ElementCovariance`;
    ``rounds``: update/search rounds (from the second on, the update is made on the residual
    minus the previous round's effects, so that it does not take up an effect, then the
    search starts afresh)."""
    s = settings or DiagnosisSettings()
    n = len(checks)
    s.validate(n)
    n_fit = int(round(s.fit_fraction * n))
    fit_idx, hold_idx = np.arange(n_fit), np.arange(n_fit, n)
    base = HTMField(machine, covariance.elements)
    r0, _ = measured_residual(checks, base)
    upd = update_elements(machine, covariance, checks.axes[fit_idx], r0[fit_idx], alpha=s.alpha)
    updated = HTMField(machine, upd.elements_)
    d = diagnose(machine, updated, checks, s)
    for _ in range(rounds - 1):  # backfitting: update without what the effects explain, search again
        if not d.selector.terms_:
            break
        terms = CorrectedField(machine, base, d.selector.terms_).terms_only(checks.axes, **checks.conditions)
        upd = update_elements(machine, covariance, checks.axes[fit_idx], (r0 - terms)[fit_idx], alpha=s.alpha)
        updated = HTMField(machine, upd.elements_)
        d = diagnose(machine, updated, checks, s)
    r1 = d.residual_before_um
    ctx = Context.build(machine, checks.axes, checks.conditions, reference(machine, checks.conditions, s.ref_temp_c))
    kept, rejected, r2 = [], [], r1.copy()
    for t, e in zip(d.selector.terms_, d.effects):  # rank order; each must beat what is kept so far
        c = t.contribution(ctx)
        gain = np.sum(r2[hold_idx] ** 2, axis=1) - np.sum((r2 - c)[hold_idx] ** 2, axis=1)
        z = gain.mean() / (gain.std(ddof=1) / np.sqrt(gain.size)) if gain.std() > 0 else 0.0
        e = dict(e, held_out_gain_z=float(z))
        if z > HELD_OUT_Z and not rejected:
            kept.append((t, e))
            r2 = r2 - c
        else:
            rejected.append(e)
    st0, st1, st2 = (residual_stats(r[hold_idx], ERROR_COLUMNS) for r in (r0, r1, r2))
    accepted = bool(kept)
    model = CorrectedField(machine, updated, [t for t, _ in kept])
    summary = dict(d.summary)
    summary.update({
        "stages": {
            "identified": {"held_out": st0, "fitting": residual_stats(r0[fit_idx], ERROR_COLUMNS)},
            "updated": {"held_out": st1, "fitting": residual_stats(r1[fit_idx], ERROR_COLUMNS)},
            "updated_plus_effects": {"held_out": st2, "fitting": residual_stats(r2[fit_idx], ERROR_COLUMNS)},
        },
        "update": upd.to_dict(),
        "effects_accepted": accepted,
        "effects": [e for _, e in kept],
        "effects_rejected": rejected,
        "rms_identified_um": st0["rms_um"], "rms_updated_um": st1["rms_um"],
        "rms_final_um": st2["rms_um"], "max_final_um": st2["max_um"],
    })
    if rejected:
        summary["effects_rejected_why"] = (f"not a significant held-out improvement over the update (and the effects "
                                           f"ranked before it): paired z ≤ {HELD_OUT_Z} on the per-point squared residual")
    return ClosedLoop(upd, d, model, accepted, summary)
