"""The benchmark's HTML report: the ``benchmark.html`` page of the report toolkit (:mod:`.toolkit`).

``render_html(doc)`` takes the ``benchmark.json`` document of :func:`compensation.app.workflows.benchmark.run_benchmark`
and returns the page. Every number on it comes from the rows; the "where each path wins" lines
are computed from them (:func:`verdicts`).
"""
from __future__ import annotations

import numpy as np
from markupsafe import Markup

from ..families import ARM, MACHINE_TOOL, PARALLEL
from .figures import pyplot
from .toolkit import Figure, Table, figure, num, render_page, um

PATH_COLORS = {"parametric": "tab:blue", "learned": "tab:orange", "hybrid": "tab:green"}
PLOT_FLOOR_UM = 0.01
"""Line plots draw values below this (noise-free exact compensation, ~1e-9 μm) at this floor."""


def machine_label(row) -> str:
    """What a row's lines name: a machine tool's machine (several share the kind ``machine-tool``), else the kind."""
    return row["machine"] if row["machine_kind"] in MACHINE_TOOL.kinds else row["machine_kind"]


def _stop(s: dict, prefix: str) -> str:
    """How training stopped: ``{prefix}_iter`` iterations of the settings, an optional ``{prefix}_s``."""
    secs = s[f"{prefix}_s"]
    return f"for {s[f'{prefix}_iter']} iterations" + (f" (at most {secs:g} s)" if secs is not None else "")


def verdict_failed(r) -> bool:
    """Whether a row's model (its diagnosis or calibration verdict, key ``model_verdict``) failed: such a row is
    shown, marked, and never counted (no win, no headline, no plot): :func:`_rows` with ``available=True`` skips it."""
    return (r.get("model_verdict") or {}).get("status") == "failed"


def _rows(doc, kinds=None, group=None, path=None, available=True):
    """The rows of ``doc`` of machines of ``kinds`` (a family's, :mod:`compensation.app.families`; None: all),
    ``group`` and ``path``; ``available``: True the rows that ran (and passed their verdict), None all."""
    return [r for r in doc["rows"] if (kinds is None or r["machine_kind"] in kinds)
            and (not group or r.get("group") == group) and (not path or r["path"] == path)
            and (available is None or bool(r.get("available")) == available)
            and not (available and verdict_failed(r))]


def _line_plot(rows, select, xkey, xlabel, title, alt) -> Figure | None:
    """True RMS and max against ``xkey`` for the counted ``rows`` (:func:`_rows`) that ``select(row)`` keeps."""
    plt = pyplot()
    rows = [r for r in rows if select(r)]
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
    return figure(fig, alt, tight_layout=True)


def _effects_plot(rows, name) -> Figure | None:
    """Before / after the closed loop per undeclared effect, of one machine tool's counted ``rows``."""
    plt = pyplot()
    rows = [r for r in rows if r.get("group") == "effect"]
    effects = list(dict.fromkeys(r["effect"] for r in rows))
    if not effects:
        return None
    fig, ax = plt.subplots(figsize=(10, 3.8))
    bars = [("parametric", False), ("parametric", True), ("learned", False), ("learned", True)]
    w = 0.2
    for j, (p, loop) in enumerate(bars):
        vals = [next((r["true_rms_um"] for r in rows if r["effect"] == e and r["path"] == p
                      and bool(r.get("closed_loop")) == loop), np.nan) for e in effects]
        ax.bar(np.arange(len(effects)) + (j - 1.5) * w, vals, w, color=PATH_COLORS[p], alpha=1.0 if loop else 0.45,
               label=f"{p}, {'after' if loop else 'before'} closed loop")
    ax.set_xticks(np.arange(len(effects)))
    ax.set_xticklabels(effects)
    ax.set_ylabel("true residual RMS on the test path (μm)")
    ax.set_title("Undeclared effects in the truth: before / after the closed loop (diagnosis)")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    return figure(fig, f"{name} effects")


def _cost_plot(doc) -> Figure | None:
    plt = pyplot()
    rows = [r for r in _rows(doc) if r.get("fit_seconds") is not None]
    if not rows:
        return None
    kinds = list(dict.fromkeys(machine_label(r) for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    for ax, key, lab, scale in ((axes[0], "fit_seconds", "identification / training time (s)", 1.0),
                                (axes[1], "compensate_seconds_per_point", "compensation time per point (ms)", 1e3)):
        for j, p in enumerate(("parametric", "learned")):
            vals = []
            for k in kinds:
                v = [r[key] for r in rows if machine_label(r) == k and r["path"] == p and r.get(key) is not None]
                vals.append(np.median(v) * scale if v else np.nan)
            ax.bar(np.arange(len(kinds)) + (j - 0.5) * 0.35, vals, 0.35, color=PATH_COLORS[p], label=p)
        ax.set_xticks(np.arange(len(kinds)))
        ax.set_xticklabels(kinds)
        ax.set_ylabel(lab + " (median)")
        ax.set_yscale("log")
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend()
    return figure(fig, "cost", tight_layout=True)


def verdicts(doc) -> list[str]:
    """One line per (machine kind, condition): which path has the lower true RMS, and by how much."""
    out = []
    by = {}
    for r in _rows(doc):
        by.setdefault((machine_label(r), r["condition"]), {})[r["path"]] = r
    for (kind, cond), d in by.items():
        if "parametric" in d and "learned" in d:
            p, l = d["parametric"]["true_rms_um"], d["learned"]["true_rms_um"]
            win = "parametric" if p < l else "learned"
            ratio = max(p, l) / max(min(p, l), 1e-12)
            out.append(Markup("{}, {}: <b>{}</b> (true RMS parametric {}, learned {}, ×{})").format(
                kind, cond, win, um(p), um(l), num(ratio)))
        if "parametric" in d and "hybrid" in d:
            p, h = d["parametric"]["true_rms_um"], d["hybrid"]["true_rms_um"]
            out.append(Markup("{}, {}: hybrid (learned residual {}) true RMS {} against the parametric loop's {} (×{})").format(
                kind, cond, "kept" if d["hybrid"].get("learned_kept") else "declined", um(h), um(p),
                num(p / max(h, 1e-12))))
    return out


def _ooc_pairs(rows) -> dict:
    """``{condition name: {"parametric": row, "hybrid": row}}`` of the out-of-catalogue group after the loop, of one
    machine tool's ``rows``."""
    by = {}
    for r in rows:
        if r.get("closed_loop") and r["path"] in ("parametric", "hybrid"):
            by.setdefault(r["condition"].replace(" (after closed loop)", ""), {})[r["path"]] = r
    return {k: v for k, v in by.items() if len(v) == 2}


def _checks_of(cond: str, row: dict):
    """The check count of an out-of-catalogue condition: the row's ``n_checks``, else the name's
    ``checks=N`` (None when neither says)."""
    if row.get("n_checks") is not None:
        return int(row["n_checks"])
    for part in cond.split(","):
        if part.strip().startswith("checks="):
            return int(part.strip().split("=", 1)[1])
    return None


def conclusion_lines(doc) -> list[str]:
    """The out-of-catalogue conclusion of each machine tool (:func:`_conclusion`), its lines named by the machine
    when the rows hold several."""
    rows = _rows(doc, MACHINE_TOOL.kinds, group="out-of-catalogue")
    names = list(dict.fromkeys(r["machine"] for r in rows))
    return [f"{n}: {line}" if len(names) > 1 else line for n in names
            for line in _conclusion([r for r in rows if r["machine"] == n])]


def _conclusion(rows) -> list[str]:
    """The out-of-catalogue conclusion, computed from the rows (never written by hand): per condition
    the compensated volume's TRUE RMS of the parametric loop and of the hybrid, the machine without
    an effect beside, whether the learned stage was kept, and the two ratios its conclusion judges."""
    pairs = _ooc_pairs(rows)
    if not pairs:
        return []
    key = "volume_rms_um"
    clean = {c: d for c, d in pairs.items() if c.startswith("effect=none")}
    out = []
    for cond, d in pairs.items():
        p, h = d["parametric"], d["hybrid"]
        suffix = cond.split(",", 1)[1].strip() if "," in cond else ""
        ref = next((v for c, v in clean.items() if (c.split(",", 1)[1].strip() if "," in c else "") == suffix), None)
        line = (f"{cond}: compensated volume TRUE RMS parametric loop {num(p.get(key))} μm, hybrid {num(h.get(key))} μm "
                f"(learned residual {'kept, ' + str(h.get('learned_family')) if h.get('learned_kept') else 'declined'}; "
                f"held-out checks RMS {num(h.get('checks_rms_after_um'))} μm at {num(h.get('check_noise_um'))} μm noise "
                f"per component)")
        if not cond.startswith("effect=none") and ref is not None and None not in (p.get(key), h.get(key)):
            base = ref["hybrid"].get(key)
            line += (f"; against the same machine without the effect ({num(base)} μm) ×{num(h[key] / max(base, 1e-12))}, "
                     f"parametric loop / hybrid ×{num(p[key] / max(h[key], 1e-12))}")
        out.append(line)
    eff = [(d["parametric"].get(key), d["hybrid"].get(key)) for c, d in pairs.items() if not c.startswith("effect=none")]
    eff = [(a, b) for a, b in eff if a is not None and b is not None]
    if eff:
        gains = np.array([a / max(b, 1e-12) for a, b in eff])
        kept = sum(bool(d["hybrid"].get("learned_kept")) for c, d in pairs.items() if not c.startswith("effect=none"))
        out.append(f"over {len(eff)} out-of-catalogue conditions: the learned stage was kept in {kept}; the hybrid "
                   f"lowers the parametric loop's volume RMS by ×{num(float(np.min(gains)))}–×{num(float(np.max(gains)))} "
                   f"(median ×{num(float(np.median(gains)))})")
    by_count = {}   # the same figures per check count (the condition's ", checks=N" suffix; none: n_checks)
    for c, d in pairs.items():
        if not c.startswith("effect=none") and None not in (d["parametric"].get(key), d["hybrid"].get(key)):
            by_count.setdefault(_checks_of(c, d["hybrid"]), []).append(d)
    if len(by_count) > 1:
        for n, ds in sorted(by_count.items(), key=lambda kv: (kv[0] is None, kv[0] or 0)):
            g = np.array([d["parametric"][key] / max(d["hybrid"][key], 1e-12) for d in ds])
            out.append(f"at {n if n is not None else '?'} checks: the learned stage kept in "
                       f"{sum(bool(d['hybrid'].get('learned_kept')) for d in ds)} of {len(ds)} out-of-catalogue "
                       f"conditions; parametric loop / hybrid ×{num(float(np.min(g)))}–×{num(float(np.max(g)))}")
    declined = [not d["hybrid"].get("learned_kept") for c, d in clean.items()]
    if declined:
        out.append(f"without an effect the learned stage was declined in {sum(declined)} of {len(declined)} conditions")
    return out


def summary_lines(doc) -> list[str]:
    """Per machine (a machine tool by its name, others by kind): how many conditions each path wins, and the median ratio of true RMS; where the
    closed loop has a hybrid row (the loop's learned residual on the checks), one more line: the hybrid
    against the parametric loop of the same checks, on the test path and on the compensated volume
    (equal where the learned stage was declined: the hybrid is then the loop)."""
    out = []
    by = {}
    for r in _rows(doc):
        by.setdefault(machine_label(r), {}).setdefault(r["condition"], {})[r["path"]] = r
    for kind, conds in by.items():
        pairs = [(d["parametric"]["true_rms_um"], d["learned"]["true_rms_um"]) for d in conds.values()
                 if "parametric" in d and "learned" in d]
        if pairs:
            p = np.array(pairs)
            wins = int(np.sum(p[:, 0] < p[:, 1]))
            out.append(f"{kind}: parametric lower true RMS in {wins} of {len(p)} conditions, learned in "
                       f"{len(p) - wins}; median learned / parametric RMS ratio "
                       f"{num(np.median(p[:, 1] / np.maximum(p[:, 0], 1e-12)))}")
        hyb = [(d["parametric"], d["hybrid"]) for d in conds.values() if "parametric" in d and "hybrid" in d]
        if hyb:
            out.append(f"{kind}: hybrid (the closed loop's learned residual) against the parametric loop on the same "
                       f"checks, {len(hyb)} conditions: {_hybrid_counts(hyb, 'true_rms_um')} on the test path; "
                       f"{_hybrid_counts(hyb, 'volume_rms_um')} on the compensated volume")
    return out


def _hybrid_counts(pairs, key) -> str:
    """'lower in a, equal in e (stage declined), higher in h; median parametric / hybrid ratio r' over the
    (parametric row, hybrid row) pairs that have ``key``; equal = the hybrid is the loop (declined)."""
    p = np.array([(a[key], b[key]) for a, b in pairs if a.get(key) is not None and b.get(key) is not None], float)
    if not len(p):
        return "no figures"
    eq = np.isclose(p[:, 0], p[:, 1], rtol=1e-12, atol=0.0)
    lower = int(np.sum(~eq & (p[:, 1] < p[:, 0])))
    higher = int(np.sum(~eq & (p[:, 1] > p[:, 0])))
    return (f"hybrid lower in {lower}, equal in {int(eq.sum())} (stage declined), higher in {higher}; median "
            f"parametric / hybrid RMS ratio {num(np.median(p[:, 0] / np.maximum(p[:, 1], 1e-12)))}")


def _verdict_text(r) -> str | None:
    v = r.get("model_verdict")
    return None if not v else "passed" if v.get("status") != "failed" else "FAILED: " + "; ".join(v.get("reasons", []))


def _table(rows, cols) -> Table:
    """``cols``: (key, header) pairs; one row per dict in ``rows``, its class the row's path; a column "model
    verdict" where a row carries one (a failed one says so and why)."""
    if any(r.get("model_verdict") for r in rows):
        cols = [*cols, ("_verdict", "model verdict")]
    return Table([c[1] for c in cols], [[_verdict_text(r) if key == "_verdict" else r.get(key) for key, _ in cols]
                                        for r in rows], row_classes=[r["path"] for r in rows], left=2)


PKM_COLS = [("condition", "condition"), ("path", "path"), ("true_rms_um", "true RMS (μm)"),
            ("true_max_um", "true max (μm)"), ("uncompensated_rms_um", "uncompensated RMS (μm)"),
            ("n_measurements", "poses"), ("fit_seconds", "fit (s)"),
            ("compensate_seconds_per_point", "compensate (s/point)")]
CHAIN_COLS = [("condition", "condition"), ("path", "path"), ("true_rms_um", "true RMS (μm)"),
              ("true_max_um", "true max (μm)"), ("uncompensated_rms_um", "uncompensated RMS (μm)"),
              ("uncompensated_max_um", "uncompensated max (μm)"), ("volume_rms_um", "volume RMS (μm)"),
              ("volume_uncompensated_rms_um", "volume uncompensated RMS (μm)"),
              ("checks_rms_after_um", "held-out measured RMS (μm)"),
              ("held_out_ols_linear_um", "held-out OLS baseline (μm)"), ("noise_floor_um", "noise floor (μm)"),
              ("effects_found", "effects found"), ("n_measurements", "measurements"), ("fit_seconds", "fit (s)")]

ARM_COLS = [("condition", "condition"), ("path", "path"), ("stage", "stage"), ("true_rms_um", "true RMS (μm)"),
            ("true_max_um", "true max (μm)"), ("uncompensated_rms_um", "uncompensated RMS (μm)"),
            ("checks_rms_after_um", "held-out measured RMS (μm)"), ("noise_floor_um", "noise floor (μm)"),
            ("n_measurements", "poses"), ("fit_seconds", "calibrate (CPU s)"),
            ("compensate_seconds_per_point", "compensate (CPU s/point)")]


def _sub_table(rows, key: str, label: str, cols) -> Table:
    """A line per entry of each row's ``key`` dict (``solvers``, ``per_path``), named in column ``label``."""
    out = [{"path": r["path"], "condition": r["condition"], label: name, **d}
           for r in rows for name, d in (r.get(key) or {}).items()]
    return _table(out, [("condition", "condition"), ("path", "path"), (label, label), *cols])


def _solver_table(rows) -> Table:
    return _sub_table(rows, "solvers", "solver", [
        ("points", "points"), ("true_rms_um", "true RMS (μm)"), ("true_max_um", "true max (μm)"),
        ("model_max_um", "model residual max (μm)"), ("seconds_per_point", "s/point"),
        ("failures", "not converged")])


def _per_path_table(rows) -> Table:
    return _sub_table(rows, "per_path", "test path",
                      [("true_rms_um", "true RMS (μm)"), ("true_max_um", "true max (μm)")])


def _machine_tool_part(doc, name) -> dict:
    """One machine tool's part of the page: its rows' table, true residual against sweep density and tracker noise,
    the undeclared effects before / after the closed loop, and the per-solver table."""
    s = doc["settings"]
    c = [r for r in _rows(doc, MACHINE_TOOL.kinds, available=None) if r["machine"] == name]
    counted = [r for r in _rows(doc, MACHINE_TOOL.kinds) if r["machine"] == name]
    plain = ("density", "noise")
    sweeps = (("density", lambda r: r.get("group") in plain and r.get("noise_um") == s["base_noise_um"],
               "stations", "stations per axis", f"against sweep density (noise {s['base_noise_um']:g} μm)"),
              ("noise", lambda r: r.get("group") in plain and r.get("stations") == s["base_stations"],
               "noise_um", "tracker noise σ (μm)", f"against tracker noise ({s['base_stations']} stations)"))
    figures = [_line_plot(counted, sel, xkey, xl, f"{name}: true residual on the test path " + t, f"{name} {grp}")
               for grp, sel, xkey, xl, t in sweeps] + [_effects_plot(counted, name)]
    return {"table": _table(c, CHAIN_COLS), "test_path": c[0].get("test_path"),
            "figures": [f for f in figures if f is not None],
            "solvers": _solver_table([r for r in c if r.get("available")])}


def render_html(doc: dict) -> str:
    """The benchmark page (``templates/benchmark.html``) of a ``benchmark.json`` document."""
    s = doc["settings"]
    not_available = [f"{r['machine_kind']} / {r['path']} / {r['condition']}: not available: {r.get('not_available')}"
                     for r in _rows(doc, available=False)]
    not_available += [f"{k['machine']}: not available: {k['why']}" for k in doc.get("skipped", [])]
    not_available += [f"{r['machine_kind']} / {r['path']} / {r['condition']}: not counted: its model's verdict "
                      f"{_verdict_text(r)}" for r in doc["rows"] if r.get("available") and verdict_failed(r)]
    chains = [(name, _machine_tool_part(doc, name)) for name in
              dict.fromkeys(r["machine"] for r in _rows(doc, MACHINE_TOOL.kinds, available=None))]
    arms = []
    for name in dict.fromkeys(r["machine"] for r in _rows(doc, ARM.kinds, available=None)):
        a = [r for r in _rows(doc, ARM.kinds, available=None) if r["machine"] == name]
        arms.append((name, {"table": _table(a, ARM_COLS), "test_path": a[0].get("test_path") or "a joint program"}))
    pkm = []
    for kind in PARALLEL.kinds:
        h = _rows(doc, (kind,), available=None)
        if not h:
            continue
        sweeps = (("poses", lambda r: r.get("noise_um") == s["pkm_base_noise_um"], "n_poses", "measured poses",
                   f"against the number of poses (noise {s['pkm_base_noise_um']:g} μm)"),
                  ("noise", lambda r: r.get("n_poses") == s["pkm_base_poses"], "noise_um", "noise σ (μm)",
                   f"against measurement noise ({s['pkm_base_poses']} poses)"))
        figures = [_line_plot(_rows(doc, (kind,)), sel, xkey, xl, f"{kind.capitalize()}: true residual on the test paths {t}",
                              f"{kind} {grp}") for grp, sel, xkey, xl, t in sweeps]
        pkm.append((kind, {"table": _table(h, PKM_COLS), "per_path": _per_path_table([r for r in h if r.get("available")]),
                           "figures": [f for f in figures if f is not None]}))
    return render_page("benchmark.html", title="volcomp benchmark: learned vs parametric compensation", doc=doc, s=s,
                       summary=summary_lines(doc) + conclusion_lines(doc), verdicts=verdicts(doc), not_available=not_available,
                       chains=chains, arms=arms, pkm=pkm, cost_figure=_cost_plot(doc),
                       train_stop=_stop(s, "train"), pkm_train_stop=_stop(s, "pkm_train"))

