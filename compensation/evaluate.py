"""Evaluating compensated commands: the model residual and, on a simulated machine, the true one.

The residuals of docs/explanation/kinematics.md, never mixed up: the **model residual** ``p_r + E(axes(p_r))
− p_d`` (μm, how well a solver satisfied its own field; with each
:class:`~compensation.solvers.SolveResult`) and the **true residual** (the tool point the simulated truth
machine reaches with the compensated commands, minus the target: :func:`true_residual_um`). A truth is any
simulated machine tool with ``machine``, ``spatial_error(axes, **conditions) -> (n, 3)`` μm and
``default_conditions(n)`` (:class:`errormap.chain_truth.ChainTruth`); :func:`load_truth` reads one from what
``simulate`` wrote. Metrics give the norm ``|r|`` and its square ``|r|²`` (μm², the grinder paper's
figures)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.chain_elements import ChainElementSet
from errormap.chain_kernel import NominalChain
from errormap.chain_truth import ChainTruth
from errormap.io import InputError, read_json_object
from errormap.machine import made_on
from errormap.stats import residual_stats

RESIDUAL_DEFINITIONS = {
    "model": "model residual: p_r + E(axes(p_r)) - p_d, the solver's own error field E (μm)",
    "true": "true residual: tool point reached by the simulated truth machine driven with the "
            "compensated axis commands, minus the target p_d (μm)",
}
CHAIN_TRUTH_FORMAT = "volcomp-chain-truth/1"
"""``truth.json`` of ``simulate`` on a machine-tool chain (elements file beside it + effect parameters)."""
PARAMETER_NAMES = {"x_frac": "p_frac", "z_frac": "q_frac"}
"""A truth.json without a ``format`` key (an older grinder simulate folder) names the stroke fractions
of its two-axis effects by its axes; the chain's effects name them by their order (first, second axis)."""


def _effects(info: dict, path: Path, mt) -> dict:
    """The effects of a truth.json (``{"KIND[:AXES]": parameters}``) as the chain's truth takes them; an effect the
    chain's truth does not carry is refused naming the file and the key."""
    from errormap.chain_truth import parse_effect
    effects = info.get("effects") or {}
    if not isinstance(effects, dict):
        raise InputError(f"{path}: key 'effects': expected a mapping of effect names to parameters, got {effects!r}")
    out = {}
    for name, p in effects.items():
        try:
            parse_effect(mt, name)
        except ValueError as exc:
            raise InputError(f"{path}: key 'effects', {name!r}: {exc}; simulate the truth without it") from None
        out[name] = {PARAMETER_NAMES.get(k, k): v for k, v in (p or {}).items()}
    return out


def load_truth(spec, machine) -> ChainTruth:
    """The truth machine of ``spec`` on the machine tool ``machine`` (a grinder file through its chain): a
    ``simulate`` folder or its ``truth.json`` (elements beside it plus the effects it lists), or an element-set
    file (the elements alone). InputError naming the file and key otherwise."""
    p = Path(spec)
    if p.is_dir():
        p = p / "truth.json"
        if not p.is_file():
            if (p.parent / "truth_elements.json").is_file():
                return ChainTruth(machine, ChainElementSet.load(p.parent / "truth_elements.json", machine), {})
            raise InputError(f"{p.parent}: not a simulate folder (no truth.json)")
    elif not p.is_file():
        raise InputError(f"{p}: no such simulate folder or element-set file")
    d = read_json_object(p, "a truth or element-set file")
    fmt = d.get("format")
    if fmt == CHAIN_TRUTH_FORMAT or (fmt is None and "effects" in d):
        if fmt == CHAIN_TRUTH_FORMAT and d.get("machine_sha256") and machine.sha256 and not made_on(machine, d["machine_sha256"]):
            raise InputError(f"{p}: key 'machine_sha256': the truth belongs to machine {d.get('machine')!r}, "
                             f"not {machine.name!r}")
        el = p.parent / str(d.get("elements") or "truth_elements.json")
        return ChainTruth(machine, ChainElementSet.load(el, machine), _effects(d, p, machine), d.get("seed"))
    return ChainTruth(machine, ChainElementSet.load(p, machine), {})


def true_residual_um(truth, axes, targets_mm, conditions: dict | None = None) -> np.ndarray:
    """True residual (μm), shape (n, 3): the truth's tool point at ``axes`` (its chain's nominal point plus its
    true error) minus ``targets_mm``.

    ``axes`` shape (n, k) compensated axes of the truth's machine; ``targets_mm`` shape (n, 3) WCS.
    ``conditions`` default to the truth's reference conditions (20 °C, positive approach).
    """
    axes = np.asarray(axes, dtype=float)
    targets_mm = np.asarray(targets_mm, dtype=float)
    if axes.shape[0] != targets_mm.shape[0] or targets_mm.shape[1:] != (3,):
        raise ValueError(f"Expected axes (n, k) and targets (n, 3) of the same n, got {axes.shape} and "
                         f"{targets_mm.shape}")
    cond = truth.default_conditions(axes.shape[0]) if conditions is None else conditions
    nominal = NominalChain(truth.machine).forward(axes)
    return 1e3 * (nominal - targets_mm) + truth.spatial_error(axes, **cond)


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


def method_metrics(result, truth=None, true_residual=None) -> dict:
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


GRADIENT_STEP_MM = 0.5
"""Step of the central differences of a field's gradient (its elements vary over tens of mm)."""


def gradient_norm(field, axes, lin) -> np.ndarray:
    """Per row of ``axes`` (n, k), the spectral norm of the field's gradient along the linear axes ``lin`` (indices
    into k; μm per mm): central differences of :data:`GRADIENT_STEP_MM`. Shape (n,). What the error may differ by
    per mm of distance from the point (the bound a cutter's or a nose's radius leaves, the radius times this)."""
    axes = np.asarray(axes, dtype=float)
    G = np.empty((len(axes), 3, len(lin)))
    for c, j in enumerate(lin):
        d = np.zeros(axes.shape[1])
        d[j] = GRADIENT_STEP_MM
        ahead, behind = np.asarray(field.predict(axes + d)), np.asarray(field.predict(axes - d))
        G[:, :, c] = (ahead - behind) / (2 * GRADIENT_STEP_MM)
    return np.linalg.norm(G, ord=2, axis=(1, 2))
