"""Causal drift models chosen on held-out time, and their controller form (``volcomp.drift_model`` v1).

A model is ``intercept_um + Σ_j coef_j · f_j(t)``; a feature ``f_j`` is one logged input (``temp_<sensor>_c``
or ``speed_rpm``), optionally raised to a power, through the exact first-order lag ``tau·dy/dt = v − y`` of a
zero-order-held input (uneven sampling handled), delayed by ``delay_s``; the prediction at ``t`` uses samples
at or before ``t`` only. Formulas: ``docs/explanation/drift.md``. The code lives by responsibility
(:mod:`.drift_features`, :mod:`.drift_candidates`, :mod:`.drift_constrained`, :mod:`.drift_validation`,
:mod:`.drift_selection`, :mod:`.drift_model_file`); this module gathers the names callers import."""
from __future__ import annotations

from .drift_features import (  # noqa: F401
    COV_FLOOR, Feature, RANGE_QUANTILE, distance_weight, feature_matrix, feature_novelty, first_order,
    fit_ols, fit_ridge_path, input_matrix, input_values, mahalanobis, relative_distance,
    whitener)
from .drift_constrained import (  # noqa: F401
    GradientFamily, GreyBoxFamily, GreyBoxModesFamily, ModesFamily, StableLagOLSFamily, StableOLSFamily,
    ThermalNNFamily)
from .drift_candidates import (  # noqa: F401
    ConstantFamily, OLSFamily, RidgeBankFamily, default_families, measured_families)
from .drift_model_file import (  # noqa: F401
    ChannelFit, DriftModel, SCHEMA, SCHEMA_VERSION, input_novelty)
from .drift_validation import (  # noqa: F401
    BAND_GAMMAS, BAND_QUANTILE, BAND_SUBSET_SE, MAX_FOLD_LOSS, MIN_GAIN, SHRINK_WEIGHTS, band_of,
    blend_statistics, blend_with_ols, candidate_name, conformal_quantile, constant_gate, horizon_folds,
    horizon_gate, novelty_folds, rho_power_band, rolling_origin_folds)
from .drift_selection import (  # noqa: F401
    DriftSelector)
