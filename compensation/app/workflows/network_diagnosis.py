"""``volcomp diagnose CHECKS --model NETWORK`` on a machine tool: the closed loop on a trained network.

A network (a folder or an MLflow run id; the grinder's or a chain's, read by
:func:`compensation.model_file.read_model`) has no element covariance, so the loop runs its identified
stage and the effect search (:func:`errormap.diagnosis.chain_loop.closed_loop_chain` with ``base``):
the held-out MEASURED residual before and after the terms it names. With ``--featurepoints``, terms of
the axes alone are carried into the network by retraining it on the feature points plus the terms
(:func:`retrain_learned`, the parent's architecture, LM, tracked as a child run), unless the feature
points' grid aliases them (:func:`grid_aliasing`): then they stay parametric terms beside the network.
Writes ``DIR/diagnosis.json`` (whole).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from errormap.featurepoints import FeaturePoints
from errormap.io import InputError, write_json
from errormap.stats import residual_stats


class TermsOnBase:
    """A base field (a trained network) plus the loop's effect terms on the machine tool ``machine``:
    ``predict(axes, **conditions)`` (n, 3) μm, ``terms_only(axes, **conditions)`` the terms' part,
    ``needs`` the conditions the terms need, ``base`` the network."""

    def __init__(self, machine, base, terms):
        from errormap.chain_elements import ChainElementSet
        from errormap.diagnosis.loop_model import ChainModelField
        self.machine, self.base, self.terms = machine, base, list(terms)
        self._terms = ChainModelField(machine, ChainElementSet.zeros(machine), self.terms)   # zero elements: terms only
        self.needs = self._terms.needs

    def terms_only(self, axes, **conditions) -> np.ndarray:
        f = self._terms.with_conditions(conditions) if conditions else self._terms
        return np.asarray(f.predict(np.atleast_2d(np.asarray(axes, float))), float)

    def predict(self, axes, **conditions) -> np.ndarray:
        axes = np.atleast_2d(np.asarray(axes, float))
        return np.asarray(self.base.predict(axes), float) + self.terms_only(axes, **conditions)


def augmented_feature_points(fp: FeaturePoints, corrected: TermsOnBase) -> FeaturePoints:
    """Feature points plus the loop's terms at the grid (terms of the axes alone only)."""
    if corrected.needs:
        raise ValueError(f"the selected terms need conditions {list(corrected.needs)}; a learned field "
                         "maps axes only, so it cannot carry them (keep them as parametric terms)")
    meta = dict(fp.meta)
    meta["diagnosis_terms"] = ";".join(f"{t.kind} {'*'.join(t.axes)} {t.element}" for t in corrected.terms)
    return FeaturePoints(fp.axes.copy(), fp.errors_um + corrected.terms_only(fp.axes), meta)


ALIAS_RATIO = 0.5
"""A term is not representable by feature points when interpolating its values at the grid back over the
volume misses more than this fraction of its RMS there (e.g. a 40/rev worm harmonic on an 11-point A grid,
every 36°, looks constant; so does a 10 mm pitch error on a 20 mm X grid)."""


def grid_aliasing(fp: FeaturePoints, corrected: TermsOnBase, n_probe: int = 4000, seed: int = 0) -> dict:
    """Whether feature points can carry the terms: the terms sampled at the grid, interpolated (cubic, per
    axis) back to random points of the volume (``seed``), against the terms there."""
    from scipy.interpolate import RegularGridInterpolator
    rng = np.random.default_rng(seed)
    k = fp.axes.shape[1]
    ticks = [np.unique(fp.axes[:, j]) for j in range(k)]
    if np.prod([len(t) for t in ticks]) != len(fp.axes) or min(len(t) for t in ticks) < 4:
        return {"aliased": False, "note": "feature points are not a full grid; representability not checked"}
    order = np.lexsort(tuple(fp.axes[:, j] for j in reversed(range(k))))
    values = corrected.terms_only(fp.axes)[order].reshape(*[len(t) for t in ticks], 3)
    lo, hi = np.array([t[0] for t in ticks]), np.array([t[-1] for t in ticks])
    probe = lo + (hi - lo) * rng.random((n_probe, k))
    interp = RegularGridInterpolator(ticks, values, method="cubic")(probe)
    truth = corrected.terms_only(probe)
    rms, miss = residual_stats(truth)["rms_um"], residual_stats(interp - truth)["rms_um"]
    return {"rms_in_volume_um": rms, "rms_missed_by_grid_um": miss, "aliased": bool(rms > 0 and miss > ALIAS_RATIO * rms)}


def retrain_learned(fp: FeaturePoints, corrected: TermsOnBase, parent_run_id: str | None, *, fit_field=None,
                    settings=None, tracking_uri: str | None = None):
    """Retrain the network on feature points + the loop's terms of the axes, tracked as a child of
    ``parent_run_id``, with the parent network's architecture. ``settings``: a :class:`training.TrainSettings`
    (default: its defaults, which stop on iterations, so the retrain is the same on any machine); the trainer is
    LM. ``fit_field`` defaults to :func:`training.fit_field` (``fit_field(featurepoints, settings,
    tracking=TrackSettings)`` returning ``.field``, ``.metrics``, ``.run_id``)."""
    aug = augmented_feature_points(fp, corrected)
    try:
        from training import TrackSettings, TrainSettings
        if fit_field is None:
            from training import fit_field  # noqa: F811
    except ImportError as exc:
        raise InputError(f"learned-field retrain unavailable: training.fit_field cannot be imported ({exc})") from None
    arch = {}
    config = getattr(corrected.base, "config", None)
    if callable(config):
        c = config()
        arch = {k: (tuple(c[k]) if k == "hidden" else c[k]) for k in ("hidden", "activation", "a_encoding") if k in c}
    settings = dataclasses.replace(settings or TrainSettings(), trainer="lm", **arch)
    return fit_field(aug, settings, tracking=TrackSettings(tracking_uri=tracking_uri, parent_run_id=parent_run_id))


def _retrain_record(checks, hold_idx, fp, corrected, model, retrain, fit_field, tracking_uri, parent) -> dict:
    """diagnosis.json's ``learned_retrain``: skipped (why) or the retrained network's held-out figures."""
    if corrected.needs:
        return {"skipped": "some selected terms need conditions (temperature, direction) that a learned field of "
                           "the axes cannot carry"}
    alias = grid_aliasing(fp, corrected)
    if alias["aliased"]:
        return {"skipped": "the feature-point grid aliases the selected terms (interpolated from the grid they miss "
                           f"{alias['rms_missed_by_grid_um']:.3g} μm RMS of {alias['rms_in_volume_um']:.3g} μm over "
                           "the volume): retraining on these feature points cannot carry them; they stay parametric "
                           "terms on the network", **alias}
    res = retrain_learned(fp, corrected, parent_run_id=parent, fit_field=fit_field, settings=retrain,
                          tracking_uri=tracking_uri)
    r_new = checks.measured_um - np.asarray(res.field.predict(checks.axes), float)
    st = residual_stats(r_new[hold_idx])
    return {"run_id": getattr(res, "run_id", None), "parent_run_id": str(model), "metrics": getattr(res, "metrics", {}),
            "rms_after_um": st["rms_um"], "max_after_um": st["max_um"], **alias}


def diagnose_network(checks, machine, source, out, *, base=None, fit_fraction=0.6, noise_um=None, max_effects=4,
                     units="check", tracking_uri=None, featurepoints=None, retrain=None, fit_field=None) -> tuple:
    """The loop on the trained network ``source`` (:class:`compensation.fields.ModelSource`; ``base``: the field
    already loaded) over the machine tool ``machine`` (its chain) and the read ``checks``
    (:class:`errormap.diagnosis.chain_loop.ChainChecks`); ``featurepoints``: a feature-point file for the retrain
    (``retrain``: its :class:`training.TrainSettings`). → ``(summary, [diagnosis.json])``."""
    from compensation.model_file import read_model
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.plausibility import diagnosis_verdict
    from .measurement import closed_loop
    if base is None:
        base = read_model(source.spec, machine, tracking_uri, source=source).field
    summary, _, terms = closed_loop(checks.path, machine, ChainElementSet.zeros(machine), checks, cov=None, base=base,
                                    fit_fraction=fit_fraction, noise_um=noise_um, max_effects=max_effects, units=units)
    summary.update({"checks": str(checks.path), "model": str(source.spec), "model_source": source.to_dict(),
                    "update": False, "covariance": None})
    if terms and featurepoints is not None:
        hold_idx = np.arange(int(summary["n_fit"]), len(checks))
        summary["learned_retrain"] = _retrain_record(checks, hold_idx, FeaturePoints.load(featurepoints),
                                                     TermsOnBase(machine, base, terms), source.spec, retrain,
                                                     fit_field, tracking_uri,
                                                     str(source.spec) if source.kind == "mlflow" else None)
    summary["verdict"] = diagnosis_verdict(summary)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "diagnosis.json", summary)
    return summary, [out / "diagnosis.json"]
