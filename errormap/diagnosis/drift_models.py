"""Causal drift models chosen on held-out time, and their controller form (``volcomp.drift_model`` v1).

Every model here is a linear combination of **features**; a feature is one logged input
(``temp_<sensor>_c`` or ``speed_rpm``), optionally raised to a power, passed through a first-order
lag of time constant ``tau_s`` and delayed by ``delay_s``::

    v[k] = u[k] ** power
    y[0] = v[0];  y[k] = y[k-1] + (1 − exp(−(t[k] − t[k-1]) / tau_s)) · (v[k] − y[k-1])   (tau_s = 0: y = v)
    f(t) = y(t − delay_s)   (linear interpolation between logged samples; before the first: y[0])

    prediction_um(t) = intercept_um + Σ_j coef_j · f_j(t)

The filter is the exact response of ``tau·dy/dt = v − y`` to an input that holds ``v[k]`` over
``(t[k-1], t[k]]`` (each sample acts at once, no added half-step delay), so uneven sampling is handled; the prediction at ``t`` uses samples at or before ``t`` only (causal).

The code lives by responsibility: :mod:`.drift_features` (features, fits, distance), :mod:`.drift_candidates` and
:mod:`.drift_constrained` (the families), :mod:`.drift_validation` (folds, blends, gates, bands),
:mod:`.drift_selection` (:class:`DriftSelector`) and :mod:`.drift_model_file` (:class:`DriftModel` and its file).
This module gathers their names, the ones callers import from here.
"""
from __future__ import annotations

from .drift_features import (  # noqa: F401
    COV_FLOOR, Feature, RANGE_QUANTILE, SPEED_SCALE_RPM, TAU_BANK_S, _Family, _inputs, _standardise, distance_weight,
    feature_matrix, feature_novelty, first_order, fit_ols, fit_pls_path, fit_ridge_path, input_matrix, input_values,
    mahalanobis, novelty_rho, relative_distance, whitener)
from .drift_constrained import (  # noqa: F401
    GREYBOX_LAMBDA, GREYBOX_MODE_COUNTS, GREYBOX_TAUS_S, GradientFamily, GreyBoxFamily, GreyBoxModesFamily,
    MODE_COUNTS, ModesFamily, NN_LAMBDAS, STABLE_FREQ, STABLE_LAG_MAX_INPUTS, STABLE_MAX_INPUTS, STABLE_SUBSAMPLES,
    StableLagOLSFamily, StableOLSFamily, ThermalNNFamily, _forward_bic, _mode_inputs, _mode_maps, _oriented_nnls,
    _stable_selection)
from .drift_candidates import (  # noqa: F401
    ConstantFamily, OLSFamily, PLSBankFamily, PLSTowardOLSFamily, PLS_MAX_COMPONENTS, RIDGE_LAMBDAS,
    RIDGE_OLS_LAMBDAS, RidgeBankFamily, RidgeTowardOLSFamily, SUBSET_SEARCH_STEP_S, SubsetLagFamily, TAU_GRID_S,
    TRANSFER_LAMBDA, TransferFamily, _ols_in_bank, default_families, measured_families)
from .drift_model_file import (  # noqa: F401
    ChannelFit, DriftModel, OTHER_FORMATS, SCHEMA, SCHEMA_VERSION, _channel_from_json, _kind_of, _refuse_withdrawn,
    input_novelty, input_rho)
from .drift_validation import (  # noqa: F401
    BAND_GAMMAS, BAND_QUANTILE, BAND_RULE, BAND_RULES, BAND_SUBSET_SE, CONSTANT_GATE_LEVEL, FEATURE_DISTANCE, GATE_SE,
    MAX_FOLD_LOSS, MIN_GAIN, RANKING_FOLD_LOSS, SHRINK_SCALES, SHRINK_WEIGHTS, _blend_residuals, _merge, _rms, band_of,
    blend_statistics, blend_with_ols, candidate_name, conformal_quantile, constant_gate, cv_residuals, horizon_folds,
    horizon_gate,
    novelty_folds, rho_power_band, rolling_origin_folds)
from .drift_selection import (  # noqa: F401
    DriftSelector, _FoldRho)
