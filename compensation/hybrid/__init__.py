"""The hybrid error field: the physical model plus a residual learned from the check measurements.

After the closed loop (:func:`errormap.diagnosis.chain_loop.closed_loop_chain`), the residual left at the
checks is learned by a :class:`training.residual.ResidualRegressor` over the machine's axes
(:func:`learned_stage`: blocked CV, held-out gate :data:`KEEP_Z`, condition terms kept or replaced by
:func:`keeps_condition_terms`), tapered to zero outside the checks' box (:class:`LearnedResidual`);
:class:`HybridField` = base field + learned part, with the base's Jacobian capabilities and the total band
:meth:`HybridField.band_std`. Rules and measurements: docs/reference/learned-stage.md. The package:
:mod:`.inputs` (features and frames), :mod:`.field` (:class:`LearnedResidual`, :class:`HybridField`, bands,
map), :mod:`.stage` (:func:`learned_stage` and its rules)."""
from __future__ import annotations

from .inputs import (LINEAR_SMOOTHERS, TAPER_FRAC, CV_BLOCKS, MIN_FIT_CHECKS, MIN_HELD_CHECKS, MAP_N,
                     LEARNED_FAMILIES, CANDIDATE_FAMILIES, axis_stem, axes_feature_names,
                     axes_input_groups, linear_columns, INPUT_SETS, work_columns_ok, work_feature_names,
                     work_radius, LEARNED_INPUTS, OUTPUT_FRAMES, LEARNED_FRAMES, frame_key,
                     split_frame_key, to_frame, input_set_features, input_set_groups,
                     axis_features, work_features, check_input_set, input_features)  # noqa: F401
from .field import (FORMAT, LearnedResidual, HybridField, total_band_std, learned_map)  # noqa: F401
from .stage import (KEEP_Z, TERM_KEEP_Z, TERM_CONSISTENT_Z, keeps_condition_terms, REFIT_MODES, BACKFIT_ROUNDS,
                    condition_term_test, learned_stage)  # noqa: F401
