"""Comparing the compensation methods on one tool path, and the self-contained HTML report.

:func:`compare_methods` runs each solver (``traditional``, ``ga``, ``batched-ga``, ``exact``)
on the same WCS targets with the same error field; the per-point reference ``ga`` may run on
an evenly spaced subset of the points when the whole path would take too long (the report
says so). :func:`write_report` writes, atomically:

* ``report.html`` — self-contained (PNG plots embedded as base64; matplotlib Agg): the
  residual per interpolation point for every method, as ``|r|`` and as ``|r|²`` (the
  grinder paper's Fig. 18 kind: the traditional residual repeats once per A turn), a
  table of max and mean per method, and the solver times. Every plot and table names its
  residual: **model** (the solver's own field) or **true** (the simulated truth machine).
* ``metrics.json`` — ``methods``: method name → ``model_max_um``, ``model_mean_um``,
  ``model_max_sq_um2``, ``model_mean_sq_um2``, ``true_max_um`` … (when a truth exists),
  ``seconds``, ``points``, ``nfev``, ``failures``, ``max_correction_um``, ``subset``;
  ``uncompensated`` (the same for the nominal commands); ``residuals`` (the definitions).
* ``residuals.csv`` — per point: the nominal axes and each method's ``|r|`` (model/true).
"""
from __future__ import annotations

import functools
import contextlib
import html
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import atomic_write, write_csv, write_json
from errormap.kinematics import inverse

from ...evaluate import RESIDUAL_DEFINITIONS, method_metrics, residual_stats, true_residual_um
from ...pathio import align_turns
from ...solvers import METHODS, solve
from .figures import png_base64, pyplot

REPORT_FORMAT = "volcomp-report/1"
GA_PROBE_POINTS = 3        # points timed to estimate the per-point GA cost
DEFAULT_GA_BUDGET_S = 120.0


@dataclass
class MethodRun:
    """One method's result on (a subset of) the path.

    index : shape (m,)            which path points were solved
    result : SolveResult          on targets[index]
    axes : shape (m, 3)           compensated axes, A aligned to the nominal turn
    true_residual_um : (m, 3) | None
    metrics : dict
    note : str                    e.g. why a subset was used
    """

    method: str
    index: np.ndarray
    result: object
    axes: np.ndarray
    true_residual_um: np.ndarray | None
    metrics: dict
    note: str = ""


@dataclass
class Comparison:
    """All methods on one path: nominal axes (n, 3), targets (n, 3), runs by method."""

    targets_mm: np.ndarray
    nominal_axes: np.ndarray
    runs: dict
    baseline: dict
    baseline_model_um: np.ndarray
    baseline_true_um: np.ndarray | None
    turn_of_point: np.ndarray
    info: dict = field(default_factory=dict)

    def metrics(self) -> dict:
        return {"format": REPORT_FORMAT, "residuals": dict(RESIDUAL_DEFINITIONS),
                "methods": {k: r.metrics for k, r in self.runs.items()},
                "uncompensated": self.baseline, **self.info}


def subset_index(n: int, m: int) -> np.ndarray:
    """``m`` evenly spaced indices into ``range(n)`` (all of them when ``m >= n``), shape (m,)."""
    if m >= n:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, max(m, 1))).astype(int))


SMALL_BATCH_POINTS = 500
"""Paths shorter than this are solved with one torch thread (see :func:`small_batch_threads`)."""


@contextlib.contextmanager
def small_batch_threads(method: str, n_points: int | None = None):
    """One torch thread while the field sees small batches (if torch is loaded).

    The per-point ``ga`` calls the field on 40 points at a time (and every solver does so on
    a short path); on a busy 2-core machine torch's intra-op threads then spin against each
    other and a call costs ~100× more than on one thread (measured: 81 ms vs 0.8 ms for
    40 points). Long paths in the batched solvers keep the default.
    """
    torch = sys.modules.get("torch")
    small = method == "ga" or (n_points is not None and n_points < SMALL_BATCH_POINTS)
    if not small or torch is None:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _solve(method, field_, targets, machine, options):
    with small_batch_threads(method, len(targets)):
        return solve(method, field_, targets, machine, **options)


def guard_counts(result, machine, field_, target_axes=None) -> dict:
    """Guard violations per guard name (reported, never enforced, in a comparison);
    ``target_axes`` (n, 3): the targets' nominal axes, checked too when given."""
    from ... import guards
    try:
        rep = guards.check(result, machine, field_, allow="all", target_axes=target_axes)
    except TypeError:  # a field that does not say where it is calibrated
        return {}
    return {g: int(len(v)) for g, v in rep.violations.items()}


def compare_methods(field_, targets_mm, machine, methods=METHODS, truth=None, ga_points: int | None = None,
                    ga_budget_s: float = DEFAULT_GA_BUDGET_S, seed: int = 0, solver_options: dict | None = None,
                    nominal_axes=None, log=None) -> Comparison:
    """Run ``methods`` on WCS targets (n, 3) with ``field_``; evaluate model and true residuals.

    ``ga`` runs on ``ga_points`` evenly spaced points when given; otherwise its cost per
    point is timed on ``GA_PROBE_POINTS`` points and it runs on as many evenly spaced points
    as fit in ``ga_budget_s`` seconds (all of them if they fit). ``seed`` goes to the
    stochastic solvers; ``solver_options`` maps method -> extra keyword options.
    """
    log = sys.stderr if log is None else log
    targets_mm = np.asarray(targets_mm, dtype=float)
    n = targets_mm.shape[0]
    nominal = inverse(machine, targets_mm, unwrap=True) if nominal_axes is None else np.asarray(nominal_axes, float)
    solver_options = solver_options or {}
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"Expected methods from {list(METHODS)}, got {unknown}")
    runs = {}
    for method in methods:
        opts = dict(solver_options.get(method, {}))
        opts.setdefault("target_axes", None)
        if method in ("ga", "batched-ga"):
            opts.setdefault("seed", seed)
        idx, note = np.arange(n), ""
        if method == "ga":
            if ga_points is not None:
                idx = subset_index(n, ga_points)
            else:
                probe = subset_index(n, min(GA_PROBE_POINTS, n))
                t0 = time.perf_counter()
                _solve(method, field_, targets_mm[probe], machine, {**opts, "target_axes": nominal[probe]})
                probe_s = time.perf_counter() - t0
                per_point_s = probe_s / len(probe)
                fit = int(max(ga_budget_s - probe_s, 0.0) / max(per_point_s, 1e-9))
                if fit < n:
                    idx = subset_index(n, max(fit, GA_PROBE_POINTS))
            if len(idx) < n:
                note = (f"per-point GA on {len(idx)} of {n} evenly spaced points "
                        f"(the whole path would take too long)")
                print(f"ga: {note}", file=log)
        print(f"{method}: solving {len(idx)} points ...", file=log)
        res = _solve(method, field_, targets_mm[idx], machine, {**opts, "target_axes": nominal[idx]})
        axes = np.array(res.axes, dtype=float)
        axes[:, 2] = align_turns(axes[:, 2], nominal[idx, 2])
        tr = true_residual_um(truth, axes, targets_mm[idx]) if truth is not None else None
        met = method_metrics(res, true_residual=tr)
        met["subset"] = bool(len(idx) < n)
        res.axes = axes
        met["guard_violations"] = guard_counts(res, machine, field_, target_axes=nominal[idx])
        if note:
            met["note"] = note
        runs[method] = MethodRun(method, idx, res, axes, tr, met, note)
        msg = f"{method}: {met['seconds']:.2f} s, model residual max {met['model_max_um']:.4g} um"
        if tr is not None:
            msg += f", true residual max {met['true_max_um']:.4g} um"
        print(msg, file=log)
    base_model = -field_.predict(nominal)  # uncompensated: the tool misses by E(p_d)
    base_true = true_residual_um(truth, nominal, targets_mm) if truth is not None else None
    baseline = {"points": n, **residual_stats(base_model, "model")}
    if base_true is not None:
        baseline.update(residual_stats(base_true, "true"))
    baseline["note"] = ("nominal commands, no compensation; the model residual here is the field's "
                        "predicted error E(axes(p_d)), with sign flipped")
    a0 = nominal[0, 2]
    turn = np.floor((nominal[:, 2] - a0) / 360.0 + 1e-9).astype(int)
    return Comparison(targets_mm, nominal, runs, baseline, base_model, base_true, turn)


# ----------------------------------------------------------------------------- plots

COLORS = {"traditional": "tab:red", "ga": "tab:green", "batched-ga": "tab:blue", "exact": "tab:purple",
          "uncompensated": "0.6"}


_png = functools.partial(png_base64, dpi=110)


def _residual_plot(cmp: Comparison, kind: str, squared: bool) -> str | None:
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
    fig, ax = plt.subplots(figsize=(10, 4.2))
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
    ax.set_xlabel("interpolation point (grey lines: A turns; values below 1e-12 drawn at 1e-12)")
    unit = "μm²" if squared else "μm"
    ax.set_ylabel(f"{kind} residual {'|r|²' if squared else '|r|'} ({unit})")
    ax.set_title(f"{kind.upper()} residual per interpolation point{' (squared)' if squared else ''}")
    ax.legend(loc="upper right", fontsize=8, ncol=5)
    ax.grid(True, which="major", alpha=0.3)
    return _png(fig)


def _times_plot(cmp: Comparison) -> str:
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
    return _png(fig)


def _fmt(v, spec=".4g") -> str:
    return "—" if v is None else format(v, spec)


def render_html(cmp: Comparison, title: str, context: dict) -> str:
    """The report as one self-contained HTML string."""
    has_true = cmp.baseline_true_um is not None
    rows = []
    entries = [(k, r.metrics) for k, r in cmp.runs.items()] + [("uncompensated", cmp.baseline)]
    for k, m in entries:
        cells = [k, str(m.get("points", "")), _fmt(m.get("model_max_um")), _fmt(m.get("model_mean_um")),
                 _fmt(m.get("model_max_sq_um2")), _fmt(m.get("model_mean_sq_um2"))]
        if has_true:
            cells += [_fmt(m.get("true_max_um")), _fmt(m.get("true_mean_um")),
                      _fmt(m.get("true_max_sq_um2")), _fmt(m.get("true_mean_sq_um2"))]
        cells += [_fmt(m.get("seconds"), ".3f"), str(m.get("failures", "—")), _fmt(m.get("max_correction_um"))]
        rows.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    head = ["method", "points", "MODEL max |r| μm", "MODEL mean |r| μm", "MODEL max |r|² μm²",
            "MODEL mean |r|² μm²"]
    if has_true:
        head += ["TRUE max |r| μm", "TRUE mean |r| μm", "TRUE max |r|² μm²", "TRUE mean |r|² μm²"]
    head += ["solver s", "failures", "max correction μm"]
    table = ("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
             + "".join(rows) + "</table>")
    notes = "".join(f"<li>{html.escape(r.note)}</li>" for r in cmp.runs.values() if r.note)
    ctx = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in context.items())
    figs = []
    for kind in ("model", "true"):
        if kind == "true" and not has_true:
            continue
        for sq in (False, True):
            png = _residual_plot(cmp, kind, sq)
            if png:
                figs.append(f'<figure><img alt="{kind} residual" src="data:image/png;base64,{png}">'
                            f"<figcaption>{html.escape(RESIDUAL_DEFINITIONS[kind])}"
                            f"{' — squared, the grinder paper’s Fig. 18 kind' if sq and kind == 'model' else ''}"
                            "</figcaption></figure>")
    figs.append(f'<figure><img alt="solver times" src="data:image/png;base64,{_times_plot(cmp)}">'
                "<figcaption>Solver wall time per method (total and per point).</figcaption></figure>")
    which = "MODEL and TRUE residuals" if has_true else "MODEL residual only (no truth machine given)"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 1100px; }}
table {{ border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }}
td, th {{ border: 1px solid #ccc; padding: 3px 8px; text-align: right; }}
th {{ background: #f3f3f3; }}
figure {{ margin: 1.5em 0; }} img {{ max-width: 100%; }}
.residual {{ background: #fff6d5; padding: 0.5em 1em; border-left: 4px solid #e0b000; }}
</style></head><body>
<h1>{html.escape(title)}</h1>
<p class="residual">This report shows the <b>{which}</b>.<br>
<b>Model residual</b>: {html.escape(RESIDUAL_DEFINITIONS['model'].split(': ', 1)[-1])}.<br>
<b>True residual</b>: {html.escape(RESIDUAL_DEFINITIONS['true'].split(': ', 1)[-1])}.<br>
The measured residual (measurement minus model at check points) is not shown here.</p>
<h2>Setting</h2><table>{ctx}</table>
<h2>Max and mean per method</h2>{table}
{f'<ul>{notes}</ul>' if notes else ''}
<h2>Residual per interpolation point</h2>
{''.join(figs)}
</body></html>
"""


def write_report(cmp: Comparison, out_dir, title: str = "volcomp compensation report", context: dict | None = None,
                 extra_metrics: dict | None = None) -> dict:
    """Write report.html, metrics.json and residuals.csv into ``out_dir`` (each atomically).

    Returns ``{"html": path, "metrics": path, "residuals": path}``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    n = len(cmp.targets_mm)
    cols = {"point": np.arange(n), "x_mm": cmp.nominal_axes[:, 0], "z_mm": cmp.nominal_axes[:, 1],
            "a_deg": cmp.nominal_axes[:, 2],
            "uncompensated_model_um": np.linalg.norm(cmp.baseline_model_um, axis=1)}
    if cmp.baseline_true_um is not None:
        cols["uncompensated_true_um"] = np.linalg.norm(cmp.baseline_true_um, axis=1)
    for k, r in cmp.runs.items():
        for kind, arr in (("model", r.result.residual_um), ("true", r.true_residual_um)):
            if arr is None:
                continue
            col = np.full(n, np.nan)
            col[r.index] = np.linalg.norm(np.asarray(arr), axis=1)
            cols[f"{k}_{kind}_um"] = col
    paths = {"residuals": write_csv(out / "residuals.csv", cols, header_comments=[
        "format: volcomp-residuals/1", "columns *_model_um: |model residual|, *_true_um: |true residual| (μm)"])}
    metrics = cmp.metrics()
    if context:
        metrics["context"] = context
    if extra_metrics:
        metrics.update(extra_metrics)
    paths["metrics"] = write_json(out / "metrics.json", metrics)
    text = render_html(cmp, title, context or {})
    with atomic_write(out / "report.html", "w", encoding="utf-8") as fh:
        fh.write(text)
    paths["html"] = out / "report.html"
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
        line = f"{k:<14}{m['points']:>7}{_fmt(m.get('model_max_um')):>14}{_fmt(m.get('model_mean_sq_um2')):>16}"
        if has_true:
            line += f"{_fmt(m.get('true_max_um')):>13}{_fmt(m.get('true_mean_um')):>14}"
        line += f"{_fmt(m.get('seconds'), '.3f'):>10}"
        print(line, file=stream)
