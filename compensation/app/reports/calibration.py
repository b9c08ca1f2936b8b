"""The PKM calibration report (``volcomp calibrate``): PNG plots and ``report.html`` (``calibrate.html``).

:func:`write_plots` writes the figures as PNG files (``singular_values.png``, ``heldout_residual.png``,
``lcurve.png``); :func:`write_html` writes ``report.html`` with them embedded (the page does not
depend on the files beside it).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .figures import pyplot
from .toolkit import Figure, Table, figure, num, render_page, write_page

FIG_DPI = 110
LAMBDA_MARKERS = (("lambda_gcv", "GCV", "tab:blue", "o", 13), ("lambda_morozov", "Morozov", "tab:red", "s", 9),
                  ("lambda_lcurve", "L-curve corner", "tab:green", "^", 5))
"""The three lambda rules on the L-curve: hollow markers of decreasing size, so that rules choosing the
same (or a neighbouring) lambda stay visible one inside the other instead of hiding each other."""


def _rms(v) -> float:
    return float(np.sqrt(np.mean(np.asarray(v) ** 2)))


CAPTIONS = {"singular_values.png": ("singular values", "Singular values of the scaled Jacobian; the dashed line is "
                                                      "√λ of the chosen rule."),
            "heldout_residual.png": ("held-out measured residual", "Measured residual (position norm) per held-out "
                                                                   "pose, nominal and calibrated."),
            "lcurve.png": ("L-curve", "L-curve with the λ each rule chooses (markers nested where rules agree).")}


def calibration_figures(result, before_um, after_um) -> dict[str, Figure]:
    """Singular values, held-out residual per pose and the L-curve (when computed), by PNG file name."""
    plt = pyplot()
    out = {}
    fig, ax = plt.subplots(figsize=(6.5, 3.5))
    s = result.singular_values
    if result.singular_values_raw is not None:
        sr = result.singular_values_raw
        ax.semilogy(np.arange(1, sr.size + 1), np.maximum(sr, 1e-18), "x", ms=4, color="0.5",
                    label=f"raw (all directions), cond {num(result.condition_number_raw)}")
    ax.semilogy(np.arange(1, s.size + 1), np.maximum(s, 1e-18), "o-", ms=3,
                label=f"identifiable subspace, cond {num(result.condition_number)}")
    if result.lam > 0:
        ax.axhline(np.sqrt(result.lam), color="r", ls="--", label=f"√λ ({result.lambda_rule})")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled J)")
    ax.set_title(f"condition number {num(result.condition_number)} (raw {num(result.condition_number_raw)})")
    ax.legend(fontsize=8)
    out["singular_values.png"] = figure(fig, *CAPTIONS["singular_values.png"], dpi=FIG_DPI)
    fig, ax = plt.subplots(figsize=(6.5, 3.5))
    ax.plot(before_um, "o", ms=3, label=f"nominal (RMS {num(_rms(before_um))} μm)")
    ax.plot(after_um, "o", ms=3, label=f"calibrated (RMS {num(_rms(after_um))} μm)")
    ax.set_yscale("log")
    ax.set_xlabel("held-out pose")
    ax.set_ylabel("measured residual |dp| (μm)")
    ax.legend(fontsize=8)
    out["heldout_residual.png"] = figure(fig, *CAPTIONS["heldout_residual.png"], dpi=FIG_DPI)
    c = result.lcurve
    if "residual_norm" in c:
        fig, ax = plt.subplots(figsize=(6.5, 3.5))
        ax.loglog(c["residual_norm"], c["solution_norm"], "-", color="0.4", lw=1)
        for attr, lab, col, marker, size in LAMBDA_MARKERS:
            lam = getattr(result, attr)
            if np.isfinite(lam) and lam > 0:
                i = int(np.argmin(np.abs(np.log(c["lambda"]) - np.log(lam))))
                ax.plot(c["residual_norm"][i], c["solution_norm"][i], marker, ms=size, mfc="none", mew=1.5,
                        color=col, label=f"{lab}: λ = {num(lam)}")
        ax.legend(fontsize=8)
        ax.set_xlabel("|J w − b| (mm)")
        ax.set_ylabel("|w| (scaled)")
        ax.set_title("L-curve of the final linearisation")
        out["lcurve.png"] = figure(fig, *CAPTIONS["lcurve.png"], dpi=FIG_DPI)
    return out


def _tables(doc) -> dict:
    heldout = Table(["model", "RMS (μm)", "max (μm)"], [
        ["nominal", doc["rms_before_um"], doc["max_before_um"]],
        ["volcomp rigid", doc["volcomp"]["rigid_rms_um"], None],
        ["volcomp (returned model candidate)", doc["volcomp"]["rms_um"], doc["volcomp"]["max_um"]],
        [doc["baseline"]["what"], doc["baseline"]["rms_um"], doc["baseline"]["max_um"]]])
    loop = doc.get("loop", {})
    loop_table = None
    if loop.get("run"):
        loop_table = Table(["round", "term", "leg", "CV RSS before (mm²)", "CV RSS after (mm²)", "gain", "F", "p",
                            "accepted"],
                           [[r["round"], r["family"], r["leg"], r["cv_rss_before_mm2"], r["cv_rss_after_mm2"],
                             r["cv_gain"], r["F"], r["p_value"], r["passes"]] for rows in loop["rounds"] for r in rows],
                           formats={3: 4, 4: 4, 5: lambda v: num(100 * v, 3) + " %", 7: 2}, left=2)
    lambdas = None
    if "lambda_comparison" in doc:
        lambdas = Table(["rule", "λ", "δ (μm)", "held-out RMS (μm)", "held-out max (μm)"],
                        [[r["rule"], r["lambda"], r["delta_um"], r["heldout_rms_um"], r["heldout_max_um"]]
                         for r in doc["lambda_comparison"]["rules"]])
    params = Table(["name", "value", "delta", "std error"],
                   [[k, v["value"], v["delta"], v["std_error"]] for k, v in doc["parameters"].items()],
                   formats={1: lambda v: num(v) if v is None else f"{v:.6f}",
                            2: lambda v: num(v) if v is None else f"{v:+.4f}", 3: 2})
    return {"heldout": heldout, "loop": loop_table, "lambdas": lambdas, "parameters": params}


def write_plots(result, before, after, out: Path) -> list[Path]:
    """Singular values, held-out residual and L-curve PNGs in ``out`` (atomic); their paths.

    ``before``/``after`` (m,): the held-out measured residual per pose (μm), nominal and calibrated.
    """
    return [f.save(Path(out) / name) for name, f in calibration_figures(result, before, after).items()]


def render_html(doc: dict, figures: list[Figure]) -> str:
    """The page of ``model.json``'s document with ``figures`` embedded."""
    return render_page("calibrate.html", title=f"PKM calibration: {doc['machine']['name']}", doc=doc,
                       figures=figures, **_tables(doc))


def write_html(doc: dict, pngs: list[Path], out: Path) -> Path:
    """``out/report.html`` (atomic) from ``model.json``'s document and the PNGs (embedded)."""
    figures = [Figure.from_png(p, *CAPTIONS.get(Path(p).name, (Path(p).stem, None))) for p in pngs]
    return write_page(Path(out) / "report.html", render_html(doc, figures))
