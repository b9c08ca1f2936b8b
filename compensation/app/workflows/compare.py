"""Comparing the compensation methods on one tool path (``volcomp report`` and ``volcomp demo``).

:func:`compare_methods` runs each solver (``traditional``, ``ga``, ``batched-ga``, ``exact``)
on the same WCS targets with the same error field, on any machine tool through its chain (the solvers of
``compensate``, :mod:`compensation.solvers`; a grinder file through its chain, the same axis columns);
the per-point reference ``ga`` may run on
an evenly spaced subset of the points when the whole path would take too long (the report
says so). The :class:`Comparison` it returns is what :mod:`compensation.app.reports.methods`
writes (``report.html``, ``metrics.json``, ``residuals.csv``; the keys are described there).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

# the evaluation and the exact solver (numba kernels, scipy) load in the functions that run them, so that
# the commands' defaults below (read when ``volcomp report``/``demo`` build their options) cost nothing
from ...batch import CHUNK_POINTS, GA_METHODS, solve_batch
from ...pathio import align_turns
from ...solvers import METHODS, solver_spec
from ...solvers.threads import small_batch_threads

REPORT_FORMAT = "volcomp-report/1"
GA_PROBE_POINTS = 3        # points timed to estimate the per-point GA cost
DEFAULT_GA_BUDGET_S = 120.0
DEMO_GA_BUDGET_S = 5.0  # the per-point PyGAD GA (0.5–1 s a point, one core): a sample of the path, said so
"""The demo's per-point GA budget (s): ``volcomp demo``'s default and its --help, from this one name (here, beside
the comparison's default, so that the command reads it without loading the demo's workflow)."""


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
    """All methods on one path: nominal axes (n, k) in the machine's ``columns``, targets (n, 3), runs by method;
    ``turn_of_point`` (n,) the turn of the first full-turn rotary axis (all 0 on a machine without one)."""

    targets_mm: np.ndarray
    nominal_axes: np.ndarray
    runs: dict
    baseline: dict
    baseline_model_um: np.ndarray
    baseline_true_um: np.ndarray | None
    turn_of_point: np.ndarray
    info: dict = field(default_factory=dict)
    columns: tuple = ()

    def metrics(self) -> dict:
        from ...evaluate import RESIDUAL_DEFINITIONS
        return {"format": REPORT_FORMAT, "residuals": dict(RESIDUAL_DEFINITIONS),
                "methods": {k: r.metrics for k, r in self.runs.items()},
                "uncompensated": self.baseline, **self.info}


def subset_index(n: int, m: int) -> np.ndarray:
    """``m`` evenly spaced indices into ``range(n)`` (all of them when ``m >= n``), shape (m,)."""
    if m >= n:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, max(m, 1))).astype(int))


def _solve(method, field_, targets, machine, options):
    """One method on ``targets`` through the chunk plan of ``volcomp compensate``
    (:func:`compensation.batch.solve_batch`: fixed chunks of ``CHUNK_POINTS``, per-chunk seeds
    spawned from ``seed``), so the same ``--seed`` gives the GA methods the same streams, and the
    same commands, as ``compensate`` on the same points. ``options``: ``target_axes`` (n, 3),
    ``seed`` (GA methods), and any other solver keyword option."""
    opts = dict(options)
    axes = opts.pop("target_axes")
    seed = opts.pop("seed", 0)
    path = SimpleNamespace(targets_mm=np.ascontiguousarray(targets, dtype=float),
                           axes=np.ascontiguousarray(axes, dtype=float), path="")
    with small_batch_threads(method, len(targets)):
        return solve_batch(method, field_, machine, [path], seed=seed if method in GA_METHODS else 0,
                           chunk_points=CHUNK_POINTS, options=opts)[0]


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
    """Run ``methods`` on WCS targets (n, 3) with ``field_`` on the machine tool ``machine``; evaluate model and
    true residuals (``truth``: :mod:`compensation.evaluate`). ``nominal_axes`` (n, k): the targets' axes (default:
    the chain's nominal inverse, a machine whose rotary axes have none refused by it).

    ``ga`` runs on ``ga_points`` evenly spaced points when given; otherwise its cost per
    point is timed on ``GA_PROBE_POINTS`` points and it runs on as many evenly spaced points
    as fit in ``ga_budget_s`` seconds (all of them if they fit). ``seed`` goes to the
    stochastic solvers; ``solver_options`` maps method -> extra keyword options.
    """
    from ...evaluate import method_metrics, residual_metrics, true_residual_um
    from ...solvers.chain_exact import target_axes_of
    log = sys.stderr if log is None else log
    targets_mm = np.asarray(targets_mm, dtype=float)
    n = targets_mm.shape[0]
    nominal = target_axes_of(machine, targets_mm, nominal_axes, None)
    full_turn = [j for j, a in enumerate(machine.axes) if a.full_turn]
    solver_options = solver_options or {}
    specs = [solver_spec(m) for m in methods]  # the registry refuses an unknown name
    runs = {}
    for method, spec in zip(methods, specs):
        opts = dict(solver_options.get(method, {}))
        opts.setdefault("target_axes", None)
        if spec.seeded:
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
        for j in full_turn:
            axes[:, j] = align_turns(axes[:, j], nominal[idx, j])
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
    baseline = {"points": n, **residual_metrics(base_model, "model")}
    if base_true is not None:
        baseline.update(residual_metrics(base_true, "true"))
    baseline["note"] = ("nominal commands, no compensation; the model residual here is the field's "
                        "predicted error E(axes(p_d)), with sign flipped")
    turn = np.zeros(n, dtype=int)
    if full_turn:
        a = nominal[:, full_turn[0]]
        turn = np.floor((a - a[0]) / 360.0 + 1e-9).astype(int)
    return Comparison(targets_mm, nominal, runs, baseline, base_model, base_true, turn, columns=machine.axis_columns)
