"""The arm calibration report (``volcomp calibrate --machine ARM``): ``report.html`` (``arm_calibrate.html``).

Per-pose held-out errors of every stage, the residual over the workspace (held-out tool points
coloured by the kept stage's error) and the geometric stage's 95 % prediction band (J Σ Jᵀ) beside
the residual it should cover.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.arm_calibration import TABLE_KNOT_RE

from .figures import pyplot
from .toolkit import Table, figure, render_page, write_page

FIG_DPI = 100
Z95 = 1.959963984540054


def _figures(chain, core, check) -> list:
    plt = pyplot()
    geo = core["geometric_model"]                       # the kept stage's geometric part
    vgeo = core.get("volcomp_geometric_model", geo)     # volcomp's geometric choice (under the learned stage)
    pred = geo.predict(check.q)

    def label(g):
        return "plain geometric LSQ" if g.method.startswith("plain") else core.get("geometric_stage", "geometric")
    gname = label(vgeo)
    e = {"nominal": np.linalg.norm(check.xyz_mm - chain.tool_point(check.q), axis=1),
         gname: np.linalg.norm(check.xyz_mm - vgeo.predict(check.q), axis=1)}
    if label(geo) not in e:
        e[label(geo)] = np.linalg.norm(check.xyz_mm - pred, axis=1)
    if core["learner"] is not None:
        e["learned"] = np.linalg.norm(check.xyz_mm - vgeo.predict(check.q) - core["learner"].predict(check.q), axis=1)
    if core.get("kept_learner") is not None and core["kept_stage"] not in e:
        e[core["kept_stage"]] = np.linalg.norm(check.xyz_mm - pred - core["kept_learner"].predict(check.q), axis=1)
    figs = []
    fig, ax = plt.subplots(figsize=(7, 3.5))
    order = np.argsort(e[gname])
    for k, v in e.items():
        ax.plot(v[order], "o", ms=3, label=f"{k} (mean {v.mean():.3g} mm)")
    ax.set_yscale("log")
    ax.set_xlabel("held-out pose (sorted by geometric error)")
    ax.set_ylabel("|measured − model| (mm)")
    ax.legend(fontsize=8)
    figs.append(figure(fig, "per-pose errors", "Measured residual per held-out pose, each stage.", dpi=FIG_DPI))
    kept = e[core["kept_stage"]] if core["kept_stage"] in e else e[label(geo)]
    fig, axs = plt.subplots(1, 2, figsize=(8, 3.5))
    for ax, (i, j, lab) in zip(axs, ((0, 1, "x–y"), (0, 2, "x–z"))):
        sc = ax.scatter(check.xyz_mm[:, i], check.xyz_mm[:, j], c=kept, s=10, cmap="viridis")
        ax.set_xlabel("xyz"[i] + " (mm)")
        ax.set_ylabel("xyz"[j] + " (mm)")
        ax.set_title(lab)
    fig.colorbar(sc, ax=axs, label=f"{core['kept_stage']} error (mm)")
    figs.append(figure(fig, "residual over the workspace", "Held-out tool points coloured by the kept stage's "
                       "measured residual.", dpi=FIG_DPI))
    band = np.sqrt(geo.band_std_mm(check.q) ** 2 + geo.sigma_mm ** 2)
    r = check.xyz_mm - pred
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(np.abs(r).ravel(), "o", ms=2, label="|residual| per component")
    ax.plot(Z95 * band.ravel(), "-", lw=1, color="tab:red", label="95 % prediction band (J Σ Jᵀ + σ²)")
    ax.set_xlabel("held-out pose × component")
    ax.set_ylabel("mm")
    cov = float(np.mean(np.abs(r) <= Z95 * band))
    ax.set_title(f"{label(geo)} stage: {100 * cov:.1f} % of components inside the 95 % band")
    ax.legend(fontsize=8)
    figs.append(figure(fig, "prediction bands", "Geometric stage's 95 % prediction band and the held-out residual.",
                       dpi=FIG_DPI))
    return figs


def fixed_slots_text(names) -> str:
    """The slots a fit held at nominal, for a reader: every slot by name, except a joint-error table's knots, which
    are counted per joint (``table.q1: 58 knots``) — a table has ~70 knots a joint, most of them held where the
    poses give them no support, and listing each buried the page's other slots."""
    plain, knots = [], {}
    for n in names:
        m = TABLE_KNOT_RE.match(n)
        if m:
            knots[m.group(1)] = knots.get(m.group(1), 0) + 1
        else:
            plain.append(n)
    plain += [f"table.{j}: {k} knot{'s' if k > 1 else ''}" for j, k in knots.items()]
    return ", ".join(plain) or "none"


def render_html(doc: dict, figures=()) -> str:
    """The page of an arm calibration document (``model.json``) with the given figures."""
    rows = [[("stage: " if i < len(doc["stages"]) else "baseline: ") + r["name"], r["mean_mm"], r["rms_mm"],
             r["max_mm"], r["what"]] for i, r in enumerate(doc["stages"] + doc["baselines"])]
    # css "notes": the last column (what each row is, a sentence) wraps instead of running off the page
    stages = Table(["model", "mean (mm)", "RMS (mm)", "max (mm)", "what"], rows, digits=4, css_class="notes")
    combos = Table(["unidentifiable combination (scaled null-space direction)"],
                   [[c] for c in doc["geometric"]["unidentifiable_combinations"]])
    params = Table(["slot", "value", "std error"], [[p["name"], p["value"], p["std"]]
                                                   for p in doc["geometric"]["parameters"] if p["identified"]], digits=4)
    ls = doc.get("learned_summary")
    learned = None if ls is None else Table(
        ["candidate (CV inside the fit poses)", "CV RMS (mm)", "mean gain over zero (mm²)", "its std error (mm²)",
         "95 % coverage before calibration"],
        [[("geometric stage alone" if k == "zero" else k), r["cv_rms"], r["gain_mean"], r["gain_se"], r["coverage_95"]]
         for k, r in ls["cv_table"].items()], digits=4)
    gcv = doc.get("geometric_cv") or []
    geocv = Table(["slot set", "CV mean (mm)", "CV RMS (mm)"], [[r["model"], r["cv_mean_mm"], r["cv_rms_mm"]]
                                                                for r in gcv], digits=4) if gcv else None
    bc = doc.get("band_calibration")
    bands = None if not bc else Table(
        ["blocking of the fit poses (inner CV)", "blocks", "factor", "95 % coverage before", "after"],
        [[name, b["n_blocks"], b["factor"], b["coverage95_before"], b["coverage95_after"]]
         for name, b in bc["blockings"].items()], digits=3)
    return render_page("arm_calibrate.html", title=f"arm calibration: {doc['machine']['name']}", doc=doc,
                       fixed_slots=fixed_slots_text(doc["geometric"]["fixed_slots"]), stages=stages, combos=combos, parameters=params, learned=learned, geocv=geocv,
                       bands=bands, figures=list(figures))


def write_report(doc: dict, chain, core, check, out) -> Path:
    """``out/report.html`` (atomic) of an arm calibration."""
    return write_page(Path(out) / "report.html", render_html(doc, _figures(chain, core, check)))
