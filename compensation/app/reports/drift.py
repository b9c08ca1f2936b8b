"""The page of a drift-log diagnosis (``drift.html``): :func:`drift_report` takes what the drift workflow
(:mod:`compensation.app.workflows.drift`) computed and returns one self-contained page (matplotlib Agg figures,
embedded by the report toolkit)."""
from __future__ import annotations

import numpy as np

from .figures import pyplot
from .toolkit import Table, figure, render_page

FIG_DPI = 90


def drift_report(log, sel, channels, log_path) -> str:
    """The ``drift.html`` page of a drift-log diagnosis: ``sel`` a fitted DriftSelector, ``channels`` its report."""
    plt = pyplot()
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
        figures.append(figure(fig, ch, f"{ch}: displacement before and after the drift model over time (dashed: "
                                        "start of the held-out part) and the held-out histogram.", dpi=FIG_DPI,
                                      tight_layout=True))
    return render_page("drift.html", title="volcomp diagnose — drift log", log=str(log_path),
                       n_fit=len(log.time_s) - len(hold), n_hold=len(hold), repaired=repaired, channels=table,
                       sensors=sensors, figures=figures)
