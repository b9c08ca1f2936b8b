"""The grinder file's identification with its uncertainty.

:func:`smooth_identify` runs the one identification of every machine tool
(:class:`errormap.identification.ChainIdentification` on the grinder file's chain, in the ``station-mean`` gauge
by default), its covariance Gauss–Newton's σ̂²·(JᵀJ)⁻¹ through the gauge (or a residual bootstrap), the
station values smoothed by :func:`errormap.identification.smooth_chain`. The covariance and its band are
the chain's (:mod:`errormap.chain_covariance`). θ (:func:`theta_layout`): the 18 functions' values at their
stations (X and Z: all; A: all but the last, which equals the first), then the 5 constants; the per-element
smoothing experiments of the benchmarks work on it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chain_elements import ChainElementSet
from .elements import A_ELEMENTS, AXIS_OF, CONSTANT_ELEMENTS, FUNCTION_ELEMENTS
from .machine_tool import MachineTool

Z95 = 1.959963984540054


def theta_layout(elements: ChainElementSet) -> list[tuple[str, int]]:
    """``(element, station index)`` of every entry of θ (station −1 for a constant)."""
    out = []
    for k in FUNCTION_ELEMENTS:
        m = elements.stations[AXIS_OF[k]].size - (1 if k in A_ELEMENTS else 0)
        out += [(k, i) for i in range(m)]
    return out + [(k, -1) for k in CONSTANT_ELEMENTS]


def theta_blocks(elements: ChainElementSet) -> dict:
    """Function element -> indices (m,) of its station values in θ (see :func:`theta_layout`)."""
    names = np.array([k for k, _ in theta_layout(elements)])
    return {k: np.flatnonzero(names == k) for k in FUNCTION_ELEMENTS}


def theta_from_elements(elements: ChainElementSet) -> np.ndarray:
    """θ (P,) from an element set (see module doc)."""
    parts = [elements.functions[k][:-1] if k in A_ELEMENTS else elements.functions[k] for k in FUNCTION_ELEMENTS]
    return np.concatenate(parts + [np.array([elements.constants[k] for k in CONSTANT_ELEMENTS])])


def elements_from_theta(theta, template: ChainElementSet) -> ChainElementSet:
    """The element set with θ's values on ``template``'s stations."""
    theta = np.asarray(theta, dtype=float)
    fun, i = {}, 0
    for k in FUNCTION_ELEMENTS:
        m = template.stations[AXIS_OF[k]].size
        if k in A_ELEMENTS:
            fun[k] = np.r_[theta[i:i + m - 1], theta[i]]
            i += m - 1
        else:
            fun[k] = theta[i:i + m].copy()
            i += m
    const = {k: float(theta[i + j]) for j, k in enumerate(CONSTANT_ELEMENTS)}
    return ChainElementSet(template.machine, template.stations, fun, const, template.machine_name,
                           template.machine_sha256)


def theta_covariance(elements: ChainElementSet, C) -> tuple:
    """A θ covariance ``C`` (P, P) as the chain's ``(slot names, stations, Σ)``
    (:func:`errormap.chain_covariance.band_sd`)."""
    lay = theta_layout(elements)
    return [k for k, _ in lay], np.array([i for _, i in lay]), C


def station_se(elements: ChainElementSet, C) -> dict:
    """Standard error per element at each of its stations (A: last = first), μm or μrad, from a θ
    covariance."""
    sd = np.sqrt(np.clip(np.diag(C), 0, None))
    blocks = theta_blocks(elements)
    out = {k: np.r_[sd[i], sd[i[0]]] if k in A_ELEMENTS else sd[i] for k, i in blocks.items()}
    return out | {k: float(sd[len(sd) - len(CONSTANT_ELEMENTS) + j]) for j, k in enumerate(CONSTANT_ELEMENTS)}


def nullspace_smoother(Sigma, periodic: bool) -> np.ndarray:
    """The λ → ∞ limit of :func:`errormap.smoothing._smoother` with the same weights: the weighted
    least-squares projection of the station values onto the second-difference penalty's null space
    (a constant and a slope in the station index; a constant for a periodic element), shape (m, m)."""
    m = Sigma.shape[0]
    var = np.diag(Sigma).copy()
    if var.max() <= 0:
        return np.eye(m)
    var = np.maximum(var, 1e-3 * var.max())
    X = np.ones((m, 1)) if periodic else np.stack([np.ones(m), np.arange(m, dtype=float)], axis=1)
    Xw = X / var[:, None]
    return X @ np.linalg.solve(X.T @ Xw, Xw.T)


def nullspace_noise_cov(raw_cov, elements: ChainElementSet) -> np.ndarray:
    """Covariance (P, P) of the station values after the heaviest smoothing of this family
    (:func:`nullspace_smoother` per element, constants as identified), from the raw
    identification's bootstrap covariance ``raw_cov`` (P, P): the tracker noise that no
    second-difference smoother removes — per element the offset and slope the penalty does
    not touch (the tracker pose and the frames carry most of the noise there). Propagated to
    points (``J C Jᵀ``) it is the noise part of the prediction error at λ → ∞; the variance of
    a Whittaker smoother falls towards it as λ grows (exactly so for uncorrelated station
    noise; the cross-element lever-arm correlations of the bootstrap can make a point's
    variance differ either way), so it is the noise-propagation floor of the smoothing
    choice, not a bound on every estimator."""
    H = np.eye(raw_cov.shape[0])
    for k, idx in theta_blocks(elements).items():
        H[np.ix_(idx, idx)] = nullspace_smoother(raw_cov[np.ix_(idx, idx)], periodic=k in A_ELEMENTS)
    return H @ raw_cov @ H.T


@dataclass
class SmoothIdentificationResult:
    """``raw``: the interpolating identification; ``result``: the smoothed one (its ``elements_``, ``cov``
    over ``param_slot``/``param_station`` and ``prior_extra``: the covariance file,
    :func:`errormap.chain_covariance.save_chain_covariance`); ``noise_um``: σ used; ``smoothing``: per element
    {lambda, edf}; ``info``: how the covariance was obtained."""

    raw: object
    result: object
    noise_um: float
    smoothing: dict
    info: dict
    raw_cov: np.ndarray | None = None
    """(P, P) θ covariance of the raw (interpolating) station values, before smoothing
    (kept in memory, not written: :func:`nullspace_noise_cov` uses it)."""

    @property
    def elements_(self) -> ChainElementSet:
        return self.result.elements_

    @property
    def covariance_(self) -> tuple:
        """``(slot names, stations (N,), Σ (N, N))`` of the smoothed elements (μm² / μrad²)."""
        return list(self.result.param_slot), self.result.param_station, self.result.cov

    def station_se(self) -> dict:
        idx = _grinder_theta_index(self.result)
        return station_se(self.elements_, self.result.cov[np.ix_(idx, idx)])

    def summary_lines(self) -> list[str]:
        se = self.station_se()
        edf = ", ".join(f"{k} {v['edf']:.3g}" for k, v in self.smoothing.items()) or "none (interpolating)"
        worst = max(FUNCTION_ELEMENTS, key=lambda k: float(np.max(se[k])))
        return [f"noise {self.noise_um:.3g} um per ball coordinate "
                f"({'from the ball residuals' if self.info.get('noise_estimated') else 'given'}); "
                f"covariance: {self.info['method']}",
                f"smoothing (effective degrees of freedom per element): {edf}",
                f"largest station standard error: {worst} {np.max(se[worst]):.3g}"]

    def report_dict(self) -> dict:
        return {"noise_um": self.noise_um, "smoothing": self.smoothing,
                "standard_errors": {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                    for k, v in self.station_se().items()},
                "covariance": dict(self.info)}


def _grinder_theta_index(result) -> np.ndarray:
    """Indices (P,) into a grinder chain identification's parameter vector (``param_slot``/``param_station``)
    of the grinder's θ (:func:`theta_layout`; the element and slot names are the same, the A axis' last
    station, the first pose again, not in θ)."""
    where = {(s, int(i)): j for j, (s, i) in enumerate(zip(result.param_slot, result.param_station))}
    return np.array([where[key] for key in theta_layout(result.elements_)])


def smooth_identify(sweeps, machine: MachineTool, noise_um: float | None = None, n_boot: int | None = None, seed: int = 0,
                    smooth: bool = True, gauge: str = "station-mean", **settings) -> SmoothIdentificationResult:
    """The grinder's identification, through the one identification of every machine tool: the grinder
    file's chain (:func:`errormap.grinder_file.grinder_chain`) identified by
    :class:`errormap.identification.ChainIdentification` in ``gauge``, its covariance Gauss–Newton's
    (σ̂ from the ball residuals, or the known ``noise_um``) or, with ``n_boot`` ≥ 2, the residual bootstrap's
    (:func:`errormap.identification.bootstrap_covariance`, seeded by ``seed``), smoothed by the UBRE smoother
    (:func:`errormap.identification.smooth_chain`) unless ``smooth=False``. ``sweeps``:
    :class:`errormap.sweeps.Sweeps` or a dict of sweep columns."""
    from dataclasses import replace
    from .identification import ChainIdentification, bootstrap_covariance, smooth_chain
    from .sweeps import Sweeps, sweeps_from_columns
    if not isinstance(sweeps, Sweeps):
        sweeps = sweeps_from_columns(sweeps)
    settings = {"gauge": gauge, "noise_um": noise_um, **settings}
    raw = ChainIdentification(**settings).fit(sweeps, machine).result_
    if n_boot is not None:
        raw = bootstrap_covariance(sweeps, machine, raw, n_boot, seed, **settings)
    res = smooth_chain(raw, machine) if smooth else raw
    idx = _grinder_theta_index(raw)
    sigma = raw.sigma_um if noise_um is None else float(noise_um)
    info = {"method": (f"residual bootstrap of the identification, {n_boot} draws" if n_boot is not None else
                       "Gauss-Newton covariance of the identification") +
                      (", smoothed (H C H^T plus the smoother's estimated squared bias per element)" if smooth else ""),
            "n_boot": n_boot, "seed": seed, "noise_um": sigma, "noise_estimated": noise_um is None,
            "smoothed": bool(smooth), "gauge": gauge}
    smoothing = res.covariance_info.get("smoothing", {})
    return SmoothIdentificationResult(replace(raw), res, sigma, smoothing, info, raw.cov[np.ix_(idx, idx)])
