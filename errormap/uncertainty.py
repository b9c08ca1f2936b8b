"""The uncertainty of a machine tool's identification, as ``volcomp identify`` reports it (any machine tool).

An identification (:class:`errormap.estimators.Identification`, its ``result_`` a
:class:`errormap.identification.ChainIdentificationResult`) carries its covariance over ``param_slot`` /
``param_station``: Gauss–Newton's σ̂²·(JᵀJ)⁻¹ or the residual bootstrap's, through the UBRE smoother when smoothed.
:func:`station_standard_errors` reads each slot's standard error at its stations from it; :func:`uncertainty_report`
and :func:`uncertainty_lines` say how it was obtained (the report's ``uncertainty`` block and the summary lines).
"""
from __future__ import annotations

import numpy as np

Z95 = 1.959963984540054


def station_standard_errors(result) -> dict:
    """Standard error per slot of the identified machine, μm or μrad, from the diagonal of ``result.cov``: a function
    slot -> (m,) at its stations in order (a full-turn axis' last station is its first pose again: the first's), a
    constant -> float. Slots without a parameter (none identified) are left out."""
    machine = result.elements_.machine
    sd = np.sqrt(np.clip(np.diag(result.cov), 0, None))
    slots, stations = np.asarray(result.param_slot), np.asarray(result.param_station)
    full_turn = {a.word for a in machine.axes if getattr(a, "full_turn", False)}
    out = {}
    for s in machine.slots:
        idx = np.flatnonzero(slots == s.name)
        if idx.size == 0:
            continue
        if not s.is_function:
            out[s.name] = float(sd[idx[0]])
            continue
        v = sd[idx[np.argsort(stations[idx])]]
        if s.axis in full_turn:
            v[-1] = v[0]
        out[s.name] = v
    return out


def noise_um(result) -> float:
    """The tracker σ per ball coordinate (μm) the covariance was scaled with: the given one, else σ̂."""
    return float(result.sigma_um if result.noise_um is None else result.noise_um)


def _covariance_info(result) -> dict:
    info = result.covariance_info
    boot = info["method"] == "residual-bootstrap"
    smoothed = "smoothing" in info
    method = (f"residual bootstrap of the identification, {info['n_boot']} draws" if boot else
              "Gauss-Newton covariance of the identification") + \
        (", smoothed (H C H^T plus the smoother's estimated squared bias per element)" if smoothed else "")
    return {"method": method, "n_boot": info.get("n_boot"), "seed": info.get("seed"), "noise_um": noise_um(result),
            "noise_estimated": result.noise_um is None, "smoothed": smoothed, "gauge": result.gauge}


def uncertainty_report(result) -> dict:
    """The identification report's ``uncertainty`` block: ``noise_um``, ``smoothing`` (per function slot its λ and
    effective degrees of freedom; empty: interpolating), ``standard_errors`` (:func:`station_standard_errors`) and
    ``covariance`` (how it was obtained)."""
    return {"noise_um": noise_um(result), "smoothing": result.covariance_info.get("smoothing", {}),
            "standard_errors": {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                for k, v in station_standard_errors(result).items()},
            "covariance": _covariance_info(result)}


def uncertainty_lines(result) -> list[str]:
    """Three summary lines: the noise and how the covariance was obtained, the smoothing's effective degrees of
    freedom per slot, the largest station standard error."""
    se = station_standard_errors(result)
    smoothing = result.covariance_info.get("smoothing", {})
    edf = ", ".join(f"{k} {v['edf']:.3g}" for k, v in smoothing.items()) or "none (interpolating)"
    functions = [k for k, v in se.items() if isinstance(v, np.ndarray)]
    lines = [f"noise {noise_um(result):.3g} um per ball coordinate "
             f"({'from the ball residuals' if result.noise_um is None else 'given'}); "
             f"covariance: {_covariance_info(result)['method']}",
             f"smoothing (effective degrees of freedom per element): {edf}"]
    if functions:
        worst = max(functions, key=lambda k: float(np.max(se[k])))
        lines.append(f"largest station standard error: {worst} {np.max(se[worst]):.3g}")
    return lines
