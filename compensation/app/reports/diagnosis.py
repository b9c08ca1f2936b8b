"""The diagnosis pages: check measurements (``diagnose.html``) and drift logs (``drift.html``).

:func:`checks_report` and :func:`drift_report` take what the diagnosis workflow
(:mod:`compensation.app.workflows.diagnosis`) computed and return one self-contained page; the
figures are made here (matplotlib Agg, embedded by the report toolkit).
"""
from __future__ import annotations

import json

import numpy as np

from errormap.diagnosis.effects import AXIS_COL, Context
from errormap.effect_kinds import diagnosed_kind

from .figures import pyplot
from .toolkit import Figure, Table, figure, num, qty, render_page, unit_text

FIG_DPI = 90
SENSITIVE_FRACTION = 0.1
"""Effect figures show the checks whose |J_e|² is above this fraction of the median: the projected
residual J_eᵀr/|J_e|² of the others is noise magnified (it hid a 94 μrad worm harmonic behind ±2500 μrad)."""
_plt = pyplot


def element_label(name: str) -> str:
    """An element name with its ISO 230-1 name beside it (``dz_z (EZZ)``); other names as they are."""
    from errormap.iso230 import ISO_NAME
    return f"{name} ({ISO_NAME[name]})" if name in ISO_NAME else name


# -- figures --------------------------------------------------------------------------------
def _histograms(before, after, labels, title) -> Figure:
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
    fig.tight_layout()
    return figure(fig, "histograms", dpi=FIG_DPI)


def _thermal_variable(term, ctx):
    ax = term.axis
    return (ctx.cond("temp_c") - term.ref["ref_temp_c"]) * ctx.position(ax), f"(temp_c − ref)·({ax} − lo)  (°C·mm)"


def _drift_variable(term, ctx):
    ax = term.axis
    return (ctx.cond("time_s") - term.ref["ref_time_s"]) / 3600 * ctx.position(ax), f"time·({ax} − lo)  (h·mm)"


def _reversal_variable(term, ctx):
    return ctx.cond(f"dir_{term.axis}") + 0.0, f"dir_{term.axis}"


def _periodic_variable(term, ctx):
    ax, p = term.axis, float(term.period_mm)
    return np.mod(ctx.axes[:, AXIS_COL[ax]], p), f"{ax}_mm folded on one period: {ax} mod {num(p, 4)} mm"


def _harmonic_variable(term, ctx):
    n = int(term.order)
    return np.mod(n * ctx.axes[:, AXIS_COL[term.axis]], 360.0), f"phase of the {n}/rev harmonic: {n}·a_deg mod 360 (°)"


def _interaction_variable(term, ctx):
    p, q = term.axis.split("*")
    return ctx.position(p) * ctx.position(q), f"({p} − lo)({q} − lo)  (mm²)"


EXPLAINING_VARIABLE = {"thermal": _thermal_variable, "drift": _drift_variable, "reversal": _reversal_variable,
                       "periodic": _periodic_variable, "harmonic": _harmonic_variable,
                       "interaction": _interaction_variable}
"""How the report draws each diagnosed kind (keyed by the registry's names, :mod:`errormap.effect_kinds`;
``tests/test_effect_kinds.py`` checks it covers exactly the diagnosed kinds)."""


def _explaining_variable(term, ctx):
    """The variable a term depends on at the points, with its label.

    Periodic terms are folded onto one period (a 40/rev worm harmonic over a whole turn shows
    40 cycles in a few hundred points, i.e. nothing; folded, every point falls on one sine).
    An unknown kind is a ``ValueError`` (the registry's), never drawn as some other kind.
    """
    kind = diagnosed_kind(term.kind).name
    return EXPLAINING_VARIABLE[kind](term, ctx)


def _effect_figure(d, term, ctx, hold) -> Figure:
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
    # points where the element barely moves the tool (|J_e|² small) carry no information about it and,
    # divided by |J_e|², only noise: they are left out, and the y range follows the rest
    keep = hold[w[hold] > SENSITIVE_FRACTION * np.nanmedian(w[hold])]
    fitted = term.value(ctx)
    order = keep[np.argsort(v[keep])]
    lo, hi = np.nanpercentile(np.concatenate([g_before[keep], g_after[keep], fitted[keep]]), [1, 99])
    pad = 0.15 * (hi - lo) + 1e-12
    fig, axs = plt.subplots(1, 2, figsize=(9, 3.2), sharey=True)
    for ax, g, name in zip(axs, (g_before, g_after), ("before", "after")):
        ax.plot(v[keep], g[keep], ".", ms=3, label="held-out checks")
        ax.set_xlabel(label)
        ax.set_title(f"{name}: {term.cand.label}", fontsize=9)
        ax.grid(True, alpha=0.3)
    axs[0].plot(v[order], fitted[order], "-", color="tab:red", lw=1, label="fitted term")
    axs[0].set_ylim(lo - pad, hi + pad)
    axs[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(0.0, -0.22), ncol=2, frameon=False)
    axs[0].set_ylabel(f"residual on {element_label(term.element)} ({'μrad' if term.element.startswith('e') else 'μm'})")
    fig.tight_layout()
    return figure(fig, term.cand.label, f"Held-out measured residual on {element_label(term.element)} against "
                  f"the variable of {term.cand.label}, before and after the term (checks where the element "
                  f"moves the tool less than {SENSITIVE_FRACTION:g} × the median are left out).", dpi=FIG_DPI)


def _finding_figure(d, finding, hold) -> Figure:
    plt = _plt()
    j = ("dx", "dy", "dz").index(finding["output"])
    inputs = {"x_mm": d.checks.axes[:, 0], "z_mm": d.checks.axes[:, 1], "a_deg": d.checks.axes[:, 2], **d.checks.conditions}
    v = inputs.get(finding["input"], d.checks.seq.astype(float))
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.plot(v[hold], d.residual_after_um[hold, j], ".", ms=3)
    ax.set_xlabel(finding["input"] if finding["input"] != "none" else "seq")
    ax.set_ylabel(f"{finding['output']} residual after (μm)")
    return figure(fig, "largest unexplained", "The largest dependence left in the held-out residual after the "
                  "effects.", dpi=FIG_DPI)


# -- pages ----------------------------------------------------------------------------------
def _stages(s) -> dict:
    """The closed loop's three stages and the update's findings, for ``diagnose.html``."""
    st = s["stages"]
    kept = s.get("kept_stage", "updated_plus_effects")
    rows = [[name + (" (kept)" if key == kept else ""), st[key]["held_out"]["rms_um"], st[key]["held_out"]["max_um"],
             st[key]["fitting"]["rms_um"]]
            for name, key in (("identified", "identified"), ("update alone (whole residual)", "updated_alone"),
                              ("updated", "updated"), ("updated + effects", "updated_plus_effects"),
                              ("+ learned residual (" + str(st.get("learned_residual", {}).get("learned", {}).get("family"))
                               + ")", "learned_residual")) if key in st]
    u = s["update"]
    joint = []
    for j in u.get("joint_screen", []):
        imit = ", ".join(f"{element_label(e['element'])} ({num(e['imitation_rms_um'], 2)} μm)"
                         for e in j.get("update_alone_imitated_it_with", []))
        joint.append({"term": f"{j['kind']} {j['axis']} on {element_label(j['element'])}",
                      "F": num(j["F"], 3), "n_candidates": j["n_candidates"], "p": num(j["p_adjusted"], 2),
                      "imitation": imit, "confirmed": bool(j.get("confirmed"))})
    return {"table": Table(["model", "held-out RMS (μm)", "held-out max (μm)", "fitting RMS (μm)"], rows),
            "kept": kept if "kept_why" in s else None, "kept_why": s.get("kept_why"), "joint": joint,
            "refit": (s.get("refit_on_all_checks") or {}).get("note"),
            "noise_sigma_um": u["check_noise_sigma_um"],
            "contradicted": [f"{element_label(c['element'])} (p = {num(c['p_adjusted'], 2)})"
                             for c in u["contradicted_by_sweeps"]],
            "not_updated": [f"{element_label(c['element'])}: {c['why']}" for c in u["not_updated"]],
            "rejected": s.get("effects_rejected_why", "") if s.get("effects_rejected") else ""}


FRAME_WORDS = {"work": "learned in the work frame, as measured",
               "machine": "learned in the machine frame (the residual turned by the work frame's nominal rotation, "
                          "and turned back)"}
"""How the report names the learned part's output frame (compensation.hybrid.OUTPUT_FRAMES)."""


def _learned(s) -> dict | None:
    """The learned-residual stage (compensation.hybrid): its CV table, gate and map figure."""
    lr = s.get("learned_residual")
    if not lr:
        return None
    rows = [[fam, r["cv_rms"], r["cv_rms_se"], r["gain_mean"], r["gain_se"],
             "" if r.get("coverage_95") is None else r["coverage_95"]] for fam, r in lr["cv_table"].items()]
    out = {"family": lr["family"], "family_name": lr.get("family_name", lr["family"]),
           "compared": ", ".join(lr.get("families_compared", [])), "rule": lr.get("selection_rule"),
           "shipped": (lr.get("shipped") or {}).get("note"),
           "kept": lr["kept"], "why": lr["why"], "inputs": ", ".join(lr["inputs"]),
           "cv": lr["cv"], "z": lr["held_out_gain_z"],
           "cover": lr.get("held_out_band95_cover_total") if lr.get("held_out_band95_cover_total") is not None
           else lr.get("held_out_band95_cover"),
           "cover_what": ("the hybrid's total band: learned ⊕ elements ⊕ measurement noise"
                          if lr.get("held_out_band95_cover_total") is not None else "learned band ⊕ measurement noise"),
           "replaced": ", ".join(f"{e['kind']} {e['axis']}" for e in s.get("effects_replaced_by_learned", [])),
           # the rule that replaced them, as the run recorded it (it changed between rounds: diagnosis.json says which)
           "replaced_rule": (lr.get("condition_terms_vs_static") or {}).get("rule"),
           "table": Table(["family", "CV RMS (μm)", "its SE (μm)", "mean gain over zero (μm²)", "its SE (μm²)",
                           "95 % band coverage"], rows), "figure": None,
           "frame": FRAME_WORDS.get(lr.get("output_frame", "work"), lr.get("output_frame")),
           "frames_table": None, "backfit": None}
    bf = lr.get("backfit")
    if bf:   # backfitted with the element update it sits on (compensation.hybrid.BACKFIT_ROUNDS)
        out["backfit"] = {"rounds": bf["rounds"], "rms": bf["held_out_sequential"]["rms_um"],
                          "z": bf["held_out_gain_z_sequential"],
                          "steps": ", ".join(f"{v:.3g}" for v in bf["step_rms_um"])}
    cands = lr.get("inputs_table") or {}
    if len(cands) > 1:   # more than one (input set, output frame) candidate: each one's chosen family and CV RMS
        out["frames_table"] = Table(
            ["input set", "output frame", "family chosen there", "CV RMS (μm)", "zero's CV RMS (μm)"],
            [[k.split("@")[0], v.get("output_frame", "work"), v["family"], v["cv_rms"], v["cv_rms_zero"]]
             for k, v in cands.items()])
    m = lr.get("map")
    if m:
        out["figure"] = learned_map_figure(m)
    return out


def map_axes(m: dict) -> tuple:
    """The two axis columns a learned map (:func:`compensation.hybrid.learned_map`) spans, in its order: its
    first two ``*_mm`` keys (the machine's first two linear axes: the grinder's x_mm, z_mm; a mill's x_mm,
    y_mm), and the ``<rotary columns>_averaged`` key or None."""
    lin = [k for k in m if k.endswith("_mm")][:2]
    if len(lin) != 2:
        raise ValueError(f"a learned map over two linear axes, got keys {list(m)}")
    return lin[0], lin[1], next((k for k in m if k.endswith("_averaged")), None)


def learned_map_figure(m: dict) -> Figure:
    """The learned correction's map (its norm and its band over the first two linear axes) as a figure; the
    axis names come from the map's keys (:func:`map_axes`)."""
    c1, c2, rot = map_axes(m)
    s1, s2 = c1.rsplit("_", 1)[0], c2.rsplit("_", 1)[0]
    fig, axs = _plt().subplots(1, 2, figsize=(9, 3.6))
    ext = [m[c1][0], m[c1][-1], m[c2][0], m[c2][-1]]
    band_key, band_title = (("band95_total_um", "the hybrid's total 95 % band (μm)") if "band95_total_um" in m
                            else ("band95_um", "its 95 % band (μm)"))
    for ax, key, title in ((axs[0], "norm_um", "learned correction |Δ| (μm)"), (axs[1], band_key, band_title)):
        im = ax.imshow(np.array(m[key]), origin="lower", extent=ext, aspect="auto", cmap="viridis")
        ax.set_xlabel(f"{s1} (mm)")
        ax.set_ylabel(f"{s2} (mm)")
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax)
    fig.tight_layout()
    if rot is not None and isinstance(m.get("rotary_deg"), dict) and m["rotary_deg"]:
        # the angles each rotary axis was at (a short stroke clips them: five-axis-ac's A [-120, 30])
        over = "averaged over " + "; ".join(f"{c.rsplit('_', 1)[0].upper()} = {', '.join(f'{a:g}' for a in v)}°"
                                            for c, v in m["rotary_deg"].items())
    elif rot is not None:   # a map written before rotary_deg: the positions asked for
        names = "/".join(c.rsplit("_", 1)[0].upper() for c in rot[:-len("_averaged")].split("+"))
        over = f"averaged over {names} = {', '.join(f'{a:g}' for a in m[rot])}°"
    else:
        over = "any further linear axis at mid-stroke"
    return figure(fig, "learned map", f"The learned correction over {s1.upper()}–{s2.upper()} (vector norm, {over}) "
                  "and the norm of its 95 % band: it is zero, and its band the prior's, where the checks do not reach",
                  dpi=FIG_DPI)


def _effects_table(effects) -> Table | None:
    if not effects:
        return None
    rows = []
    for i, e in enumerate(effects, 1):
        ps = "; ".join(f"{k} = {num(p['value'], 4)}{'' if p['se'] is None else ' ± ' + num(p['se'], 2)} "
                       f"{unit_text(p['unit'])}".rstrip() for k, p in e["parameters"].items())
        rows.append([i, e["kind"], e["axis"], element_label(e["element"]), ps, e["rms_reduction_um"],
                     e["selection"].get("p_adjusted"), e["selection"].get("delta_bic")])
    return Table(["rank", "kind", "axis", "element (ISO 230-1)", "parameters", "held-out RMS reduction (μm)",
                  "p (Bonferroni)", "ΔBIC"], rows, left=5, formats={7: 4})


def _unexplained_table(findings) -> Table | None:
    if not findings:
        return None
    return Table(["output", "input", "pattern", "period", "RMS (μm)", "explained fraction", "p (Bonferroni)"],
                 [[u["output"], u["input"], u["pattern"], qty(u["period"], u["period_unit"], 4) if "period" in u else "",
                   u["rms_um"], u["explained_fraction"], u["p_adjusted"]] for u in findings], left=4)


def checks_report(d, summary, model_spec, checks_path) -> str:
    """The ``diagnose.html`` page of a check-measurement diagnosis ``d`` and its ``summary``."""
    s = summary
    hold = d.hold_idx
    effect_figures = []
    if d.selector.terms_:
        ctx = Context.build(d.corrected.machine, d.checks.axes, d.checks.conditions, d.selector.terms_[0].ref)
        effect_figures = [_effect_figure(d, t, ctx, hold) for t in d.selector.terms_]
    return render_page(
        "diagnose.html", title="volcomp diagnose — check measurements", checks=str(checks_path), model=str(model_spec),
        split=s["split"],
        summary_table=Table(["", "before", "after"], [["held-out RMS (μm)", s["rms_before_um"], s["rms_after_um"]],
                                                      ["held-out max (μm)", s["max_before_um"], s["max_after_um"]]]),
        stages=_stages(s) if "stages" in s else None, effects=_effects_table(s["effects"]),
        histograms=_histograms(d.residual_before_um[hold], d.residual_after_um[hold], ("dx", "dy", "dz"),
                               "held-out measured residual, before and after"),
        effect_figures=effect_figures,
        unexplained=[(name, _unexplained_table(s[key])) for key, name in (("unexplained_before", "before"),
                                                                          ("unexplained_after", "after"))],
        finding_figure=_finding_figure(d, s["unexplained_after"][0], hold) if s["unexplained_after"] else None,
        retrain=json.dumps(s["learned_retrain"], indent=1) if s.get("learned_retrain") else None,
        learned=_learned(s))


def drift_report(log, sel, channels, log_path) -> str:
    """The ``drift.html`` page of a drift-log diagnosis: ``sel`` a fitted DriftSelector, ``channels`` its report."""
    plt = _plt()
    _, hold = sel.split(log)
    notes = log.notes or {}
    repaired = [f"{c}: dropped — {w}" for c, w in notes.get("dropped", {}).items()]
    repaired += [f"{c}: missing samples filled by linear interpolation, rows {', '.join(f'{a}–{b}' for a, b in r)}"
                 for c, r in notes.get("filled", {}).items()]
    fams = sorted({f for c in channels.values() for f in c["cv_rms_um"]})
    rows = [[ch, c["model"], *[c["cv_rms_um"].get(f) for f in fams], c["rms_before_um"], c["rms_after_um"],
             c["rms_ols_um"], c.get("rms_constant_um"), c["band95_um"], c["band_coverage_heldout"]]
            for ch, c in channels.items()]
    table = Table(["channel", "chosen", *[f"CV {f} (μm)" for f in fams], "held-out RMS before (μm)",
                   "held-out RMS after, volcomp (μm)", "held-out RMS after, OLS baseline (μm)",
                   "held-out RMS after, constant offset (μm)",
                   "band ± (μm) inside the fit range (× max(1, ρ) beyond): 95 % of horizon + novelty validation residuals", "band coverage CHECKED on the held-out part"], rows, left=2)
    sensors = None
    sub = getattr(sel, "subset_modeller_", None)
    if sub is not None:
        sensors = Table(["channel", "regressors", "lag (s)", "selection"],
                        [[ch, ", ".join(c["regressors"]) or "—", c["lag_s"], "AMBIGUOUS" if c["ambiguous"] else ""]
                         for ch, c in sub.report_selection().items()], left=2)
    pred = sel.model_.predict(log, sel.cache_)
    figures = []
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
        fig.tight_layout()
        figures.append(figure(fig, ch, f"{ch}: displacement before and after the drift model over time (dashed: "
                                        "start of the held-out part) and the held-out histogram.", dpi=FIG_DPI))
    return render_page("drift.html", title="volcomp diagnose — drift log", log=str(log_path),
                       n_fit=len(log.time_s) - len(hold), n_hold=len(hold), repaired=repaired, channels=table,
                       sensors=sensors, figures=figures)
