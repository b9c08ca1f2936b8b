"""Geometric calibration of a serial chain from measured tool points.

Levenberg–Marquardt on the chain's analytic error Jacobian; a pivoted QR of the column-scaled Jacobian at the
nominal chain keeps the largest independent set of slots, the others fixed at 0 and named with the
unidentifiable combinations (nothing regularised away); standard errors σ²(JᵀWJ)⁻¹ and prediction bands
J Σ Jᵀ. The plain baselines beside it: :func:`fit_plain_lsq` (every slot, minimum-norm Gauss–Newton) and
:func:`fit_base_tool` (base frame and tool point only). Method: ``docs/reference/arm-calibration.md``.
Lengths mm, angles rad; ``q`` (n, nq) in the joints' units."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from .arm_frames import placed_start
from .io import InputError

RANK_RTOL = 1e-7          # |R_kk| / |R_00| of the scaled QR below this: the slot depends on the others EXACTLY
IDENTIFY_RTOL = 3e-4
"""The fits' cut (:func:`fit_model`): a slot whose unit-norm column keeps less than this fraction of its length once
the columns chosen before it are removed (the pivoted QR's |R_kk|) is held at nominal: the data cannot tell it from
the others at the arm's scale. The plain fit's cutoff (:data:`PLAIN_RCOND`, the gap measured on both real grids). At
:data:`RANK_RTOL` (exact dependencies only) the UR5 grid's fit freed link 5's a and d offsets beside the nearly
parallel shoulder/elbow axes and returned 4.5 to 11.6 mm and 39 to 102 mrad with standard errors of the same size
(8.5 mm, 73 mrad): no physical link parameters. At this cut the largest identified UR5 link deviation is 0.67 mm /
11.6 mrad and the held-out error is unchanged or lower (docs/decisions/020-benchmark-notebook.md, "Arm frames kept apart"). The pose-set check
(:func:`check_pose_set`) still counts exact dependencies only."""
COMBINATION_SHOW = 0.1    # a slot enters a named null combination with |weight| above this
LM_MAX_ITER = 100
LM_XTOL = 1e-10           # stop when a step lowers the residual sum of squares by less than this (relative)
LAMBDA0 = 1e-3
GENERIC_POSES = 400       # random poses within the limits that define the chain's generic identifiable rank
GENERIC_LIMIT_DEG = 170.0  # random revolute poses stay within ±this (a full turn adds nothing)


TABLE_MODEL = "dh+compliance+table"
"""A slot set (the last of :data:`MODELS`, ``docs/explanation/serial-arms.md``): link errors +
base + tool + joint compliance + a JOINT-ERROR TABLE per joint, Δθ_i(q_i) linear between knots every
:data:`TABLE_STEP_DEG` (:class:`ExtendedChain` ``table``) — the non-parametric form of the first-harmonic slots (a
gear's or encoder's cyclic error over a few degrees, which one sine per turn cannot follow)."""
TABLE_STEP_DEG = 5.0
"""Knot spacing of the joint-error table, deg (knots at multiples of it)."""
TABLE_SPAN_DEG = 180.0
"""Table knots lie within ±this of the joint zero (and inside the joint's limits): beyond, the table is zero."""
TABLE_KNOT_RE = re.compile(r"^table\.([^.]+)\.at_[-+0-9.e]+deg_rad$")
"""A joint-error table knot's slot name (:func:`table_knot_name`); group 1: the joint's column stem (``q1``)."""


def table_knot_name(joint: str, knot_deg: float) -> str:
    """The slot name of the table knot of ``joint`` (its column stem, ``q1``) at ``knot_deg``: ``table.q1.at_+5deg_rad``."""
    return f"table.{joint}.at_{knot_deg:+g}deg_rad"


TABLE_MIN_SUPPORT = 10.0
"""A table knot is identified only where the fit poses give it at least this much support (Σ over poses of its hat
function, in poses): a knot seen by one or two poses at the edge of the data would fit them and swing freely."""
MODELS = ("dh", "dh+compliance", "dh+compliance+harmonic", TABLE_MODEL)
"""Slot sets of the geometric stage, chosen by CV inside the fit poses: link errors + base + tool; + joint compliance
under gravity; + first-harmonic joint errors (encoder / gear eccentricity); the joint-error table instead of the
harmonics (:data:`TABLE_MODEL`)."""
CV_FOLDS = 5               # k-fold CV inside the fit set that chooses the slot set
TIE_REL = 1e-3             # a richer slot set must lower the CV mean error by more than this (relative)
GRAVITY_M_PER_MM = 1e-3    # gravity moments in m (per unit mass): compliance slots in rad per m
LEVER_MIN_MM = 1.0         # a joint moving the tool point less than this per rad (RMS over generic poses) gets no
# non-geometric slot: 1e-4 rad of deflection there is 0.1 µm, below any tracker (e.g. a wrist joint on the tool axis)
ZERO_COLUMN_MM = 1e-8     # a slot moving the tool point less than this (mm per mm or rad, RMS over poses) does nothing


def _scaled(J2d):
    """Unit-norm columns (slots in mm and rad made comparable); a column that is zero up to rounding stays zero."""
    s = np.linalg.norm(J2d, axis=0)
    zero = s <= ZERO_COLUMN_MM * np.sqrt(J2d.shape[0])
    s = np.where(zero, 1.0, s)
    return np.where(zero, 0.0, J2d / s), s


def _independent_columns(Js, first, rtol: float = RANK_RTOL) -> np.ndarray:
    """The largest independent set of the columns of ``Js`` (m, p) (unit-norm or zero), the columns ``first`` (p,)
    bool taken before the others: a pivoted QR of the ``first`` block, then one of the other columns with their
    components along the chosen ones removed. A column whose remaining norm is below ``rtol`` (relative to the
    largest column) depends on the chosen ones. Returns a mask (p,)."""
    from scipy.linalg import qr
    tol = rtol * max(float(np.linalg.norm(Js, axis=0).max(initial=0.0)), 1e-300)
    free = np.zeros(Js.shape[1], bool)
    head, rest = np.flatnonzero(first), np.flatnonzero(~np.asarray(first, bool))
    Q = np.zeros((Js.shape[0], 0))
    if len(head):                        # the frame block (at most 9 columns): its orthonormal basis is kept
        Qb, R, piv = qr(Js[:, head], mode="economic", pivoting=True)
        r = int(np.sum(np.abs(np.diag(R)) > tol))
        free[head[piv[:r]]] = True
        Q = Qb[:, :r]
    if len(rest):                        # the link block, factored in place (no second (3n, p) array)
        B = np.asfortranarray(Js[:, rest] - Q @ (Q.T @ Js[:, rest]))
        _, R, piv = qr(B, mode="raw", pivoting=True, overwrite_a=True)
        r = int(np.sum(np.abs(np.diag(R)) > tol))
        free[rest[piv[:r]]] = True
    return free


def identifiable_slots(chain, q, errors=None, exclude=None, orientation: bool = False,
                       rtol: float = RANK_RTOL) -> tuple[np.ndarray, list[dict], np.ndarray]:
    """(free mask (n_params,), null combinations, scaled singular values) from the Jacobian at ``q``; ``rtol``: the
    dependency cut (:data:`RANK_RTOL` exact, :data:`IDENTIFY_RTOL` the fits'); ``exclude``
    (n_params,) bool: slots held at nominal whatever the data (their columns count as zero); ``orientation``: 6-DoF
    poses, the tool frame's rotation rows (times :data:`ORIENTATION_LEVER_MM`) count too. The frame slots
    (:data:`errormap.arm_frames.FRAME_SLOT_PREFIXES`: base and tool) are taken first, so a link slot that moves the
    tool point like a frame slot (link 1's offsets against the base) is the one held at nominal: the link
    parameters stay deviations of the machine's table wherever the instrument stands."""
    from .arm_frames import FRAME_SLOT_PREFIXES
    if orientation:
        J6 = chain.error_jacobian(q, errors, orientation=True)
        J = np.concatenate([J6[:, :3], J6[:, 3:] * ORIENTATION_LEVER_MM], axis=1).reshape(-1, chain.n_params)
    else:
        J = chain.error_jacobian(q, errors).reshape(-1, chain.n_params)
    if exclude is not None:
        J = np.where(np.asarray(exclude, bool)[None, :], 0.0, J)
    Js, _ = _scaled(J)
    free = _independent_columns(Js, np.array([n.startswith(FRAME_SLOT_PREFIXES) for n in chain.param_names]), rtol)
    rank = int(free.sum())
    # the singular values and right singular vectors of Js are those of its triangular factor (min(3n, p), p), so
    # the (3n)² factor of a full SVD is never formed (memory O(n p)); Vt (p, p) holds the null space
    C = np.linalg.qr(Js, mode="r")
    _, sv, Vt = np.linalg.svd(C, full_matrices=True)
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


ORIENTATION_LEVER_MM = 150.0
"""The default weight of a measured orientation beside a measured position: an orientation standard deviation of
σ_mm / this (rad) where the pose file states no ``sigma_rad`` — 1 mrad counts like 0.15 mm. A 6-DoF laser tracker
states ~0.01° (1.7e-4 rad) on the probe's orientation beside ~0.025 mm on its position at a cell's distance: their
ratio is ~150 mm (and it is about the lever of a tool on a flange, where a tilt becomes a displacement)."""


def _rot_data(poses):
    """(measured tool-frame rotations (n, 3, 3), weights (n,) in 1/rad) of 6-DoF poses, or None (position only)."""
    if getattr(poses, "rot", None) is None:
        return None
    w = 1.0 / poses.sigma_rad if poses.sigma_rad is not None else ORIENTATION_LEVER_MM * _weights(poses)
    return poses.rot, w


def orientation_rows(chain, q, x, free, rot):
    """The orientation rows of a 6-DoF fit: weighted residuals (3n,) — the rotation vector (world axes, rad) taking
    the predicted tool frame to the measured one, ``rotvec(R_meas · R_predᵀ)`` — and, where ``free`` is given, their
    Jacobian rows (3n, n_free) (the slots' tool-frame rotation columns); ``rot`` from :func:`_rot_data`."""
    from scipy.spatial.transform import Rotation
    R, w = rot
    F = chain.frames(q, x)
    r = (Rotation.from_matrix(R @ np.swapaxes(F[:, -1, :3, :3], 1, 2)).as_rotvec() * w[:, None]).ravel()
    if free is None:
        return r, None
    J = chain.error_jacobian(q, x, frames=F, orientation=True)[:, 3:, free] * w[:, None, None]
    return r, J.reshape(-1, int(np.sum(free)))


def _residual(chain, q, xyz, x, w, rot):
    r = ((xyz - chain.tool_point(q, x)) * w[:, None]).ravel()
    return r if rot is None else np.concatenate([r, orientation_rows(chain, q, x, None, rot)[0]])


def _jacobian(chain, q, x, free, w, rot):
    J = (chain.error_jacobian(q, x)[:, :, free] * w[:, None, None]).reshape(-1, free.sum())
    return J if rot is None else np.vstack([J, orientation_rows(chain, q, x, free, rot)[1]])


def _lm(chain, q, xyz, x0, free, w, max_iter=LM_MAX_ITER, rot=None):
    """Levenberg–Marquardt on the slots ``free``; ``w`` (n,) weights (1/σ); ``rot`` measured orientations and their
    weights (:func:`_rot_data`) or None. Returns (x, iterations, converged)."""
    x = x0.copy()
    r = _residual(chain, q, xyz, x, w, rot)
    cost = r @ r
    lam = LAMBDA0
    for it in range(1, max_iter + 1):
        J = _jacobian(chain, q, x, free, w, rot)
        A = J.T @ J
        g = J.T @ r
        dA = np.diag(A).copy()
        improved = False
        while lam < 1e12:
            step = np.linalg.solve(A + lam * np.diag(np.maximum(dA, 1e-30)), g)
            xn = x.copy()
            xn[free] += step
            rn = _residual(chain, q, xyz, xn, w, rot)
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
    cv_table: list = field(default_factory=list)
    full_covariance: bool = True
    """False for a stage read from a file written before the covariance was saved (its ``cov`` then holds the
    standard errors alone: J Σ Jᵀ without the correlations is no band)."""

    @property
    def model(self) -> str:
        """The slot set: ``"dh"`` (link errors + base + tool) or ``"dh+compliance"`` / ``"dh+compliance+harmonic"``."""
        return getattr(self.chain, "model", "dh")

    def predict(self, q) -> np.ndarray:
        """Tool point of the identified chain, mm, shape (n, 3)."""
        return self.chain.tool_point(q, self.params)

    def band_std_mm(self, q) -> np.ndarray:
        """Standard deviation of the predicted tool point per component (J Σ Jᵀ), shape (n, 3)."""
        J = self.chain.error_jacobian(q, self.params)
        return np.sqrt(np.maximum(np.einsum("nip,pq,niq->ni", J, self.cov, J), 0.0))

    def to_dict(self) -> dict:
        names = self.chain.param_names
        return {"method": self.method, "model": self.model, "cv_table": self.cv_table, "iterations": self.iterations, "converged": self.converged,
                "sigma_mm": self.sigma_mm, "fit_rms_mm": self.fit_rms_mm,
                "n_identified": int(self.free.sum()), "n_slots": len(names),
                "parameters": [{"name": n, "value": float(v), "std": float(s) if f else None, "identified": bool(f)}
                               for n, v, s, f in zip(names, self.params, self.std, self.free)],
                "fixed_slots": [n for n, f in zip(names, self.free) if not f],
                "unidentifiable_combinations": [c["text"] for c in self.fixed],
                "singular_values_scaled": self.singular_values.tolist(),
                "covariance_identified": self.cov[np.ix_(self.free, self.free)].tolist()}

    @classmethod
    def from_dict(cls, chain, d: dict) -> "GeometricResult":
        p = d["parameters"]
        chain = extended_chain(chain, d.get("model", "dh"))
        if [x["name"] for x in p] != list(chain.param_names):
            raise InputError(f"model parameters {[x['name'] for x in p][:4]}... do not belong to machine {chain.name!r}")
        params = np.array([x["value"] for x in p], float)
        std = np.array([x["std"] or 0.0 for x in p], float)
        free = np.array([x["identified"] for x in p], bool)
        cov, full = np.diag(std ** 2), "covariance_identified" in d   # files before it: the standard errors only
        if full:
            c = np.asarray(d["covariance_identified"], float)
            if c.shape != (free.sum(),) * 2:
                raise InputError(f"model key 'covariance_identified': shape {c.shape}, expected {(int(free.sum()),) * 2}")
            cov = np.zeros((len(p), len(p)))
            cov[np.ix_(free, free)] = c
        out = cls(chain, params, free, cov, std, d["sigma_mm"], d["fit_rms_mm"],
                  np.array(d["singular_values_scaled"]), [{"text": t} for t in d["unidentifiable_combinations"]],
                  d["iterations"], d["converged"], d.get("method", "volcomp"), d.get("cv_table", []))
        out.full_covariance = full
        return out


def _weights(poses):
    return np.ones(len(poses)) if poses.sigma_mm is None else 1.0 / poses.sigma_mm


def _result(chain, poses, x, free, combos, sv, it, conv, method) -> GeometricResult:
    w, rot = _weights(poses), _rot_data(poses)
    r = (poses.xyz_mm - chain.tool_point(poses.q, x))
    rw = _residual(chain, poses.q, poses.xyz_mm, x, w, rot)
    J = _jacobian(chain, poses.q, x, free, w, rot)
    dof = max(rw.size - int(free.sum()), 1)
    s2 = float(rw @ rw / dof) if poses.sigma_mm is None else 1.0
    cov = np.zeros((chain.n_params, chain.n_params))
    cov[np.ix_(free, free)] = s2 * np.linalg.pinv(J.T @ J)
    return GeometricResult(chain, x, free, cov, np.sqrt(np.maximum(np.diag(cov), 0.0)), float(np.sqrt(np.mean(r ** 2))),
                           float(np.sqrt(np.mean(np.sum(r ** 2, 1)))), sv, combos, it, conv, method)


PLAIN_RCOND = 3e-4
"""Relative singular-value cutoff of the plain fit's step (column-scaled Jacobian, unit-norm columns): directions
below it are ones the data do not determine and the step never moves along them. Measured on both real grids, whole
and in all 161 outer / inner fold fit parts the benchmark uses, the scaled spectrum has a gap: the weakest
well-determined direction sits at >= 4.5e-3 of the largest, the exact dependencies (base z against link-1 offset,
offsets along parallel axes, ...) at <= 1e-13, i.e. round-off. On the UR5 only, two directions sit between 1.2e-6 and
2.3e-5 (link 5's a and d offsets beside the nearly parallel shoulder/elbow axes); their standard errors at the fit's
residual are 19 mm and 179 mm, so the data do not pin them down at the arm's scale and they are dropped too. A cutoff
of 1e-9 (exact dependencies only) did not converge in 100 iterations on the UR5, at the same fit RMS to 5 digits."""
PLAIN_MAX_ITER = 100
PLAIN_STEP_TOL_MM = 1e-11
"""The plain fit stops when a step changes the fitted tool points by less than this (RMS per component, mm): two
orders below the round-off reproducibility it is tested to (1e-9 mm) and two above the tool point's own round-off
(~1e-13 mm at 1 m)."""
PLAIN_COST_RTOL = 1e-12
"""A step is accepted when it raises the (weighted) cost by no more than this fraction: the cost's own round-off
(a sum of up to a few thousand squares, relative error ~1e-14). Gauss–Newton converges only linearly on the real grids
(the step shrinks by ~0.4 per iteration: a large-residual fit), so the last dozen steps change the cost below its
round-off; a strict ``<=`` then rejected them at random, the damping stalled the fit ~1e-7 mm short of its minimum
and where it stalled moved with the BLAS thread count (measured 3.5e-7 mm on a WAM sector). With this tolerance
both thread counts reach the minimum to ~1e-13 mm."""
PLAIN_DAMP0 = 1e-3        # first damping (relative to the largest scaled singular value) when a Gauss–Newton step fails


def _min_norm_lsq(chain, q, xyz, x0, free, w, max_iter=PLAIN_MAX_ITER):
    """Gauss–Newton on the slots ``free`` whose step is the MINIMUM-NORM least-squares step of the column-scaled
    Jacobian (SVD, directions below :data:`PLAIN_RCOND` dropped), damped (Levenberg–Marquardt in the SVD basis) only
    where the full step does not lower the residual. It never moves along directions the data do not determine, so
    from ``x0`` it converges to the pseudo-inverse solution: reproducible to round-off whatever the BLAS threading.
    Returns (x, iterations, converged)."""
    x = x0.copy()
    r = ((xyz - chain.tool_point(q, x)) * w[:, None]).ravel()
    cost = r @ r
    n_res = r.size
    for it in range(1, max_iter + 1):
        J = (chain.error_jacobian(q, x)[:, :, free] * w[:, None, None]).reshape(-1, free.sum())
        Js, s = _scaled(J)
        U, sv, Vt = np.linalg.svd(Js, full_matrices=False)
        keep = sv > PLAIN_RCOND * sv[0]
        U, sv, Vt = U[:, keep], sv[keep], Vt[keep]
        ur = U.T @ r
        lam, accepted = 0.0, False
        while lam < 1e12 * sv[0] ** 2:
            coef = sv * ur / (sv ** 2 + lam)
            z = (Vt.T @ coef) / s
            xn = x.copy()
            xn[free] += z
            rn = ((xyz - chain.tool_point(q, xn)) * w[:, None]).ravel()
            cn = rn @ rn
            if cn <= cost * (1.0 + PLAIN_COST_RTOL):
                accepted = True
                change = np.sqrt(np.sum((sv * coef) ** 2) / n_res)   # RMS change of the (weighted) tool points
                x, r, cost = xn, rn, cn
                break
            lam = (PLAIN_DAMP0 * sv[0]) ** 2 if lam == 0 else lam * 10
        if not accepted or change < PLAIN_STEP_TOL_MM:
            return x, it, True
    return x, max_iter, False


def fit_plain_lsq(chain, poses) -> GeometricResult:
    """The plain baseline: unregularised least squares on every DH slot + base + tool (no β, no identifiability
    handling, no regularisation), from the nominal chain — by Gauss–Newton with the minimum-norm step
    (:func:`_min_norm_lsq`), i.e. the pseudo-inverse solution: the least-squares fit of everything the data determine,
    and no motion along what they do not (which an unguarded LM runs away along, its prediction then moving with
    round-off)."""
    free = np.array(["beta" not in n for n in chain.param_names])
    x, it, conv = _min_norm_lsq(chain, poses.q, poses.xyz_mm, placed_start(chain, poses.q, poses.xyz_mm), free,
                                _weights(poses))
    return _result(chain, poses, x, free, [], np.array([]), it, conv, "plain least squares")


def fit_base_tool(chain, poses) -> GeometricResult:
    """Nominal chain with a fitted base frame and tool point (LM on the ``base.*`` and ``tool.*`` slots)."""
    free = np.array([n.startswith(("base.", "tool.")) for n in chain.param_names])
    x, it, conv = _lm(chain, poses.q, poses.xyz_mm, placed_start(chain, poses.q, poses.xyz_mm), free, _weights(poses),
                      rot=_rot_data(poses))
    return _result(chain, poses, x, free, [], np.array([]), it, conv, "nominal + base/tool")


# ---------------------------------------------------------------- non-geometric joint slots



class ExtendedChain:
    """A serial chain with non-geometric joint slots after its own error slots.

    The arm's own geometry (``chain``) is evaluated at effective joints ``q + Δθ(q)``, per revolute
    joint ``i``:

    Only revolute joints that move the tool point by at least :data:`LEVER_MIN_MM` per rad get slots.

    * ``compliance.<qi>_rad_per_m`` — ``Δθ_i = c_i · τ_i(q)``, ``τ_i`` the gravity moment about the
      joint's axis of unit masses at the downstream joint origins (link ends) and the tool point, from
      the NOMINAL chain, gravity along −z of the chain's base frame (an upright arm), in m per unit
      mass (:func:`errormap.arm_simulate.gravity_moment_mm` / 1000). A joint whose axis is vertical
      carries no moment: its column is zero and the identifiability check fixes it;
    * ``harmonic.<qi>.sin_rad`` / ``.cos_rad`` — ``Δθ_i = a_i sin q_i + b_i cos q_i`` (once-per-turn
      encoder or gear eccentricity; the constant offset is the DH slot already).

    Duck-types what calibration and compensation use of :class:`errormap.chain.Chain`
    (``param_names``, ``tool_point``, ``error_jacobian``, ``frames``, ``fk``, ``joint_jacobian``);
    everything else is the chain's. The joint Jacobian is that of the effective joints,
    ``J(q + Δθ) · (I + ∂Δθ/∂q)`` (∂τ/∂q by :func:`errormap.arm_simulate.gravity_moment_jacobian_mm`).
    """

    def __init__(self, chain, compliance: bool = True, harmonic: bool = False, table: bool = False):
        self.chain = chain
        self.compliance, self.harmonic, self.table = bool(compliance), bool(harmonic), bool(table)
        self.model = ("dh" + ("+compliance" if compliance else "") + ("+harmonic" if harmonic else "")
                      + ("+table" if table else ""))
        rng = np.random.default_rng(0)
        qg = rng.uniform(np.maximum(chain.joint_lo, -GENERIC_LIMIT_DEG), np.minimum(chain.joint_hi, GENERIC_LIMIT_DEG),
                         (GENERIC_POSES, chain.n_joints))
        lever = np.degrees(np.sqrt(np.mean(np.sum(chain.joint_jacobian(qg) ** 2, axis=1), axis=0)))  # mm per rad
        rev = [j for j, jt in enumerate(chain.joints) if jt.type == "revolute" and lever[j] >= LEVER_MIN_MM]
        cols = chain.joint_columns
        terms = []   # (name, joint, kind)
        if compliance:
            terms += [(f"compliance.{cols[j].rsplit('_', 1)[0]}_rad_per_m", j, "c") for j in rev]
        if harmonic:
            for j in rev:
                b = cols[j].rsplit('_', 1)[0]
                terms += [(f"harmonic.{b}.sin_rad", j, "s"), (f"harmonic.{b}.cos_rad", j, "k")]
        knots = []   # (n_table,) knot of each table term, deg
        if table:
            for j in rev:
                b = cols[j].rsplit('_', 1)[0]
                lo = max(chain.joint_lo[j], -TABLE_SPAN_DEG)
                hi = min(chain.joint_hi[j], TABLE_SPAN_DEG)
                for kn in np.arange(np.ceil(lo / TABLE_STEP_DEG), np.floor(hi / TABLE_STEP_DEG) + 1) * TABLE_STEP_DEG:
                    terms.append((table_knot_name(b, kn), j, "t"))
                    knots.append(float(kn))
        self.terms = terms
        self._table_idx = np.array([k for k, t in enumerate(terms) if t[2] == "t"], int)
        self._table_joint = np.array([terms[k][1] for k in self._table_idx], int)
        self._table_knot_deg = np.array(knots, float)
        self._term_joint = np.array([t[1] for t in terms], int)   # (n_extra,) the joint each slot turns
        self.param_names = tuple(chain.param_names) + tuple(t[0] for t in terms)
        self.n_geo = chain.n_params
        self._basis_memo = None   # (q bytes, its basis): a fit evaluates the same poses at every iteration

    def __getattr__(self, name):
        return getattr(self.__dict__["chain"], name)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def _split(self, errors):
        if errors is None:
            return None, np.zeros(len(self.terms))
        e = np.asarray(errors, float)
        if e.shape != (self.n_params,):
            raise ValueError(f"expected errors of shape ({self.n_params},), got {e.shape}")
        return e[:self.n_geo], e[self.n_geo:]

    def _basis(self, q) -> np.ndarray:
        """∂Δθ/∂(extra slot) per pose, rad per slot unit, shape (n, n_extra), read-only; the last poses' kept."""
        q = np.atleast_2d(np.asarray(q, float))
        key, memo = (q.shape, q.tobytes()), self._basis_memo   # read once: another thread may replace it
        if memo is None or memo[0] != key:
            out = self._basis_of(q)
            out.flags.writeable = False
            memo = self._basis_memo = (key, out)
        return memo[1]

    def _basis_of(self, q) -> np.ndarray:
        """:meth:`_basis` computed, (n, n_extra)."""
        from .arm_simulate import gravity_moment_mm
        out = np.zeros((len(q), len(self.terms)))
        tau = gravity_moment_mm(self.chain, q) * GRAVITY_M_PER_MM if self.compliance else None
        for k, (_, j, kind) in enumerate(self.terms):
            if kind == "t":
                continue
            out[:, k] = tau[:, j] if kind == "c" else (np.sin if kind == "s" else np.cos)(np.radians(q[:, j]))
        if len(self._table_idx):   # hat functions: 1 at the knot, 0 one step away (linear interpolation of a table)
            u = (q[:, self._table_joint] - self._table_knot_deg[None, :]) / TABLE_STEP_DEG
            out[:, self._table_idx] = np.maximum(0.0, 1.0 - np.abs(u))
        return out

    def _basis_jacobian(self, q) -> np.ndarray:
        """∂(∂Δθ/∂slot)/∂q: rad per slot unit per joint unit, shape (n, n_extra, nq)."""
        from .arm_simulate import gravity_moment_jacobian_mm
        q = np.atleast_2d(np.asarray(q, float))
        out = np.zeros((len(q), len(self.terms), q.shape[1]))
        dtau = gravity_moment_jacobian_mm(self.chain, q) * GRAVITY_M_PER_MM if self.compliance else None
        for k, (_, j, kind) in enumerate(self.terms):
            if kind == "t":
                continue
            if kind == "c":
                out[:, k, :] = dtau[:, j, :]
            else:
                r = np.radians(q[:, j])
                out[:, k, j] = (np.cos(r) if kind == "s" else -np.sin(r)) * (np.pi / 180)
        if len(self._table_idx):   # the hat's slope, per deg (one-sided at a knot: the right-hand slope)
            u = (q[:, self._table_joint] - self._table_knot_deg[None, :]) / TABLE_STEP_DEG
            slope = np.where((u >= 0) & (u < 1), -1.0, np.where((u < 0) & (u > -1), 1.0, 0.0)) / TABLE_STEP_DEG
            out[:, self._table_idx, self._table_joint] = slope
        return out

    def effective_joints(self, q, errors=None) -> np.ndarray:
        """``q + Δθ(q)`` in the joints' units, shape (n, nq)."""
        q = np.atleast_2d(np.asarray(q, float))
        _, ex = self._split(errors)
        if not len(self.terms) or not np.any(ex):
            return q
        dth = self._basis(q) * ex[None, :]
        qe = q.copy()
        for k, (_, j, kind) in enumerate(self.terms):
            if kind != "t":
                qe[:, j] += np.degrees(dth[:, k])
        for j in np.unique(self._table_joint):   # a table's hats, summed per joint
            qe[:, j] += np.degrees(dth[:, self._table_idx[self._table_joint == j]].sum(1))
        return qe

    def frames(self, q, errors=None):
        return self.chain.frames(self.effective_joints(q, errors), self._split(errors)[0])

    def fk(self, q, errors=None):
        return self.frames(q, errors)[:, -1]

    def tool_point(self, q, errors=None):
        return self.frames(q, errors)[:, -1, :3, 3]

    def joint_jacobian(self, q, errors=None, orientation: bool = False, frames=None):
        """∂(tool point [, rotation vector])/∂q of the extended chain, ``J(q + Δθ) · (I + ∂Δθ/∂q)``,
        shape (n, 3 or 6, nq) per joint unit."""
        F = self.frames(q, errors) if frames is None else frames
        geo, ex = self._split(errors)
        J = self.chain.joint_jacobian(q, geo, orientation=orientation, frames=F)
        if not len(self.terms) or not np.any(ex):
            return J
        q = np.atleast_2d(np.asarray(q, float))
        dq = np.zeros((len(q), q.shape[1], q.shape[1]))       # ∂(Δθ in joint units)/∂q
        B = np.degrees(self._basis_jacobian(q)) * ex[None, :, None]
        for k, (_, j, kind) in enumerate(self.terms):
            if kind != "t":
                dq[:, j, :] += B[:, k, :]
        for j in np.unique(self._table_joint):
            dq[:, j, :] += B[:, self._table_idx[self._table_joint == j], :].sum(1)
        return J + np.einsum("nij,njk->nik", J, dq)

    def error_jacobian(self, q, errors=None, frames=None, orientation: bool = False):
        """∂(tool point [, tool-frame rotation vector])/∂(every slot), shape (n, 3 or 6, n_params)."""
        F = self.frames(q, errors) if frames is None else frames
        geo = self._split(errors)[0]
        Jg = self.chain.error_jacobian(q, geo, frames=F, orientation=orientation)
        if not self.terms:
            return Jg
        Jq = self.chain.joint_jacobian(q, geo, frames=F, orientation=orientation)   # per joint unit (deg)
        B = np.degrees(self._basis(q))                              # deg per slot unit
        cols = Jq[:, :, self._term_joint] * B[:, None, :]
        return np.concatenate([Jg, cols], axis=2)


def extended_chain(chain, model: str):
    """``chain`` itself for ``"dh"``, else its :class:`ExtendedChain` with the slot set ``model``."""
    if model not in MODELS:
        raise InputError(f"geometric model {model!r}: expected one of {MODELS}")
    if model == "dh":
        return chain
    return ExtendedChain(chain, compliance=True, harmonic="+harmonic" in model, table=model.endswith("+table"))


def table_held(c, q) -> np.ndarray | None:
    """The joint-error table slots of the extended chain ``c`` held at zero on the poses ``q`` (n, nq): (n_params,)
    bool, or None for a chain without a table. Held: every knot whose support (Σ over poses of its hat) is below
    :data:`TABLE_MIN_SUPPORT`, and per joint the knot of the largest support — its value is the table's zero, so the
    joint's constant offset stays the DH slot's (the hats sum to one: a table with every knot free and the DH offset
    is one exact dependency, and a weak constant drift along it was measured: 1.6° on the UR5's joint 5)."""
    if not getattr(c, "table", False):
        return None
    held = np.zeros(c.n_params, bool)
    w = c._basis(q)[:, c._table_idx].sum(0)
    held[c.n_geo + c._table_idx[w < TABLE_MIN_SUPPORT]] = True
    for j in np.unique(c._table_joint):
        k = np.flatnonzero(c._table_joint == j)
        held[c.n_geo + c._table_idx[k[np.argmax(w[k])]]] = True
    return held


def fit_model(chain, poses, model: str = "dh", max_iter: int = LM_MAX_ITER) -> GeometricResult:
    """Volcomp's LM on the identifiable slots of the slot set ``model`` (:data:`MODELS`; a joint-error table's
    knots held at zero where :func:`table_held` says)."""
    c = extended_chain(chain, model)
    free, combos, sv = identifiable_slots(c, poses.q, exclude=table_held(c, poses.q),
                                          orientation=getattr(poses, "rot", None) is not None, rtol=IDENTIFY_RTOL)
    x, it, conv = _lm(c, poses.q, poses.xyz_mm, placed_start(c, poses.q, poses.xyz_mm), free, _weights(poses),
                      max_iter, _rot_data(poses))
    return _result(c, poses, x, free, combos, sv, it, conv, "volcomp")


def fit_slots(chain, poses, free, model: str = "dh", max_iter: int = LM_MAX_ITER) -> GeometricResult:
    """LM on the given slots ``free`` (n_params of the slot set ``model``,) — e.g. another fit's identified
    set: the same parameterisation, so that two fits' slot values can be compared one by one."""
    c = extended_chain(chain, model)
    free = np.asarray(free, bool)
    if free.shape != (c.n_params,):
        raise ValueError(f"free must have shape ({c.n_params},), got {free.shape}")
    x, it, conv = _lm(c, poses.q, poses.xyz_mm, placed_start(c, poses.q, poses.xyz_mm), free, _weights(poses),
                      max_iter, _rot_data(poses))
    return _result(c, poses, x, free, [], np.array([]), it, conv, "volcomp")


def cv_labels(n: int, k_folds: int = CV_FOLDS, seed=0, groups=None) -> np.ndarray:
    """Fold label per pose, (n,) ints 0..k-1: shuffled k-fold from ``seed``, or with ``groups`` (n,)
    block labels whole blocks per fold (BLOCKED CV; at most ``k_folds`` folds).

    The same ``seed`` gives the same folds on every call, also when it is a ``SeedSequence`` object (spawning
    from it advances its count of children: the labels are drawn from a copy, so a later CV on "the same
    folds" — :func:`training.arm_residual.cv_pipelines` reusing this CV's fold fits — really is on them)."""
    import copy
    from .seeds import spawn_rngs
    rng = spawn_rngs(copy.deepcopy(seed), 1)[0]
    if groups is None:
        return rng.permutation(n) % k_folds
    u, inv = np.unique(np.asarray(groups), return_inverse=True)
    if len(u) < 2:
        raise ValueError("blocked CV needs at least 2 distinct groups")
    k_folds = min(k_folds, len(u))
    return (np.arange(len(u)) * k_folds // len(u))[inv]


FOLD_LABELS = "labels"
"""Key of the fold labels (n,) in a ``fold_fits`` dict of :func:`cv_models`: a CV reusing the fold fits checks
that its folds are these (a fit on another fold's fit part would have seen the held-out poses)."""


def cv_models(chain, poses, models=MODELS, k_folds: int = CV_FOLDS, seed=0, plain: bool = True,
              groups=None, fold_fits: dict | None = None) -> list[dict]:
    """k-fold CV inside ``poses`` of every slot set (and the plain LSQ baseline when ``plain``):
    per candidate ``{"model", "cv_mean_mm", "cv_rms_mm"}`` of the held-out position error norm.
    ``groups`` (n,) block labels: each fold holds whole blocks (BLOCKED CV; at most ``k_folds``).
    Folds: :func:`cv_labels`. ``fold_fits``: a dict filled with ``(fold, model) → GeometricResult`` (the fits
    on each fold's fit part, for a later CV of whole pipelines on the same folds without refitting)."""
    lab = cv_labels(len(poses), k_folds, seed, groups)
    cands = list(models) + (["plain"] if plain else [])
    errs = {m: np.empty(len(poses)) for m in cands}
    for f in range(int(lab.max()) + 1):
        tr, te = poses.subset(np.flatnonzero(lab != f)), np.flatnonzero(lab == f)
        for m in cands:
            r = fit_plain_lsq(chain, tr) if m == "plain" else fit_model(chain, tr, m)
            errs[m][te] = np.linalg.norm(poses.xyz_mm[te] - r.predict(poses.q[te]), axis=1)
            if fold_fits is not None:
                fold_fits[(f, m)] = r
    if fold_fits is not None:
        fold_fits[FOLD_LABELS] = lab
    return [{"model": m, "cv_mean_mm": float(e.mean()), "cv_rms_mm": float(np.sqrt(np.mean(e ** 2)))}
            for m, e in errs.items()]


def choose_model(table: list[dict]) -> str:
    """The candidate of ``table`` (:func:`cv_models`) with the lowest CV mean error; a richer slot set
    (later in the table) only if it lowers it by more than :data:`TIE_REL`."""
    best = table[0]
    for r in table[1:]:
        if r["cv_mean_mm"] < best["cv_mean_mm"] * (1 - TIE_REL):
            best = r
    return best["model"]


def _rank_blocks(key, k: int) -> np.ndarray:
    """k contiguous blocks of (nearly) equal size along ``key`` (n,), ties in file order: labels (n,) 0..k-1."""
    n = len(key)
    rank = np.empty(n, int)
    rank[np.argsort(np.asarray(key, float), kind="stable")] = np.arange(n)
    return rank * int(k) // n


def content_blocks(poses, k: int) -> dict:
    """Contiguous blocks of the poses, formed from the file's content alone (never its name), for checking a band on
    another part of the data than interleaved folds see: name (``"order"``, ``"sector"``) → labels (n,) ints 0..k-1.

    ``"order"``: ``k`` runs of consecutive poses in acquisition order — by ``time_s`` where the file has it, else by
    the file's row order (a later stretch of the session); ``"sector"``: ``k`` contiguous ranges of the FIRST joint's
    value, equal counts (another region of the workspace around the base axis). ``k`` in [2, n]."""
    n = len(poses)
    if not 2 <= int(k) <= n:
        raise ValueError(f"k must be in [2, {n}], got {k}")
    order = poses.time_s if poses.time_s is not None else poses.rows
    return {"order": _rank_blocks(order, k), "sector": _rank_blocks(poses.q[:, 0], k)}
