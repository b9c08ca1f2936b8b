"""The learned stage after the closed loop: fitted on the fitting checks by blocked cross-validation, kept
only when it beats the stage before it on the held-out checks, the condition-term rule, backfitting with
the element update (module doc of :mod:`compensation.hybrid`)."""
from __future__ import annotations

import numpy as np

from errormap.field import machine_axes
from errormap.progress import Progress
from errormap.stats import residual_stats
from errormap.transforms import check_points
from training.residual import FAMILY_NAMES, Z95, ResidualRegressor

from .field import LearnedResidual, learned_map, total_band_std
from .inputs import (CV_BLOCKS, LEARNED_FAMILIES, LEARNED_FRAMES, LEARNED_INPUTS, LINEAR_SMOOTHERS, MIN_FIT_CHECKS,
                     MIN_HELD_CHECKS, OUTPUT_FRAMES, axes_feature_names, frame_key, input_features, input_set_features,
                     input_set_groups, linear_columns, split_frame_key, to_frame, work_radius)

KEEP_Z = 1.0
"""The learned stage is kept when it beats the stage before it on the held-out checks by more
than one paired standard error of the per-point squared-norm gain (the issue's rule)."""

TERM_KEEP_Z = 3.0
"""Condition terms of the stage before the learned one STAY only when their coefficient, estimated jointly
with a static learned field of the axes (:func:`condition_term_test`), is positive by more than 3 standard
errors (and :data:`TERM_CONSISTENT_Z`); otherwise the learned field replaces them. Why 3, and the
measurements: docs/reference/learned-stage.md and docs/decisions/008-learned-residual-measurements.md."""

TERM_CONSISTENT_Z = 3.0
"""Condition terms whose coefficient is significantly non-zero (:data:`TERM_KEEP_Z`) STAY only when it is
also consistent with 1, ``|γ̂ − 1| / se < 3``: a coefficient far from 1 says only part of a term varies with
its condition, the rest stood in for a static error. Applied per term when :func:`learned_stage` is given
each term's contribution (``condition_terms_um``). Why, and the development seeds' figures:
docs/reference/learned-stage.md, docs/explanation/closed-loop.md."""


def keeps_condition_terms(term: dict) -> bool:
    """The condition-term rule on :func:`condition_term_test`'s result: the terms stay only when their
    coefficient is positive by more than :data:`TERM_KEEP_Z` standard errors AND within
    :data:`TERM_CONSISTENT_Z` standard errors of 1; otherwise (or when no coefficient could be
    estimated) the static learned field replaces them."""
    if term.get("z") is None or term.get("coefficient_se") is None:
        return False
    return bool(term["z"] > TERM_KEEP_Z and abs(term["coefficient"] - 1.0) / term["coefficient_se"] < TERM_CONSISTENT_Z)


def _paired_z(r_before, r_after):
    g = np.sum(r_before**2, axis=1) - np.sum(r_after**2, axis=1)
    se = g.std(ddof=1) / np.sqrt(g.size) if g.size > 1 else np.inf
    return float(g.mean() / se) if se > 0 else 0.0, float(g.mean()), float(se)


REFIT_MODES = ("hyper", "weights")
"""How the kept learned stage is estimated on all checks before it is shipped: ``"hyper"`` —
the chosen family re-estimated (standardisation, hyper-parameters, weights) on all checks
(:meth:`training.residual.ResidualRegressor.refit`); ``"weights"`` — the fitting part's
hyper-parameters kept, the weights re-solved on all checks
(:meth:`~training.residual.ResidualRegressor.with_data`)."""

BACKFIT_ROUNDS = 3
"""Rounds of backfitting of the learned residual with the element update it sits on (:func:`learned_stage`
``base_update``): each round re-estimates the base stage on its residual minus the learned part's
prediction, then the learned part (family, input set and frame kept) on what that base leaves. Why:
docs/reference/learned-stage.md, docs/decisions/008-learned-residual-measurements.md."""


def _cv_key(reg) -> str:
    """The CV-table key of what ``reg`` predicts: its chosen family, or ``"zero"`` where it chose none."""
    return reg.chosen_ if reg.chosen_ != "none" else "zero"


def _fit_inputs(feats, r_um, fit_idx, groups, families, seed, columns, R=None, frames=("work",)):
    """Cross-validate every family on every input set and output frame (same blocked folds: they
    depend on ``groups`` only) → (key, its cross-validated :class:`ResidualRegressor`, table): the
    (input set, frame) candidate (:func:`frame_key`) whose chosen family has the lowest CV RMS (the
    first when every one declines); table per candidate: ``family`` chosen there, its ``cv_rms``,
    the ``zero`` CV RMS, per family ``cv_rms_by_family``, and ``output_frame``. ``R`` (n, 3, 3) the
    work frame's rotation at the checks (base <- work), needed for a frame other than ``work``. The key's
    regressor is not yet fitted on all its data: its ``fit_chosen`` does that where it is used (the fit draws on
    its own generator, so when it runs changes no bit)."""
    regs, table = {}, {}
    with Progress(len(feats) * len(frames) * len(families), "learned residual: blocked CV") as bar:
        for name, f in feats.items():
            for frame in frames:
                key = frame_key(name, frame)
                reg = ResidualRegressor(families=families, seed=seed, input_groups=input_set_groups(name, columns),
                                        progress=lambda fam, key=key: bar.update(1, f"{key} {fam}")).cross_validate(
                    f[fit_idx], to_frame(r_um, R, frame)[fit_idx], groups=groups)
                reg.progress = None                  # the bar's hook is not part of the fitted model
                regs[key] = reg
                table[key] = {"family": reg.chosen_,
                              "cv_rms": reg.cv_table_[_cv_key(reg)]["cv_rms"],
                              "cv_rms_zero": reg.cv_table_["zero"]["cv_rms"],
                              "cv_rms_by_family": {k: v["cv_rms"] for k, v in reg.cv_table_.items()},
                              "output_frame": frame}
    fitted = [n for n in regs if regs[n].chosen_ != "none"]
    best = min(fitted, key=lambda n: table[n]["cv_rms"]) if fitted else next(iter(regs))
    return best, regs[best], table


def condition_term_test(reg_static, f, r_static_um, c_um) -> dict:
    """Is the condition terms' dependence on their conditions in the data, once a static field of the axes
    takes the static part? ``reg_static``: the :class:`ResidualRegressor` fitted (its family chosen) on
    ``f`` (n, d), ``r_static_um`` (n, 3), the stage's residual WITHOUT its condition terms; ``c_um`` (n, 3)
    the terms' contribution at the same checks (``r_static − r_prev``), or (m, n, 3) each term's own
    contribution: then one coefficient per term, estimated jointly and the result's values are lists in the
    terms' order.

    The model ``r_static = g(axes) + γ·c + noise`` (``g`` the chosen family's Gaussian prior with its fitted
    hyper-parameters; a :data:`LINEAR_SMOOTHERS` family stands in for the ensemble) is estimated by
    generalised least squares (docs/reference/learned-stage.md). Returns {``coefficient``,
    ``coefficient_se``, ``z``, ``family``} (``z`` None and no family when no such family was
    cross-validated)."""
    fam = reg_static.chosen_
    reg = reg_static
    if fam not in LINEAR_SMOOTHERS:
        cands = [k for k in reg_static.cv_table_ if k in LINEAR_SMOOTHERS]
        if not cands:
            return {"coefficient": None, "coefficient_se": None, "z": None, "family": None}
        fam = min(cands, key=lambda k: reg_static.cv_table_[k]["cv_rms"])
        reg = reg_static.refit(f, r_static_um, family=fam)
    m_r = reg.predict(f)
    nv = reg.model_.noise_var() * reg.y_scale_ ** 2                      # (3,) μm²
    c_all = np.asarray(c_um, dtype=float)
    cs = c_all[None] if c_all.ndim == 2 else c_all                        # (m, n, 3): one per term
    vic = np.stack([(c - reg.with_data(f, c).predict(f)) / nv for c in cs])   # V⁻¹c_k, (m, n, 3)
    B = np.einsum("knj,lnj->kl", cs, vic)
    B = 0.5 * (B + B.T)
    a = np.einsum("knj,nj->k", cs, (r_static_um - m_r) / nv)
    if not (np.all(np.isfinite(B)) and np.all(np.linalg.eigvalsh(B) > 0)):
        return {"coefficient": None, "coefficient_se": None, "z": None, "family": fam}
    cov = np.linalg.inv(B)
    gamma, se = cov @ a, np.sqrt(np.diag(cov))
    if c_all.ndim == 2:
        return {"coefficient": float(gamma[0]), "coefficient_se": float(se[0]), "z": float(gamma[0] / se[0]),
                "family": fam}
    return {"coefficient": gamma.tolist(), "coefficient_se": se.tolist(), "z": (gamma / se).tolist(), "family": fam}


def _backfit(reg, f, make, axes, idx, base_update, replaced, R, frame, estimate, start):
    """:data:`BACKFIT_ROUNDS` rounds of backfitting (:func:`learned_stage`): per round the base is
    re-estimated on the checks ``idx`` with the learned part's prediction at every check taken off
    (``base_update(replaced, prediction (n, 3), idx)`` → the new base's residual (n, 3)), then the learned
    part is re-estimated on ``idx`` (``estimate(reg, X, Y)``, its family kept) on what that base leaves
    (turned into its output ``frame`` by ``R``). ``make(reg)`` → its :class:`LearnedResidual`; ``start``:
    the prediction of the first round (``make(reg)``'s at ``axes``, which the caller has). → ``(reg, base
    residual (n, 3), RMS change of the prediction at the checks per round (μm))``."""
    pred, steps, r_b = start, [], None
    for _ in range(BACKFIT_ROUNDS):
        r_b = np.asarray(base_update(replaced, pred, idx), dtype=float)
        reg = estimate(reg, f[idx], to_frame(r_b, R, frame)[idx])
        new = make(reg).predict(axes)
        steps.append(float(np.sqrt(np.mean(np.sum((new - pred) ** 2, axis=1)))))
        pred = new
    return reg, r_b, steps


def learned_stage(machine, r_prev_um, axes, fit_idx, hold_idx, seed=0, families=None, r_static_um=None,
                  covariance=None, refit_residual=None, refit_mode: str = "hyper", inputs=None,
                  condition_terms_um=None, frames=None, base_update=None):
    """Fit the learned residual on what the previous stage leaves at the checks and gate it (the rules:
    docs/reference/learned-stage.md).

    ``r_prev_um`` (n, 3): measured residual of the previous (kept) stage at every check; ``axes`` (n, k) in
    the machine's axis columns (:func:`errormap.field.machine_axes`); ``fit_idx`` / ``hold_idx``: the loop's
    fitting and held-out checks. ``r_static_um`` (n, 3) or None: the same stage's residual WITHOUT its
    condition terms; the terms stay only when :func:`keeps_condition_terms` says so on
    :func:`condition_term_test`, else the learned field of the axes replaces them. ``condition_terms_um``
    (m, n, 3) or None: each term's own contribution (the rule is then applied per term;
    ``stage["learned"]["replaced_condition_terms"]`` lists the replaced ones and ``refit_residual`` is
    called with that tuple instead of the bool). ``families`` / ``inputs`` / ``frames``: what is
    cross-validated (None: :data:`LEARNED_FAMILIES`, :data:`LEARNED_INPUTS`, :data:`LEARNED_FRAMES` at call
    time). ``covariance``: the previous stage's elements' band (a function of the axes giving the elements'
    standard deviation, :func:`total_band_std`) or None (with it, the held-out coverage of the TOTAL band,
    ``held_out_band95_cover_total``). ``refit_residual``: None or
    ``(replaces_condition_terms) -> (n, 3)``, the residual of the base re-estimated on all checks, on which
    the shipped learned part is estimated (``refit_mode``, :data:`REFIT_MODES`); selection, gate and
    held-out figures come before any refit. ``base_update``: None or ``(replaced, offset_um, idx) -> (n,
    3)``, the base re-estimated on the checks ``idx`` with ``offset_um`` taken off its residual: the two are
    then backfitted (:data:`BACKFIT_ROUNDS`) before the gate, the sequential hybrid's held-out figures
    reported beside (``learned["backfit"]``).

    Returns ``(learned or None, stage)``: ``learned`` when kept, and the stage's summary for diagnosis.json.
    """
    columns = tuple(machine_axes(machine))
    axes = check_points(axes, f"axes ({', '.join(columns)})", len(columns))
    lin = list(linear_columns(columns))
    families = tuple(LEARNED_FAMILIES if families is None else families)
    if refit_mode not in REFIT_MODES:
        raise ValueError(f"Expected refit_mode one of {REFIT_MODES}, got {refit_mode!r}")
    if len(fit_idx) < MIN_FIT_CHECKS or len(hold_idx) < MIN_HELD_CHECKS:
        return None, {"learned": {"family": "none", "kept": False, "cv_table": {}, "inputs": list(axes_feature_names(columns)),
                                  "cv": "not run", "held_out_gain_z": None, "held_out_band95_cover": None,
                                  "why": f"declined: fewer than {MIN_FIT_CHECKS} fitting or {MIN_HELD_CHECKS} held-out "
                                         f"checks ({len(fit_idx)}, {len(hold_idx)})"}}
    inputs = tuple(LEARNED_INPUTS if inputs is None else inputs)
    frames = tuple(LEARNED_FRAMES if frames is None else frames)
    if not frames or any(fr not in OUTPUT_FRAMES for fr in frames):
        raise ValueError(f"Expected output frames from {list(OUTPUT_FRAMES)}, got {list(frames)}")
    rotation = machine.work_rotation() if any(fr != "work" for fr in frames) else None
    if rotation is not None and not rotation.turns:   # a constant rotation: the frames learn the same
        frames, rotation = ("work",), None
    R_chk = None if rotation is None else rotation(axes)[0]
    rho0 = work_radius(machine) if any(i != "axes" for i in inputs) else None
    feats = {name: input_features(axes, name, rho0, columns)[0] for name in inputs}
    groups = np.repeat(np.arange(CV_BLOCKS), int(np.ceil(len(fit_idx) / CV_BLOCKS)))[:len(fit_idx)]
    fit_cands = (lambda r: _fit_inputs(feats, r, fit_idx, groups, families, seed, columns, R_chk, frames))
    key, reg, inputs_table = fit_cands(r_prev_um)
    r_base, replaces, alt, per_term, replaced_k = r_prev_um, False, None, None, ()
    if r_static_um is not None:
        r_static_um = np.asarray(r_static_um, dtype=float)
        key_s, reg_s, inputs_table_s = fit_cands(r_static_um)
        inp_s, frame_s = split_frame_key(key_s)
        e_with, e_static = reg.cv_sq_err_[_cv_key(reg)], reg_s.cv_sq_err_[_cv_key(reg_s)]
        z_s, g_s, se_s = _paired_z(np.sqrt(e_with)[:, None], np.sqrt(e_static)[:, None])
        term = {"coefficient": None, "coefficient_se": None, "z": None, "family": None}
        c_sum = r_static_um - np.asarray(r_prev_um, dtype=float)
        reg_s = reg_s.fit_chosen()   # the condition-term test reads its fitted model
        if reg_s.chosen_ != "none":
            term = condition_term_test(reg_s, feats[inp_s][fit_idx], to_frame(r_static_um, R_chk, frame_s)[fit_idx],
                                       to_frame(c_sum, R_chk, frame_s)[fit_idx])
        replaces = reg_s.chosen_ != "none" and term["z"] is not None and not keeps_condition_terms(term)
        per_term = None
        if condition_terms_um is not None:
            cts = np.asarray(condition_terms_um, dtype=float)
            if reg_s.chosen_ != "none":
                per_term = condition_term_test(reg_s, feats[inp_s][fit_idx], to_frame(r_static_um, R_chk, frame_s)[fit_idx],
                                               to_frame(cts, R_chk, frame_s)[:, fit_idx])
            if per_term is None or per_term["z"] is None:
                per_term = {k: [None] * len(cts) for k in ("coefficient", "coefficient_se", "z")}
            keep_k = [reg_s.chosen_ == "none" or keeps_condition_terms(
                {"coefficient": g, "coefficient_se": e, "z": z}) for g, e, z in
                zip(per_term["coefficient"], per_term["coefficient_se"], per_term["z"])]
            replaced_k = tuple(k for k, kk in enumerate(keep_k) if not kk)
            replaces = bool(replaced_k)
        alt = {"cv_rms_with_terms_um": float(np.sqrt(e_with.mean())), "cv_rms_static_um": float(np.sqrt(e_static.mean())),
               "cv_gain_z": z_s, "cv_gain_um2": g_s, "cv_gain_se_um2": se_s, "static_family": reg_s.chosen_,
               "static_input_set": inp_s, "static_output_frame": frame_s,
               "term_coefficient": term["coefficient"], "term_coefficient_se": term["coefficient_se"],
               "term_z": term["z"], "term_test_family": term["family"],
               "term_z_from_one": (None if term["z"] is None else abs(term["coefficient"] - 1.0) / term["coefficient_se"]),
               "replaces_condition_terms": bool(replaces),
               **({} if per_term is None else {"per_term_sum_mismatch_um": float(np.abs(cts.sum(axis=0) - c_sum).max()),
                                               "per_term": [
                   {"coefficient": g, "coefficient_se": e, "z": z,
                    "z_from_one": (None if z is None else abs(g - 1.0) / e), "replaced": k in replaced_k}
                   for k, (g, e, z) in enumerate(zip(per_term["coefficient"], per_term["coefficient_se"],
                                                     per_term["z"]))]}),
               "rule": (f"the condition terms (each, when per_term is given) stay only when their coefficient, estimated "
                        f"jointly with the static learned "
                        f"field of the axes (its family and hyper-parameters; generalised least squares on the fitting "
                        f"checks), is positive by more than {TERM_KEEP_Z} standard errors and within "
                        f"{TERM_CONSISTENT_Z} standard errors of 1; otherwise the learned field "
                        f"of the axes replaces them (cv_* are the blocked-CV errors of the two variants, for information)")}
        if replaces and per_term is not None and len(replaced_k) < len(cts):   # some terms stay
            r_part = np.asarray(r_prev_um, dtype=float) + cts[list(replaced_k)].sum(axis=0)
            key_p, reg_p, inputs_table_p = fit_cands(r_part)
            reg, r_base, key, inputs_table = reg_p, r_part, key_p, inputs_table_p
        elif replaces:
            reg, r_base, key, inputs_table = reg_s, r_static_um, key_s, inputs_table_s
    reg = reg.fit_chosen()   # the learned part's candidate: fitted on all the fitting checks (a no-op if it was)
    inp, frame = split_frame_key(key)
    f = feats[inp]
    lo = axes[:, lin].min(0)
    hi = axes[:, lin].max(0)
    rot = rotation if frame != "work" else None
    fit_lo, fit_hi = axes[fit_idx][:, lin].min(0), axes[fit_idx][:, lin].max(0)
    rep_arg = replaced_k if per_term is not None else bool(replaces)
    backfit = None
    if base_update is not None and reg.chosen_ != "none":
        make = (lambda rg: LearnedResidual(rg, fit_lo, fit_hi, inp, rho0, columns, frame, rot))
        pred_seq = make(reg).predict(axes)   # the sequential hybrid's learned part: also the first round's start
        r_seq = r_base - pred_seq
        reg, r_base, steps = _backfit(reg, f, make, axes, fit_idx, base_update, rep_arg, R_chk, frame,
                                      lambda rg, X, Y: rg.refit(X, Y, seed=seed), start=pred_seq)
        backfit = {"rounds": BACKFIT_ROUNDS, "step_rms_um": steps,
                   "held_out_sequential": residual_stats(r_seq[hold_idx], ("dx_um", "dy_um", "dz_um")),
                   "held_out_gain_z_sequential": _paired_z(r_prev_um[hold_idx], r_seq[hold_idx])[0],
                   "rule": (f"after the choice of family, input set and frame (blocked CV on the sequential residual), the "
                            f"base stage and the learned part were backfitted {BACKFIT_ROUNDS} rounds on the fitting "
                            "checks: the base re-estimated on its residual minus the learned part's prediction, the "
                            "learned part (hyper-parameters too) on what that base leaves; the held-out figures and "
                            "the gate are the backfitted hybrid's (its base re-estimated too); held_out_sequential: "
                            "the hybrid without backfitting, for comparison; step_rms_um: how far the learned part's "
                            "prediction at the checks moved in each round")}
    fitted = LearnedResidual(reg, fit_lo, fit_hi, inp, rho0, columns, frame, rot)
    pred, sd = fitted.predict(axes, return_std=True)
    r_new = r_base - pred
    z, gain, se = _paired_z(r_prev_um[hold_idx], r_new[hold_idx])
    noise = reg.noise_std_                                  # (3,) in the learned frame
    noise_var = fitted.work_var(axes, noise ** 2)           # (n, 3) in the work frame
    band = Z95 * np.sqrt(sd**2 + noise_var)
    cover = float(np.mean(np.abs(r_new[hold_idx]) <= band[hold_idx])) if reg.chosen_ != "none" else None
    cover_total = None
    if covariance is not None and reg.chosen_ != "none":
        sd_t = total_band_std(fitted, machine, axes[hold_idx], covariance)
        cover_total = float(np.mean(np.abs(r_new[hold_idx]) <= Z95 * np.sqrt(sd_t**2 + noise_var[hold_idx])))
    kept = reg.chosen_ != "none" and z > KEEP_Z
    if reg.chosen_ == "none":
        why = "declined: no family beat predicting zero in the blocked cross-validation on the fitting checks"
    elif kept:
        why = (f"kept: lowers the held-out squared residual by paired z = {z:.2f} (> {KEEP_Z}) over the stage before; "
               "it was then estimated on all checks before it was shipped (see 'shipped')")
    else:
        why = f"declined: on the held-out checks its paired z = {z:.2f} is not above {KEEP_Z}"
    stage = {"held_out": residual_stats(r_new[hold_idx], ("dx_um", "dy_um", "dz_um")),
             "fitting": residual_stats(r_new[fit_idx], ("dx_um", "dy_um", "dz_um")),
             "learned": {"family": reg.chosen_, "family_name": FAMILY_NAMES.get(reg.chosen_, reg.chosen_),
                         "families_compared": list(families),
                         "selection_rule": (f"each (input set, output frame, family) cross-validated on the same blocked folds; eligible if "
                                            f"its mean paired gain over zero exceeds {reg.margin_se} standard error(s); of "
                                            f"those the lowest CV RMS wins"),
                         "cv_table": reg.cv_table_, "inputs": list(input_set_features(inp, columns)), "input_set": inp,
                         "input_sets_compared": list(inputs), "inputs_table": inputs_table,
                         "output_frame": frame, "output_frames_compared": list(frames),
                         "cv": f"blocked: {CV_BLOCKS} contiguous seq blocks of the fitting checks",
                         "held_out_gain_um2": gain, "held_out_gain_se_um2": se, "held_out_gain_z": z,
                         "held_out_band95_cover": cover, "held_out_band95_cover_total": cover_total,
                         "noise_std_um": noise.tolist(),
                         "kept": bool(kept), "why": why,
                         "replaces_condition_terms": bool(kept and replaces)}}
    if backfit is not None:
        stage["learned"]["backfit"] = backfit
    if kept and replaces and per_term is not None:
        stage["learned"]["replaced_condition_terms"] = list(replaced_k)
    if alt is not None:
        stage["learned"]["condition_terms_vs_static"] = alt
    if kept and replaces:   # why, in the rule's words (condition_terms_vs_static holds the coefficients)
        which = ("the condition terms" if per_term is None else
                 f"condition term(s) {', '.join(str(k) for k in replaced_k)} of {len(cts)} (0-based)")
        stage["learned"]["why"] = why + (f"; it replaces {which}: their coefficient beside a static field of the axes "
                                         f"is not above {TERM_KEEP_Z:g} standard errors or not within "
                                         f"{TERM_CONSISTENT_Z:g} standard errors of 1, so they stood in for a static error")
    if not kept:
        return None, stage
    def estimate(rg, X, Y):
        return rg.refit(X, Y, seed=seed) if refit_mode == "hyper" else rg.with_data(X, Y)

    if refit_residual is not None and backfit is not None:   # backfitted again on all checks
        make_all = (lambda rg: LearnedResidual(rg, lo, hi, inp, rho0, columns, frame, rot))
        reg_all, _, steps_all = _backfit(reg, f, make_all, axes, np.arange(len(axes)), base_update, rep_arg, R_chk,
                                         frame, estimate, start=pred)
        stage["learned"]["backfit"]["shipped_step_rms_um"] = steps_all
        base_refit = True
    else:
        if refit_residual is not None:
            r_ship = np.asarray(refit_residual(rep_arg), dtype=float)
            base_refit = True
        else:
            r_ship, base_refit = r_base, False
        reg_all = estimate(reg, f, to_frame(r_ship, R_chk, frame))
    stage["learned"]["shipped"] = {
        "estimated_on_checks": int(len(axes)), "refit_mode": refit_mode, "base_refit_on_all_checks": base_refit,
        "note": ("the family, the keep decision and every held-out figure come from the fitting/held-out split; "
                 "the shipped learned part was then estimated on all "
                 f"{len(axes)} checks ({'hyper-parameters and weights' if refit_mode == 'hyper' else 'weights only, hyper-parameters of the fitting part'})"
                 + (", on the residual of the base model re-estimated on all checks" if base_refit else ""))}
    if refit_mode == "hyper" and reg_all.model_ is not None:
        stage["learned"]["noise_std_um"] = reg_all.noise_std_.tolist()
    learned = LearnedResidual(reg_all, lo, hi, inp, rho0, columns, frame, rot)
    stage["learned"]["map"] = learned_map(learned, machine, covariance=covariance)
    return learned, stage
