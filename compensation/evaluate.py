"""Evaluating compensated commands: the model residual and, on a simulated machine, the true one.

The three residuals of docs/explanation/kinematics.md, never mixed up:

* **model residual** — ``p_r + E(axes(p_r)) − p_d`` (μm): how well a solver satisfied its
  own error field ``E``; it comes with each :class:`~compensation.solvers.SolveResult`.
* **true residual** — the tool point the simulated truth machine reaches when driven with
  the compensated axis commands, minus the target (μm). Only the simulator knows it:
  :func:`true_residual_um` drives :meth:`errormap.simulator.TruthGrinder.tool_point`.
* (the **measured residual** — measurement minus model at check points — belongs to
  diagnosis, not here.)

The magnitude of a residual is the vector norm ``|r|`` per point; the grinder paper's
figures show its square ``|r|²`` (μm²), so metrics give both.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from errormap.elements import ElementSet
from errormap.io import InputError, read_document_text
from errormap.simulator import EFFECT_NAMES, TruthGrinder
from errormap.stats import residual_stats

RESIDUAL_DEFINITIONS = {
    "model": "model residual: p_r + E(axes(p_r)) - p_d, the solver's own error field E (μm)",
    "true": "true residual: tool point reached by the simulated truth machine driven with the "
            "compensated axis commands, minus the target p_d (μm)",
}


def load_truth(spec, machine) -> TruthGrinder:
    """A truth machine from a ``volcomp simulate`` folder or an element-set JSON file.

    A folder gives ``truth_elements.json`` plus the undeclared effects listed in its
    ``truth.json``; a JSON element-set file gives the 23 elements alone.
    """
    p = Path(spec)
    if p.is_dir():
        el_path = p / "truth_elements.json"
        if not el_path.is_file():
            raise InputError(f"{p}: not a simulate folder (no truth_elements.json)")
        effects, seed = {}, None
        info_path = p / "truth.json"
        if info_path.is_file():
            try:
                info = json.loads(read_document_text(info_path, "a simulation's truth.json"))
            except json.JSONDecodeError as exc:
                raise InputError(f"{info_path}: not valid JSON: {exc}") from None
            effects = info.get("effects") or {}
            if not isinstance(effects, dict) or set(effects) - set(EFFECT_NAMES):
                raise InputError(f"{info_path}: key 'effects': expected a mapping with names from "
                                 f"{list(EFFECT_NAMES)}, got {effects!r}")
            seed = info.get("seed")
        return TruthGrinder(machine, ElementSet.load(el_path), effects, seed)
    if p.is_file():
        return TruthGrinder(machine, ElementSet.load(p), {}, None)
    raise InputError(f"{p}: no such simulate folder or element-set file")


def true_residual_um(truth: TruthGrinder, axes, targets_mm, conditions: dict | None = None) -> np.ndarray:
    """True residual (μm), shape (n, 3): ``truth.tool_point(axes) − targets``.

    ``axes`` shape (n, 3) compensated (x_mm, z_mm, a_deg); ``targets_mm`` shape (n, 3) WCS.
    ``conditions`` default to the truth's reference conditions (20 °C, positive approach).
    """
    axes = np.asarray(axes, dtype=float)
    targets_mm = np.asarray(targets_mm, dtype=float)
    if axes.shape != targets_mm.shape:
        raise ValueError(f"Expected axes and targets of the same shape (n, 3), got {axes.shape} and {targets_mm.shape}")
    cond = truth.default_conditions(axes.shape[0]) if conditions is None else conditions
    return 1e3 * (truth.tool_point(axes, **cond) - targets_mm)


def residual_metrics(residual_um, prefix: str) -> dict:
    """``{prefix}_max_um, _mean_um, _max_sq_um2, _mean_sq_um2`` (the metrics.json names) of the
    per-point norm ``|r|``, from :func:`errormap.stats.residual_stats`: ``max_sq`` = ``max_um``²,
    ``mean_sq`` = ``rms_um``².

    ``residual_um`` shape (n, 3); NaN rows (points not solved) are ignored.
    """
    st = residual_stats(residual_um, drop_nonfinite=True)
    if st["n"] == 0:
        return {f"{prefix}_max_um": None, f"{prefix}_mean_um": None,
                f"{prefix}_max_sq_um2": None, f"{prefix}_mean_sq_um2": None}
    return {f"{prefix}_max_um": st["max_um"], f"{prefix}_mean_um": st["mean_um"],
            f"{prefix}_max_sq_um2": st["max_um"] ** 2, f"{prefix}_mean_sq_um2": st["rms_um"] ** 2}


def method_metrics(result, truth: TruthGrinder | None = None, true_residual=None) -> dict:
    """Metrics of one solver result (see :mod:`compensation.app.reports.methods` for the metrics.json keys).

    ``result`` is a SolveResult; the true residual is computed from ``truth`` unless given.
    """
    m = {"points": int(result.targets_mm.shape[0]), "seconds": float(result.seconds),
         "nfev": int(result.nfev), "failures": int(np.count_nonzero(~np.asarray(result.success, bool))),
         "max_correction_um": float(np.max(result.correction_um)) if len(result.correction_um) else None}
    m.update(residual_metrics(result.residual_um, "model"))
    if truth is not None or true_residual is not None:
        tr = true_residual if true_residual is not None else true_residual_um(truth, result.axes, result.targets_mm)
        m.update(residual_metrics(tr, "true"))
    return m
