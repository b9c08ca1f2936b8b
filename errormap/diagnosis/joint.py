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
from .effects import KINDS, SINUSOIDS, WCS_ELEMENTS, Context, EffectTerm, design, library

JOINT_KINDS = tuple(k for k in KINDS if k not in SINUSOIDS)
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


REFIT_ITERATIONS = 3
"""Alternations of (update on the residual minus the terms, σc by marginal likelihood) and (GLS of
the terms against that update's marginal): the check-noise σc of the update alone absorbs the
terms' signal (a worm harmonic of 100 μrad doubles it), so the marginal is re-made without
them; the coefficients change by < 1 % of their standard error after the second alternation."""
PERIOD_STEP = 1e-6
"""Relative step of the central difference for ∂(design·coef)/∂period of a periodic term."""


def joint_refit(machine, covariance, axes, residual_um, ctx: Context, terms, alpha: float = 0.01,
                iterations: int = REFIT_ITERATIONS):
    """The kept effect terms re-estimated jointly with the model update, with their covariance.

    The effect search fits its terms on what the update left (the update made without them,
    or made on the residual minus a first estimate of them: backfitting), and its covariance
    treats the updated elements as known. Both are wrong when the elements can imitate part of
    a term (a slope of ``dx_x`` for thermal growth, angular elements × lever arms for an X·Z
    coupling, the A splines for part of a worm harmonic): the estimate is pulled towards what
    the update left, and its band is too narrow by the update's own uncertainty. Here, with
    ``Δθ ~ N(0, Σp)`` (the sweep prior) marginalised out, the stacked fitting residual is
    ``r ~ N(D·β, V)``, ``V = A Σp Aᵀ + σc² I``; β by generalised least squares on
    ``V^{-1/2}`` (:meth:`.update.ModelUpdate.whiten`), its covariance
    ``s² (Dᵀ V⁻¹ D)⁻¹`` (``s²``: the whitened residual's variance, dof-corrected) — the joint
    (integrated-likelihood) estimate, equal to the converged backfitting. A periodic term's
    period is refined with them (Gauss–Newton, the derivative column), and its variance is
    part of the same covariance; a harmonic order stays fixed.

    ``axes`` (n, 3) fitting points, ``residual_um`` (n, 3) the identified model's measured
    residual there, ``ctx`` their context, ``terms`` :class:`EffectTerm` list.
    Returns (terms with joint coefficients and covariance, the update made on
    ``residual − terms``: a :class:`~.update.ModelUpdate`).
    """
    from dataclasses import replace

    from .update import update_elements
    r = np.asarray(residual_um, dtype=float)
    terms = list(terms)
    for _ in range(iterations):
        upd = update_elements(machine, covariance, axes, r - sum(t.contribution(ctx) for t in terms), alpha=alpha)
        cols, slots = [], []
        k = 0
        for t in terms:
            D = design(t.cand, ctx, t.period_mm, t.order)
            cols.append(D)
            idx = list(range(k, k + D.shape[1]))
            k += D.shape[1]
            if t.kind == "periodic":
                h = PERIOD_STEP * t.period_mm
                dD = (design(t.cand, ctx, t.period_mm + h, t.order) - design(t.cand, ctx, t.period_mm - h, t.order)) @ t.coef / (2 * h)
                cols.append(dD[:, None])
                idx.append(k)
                k += 1
            slots.append(idx)
        X = upd.whiten(np.hstack(cols))
        y = upd.whiten(r.reshape(-1))
        # the Gauss–Newton column carries δperiod: the linearised model is D(P)·coef + dD·δP
        v, *_ = np.linalg.lstsq(X, y, rcond=None)
        res = y - X @ v
        s2 = float(res @ res) / max(y.size - v.size, 1)
        cov = s2 * np.linalg.pinv(X.T @ X)
        new = []
        for t, idx in zip(terms, slots):
            m = len(t.coef)
            per = t.period_mm + float(v[idx[m]]) if t.kind == "periodic" else t.period_mm
            new.append(replace(t, coef=v[idx[:m]].copy(), period_mm=per, cov=cov[np.ix_(idx, idx)].copy(),
                               stats=dict(t.stats)))
        terms = new
    upd = update_elements(machine, covariance, axes, r - sum(t.contribution(ctx) for t in terms), alpha=alpha)
    return terms, upd
