"""Model update before effect search: re-estimate the 23 elements from the check measurements,
with the sweep identification as the prior, then search only what is left.

The element values at any axis point are linear in θ (the station values and constants,
:mod:`errormap.uncertainty`), and the spatial error is linear in them to first order, so the
checks' measured residual on the fitting part is ``r ≈ A·Δθ + noise`` with ``A = ∂e/∂θ``
(3n × P, :func:`errormap.uncertainty.theta_design`). With the identification's covariance as
prior ``Δθ ~ N(0, Σp)`` (``Σp = Σ + PRIOR_RIDGE·diag(Σ)``, full rank) and check noise
``N(0, σc² I)``, the posterior is Gaussian:

* ``Σp = L Lᵀ``; ``B = A L = U s Vᵀ`` (thin SVD); mean ``Δθ = L V diag(s/(s²+σc²)) Uᵀ r``;
  covariance ``L V diag(σc²/(s²+σc²)) Vᵀ Lᵀ``;
* σc by maximum marginal likelihood of ``r ~ N(0, B Bᵀ + σc² I)`` over a grid (closed form
  from the same SVD).

Two findings come with it:

* **contradicted elements** — an element whose update the sweeps rule out: its Mahalanobis
  distance ``Δθ_kᵀ Σp_kk⁻¹ Δθ_k`` against χ² with ``dim θ_k`` degrees of freedom,
  Bonferroni over the 23 elements, ``p_adj < alpha``. The checks demand a change the sweeps
  contradict: the model is standing in for something it does not have (e.g. an X·Z
  interaction taken up as an X roll) — reported as evidence of a missing effect.
* **uncovered elements** — element stations about which the checks alone say little: with
  ``I = Σ A²/σc²`` (the checks' information on that θ by itself) and the prior variance ``v``,
  ``1/√(1 + I·v) ≥`` :data:`UNCOVERED_RATIO`. (The full posterior is no measure of this: the
  sweep prior's correlations — a common frame mode shared by all stations — let checks at one
  end move stations at the other.) They stay at the sweep estimate; the reason is named (the
  checks' range of the element's axis, or a sensitivity below the check noise).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..elements import AXIS_OF, ELEMENT_NAMES, FUNCTION_ELEMENTS
from ..uncertainty import ElementCovariance, elements_from_theta, theta_design, theta_layout

PRIOR_RIDGE = 0.05
"""Diagonal added to the bootstrap covariance, as a fraction of its diagonal: the sample
covariance has rank ≤ n_boot − 1 < P, and a prior must let the checks move every θ."""
UNCOVERED_RATIO = 0.9
"""An element station whose one-parameter posterior sd from the checks is ≥ 90 % of its prior sd
(the checks' information ≤ 0.23 / prior variance) is not updated by the checks."""
SIGMA_GRID_UM = np.geomspace(0.05, 50.0, 121)


@dataclass
class ModelUpdate:
    """Result of :func:`update_elements`: ``elements_`` (updated), ``delta_theta`` (P,),
    ``posterior_cov`` (P, P), ``prior_cov`` (P, P), ``sigma_um`` (check noise by marginal
    likelihood), ``contradicted`` / ``uncovered`` (lists of dicts), ``covariance_`` (the
    posterior as an :class:`ElementCovariance` of the updated elements)."""

    elements_: object
    delta_theta: np.ndarray
    posterior_cov: np.ndarray
    prior_cov: np.ndarray
    sigma_um: float
    contradicted: list = field(default_factory=list)
    uncovered: list = field(default_factory=list)
    covariance_: ElementCovariance | None = None
    marginal: tuple | None = field(default=None, repr=False)
    """(U (N, k), s (k,)) of the thin SVD of ``A·L``: the residual's marginal covariance under
    "update alone" is ``U diag(s²) Uᵀ + σc² I`` (:meth:`whiten`)."""

    design_: np.ndarray | None = field(default=None, repr=False)
    """``A`` (N, P): ∂(stacked fitting residual)/∂θ the update was made with."""

    def whiten(self, y) -> np.ndarray:
        """``V^{-1/2}·y`` for the marginal covariance ``V = A Σp Aᵀ + σc² I`` of the stacked
        fitting residual (rows (point, component); ``y`` (N,) or (N, p)): a residual that
        "update alone" explains has unit variance after it, so a term can be tested against
        the update jointly (:mod:`.joint`) instead of on what the update left."""
        U, s = self.marginal
        y = np.asarray(y, dtype=float)
        uy = U.T @ y
        d = 1.0 / np.sqrt(s**2 + self.sigma_um**2)
        scale = d[:, None] if y.ndim == 2 else d
        return U @ (uy * scale) + (y - U @ uy) / self.sigma_um

    def to_dict(self) -> dict:
        return {"check_noise_sigma_um": self.sigma_um, "contradicted_by_sweeps": self.contradicted,
                "not_updated": self.uncovered}


def _sqrt_psd(S):
    w, Q = np.linalg.eigh(0.5 * (S + S.T))
    return Q * np.sqrt(np.clip(w, 0, None))


def update_elements(machine, covariance: ElementCovariance, axes, residual_um, alpha: float = 0.01,
                    sigma_um: float | None = None) -> ModelUpdate:
    """Posterior update of the elements of ``covariance.elements`` from check residuals.

    ``axes`` (n, 3) check points, ``residual_um`` (n, 3) measurement − model prediction there;
    ``sigma_um`` check noise σ (default: maximum marginal likelihood).
    """
    el = covariance.elements
    axes = np.asarray(axes, dtype=float)
    r = np.asarray(residual_um, dtype=float).reshape(-1)
    A = theta_design(machine, el, axes).reshape(-1, covariance.theta.size)  # rows: (point, component)
    S = covariance.prior_cov()
    d = np.diag(S).copy()
    floor = 1e-6 * np.median(d[d > 0]) if np.any(d > 0) else 1.0
    Sp = S + PRIOR_RIDGE * np.diag(d) + floor * np.eye(d.size)
    L = _sqrt_psd(Sp)
    B = A @ L
    U, s, Vt = np.linalg.svd(B, full_matrices=False)
    ur = U.T @ r
    rr = r @ r
    N = r.size
    if sigma_um is None:
        s2 = s**2
        ll = [-(np.sum(ur**2 / (s2 + g**2)) + (rr - ur @ ur) / g**2) - (np.sum(np.log(s2 + g**2))
                                                                         + (N - s.size) * np.log(g**2))
              for g in SIGMA_GRID_UM]
        sigma_um = float(SIGMA_GRID_UM[int(np.argmax(ll))])
    g2 = sigma_um**2
    LV = L @ Vt.T
    dtheta = LV @ (s / (s**2 + g2) * ur)
    post = (LV * (g2 / (s**2 + g2))) @ LV.T
    theta = covariance.theta + dtheta
    new_el = elements_from_theta(theta, el)

    info = np.sum(A**2, axis=0) / g2
    lay = theta_layout(el)
    names = np.array([k for k, _ in lay])
    contradicted, uncovered = [], []
    lo, hi = axes.min(axis=0), axes.max(axis=0)
    col = {"x_mm": 0, "z_mm": 1, "a_deg": 2}
    for k in ELEMENT_NAMES:
        idx = np.flatnonzero(names == k)
        dk = dtheta[idx]
        m2 = float(dk @ np.linalg.solve(Sp[np.ix_(idx, idx)], dk))
        p = float(stats.chi2.sf(m2, idx.size))
        p_adj = min(1.0, p * len(ELEMENT_NAMES))
        if p_adj < alpha:
            contradicted.append({"element": k, "mahalanobis2": m2, "dof": int(idx.size), "p_adjusted": p_adj,
                                 "max_update_in_prior_sd": float(np.max(np.abs(dk) / np.sqrt(np.diag(Sp)[idx]))),
                                 "meaning": "the checks demand an update of this element that the sweeps rule out: "
                                            "evidence of an effect the 23 elements lack, standing in here"})
        # local information: what the checks alone say about each θ (its own column, no prior
        # correlations), against the prior variance: sd ratio of a one-parameter update
        ratio = 1.0 / np.sqrt(1.0 + info[idx] * np.diag(Sp)[idx])
        bad = (ratio >= UNCOVERED_RATIO) & (d[idx] > 1e3 * floor)  # gauge stations (fixed at zero) excluded
        if bad.any():
            entry = {"element": k, "local_posterior_over_prior_sd": [float(v) for v in ratio]}
            if k in FUNCTION_ELEMENTS:
                key = AXIS_OF[k]
                st = el.stations[key]
                stations = [int(i) for i in np.flatnonzero(bad)]
                entry["stations"] = stations
                outside = [i for i in stations if st[i] < lo[col[key]] or st[i] > hi[col[key]]]
                if key != "a_deg" and outside:
                    entry["why"] = (f"the checks cover {key} {lo[col[key]]:.4g}..{hi[col[key]]:.4g}; stations "
                                    f"{outside} lie outside, so these station values stay at the sweep estimate")
                else:
                    entry["why"] = ("the checks' sensitivity to this element is below the check noise there "
                                    "(their information on it leaves ≥ 90 % of the sweep sd); it stays at the sweep estimate")
            else:
                entry["why"] = "the checks do not separate this constant from the other elements; it stays at the sweep estimate"
            uncovered.append(entry)
    info = dict(covariance.info, posterior="updated from check measurements", check_noise_sigma_um=sigma_um)
    cov = ElementCovariance(theta, post, new_el, info)
    return ModelUpdate(new_el, dtheta, post, Sp, float(sigma_um), contradicted, uncovered, cov, (U, s), A)
