"""Arm (serial-chain) calibration (``volcomp calibrate POSES --machine ur5``): stages, validation, document.

The poses are split into fit and held-out poses (``--check`` file, else a hold-out fraction); on the
fit poses: the nominal chain, the plain baselines (nominal + fitted base/tool; plain least-squares
calibration; a plain GP on the plain calibration's residual), volcomp's geometric stage
(:class:`errormap.estimators.ArmCalibration`) and the learned residual stage
(:class:`training.arm_residual.ArmResidualRegressor`). Every figure is the *measured residual*
(measured − model) on the held-out poses; every DECISION is made by k-fold CV inside the fit poses
(the held-out poses only report): the geometric slot set (``dh``, ``dh+compliance``,
``dh+compliance+harmonic``, :mod:`errormap.arm_calibration`), the plain LSQ fit instead where it did
better in that CV (never return a model that loses to the plain baseline), the learned stage on
top only if the ResidualRegressor's CV says it beats the geometric stage, and then among whole pipelines
(volcomp's choice, the plain LSQ fit, the plain GP on its residual, and ``stacked``: volcomp's choice and
the plain GP blended with the weight their out-of-fold predictions choose) the lowest CV mean error.
The calibration document (:func:`model_document`; ``model.json``'s ``calibration`` section,
:mod:`compensation.calibration_models`); the run end to end, with its report:
:mod:`compensation.app.workflows.arm_run`.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from errormap.arm_calibration import GeometricResult, fit_base_tool, fit_plain_lsq
from errormap.arm_poses import temperature_summary
from ...calibration_models import STACKED
from ...fields import ARM_FORMAT

Z95 = 1.959963984540054
FRAMES = {"poses, stages": "the measuring instrument's (tracker's) frame of the calibration poses",
          "compensate targets, predict x_mm and dx_mm": "the robot's base frame (after the base.* transform)",
          "base.*": "instrument (world) → robot base transform (tx ty tz rz ry rx); `volcomp register` refits it for a "
                    "new session",
          "link*.*": "deviations of the link parameters from the machine file's table (mm, rad); a link slot the base "
                     "or tool slots account for (link 1's offsets along and about its axis) is held at 0",
          "tool.*": "tool point in the last link's frame (mm)",
          "compliance.*, harmonic.*, table.*": "joint-angle slots (rad per unit of their input)",
          "learned": "residual (mm) in the instrument frame of the calibration poses, a function of the joints",
          "plain_geometric": "the plain least-squares calibration (same frames as geometric: base.* instrument → robot "
                             "base, link*.* deviations, tool.* last link's frame); `volcomp register` falls back to it",
          "registration": "written by `volcomp register`: the session's frame, held-out figures in that session's "
                          "instrument frame",
          "across_sessions": "poses with a session column: every session moved into the frame of the reference "
                             "session (the most poses; frames[].base its registered base); held-out figures each in its "
                             "own session's frame"}
"""Which frame every block of ``model.json`` is in (its key ``frames``)."""
DECIDE_MAX_POSES = 500
"""Every decision of :func:`calibrate_arm` (CVs, learned stages, band) runs on at most this many fit poses (a seeded
subset, :func:`decision_subset`); the geometric fits use all. Its cost grows with the GPs' n³ and the CV's refits;
docs/decisions/020-benchmark-notebook.md ("Arm calibration at scale") measures the held-out error with and without the subset."""


@dataclass
class ArmCalibrationSettings:
    """``check``: held-out pose file (else ``holdout`` of the poses by ``seed``); ``learned``: run the
    learned stage; ``k_folds``/``n_restarts``: its CV folds and marginal-likelihood restarts."""

    poses: str
    check: str | None = None
    holdout: float = 0.2
    seed: int = 0
    learned: bool = True
    k_folds: int = 5
    n_restarts: int = 1
    noise_um: float | None = None
    """The tracker's stated noise σ per coordinate (μm) the verdict judges the held-out residual against (None: the
    poses' ``sigma_mm`` column where they have one, else not judged)."""


def errors_mm(poses, pred) -> np.ndarray:
    """Position error norm per pose, mm, shape (n,)."""
    return np.linalg.norm(poses.xyz_mm - pred, axis=1)


def stage_row(name, e, what) -> dict:
    return {"name": name, "mean_mm": float(e.mean()), "rms_mm": float(np.sqrt(np.mean(e ** 2))),
            "max_mm": float(e.max()), "what": what}


def stage_name(model: str) -> str:
    """Stage name of a geometric slot set: ``"geometric"`` (DH) or ``"geometric+compliance"`` …"""
    return "geometric" + model[len("dh"):]


PIPELINE_RULES = ("lowest", "one-se")
"""How the CV of whole pipelines picks (:func:`choose_pipeline`)."""
PLAIN_GP = "plain GP on plain LSQ residual"


def choose_pipeline(pipeline_cv: dict, volcomp: str, rule: str = "lowest") -> str:
    """The pipeline returned from the inner CV of whole pipelines (``pipeline_cv``: name → ``{"cv_mean_mm",
    "errors_mm" (n,)}``, ``volcomp`` the name of volcomp's own choice). ``"lowest"``: the lowest CV mean error,
    ties to volcomp's choice. ``"one-se"``: the lowest CV mean error, but a pipeline other than the plain GP
    (where it is a candidate: the baseline the product must not lose to) only if its paired per-pose gain
    over the plain GP exceeds one standard error of that gain — else the plain GP."""
    if rule not in PIPELINE_RULES:
        raise ValueError(f"pipeline rule must be one of {PIPELINE_RULES}, got {rule!r}")
    best = min(pipeline_cv, key=lambda k: (pipeline_cv[k]["cv_mean_mm"], k != volcomp))
    if rule == "lowest" or PLAIN_GP not in pipeline_cv or best == PLAIN_GP:
        return best
    gain = pipeline_cv[PLAIN_GP]["errors_mm"] - pipeline_cv[best]["errors_mm"]
    se = gain.std(ddof=1) / np.sqrt(len(gain)) if len(gain) > 1 else np.inf
    return best if gain.mean() > se else PLAIN_GP


def decision_subset(n: int, max_poses: int | None, seed) -> np.ndarray | None:
    """Indices (sorted, (m,) with m = ``max_poses``) of the fit poses every DECISION is made on when there are more
    than ``max_poses`` of them (drawn without replacement from ``seed``), else None (all of them)."""
    if max_poses is None or n <= max_poses:
        return None
    return np.sort(np.random.default_rng(seed).choice(n, int(max_poses), replace=False))


@dataclass
class _Kept:
    """The stage ``calibrate_arm`` keeps so far: its name, geometric model and learner (or None), why, notes, and
    the held-out residual of its geometric part and its 95 % band coverage on the check poses."""
    name: str
    geo: object
    learner: object
    why: str
    notes: list
    r_geo: np.ndarray
    coverage_check: float


def calibrate_arm(chain, fit, check, learned=True, k_folds=5, n_restarts=1, seed=0, log=None, groups=None,
                  pipeline_rule: str = "lowest", learner_families=None, band_blocked: bool = True,
                  decide_max: int | None = None) -> dict:
    """Every stage and baseline on ``fit``, judged on ``check``. Every decision (the geometric slot
    set, plain LSQ instead, the learned stage kept and its GP kernel) is made by k-fold CV INSIDE ``fit``
    (blocked by ``groups`` (n_fit,) labels where given: whole blocks per fold); ``check`` only reports.
    ``learner_families``: the GP families the learned stage cross-validates (default
    :data:`training.arm_residual.KERNEL_FAMILIES`). ``band_blocked``: scale the kept stage's band so that it holds 95 %
    on blocked inner CVs of the fit poses (:func:`kept_band_calibration`; False: the band as its stage's rule gives it,
    ``band_calibration`` None). ``decide_max`` (default :data:`DECIDE_MAX_POSES`): with more fit poses than this,
    every CV, the learned stages and the band calibration run on a seeded subset of this many
    (:func:`decision_subset`); the geometric stages and the plain baselines are fitted on every fit pose. Returns the
    document's core: ``stages``, ``baselines``, ``kept_stage``, the models, ``decision_poses``."""
    from training.arm_residual import KERNEL_FAMILIES
    from training.residual import MAX_TRAIN_POINTS
    learner_families = KERNEL_FAMILIES if learner_families is None else tuple(learner_families)
    s_geo, s_learn, s_plain, s_dec = np.random.SeedSequence(seed).spawn(4)
    decide_max = DECIDE_MAX_POSES if decide_max is None else int(decide_max)
    if not 2 * k_folds <= decide_max <= MAX_TRAIN_POINTS:     # before any work: the GPs train on at most this many
        raise ValueError(f"decide_max must be in [{2 * k_folds}, {MAX_TRAIN_POINTS}], got {decide_max}")
    t0 = time.perf_counter()
    say = (lambda m: print(f"calibrate: [{time.perf_counter() - t0:6.1f} s] {m}", file=log or sys.stderr, flush=True))
    dec_idx = decision_subset(len(fit), decide_max, s_dec)
    dfit, dgroups = fit, groups
    if dec_idx is not None:
        dfit, dgroups = fit.subset(dec_idx), None if groups is None else np.asarray(groups)[dec_idx]
        say(f"{len(fit)} fit poses: every decision (CV, learned stages, band) on a seeded subset of {len(dfit)}, "
            f"the geometric fits on all {len(fit)}")
    g = _geometric_stages(chain, fit, dfit, dgroups, check, k_folds, s_geo, say)
    model, cvd, plain = g["model"], g["cvd"], g["plain"]
    kept = _Kept(stage_name(model), g["fits"][model], None, "", [], None, 0.0)
    cvk = "blocked " if groups is not None else ""
    kept.why = (f"{kept.name} had the lowest {k_folds}-fold {cvk}CV mean error inside the fit poses "
                f"({cvd[model]:.4f} mm; " + ", ".join(f"{k} {v:.4f}" for k, v in cvd.items() if k != model) + ")")
    if dec_idx is not None:
        kept.why += f" (every CV on a seeded {len(dfit)} of the {len(fit)} fit poses)"
    if cvd["plain"] < cvd[model]:
        kept.geo = plain
        plain.cv_table = g["cv"]
        kept.notes.append(f"the plain least-squares calibration beat volcomp's {kept.name} in CV inside the fit poses "
                          f"({cvd['plain']:.6f} vs {cvd[model]:.6f} mm mean): it is the geometric stage returned")
        kept.why += "; the plain LSQ fit did better in that CV and is returned as it"
        kept.name = "plain geometric LSQ"
    stages, baselines = g["stages"], g["baselines"]
    geo_volcomp = kept.geo
    kept.r_geo = check.xyz_mm - kept.geo.predict(check.q)
    band_geo = np.sqrt(kept.geo.band_std_mm(check.q) ** 2 + kept.geo.sigma_mm ** 2)
    kept.coverage_check = float(np.mean(np.abs(kept.r_geo) <= Z95 * band_geo))
    learner, plain_gp, pipeline_cv, pipe_volcomp, stacked, stacked_summary = None, None, None, None, None, None
    pipes = {kept.name: ("plain" if kept.geo is plain else model, None)}
    if learned:
        learner, plain_gp = _learned_stages(chain, dfit, dgroups, check, kept, plain, stages, baselines, k_folds,
                                            n_restarts, s_learn, s_plain, learner_families, say)
        pipe_volcomp = kept.name   # volcomp's own choice, before the pipelines are compared
        pipes, pipeline_cv, stacked, stacked_summary = _pipeline_choice(
            chain, dfit, dgroups, check, kept, plain, plain_gp, model, g["fold_fits"], stages, k_folds, s_geo,
            pipeline_rule, say)
    else:
        kept.why += "; learned stage not run"
        if band_blocked:   # its interleaved CV (the geometric CV's fold fits, reused) caps the band factor below
            from training.arm_residual import cv_pipelines
            pipeline_cv = cv_pipelines(chain, dfit, pipes, k_folds, s_geo, dgroups, g["fold_fits"])
    band_cal = None
    if band_blocked:
        band_cal = _calibrate_band(chain, dfit, check, kept, pipes, pipe_volcomp, pipeline_cv, k_folds, s_geo, say)
    if kept.name not in [r["name"] for r in stages]:     # a plain pipeline kept: it is a stage of the document too
        row = next(r for r in baselines if r["name"] == kept.name)
        stages.append({**row, "what": row["what"] + " (kept: it did better in the CV inside the fit poses)"})
    return {"stages": stages, "baselines": baselines, "kept_stage": kept.name, "kept_why": kept.why,
            "notes": kept.notes, "geometric_model": kept.geo, "kept_learner": kept.learner,
            "volcomp_geometric_model": geo_volcomp, "geometric_stage": stage_name(model),
            "volcomp_geometric": g["fits"]["dh"], "geometric_fits": g["fits"], "learner": learner,
            "base_tool_model": g["base_tool"], "plain_model": plain, "plain_gp": plain_gp, "cv_geometric": g["cv"],
            "pipeline_cv_errors": pipeline_cv, "pipeline_volcomp": pipe_volcomp,
            "stacked": stacked, "stacked_summary": stacked_summary,
            "cv_pipelines": None if pipeline_cv is None else
            [{"pipeline": k, "cv_mean_mm": v["cv_mean_mm"], "cv_rms_mm": v["cv_rms_mm"]} for k, v in pipeline_cv.items()],
            "coverage95_heldout": kept.coverage_check, "band_calibration": band_cal,
            "decision_poses": len(dfit), "temperature_c": temperature_summary(fit)}


def _geometric_stages(chain, fit, dfit, dgroups, check, k_folds, s_geo, say) -> dict:
    """The plain baselines and every geometric slot set fitted on ``fit``, the slot set chosen by CV on ``dfit``;
    their stage and baseline rows on ``check``."""
    from errormap.arm_calibration import MODELS, choose_model, cv_models, fit_model
    nominal = errors_mm(check, chain.tool_point(check.q))
    base_tool = fit_base_tool(chain, fit)
    plain = fit_plain_lsq(chain, fit)
    say(f"plain baselines fitted; CV of the geometric slot sets {', '.join(MODELS)} and plain LSQ "
        f"({k_folds} folds, {len(dfit)} poses)")
    fold_fits = {}
    cv = cv_models(chain, dfit, MODELS, k_folds, s_geo, plain=True, groups=dgroups, fold_fits=fold_fits)
    cvd = {r["model"]: r["cv_mean_mm"] for r in cv}
    model = choose_model([r for r in cv if r["model"] != "plain"])
    say("geometric CV done; fitting every slot set on the fit poses")
    fits = {m: fit_model(chain, fit, m) for m in MODELS}
    for m in MODELS:
        fits[m].cv_table = cv
    e_bt, e_plain = (errors_mm(check, m.predict(check.q)) for m in (base_tool, plain))
    e_fit = {m: errors_mm(check, r.predict(check.q)) for m, r in fits.items()}
    say("CV mean error in the fit set: " + ", ".join(f"{r['model']} {r['cv_mean_mm']:.4f} mm" for r in cv)
        + f"; held-out: nominal {nominal.mean():.4f}, base/tool {e_bt.mean():.4f}, plain LSQ {e_plain.mean():.4f}, "
        + ", ".join(f"{stage_name(m)} {e.mean():.4f}" for m, e in e_fit.items()))
    stages = [stage_row("nominal", nominal, "nominal chain of the machine file")]
    for m in MODELS:
        stages.append(stage_row(stage_name(m), e_fit[m], f"{fits[m].method}: LM on the identifiable slots of {m} "
                                                         f"(CV mean in fit set {cvd[m]:.4f} mm)"))
    baselines = [stage_row("nominal + base/tool", e_bt, "nominal chain, fitted base frame and tool point"),
                 stage_row("plain geometric LSQ", e_plain, "unregularised least squares on every DH slot + base + "
                                                           "tool (Gauss–Newton, minimum-norm step: no motion along "
                                                           "combinations the poses do not determine)"),
                 stage_row("volcomp geometric", e_fit["dh"], "LM on the identifiable DH slots (unidentifiable fixed)")]
    return {"base_tool": base_tool, "plain": plain, "cv": cv, "cvd": cvd, "model": model, "fits": fits,
            "fold_fits": fold_fits, "stages": stages, "baselines": baselines}


def _learned_stages(chain, dfit, dgroups, check, kept: _Kept, plain, stages, baselines, k_folds, n_restarts, s_learn,
                    s_plain, learner_families, say) -> tuple:
    """The plain GP on the plain fit's residual (a baseline row) and volcomp's learned stage on the kept geometric
    stage's residual (a stage row; kept when its CV beats zero, ``kept`` updated) → ``(learner, plain_gp)``."""
    from training.arm_residual import ArmResidualRegressor
    from training.residual import FAMILY_NAMES
    say(f"learned stages: GP families cross-validated ({k_folds} folds) on {len(dfit)} poses' residuals")
    plain_gp = ArmResidualRegressor(chain, inputs="sincos", k_folds=k_folds, n_restarts=n_restarts, margin_se=0.0,
                                    seed=s_plain).fit(dfit.q, dfit.xyz_mm - plain.predict(dfit.q), dgroups)
    e_pgp = errors_mm(check, plain.predict(check.q) + plain_gp.predict(check.q))
    baselines.append(stage_row("plain GP on plain LSQ residual", e_pgp,
                               "Gaussian process on joint sin/cos, fitted to the plain calibration's residual"))
    learner = ArmResidualRegressor(chain, inputs="physics", k_folds=k_folds, n_restarts=n_restarts,
                                   seed=s_learn, families=learner_families).fit(
        dfit.q, dfit.xyz_mm - kept.geo.predict(dfit.q), dgroups)
    m, sd = learner.predict(check.q, return_std=True)
    r = kept.r_geo - m
    e_l = np.linalg.norm(r, axis=1)
    fam_cv = ", ".join(f"{f} {learner.cv_table_[f]['cv_rms']:.4f}" for f in learner_families)
    stages.append(stage_row("learned", e_l, f"{kept.name} + GP on joint sin/cos and gravity moments; kernel by "
                                            f"{learner.k_folds}-fold CV in the fit set (RMS mm: {fam_cv}; zero "
                                            f"{learner.cv_table_['zero']['cv_rms']:.4f}): "
                                            f"{FAMILY_NAMES.get(learner.chosen_, learner.chosen_)}"))
    say(f"learned stage (CV choice: {learner.chosen_}; CV RMS {fam_cv}): held-out mean {e_l.mean():.4f} mm; "
        f"plain GP {e_pgp.mean():.4f} mm")
    gp = learner.cv_table_.get(learner.chosen_, {})
    if learner.chosen_ != "none":
        kept.name, kept.learner = "learned", learner
        kept.coverage_check = float(np.mean(np.abs(r) <= Z95 * sd))
        kept.why += (f"; the learned stage ({learner.chosen_}, the lowest CV error of {', '.join(learner_families)}) "
                     f"beat it in {k_folds}-fold CV inside the fit poses (RMS "
                     f"{gp['cv_rms']:.4f} vs {learner.cv_table_['zero']['cv_rms']:.4f} mm, gain > "
                     f"{learner.margin_se:g} standard errors): kept")
    else:
        kept.why += (f"; the learned stage did not beat it by {learner.margin_se:g} standard errors in {k_folds}-fold "
                     f"CV inside the fit poses: not kept")
    return learner, plain_gp


def _pipeline_choice(chain, dfit, dgroups, check, kept: _Kept, plain, plain_gp, model, fold_fits, stages, k_folds,
                     s_geo, pipeline_rule, say) -> tuple:
    """Never lose to the plain pipelines in validation: volcomp's choice against the plain LSQ fit, the plain GP on
    its residual and the stacked blend of the two, all cross-validated as whole pipelines on the geometric CV's
    folds (``pipeline_rule``: :func:`choose_pipeline`); ``kept`` updated → ``(pipes, pipeline_cv, stacked,
    stacked_summary)``."""
    from errormap.arm_calibration import FOLD_LABELS
    from training.arm_residual import STACK_BAND_RULE, StackedResidual, cv_pipelines, stack_cv, stack_weight
    name = kept.name
    pipes = {name: ("plain" if kept.geo is plain else model, kept.learner),
             "plain geometric LSQ": ("plain", None), "plain GP on plain LSQ residual": ("plain", plain_gp)}
    say("CV of whole pipelines")
    pipeline_cv = cv_pipelines(chain, dfit, pipes, k_folds, s_geo, dgroups, fold_fits)
    # the stacked candidate: volcomp's choice and the plain GP blended, the weight fitted to their out-of-fold
    # predictions on these folds; its CV figure with each fold's weight chosen on the other folds (stack_cv)
    pa, pb = pipeline_cv[name], pipeline_cv[PLAIN_GP]
    w_stack = stack_weight(dfit.xyz_mm, pa["pred_mm"], pb["pred_mm"])[0]
    pipeline_cv[STACKED] = stack_cv(dfit.xyz_mm, pa["pred_mm"], pb["pred_mm"], fold_fits[FOLD_LABELS],
                                    pa["std_mm"], pb["std_mm"])
    stacked = StackedResidual(w_stack, (kept.geo, kept.learner), (plain, plain_gp), names=(name, PLAIN_GP))
    st_cv = pipeline_cv[STACKED]
    stacked_summary = {
        "weight": w_stack, "pipelines": [name, PLAIN_GP], "fold_weights": st_cv["fold_weights"],
        "cv_mean_mm": st_cv["cv_mean_mm"], "band_rule": STACK_BAND_RULE,
        "coverage95_cv": float(np.mean(np.abs(dfit.xyz_mm - st_cv["pred_mm"]) <= Z95 * st_cv["std_mm"]))}
    e_st = errors_mm(check, stacked.point(check.q))
    stages.append(stage_row(STACKED, e_st, f"{w_stack:.2f}·({name}) + {1 - w_stack:.2f}·({PLAIN_GP}), the weight "
                                           f"fitted to their {k_folds}-fold out-of-fold predictions inside the fit "
                                           f"poses (its CV mean {st_cv['cv_mean_mm']:.4f} mm with each fold's "
                                           f"weight chosen on the other folds)"))
    say(f"stacked: weight {w_stack:.2f} on {name} (per fold {', '.join(f'{x:.2f}' for x in st_cv['fold_weights'])}); "
        f"held-out mean {e_st.mean():.4f} mm")
    best = choose_pipeline(pipeline_cv, name, pipeline_rule)
    pcv_text = ", ".join(f"{k} {v['cv_mean_mm']:.4f}" for k, v in pipeline_cv.items())
    if best == STACKED:
        kept.why += (f"; in the CV of whole pipelines inside the fit poses ({pcv_text} mm mean) the stacked pipeline "
                     f"({w_stack:.2f}·{name} + {1 - w_stack:.2f}·{PLAIN_GP}) did best: kept")
        kept.name, kept.geo, kept.learner = STACKED, stacked.geometric, stacked
        sd = stacked.predict(check.q, return_std=True)[1]
        kept.coverage_check = float(np.mean(np.abs(check.xyz_mm - stacked.point(check.q)) <= Z95 * sd))
    elif best != name:
        kept.notes.append(f"the plain pipeline '{best}' beat volcomp's {name} in the pipeline CV inside the fit poses "
                          f"({pcv_text} mm mean): it is the stage returned")
        kept.why += f"; in the CV of whole pipelines inside the fit poses ({pcv_text} mm mean) {best} did better: kept"
        kept.name, kept.geo = best, plain
        kept.learner = plain_gp if best == "plain GP on plain LSQ residual" and plain_gp.chosen_ != "none" else None
        kept.r_geo = check.xyz_mm - plain.predict(check.q)
        if kept.learner is None:
            band_geo = np.sqrt(plain.band_std_mm(check.q) ** 2 + plain.sigma_mm ** 2)
            kept.coverage_check = float(np.mean(np.abs(kept.r_geo) <= Z95 * band_geo))
        else:
            m, sd = kept.learner.predict(check.q, return_std=True)
            kept.coverage_check = float(np.mean(np.abs(kept.r_geo - m) <= Z95 * sd))
    else:
        kept.why += f"; it was not worse than the plain pipelines in their CV inside the fit poses ({pcv_text} mm mean)"
    say(f"pipeline CV inside the fit poses: {pcv_text} mm mean; kept {kept.name}")
    return pipes, pipeline_cv, stacked, stacked_summary


def _calibrate_band(chain, dfit, check, kept: _Kept, pipes, pipe_volcomp, pipeline_cv, k_folds, s_geo, say) -> dict:
    """The kept stage's band factor on blocked inner CVs (:func:`kept_band_calibration`); ``kept.coverage_check``
    becomes the held-out coverage after it."""
    say("band calibration on blocked inner CVs")
    band_cal = kept_band_calibration(chain, dfit, check, kept.name, pipes, pipe_volcomp, pipeline_cv, kept.geo,
                                     kept.learner, k_folds, s_geo)
    kept.coverage_check = band_cal["coverage95_heldout_after"]
    cap = band_cal["cap_interleaved"]
    say(f"band calibrated on blocked inner CVs: factor {band_cal['factor']:.3f} (blocked "
        f"{band_cal['factor_blocked']:.3f}, interleaved 98 % cap {'none' if cap is None else format(cap, '.3f')}; "
        + ", ".join(f"{k} {v['factor']:.3f}, coverage {v['coverage95_before']:.3f} → {v['coverage95_after']:.3f}"
                    for k, v in band_cal["blockings"].items())
        + f"); held-out coverage {band_cal['coverage95_heldout_before']:.3f} → {kept.coverage_check:.3f}")
    return band_cal


def kept_band_calibration(chain, fit, check, kept, pipes, pipe_volcomp, pipeline_cv, geo_kept, kept_learner, k_folds,
                          seed) -> dict:
    """The kept stage's band factor from blocked inner CVs (:func:`training.arm_residual.blocked_band_scale` on the
    fit poses' :func:`errormap.arm_calibration.content_blocks`), with the 95 % coverage before / after it on the
    interleaved pipeline CV (where run) and on the held-out poses (``check``, which only reports)."""
    from errormap.arm_calibration import content_blocks
    from training.arm_residual import (BAND_COVERAGE_MAX_INTERLEAVED, band_factor, band_z, blocked_band_scale,
                                       coverage_before_after, pipeline_std_mm)
    beside = {BESIDE_PLAIN: ("plain", None)}
    if kept == STACKED:
        run, stacked = {pipe_volcomp: pipes[pipe_volcomp], PLAIN_GP: pipes[PLAIN_GP]}, (pipe_volcomp, PLAIN_GP)
    else:
        run, stacked = {kept: pipes[kept]}, None
        model, learner = pipes[kept]
        if learner is not None and learner.chosen_ != "none":
            beside[BESIDE_GEOMETRIC] = (model, None)
    icv = pipeline_cv.get(kept) if pipeline_cv is not None else None
    cap = None if icv is None else band_factor(fit.xyz_mm, icv["pred_mm"], icv["std_mm"], BAND_COVERAGE_MAX_INTERLEAVED)
    cal = blocked_band_scale(chain, fit, run, content_blocks(fit, k_folds), k_folds, seed, stacked=stacked, cap=cap,
                             beside=beside)
    c = cal["factor"]
    p = geo_kept.predict(check.q) + (0.0 if kept_learner is None else kept_learner.predict(check.q))
    cal["coverage95_heldout_before"], cal["coverage95_heldout_after"] = coverage_before_after(
        band_z(check.xyz_mm, p, pipeline_std_mm(geo_kept, kept_learner, check.q)), c)
    if icv is not None:
        cal["coverage95_cv_before"], cal["coverage95_cv_after"] = coverage_before_after(
            band_z(fit.xyz_mm, icv["pred_mm"], icv["std_mm"]), c)
    return cal


BESIDE_PLAIN = "plain geometric LSQ (same blocks)"
BESIDE_GEOMETRIC = "its geometric stage alone (same blocks)"
"""Pipelines cross-validated beside the kept stage on the blocked inner CVs (:func:`kept_band_calibration`)."""
TRANSFER_BLOCKING = "order"
"""The blocking that stands for another session (:func:`errormap.arm_calibration.content_blocks`: runs of consecutive
poses — a later stretch of the acquisition, measured after the others): a learned stage is carried to other
sessions (``volcomp register``) only if it beats its geometric stage alone there."""


def across_blocks(band_cal, kept: str, has_learner: bool) -> dict | None:
    """The kept stage beside the plain calibration (and, for a kept learned stage, beside its geometric stage alone) on
    the BLOCKED inner CVs, and whether the learned stage is carried to other sessions (``learned_carried``: None
    without a learned stage)."""
    if band_cal is None:
        return None
    rows = {k: {kept: v["cv_mean_mm"], **v.get("beside_cv_mean_mm", {})} for k, v in band_cal["blockings"].items()}
    out = {"blockings": rows, "residual_kind": "measured residual on the held-out blocks of the fit poses, mean mm",
           "learned_carried": None, "why": "no learned stage kept"}
    if has_learner and kept != STACKED:
        r = rows[TRANSFER_BLOCKING]
        out["learned_carried"] = bool(r[kept] < r[BESIDE_GEOMETRIC])
        out["why"] = (f"on the blocked CV by acquisition order (a later stretch held out, standing for another "
                      f"session) the learned stage {'beat' if out['learned_carried'] else 'did not beat'} its "
                      f"geometric stage alone ({r[kept]:.4f} vs {r[BESIDE_GEOMETRIC]:.4f} mm mean): "
                      + ("carried to other sessions by register" if out["learned_carried"] else
                         "it helps inside this session only and register does not carry it"))
    return out


def model_document(chain, core, s, n_fit, n_check) -> dict:
    geo: GeometricResult = core["geometric_model"]
    learner = core["learner"]
    doc = {"format": ARM_FORMAT, "machine": {"name": chain.name, "kind": chain.kind, "path": chain.path,
                                               "sha256": chain.sha256, "joints": chain.joint_columns},
           "residual_kind": "measured residual (measured − model) on the held-out poses, position norm, mm",
           "poses_file": str(s.poses), "check_file": s.check, "n_fit_poses": n_fit, "n_check_poses": n_check,
           "holdout": None if s.check else {"fraction": s.holdout, "seed": s.seed, "split": "random"},
           "stages": core["stages"], "baselines": core["baselines"], "kept_stage": core["kept_stage"],
           "kept_why": core["kept_why"], "notes": core["notes"],
           "geometric": geo.to_dict(), "learned": None, "plain_geometric": core["plain_model"].to_dict()}
    if learner is not None:
        kl = core.get("kept_learner")
        doc["learned"] = kl.to_dict() if kl is not None else None
        doc["learned_summary"] = {"chosen": learner.chosen_, "cv_table": learner.cv_table_,
                                  "coverage95_cv": learner.coverage_, "kept": core["kept_stage"] == "learned"}
    if core.get("stacked_summary") is not None:
        doc["stacked_summary"] = {**core["stacked_summary"], "kept": core["kept_stage"] == STACKED}
    if core["kept_stage"] == STACKED:        # both pipelines and the weight; "geometric" is its primary pipeline's
        doc["learned"] = None
        doc["stacked"] = core["kept_learner"].to_dict()
    doc["geometric_cv"] = core["cv_geometric"]
    doc["pipeline_cv"] = core.get("cv_pipelines")
    doc["coverage95_heldout"] = core["coverage95_heldout"]
    doc["decision_poses"] = core.get("decision_poses", n_fit)
    doc["frames"] = FRAMES
    doc["across_blocks"] = across_blocks(core.get("band_calibration"), core["kept_stage"],
                                         core.get("kept_learner") is not None)
    doc["temperature_c"] = core.get("temperature_c")
    doc["band_calibration"] = core.get("band_calibration")
    return doc


def held_out_verdict(core, check, sigma_mm=None) -> dict:
    """The verdict of a calibration (:func:`errormap.diagnosis.plausibility.arm_verdict`) on the held-out poses
    ``check``: the kept stage's and the plain LSQ calibration's residual vectors there, ``sigma_mm`` the stated
    tracker σ (scalar or per pose; None: not judged)."""
    from errormap.diagnosis.plausibility import arm_verdict
    geo, learner = core["geometric_model"], core["kept_learner"]
    pred = geo.predict(check.q) + (0.0 if learner is None else learner.predict(check.q))
    return arm_verdict(core["kept_stage"], check.xyz_mm - pred, check.xyz_mm - core["plain_model"].predict(check.q),
                       sigma_mm)


def stated_sigma_mm(s: ArmCalibrationSettings, check):
    """The stated tracker σ (mm) the verdict uses: ``--noise-um``, else the held-out poses' ``sigma_mm``, else None."""
    return s.noise_um / 1000.0 if s.noise_um is not None else check.sigma_mm
