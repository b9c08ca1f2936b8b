"""Diagnosis orchestration: files in, ``DIR/diagnosis.json`` and ``DIR/report.html`` out.

* :func:`run_checks` — check measurements against a model (element-set file or learned run):
  the measured residual, the effects that explain it (:mod:`errormap.diagnosis`), before/after
  on the held-out part, and, for a learned model with axis-only effects and feature points,
  the retrain of the network on feature points plus the new terms (:func:`retrain_learned`).
* :func:`run_drift` — a drift log: causal model chosen by rolling-origin CV, before/after beside the
  OLS baseline, the controller model (JSON) and the compensation series (CSV).

Everything is computed before anything is written; both files are written atomically.
The report names its residual: the MEASURED residual (measurement − model prediction).
"""
from __future__ import annotations

import functools
import html
import json
from pathlib import Path

import numpy as np

from errormap.diagnosis.checks import load_checks
from errormap.diagnosis.drift import load_drift_log
from errormap.diagnosis.effects import Context
from errormap.diagnosis.pipeline import DiagnosisSettings, diagnose
from errormap.featurepoints import FeaturePoints
from errormap.io import InputError, atomic_write, write_json

from ...fields import load_field
from ..reports.figures import png_base64, pyplot


# -- learned path ---------------------------------------------------------------------------
def augmented_feature_points(fp: FeaturePoints, corrected) -> FeaturePoints:
    """Feature points plus the corrected model's terms at the grid (axis-only terms only)."""
    if corrected.needs:
        raise ValueError(f"the selected terms need conditions {list(corrected.needs)}; a learned field "
                         "maps axes only, so it cannot carry them (keep them as parametric terms)")
    extra = corrected.terms_only(fp.axes)
    meta = dict(fp.meta)
    meta["diagnosis_terms"] = ";".join(t.cand.label for t in corrected.terms)
    return FeaturePoints(fp.axes.copy(), fp.errors_um + extra, meta)


ALIAS_RATIO = 0.5
"""A term is not representable by feature points when interpolating its values at the grid
back over the volume misses more than this fraction of its RMS there (e.g. a 40/rev worm
harmonic on an 11-point A grid, every 36°, looks constant; so does a 10 mm pitch error on a
20 mm X grid)."""


def grid_aliasing(fp: FeaturePoints, corrected, n_probe: int = 4000, seed: int = 0) -> dict:
    """Whether feature points can carry the terms: the terms sampled at the grid, interpolated
    (cubic, per axis) back to random points of the volume, against the terms there."""
    from scipy.interpolate import RegularGridInterpolator
    rng = np.random.default_rng(seed)
    ticks = [np.unique(fp.axes[:, k]) for k in range(3)]
    if np.prod([len(t) for t in ticks]) != len(fp.axes) or min(len(t) for t in ticks) < 4:
        return {"aliased": False, "note": "feature points are not a full grid; representability not checked"}
    order = np.lexsort((fp.axes[:, 2], fp.axes[:, 1], fp.axes[:, 0]))
    values = corrected.terms_only(fp.axes)[order].reshape(*[len(t) for t in ticks], 3)
    lo, hi = np.array([t[0] for t in ticks]), np.array([t[-1] for t in ticks])
    probe = lo + (hi - lo) * rng.random((n_probe, 3))
    interp = RegularGridInterpolator(ticks, values, method="cubic")(probe)
    truth = corrected.terms_only(probe)
    rms = float(np.sqrt(np.mean(truth ** 2)))
    miss = float(np.sqrt(np.mean((interp - truth) ** 2)))
    return {"rms_in_volume_um": rms, "rms_missed_by_grid_um": miss,
            "aliased": bool(rms > 0 and miss > ALIAS_RATIO * rms)}


def retrain_learned(fp: FeaturePoints, corrected, parent_run_id: str | None, *, fit_field=None,
                    max_time_s: float = 120.0, seed: int = 0, tracking_uri: str | None = None):
    """Retrain the learned field on feature points + the fitted axis-only terms, tracked as a
    child of ``parent_run_id``, with the parent network's architecture. ``fit_field`` defaults to
    :func:`training.fit_field` (``fit_field(featurepoints, trainer='lm', max_time_s=, seed=,
    tracking_uri=, parent_run_id=, **architecture)`` returning ``.field``, ``.metrics``, ``.run_id``)."""
    aug = augmented_feature_points(fp, corrected)
    if fit_field is None:
        try:
            from training import fit_field  # noqa: F811
        except ImportError as exc:
            raise InputError(f"learned-field retrain unavailable: training.fit_field cannot be imported ({exc})") from None
    arch = {}
    config = getattr(corrected.base, "config", None)
    if callable(config):
        c = config()
        arch = {k: (tuple(c[k]) if k == "hidden" else c[k]) for k in ("hidden", "activation", "a_encoding") if k in c}
    return fit_field(aug, trainer="lm", max_time_s=max_time_s, seed=seed, tracking_uri=tracking_uri,
                     parent_run_id=parent_run_id, **arch)


# -- figures --------------------------------------------------------------------------------
_png = functools.partial(png_base64, dpi=90)
_plt = pyplot


def _histograms(before, after, labels, title) -> str:
    plt = _plt()
    k = before.shape[1]
    fig, axs = plt.subplots(1, k, figsize=(4.2 * k, 3.2), squeeze=False)
    for j in range(k):
        ax = axs[0, j]
        lim = max(np.abs(before[:, j]).max(), np.abs(after[:, j]).max(), 1e-9)
        bins = np.linspace(-lim, lim, 31)
        ax.hist(before[:, j], bins=bins, alpha=0.5, label="before")
        ax.hist(after[:, j], bins=bins, alpha=0.5, label="after")
        ax.set_xlabel(f"{labels[j]} residual (μm)")
        ax.legend(fontsize=8)
    fig.suptitle(title)
    return _png(fig)


def _explaining_variable(term, ctx):
    """The variable a term depends on at the points, with its label."""
    k, ax = term.kind, term.axis
    if k == "thermal":
        return (ctx.cond("temp_c") - term.ref["ref_temp_c"]) * ctx.position(ax), f"(temp_c − ref)·({ax} − lo)  (°C·mm)"
    if k == "drift":
        return (ctx.cond("time_s") - term.ref["ref_time_s"]) / 3600 * ctx.position(ax), f"time·({ax} − lo)  (h·mm)"
    if k == "reversal":
        return ctx.cond(f"dir_{ax}") + 0.0, f"dir_{ax}"
    if k == "periodic":
        return ctx.axes[:, {"x": 0, "z": 1}[ax]], f"{ax}_mm"
    if k == "harmonic":
        return ctx.axes[:, 2] % 360.0, "a_deg"
    return ctx.position("x") * ctx.position("z"), "(x − lo)(z − lo)  (mm²)"


def _effect_figure(d, term, ctx, hold) -> str:
    """Partial residual of ``term`` (projected on its element) against its variable, held-out part."""
    plt = _plt()
    others = sum((t.contribution(ctx) for t in d.selector.terms_ if t is not term), np.zeros_like(d.residual_before_um))
    partial = d.residual_before_um - others
    J = ctx.column(term.element)
    w = np.einsum("ni,ni->n", J, J)
    w = np.where(w > 1e-12, w, np.nan)
    g_before = np.einsum("ni,ni->n", J, partial) / w
    g_after = np.einsum("ni,ni->n", J, partial - term.contribution(ctx)) / w
    v, label = _explaining_variable(term, ctx)
    fig, axs = plt.subplots(1, 2, figsize=(9, 3.2), sharey=True)
    for ax, g, name in zip(axs, (g_before, g_after), ("before", "after")):
        ax.plot(v[hold], g[hold], ".", ms=3)
        ax.set_xlabel(label)
        ax.set_title(f"{name}: {term.cand.label}", fontsize=9)
    axs[0].set_ylabel(f"residual on {element_label(term.element)} ({'μrad' if term.element.startswith('e') else 'μm'})")
    return _png(fig)


def _finding_figure(d, finding, hold) -> str:
    plt = _plt()
    j = ("dx", "dy", "dz").index(finding["output"])
    inputs = {"x_mm": d.checks.axes[:, 0], "z_mm": d.checks.axes[:, 1], "a_deg": d.checks.axes[:, 2], **d.checks.conditions}
    v = inputs.get(finding["input"], d.checks.seq.astype(float))
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.plot(v[hold], d.residual_after_um[hold, j], ".", ms=3)
    ax.set_xlabel(finding["input"] if finding["input"] != "none" else "seq")
    ax.set_ylabel(f"{finding['output']} residual after (μm)")
    return _png(fig)


# -- HTML -----------------------------------------------------------------------------------
def _table(rows, header) -> str:
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def _fmt(v, nd=3):
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.{nd}g}"
    return str(v)


def _page(title, parts) -> str:
    css = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse;margin:1em 0}"
           "td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}img{max-width:100%}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{css}</style></head><body><h1>{html.escape(title)}</h1>{''.join(parts)}</body></html>\n")


def _img(b64, alt) -> str:
    return f"<p><img alt='{html.escape(alt)}' src='data:image/png;base64,{b64}'></p>"


def stages_html(s) -> str:
    """The closed loop's three stages and the update's findings, as HTML."""
    st = s["stages"]
    rows = [[name, _fmt(st[key]["held_out"]["rms_um"]), _fmt(st[key]["held_out"]["max_um"]),
             _fmt(st[key]["fitting"]["rms_um"])]
            for name, key in (("identified", "identified"), ("updated", "updated"),
                              ("updated + effects", "updated_plus_effects"))]
    out = ["<h2>Closed loop: identified → updated → updated + effects</h2>",
           _table(rows, ["model", "held-out RMS (μm)", "held-out max (μm)", "fitting RMS (μm)"])]
    u = s["update"]
    out.append(f"<p>Check noise σ (marginal likelihood): {_fmt(u['check_noise_sigma_um'])} μm.</p>")
    if u["contradicted_by_sweeps"]:
        out.append("<p><b>Updates the sweeps contradict</b> (evidence of an effect the 23 elements lack): "
                   + html.escape(", ".join(f"{element_label(c['element'])} (p = {c['p_adjusted']:.2g})" for c in u["contradicted_by_sweeps"]))
                   + "</p>")
    if u["not_updated"]:
        out.append("<p><b>Not updated by the checks</b> (stay at the sweep estimate): "
                   + html.escape("; ".join(f"{element_label(c['element'])}: {c['why']}" for c in u["not_updated"])) + "</p>")
    if s.get("effects_rejected"):
        out.append("<p>Effects rejected: " + html.escape(s.get("effects_rejected_why", "")) + "</p>")
    return "".join(out)


def element_label(name: str) -> str:
    """An element name with its ISO 230-1 name beside it (``dz_z (EZZ)``); other names as they are."""
    from errormap.iso230 import ISO_NAME
    return f"{name} ({ISO_NAME[name]})" if name in ISO_NAME else name


def checks_report(d, summary, model_spec, checks_path) -> str:
    s = summary
    parts = [f"<p>Residual shown: <b>measured residual</b> (measurement − model prediction). Checks: "
             f"{html.escape(str(checks_path))}; model: {html.escape(str(model_spec))}. {html.escape(s['split'])}. "
             f"RMS and max are of the residual vector norm |r| on the held-out part.</p>"]
    parts.append(_table([["held-out RMS (μm)", _fmt(s["rms_before_um"]), _fmt(s["rms_after_um"])],
                         ["held-out max (μm)", _fmt(s["max_before_um"]), _fmt(s["max_after_um"])]],
                        ["", "before", "after"]))
    if "stages" in s:
        parts.append(stages_html(s))
    parts.append("<h2>Effects found</h2>")
    if s["effects"]:
        rows = []
        for i, e in enumerate(s["effects"], 1):
            ps = "; ".join(f"{k} = {_fmt(p['value'], 4)} ± {_fmt(p['se'], 2)} {p['unit']}" for k, p in e["parameters"].items())
            rows.append([i, e["kind"], e["axis"], element_label(e["element"]), ps, _fmt(e["rms_reduction_um"]),
                         _fmt(e["selection"].get("p_adjusted")), _fmt(e["selection"].get("delta_bic"), 4)])
        parts.append(_table(rows, ["rank", "kind", "axis", "element (ISO 230-1)", "parameters", "held-out RMS reduction (μm)",
                                   "p (Bonferroni)", "ΔBIC"]))
    else:
        parts.append("<p>No effect of the library passed the significance and forward-validation tests.</p>")
    hold = d.hold_idx
    parts.append(_img(_histograms(d.residual_before_um[hold], d.residual_after_um[hold], ("dx", "dy", "dz"),
                                  "held-out measured residual, before and after"), "histograms"))
    if d.selector.terms_:
        ctx = Context.build(d.corrected.machine, d.checks.axes, d.checks.conditions, d.selector.terms_[0].ref)
        for t in d.selector.terms_:
            parts.append(_img(_effect_figure(d, t, ctx, hold), t.cand.label))
    for key, name in (("unexplained_before", "before"), ("unexplained_after", "after")):
        parts.append(f"<h2>Where the held-out residual lives ({name})</h2>")
        f = s[key]
        if f:
            parts.append(_table([[u["output"], u["input"], u["pattern"],
                                  (f"{u['period']:.4g} {u['period_unit']}" if "period" in u else ""),
                                  _fmt(u["rms_um"]), _fmt(u["explained_fraction"]), _fmt(u["p_adjusted"])] for u in f],
                                ["output", "input", "pattern", "period", "rms (μm)", "explained fraction", "p (Bonferroni)"]))
        else:
            parts.append("<p>No significant dependence on any input.</p>")
    if s["unexplained_after"]:
        parts.append(_img(_finding_figure(d, s["unexplained_after"][0], hold), "largest unexplained"))
    if s.get("learned_retrain"):
        parts.append(f"<h2>Learned field retrain</h2><pre>{html.escape(json.dumps(s['learned_retrain'], indent=1))}</pre>")
    return _page("volcomp diagnose — check measurements", parts)


def drift_report(log, sel, channels, log_path) -> str:
    """HTML page of a drift-log diagnosis: ``sel`` a fitted DriftSelector, ``channels`` its report."""
    plt = _plt()
    _, hold = sel.split(log)
    parts = [f"<p>Drift log {html.escape(str(log_path))}: fitted on the first {len(log.time_s) - len(hold)} rows, "
             f"before/after on the last {len(hold)} (forward in time). Residual shown: measured displacement "
             "minus the causal model's prediction (the MEASURED residual). The baseline is ordinary least squares "
             "on every temperature and speed_rpm, fitted on the same rows.</p>"]
    notes = log.notes or {}
    if notes.get("dropped") or notes.get("filled"):
        items = [f"<li>{html.escape(c)}: dropped — {html.escape(w)}</li>" for c, w in notes.get("dropped", {}).items()]
        items += [f"<li>{html.escape(c)}: missing samples filled by linear interpolation, rows "
                  f"{html.escape(', '.join(f'{a}–{b}' for a, b in r))}</li>" for c, r in notes.get("filled", {}).items()]
        parts.append("<h2>Inputs repaired or dropped</h2><ul>" + "".join(items) + "</ul>")
    fams = sorted({f for c in channels.values() for f in c["cv_rms_um"]})
    rows = [[ch, c["model"], *[_fmt(c["cv_rms_um"].get(f)) for f in fams], _fmt(c["rms_before_um"]),
             _fmt(c["rms_after_um"]), _fmt(c["rms_ols_um"]), _fmt(c["band95_um"]),
             _fmt(c["band_coverage_heldout"])] for ch, c in channels.items()]
    parts.append(_table(rows, ["channel", "chosen", *[f"CV {f}" for f in fams], "held-out before", "volcomp",
                               "OLS baseline", "95 % band ±", "band coverage"]))
    parts.append("<p>CV: rolling-origin cross-validation on the fitting part (RMS μm over all validation blocks of the "
                 "ranking folds; best hyper-parameter per family). The chosen candidate is the best-ranked one that "
                 "also beats the OLS baseline by more than one standard error of the fold-to-fold scatter on the "
                 "horizon folds (validation blocks as long, relative to their training, as the held-out part is to "
                 "the fitting part); otherwise the OLS baseline itself. The model never loses to OLS in "
                 "validation.</p>")
    sub = getattr(sel, "subset_modeller_", None)
    if sub is not None:
        sr = {ch: c for ch, c in sub.report_selection().items()}
        parts.append("<h2>Sensor-subset search (subset_lag family)</h2>")
        parts.append(_table([[ch, ", ".join(c["regressors"]) or "—", _fmt(c["lag_s"]),
                              "AMBIGUOUS" if c["ambiguous"] else ""] for ch, c in sr.items()],
                            ["channel", "regressors", "lag (s)", "selection"]))
    pred = sel.model_.predict(log, sel.cache_)
    for ch in sel.model_.channels:
        d = log.disp_um[ch]
        after = d - pred[ch]
        fig, axs = plt.subplots(1, 2, figsize=(10, 3.2))
        axs[0].plot(log.time_s / 3600, d, lw=0.8, label="before")
        axs[0].plot(log.time_s / 3600, after, lw=0.8, label="after")
        axs[0].axvline(log.time_s[hold[0]] / 3600, color="k", ls="--", lw=0.8)
        axs[0].set_xlabel("time (h)")
        axs[0].set_ylabel(f"{ch} (μm)")
        axs[0].legend(fontsize=8)
        lim = max(np.abs(d[hold]).max(), 1e-9)
        bins = np.linspace(-lim, lim, 31)
        axs[1].hist(d[hold], bins=bins, alpha=0.5, label="before")
        axs[1].hist(after[hold], bins=bins, alpha=0.5, label="after")
        axs[1].set_xlabel(f"held-out {ch} (μm)")
        axs[1].legend(fontsize=8)
        parts.append(_img(_png(fig), ch))
    return _page("volcomp diagnose — drift log", parts)


def compensation_columns(log, model, cache=None) -> dict:
    """The compensation series: ``time_s`` and per channel ``<ch>_pred_um``, ``<ch>_lo_um``, ``<ch>_hi_um``
    (prediction ± the 95 % band), causal."""
    pred = model.predict(log, cache)
    cols = {"time_s": log.time_s}
    for ch, p in pred.items():
        band = model.channels[ch].band95_um
        cols[f"{ch}_pred_um"] = p
        cols[f"{ch}_lo_um"] = p - band
        cols[f"{ch}_hi_um"] = p + band
    return cols


COMPENSATION_COMMENTS = ("compensation series: predicted thermal displacement per channel (um), causal "
                         "(the value at time_s uses log samples at or before time_s only)",
                         "<ch>_lo_um / <ch>_hi_um: 95 % band from forward-chained validation residuals",
                         "the controller corrects by subtracting <ch>_pred_um")


# -- entry points ---------------------------------------------------------------------------
def _write(out_dir, summary, page):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "report.html", "w", encoding="utf-8") as fh:
        fh.write(page)
    write_json(out / "diagnosis.json", summary)
    return out / "diagnosis.json", out / "report.html"


def run_checks(checks_path, machine, model_spec, out_dir, settings: DiagnosisSettings | None = None,
               tracking_uri=None, featurepoints=None, retrain_time_s: float = 120.0, seed: int = 0, fit_field=None,
               field_=None, update: bool = True):
    """Diagnose ``checks_path`` against ``model_spec``; returns (summary, paths).

    ``field_`` overrides loading ``model_spec`` (tests, benchmarks). With a learned model
    (a run id) and ``featurepoints`` given, axis-only effects trigger the retrain. With an
    element-set file whose covariance (``NAME.cov.npz``, from ``volcomp identify``) lies beside
    it and ``update``, the closed loop runs (:func:`errormap.diagnosis.loop.closed_loop`):
    identified → updated → updated + effects; the updated elements are written to
    ``DIR/updated_elements.json`` (with their covariance) and the final model to ``DIR/model.json``.
    """
    from errormap.uncertainty import covariance_path
    if (update and field_ is None and Path(str(model_spec)).suffix.lower() == ".json"
            and covariance_path(model_spec).is_file()):
        return run_closed_loop(checks_path, machine, model_spec, out_dir, settings)
    checks = load_checks(checks_path, machine)
    settings = settings or DiagnosisSettings()
    settings.validate(len(checks))
    learned = field_ is None and not (Path(str(model_spec)).suffix.lower() == ".json" or Path(str(model_spec)).is_file())
    fp = FeaturePoints.load(featurepoints) if featurepoints else None
    if field_ is None:
        field_ = load_field(str(model_spec), machine, tracking_uri)
    d = diagnose(machine, field_, checks, settings)
    summary = dict(d.summary)
    summary.update({"checks": str(checks_path), "model": str(model_spec), "machine": machine.name})
    if d.selector.terms_ and fp is not None and (learned or fit_field is not None):
        axis_only = [t for t in d.selector.terms_ if not t.needs]
        alias = grid_aliasing(fp, d.corrected) if axis_only and len(axis_only) == len(d.selector.terms_) else None
        if alias is not None and alias["aliased"]:
            summary["learned_retrain"] = {
                "skipped": "the feature-point grid aliases the selected terms (interpolated from the grid they miss "
                           f"{alias['rms_missed_by_grid_um']:.3g} μm RMS of {alias['rms_in_volume_um']:.3g} μm over "
                           "the volume): retraining on these feature points cannot carry them; they stay parametric "
                           "terms on the learned field (the corrected model above)", **alias}
        elif alias is not None:
            res = retrain_learned(fp, d.corrected, parent_run_id=str(model_spec) if learned else None,
                                  fit_field=fit_field, max_time_s=retrain_time_s, seed=seed, tracking_uri=tracking_uri)
            new = res.field
            r_new = checks.measured_um - np.asarray(new.predict(checks.axes))
            from errormap.diagnosis.pipeline import residual_stats
            st = residual_stats(r_new[d.hold_idx])
            summary["learned_retrain"] = {"run_id": getattr(res, "run_id", None), "parent_run_id": str(model_spec),
                                          "metrics": getattr(res, "metrics", {}), "rms_after_um": st["rms_um"],
                                          "max_after_um": st["max_um"], **alias}
        else:
            summary["learned_retrain"] = {"skipped": "some selected terms need conditions (temperature, time, "
                                                     "direction) that a learned field of the axes cannot carry"}
    page = checks_report(d, summary, model_spec, checks_path)
    return summary, _write(out_dir, summary, page)


def run_closed_loop(checks_path, machine, model_spec, out_dir, settings: DiagnosisSettings | None = None):
    """The closed loop on an identified element set with its covariance; returns (summary, paths)."""
    from errormap.diagnosis.loop import closed_loop
    from errormap.elements import ElementSet
    from errormap.uncertainty import ElementCovariance, covariance_path
    checks = load_checks(checks_path, machine)
    settings = settings or DiagnosisSettings()
    settings.validate(len(checks))
    el = ElementSet.load(model_spec)
    cov = ElementCovariance.load(covariance_path(model_spec), el)
    loop = closed_loop(machine, cov, checks, settings)
    summary = dict(loop.summary)
    summary.update({"checks": str(checks_path), "model": str(model_spec), "machine": machine.name,
                    "residual": "measured (measurement − model prediction); stages judged on the same held-out checks"})
    page = checks_report(loop.diagnosis, summary, model_spec, checks_path)
    out_dir = Path(out_dir)
    upd_path = out_dir / "updated_elements.json"
    summary["updated_elements_file"] = str(upd_path)
    model = {"format": "volcomp-diagnosed-model/1", "elements": "updated_elements.json",
             "terms": summary["effects"], "needs": sorted({c for e in summary["effects"] for c in e.get("needs", [])})}
    paths = _write(out_dir, summary, page)
    loop.update.covariance_.save(covariance_path(upd_path))
    loop.update.elements_.save(upd_path)
    write_json(out_dir / "model.json", model)
    return summary, list(paths) + [upd_path, covariance_path(upd_path), out_dir / "model.json"]


def run_drift(log_path, out_dir, selector=None):
    """Diagnose a drift log: model families chosen by rolling-origin CV, before/after with the OLS
    baseline beside. Writes diagnosis.json, report.html, drift_model.json (``volcomp.drift_model``)
    and drift_compensation.csv; returns (summary, paths)."""
    from errormap.diagnosis.drift_models import SCHEMA, SCHEMA_VERSION, DriftSelector
    from errormap.io import write_csv
    log = load_drift_log(log_path)
    sel = (selector or DriftSelector()).fit(log)
    channels = sel.report(log)
    fit, hold = sel.split(log)
    summary = {"log": str(log_path), "residual": "measured displacement − causal drift model prediction",
               "split": f"by time: first {len(fit)} rows fit, last {len(hold)} held out",
               "baseline": "ordinary least squares on every temperature and speed_rpm (no filter, no lag)",
               "selection": sel.model_.meta["selection"],
               "inputs_filled": log.notes.get("filled", {}), "inputs_dropped": log.notes.get("dropped", {}),
               "channels": channels, "model_file": f"drift_model.json ({SCHEMA} v{SCHEMA_VERSION})",
               "settings": {"fit_fraction": sel.fit_fraction, "n_folds": sel.n_folds, "cv_start": sel.cv_start,
                            "n_horizon_folds": sel.n_horizon_folds, "gate_se": sel.gate_se}}
    sub = getattr(sel, "subset_modeller_", None)
    if sub is not None:
        summary["sensor_selection"] = sub.report_selection()
    page = drift_report(log, sel, channels, log_path)
    comp = compensation_columns(log, sel.model_, sel.cache_)
    paths = _write(out_dir, summary, page)
    out = Path(out_dir)
    model_path = sel.model_.save(out / "drift_model.json")
    csv_path = write_csv(out / "drift_compensation.csv", comp, header_comments=COMPENSATION_COMMENTS)
    return summary, (*paths, model_path, csv_path)
