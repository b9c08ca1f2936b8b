"""Selecting the effects that explain a measured residual: greedy forward selection.

At each step every remaining candidate of the library (:mod:`.effects`) is fitted to the
current residual (the measured residual minus the terms selected so far) on the fitting
data, and judged three ways:

1. **significance** — nested F-test of the term against the current model, on the stacked
   3-vector residual (``N = 3n`` observations, the noise variance estimated from the
   residual itself). The p-value is Bonferroni-corrected for the number of candidates ``K``
   and, for the terms whose period/order is searched by a periodogram, for the number of
   independent frequencies ``M`` searched: ``p_adj = min(1, p·K·M)``. A term needs
   ``p_adj < alpha``.
2. **forward validation** — the selected terms plus the candidate (its period/order searched
   again) are refitted on the first ``inner_fraction`` of the fitting data (in ``seq`` order)
   and must lower the residual sum of squares on the rest below that of the selected terms
   alone, refitted the same way: the term must predict forwards in time, not just fit.
3. **rank** — among the terms that pass both, the largest BIC improvement
   ``ΔBIC = N·ln(RSS0/RSS1) − p·ln N`` (``p`` counts a searched period/order) wins. Exact
   ties go to an element term over a WCS-direct one, and to ``thermal`` over ``drift``:
   temperature and time are collinear on a warm-up log, so both are scored and the one that
   explains better wins; when temperature explains equally well, the measured cause is named.

The winner joins the model; all selected terms are then refitted jointly (periods by
nonlinear least squares), and the next step starts. Selection stops when no candidate
passes or after ``max_effects`` terms.
"""
from __future__ import annotations

import numpy as np
from scipy import optimize, stats

from .effects import (AXIS_COL, KINDS, SINUSOIDS, Candidate, Context, EffectTerm, design, library, periodogram_trig,
                      projected_periodogram)

KIND_PREFERENCE = {k: i for i, k in enumerate(KINDS)}
STAT_KEYS = ("F", "p_value", "p_adjusted", "delta_bic", "validation_gain_um2")


def _round_sig(v: float, digits: int = 6) -> float:
    return float(f"{v:.{digits}g}")


class EffectSelector:
    """Greedy forward selection of effect terms (see module doc).

    Settings: ``alpha`` family-wise significance level; ``max_effects``; ``inner_fraction``
    of the fitting data used to fit in the forward validation; ``period_min_mm`` shortest
    period searched for ``periodic``; ``max_order`` highest A harmonic searched;
    ``oversample`` of the frequency grid; ``kinds`` the library kinds to use.

    Learned state: ``terms_`` (list of :class:`EffectTerm`, in selection order), ``steps_``
    (per step, the scored candidates best first), ``sigma_um_`` (noise σ per component
    estimated after the selected terms), ``n_candidates_``.
    """

    def __init__(self, alpha: float = 0.01, max_effects: int = 4, inner_fraction: float = 2 / 3,
                 period_min_mm: float = 1.0, max_order: int = 120, oversample: float = 5.0, kinds=KINDS):
        self.alpha = alpha
        self.max_effects = max_effects
        self.inner_fraction = inner_fraction
        self.period_min_mm = period_min_mm
        self.max_order = max_order
        self.oversample = oversample
        self.kinds = tuple(kinds)

    # -- nonlinear search -------------------------------------------------------------------
    def _omegas(self, cand: Candidate, ctx: Context):
        """Angular frequencies to search and the number of independent ones, M."""
        if cand.kind == "harmonic":
            return np.arange(1, self.max_order + 1, dtype=float), float(self.max_order)
        lo, hi = ctx.ref["strokes"]["x_mm" if cand.axis == "x" else "z_mm"]
        span = hi - lo
        f_min, f_max = 2.0 / span, 1.0 / self.period_min_mm
        df = 1.0 / (self.oversample * span)
        f = np.arange(f_min, f_max + df / 2, df)
        return 2 * np.pi * f, max(1.0, span * (f_max - f_min))

    def _search(self, cand: Candidate, ctx: Context, r: np.ndarray):
        """Best period (mm) or order for ``cand`` on residual ``r`` (n, 3); (None, None) if linear."""
        if cand.kind not in SINUSOIDS:
            return None, None
        om, _ = self._omegas(cand, ctx)
        jcol = ctx.column(cand.element)
        pos = ctx.position("a") if cand.kind == "harmonic" else ctx.axes[:, AXIS_COL[cand.axis]]
        key = ("periodogram", cand.kind, cand.axis)
        if key not in ctx.cache:
            ctx.cache[key] = periodogram_trig(pos, om)
        gain, _ = projected_periodogram(r, jcol, pos, om, ctx.cache[key])
        k = int(np.argmax(gain))
        if cand.kind == "harmonic":
            return None, int(round(om[k]))
        d = om[1] - om[0] if len(om) > 1 else om[0] * 1e-3

        def neg(w):
            return -projected_periodogram(r, jcol, pos, np.array([w]))[0][0]
        res = optimize.minimize_scalar(neg, bounds=(om[k] - d, om[k] + d), method="bounded",
                                       options={"xatol": d * 1e-4})
        w = res.x if -res.fun >= gain[k] else om[k]
        return 2 * np.pi / w, None

    @staticmethod
    def _fit_linear(D: np.ndarray, y: np.ndarray):
        theta, *_ = np.linalg.lstsq(D, y, rcond=None)
        return theta

    # -- scoring ----------------------------------------------------------------------------
    @staticmethod
    def _designs(specs, ctx):
        """Stacked design of the selected terms (fixed periods), shape (3n, p) (p may be 0)."""
        n = ctx.axes.shape[0]
        mats = [design(c, ctx, per, order) for c, per, order in specs]
        return np.hstack(mats) if mats else np.zeros((3 * n, 0))

    @staticmethod
    def _rss(D, y):
        if D.shape[1] == 0:
            return float(y @ y), y
        res = y - D @ np.linalg.lstsq(D, y, rcond=None)[0]
        return float(res @ res), res

    def _score(self, cand, ctx, r0, specs, pre, K) -> dict:
        """Score ``cand`` added to the selected ``specs``: nested F-test and BIC on the whole
        fitting data, forward validation (all terms refitted on the inner part)."""
        D_sel, rss0, res0, D_sel_in, D_sel_val, res0_in, ci, cv, inner, val = pre
        y = r0.reshape(-1)
        N = y.size
        period, order = self._search(cand, ctx, res0.reshape(-1, 3))
        Dc = design(cand, ctx, period, order)
        rss1, _ = self._rss(np.hstack([D_sel, Dc]), y)
        p = Dc.shape[1]
        dof2 = N - D_sel.shape[1] - p
        F = ((rss0 - rss1) / p) / max(rss1 / dof2, 1e-300)
        pval = float(stats.f.sf(F, p, dof2)) if F > 0 else 1.0
        M = self._omegas(cand, ctx)[1] if cand.kind in SINUSOIDS else 1.0
        p_adj = min(1.0, pval * M * K)
        n_nonlin = 1 if cand.kind in SINUSOIDS else 0
        dbic = N * np.log(rss0 / max(rss1, 1e-300)) - (p + n_nonlin) * np.log(N)
        # forward validation: refit everything on the inner part, compare on the rest
        per_i, ord_i = self._search(cand, ci, res0_in.reshape(-1, 3))
        yi, yv = r0[inner].reshape(-1), r0[val].reshape(-1)
        Di = np.hstack([D_sel_in, design(cand, ci, per_i, ord_i)])
        Dv = np.hstack([D_sel_val, design(cand, cv, per_i, ord_i)])
        th1 = np.linalg.lstsq(Di, yi, rcond=None)[0]
        if D_sel_in.shape[1]:
            th0 = np.linalg.lstsq(D_sel_in, yi, rcond=None)[0]
            rv0 = yv - D_sel_val @ th0
        else:
            rv0 = yv
        val_gain = float(rv0 @ rv0 - np.sum((yv - Dv @ th1) ** 2))
        return {"cand": cand, "period_mm": period, "order": order, "F": float(F), "p_value": pval,
                "p_adjusted": p_adj, "delta_bic": float(dbic), "rss_reduction_um2": rss0 - rss1,
                "validation_gain_um2": val_gain, "passes": bool(p_adj < self.alpha and val_gain > 0)}

    def _prepare(self, ctx, r0, specs, inner, val, sub=None):
        y = r0.reshape(-1)
        D_sel = self._designs(specs, ctx)
        rss0, res0 = self._rss(D_sel, y)
        ci, cv = sub if sub is not None else (ctx.subset(inner), ctx.subset(val))
        D_sel_in, D_sel_val = self._designs(specs, ci), self._designs(specs, cv)
        _, res0_in = self._rss(D_sel_in, r0[inner].reshape(-1))
        return D_sel, rss0, res0, D_sel_in, D_sel_val, res0_in, ci, cv, inner, val

    @staticmethod
    def _rank_key(s):
        c = s["cand"]
        return (-_round_sig(s["delta_bic"]), c.element in ("dx", "dy", "dz"), KIND_PREFERENCE[c.kind])

    # -- joint fit --------------------------------------------------------------------------
    @staticmethod
    def joint_fit(ctx: Context, residual_um: np.ndarray, specs) -> tuple[list[EffectTerm], float, int]:
        """Fit the terms ``specs`` [(Candidate, period_mm, order)] jointly to ``residual_um`` (n, 3).

        Linear coefficients by least squares; periods refined by nonlinear least squares.
        Returns (terms with covariances, RSS μm², residual degrees of freedom).
        """
        y = residual_um.reshape(-1)
        sizes = [c.n_linear for c, _, _ in specs]
        per_idx = [i for i, (c, _, _) in enumerate(specs) if c.kind == "periodic"]

        def build(periods):
            mats, pi = [], 0
            for i, (c, per, order) in enumerate(specs):
                if c.kind == "periodic":
                    per = periods[pi]
                    pi += 1
                mats.append(design(c, ctx, per, order))
            return np.hstack(mats)

        periods0 = np.array([specs[i][1] for i in per_idx], dtype=float)
        D = build(periods0)
        theta = np.linalg.lstsq(D, y, rcond=None)[0]
        P = len(theta)
        if per_idx:
            def fun(v):
                return build(v[P:]) @ v[:P] - y
            sol = optimize.least_squares(fun, np.concatenate([theta, periods0]), x_scale="jac", method="lm")
            v, Jm = sol.x, sol.jac
            theta, periods = v[:P], v[P:]
        else:
            v, Jm, periods = theta, D, periods0
        res = (build(periods) @ theta - y) if per_idx else (D @ theta - y)
        rss = float(res @ res)
        dof = max(y.size - v.size, 1)
        cov = (rss / dof) * np.linalg.pinv(Jm.T @ Jm)
        terms, k, pi = [], 0, 0
        for (c, per, order), m in zip(specs, sizes):
            idx = list(range(k, k + m))
            if c.kind == "periodic":
                idx.append(P + pi)
                per = float(periods[pi])
                pi += 1
            terms.append(EffectTerm(c, theta[k:k + m].copy(), ctx.ref, per, order, cov[np.ix_(idx, idx)]))
            k += m
        return terms, rss, dof

    # -- fit --------------------------------------------------------------------------------
    def fit(self, ctx: Context, residual_um) -> "EffectSelector":
        """Select terms explaining ``residual_um`` (n, 3) μm at the context's points (seq order)."""
        r0 = np.asarray(residual_um, dtype=float)
        n = ctx.axes.shape[0]
        if r0.shape != (n, 3):
            raise ValueError(f"Expected a residual of shape ({n}, 3), got {r0.shape}")
        if not np.all(np.isfinite(r0)):
            raise ValueError("Expected a finite residual, got NaN or inf")
        if n < 20:
            raise ValueError(f"Expected at least 20 fitting points for effect selection, got {n}")
        if not 0 < self.alpha < 1 or not 0 < self.inner_fraction < 1 or self.max_effects < 0:
            raise ValueError(f"Expected 0<alpha<1, 0<inner_fraction<1, max_effects>=0, got "
                             f"{self.alpha}, {self.inner_fraction}, {self.max_effects}")
        cands = library(set(ctx.conditions), self.kinds)
        K = len(cands)
        n_in = int(round(self.inner_fraction * n))
        inner, val = np.arange(n_in), np.arange(n_in, n)
        specs, terms, r = [], [], r0.copy()
        self.steps_ = []
        p_prev = 0
        sel_stats = {}
        sub = (ctx.subset(inner), ctx.subset(val))  # built once: their periodogram caches are reused by every step
        for _ in range(self.max_effects):
            chosen = {s[0] for s in specs}
            pre = self._prepare(ctx, r0, specs, inner, val, sub)
            scored = [self._score(c, ctx, r0, specs, pre, K) for c in cands if c not in chosen]
            scored.sort(key=self._rank_key)
            self.steps_.append(scored)
            passing = [s for s in scored if s["passes"]]
            if not passing:
                break
            best = passing[0]
            specs.append((best["cand"], best["period_mm"], best["order"]))
            sel_stats[best["cand"]] = {k: best[k] for k in STAT_KEYS}
            terms, _, _ = self.joint_fit(ctx, r0, specs)
            specs = [(t.cand, t.period_mm, t.order) for t in terms]
            for t in terms:
                t.stats = dict(sel_stats[t.cand])
            r = r0 - sum(t.contribution(ctx) for t in terms)
            p_prev = sum(len(t.coef) + (t.kind == "periodic") for t in terms)
        self.terms_ = terms
        self.n_candidates_ = K
        self.sigma_um_ = float(np.sqrt(np.sum(r**2) / max(r.size - p_prev, 1)))
        return self
