"""The hybrid error field: the physical model plus a residual learned from the check measurements.

After the closed loop (:func:`errormap.diagnosis.chain_loop.closed_loop_chain`) has updated the elements and
accepted the effect terms it can name, the measured residual that is left at the checks is
learned by a :class:`training.residual.ResidualRegressor` (:func:`learned_stage`):

* inputs: the machine's axes, from its axis list (:func:`errormap.field.machine_axes`): each linear
  axis its value, each rotary axis the cosine and sine of its angle, one input group (periodic in
  it) — on the grinder ``(x_mm, z_mm, cos a, sin a)`` (:func:`axes_feature_names`); the conditions (temperature, time, direction) are NOT inputs: on the checks they grow with
  ``seq``, so the later held-out block would be an extrapolation in them;
* fitted on the fitting checks (its own cross-validation uses contiguous ``seq`` blocks, i.e.
  BLOCKED in time), then KEPT only if it lowers the held-out squared residual norm, paired per
  point, by more than :data:`KEEP_Z` standard errors over the stage before it; when kept, its
  weights are re-solved on all checks with the hyper-parameters chosen on the fitting part;
* condition terms of the stage before it (temperature, time, direction) are REPLACED by the
  learned field of the axes unless their coefficient, estimated jointly with a static field of the
  axes, is positive by more than :data:`TERM_KEEP_Z` standard errors and within
  :data:`TERM_CONSISTENT_Z` standard errors of 1 (:func:`keeps_condition_terms`,
  :func:`condition_term_test`, :func:`learned_stage`, ``r_static_um``): on warm checks a thermal term can stand in for a
  static error and subtract it at the reference temperature;
* outside the checks: the regressor decays to zero within a few length scales, and
  :class:`LearnedResidual` multiplies it by a C¹ taper that is 1 inside the checks' box in the
  machine's linear axes (the grinder's X and Z) and falls to 0 within :data:`TAPER_FRAC` of the range outside it, so the learned part never
  extrapolates a fit; :attr:`HybridField.calibrated_volume` is the checks' box (within the
  base's), so the guards refuse commands outside it unless overridden;
* band: :meth:`HybridField.band_std` is the total predictive band, the learned part's
  (CV-calibrated) ⊕ the elements' ``diag(J Σ Jᵀ)``.

:class:`HybridField` = base field + learned part is an :class:`errormap.field.ErrorField` with the
base's Jacobian capabilities (value and Jacobian in closed form), so ``exact``, ``ga`` and
``batched-ga`` solve with it.

The package: :mod:`.inputs` (the features and frames), :mod:`.field` (:class:`LearnedResidual`,
:class:`HybridField`, bands, map), :mod:`.stage` (:func:`learned_stage` and its rules).
"""
from __future__ import annotations

from .inputs import (LINEAR_SMOOTHERS, TAPER_FRAC, CV_BLOCKS, MIN_FIT_CHECKS, MIN_HELD_CHECKS, MAP_N,
                     LEARNED_FAMILIES, CANDIDATE_FAMILIES, axis_stem, axes_feature_names,
                     axes_input_groups, linear_columns, FEATURE_NAMES, WORK_AXES, INPUT_SETS,
                     INPUT_GROUPS, LEARNED_INPUTS, OUTPUT_FRAMES, LEARNED_FRAMES, frame_key,
                     split_frame_key, to_frame, input_set_features, input_set_groups,
                     axis_features, work_features, check_input_set, input_features)  # noqa: F401
from .field import (FORMAT, LearnedResidual, HybridField, total_band_std, learned_map)  # noqa: F401
from .stage import (KEEP_Z, TERM_KEEP_Z, TERM_CONSISTENT_Z, keeps_condition_terms, REFIT_MODES, BACKFIT_ROUNDS,
                    condition_term_test, learned_stage)  # noqa: F401
