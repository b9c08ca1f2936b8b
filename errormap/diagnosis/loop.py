"""The closed loop on an identified model: update what the model has, then name what it lacks.

Three stages, each judged on the same held-out checks (the last ``1 − fit_fraction`` by seq):

1. **identified** — the sweep identification as it is;
2. **updated** — the 23 elements re-estimated from the fitting checks with the sweep estimate
   as prior (:func:`.update.update_elements`);
3. **updated + effects** — the effect search (:func:`.pipeline.diagnose`) on what the update
   leaves. The effects are accepted only if they beat "update alone" on the held-out checks;
   otherwise they are reported as rejected and the updated model is the result.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..htm import HTMField
from .checks import CheckData, measured_residual
from .corrected import CorrectedField
from .pipeline import Diagnosis, DiagnosisSettings, diagnose, residual_stats
from .update import ModelUpdate, update_elements


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
    r2 = d.residual_after_um
    st0, st1, st2 = (residual_stats(r[hold_idx]) for r in (r0, r1, r2))
    accepted = bool(d.effects) and st2["rms_um"] < st1["rms_um"]
    model = d.corrected if accepted else CorrectedField(machine, updated, [])
    summary = dict(d.summary)
    summary.update({
        "stages": {
            "identified": {"held_out": st0, "fitting": residual_stats(r0[fit_idx])},
            "updated": {"held_out": st1, "fitting": residual_stats(r1[fit_idx])},
            "updated_plus_effects": {"held_out": st2 if accepted else st1,
                                     "fitting": residual_stats((r2 if accepted else r1)[fit_idx])},
        },
        "update": upd.to_dict(),
        "effects_accepted": accepted,
        "effects": d.effects if accepted else [],
        "effects_rejected": [] if accepted else d.effects,
        "rms_identified_um": st0["rms_um"], "rms_updated_um": st1["rms_um"],
        "rms_final_um": (st2 if accepted else st1)["rms_um"],
    })
    if not accepted and d.effects:
        summary["effects_rejected_why"] = ("the effects did not beat the model update alone on the held-out checks "
                                           f"({st2['rms_um']:.3g} vs {st1['rms_um']:.3g} μm RMS)")
    return ClosedLoop(upd, d, model, accepted, summary)
