"""The grinder file's identification with its uncertainty, in the grinder's element-set and covariance files.

:func:`smooth_identify` runs the one identification of every machine tool
(:class:`errormap.identification.ChainIdentification` on the grinder file's chain, in the ``station-mean`` gauge
by default), its covariance Gauss–Newton's σ̂²·(JᵀJ)⁻¹ through the gauge (or a residual bootstrap), the
station values smoothed by the UBRE smoother (:func:`errormap.smoothing.smooth_blocks` through
:func:`errormap.identification.smooth_chain`), and re-expresses the result as the grinder's
:class:`~errormap.chain_elements.ChainElementSet` and :class:`ElementCovariance` (the covariance of the smoothed values
``H Σ Hᵀ`` plus the smoother's estimated squared bias per element on the diagonal).

The parameter vector θ (:class:`ElementCovariance`): the 18 functions' values at their
stations (X and Z: all stations; A: all but the last, which equals the first), then the
5 constants. The element values at any axis point are linear in θ (cubic interpolation
weights), so the spatial-error covariance at points is ``J Σ Jᵀ`` with ``J = ∂e/∂θ`` of
shape (n, 3, P) (:meth:`ElementCovariance.prediction_cov`, shape (n, 3, 3)).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import make_interp_spline

from .chain_elements import ChainElementSet
from .elements import A_ELEMENTS, AXIS_OF, CONSTANT_ELEMENTS, FUNCTION_ELEMENTS
from .chain_kernel import error_jacobian
from .io import NPY_ERRORS, InputError, atomic_write, check_document_size, companion_path
from .machine_tool import MachineTool
from .smoothing import LAMBDA_GRID, _second_differences, _smoother, bootstrap_draws, smooth_blocks  # noqa: F401

Z95 = 1.959963984540054


COMPANION_THETA_TOL = 1e-9
"""Relative: a covariance file holds the θ of the element set it was saved with, and the element-set
JSON keeps every float exactly (round-trip repr); a larger difference is another identification's file."""


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


def interpolation_weights(elements: ChainElementSet, axes) -> dict:
    """Per axis key, the cubic-interpolation weights (n, m_free) mapping the free station values
    to the element value at the points (the element set's own splines, applied to unit vectors)."""
    axes = np.asarray(axes, dtype=float)
    cols = {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": elements.wrap("a_deg", axes[:, 2])}
    out = {}
    for key in ("x_mm", "z_mm"):
        st = elements.stations[key]
        out[key] = make_interp_spline(st, np.eye(st.size), k=3)(cols[key])
    st = elements.stations["a_deg"]
    eye = np.eye(st.size - 1)
    out["a_deg"] = make_interp_spline(st, np.vstack([eye, eye[:1]]), k=3, bc_type="periodic")(cols["a_deg"])
    return out


def theta_design(machine: MachineTool, elements: ChainElementSet, axes) -> np.ndarray:
    """``∂(spatial error μm)/∂θ`` at axis points, shape (n, 3, P) (first order, exact in θ)."""
    axes = np.asarray(axes, dtype=float)
    J = error_jacobian(machine, axes)
    W = interpolation_weights(elements, axes)
    blocks = []
    for j, k in enumerate(FUNCTION_ELEMENTS):
        blocks.append(J[:, :, j, None] * W[AXIS_OF[k]][:, None, :])
    blocks.append(J[:, :, len(FUNCTION_ELEMENTS):])
    return np.concatenate(blocks, axis=2)


@dataclass
class ElementCovariance:
    """Covariance of θ (P, P) of an element set, with ``theta`` (P,) its mean; ``info`` says
    how it was obtained (noise level, bootstrap size, smoothing parameters)."""

    theta: np.ndarray
    cov: np.ndarray
    elements: ChainElementSet
    info: dict = field(default_factory=dict)
    prior_extra: np.ndarray | None = None
    """(P,) variance added on the diagonal when θ is used as a prior for an update (the
    smoother's whole mean-square change per element: a conservative bound on its bias, so that
    checks can correct what smoothing took away); None: nothing added."""

    def prior_cov(self) -> np.ndarray:
        """Covariance to use as a prior (P, P): ``cov`` plus ``prior_extra`` on the diagonal."""
        return self.cov if self.prior_extra is None else self.cov + np.diag(self.prior_extra)

    def station_se(self) -> dict:
        """Standard error per element at each of its stations (A: last = first), μm or μrad."""
        sd = np.sqrt(np.clip(np.diag(self.cov), 0, None))
        out, i = {}, 0
        for k in FUNCTION_ELEMENTS:
            m = self.elements.stations[AXIS_OF[k]].size
            if k in A_ELEMENTS:
                out[k] = np.r_[sd[i:i + m - 1], sd[i]]
                i += m - 1
            else:
                out[k] = sd[i:i + m]
                i += m
        for j, k in enumerate(CONSTANT_ELEMENTS):
            out[k] = float(sd[i + j])
        return out

    def prediction_cov(self, machine: MachineTool, axes, chunk: int = 20_000) -> np.ndarray:
        """Spatial-error covariance ``J Σ Jᵀ`` at axis points, shape (n, 3, 3) (μm²)."""
        axes = np.asarray(axes, dtype=float)
        out = np.empty((axes.shape[0], 3, 3))
        for s in range(0, axes.shape[0], chunk):
            A = theta_design(machine, self.elements, axes[s:s + chunk])
            out[s:s + chunk] = np.einsum("nip,pq,njq->nij", A, self.cov, A, optimize=True)
        return out

    def save(self, path) -> Path:
        """Write ``.npz`` atomically (theta, cov, layout names, info as JSON text)."""
        import io as _io
        import json
        buf = _io.BytesIO()
        lay = theta_layout(self.elements)
        np.savez_compressed(buf, theta=self.theta, cov=self.cov,
                            prior_extra=np.zeros_like(self.theta) if self.prior_extra is None else self.prior_extra,
                            layout_element=np.array([k for k, _ in lay]), layout_station=np.array([i for _, i in lay]),
                            info=np.array(json.dumps(self.info)))
        with atomic_write(path, "wb") as fh:
            fh.write(buf.getvalue())
        return Path(path)

    @classmethod
    def load(cls, path, elements: ChainElementSet) -> "ElementCovariance":
        """Read a covariance file written by :meth:`save` for ``elements``; errors name the file."""
        import json
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such covariance file (written by `volcomp identify` beside the elements)")
        check_document_size(path, "an element covariance")   # ~15 MB at most for the 61-station chains
        try:
            d = np.load(path, allow_pickle=False)
            theta, cov = d["theta"], d["cov"]
            lay = list(zip(d["layout_element"].tolist(), d["layout_station"].tolist()))
            info = json.loads(str(d["info"]))
            extra = d["prior_extra"] if "prior_extra" in d.files else None
        except NPY_ERRORS as exc:
            raise InputError(f"{path}: not a readable volcomp covariance file ({exc}); a truncated or damaged copy? "
                             "Run `volcomp identify` again to write it") from None
        if lay != theta_layout(elements) or cov.shape != (len(lay), len(lay)):
            raise InputError(f"{path}: its parameter layout does not match the element set's stations")
        own = theta_from_elements(elements)
        k = int(np.argmax(np.abs(theta - own)))
        if abs(theta[k] - own[k]) > COMPANION_THETA_TOL * max(1.0, float(np.abs(own).max())):
            name, st = lay[k]
            raise InputError(f"{path}: not the covariance of this element set: its values differ at {name}"
                             f"{'' if st < 0 else f' station {st}'} ({theta[k]:.6g} vs {own[k]:.6g}); a companion "
                             "left from another identification? Identify again or move the right one beside it")
        return cls(theta, cov, elements, info, extra)


def covariance_path(elements_path) -> Path:
    """Where the covariance of an element-set file lives: ``NAME.cov.npz`` beside it, whatever the
    element set's suffix (:func:`errormap.io.companion_path`)."""
    return companion_path(elements_path, ".cov.npz")


def nullspace_smoother(Sigma, periodic: bool) -> np.ndarray:
    """The λ → ∞ limit of :func:`_smoother` with the same weights: the weighted least-squares
    projection of the station values onto the second-difference penalty's null space
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


def prediction_sd(machine: MachineTool, elements: ChainElementSet, cov, axes) -> np.ndarray:
    """Per-component standard deviation (n, 3) μm of the spatial error at ``axes`` for a θ
    covariance ``cov`` (P, P) of ``elements``' layout (the diagonal of ``J Σ Jᵀ``)."""
    A = theta_design(machine, elements, np.asarray(axes, dtype=float))
    return np.sqrt(np.clip(np.einsum("nip,pq,niq->ni", A, cov, A, optimize=True), 0, None))


@dataclass
class SmoothIdentificationResult:
    """``raw``: the interpolating identification; ``elements_``: the smoothed elements;
    ``covariance_``: :class:`ElementCovariance` of the smoothed θ; ``noise_um``: σ used;
    ``smoothing``: per element {lambda, edf}."""

    raw: object
    elements_: ChainElementSet
    covariance_: ElementCovariance
    noise_um: float
    smoothing: dict
    raw_cov: np.ndarray | None = None
    """(P, P) covariance of the raw (interpolating) station values, before smoothing
    (kept in memory, not written: :func:`nullspace_noise_cov` uses it)."""

    def summary_lines(self) -> list[str]:
        se = self.covariance_.station_se()
        edf = ", ".join(f"{k} {v['edf']:.3g}" for k, v in self.smoothing.items()) or "none (interpolating)"
        worst = max(FUNCTION_ELEMENTS, key=lambda k: float(np.max(se[k])))
        return [f"noise {self.noise_um:.3g} um per ball coordinate "
                f"({'from the ball residuals' if self.covariance_.info.get('noise_estimated') else 'given'}); "
                f"covariance: {self.covariance_.info['method']}",
                f"smoothing (effective degrees of freedom per element): {edf}",
                f"largest station standard error: {worst} {np.max(se[worst]):.3g}"]

    def report_dict(self) -> dict:
        se = self.covariance_.station_se()
        return {"noise_um": self.noise_um, "smoothing": self.smoothing,
                "standard_errors": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in se.items()},
                "covariance": dict(self.covariance_.info)}


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
    (:func:`errormap.identification.smooth_chain`) unless ``smooth=False``. The result carries the grinder's
    element set and :class:`ElementCovariance` (θ layout, files as before); ``raw`` is the chain identification
    (its ``elements_`` the interpolating set). ``sweeps``: :class:`errormap.sweeps.Sweeps`
    or a dict of sweep columns."""
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
    elements = res.elements_
    C = res.cov[np.ix_(idx, idx)]
    extra = None if res.prior_extra is None else res.prior_extra[idx]
    sigma = raw.sigma_um if noise_um is None else float(noise_um)
    info = {"method": (f"residual bootstrap of the identification, {n_boot} draws" if n_boot is not None else
                       "Gauss-Newton covariance of the identification") +
                      (", smoothed (H C H^T plus the smoother's estimated squared bias per element)" if smooth else ""),
            "n_boot": n_boot, "seed": seed, "noise_um": sigma, "noise_estimated": noise_um is None,
            "smoothed": bool(smooth), "gauge": gauge}
    smoothing = res.covariance_info.get("smoothing", {})
    return SmoothIdentificationResult(replace(raw), elements, ElementCovariance(theta_from_elements(elements), C, elements,
                                                                           info, extra),
                                      sigma, smoothing, raw.cov[np.ix_(idx, idx)])
