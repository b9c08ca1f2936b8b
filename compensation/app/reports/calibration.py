"""The PKM calibration report (``volcomp calibrate``): PNG plots and ``report.html``."""
from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from errormap.io import atomic_write

from .figures import pyplot


def _save(fig, path: Path) -> None:
    """Save a figure as PNG atomically."""
    import io
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


def write_plots(result, before, after, out: Path) -> list[Path]:
    """Singular values, held-out residual and L-curve PNGs in ``out`` (atomic); their paths."""
    plt = pyplot()
    paths = []
    fig, ax = plt.subplots(figsize=(6, 3.5))
    s = result.singular_values
    if result.singular_values_raw is not None:
        sr = result.singular_values_raw
        ax.semilogy(np.arange(1, sr.size + 1), np.maximum(sr, 1e-18), "x", ms=4, color="0.5",
                    label=f"raw (all directions), cond {result.condition_number_raw:.3g}")
    ax.semilogy(np.arange(1, s.size + 1), np.maximum(s, 1e-18), "o-", ms=3,
                label=f"identifiable subspace, cond {result.condition_number:.3g}")
    if result.lam > 0:
        ax.axhline(np.sqrt(result.lam), color="r", ls="--", label=f"sqrt(lambda) ({result.lambda_rule})")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled J)")
    ax.set_title(f"condition number {result.condition_number:.3g} (raw {result.condition_number_raw:.3g})")
    ax.legend()
    fig.tight_layout()
    paths.append(out / "singular_values.png")
    _save(fig, paths[-1])
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(before, "o", ms=3, label=f"nominal (RMS {np.sqrt(np.mean(before ** 2)):.1f} um)")
    ax.plot(after, "o", ms=3, label=f"calibrated (RMS {np.sqrt(np.mean(after ** 2)):.1f} um)")
    ax.set_yscale("log")
    ax.set_xlabel("held-out pose")
    ax.set_ylabel("measured residual |dp| (um)")
    ax.legend()
    fig.tight_layout()
    paths.append(out / "heldout_residual.png")
    _save(fig, paths[-1])
    plt.close(fig)
    c = result.lcurve
    if "residual_norm" in c:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.loglog(c["residual_norm"], c["solution_norm"], "-")
        for lam, lab, col in ((result.lambda_lcurve, "L-curve corner", "g"), (result.lambda_gcv, "GCV", "b"),
                              (result.lambda_morozov, "Morozov", "r")):
            if np.isfinite(lam) and lam > 0:
                i = int(np.argmin(np.abs(np.log(c["lambda"]) - np.log(lam))))
                ax.plot(c["residual_norm"][i], c["solution_norm"][i], "o", color=col, label=f"{lab} {lam:.3g}")
        ax.legend(fontsize=8)
        ax.set_xlabel("|J w - b| (mm)")
        ax.set_ylabel("|w| (scaled)")
        ax.set_title("L-curve of the final linearisation")
        fig.tight_layout()
        paths.append(out / "lcurve.png")
        _save(fig, paths[-1])
        plt.close(fig)
    return paths


def write_html(doc: dict, pngs: list[Path], out: Path) -> Path:
    """``out/report.html`` (atomic) from ``calibration.json``'s document and the PNGs."""
    rows = "".join(f"<tr><td>{k}</td><td>{v['value']:.6f}</td><td>{v['delta']:+.4f}</td><td>{v['std_error']:.2g}</td></tr>"
                   for k, v in doc["parameters"].items())
    imgs = "".join(f'<p><img src="data:image/png;base64,{base64.b64encode(p.read_bytes()).decode()}"></p>' for p in pngs)
    summary = (f"<p>Measured residual (measurement minus model) on {doc['n_check_poses']} held-out poses: "
               f"RMS {doc['rms_before_um']:.2f} &rarr; {doc['rms_after_um']:.2f} um, max {doc['max_before_um']:.2f} "
               f"&rarr; {doc['max_after_um']:.2f} um. Fit poses: {doc['n_fit_poses']}. lambda ({doc['lambda_rule']}) "
               f"{doc['lambda']:.3g}, GCV {doc['lambda_gcv']:.3g}, L-curve {doc['lambda_lcurve']:.3g}; delta "
               f"{doc['delta_um']:.3g} um ({'estimated' if doc['delta_estimated'] else 'given'}); condition number "
               f"{doc['condition_number']:.3g} on the identifiable subspace (raw, gauge directions included: "
               f"{doc['condition_number_raw'] if doc['condition_number_raw'] is not None else float('inf'):.3g}); "
               f"{len(doc['unidentifiable'])} unidentifiable combinations ({doc['n_gauge']} fixed by the gauge).</p>")
    summary += (f"<p><b>success: {str(doc['success']).lower()}</b>"
                + "".join(f"<br>reason: {r}" for r in doc["success_reasons"])
                + "".join(f"<br>note: {n}" for n in doc["notes"]) + "</p>")
    summary += ("<h2>Held-out poses: nominal, volcomp, plain baseline</h2><table border=1><tr><th>model</th>"
                "<th>RMS / max um</th></tr>"
                f"<tr><td>nominal</td><td>{doc['rms_before_um']:.2f} / {doc['max_before_um']:.2f}</td></tr>"
                f"<tr><td>volcomp rigid</td><td>{doc['volcomp']['rigid_rms_um']:.2f}</td></tr>"
                f"<tr><td>volcomp (returned model candidate)</td><td>{doc['volcomp']['rms_um']:.2f} / "
                f"{doc['volcomp']['max_um']:.2f}</td></tr>"
                f"<tr><td>{doc['baseline']['what']}</td><td>{doc['baseline']['rms_um']:.2f} / "
                f"{doc['baseline']['max_um']:.2f}</td></tr></table><p>returned: {doc['returned_model']}</p>")
    loop = doc.get("loop", {})
    if loop.get("run"):
        summary += ("<h2>Loop on leg residuals</h2><table border=1><tr><th>round</th><th>term</th><th>leg</th>"
                    "<th>CV RSS before / after mm^2</th><th>gain</th><th>F</th><th>p</th><th>accepted</th></tr>"
                    + "".join(f"<tr><td>{r['round']}</td><td>{r['family']}</td><td>{r['leg']}</td>"
                              f"<td>{r['cv_rss_before_mm2']:.4g} / {r['cv_rss_after_mm2']:.4g}</td>"
                              f"<td>{r['cv_gain']:.1%}</td><td>{r['F']:.3g}</td><td>{r['p_value']:.2g}</td>"
                              f"<td>{r['passes']}</td></tr>" for rows in loop["rounds"] for r in rows)
                    + "</table>")
    if "lambda_comparison" in doc:
        summary += ("<h2>Choice of lambda</h2><table border=1><tr><th>rule</th><th>lambda</th><th>delta um</th>"
                    "<th>held-out RMS / max um</th></tr>" + "".join(
                        f"<tr><td>{r['rule']}</td><td>{r['lambda']:.3g}</td><td>{r['delta_um']:.3g}</td>"
                        f"<td>{r['heldout_rms_um']:.2f} / {r['heldout_max_um']:.2f}</td></tr>"
                        for r in doc["lambda_comparison"]["rules"]) + "</table>")
    html = (f"<!doctype html><html><head><meta charset='utf-8'><title>PKM calibration</title></head><body>"
            f"<h1>PKM calibration: {doc['machine']['name']}</h1>{summary}{imgs}"
            f"<h2>Parameters</h2><table border=1><tr><th>name</th><th>value</th><th>delta</th><th>std error</th></tr>"
            f"{rows}</table></body></html>")
    with atomic_write(out / "report.html", "w", encoding="utf-8") as fh:
        fh.write(html)
    return out / "report.html"
