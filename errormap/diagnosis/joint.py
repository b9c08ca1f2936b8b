"""Effects tested jointly with the model update (not on what the update left).

The update (:mod:`.update`) re-estimates the 23 elements from the checks with the sweep
prior. An effect that the elements can imitate within the sweeps' uncertainty — thermal
growth of X as a slope of ``dx_x``, an X·Z coupling as angular errors times lever arms — is
taken up by the update, and a search on what the update leaves sees only the part that
could not be imitated (for thermal growth: its variation about the mean temperature, which
the thermal basis does not fit). Here each linear candidate of the library (thermal,
drift, reversal, interaction) is fitted together with the update: under "update alone" the
stacked fitting residual is ``r ~ N(0, V)``, ``V = A Σp Aᵀ + σc² I`` (the update's own
marginal), under "update + term" ``r ~ N(D·β, V)``. Both are compared by generalised least
squares on the whitened residual ``V^{-1/2} r`` (:meth:`.update.ModelUpdate.whiten`):

* nested F-test of the term (Bonferroni over the ``K`` candidates, ``p_adj < alpha``), greedy
  forward, largest F first (ties: element over WCS-direct, thermal over drift);
* the selected terms' coefficients by GLS, with their covariance.

The screen only proposes: its terms are removed from the residual before the update is made
again, so that the update no longer takes them up, and the effect search and the held-out
gate of :mod:`.loop` then decide, as for any effect. Each proposed term is reported with
the elements the update alone had moved to imitate it (evidence of an effect the 23
elements lack, standing in for it).
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..elements import ELEMENT_NAMES
from .effects import KINDS, WCS_ELEMENTS, Context, EffectTerm, design, library

JOINT_KINDS = ("thermal", "drift", "reversal", "interaction")
"""The linear kinds tested jointly (periodic/harmonic terms are not imitated by the smooth
elements and are found by the periodogram search on what the update leaves)."""
KIND_PREFERENCE = {k: i for i, k in enumerate(KINDS)}


def _rss(D, y):
    if D.shape[1] == 0:
        return float(y @ y), np.zeros(0)
    beta = np.linalg.lstsq(D, y, rcond=None)[0]
    res = y - D @ beta
    return float(res @ res), beta


def joint_screen(update, ctx: Context, residual_um, alpha: float = 0.01, max_effects: int = 4) -> tuple[list, list]:
    """Greedy GLS screen of the linear candidates against ``update`` (see module doc).

    ``ctx``: context of the fitting checks (n points); ``residual_um`` (n, 3) the identified
    model's measured residual there (the one the update was made on). Returns
    (terms: list of :class:`EffectTerm` with GLS coefficients and covariance, steps: per
    selected term a dict with F, p_value, p_adjusted).
    """
    r = np.asarray(residual_um, dtype=float).reshape(-1)
    y = update.whiten(r)
    N = y.size
    cands = library(set(ctx.conditions), JOINT_KINDS)
    K = len(cands)
    if K == 0:
        return [], []
    Dw = {c: update.whiten(design(c, ctx)[:, 0]) for c in cands}
    chosen, steps = [], []
    for _ in range(max_effects):
        Dsel = np.stack([Dw[c] for c in chosen], axis=1) if chosen else np.zeros((N, 0))
        rss0, _ = _rss(Dsel, y)
        scored = []
        for c in cands:
            if c in chosen:
                continue
            rss1, _ = _rss(np.column_stack([Dsel, Dw[c]]), y)
            dof = N - Dsel.shape[1] - 1
            F = (rss0 - rss1) / max(rss1 / dof, 1e-300)
            scored.append((float(f"{F:.6g}"), c, rss1, dof))
        scored.sort(key=lambda t: (-t[0], t[1].element in WCS_ELEMENTS, KIND_PREFERENCE[t[1].kind]))
        F, c, rss1, dof = scored[0]
        p = float(stats.f.sf(F, 1, dof)) if F > 0 else 1.0
        p_adj = min(1.0, p * K)
        if p_adj >= alpha:
            break
        chosen.append(c)
        steps.append({"kind": c.kind, "axis": c.axis, "element": c.element, "F": F, "p_value": p,
                      "p_adjusted": p_adj, "n_candidates": K})
    if not chosen:
        return [], []
    D = np.stack([Dw[c] for c in chosen], axis=1)
    rss, beta = _rss(D, y)
    s2 = rss / max(N - D.shape[1], 1)
    cov = s2 * np.linalg.pinv(D.T @ D)
    terms = [EffectTerm(c, np.array([beta[i]]), ctx.ref, cov=cov[i:i + 1, i:i + 1]) for i, c in enumerate(chosen)]
    for t, st in zip(terms, steps):
        st["parameters"] = t.parameters()
    return terms, steps


def stand_ins(machine, update_alone, update_without, top: int = 3) -> list[dict]:
    """The elements the update alone moved to imitate the proposed terms: per element, the RMS
    over the fitting checks of (update alone − update made without the terms' part), μm,
    largest first (``top`` of them)."""
    from ..uncertainty import theta_layout
    lay = np.array([k for k, _ in theta_layout(update_alone.elements_)])
    A = update_alone.design_
    diff = update_alone.delta_theta - update_without.delta_theta
    out = []
    for k in ELEMENT_NAMES:
        idx = np.flatnonzero(lay == k)
        c = (A[:, idx] @ diff[idx]).reshape(-1, 3)
        out.append({"element": k, "imitation_rms_um": float(np.sqrt(np.mean(np.sum(c**2, axis=1))))})
    out.sort(key=lambda e: -e["imitation_rms_um"])
    return out[:top]
