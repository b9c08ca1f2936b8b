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
