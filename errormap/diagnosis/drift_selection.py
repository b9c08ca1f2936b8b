"""The drift model chosen on held-out time: :class:`DriftSelector` (docs/explanation/drift.md states the rule)."""
from __future__ import annotations

import numpy as np

from ..estimators import Estimator
from ..settings import keep_settings
from .drift import DriftLog
from .drift_candidates import default_families
from .drift_features import (RANGE_QUANTILE, _inputs, feature_matrix, feature_novelty, input_matrix, mahalanobis,
                             relative_distance, whitener)
from .drift_model_file import ChannelFit, DriftModel
from .drift_validation import (BAND_RULE, BAND_RULES, CONSTANT_GATE_LEVEL, FEATURE_DISTANCE, GATE_SE, MAX_FOLD_LOSS,
                               MIN_GAIN, RANKING_FOLD_LOSS, SHRINK_SCALES, SHRINK_WEIGHTS, _blend_residuals, _rms,
                               band_of, blend_statistics, blend_with_ols, candidate_name, constant_gate, cv_residuals,
                               horizon_folds, novelty_folds, rolling_origin_folds)


PLAIN_BASELINES = (("ols", ""), ("constant", ""))   # judged as they are: never blended, never shrunk by distance


class DriftSelector(Estimator):
    """Per channel, a family (and hyper-parameter) chosen on the fitting part only, refitted on all of it.

    The rule (``docs/explanation/drift.md``, "How a model is chosen"): every family × hyper-parameter, shrunk
    toward OLS as a whole (``shrink_weights``) and per sample by the distance ρ of its inputs (and, with
    ``feature_distance``, its own features) from the training data (:func:`distance_weight`, scale from
    ``shrink_scales``), is scored on three sets of forward-chaining folds of the fitting part: ranking
    (``n_folds`` after the first ``cv_start``, :func:`rolling_origin_folds`), horizon (``n_horizon_folds``,
    :func:`horizon_folds`, ``horizon`` default (1 − fit_fraction)/fit_fraction) and novelty
    (``n_novelty_folds`` of ``n_novelty_blocks``, :func:`novelty_folds`). Eligible: below OLS on the ranking
    folds, passing :func:`horizon_gate` (``gate_se``) with a mean log-gain ≥ ``min_gain`` on the horizon and
    novelty folds, no fold worse than OLS by more than ``max_fold_loss`` (ranking folds too with
    ``ranking_fold_loss``); the eligible of largest mean log-gain is returned if it also beats the constant
    offset, else the better plain baseline (``PLAIN_BASELINES``, :meth:`_choose`). The band: ``band_rule``.

    Learned: ``model_`` (:class:`DriftModel`), ``baseline_`` (the OLS :class:`DriftModel`), ``chosen_``,
    ``scale_``, ``shrink_``, ``cv_`` / ``cv_horizon_`` / ``cv_novelty_`` ({channel: {candidate: RMS μm}}),
    ``gate_`` ({channel: {candidate: (passes, mean log gain, its se)}}), ``gain_``, ``score_``, ``eligible_``,
    ``worst_fold_``, ``band_alt_``, ``novelty_`` ((n_novelty_blocks,) median distance of each block),
    ``subset_modeller_``, ``candidates_`` ({channel: {(family, hyper, w0): every validation statistic}}).
    ``families``: default :func:`default_families`. ``deploy`` (False): also refit each channel's chosen
    candidate on every row of the log, ``deployed_`` (its meta ``fit_rows`` all rows, ``validated_on_rows``
    the fitting part; None without it); the selection and every validation figure are the same either way."""

    def __init__(self, fit_fraction: float = 0.6, n_folds: int = 4, cv_start: float = 0.5, families=None,
                 subset_kw: dict | None = None, horizon: float | None = None, n_horizon_folds: int = 4,
                 gate_se: float = GATE_SE, n_novelty_folds: int = 3, n_novelty_blocks: int = 8,
                 shrink_weights=SHRINK_WEIGHTS, shrink_scales=SHRINK_SCALES, max_fold_loss: float = MAX_FOLD_LOSS,
                 min_gain: float = MIN_GAIN, feature_distance: bool = FEATURE_DISTANCE,
                 ranking_fold_loss: bool = RANKING_FOLD_LOSS, band_rule: str = BAND_RULE, deploy: bool = False):
        keep_settings(self, locals())

    def eligible(self, stats: dict, gate: tuple, w: float, ranking_ols: float, novelty: bool = True) -> bool:
        """Whether a candidate blended at weight ``w`` (its :func:`blend_statistics` ``stats`` and ``gate``) passes
        every gate of the rule against OLS, whose ranking-fold RMS is ``ranking_ols``: below it on the ranking
        folds, > ``gate_se`` SE and a mean log-gain ≥ ``min_gain`` on the horizon and (``novelty``) the novelty
        folds, and no fold above ``max_fold_loss``× OLS."""
        (ok_h, gain_h, _), (ok_n, gain_n, _) = gate
        return bool(stats["ranking"] < ranking_ols and ok_h and ok_n and stats["worst_fold"] <= self.max_fold_loss
                    and gain_h >= self.min_gain and (not novelty or gain_n >= self.min_gain))

    def split(self, log):
        n = len(log.time_s)
        n_fit = int(round(self.fit_fraction * n))
        return np.arange(n_fit), np.arange(n_fit, n)

    def _check_settings(self) -> None:
        if not 0 < self.fit_fraction < 1:
            raise ValueError(f"Expected 0 < fit_fraction < 1, got {self.fit_fraction}")
        if not self.shrink_scales or not all(sc > 0 for sc in self.shrink_scales):
            raise ValueError(f"Expected shrink_scales > 0 (inf: no per-sample shrinkage), got {self.shrink_scales}")
        if not self.max_fold_loss >= 1.0:
            raise ValueError(f"Expected max_fold_loss >= 1, got {self.max_fold_loss}")
        if np.isnan(self.min_gain):
            raise ValueError("Expected a number for min_gain, got nan")
        if self.band_rule not in BAND_RULES:
            raise ValueError(f"Expected band_rule in {BAND_RULES}, got {self.band_rule!r}")
        if not self.shrink_weights or not all(0 < w <= 1 for w in self.shrink_weights):
            raise ValueError(f"Expected shrink_weights in (0, 1], got {self.shrink_weights}")

    def fit(self, log: DriftLog) -> "DriftSelector":
        self._check_settings()
        fams = self.families or default_families(self.subset_kw)
        fit, _ = self.split(log)
        chans = list(log.disp_um)
        cache = {}
        sets = self._fold_sets(log, fit, cache)
        folds, hfolds, nfolds, h, U = sets
        self.fold_errors_ = []
        feats = ({}, {}, {})
        resid = tuple(cv_residuals(log, fams, chans, fs, cache, self.fold_errors_, fd)
                      for fs, fd in zip((folds, hfolds, nfolds), feats))
        rho = _FoldRho(self, log, cache, U, (folds, hfolds, nfolds))
        for name in ("cv_", "cv_horizon_", "cv_novelty_", "gate_", "chosen_", "band_", "band_ols_", "shrink_", "gain_",
                     "eligible_", "scale_", "worst_fold_", "fold_ratios_", "fold_rho_", "candidates_", "band_alt_",
                     "score_", "refused_by_constant_"):
            setattr(self, name, {})
        for ch in chans:
            scores, gate = self._score_channel(log, ch, resid, feats, rho, bool(nfolds))
            self._record_channel(ch, scores, gate, bool(nfolds))
        self.model_, self.baseline_ = self._final_models(log, fams, chans, fit, cache, U, sets)
        self.deployed_ = None
        if self.deploy:
            self._deploy(log, fams, chans, fit, cache, sets)
        self.cache_ = cache
        return self

    def _fold_sets(self, log, fit, cache):
        """(ranking folds, horizon folds, novelty folds, horizon, the fitting part's raw inputs U (n_fit, k));
        sets ``novelty_``."""
        folds = rolling_origin_folds(len(fit), self.n_folds, self.cv_start)
        h = (1 - self.fit_fraction) / self.fit_fraction if self.horizon is None else self.horizon
        hfolds = horizon_folds(len(fit), h, self.n_horizon_folds, self.cv_start)
        U = input_matrix(log, fit, cache)
        nfolds, self.novelty_ = novelty_folds(U, self.n_novelty_blocks, self.n_novelty_folds) \
            if self.n_novelty_folds else ([], np.zeros(0))
        return folds, hfolds, nfolds, h, U

    def _score_channel(self, log, ch, resid, feats, rho, novelty: bool):
        """Every candidate of channel ``ch`` at every blend weight: ({(family, hyper, w): stats}, {…: gate}).
        ``resid``/``feats``: (ranking, horizon, novelty) :func:`cv_residuals` results and candidate features."""
        base = ("ols", "")
        n_sets = [len(f) for f in rho.fold_sets]
        full = [k[1:] for k, v in resid[0].items() if k[0] == ch
                and all(len(r.get(k, [])) == n for r, n in zip(resid, n_sets))]
        if base not in full:
            raise ValueError(f"{log.path}: the OLS baseline could not be fitted on the cross-validation folds")
        ols = tuple(r.get((ch, *base), []) for r in resid)
        scores, gate = {}, {}
        for k in full:
            rhos = tuple(rho.of(i, fd.get((ch, *k), [])) for i, fd in enumerate(feats))
            cand = tuple(r.get((ch, *k), []) for r in resid)
            plain = k in PLAIN_BASELINES     # OLS and the constant: as they are (no blend, no distance shrinkage)
            for w in ((1.0,) if plain else self.shrink_weights):
                sc = self._scale(w, cand[2], ols[2], rhos[2]) if novelty and not plain else np.inf
                key = (k[0], k[1], w)
                scores[key], gate[key] = blend_statistics(w, sc, cand, ols, rhos, self.gate_se,
                                                          self.ranking_fold_loss)
        return scores, gate

    def _scale(self, w, res_n, ols_n, rho_n) -> float:
        """g's scale: the one of ``shrink_scales`` of lowest RMS on the novelty folds (ties: the least shrinkage)."""
        return min(self.shrink_scales, key=lambda s: (round(_rms(np.concatenate(
            _blend_residuals(w, res_n, ols_n, rho_n, s))), 12), -s))

    def _record_channel(self, ch, scores: dict, gate: dict, novelty: bool) -> None:
        """Choose channel ``ch``'s candidate among ``scores`` and record every learned figure of it."""
        base = ("ols", "", 1.0)
        ok, best, refused = self._choose(scores, gate, novelty)
        names = {k: candidate_name(*k) for k in scores}
        self.cv_[ch] = {names[k]: s["ranking"] for k, s in scores.items()}
        self.cv_horizon_[ch] = {names[k]: s["horizon"] for k, s in scores.items()}
        self.cv_novelty_[ch] = {names[k]: s["novelty"] for k, s in scores.items()}
        self.gate_[ch] = {names[k]: (g[0][0] and g[1][0], g[0][1], g[0][2], g[1][1], g[1][2]) for k, g in gate.items()}
        self.gain_[ch] = {names[k]: float(s["gain"]) for k, s in scores.items()}
        self.score_[ch] = dict(self.gain_[ch])
        self.worst_fold_[ch] = {names[k]: float(s["worst_fold"]) for k, s in scores.items()}
        self.fold_ratios_[ch] = {names[k]: s["fold_ratios"] for k, s in scores.items()}
        self.fold_rho_[ch] = {names[k]: s["fold_rho"] for k, s in scores.items()}
        self.candidates_[ch] = {k: dict(s, gate=gate[k]) for k, s in scores.items()}
        self.eligible_[ch] = sorted(names[k] for k in ok)
        self.refused_by_constant_[ch] = sorted(names[k] for k in refused)
        self.chosen_[ch] = best[:2]
        self.shrink_[ch] = best[2]
        self.scale_[ch] = scores[best]["scale"]
        self.band_[ch] = band_of(scores[best], self.band_rule)
        self.band_alt_[ch] = {r: band_of(scores[best], r) for r in BAND_RULES if r != self.band_rule}
        self.band_ols_[ch] = band_of(scores[base], self.band_rule)

    def _choose(self, scores: dict, gate: dict, novelty: bool) -> tuple[list, tuple, list]:
        """(the eligible candidates, the chosen one, the models refused by the constant) among ``scores``. Eligible:
        every gate against OLS (:meth:`eligible`) and, where the constant offset is a candidate, a mean log-gain over
        OLS above the constant's and, where the constant is the plain fallback (its mean log-gain over OLS above 0), a
        win over it in a paired one-sided t-test over every fold at ``CONSTANT_GATE_LEVEL`` (:func:`constant_gate`:
        never a model the plainest baseline matches in validation). The eligible one of largest mean log-gain; else the
        plain fallback: the constant where its mean log-gain over OLS is above 0, else OLS."""
        base, const = ("ols", "", 1.0), ("constant", "", 1.0)
        r_ols = scores[base]["ranking"]
        floor = scores[const]["gain"] if const in scores else -np.inf
        ok = [k for k in scores if k[0] != "ols" and self.eligible(scores[k], gate[k], k[2], r_ols, novelty)
              and (k == const or scores[k]["gain"] > floor)]
        # where the constant is the plain fallback, a model must beat it, not only OLS (the plainest baseline wins ties)
        refused = [k for k in ok if k != const and floor > 0 and not constant_gate(scores[k], scores[const])[0]]
        ok = [k for k in ok if k not in refused]
        if ok:
            return ok, max(ok, key=lambda k: scores[k]["gain"]), refused
        return ok, const if floor > 0 else base, refused

    def _deploy(self, log, fams, chans, fit, cache, sets) -> None:
        """``deployed_``: the chosen candidates (family, hyper-parameter, weight, scale, band) refitted on every row."""
        sub = getattr(self, "subset_modeller_", None)   # the validated fit's sensor selection stays the one reported
        rows = np.arange(len(log.time_s))
        self.deployed_, _ = self._final_models(log, fams, chans, rows, cache, input_matrix(log, rows, cache), sets)
        self.deployed_.meta["validated_on_rows"] = int(len(fit))
        if sub is not None:
            self.subset_modeller_ = sub

    def _selection_text(self, sets) -> str:
        folds, hfolds, nfolds, h, _ = sets
        return (f"rolling-origin CV on the fitting part: the candidate (a family blended with OLS, weight "
                f"{', '.join(f'{w:g}' for w in self.shrink_weights)}) of largest mean log-gain over OLS among those "
                f"below OLS on {len(folds)} ranking folds that beat OLS by > {self.gate_se:g} SE on {len(hfolds)} "
                f"horizon folds (horizon {h:.3g}) and on {len(nfolds)} novelty folds (the most novel blocks of the "
                f"fitting part, held out), with no fold worse than OLS by more than {self.max_fold_loss:g}×"
                + ("" if not any("constant" in v for v in self.cv_.values()) else " and a mean log-gain above the constant offset's (the fit "
                   f"part's mean) and, where the constant is the plain fallback, a win over it in a paired one-sided t-test "
                   f"at {CONSTANT_GATE_LEVEL:.0%} over every fold; else the constant where its mean log-gain over OLS is "
                   "above 0")
                + "; else OLS")

    def _meta(self, log, fit, U, sets) -> dict:
        """The model file's ``fitted_on``: the rows, the selection in words and the inputs' distance reference."""
        nfolds = sets[2]
        mu, W = whitener(U)
        dval = [mahalanobis(U[va], *whitener(U[tr])) for tr, va in nfolds]
        d_fit = mahalanobis(U, mu, W)
        return {"log": str(log.path), "fit_rows": int(len(fit)), "fit_until_s": float(log.time_s[fit[-1]]),
                "selection": self._selection_text(sets),
                "novelty": {"inputs": _inputs(log, fit), "mean": mu.tolist(),
                            "whiten": W.tolist(),
                            "validated_distance": float(np.quantile(np.concatenate(dval), 0.9)) if dval else None,
                            "fit_distance_q99": float(np.quantile(d_fit, 0.99)),
                            "range_distance": float(np.quantile(d_fit, RANGE_QUANTILE))}}

    def _final_models(self, log, fams, chans, fit, cache, U, sets):
        """The chosen candidates of every channel (``chosen_``, ``shrink_``, ``scale_``, ``band_``) and the OLS
        baseline fitted on the rows ``fit`` (the fitting part, or with ``deploy`` every row): (model, baseline)."""
        final = {}
        for fam in fams:
            need = [ch for ch in chans if self.chosen_[ch][0] == fam.name or fam.name == "ols"]
            if need:
                final[fam.name] = fam.fit(log, need, fit, cache)
                if fam.name == "subset_lag":
                    self.subset_modeller_ = fam.last_modeller_
        meta = self._meta(log, fit, U, sets)
        chosen = {ch: self._channel_fit(log, ch, final, fit, cache) for ch in chans}
        base = {ch: ChannelFit("ols", "", *final["ols"][ch][""], self.band_ols_[ch][0],
                               band_gamma=self.band_ols_[ch][1]) for ch in chans}
        return DriftModel(chosen, meta), DriftModel(base, meta)

    def _channel_fit(self, log, ch, final, fit, cache) -> ChannelFit:
        """Channel ``ch``'s chosen candidate, blended toward OLS, from the families' fits ``final``."""
        f, hy = self.chosen_[ch]
        w = self.shrink_[ch]
        own = final[f][ch][hy][0]
        feats, a, b = blend_with_ols(final[f][ch][hy], final["ols"][ch][""], w)
        sc = self.scale_[ch]
        nv = feature_novelty(own, feature_matrix(log, own, cache)[fit]) \
            if self.feature_distance and f != "ols" and own else None
        return ChannelFit(f, hy if w == 1.0 else f"{hy}{';' if hy else ''}shrink_to_ols_w={w:g}", feats, a,
                          np.asarray(b), self.band_[ch][0], base=final["ols"][ch][""] if np.isfinite(sc) else None,
                          shrink_scale=float(sc), novelty=nv, band_gamma=self.band_[ch][1])

    def predict(self, log: DriftLog) -> dict:
        """The chosen model's drift {channel: (n,)} μm at every row of ``log`` (causal: row i uses rows ≤ i)."""
        self._check_fitted("model_")
        return self.model_.predict(log)

    def family_best(self, ch) -> dict:
        """Best CV RMS of each family for channel ``ch`` (over its hyper-parameters): {family: (candidate, RMS)}."""
        out = {}
        for k, v in self.cv_[ch].items():
            f = k.split("[")[0].split("~")[0]
            if f not in out or v < out[f][1]:
                out[f] = (k, v)
        return out

    def report(self, log: DriftLog) -> dict:
        """Per channel: chosen candidate, CV scores per family, held-out before / volcomp / OLS, band coverage."""
        fit, hold = self.split(log)
        pred = self.model_.predict(log, self.cache_)
        base = self.baseline_.predict(log, self.cache_)
        bands = self.model_.band_um(log, self.cache_)
        rhos = self.model_.channel_rho(log, self.cache_)
        out = {}
        for ch in self.model_.channels:
            d = log.disp_um[ch][hold]
            a = d - pred[ch][hold]
            name = candidate_name(*self.chosen_[ch], self.shrink_[ch])
            out[ch] = self._validation_report(ch, name) | {
                "rms_before_um": _rms(d), "rms_after_um": _rms(a), "rms_ols_um": _rms(d - base[ch][hold]),
                "rms_constant_um": _rms(d - np.mean(log.disp_um[ch][fit])),
                "max_before_um": float(np.abs(d).max()), "max_after_um": float(np.abs(a).max()),
                "distance_scale": self.scale_[ch] if np.isfinite(self.scale_[ch]) else None,
                "heldout_rho_median": None if rhos[ch] is None else float(np.median(rhos[ch][hold]))} | \
                self._band_report(ch, a, hold, bands[ch], rhos[ch])
        return out

    def _validation_report(self, ch, name) -> dict:
        """Channel ``ch``'s chosen candidate ``name`` and its figures on the folds of the fitting part."""
        return {"model": name, "family": self.chosen_[ch][0], "shrink_weight": self.shrink_[ch],
                "cv_rms_um": {k: v[1] for k, v in self.family_best(ch).items()},
                "cv_rms_ols_um": self.cv_[ch]["ols"],
                "cv_ranking_rms_um": self.cv_[ch][name],
                "cv_horizon_rms_um": self.cv_horizon_[ch][name],
                "cv_horizon_rms_ols_um": self.cv_horizon_[ch]["ols"],
                "cv_novelty_rms_um": self.cv_novelty_[ch][name],
                "cv_novelty_rms_ols_um": self.cv_novelty_[ch]["ols"],
                "best_ranked": min(self.cv_[ch], key=self.cv_[ch].get),
                "refused_by_gate": sorted(k for k, v in self.cv_[ch].items()
                                          if v < self.cv_[ch]["ols"] and not self.gate_[ch][k][0]),
                "worst_fold_ratio": self.worst_fold_[ch][name],
                "refused_by_constant": self.refused_by_constant_[ch],
                "selection_score": self.score_[ch][name]} | ({
                    "cv_rms_constant_um": self.cv_[ch]["constant"], "cv_horizon_rms_constant_um":
                    self.cv_horizon_[ch]["constant"], "cv_novelty_rms_constant_um": self.cv_novelty_[ch]["constant"],
                    "selection_score_constant": self.score_[ch]["constant"]} if "constant" in self.cv_[ch] else {})

    def _band_report(self, ch, resid, hold, band, rho) -> dict:
        """The band of channel ``ch`` on the held-out rows ``hold`` (``resid`` (len(hold),) μm, ``band`` (n,) μm of
        the model's rule, ``rho`` (n,) or None), and every other band rule's on the same rows."""
        q = self.model_.channels[ch].band95_um
        gamma = self.model_.channels[ch].band_gamma
        grow = np.ones(len(band)) if rho is None else np.maximum(1.0, rho)
        alt = {r: qg[0] * grow ** qg[1] for r, qg in self.band_alt_[ch].items()}
        alt_rule = next(iter(alt))
        cover = {r: float(np.mean(np.abs(resid) <= v[hold])) for r, v in alt.items()}
        half = {r: float(np.median(v[hold])) for r, v in alt.items()}
        mine = {"q_um": q, "gamma": gamma, "coverage": float(np.mean(np.abs(resid) <= band[hold])),
                "halfwidth_median_um": float(np.median(band[hold]))}
        return {"band95_um": q, "band_coverage_heldout": mine["coverage"],
                "band_halfwidth_heldout_median_um": mine["halfwidth_median_um"], "band_gamma": gamma,
                "band_rule": self.band_rule, "band_alt_rule": alt_rule,
                "band_alt95_um": self.band_alt_[ch][alt_rule][0],
                "band_alt_coverage_heldout": cover[alt_rule],
                "band_alt_halfwidth_heldout_median_um": half[alt_rule],
                # every band rule on the same held-out part: {rule: {q_um, gamma, coverage, halfwidth_median_um}}
                "bands_heldout": {self.band_rule: mine} | {
                    r: {"q_um": self.band_alt_[ch][r][0], "gamma": self.band_alt_[ch][r][1], "coverage": cover[r],
                        "halfwidth_median_um": half[r]} for r in alt}}


class _FoldRho:
    """ρ of every validation row from its fold's training rows (the per-sample shrinkage and the band grow with it):
    the raw inputs' ρ, and with ``feature_distance`` the larger of it and the ρ of the candidate's OWN features (its
    filtered inputs / states, its selected sensors): a model extrapolates in what it computes from."""

    def __init__(self, sel, log, cache, U, fold_sets):
        self.sel, self.log, self.cache, self.fold_sets = sel, log, cache, fold_sets
        self.raw = [[relative_distance(U[tr], U[va]) for tr, va in fs] for fs in fold_sets]
        self.memo = {}

    def of(self, which: int, featlists) -> list:
        """Per fold of set ``which`` (0 ranking, 1 horizon, 2 novelty), ρ (n_i,) of a candidate with ``featlists``."""
        out = []
        for i, ((tr, va), feats) in enumerate(zip(self.fold_sets[which], featlists)):
            r = self.raw[which][i]
            if self.sel.feature_distance and feats:
                key = (which, i, tuple(f.key for f in feats))
                if key not in self.memo:
                    F = feature_matrix(self.log, feats, self.cache)
                    self.memo[key] = np.maximum(r, relative_distance(F[tr], F[va]))
                r = self.memo[key]
            out.append(r)
        return out
