"""The closed loop on any machine-tool chain: checks → held-out measured residual, update, effects.

Check measurements (``docs/reference/file-formats.md``): the machine's axis columns and ``dx_um, dy_um,
dz_um`` (optional ``time_s``, ``temp_c``, ``dir_<w>``, ``seq``); the first ``fit_fraction`` by ``seq`` fit,
the rest is held out. Stages judged by the MEASURED held-out residual: identified, updated
(:func:`update_elements`, the identification's covariance as prior), updated + effects (a forward search
over :data:`errormap.chain_truth.EFFECT_KINDS`; :data:`HELD_OUT_Z`, :func:`joint_threshold`,
:data:`ROUNDS`), beside ``baseline_ols_update`` and ``baseline_ols_linear``; the last stage is kept unless a
plainer one is better by more than :data:`FALLBACK_Z`. Noise floor ``√3·σ``. Method and reasons:
``docs/explanation/closed-loop.md``."""
from __future__ import annotations

import numpy as np

from ..machine_tool import MachineTool
from ..chain_elements import ChainElementSet
from ..stats import residual_stats
# the loop's parts, also read from here by callers (chain_checks, chain_update, chain_effects)
from .chain_checks import (  # noqa: F401
    ERROR_COLUMNS, MAX_ERROR_UM, MIN_CHECKS, STROKE_TOL, ChainChecks, condition_columns, load_chain_checks)
from .chain_update import (  # noqa: F401
    OLS_RCOND, SIGMA_ITERATIONS, SMOOTH_GRID, ChainUpdate, apply_parameters, check_smoothing, fitting_gcv,
    ols_update, parameter_matrix, parameter_values, second_differences, spline_basis, update_elements)
from .chain_effects import (  # noqa: F401
    HARMONIC_ORDERS, HELD_OUT_Z, JOINT_Z, PERIOD_GRID_MM, PERIOD_REFINE, REF_TEMP_C, REPRESENTED_TOL, SHAPE_NYQUIST,
    SPAN_RANK_TOL, SPAN_ROWS_PER_PARAM, EffectTerm, SlotSpan, _paired_z, effect_candidates, effect_columns,
    effect_search, full_parameters, joint_threshold, representable_terms, shape_band, sweep_shift)

FALLBACK_Z = 2.0
"""A plainer stage replaces the final one when it lowers the held-out squared residual norm, paired per
point, by more than 2 standard errors (one-sided p ≈ 0.02)."""
ROUNDS = 2
"""Update/search rounds: from the second on the update is made jointly with the effects found (so that it
does not take an effect up), then the search goes on ."""


# -- the loop -----------------------------------------------------------------------------------
class _Run:
    """One run of the loop: the machine, the identified elements, the checks and their blocked split, the identified
    model's residual ``r0`` (n, 3) μm, and what the stages record (``stages`` statistics, ``models`` element sets,
    ``resid_of`` residuals (n, 3), ``baseline_resid`` the plain baselines' residuals)."""

    def __init__(self, machine, elements, checks, fit_idx, hold_idx, r0, smoothing):
        self.machine, self.elements, self.checks = machine, elements, checks
        self.fit_idx, self.hold_idx, self.r0, self.smoothing = fit_idx, hold_idx, r0, smoothing
        self.stages = {"identified": self.stats(r0)}
        self.models = {"identified": elements}
        self.resid_of = {"identified": r0}
        self.baseline_resid = {}   # the plain baselines' residuals (n, 3): the kept model must not lose to them

    def resid(self, el):
        from ..chain_field import ChainField
        return self.checks.measured_um - ChainField(self.machine, el).predict(self.checks.axes)

    def stats(self, r):
        return {"held_out": residual_stats(r[self.hold_idx], ERROR_COLUMNS),
                "fitting": residual_stats(r[self.fit_idx], ERROR_COLUMNS)}


def closed_loop_chain(machine: MachineTool, elements: ChainElementSet, checks: ChainChecks, cov=None,
                      fit_fraction: float = 0.6, noise_um: float | None = None, effects: bool = True,
                      max_effects: int = 4, smoothing="gcv", units: str = "check", base=None) -> dict:
    """Run the stages (module doc) and return the summary dict (``stages`` with held-out/fitting
    statistics, ``kept_stage``, ``noise_floor_um``, ``effects``) and, under ``"_models"``, the element
    sets of the stages (not JSON). Before any estimate, the deviations are checked against the identified
    model's prediction and the stated noise (``noise_um``, else the file's): another unit or another axis
    order is refused (:func:`errormap.diagnosis.plausibility.check_deviations`; ``units="as-written"`` skips
    the unit gate). ``base``: None, or a field (``predict(axes) -> (n, 3)`` μm: a trained network) that stands for
    the identified model (``elements`` then only place the element slots' stations, e.g.
    :meth:`ChainElementSet.zeros`); it has no covariance to update (``cov`` must be None): identified + effects."""
    if base is not None and cov is not None:
        raise ValueError("a base field has no element covariance to update: give cov=None with base")
    if not 0 < fit_fraction < 1:
        raise ValueError(f"Expected 0 < fit_fraction < 1, got {fit_fraction}")
    check_smoothing(smoothing)
    n = len(checks)
    n_fit = int(round(fit_fraction * n))
    if n_fit < 5 or n - n_fit < 5:
        raise ValueError(f"Expected at least 5 fitting and 5 held-out checks, got {n_fit} and {n - n_fit}")
    fit_idx, hold_idx = np.arange(n_fit), np.arange(n_fit, n)
    from ..chain_field import ChainField
    from .plausibility import check_deviations, noise_record, ols_linear_baseline
    stated = noise_um if noise_um is not None else checks.stated_noise_um
    pred0 = np.asarray((base if base is not None else ChainField(machine, elements)).predict(checks.axes), float)
    check_deviations(checks.path, checks.measured_um, pred0, rows=checks.rows, noise_um=stated, units=units)
    run = _Run(machine, elements, checks, fit_idx, hold_idx, checks.measured_um - pred0, smoothing)
    stages, resid_of = run.stages, run.resid_of
    upd, sigma, prior = None, None, None
    if cov is not None:
        upd, prior = _update_stage(run, cov)
        sigma = upd.sigma_um
    # the plainest baseline: the residual linear in the axes
    run.baseline_resid["baseline_ols_linear"] = ols_linear_baseline(checks.axes, run.r0, fit_idx)
    stages["baseline_ols_linear"] = run.stats(run.baseline_resid["baseline_ols_linear"])
    last = "updated" if "updated" in run.models else "identified"
    accepted, rejected, dropped, absorbed = [], [], [], []
    if effects:
        accepted, rejected, dropped, absorbed, sigma = _effects_stage(run, cov, upd, last, max_effects, sigma)
    final = "plus_effects" if effects else last
    kept, why = final, "kept: no plainer stage is better on the held-out checks by more than "\
                       f"{FALLBACK_Z} paired standard errors"
    for plain in ("identified", "updated"):
        if plain in resid_of and plain != final:
            z = _paired_z(resid_of[kept][hold_idx], resid_of[plain][hold_idx])
            if z > FALLBACK_Z:
                kept, why = plain, f"fell back to {plain}: better on the held-out checks by paired z = {z:.2f}"
    sig = noise_um if noise_um is not None else sigma
    refit = None
    if kept in ("updated", "plus_effects") and last == "updated":
        refit = _kept_refit(run, cov, ols_kept=prior is not None and prior["kept"] != "update with the smoothness prior")
    kept_name = {"plus_effects": "updated_plus_effects" if last == "updated" else "identified_plus_effects"}.get(kept, kept)
    held = stages[kept_name]["held_out"]["rms_um"]
    noise = noise_record(noise_um, sigma, held, stated)
    if noise["noise_sigma_estimated_um"] is None:   # no update estimated σ: the kept model's held-out residual does
        noise.update(noise_sigma_estimated_um=float(np.sqrt(np.mean(resid_of[kept][hold_idx] ** 2))),
                     noise_sigma_estimated_how="the kept model's held-out residual per coordinate (no update ran)")
    baselines = {k: {"held_out_rms_um": stages[k]["held_out"]["rms_um"],
                     "paired_z_over_kept": _paired_z(resid_of[kept][hold_idx], r[hold_idx])}
                 for k, r in run.baseline_resid.items()}
    models = run.models
    return {"machine": machine.name, "machine_sha256": machine.sha256, "n_checks": n, "n_fit": n_fit, "n_held_out": n - n_fit,
            "split": f"blocked by seq: first {fit_fraction:g} fit, the rest held out",
            "stages": stages, "kept_stage": kept_name, "kept_why": why, "update_prior": prior,
            "effects": [t.to_dict() for t in accepted], "effects_rejected": rejected, "effects_absorbed": absorbed,
            "effects_dropped_in_joint_fit": dropped,
            "noise_sigma_um": sig, "baselines_vs_kept": baselines, "held_out_rms_um": held,
            **noise,
            "_models": {"elements": models.get("updated_plus_effects" if kept == "plus_effects" else kept,
                                               models.get("updated", elements)), "terms": accepted,
                        "refit": refit}}


def _update_stage(run: _Run, cov) -> tuple:
    """The ``updated`` stage (the element update with the sweep covariance ``cov`` as its prior, or the
    unregularised update where its GCV on the fitting checks is lower) and its baselines, recorded in ``run`` →
    ``(update, prior record)``."""
    elements, checks, fit_idx, r0, smoothing = run.elements, run.checks, run.fit_idx, run.r0, run.smoothing
    stages = run.stages
    slot_names, stations, C = cov
    upd = update_elements(elements, slot_names, stations, C, checks.axes[fit_idx], r0[fit_idx], smoothing=smoothing,
                          with_plain=True)
    plain = upd.plain if upd.plain is not None else update_elements(
        elements, slot_names, stations, C, checks.axes[fit_idx], r0[fit_idx], smoothing=0.0)
    stages["baseline_update_sweep_prior"] = run.stats(run.resid(plain.elements_))   # the update without the prior
    stages["baseline_update_sweep_prior"]["gcv"] = plain.gcv_value
    ols_el, ols_gcv = None, float("inf")
    try:
        ols_el, ols_gcv = ols_update(elements, slot_names, stations, checks.axes[fit_idx], r0[fit_idx], return_gcv=True)
        stages["baseline_ols_update"] = run.stats(run.resid(ols_el))
        run.baseline_resid["baseline_ols_update"] = run.resid(ols_el)
        stages["baseline_ols_update"]["gcv"] = ols_gcv
    except ValueError as exc:  # the unregularised fit left the machine's range: reported, not used
        stages["baseline_ols_update"] = {"failed": str(exc)}
    upd_gcv = fitting_gcv(elements, upd.elements_, checks.axes[fit_idx], r0[fit_idx], upd.dof)
    prior = {"smoothing_weight": upd.smoothing, "chosen_by": "GCV on the fitting checks" if smoothing == "gcv"
             else "given", "gcv": upd.gcv_value, "gcv_table": upd.gcv, "gcv_chain": upd_gcv,
             "gcv_ols_update": ols_gcv if np.isfinite(ols_gcv) else None,
             "gcv_compared": "n·RSS/(n − dof)² of the chain's own residual on the fitting checks",
             "kept": "update with the smoothness prior"}
    if ols_el is not None and ols_gcv < upd_gcv:   # never keep a prior that loses to the plain fit
        upd = ChainUpdate(ols_el, upd.sigma_um, float(len(slot_names)), None, 0.0, upd.gcv, ols_gcv)
        prior["kept"] = "the unregularised least-squares update (lower GCV on the fitting checks)"
    r1 = run.resid(upd.elements_)
    stages["updated"] = run.stats(r1)
    stages["updated"]["dof"] = upd.dof
    stages["updated"]["smoothing_weight"] = upd.smoothing
    run.models["updated"], run.resid_of["updated"] = upd.elements_, r1
    return upd, prior


def _effects_stage(run: _Run, cov, upd, last: str, max_effects: int, sigma) -> tuple:
    """The ``plus_effects`` stage on the ``last`` stage (module doc, 3.): the effect search, the joint refit with the
    update and its drops, the search again (:data:`ROUNDS`), recorded in ``run`` → ``(accepted terms, rejected,
    dropped, absorbed, σ)``."""
    machine, elements, checks, fit_idx, hold_idx = run.machine, run.elements, run.checks, run.fit_idx, run.hold_idx
    models, resid_of, n = run.models, run.resid_of, len(run.checks)
    terms = representable_terms(machine, elements, checks.axes, checks.conditions)
    absorbed = [{**t, "note": f"{t['kind']} {t['axis']} on {t['element']}: the element slots represent this term "
                 f"over the checks (rank {t['rank_slots']} with and without it; "
                 f"{t['outside_fraction']:.1e} of it outside their span), so the element update absorbs it: "
                 "it is in the updated elements, not a missed effect"} for t in terms if t["represented"]]
    exclude = [(t["kind"], tuple(t["axis"].split("*"))) for t in absorbed]
    response = None
    if last == "updated" and upd.gain is not None:   # what the update leaves of an effect's columns
        slot_names, stations, _ = cov
        Mall = parameter_matrix(machine, elements, checks.axes, slot_names, stations).reshape(-1, len(slot_names))
        Mfit = Mall.reshape(n, 3, -1)[fit_idx].reshape(-1, len(slot_names))
        gain = upd.gain

        def response(Cols, fit_only=False):
            Cf = Cols[fit_idx].reshape(-1, Cols.shape[2])
            if fit_only:
                return (Cf - Mfit @ (gain @ Cf)).reshape(len(fit_idx), 3, -1)
            return Cols - (Mall @ (gain @ Cf)).reshape(Cols.shape)
    bands = shape_band(elements)
    accepted, rejected, r2 = effect_search(machine, checks, resid_of[last], fit_idx, hold_idx, max_effects,
                                           exclude=exclude, response=response, bands=bands)
    dropped = []
    pending, rounds_left = bool(accepted), ROUNDS - 1
    while pending and last == "updated":  # joint fit, the weak terms dropped, then the search goes on (once)
        u, r_joint = _joint_fit(run, cov, accepted)
        weak = [t for t in accepted if t.joint_chi2 <= joint_threshold(t)]
        if weak:
            dropped += [{"kind": t.kind, "axis": "*".join(t.axes), "shape": t.shape, "held_out_gain_z": t.gain_z,
                         "joint_chi2": t.joint_chi2, "joint_chi2_threshold": joint_threshold(t)} for t in weak]
            accepted = [t for t in accepted if t not in weak]
            u, r_joint = _joint_fit(run, cov, accepted) if accepted else (None, resid_of["updated"])
        if u is not None:
            models["joint"], sigma = u.elements_, u.sigma_um
        else:
            models.pop("joint", None)
            sigma = upd.sigma_um
        r2 = r_joint
        if rounds_left == 0:
            break
        rounds_left -= 1
        more, rejected, r_more = effect_search(
            machine, checks, r_joint, fit_idx, hold_idx, max_effects - len(accepted),
            exclude=exclude + [(t.kind, t.axes) for t in accepted] + [(d["kind"], tuple(d["axis"].split("*"))) for d in dropped],
            response=response, bands=bands)
        accepted += more
        pending = bool(more)
        if not more:
            r2 = r_more
    if accepted and "joint" in models:
        models["updated_plus_effects"] = models["joint"]
    run.stages["updated_plus_effects" if last == "updated" else "identified_plus_effects"] = run.stats(r2)
    resid_of["plus_effects"] = r2
    return accepted, rejected, dropped, absorbed, sigma


def _joint_fit(run: _Run, cov, terms) -> tuple:
    """The update made jointly with ``terms`` (their columns free) on the fitting checks; each term's coefficients and
    Wald χ² set → ``(update, residual (n, 3) μm)``."""
    machine, elements, checks, fit_idx = run.machine, run.elements, run.checks, run.fit_idx
    slot_names, stations, C = cov
    E = np.concatenate([effect_columns(machine, t.kind, t.axes, checks.axes, checks.conditions, t.shape or None)[0]
                        for t in terms], axis=2)
    shift = np.concatenate([sweep_shift(machine, elements, t, slot_names, stations, C) for t in terms], axis=1)
    u = update_elements(elements, slot_names, stations, C, checks.axes[fit_idx], run.r0[fit_idx], extra=E[fit_idx],
                        extra_shift=shift, smoothing=run.smoothing)
    k = 0
    for t in terms:
        c = t.coefficients.size
        t.coefficients, k = u.extra_coef[k:k + c], k + c
        cv = u.extra_cov[k - c:k, k - c:k]
        t.joint_chi2 = float(t.coefficients @ np.linalg.pinv(cv) @ t.coefficients)
    return u, run.resid(u.elements_) - np.einsum("nic,c->ni", E, u.extra_coef)


def _kept_refit(run: _Run, cov, ols_kept: bool):
    """The kept stage's re-estimation (``_models["refit"]``): ``refit(terms, offset_um, idx)`` re-estimates the kept
    stage's update on the checks ``idx`` with ``offset_um`` (n, 3) μm taken off the identified model's residual
    (what another part of the model explains: the learned residual's backfitting,
    :func:`compensation.hybrid.learned_stage`) — jointly with ``terms`` (copies, their coefficients re-estimated)
    when there are any, else the update the loop kept (with the smoothness prior, its weight by the loop's rule, or
    the unregularised one when the loop kept that, ``ols_kept``). → ``(elements, terms, residual at every check
    (n, 3))``."""
    machine, elements, checks, smoothing = run.machine, run.elements, run.checks, run.smoothing
    slot_names, stations, C = cov

    def refit(terms, offset_um, idx):
        import copy
        idx = np.asarray(idx)
        t = run.r0 - np.asarray(offset_um, dtype=float)
        if not terms:
            if ols_kept:
                el = ols_update(elements, slot_names, stations, checks.axes[idx], t[idx])
            else:
                el = update_elements(elements, slot_names, stations, C, checks.axes[idx], t[idx],
                                     smoothing=smoothing).elements_
            return el, [], run.resid(el)
        E = np.concatenate([effect_columns(machine, q.kind, q.axes, checks.axes, checks.conditions, q.shape or None)[0]
                            for q in terms], axis=2)
        shift = np.concatenate([sweep_shift(machine, elements, q, slot_names, stations, C) for q in terms], axis=1)
        u = update_elements(elements, slot_names, stations, C, checks.axes[idx], t[idx], extra=E[idx],
                            extra_shift=shift, smoothing=smoothing)
        out, k = [], 0
        for q in terms:
            c = q.coefficients.size
            q = copy.copy(q)
            q.coefficients, k = np.array(u.extra_coef[k:k + c]), k + c
            out.append(q)
        return u.elements_, out, run.resid(u.elements_) - np.einsum("nic,c->ni", E, u.extra_coef)
    return refit


def ship_on_all_checks(summary: dict, models: dict, terms: list, learned: bool = False,
                       reestimate: bool = True) -> tuple:
    """What the loop ships (``volcomp diagnose`` and :class:`errormap.ClosedLoop` alike): once the stage, its
    effect terms (and a learned part) were chosen on the fitting/held-out split, the kept stage re-estimated on
    ALL ``summary["n_checks"]`` checks (``models["refit"]`` of :func:`closed_loop_chain`); the held-out figures
    stay the validated ones and ``summary["refit_on_all_checks"]`` says what was re-estimated. ``terms``: the
    kept stage's effect terms; ``learned``: a learned part was kept (and re-estimated with the base by its
    backfitting); ``reestimate`` False: the base was already re-estimated there (the record only). Without a
    re-estimation (the kept stage is the identified one: nothing was fitted to the checks) ``models["elements"]``
    and ``terms`` unchanged, no record. → ``(elements, terms)``."""
    refit, n = models.get("refit"), int(summary["n_checks"])
    if refit is None:
        return models["elements"], list(terms)
    el, ts = models["elements"], list(terms)
    if reestimate:
        el, ts, _ = refit(ts, np.zeros((n, 3)), np.arange(n))
    summary["refit_on_all_checks"] = {
        "checks": n, "stage": summary.get("base_stage", summary["kept_stage"]),
        "note": ("the stages, effect terms and learned family were chosen on the fitting/held-out split (the "
                 "held-out figures above are those); the shipped elements, terms"
                 f"{' and learned residual' if learned else ''} were then re-estimated on all {n} checks "
                 "(model.json and updated_elements.json; diagnosis.json's effect coefficients are the loop's)")}
    return el, ts
