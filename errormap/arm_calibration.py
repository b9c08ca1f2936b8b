"""Geometric calibration of a serial chain from measured tool points.

:class:`ArmCalibrator` identifies the chain's error slots (link parameters, base frame, tool point)
by Levenberg–Marquardt on the chain's analytic error Jacobian. Identifiability is decided before the
loop from the column-scaled Jacobian at the nominal chain: a QR factorisation with column pivoting
keeps the largest independent set of slots; every other slot is *fixed* at its nominal value (0) and
named, with the unidentifiable combinations from the SVD's null space — nothing is regularised away.
The result carries parameter standard errors (σ² (JᵀWJ)⁻¹ over the identified slots) and prediction
bands (J Σ Jᵀ) at any pose.

The plain baselines an engineer tries first sit beside it: :func:`fit_plain_lsq` (scipy
``least_squares``, every DH slot + base + tool, no identifiability handling, no β) and
:func:`fit_base_tool` (nominal chain, fitted base frame and tool point only).
Lengths mm, angles rad (as the slot names say); ``q`` (n, nq) in the joints' units.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .io import InputError

RANK_RTOL = 1e-7          # |R_kk| / |R_00| of the scaled QR below this: the slot depends on the others
COMBINATION_SHOW = 0.1    # a slot enters a named null combination with |weight| above this
LM_MAX_ITER = 100
LM_XTOL = 1e-10           # stop when a step lowers the residual sum of squares by less than this (relative)
LAMBDA0 = 1e-3
GENERIC_POSES = 400       # random poses within the limits that define the chain's generic identifiable rank
GENERIC_LIMIT_DEG = 170.0  # random revolute poses stay within ±this (a full turn adds nothing)


ZERO_COLUMN_MM = 1e-8     # a slot moving the tool point less than this (mm per mm or rad, RMS over poses) does nothing


def _scaled(J2d):
    """Unit-norm columns (slots in mm and rad made comparable); a column that is zero up to rounding stays zero."""
    s = np.linalg.norm(J2d, axis=0)
    zero = s <= ZERO_COLUMN_MM * np.sqrt(J2d.shape[0])
    s = np.where(zero, 1.0, s)
    return np.where(zero, 0.0, J2d / s), s


def identifiable_slots(chain, q, errors=None) -> tuple[np.ndarray, list[dict], np.ndarray]:
    """(free mask (n_params,), null combinations, scaled singular values) from the Jacobian at ``q``."""
    from scipy.linalg import qr
    J = chain.error_jacobian(q, errors).reshape(-1, chain.n_params)
    Js, _ = _scaled(J)
    _, R, piv = qr(Js, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > RANK_RTOL * d[0]))
    free = np.zeros(chain.n_params, bool)
    free[piv[:rank]] = True
    sv = np.linalg.svd(Js, compute_uv=False)
    _, _, Vt = np.linalg.svd(Js, full_matrices=True)
    combos = []
    for v in Vt[rank:]:
        v = v / np.abs(v).max()
        idx = np.flatnonzero(np.abs(v) > COMBINATION_SHOW)
        idx = idx[np.argsort(-np.abs(v[idx]))]
        combos.append({"slots": [chain.param_names[k] for k in idx], "weights": [float(v[k]) for k in idx],
                       "text": " ".join(f"{v[k]:+.2f}·{chain.param_names[k]}" for k in idx)})
    return free, combos, sv


def generic_rank(chain, seed=0) -> int:
    """The number of identifiable slots on random poses within the limits (position measurements)."""
    rng = np.random.default_rng(seed)
    lo = np.maximum(chain.joint_lo, -GENERIC_LIMIT_DEG)
    hi = np.minimum(chain.joint_hi, GENERIC_LIMIT_DEG)
    q = rng.uniform(lo, hi, (GENERIC_POSES, chain.n_joints))
    return int(identifiable_slots(chain, q)[0].sum())


def check_pose_set(chain, poses) -> None:
    """Refuse a pose set on which fewer slots are identifiable than on generic poses of the chain
    (poses too alike), naming the joint column that varies least."""
    free, _, _ = identifiable_slots(chain, poses.q)
    g = generic_rank(chain)
    if free.sum() < g:
        span = np.ptp(poses.q, axis=0) / np.maximum(chain.joint_hi - chain.joint_lo, 1e-9)
        j = int(np.argmin(span))
        raise InputError(f"{poses.source}: row {poses.rows[0]}, column '{chain.joint_columns[j]}': the poses are too "
                         f"alike: {int(free.sum())} of the chain's {g} identifiable parameter combinations can be told "
                         f"apart (this joint spans only {np.ptp(poses.q[:, j]):.3g} {chain.joints[j].unit}); "
                         "measure poses spread over every joint's range")


def _lm(chain, q, xyz, x0, free, w, max_iter=LM_MAX_ITER):
    """Levenberg–Marquardt on the slots ``free``; ``w`` (n,) weights (1/σ). Returns (x, iterations, converged)."""
    x = x0.copy()
    r = ((xyz - chain.tool_point(q, x)) * w[:, None]).ravel()
    cost = r @ r
    lam = LAMBDA0
    for it in range(1, max_iter + 1):
        J = (chain.error_jacobian(q, x)[:, :, free] * w[:, None, None]).reshape(-1, free.sum())
        A = J.T @ J
        g = J.T @ r
        dA = np.diag(A).copy()
        improved = False
        while lam < 1e12:
            step = np.linalg.solve(A + lam * np.diag(np.maximum(dA, 1e-30)), g)
            xn = x.copy()
            xn[free] += step
            rn = ((xyz - chain.tool_point(q, xn)) * w[:, None]).ravel()
            cn = rn @ rn
            if cn < cost:
                improved = True
                rel = (cost - cn) / max(cost, 1e-300)
                x, r, cost = xn, rn, cn
                lam = max(lam / 10, 1e-12)
                break
            lam *= 10
        if not improved or rel < LM_XTOL:
            return x, it, True
    return x, max_iter, False


@dataclass
class GeometricResult:
    """An identified chain: ``params`` (n_params,) error-slot values (fixed slots 0), ``free`` mask,
    ``cov`` (n_params, n_params) covariance (rows/columns of fixed slots 0), ``std`` (n_params,),
    ``sigma_mm`` the residual standard deviation per component, ``fixed`` the null combinations."""

    chain: object = field(repr=False)
    params: np.ndarray
    free: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    sigma_mm: float
    fit_rms_mm: float
    singular_values: np.ndarray
    fixed: list
    iterations: int
    converged: bool
    method: str = "volcomp"

    def predict(self, q) -> np.ndarray:
        """Tool point of the identified chain, mm, shape (n, 3)."""
        return self.chain.tool_point(q, self.params)

    def band_std_mm(self, q) -> np.ndarray:
        """Standard deviation of the predicted tool point per component (J Σ Jᵀ), shape (n, 3)."""
        J = self.chain.error_jacobian(q, self.params)
        return np.sqrt(np.maximum(np.einsum("nip,pq,niq->ni", J, self.cov, J), 0.0))

    def to_dict(self) -> dict:
        names = self.chain.param_names
        return {"method": self.method, "iterations": self.iterations, "converged": self.converged,
                "sigma_mm": self.sigma_mm, "fit_rms_mm": self.fit_rms_mm,
                "n_identified": int(self.free.sum()), "n_slots": len(names),
                "parameters": [{"name": n, "value": float(v), "std": float(s) if f else None, "identified": bool(f)}
                               for n, v, s, f in zip(names, self.params, self.std, self.free)],
                "fixed_slots": [n for n, f in zip(names, self.free) if not f],
                "unidentifiable_combinations": [c["text"] for c in self.fixed],
                "singular_values_scaled": self.singular_values.tolist()}

    @classmethod
    def from_dict(cls, chain, d: dict) -> "GeometricResult":
        p = d["parameters"]
        if [x["name"] for x in p] != list(chain.param_names):
            raise InputError(f"model parameters {[x['name'] for x in p][:4]}... do not belong to machine {chain.name!r}")
        params = np.array([x["value"] for x in p], float)
        std = np.array([x["std"] or 0.0 for x in p], float)
        free = np.array([x["identified"] for x in p], bool)
        return cls(chain, params, free, np.diag(std ** 2), std, d["sigma_mm"], d["fit_rms_mm"],
                   np.array(d["singular_values_scaled"]), [{"text": t} for t in d["unidentifiable_combinations"]],
                   d["iterations"], d["converged"], d.get("method", "volcomp"))


def _weights(poses):
    return np.ones(len(poses)) if poses.sigma_mm is None else 1.0 / poses.sigma_mm


def _result(chain, poses, x, free, combos, sv, it, conv, method) -> GeometricResult:
    w = _weights(poses)
    r = (poses.xyz_mm - chain.tool_point(poses.q, x))
    rw = (r * w[:, None]).ravel()
    J = (chain.error_jacobian(poses.q, x)[:, :, free] * w[:, None, None]).reshape(-1, free.sum())
    dof = max(rw.size - int(free.sum()), 1)
    s2 = float(rw @ rw / dof) if poses.sigma_mm is None else 1.0
    cov = np.zeros((chain.n_params, chain.n_params))
    cov[np.ix_(free, free)] = s2 * np.linalg.pinv(J.T @ J)
    return GeometricResult(chain, x, free, cov, np.sqrt(np.maximum(np.diag(cov), 0.0)), float(np.sqrt(np.mean(r ** 2))),
                           float(np.sqrt(np.mean(np.sum(r ** 2, 1)))), sv, combos, it, conv, method)


class ArmCalibrator:
    """Geometric calibration of a serial chain (scikit-learn style: settings here, :meth:`fit` returns self).

    ``max_iter``: LM iterations (1–10,000). After :meth:`fit`, ``result_`` is a :class:`GeometricResult`.
    """

    def __init__(self, chain, max_iter: int = LM_MAX_ITER):
        if not 1 <= int(max_iter) <= 10_000:
            raise ValueError(f"max_iter must be in [1, 10000], got {max_iter}")
        self.chain = chain
        self.max_iter = int(max_iter)

    def fit(self, poses) -> "ArmCalibrator":
        c = self.chain
        free, combos, sv = identifiable_slots(c, poses.q)
        x, it, conv = _lm(c, poses.q, poses.xyz_mm, np.zeros(c.n_params), free, _weights(poses), self.max_iter)
        self.result_ = _result(c, poses, x, free, combos, sv, it, conv, "volcomp")
        return self


def fit_plain_lsq(chain, poses) -> GeometricResult:
    """The plain baseline: scipy ``least_squares`` (LM) on every DH slot + base + tool (no β, no
    identifiability handling, no regularisation), from the nominal chain."""
    from scipy.optimize import least_squares
    free = np.array(["beta" not in n for n in chain.param_names])
    w = _weights(poses)

    def res(z):
        x = np.zeros(chain.n_params)
        x[free] = z
        return ((chain.tool_point(poses.q, x) - poses.xyz_mm) * w[:, None]).ravel()

    def jac(z):
        x = np.zeros(chain.n_params)
        x[free] = z
        return (chain.error_jacobian(poses.q, x)[:, :, free] * w[:, None, None]).reshape(-1, free.sum())

    sol = least_squares(res, np.zeros(free.sum()), jac=jac, method="lm")
    x = np.zeros(chain.n_params)
    x[free] = sol.x
    return _result(chain, poses, x, free, [], np.array([]), int(sol.nfev), bool(sol.success), "plain least squares")


def fit_base_tool(chain, poses) -> GeometricResult:
    """Nominal chain with a fitted base frame and tool point (LM on the ``base.*`` and ``tool.*`` slots)."""
    free = np.array([n.startswith(("base.", "tool.")) for n in chain.param_names])
    x, it, conv = _lm(chain, poses.q, poses.xyz_mm, np.zeros(chain.n_params), free, _weights(poses))
    return _result(chain, poses, x, free, [], np.array([]), it, conv, "nominal + base/tool")
