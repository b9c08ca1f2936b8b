"""The benchmark's self-contained HTML report (tables, PNG plots inlined as base64, matplotlib Agg).

``render_html(doc)`` takes the ``benchmark.json`` document of :func:`compensation.app.workflows.benchmark.run_benchmark`
and returns the page. Every number on it comes from the rows; the "where each path wins" lines
are computed from them (:func:`verdicts`).
"""
from __future__ import annotations

import functools
import html

import numpy as np

from .figures import png_base64, pyplot

PATH_COLORS = {"parametric": "tab:blue", "learned": "tab:orange"}
PLOT_FLOOR_UM = 0.01
"""Line plots draw values below this (noise-free exact compensation, ~1e-9 μm) at this floor."""


_png = functools.partial(png_base64, dpi=100)
_plt = pyplot


def _fmt(v, spec=".3g") -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return format(float(v), spec)
    return html.escape(str(v))


def _rows(doc, kind=None, group=None, path=None, available=True):
    out = []
    for r in doc["rows"]:
        if kind and r["machine_kind"] != kind:
            continue
        if group and r.get("group") != group:
            continue
        if path and r["path"] != path:
            continue
        if available is not None and bool(r.get("available")) != available:
            continue
        out.append(r)
    return out


def _line_plot(doc, kind, select, xkey, xlabel, title) -> str | None:
    """True RMS and max against ``xkey`` for the rows of ``kind`` that ``select(row)`` keeps."""
    plt = _plt()
    rows = [r for r in _rows(doc, kind) if select(r)]
    if not rows:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, (key, lab) in zip(axes, (("true_rms_um", "true residual RMS (μm)"), ("true_max_um", "true residual max (μm)"))):
        for p in ("parametric", "learned"):
            pts = sorted((r[xkey], max(r[key], PLOT_FLOOR_UM)) for r in rows if r["path"] == p and r.get(key) is not None)
            if pts:
                x, y = zip(*pts)
                ax.plot(x, y, "o-", color=PATH_COLORS[p], label=p)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(lab)
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(title + f" (values < {PLOT_FLOOR_UM:g} μm drawn at {PLOT_FLOOR_UM:g})")
    return _png(fig)


def _effects_plot(doc) -> str | None:
    plt = _plt()
    rows = _rows(doc, "grinder", "effect")
    effects = list(dict.fromkeys(r["effect"] for r in rows))
    if not effects:
        return None
    fig, ax = plt.subplots(figsize=(10, 3.8))
    bars = [("parametric", False), ("parametric", True), ("learned", False), ("learned", True)]
    w = 0.2
    for j, (p, loop) in enumerate(bars):
        vals = []
        for e in effects:
            v = [r["true_rms_um"] for r in rows if r["effect"] == e and r["path"] == p and bool(r.get("closed_loop")) == loop]
            vals.append(v[0] if v else np.nan)
        ax.bar(np.arange(len(effects)) + (j - 1.5) * w, vals, w, color=PATH_COLORS[p], alpha=1.0 if loop else 0.45,
               label=f"{p}, {'after' if loop else 'before'} closed loop")
    ax.set_xticks(np.arange(len(effects)))
    ax.set_xticklabels(effects)
    ax.set_ylabel("true residual RMS on the flute (μm)")
    ax.set_title("Undeclared effects in the truth: before / after the closed loop (diagnosis)")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def _cost_plot(doc) -> str | None:
    plt = _plt()
    rows = [r for r in _rows(doc) if r.get("fit_seconds") is not None]
    if not rows:
        return None
    kinds = list(dict.fromkeys(r["machine_kind"] for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    for ax, key, lab, scale in ((axes[0], "fit_seconds", "identification / training time (s)", 1.0),
                                (axes[1], "compensate_seconds_per_point", "compensation time per point (ms)", 1e3)):
        for j, p in enumerate(("parametric", "learned")):
            vals = []
            for k in kinds:
                v = [r[key] for r in rows if r["machine_kind"] == k and r["path"] == p and r.get(key) is not None]
                vals.append(np.median(v) * scale if v else np.nan)
            ax.bar(np.arange(len(kinds)) + (j - 0.5) * 0.35, vals, 0.35, color=PATH_COLORS[p], label=p)
        ax.set_xticks(np.arange(len(kinds)))
        ax.set_xticklabels(kinds)
        ax.set_ylabel(lab + " (median)")
        ax.set_yscale("log")
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend()
    return _png(fig)


def verdicts(doc) -> list[str]:
    """One line per (machine kind, condition): which path has the lower true RMS, and by how much."""
    out = []
    by = {}
    for r in _rows(doc):
        by.setdefault((r["machine_kind"], r["condition"]), {})[r["path"]] = r
    for (kind, cond), d in by.items():
        if "parametric" in d and "learned" in d:
            p, l = d["parametric"]["true_rms_um"], d["learned"]["true_rms_um"]
            win = "parametric" if p < l else "learned"
            ratio = max(p, l) / max(min(p, l), 1e-12)
            out.append(f"{kind}, {cond}: <b>{win}</b> (true RMS parametric {p:.3g} μm, learned {l:.3g} μm, "
                       f"×{ratio:.3g})")
    return out


def summary_lines(doc) -> list[str]:
    """Per machine kind: how many conditions each path wins, and the median ratio of true RMS."""
    out = []
    by = {}
    for r in _rows(doc):
        by.setdefault(r["machine_kind"], {}).setdefault(r["condition"], {})[r["path"]] = r["true_rms_um"]
    for kind, conds in by.items():
        pairs = [(d["parametric"], d["learned"]) for d in conds.values() if "parametric" in d and "learned" in d]
        if not pairs:
            continue
        p = np.array(pairs)
        wins = int(np.sum(p[:, 0] < p[:, 1]))
        out.append(f"{kind}: parametric lower true RMS in {wins} of {len(p)} conditions, learned in {len(p) - wins}; "
                   f"median learned / parametric RMS ratio {np.median(p[:, 1] / np.maximum(p[:, 0], 1e-12)):.3g}")
    return out


def _table(rows, cols) -> str:
    head = "".join(f"<th>{html.escape(c[1])}</th>" for c in cols)
    body = []
    for r in rows:
        tds = []
        for key, _, spec in cols:
            v = r.get(key)
            if key == "effects_found" and v is not None:
                v = ", ".join(v) or "none"
            tds.append(f"<td class='{r['path']}'>{_fmt(v, spec)}</td>")
        body.append("<tr>" + "".join(tds) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


GRINDER_COLS = [("condition", "condition", ""), ("path", "path", ""), ("true_rms_um", "true RMS μm", ".3g"),
                ("true_max_um", "true max μm", ".3g"), ("uncompensated_rms_um", "uncompensated RMS μm", ".3g"),
                ("volume_rms_um", "volume RMS μm", ".3g"), ("n_measurements", "measurements", ""),
                ("fit_seconds", "fit s", ".3g"), ("compensate_seconds_per_point", "compensate s/point", ".2e"),
                ("effects_found", "effects found", "")]
PKM_COLS = [("condition", "condition", ""), ("path", "path", ""), ("true_rms_um", "true RMS μm", ".3g"),
            ("true_max_um", "true max μm", ".3g"), ("uncompensated_rms_um", "uncompensated RMS μm", ".3g"),
            ("n_measurements", "poses", ""), ("fit_seconds", "fit s", ".3g"),
            ("compensate_seconds_per_point", "compensate s/point", ".2e")]


def _solver_table(rows) -> str:
    out = []
    for r in rows:
        for name, d in (r.get("solvers") or {}).items():
            out.append({"path": r["path"], "condition": r["condition"], "solver": name, **d})
    cols = [("condition", "condition", ""), ("path", "path", ""), ("solver", "solver", ""),
            ("points", "points", ""), ("true_rms_um", "true RMS μm", ".3g"), ("true_max_um", "true max μm", ".3g"),
            ("model_max_um", "model residual max μm", ".3g"), ("seconds_per_point", "s/point", ".2e"),
            ("failures", "not converged", "")]
    return _table(out, cols)


def _per_path_table(rows) -> str:
    out = []
    for r in rows:
        for name, d in (r.get("per_path") or {}).items():
            out.append({"path": r["path"], "condition": r["condition"], "test path": name, **d})
    cols = [("condition", "condition", ""), ("path", "path", ""), ("test path", "test path", ""),
            ("true_rms_um", "true RMS μm", ".3g"), ("true_max_um", "true max μm", ".3g")]
    return _table(out, cols)


CSS = """body{font-family:sans-serif;margin:24px;max-width:1250px;color:#222}
table{border-collapse:collapse;margin:8px 0 18px 0;font-size:13px}
td,th{border:1px solid #bbb;padding:3px 7px;text-align:right}th{background:#eee}
td:first-child,td:nth-child(2){text-align:left}td.learned{background:#fff6ec}td.parametric{background:#eef5fc}
img{max-width:100%;border:1px solid #ddd;margin:6px 0}.note{color:#555;font-size:13px}
h2{border-bottom:2px solid #ccc;padding-bottom:3px}"""


def render_html(doc: dict) -> str:
    s = doc["settings"]
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>volcomp benchmark</title>"
             f"<style>{CSS}</style></head><body>",
             "<h1>volcomp benchmark: learned vs parametric compensation</h1>",
             f"<p><b>Residual shown: the TRUE residual</b> — {html.escape(doc['residual'])}. "
             "RMS and max of the per-point vector norm along the test paths.</p>",
             f"<p class='note'>{'QUICK variant (reduced conditions and budgets). ' if s.get('quick') else ''}"
             f"Run time {doc['seconds']:.0f} s on {doc['environment']['cpus']} CPU(s); MLflow parent run "
             f"{_fmt(doc.get('parent_run_id'))} in {_fmt(doc.get('tracking_uri'))}. Truth seed {s['truth_seed']}, "
             f"seed {s['seed']}; one measurement draw per condition.</p>"]
    ver = verdicts(doc)
    summ = summary_lines(doc)
    if summ:
        parts.append("<h2>Summary (computed from the rows)</h2><ul>" + "".join(f"<li>{v}</li>" for v in summ) + "</ul>")
    if ver:
        parts.append("<h2>Where each path wins (computed from the rows)</h2><ul>"
                     + "".join(f"<li>{v}</li>" for v in ver) + "</ul>")
    na = _rows(doc, available=False)
    if na or doc.get("skipped"):
        parts.append("<h2>Not available</h2><ul>" + "".join(
            f"<li>{html.escape(r['machine_kind'])} / {html.escape(r['path'])} / {html.escape(r['condition'])}: "
            f"not available: {html.escape(str(r.get('not_available')))}</li>" for r in na) + "".join(
            f"<li>{html.escape(k['machine'])}: not available: {html.escape(k['why'])}</li>" for k in doc.get("skipped", []))
            + "</ul>")
    g = _rows(doc, "grinder", available=None)
    if g:
        pc = doc["path_conditions"]
        parts += ["<h2>Grinder: flute path</h2>",
                  "<p class='note'>Parametric: identified 23 elements → HTM field → exact inverse. Learned: the same "
                  f"identified elements → 11×11×11 feature points → BP network {tuple(s['hidden'])} ({s['activation']}, "
                  f"A {s['a_encoding']}), LM for at most {s['train_s']:g} s → exact (whole path; headline) and batched GA "
                  f"(population 40, {s['ga_generations']} generations, {s['ga_points']} evenly spaced points). The per-point "
                  "PyGAD GA is not run: at ~0.5–2 s per point it would take hours on the flute. Path condition: "
                  f"{html.escape(', '.join(f'{k} = {v:g}' for k, v in pc.items()))}. Measurements: stations × 3 balls × 3 "
                  f"axes (+ {s['n_checks']} check measurements after the closed loop). 'volume' = {s['volume_points']} "
                  "random points over the strokes (ρ ≥ 5 mm), exact compensation.</p>",
                  _table(g, GRINDER_COLS)]
        plain = ("density", "noise")
        sweeps = (("density", lambda r: r.get("group") in plain and r.get("noise_um") == s["base_noise_um"],
                   "stations", "stations per axis", f"against sweep density (noise {s['base_noise_um']:g} μm)"),
                  ("noise", lambda r: r.get("group") in plain and r.get("stations") == s["base_stations"],
                   "noise_um", "tracker noise σ (μm)", f"against tracker noise ({s['base_stations']} stations)"))
        for grp, sel, xkey, xl, t in sweeps:
            img = _line_plot(doc, "grinder", sel, xkey, xl, "Grinder: true residual on the flute " + t)
            if img:
                parts.append(f"<img alt='grinder {grp}' src='data:image/png;base64,{img}'>")
        img = _effects_plot(doc)
        if img:
            parts.append(f"<img alt='grinder effects' src='data:image/png;base64,{img}'>")
        parts += ["<h3>Per solver</h3>", _solver_table([r for r in g if r.get("available")])]
    for kind in ("hexapod", "tripod"):
        h = _rows(doc, kind, available=None)
        if not h:
            continue
        parts += [f"<h2>{kind.capitalize()}</h2>",
                  "<p class='note'>Parametric: Tikhonov/Morozov kinematic calibration (joints, zero lengths, scales) → "
                  "corrected inverse kinematics in the interpolation. Learned: MLP "
                  f"{tuple(s['pkm_hidden'])} (tanh, ridge {s['pkm_ridge']:g}, LM ≤ {s['pkm_train_s']:g} s) from commanded "
                  "pose to measured pose error → commanded pose iterated 6 times. Same simulated poses for both "
                  f"(instrument frame known; ~{s['pkm_pose_error_mm']:g} mm RMS error before).</p>",
                  _table(h, PKM_COLS), _per_path_table([r for r in h if r.get("available")])]
        sweeps = (("poses", lambda r: r.get("noise_um") == s["pkm_base_noise_um"], "n_poses", "measured poses",
                   f"against the number of poses (noise {s['pkm_base_noise_um']:g} μm)"),
                  ("noise", lambda r: r.get("n_poses") == s["pkm_base_poses"], "noise_um", "noise σ (μm)",
                   f"against measurement noise ({s['pkm_base_poses']} poses)"))
        for grp, sel, xkey, xl, t in sweeps:
            img = _line_plot(doc, kind, sel, xkey, xl, f"{kind.capitalize()}: true residual on the test paths {t}")
            if img:
                parts.append(f"<img alt='{kind} {grp}' src='data:image/png;base64,{img}'>")
    img = _cost_plot(doc)
    if img:
        parts += ["<h2>Cost</h2>", f"<img alt='cost' src='data:image/png;base64,{img}'>"]
    parts.append("</body></html>")
    return "\n".join(parts)


def markdown_table(doc: dict) -> str:
    """The main table (one line per machine and condition, both paths side by side) as Markdown."""
    by = {}
    for r in doc["rows"]:
        by.setdefault((r["machine_kind"], r["condition"]), {})[r["path"]] = r
    lines = ["| machine | condition | measurements | parametric RMS / max μm | learned RMS / max μm | "
             "uncompensated RMS μm | fit s (par / learned) | compensate ms/point (par / learned) |",
             "|---|---|---|---|---|---|---|---|"]

    def cell(r, a, b, scale=1.0, spec=".3g"):
        if r is None or not r.get("available"):
            return "n/a" if r is None else f"n/a: {r.get('not_available')}"
        va, vb = r.get(a), r.get(b)
        f = (lambda v: "—" if v is None else format(v * scale, spec))
        return f"{f(va)} / {f(vb)}" if b else f(va)

    for (kind, cond), d in by.items():
        p, l = d.get("parametric"), d.get("learned")
        any_r = p or l
        fit = " / ".join("—" if (x is None or x.get("fit_seconds") is None) else f"{x['fit_seconds']:.3g}" for x in (p, l))
        comp = " / ".join("—" if (x is None or x.get("compensate_seconds_per_point") is None)
                          else f"{1e3 * x['compensate_seconds_per_point']:.3g}" for x in (p, l))
        lines.append(f"| {kind} | {cond} | {any_r.get('n_measurements')} | {cell(p, 'true_rms_um', 'true_max_um')} | "
                     f"{cell(l, 'true_rms_um', 'true_max_um')} | {_fmt(any_r.get('uncompensated_rms_um'))} | {fit} | {comp} |")
    return "\n".join(lines)
