"""The method-comparison report: a :class:`~compensation.app.workflows.compare.Comparison` on disk.

:func:`write_report` writes, atomically, ``report.html`` (the toolkit's ``compare.html`` page: each method's
residual per point as ``|r|`` and ``|r|²`` μm, max and mean, solver times; every plot and table names its
residual, **model** or **true**), ``metrics.json`` (per method ``model_max_um`` …, ``true_*`` with a truth,
``seconds``, ``points``, ``nfev``, ``failures``; ``uncompensated``; ``residuals``: the definitions) and
``residuals.csv`` (per point, the methods that ran on every point; a method run on a subset has its own
``residuals_<method>.csv``). Keys and columns: docs/reference/tool-paths.md ("volcomp report").
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from errormap.io import write_csv, write_json

from ...evaluate import RESIDUAL_DEFINITIONS
from .figures import pyplot
from .toolkit import Figure, Table, figure, kv_table, num, render_page, write_page

if TYPE_CHECKING:  # annotations only: the comparison is built by the compare workflow
    from ..workflows.compare import Comparison

# ----------------------------------------------------------------------------- plots

COLORS = {"traditional": "tab:red", "ga": "tab:green", "batched-ga": "tab:blue", "exact": "tab:purple",
          "uncompensated": "0.6"}


FIG_DPI = 110


def _residual_plot(cmp: Comparison, kind: str, squared: bool) -> Figure | None:
    plt = pyplot()

    series = []
    for name, run in cmp.runs.items():
        r = run.result.residual_um if kind == "model" else run.true_residual_um
        if r is None:
            continue
        series.append((name, run.index, np.linalg.norm(np.asarray(r), axis=1)))
    base = cmp.baseline_model_um if kind == "model" else cmp.baseline_true_um
    if not series:
        return None
    fig, ax = plt.subplots(figsize=(11, 4.2))
    if kind == "true" and base is not None:
        series.insert(0, ("uncompensated", np.arange(len(base)), np.linalg.norm(base, axis=1)))
    for name, idx, v in series:
        y = v**2 if squared else v
        y = np.maximum(y, 1e-12)
        style = dict(color=COLORS.get(name), label=name, lw=0.8)
        if len(idx) < len(cmp.targets_mm) / 4:
            ax.plot(idx, y, "o", ms=2.5, **{k: v for k, v in style.items() if k != "lw"})
        else:
            ax.plot(idx, y, **style)
    for k in np.flatnonzero(np.diff(cmp.turn_of_point)) + 1:
        ax.axvline(k, color="0.85", lw=0.6, zorder=0)
    ax.set_yscale("log")
    ax.set_xlabel("interpolation point (" + ("grey lines: turns of the rotary axis; " if cmp.turn_of_point.any() else "")
                  + "values below 1e-12 drawn at 1e-12)")
    unit = "μm²" if squared else "μm"
    ax.set_ylabel(f"{kind} residual {'|r|²' if squared else '|r|'} ({unit})")
    ax.set_title(f"{kind.upper()} residual per interpolation point{' (squared)' if squared else ''}")
    # the legend sits outside the axes: inside, it hid the top curve (the uncompensated residual)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.grid(True, which="major", alpha=0.3)
    caption = RESIDUAL_DEFINITIONS[kind] + (" — squared, the grinder paper’s Fig. 18 kind" if squared and kind == "model"
                                            else "")
    return figure(fig, f"{kind} residual{' squared' if squared else ''} per interpolation point", caption, dpi=FIG_DPI)


def _times_plot(cmp: Comparison) -> Figure:
    plt = pyplot()
    names = list(cmp.runs)
    secs = [cmp.runs[k].metrics["seconds"] for k in names]
    per = [cmp.runs[k].metrics["seconds"] / max(cmp.runs[k].metrics["points"], 1) * 1e3 for k in names]
    fig, axs = plt.subplots(1, 2, figsize=(10, 3))
    axs[0].bar(names, secs, color=[COLORS.get(k) for k in names])
    axs[0].set_ylabel("solver wall time (s)")
    axs[1].bar(names, per, color=[COLORS.get(k) for k in names])
    axs[1].set_ylabel("per point (ms)")
    for a in axs:
        a.set_yscale("log")
        a.grid(True, axis="y", alpha=0.3)
    fig.suptitle("Solver times")
    return figure(fig, "solver times", "Solver wall time per method (total and per point).", dpi=FIG_DPI,
                  tight_layout=True)


RESIDUAL_DIGITS = 4
"""Significant digits of the residuals in the table (a sub-nanometre model residual still shows its size)."""


def render_html(cmp: Comparison, title: str, context: dict, kind: str = "report") -> str:
    """The report as one self-contained HTML page (``templates/compare.html``); ``kind`` names the
    command that wrote it (``report`` or ``demo``)."""
    has_true = cmp.baseline_true_um is not None
    head = ["method", "points", "MODEL max |r| (μm)", "MODEL mean |r| (μm)", "MODEL max |r|² (μm²)",
            "MODEL mean |r|² (μm²)"]
    keys = ["model_max_um", "model_mean_um", "model_max_sq_um2", "model_mean_sq_um2"]
    if has_true:
        head += ["TRUE max |r| (μm)", "TRUE mean |r| (μm)", "TRUE max |r|² (μm²)", "TRUE mean |r|² (μm²)"]
        keys += ["true_max_um", "true_mean_um", "true_max_sq_um2", "true_mean_sq_um2"]
    head += ["solver (s)", "failures", "max correction (μm)"]
    rows = [[k, m.get("points"), *[m.get(key) for key in keys], m.get("seconds"), m.get("failures"),
             m.get("max_correction_um")]
            for k, m in [(k, r.metrics) for k, r in cmp.runs.items()] + [("uncompensated", cmp.baseline)]]
    figures = [f for kind_ in (("model", "true") if has_true else ("model",)) for sq in (False, True)
               if (f := _residual_plot(cmp, kind_, sq)) is not None]
    return render_page("compare.html", title=title, kind=kind, has_true=has_true,
                       definitions={k: v.split(": ", 1)[-1] for k, v in RESIDUAL_DEFINITIONS.items()},
                       setting=kv_table(context), methods=Table(head, rows, digits=RESIDUAL_DIGITS),
                       notes=[r.note for r in cmp.runs.values() if r.note], residual_figures=figures,
                       times_figure=_times_plot(cmp))


def write_report(cmp: Comparison, out_dir, title: str = "volcomp compensation report", context: dict | None = None,
                 extra_metrics: dict | None = None, kind: str = "report") -> dict:
    """Write report.html, metrics.json and residuals.csv into ``out_dir`` (each atomically).

    Returns ``{"html": path, "metrics": path, "residuals": path}`` and ``"residuals_<method>"`` for each method
    run on a subset of the points.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    n = len(cmp.targets_mm)

    def point_columns(idx):
        return {"point": np.arange(n)[idx], **{c: cmp.nominal_axes[idx, j] for j, c in enumerate(cmp.columns)}}
    cols = dict(point_columns(np.arange(n)), uncompensated_model_um=np.linalg.norm(cmp.baseline_model_um, axis=1))
    if cmp.baseline_true_um is not None:
        cols["uncompensated_true_um"] = np.linalg.norm(cmp.baseline_true_um, axis=1)
    subsets = {}   # methods run on some points only: their own file, those rows only (never NaN padding)
    for k, r in cmp.runs.items():
        idx = np.asarray(r.index)
        full = len(idx) == n and np.array_equal(idx, np.arange(n))
        dest = cols if full else subsets.setdefault(k, point_columns(idx))
        for which, arr in (("model", r.result.residual_um), ("true", r.true_residual_um)):
            if arr is not None:
                dest[f"{k}_{which}_um"] = np.linalg.norm(np.asarray(arr), axis=1)
    head = ["format: volcomp-residuals/1", "columns *_model_um: |model residual|, *_true_um: |true residual| (μm)"]
    paths = {"residuals": write_csv(out / "residuals.csv", cols, header_comments=head + (
        ["methods run on a subset of the points have their own files: "
         + ", ".join(f"residuals_{k}.csv" for k in subsets)]
        if subsets else []))}
    for k, c in subsets.items():
        paths[f"residuals_{k}"] = write_csv(out / f"residuals_{k}.csv", c, header_comments=head + [
            f"method {k} ran on {len(c['point'])} of the {n} points (its budget): these rows only; 'point' is the "
            "row's point number in residuals.csv"])
    metrics = cmp.metrics()
    if context:
        metrics["context"] = context
    if extra_metrics:
        metrics.update(extra_metrics)
    paths["metrics"] = write_json(out / "metrics.json", metrics)
    paths["html"] = write_page(out / "report.html", render_html(cmp, title, context or {}, kind))
    return paths


def print_table(cmp: Comparison, stream=None) -> None:
    """A plain-text max/mean table of the residuals (model, and true when known)."""
    stream = sys.stdout if stream is None else stream
    has_true = cmp.baseline_true_um is not None
    hdr = f"{'method':<14}{'points':>7}{'model max um':>14}{'model mean um²':>16}"
    if has_true:
        hdr += f"{'true max um':>13}{'true mean um':>14}"
    hdr += f"{'seconds':>10}"
    print(hdr, file=stream)
    for k, m in [(k, r.metrics) for k, r in cmp.runs.items()] + [("uncompensated", cmp.baseline)]:
        line = (f"{k:<14}{m['points']:>7}{num(m.get('model_max_um'), RESIDUAL_DIGITS):>14}"
                f"{num(m.get('model_mean_sq_um2'), RESIDUAL_DIGITS):>16}")
        if has_true:
            line += f"{num(m.get('true_max_um'), RESIDUAL_DIGITS):>13}{num(m.get('true_mean_um'), RESIDUAL_DIGITS):>14}"
        line += f"{num(m.get('seconds')):>10}"
        print(line, file=stream)
