"""Error model and regularised identification for the PKMs (pkm-calibration paper).

Parameters ``r``: base joints (3k, mm), platform joints (3k, mm), leg zero lengths (k, mm), optionally leg
scales (k); ``k = 6`` (hexapod) or 3 (tripod); a leg's length is ``scale * q + offset``. The pose moves by
``dx/dr = -(dc/dx)^-1 dc/dr`` (``torch.func`` autodiff of the exact leg constraint); orientation residuals
(rad) times ``lever_mm`` are mm, so one noise level ``delta`` describes every residual component. Solved by
iteratively regularised Gauss-Newton (Tikhonov by SVD, λ by GCV, Morozov or the L-curve, the 6 gauge
directions fixed, Armijo line search, bounds). The method, its reasons and the report's keys:
``docs/explanation/parallel-kinematics.md`` (PKM calibration)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import svd
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from ..settings import keep_settings
from ..io import InputError
from ..threads import limit_threads
from ..transforms import skew
from .calibration_file import LAMBDA_RULES
from .hexapod import KinematicsError, forward_kinematics, inverse_kinematics, workspace_poses
from .machine_file import PKM
from .poses import PoseData, check_pose_set
from .pose_model import (machine_from_vector, parameter_names, parameter_vector, pose_errors_um, predict_poses,
                         robust_registration)


# ---------------------------------------------------------------------------------------------
# the error model: J = dx/dr by autodiff of the exact constraint
# ---------------------------------------------------------------------------------------------

def _constraint_single(x, r, q, R0, tool, k: int, rotate: bool):
    import torch
    base = r[:3 * k].reshape(k, 3)
    plat = r[3 * k:6 * k].reshape(k, 3)
    off = r[6 * k:7 * k]
    sc = r[7 * k:8 * k]
    tip = x[:3]
    if rotate:
        p = x[3:]
        zero = torch.zeros((), dtype=x.dtype)
        W = torch.stack([torch.stack([zero, -p[2], p[1]]), torch.stack([p[2], zero, -p[0]]),
                         torch.stack([-p[1], p[0], zero])])
        R = (torch.eye(3, dtype=x.dtype) + W) @ R0
    else:
        R = R0
    v = tip[None, :] + (plat - tool[None, :]) @ R.T - base
    return torch.linalg.norm(v, dim=1) - (sc * q + off)


def pose_jacobian(machine: PKM, q: np.ndarray, tip_mm: np.ndarray, platform2base: np.ndarray) -> np.ndarray:
    """First-order error transfer ``J = dx/dr`` at the poses reached with drive commands ``q``.

    ``q`` shape (n, k); ``tip_mm``/``platform2base`` the exact forward kinematics of ``machine`` at
    ``q`` (shape (n, 3), (n, 3, 3)). Returns shape (n, d, 8k): ``d = 6`` for the hexapod (tip, then
    the small rotation vector in the base frame, rad), 3 for the tripod.
    """
    import torch  # here, not with the module: `volcomp calibrate` checks its inputs before paying for torch
    k = machine.n_legs
    rotate = machine.kind == "hexapod"
    d = 6 if rotate else 3
    r = torch.as_tensor(parameter_vector(machine), dtype=torch.float64)
    tool = torch.as_tensor(machine.tool_in_platform_mm, dtype=torch.float64)
    x = torch.zeros((len(q), d), dtype=torch.float64)
    x[:, :3] = torch.as_tensor(tip_mm)
    fn = lambda xx, rr, qq, RR: _constraint_single(xx, rr, qq, RR, tool, k, rotate)
    jac = torch.func.vmap(torch.func.jacrev(fn, argnums=(0, 1)), in_dims=(0, None, 0, 0))
    Cx, Cr = jac(x, r, torch.as_tensor(np.asarray(q, float)), torch.as_tensor(np.asarray(platform2base, float)))
    return -np.linalg.solve(Cx.numpy(), Cr.numpy())


# ---------------------------------------------------------------------------------------------
# the calibrator
# ---------------------------------------------------------------------------------------------

@dataclass
class CalibrationResult:
    """Result of :meth:`PKMCalibrator.fit` (scipy.optimize style plus the identification report).

    ``x``: identified full parameter vector (8k,); ``machine``: the identified machine; ``success``,
    ``message``, ``nfev`` (Gauss-Newton iterations), ``residuals``: measured residual on the fit poses,
    shape (n, d) (mm; orientation rows times ``lever_mm``); ``frame_translation_mm`` (3,),
    ``frame_rotation`` (3, 3): instrument <- machine; ``std_error``: standard errors of the estimated
    parameters (same order as ``names``).
    """

    x: np.ndarray
    machine: PKM
    nominal: PKM
    success: bool
    message: str
    nfev: int
    residuals: np.ndarray
    names: list
    estimated: np.ndarray
    std_error: np.ndarray
    frame_translation_mm: np.ndarray
    frame_rotation: np.ndarray
    lam: float
    delta_mm: float
    delta_estimated: bool
    lambda_gcv: float
    lambda_lcurve: float
    singular_values: np.ndarray
    condition_number: float
    unidentifiable: list
    lever_mm: float
    n_poses: int
    fit_time_s: float
    right_singular_vectors: np.ndarray | None = None   # Vt of the scaled, registration-projected J
    param_scale: np.ndarray | None = None              # Tikhonov scaling of the estimated parameters
    history: list = field(default_factory=list)
    lcurve: dict = field(default_factory=dict)
    lambda_rule: str = "gcv"
    lambda_morozov: float = float("nan")               # Morozov's lambda at the final linearisation (NaN: no delta)
    discrepancy_reached: bool = True                   # False: LS residual above tau*delta*sqrt(m), lambda = 0
    condition_number_raw: float = float("nan")         # all estimated parameters, gauge directions included
    singular_values_raw: np.ndarray | None = None
    n_gauge: int = 0                                   # gauge directions fixed explicitly (6 with registration)
    iterations: int = 0                                # Gauss-Newton linearisations (nfev counts residual evaluations)
    lever_estimated: bool = False                      # lever_mm estimated from the data (variance components)
    leg_terms: object = None                           # accepted leg terms (legspace.LegTerms) or None

    def predict(self, q: np.ndarray, nominal: bool = False, frame=None):
        """Predicted measured poses (instrument frame) at drive commands ``q`` (n, k): (tip (n,3), R (n,3,3))."""
        m = self.nominal if nominal else self.machine
        t, R = (self.frame_translation_mm, self.frame_rotation) if frame is None else frame
        return predict_poses(m, (t, R), q, None if nominal else self.leg_terms, self.nominal)

    def pose_errors_um(self, data: PoseData, nominal: bool = False, frame=None) -> dict:
        """Measured residual (measurement minus model) on ``data``: position norm (um) and angle (urad), shape (n,)."""
        m = self.nominal if nominal else self.machine
        fr = (self.frame_translation_mm, self.frame_rotation) if frame is None else frame
        return pose_errors_um(m, fr, data, None if nominal else self.leg_terms, self.nominal)

    def parameter_table(self) -> dict:
        """Name -> {nominal, value, delta, std_error} of the estimated parameters."""
        r0 = parameter_vector(self.nominal)
        out = {}
        for j, name in zip(np.flatnonzero(self.estimated), self.names):
            out[name] = {"nominal": float(r0[j]), "value": float(self.x[j]), "delta": float(self.x[j] - r0[j]),
                         "std_error": float(self.std_error[len(out)])}
        return out


class PKMCalibrator:
    """Regularised identification of a PKM's parameters from measured poses.

    Settings (stored, validated): ``estimate_scales`` (identify the leg scales too),
    ``register`` (estimate the instrument frame; else it is taken as the machine frame),
    ``noise_um`` (measurement noise per component, the Morozov ``delta``; None = estimate it),
    ``lambda_rule`` (``"morozov"``, ``"gcv"`` or ``"lcurve"``: how each step's Tikhonov ``lambda`` is
    chosen), ``tau`` (discrepancy factor, >= 1), ``lever_mm`` (orientation residual weight,
    mm per rad; None = estimated from the data, see :meth:`fit`), ``joint_scale_mm`` (the Tikhonov
    scaling: every fit variable is a length change in mm, see :meth:`_layout`), bounds (joints and the leg
    length at mid-range in mm, ``scale_bound`` relative to the nominal scale), ``max_iter`` (Gauss-Newton
    iterations per phase), ``xtol_mm`` (convergence: the largest
    parameter / frame change, in mm-equivalents, of a full step), ``ftol`` (convergence: predicted
    relative decrease of the Tikhonov functional), ``rcond`` (identifiability threshold on the singular
    values), ``progress`` (callable taking a message, or None).
    """

    RULES = LAMBDA_RULES

    def __init__(self, machine: PKM, estimate_scales: bool = True, register: bool = True,
                 noise_um: float | None = None, tau: float = 1.0, lever_mm: float | None = None,
                 joint_scale_mm: float = 1.0, joint_bound_mm: float = 25.0,
                 offset_bound_mm: float = 200.0, scale_bound: float = 0.15, max_iter: int = 50,
                 xtol_mm: float = 1e-6, ftol: float = 1e-10, rcond: float = 1e-8, lambda_rule: str = "gcv", progress=None):
        if noise_um is not None and not noise_um > 0:
            raise ValueError(f"noise_um must be positive, got {noise_um}")
        if tau < 1:
            raise ValueError(f"tau must be >= 1, got {tau}")
        if (lever_mm is not None and not lever_mm > 0) or not joint_scale_mm > 0:
            raise ValueError("lever_mm (or None) and joint_scale_mm must be positive")
        if lambda_rule not in self.RULES:
            raise ValueError(f"lambda_rule must be one of {self.RULES}, got {lambda_rule!r}")
        if max_iter < 1 or not xtol_mm > 0 or not ftol > 0:
            raise ValueError("max_iter, xtol_mm and ftol must be positive")
        keep_settings(self, locals())

    # -- helpers ---------------------------------------------------------------------------
    def _layout(self):
        """Estimated mask (8k,), the map ``M`` (n_est, n_est) from the fit variables to parameter
        deviations, and the fit variables' bounds ``lo``, ``hi`` (n_est,).

        Fit variables (all mm-equivalents, divided by ``joint_scale_mm``): joint deviations; per leg the
        change of the leg length at the middle of its range ``c_i`` and, with scales, the change at the
        end of the range due to the scale ``u_i = ds_i * h_i`` (``h_i`` half the range in drive units).
        Then ``ds_i = u_i / h_i`` and ``do_i = c_i - q_mid,i * ds_i``. Offsets and scales in raw form are
        nearly collinear (drive commands of 8..20 revolutions from zero, or 600..1500 mm) and a scale's
        natural size depends on the drive unit (1 for mm, ~72 mm per revolution): both made a raw-scale
        fit ill-posed and its Tikhonov penalty and bounds meaningless (the root cause of "the fit gets
        worse with scales").
        """
        m0, k = self.machine, self.machine.n_legs
        est = np.ones(8 * k, bool)
        if not self.estimate_scales:
            est[7 * k:] = False
        q_lo, q_hi = m0.legs_to_drive(m0.leg_min_mm[None])[0], m0.legs_to_drive(m0.leg_max_mm[None])[0]
        q_mid, h = (q_lo + q_hi) / 2, np.abs(q_hi - q_lo) / 2
        n = 8 * k
        M = np.eye(n) * self.joint_scale_mm
        hi = np.r_[np.full(6 * k, self.joint_bound_mm), np.full(k, self.offset_bound_mm),
                   self.scale_bound * np.abs(m0.leg_scale) * h] / self.joint_scale_mm
        for i in range(k):
            o, sc = 6 * k + i, 7 * k + i
            M[sc, sc] = self.joint_scale_mm / h[i]
            M[o, sc] = -q_mid[i] * self.joint_scale_mm / h[i]
        M = M[np.ix_(est, est)]
        return est, M, -hi[est], hi[est]

    def gauge_basis(self, est: np.ndarray) -> np.ndarray:
        """Orthonormal basis (n_est, g) of the gauge directions in the scaled parameter space.

        With an estimated instrument frame, a rigid motion of the whole machine (hexapod: of the base
        joints, the platform following; tripod: of the base hinges and, rotations only, of the platform
        hinges about the tool point) is indistinguishable from a change of the frame: ``g = 6``
        directions that no data can fix. The gauge is fixed explicitly by keeping the parameter
        deviation orthogonal to them (the machine frame is defined by the nominal joints). Without
        registration ``g = 0``. Joint columns share one scale, so orthogonality in the scaled space is
        orthogonality in mm.
        """
        m0, k = self.machine, self.machine.n_legs
        if not self.register:
            return np.zeros((int(est.sum()), 0))
        G = np.zeros((8 * k, 6))
        b = m0.base_joints_mm
        G[:3 * k, :3] = np.tile(np.eye(3), (k, 1))
        for j, e in enumerate(np.eye(3)):
            G[:3 * k, 3 + j] = np.cross(e, b).ravel()
            if m0.kind == "tripod":  # no platform rotation in the model: the platform hinges turn with it
                G[3 * k:6 * k, 3 + j] = np.cross(e, m0.platform_joints_mm - m0.tool_in_platform_mm).ravel()
        return np.linalg.qr(G[est])[0]

    def _residual(self, m: PKM, data: PoseData, t_g, R_g, guess):
        """Residual (n, d) in mm (orientation rows times ``lever_mm``) and the forward kinematics; None if FK fails."""
        legs = m.drive_to_legs(data.q)
        if data.leg_correction_mm is not None:
            legs = legs + data.leg_correction_mm
        fk = forward_kinematics(m, legs, guess_tip_mm=guess[0], guess_platform2base=guess[1],
                                check_limits=False, raise_on_failure=False)
        if not fk.success.all():
            return None, None
        tip_meas = fk.x @ R_g.T + t_g
        res = [tip_meas - data.tip_mm]
        if data.rotation is not None and m.kind == "hexapod":
            R_pred = np.einsum("ij,njk->nik", R_g, fk.platform2base)
            rv = Rotation.from_matrix(np.einsum("nij,nkj->nik", R_pred, data.rotation)).as_rotvec()
            res.append(self.lever_mm * rv)
        return np.concatenate(res, 1), (fk.x, fk.platform2base)

    def _jacobians(self, m: PKM, data: PoseData, t_g, R_g, pose):
        """Parameter Jacobian (m_rows, 8k) and frame Jacobian (m_rows, 6) of the residual at ``pose``."""
        n = len(data)
        full = data.rotation is not None and m.kind == "hexapod"
        J = pose_jacobian(m, data.q, pose[0], pose[1])  # (n, 6|3, 8k) in the machine frame
        Jp = np.einsum("ij,njk->nik", R_g, J[:, :3])
        Jg_p = np.concatenate([np.broadcast_to(np.eye(3), (n, 3, 3)), -skew(pose[0] @ R_g.T)], 2)
        blocks, gblocks = [Jp], [Jg_p]
        if full:
            blocks.append(self.lever_mm * np.einsum("ij,njk->nik", R_g, J[:, 3:]))
            gblocks.append(self.lever_mm * np.concatenate([np.zeros((n, 3, 3)),
                                                           np.broadcast_to(np.eye(3), (n, 3, 3))], 2))
        d = 6 if full else 3
        return np.concatenate(blocks, 1).reshape(n * d, -1), np.concatenate(gblocks, 1).reshape(n * d, 6)

    DEGENERATE_RCOND = 1e-6   # a combination below 1e-6 s_max counts as not determined by the poses

    def _check_identifiable(self, data: PoseData, est, M, P, full: bool) -> None:
        """Refuse a degenerate pose set: fewer parameter combinations determined (singular values of the
        scaled, frame-projected Jacobian at the nominal machine above ``DEGENERATE_RCOND * s_max``) than a
        well-spread reference set of 60 workspace poses determines (e.g. one orientation, poses on a line)."""
        m0 = self.machine

        def rank(q, tips, R, rot):
            d = PoseData(q, tips, R if rot else None, data.source)
            Jr, Jg = self._jacobians(m0, d, np.zeros(3), np.eye(3), (tips, R))
            A = (Jr[:, est] @ M) @ P
            if self.register:
                Qg = np.linalg.qr(Jg)[0]
                A = A - Qg @ (Qg.T @ A)
            sv = np.linalg.svd(A, compute_uv=False)
            return int(np.sum(sv >= self.DEGENERATE_RCOND * sv.max()))

        fk = forward_kinematics(m0, m0.drive_to_legs(data.q), check_limits=False, raise_on_failure=False)
        if not fk.success.all():
            return          # the fit reports the failing rows
        tips, R = workspace_poses(m0, 60, np.random.default_rng(12345))
        q_ref = m0.legs_to_drive(inverse_kinematics(m0, tips, R))
        r_ref = rank(q_ref, tips, R, full)
        r_data = rank(data.q, fk.x, fk.platform2base, full)
        if r_data < r_ref:
            raise InputError(f"{data.source}: degenerate pose set: the {len(data)} poses determine only {r_data} of the "
                             f"{r_ref} parameter combinations a spread set determines (e.g. one orientation, poses "
                             "on a line); measure poses spread in position and orientation")

    @staticmethod
    def _tikhonov(s, beta, b_out2, lam):
        f = s / (s ** 2 + lam)
        resid2 = np.sum((lam / (s ** 2 + lam) * beta) ** 2) + b_out2
        return f * beta, resid2

    @staticmethod
    def lcurve_corner(s, beta, b_out2, n_grid: int = 241):
        """L-curve corner: maximum curvature of ``(log |J w - b|, log |w|)`` against ``log lambda``.

        The grid spans ``[s_min^2 / 100, s_max^2 * 100]`` (outside it the filter factors are 0 or 1 and
        the curve does not move), and only points where both norms still change (relative slope above
        1e-6 per unit of ``log lambda``) compete: on the flat ends the curvature is rounding noise, which
        is what made an unrestricted grid return a degenerate ``lambda`` ~ 1e-10.
        Returns ``(lambda, curve)`` with ``curve`` holding the grid, both norms and the curvature.
        """
        s2 = s ** 2
        grid = np.logspace(np.log10(s2.min()) - 2, np.log10(s2.max()) + 2, n_grid)
        L = grid[:, None]
        res2 = np.sum((L / (s2[None] + L) * beta[None]) ** 2, axis=1) + b_out2
        wn2 = np.sum((s[None] / (s2[None] + L) * beta[None]) ** 2, axis=1)
        xr, yr = 0.5 * np.log(np.maximum(res2, 1e-300)), 0.5 * np.log(np.maximum(wn2, 1e-300))
        t = np.log(grid)
        dx, dy = np.gradient(xr, t), np.gradient(yr, t)
        ddx, ddy = np.gradient(dx, t), np.gradient(dy, t)
        kappa = (dx * ddy - dy * ddx) / np.maximum(dx ** 2 + dy ** 2, 1e-300) ** 1.5
        moving = (dx > 1e-6) & (-dy > 1e-6)
        kappa_m = np.where(moving, kappa, -np.inf)
        lam = float(grid[np.argmax(kappa_m)]) if moving.any() else float("nan")
        return lam, {"lambda": grid, "residual_norm": np.sqrt(res2), "solution_norm": np.sqrt(wn2),
                     "curvature": kappa}

    def _choose_lambda(self, rule, s, beta, b_out2, m_rows, n_free, delta_mm):
        """The step's ``lambda`` by ``rule``, plus the GCV, L-curve and Morozov lambdas for the report.

        Returns ``(lam, lam_gcv, lam_lcurve, lam_morozov, discrepancy_reached, curve)``; Morozov needs
        ``delta_mm`` (else NaN). When even the unregularised fit (on the identifiable subspace) stays
        above ``tau * delta * sqrt(m)`` the discrepancy cannot be reached and Morozov gives ``lambda = 0``.
        """
        smax = s.max()
        s2 = s ** 2
        grid = smax ** 2 * np.logspace(-16, 2, 181)
        L = grid[:, None]
        res2 = np.sum((L / (s2[None] + L) * beta[None]) ** 2, axis=1) + b_out2
        trH = np.sum(s2[None] / (s2[None] + L), axis=1) + n_free
        gcv = m_rows * res2 / np.maximum(m_rows - trH, 1e-9) ** 2
        lam_gcv = float(grid[np.argmin(gcv)])
        lam_lc, curve = self.lcurve_corner(s, beta, b_out2)
        curve["gcv_lambda"], curve["gcv"] = grid, gcv
        lam_mz, reached = float("nan"), True
        if delta_mm is not None:
            target2 = (self.tau * delta_mm) ** 2 * m_rows
            lo_l, hi_l = smax ** 2 * 1e-20, smax ** 2 * 1e6
            f = lambda ll: self._tikhonov(s, beta, b_out2, np.exp(ll))[1] - target2
            if f(np.log(lo_l)) >= 0:      # even the unregularised fit is above the noise level
                lam_mz, reached = 0.0, False
            elif f(np.log(hi_l)) <= 0:    # everything explained by the noise: full regularisation
                lam_mz = hi_l
            else:
                lam_mz = float(np.exp(brentq(f, np.log(lo_l), np.log(hi_l), xtol=1e-10)))
        lam = {"morozov": lam_mz, "gcv": lam_gcv, "lcurve": lam_lc}[rule]
        if not np.isfinite(lam):          # no L-curve corner (flat curve): fall back to GCV
            lam = lam_gcv
        return lam, lam_gcv, lam_lc, lam_mz, reached, curve

    # -- the fit ---------------------------------------------------------------------------
    def fit(self, data: PoseData) -> CalibrationResult:
        """Identify the parameters (and the instrument frame) from ``data``; see the module docstring.

        With ``lever_mm`` None and measured orientations, the orientation weight is estimated from the
        data (variance components): fit with 500 mm per rad, set ``lever = sigma_position / sigma_rotation``
        of the fit's residuals (clipped to 10..5000 mm), refit until it changes by less than 20 %
        (at most 3 fits). A fixed lever that assumes a 10x better orientation than the instrument gives
        (motion capture) lets orientation noise dominate the fit.
        """
        import copy
        # BLAS on one thread: the matrices here are small (<= ~2000 x 48), and a multi-threaded
        # OpenBLAS on a loaded machine spends seconds per SVD spinning (measured: 1.7 s vs 2 ms)
        with limit_threads(1, libraries=("blas",)):
            if self.lever_mm is not None:
                return self._fit(data)
            if data.rotation is None or self.machine.kind != "hexapod":
                c = copy.copy(self)
                c.lever_mm = 500.0                  # no orientation rows: only scales the frame's step test
                return c._fit(data)
            lever, res = 500.0, None
            for _ in range(3):
                c = copy.copy(self)
                c.lever_mm = lever
                res = c._fit(data)
                sp = np.sqrt(np.mean(res.residuals[:, :3] ** 2))
                sr = np.sqrt(np.mean((res.residuals[:, 3:] / lever) ** 2))
                new = float(np.clip(sp / max(sr, 1e-300), 10.0, 5000.0))
                if abs(np.log(new / lever)) < np.log(1.2):
                    break
                lever = new
            res.lever_estimated = True
            return res

    def _checked_layout(self, data: PoseData):
        """Check ``data`` against the machine and the unknowns; ``(est, M, lo, hi, full, m_rows, legs)``."""
        m0 = self.machine
        k = m0.n_legs
        if data.q.ndim != 2 or data.q.shape[1] != k:
            raise ValueError(f"{data.source}: expected drive commands of shape (n, {k}), got {data.q.shape}")
        if data.tip_mm.shape != (len(data), 3) or not np.all(np.isfinite(data.tip_mm)) or not np.all(np.isfinite(data.q)):
            raise ValueError(f"{data.source}: expected finite tips of shape ({len(data)}, 3)")
        est, M, lo, hi = self._layout()
        full = data.rotation is not None and m0.kind == "hexapod"
        d = 6 if full else 3
        m_rows = d * len(data)
        check_pose_set(data.source, m0, data.q, int(est.sum()) + (6 if self.register else 0), d, data.rows)
        if m_rows < est.sum() + (6 if self.register else 0):
            raise ValueError(f"{data.source}: {len(data)} poses give {m_rows} equations for "
                             f"{est.sum() + 6 * self.register} unknowns; measure more poses")
        legs = m0.drive_to_legs(data.q)
        bad = np.flatnonzero(np.any((legs < m0.leg_min_mm) | (legs > m0.leg_max_mm), axis=1))
        if bad.size:
            rows = bad if data.rows is None else data.rows[bad]
            raise InputError(f"{data.source}: rows {rows[:20].tolist()}: leg commands outside the leg range")
        return est, M, lo, hi, full, m_rows, legs

    def _gn_step(self, ph: str, Jr_full, Jg, est, M, P, y, res, lo, hi, m_rows: int, n_free: int,
                 delta_mm) -> "_GNStep":
        """One regularised Gauss–Newton step of phase ``ph`` from the linearisation (Jr_full, Jg) at ``y``."""
        Jy = (Jr_full[:, est] @ M) @ P                      # scaled, gauge-fixed parameter columns
        r_vec = res.ravel()
        b = Jy @ y - r_vec                                  # target of the new deviation (Tikhonov on y)
        Qg = None
        if self.register:
            Qg = np.linalg.qr(Jg)[0]
            A = Jy - Qg @ (Qg.T @ Jy)
            bp = b - Qg @ (Qg.T @ b)
        else:
            A, bp = Jy, b
        U, s_all, Vt_all = svd(A, full_matrices=False)
        rank = int(np.sum(s_all >= self.rcond * s_all.max()))
        s, Vt = s_all[:rank], Vt_all[:rank]
        beta = U[:, :rank].T @ bp
        b_out2 = max(float(bp @ bp - beta @ beta), 0.0)
        lam, lam_gcv, lam_lc, lam_mz, reached, curve = self._choose_lambda(
            ph, s, beta, b_out2, m_rows, n_free, None if ph == "gcv" else delta_mm)
        z, _ = self._tikhonov(s, beta, b_out2, lam)
        y_new = Vt.T @ z
        w_clip = np.clip(P @ y_new, lo, hi)                 # physical bounds (a safety net)
        y_new = P.T @ w_clip
        dg = np.linalg.lstsq(Jg, b - Jy @ y_new, rcond=None)[0] if self.register else np.zeros(6)
        dy = y_new - y
        # predicted (linear-model) decrease of the Tikhonov functional |res|^2 + lam |y|^2
        phi0 = float(r_vec @ r_vec + lam * y @ y)
        lin = r_vec + Jy @ dy + Jg @ dg
        pred = phi0 - float(lin @ lin + lam * y_new @ y_new)
        full_step_mm = max(np.abs(dy).max(initial=0.0), np.abs(dg[:3]).max(),
                           self.lever_mm * np.abs(dg[3:]).max())
        # converged: the full step is below xtol, or the linear model promises no relative decrease
        # above ftol (the forward kinematics is solved to 1e-9 mm, so the functional itself is only
        # known to ~1e-7 relative and a line search cannot resolve smaller decreases)
        done = full_step_mm <= self.xtol_mm or pred <= self.ftol * phi0
        return _GNStep(Qg=Qg, s=s, Vt=Vt, beta=beta, b_out2=b_out2, lam=lam, lam_gcv=lam_gcv, lam_lc=lam_lc,
                       lam_mz=lam_mz, reached=reached, curve=curve, dy=dy, dg=dg, phi0=phi0, pred=pred,
                       full_step_mm=full_step_mm, done=done)

    def _line_search(self, machine_at, data: PoseData, y, t_g, R_g, pose, st: "_GNStep"):
        """Backtracking (Armijo on the Tikhonov functional of the step's lambda): ``(accepted, alpha,
        (y, t, R, res, pose) at the accepted point, function evaluations)``."""
        alpha, nfev = 1.0, 0
        while alpha >= 1.0 / 1024:
            ya = y + alpha * st.dy
            ta = t_g + alpha * st.dg[:3]
            Ra = Rotation.from_rotvec(alpha * st.dg[3:]).as_matrix() @ R_g
            ra, pa = self._residual(machine_at(ya), data, ta, Ra, pose)
            nfev += 1
            if ra is not None:
                phia = float(np.sum(ra ** 2) + st.lam * ya @ ya)
                if phia <= st.phi0 - 2e-4 * alpha * max(st.pred, 0.0):
                    return True, alpha, (ya, ta, Ra, ra, pa), nfev
            if st.done:  # the converged step is only taken when it does not increase the functional
                break
            alpha *= 0.5
        return False, alpha, None, nfev

    def _stop(self, ph: str, it: int, st: "_GNStep", accepted: bool):
        """``(success, message)`` when phase ``ph`` ends after iteration ``it``, else None."""
        if st.done:
            return True, f"{ph}: converged after {it + 1} Gauss-Newton iterations"
        if not accepted and (st.full_step_mm <= 100 * self.xtol_mm or st.pred <= 100 * self.ftol * st.phi0):
            # the line search cannot resolve a step this small (FK solved to 1e-9 mm): converged
            return True, (f"{ph}: converged after {it + 1} Gauss-Newton iterations (the last "
                          f"step, {st.full_step_mm:.2g} mm, at the rounding floor)")
        if not accepted:
            return False, (f"{ph}: line search failed at iteration {it + 1} (step {st.full_step_mm:.3g} mm, "
                           f"predicted relative decrease {st.pred / max(st.phi0, 1e-300):.3g})")
        return None

    def _fit(self, data: PoseData) -> CalibrationResult:
        t0 = time.perf_counter()
        m0 = self.machine
        est, M, lo, hi, full, m_rows, legs = self._checked_layout(data)
        r0 = parameter_vector(m0)
        G = self.gauge_basis(est)                                   # (n_est, g)
        P = np.linalg.qr(np.c_[G, np.eye(est.sum())])[0][:, G.shape[1]:est.sum()] if G.size else np.eye(est.sum())
        n_free = 6 if self.register else 0
        self._check_identifiable(data, est, M, P, full)
        # robust initial registration from the nominal model
        fk0 = forward_kinematics(m0, legs if data.leg_correction_mm is None else legs + data.leg_correction_mm,
                                 check_limits=False)
        if self.register:
            t_g, R_g, inliers = robust_registration(fk0.x, data.tip_mm)
        else:
            t_g, R_g, inliers = np.zeros(3), np.eye(3), np.ones(len(data), bool)
        frame0 = (t_g.copy(), R_g.copy())
        y = np.zeros(P.shape[1])                                    # deviation from nominal, gauge-fixed
        machine_at = lambda yy: machine_from_vector(m0, _with(r0, est, M @ (P @ yy)))
        res, pose = self._residual(m0, data, t_g, R_g, (fk0.x, fk0.platform2base))
        if res is None:
            raise KinematicsError(f"{data.source}: forward kinematics of the nominal machine failed")
        delta_mm = None if self.noise_um is None else self.noise_um * 1e-3
        estimated_delta = delta_mm is None
        phases = ["gcv", self.lambda_rule] if (estimated_delta and self.lambda_rule == "morozov") else [self.lambda_rule]
        history, nfev, n_jac = [], 1, 0
        success, msg = False, ""
        for ph in phases:
            success, msg = False, f"{ph}: stopped after {self.max_iter} iterations without convergence"
            for it in range(self.max_iter):
                Jr_full, Jg = self._jacobians(machine_at(y), data, t_g, R_g, pose)
                n_jac += 1
                st = self._gn_step(ph, Jr_full, Jg, est, M, P, y, res, lo, hi, m_rows, n_free, delta_mm)
                accepted, alpha, trial, k = self._line_search(machine_at, data, y, t_g, R_g, pose, st)
                nfev += k
                rms = float(np.sqrt(np.mean(res ** 2)))
                history.append({"phase": ph, "iteration": it, "rms_mm": rms, "lambda": float(st.lam),
                                "alpha": alpha if accepted else 0.0, "step_mm": float(st.full_step_mm),
                                "predicted_decrease": st.pred / max(st.phi0, 1e-300),
                                "discrepancy_reached": bool(st.reached)})
                if self.progress is not None:
                    self.progress(f"{ph} iteration {it}: rms {rms * 1e3:.3f} um, lambda {st.lam:.3g}, "
                                  f"step {st.full_step_mm:.3g} mm x {alpha if accepted else 0.0:g}")
                if accepted:
                    y, t_g, R_g, res, pose = trial
                stop = self._stop(ph, it, st, accepted)
                if stop is not None:
                    success, msg = stop
                    break
            if estimated_delta and (ph == "gcv" or delta_mm is None):
                # estimate delta from the GCV fit of the last linearisation: RSS / (m - trace H)
                trH = np.sum(st.s ** 2 / (st.s ** 2 + st.lam_gcv)) + n_free
                rss = self._tikhonov(st.s, st.beta, st.b_out2, st.lam_gcv)[1]
                delta_mm = float(np.sqrt(rss / max(m_rows - trH, 1.0)))
        if not st.reached and self.lambda_rule == "morozov":
            msg += ("; the discrepancy tau*delta*sqrt(m) is below the least-squares residual: "
                    "lambda = 0 on the identifiable subspace")
        r = _with(r0, est, M @ (P @ y))
        return CalibrationResult(
            x=r, machine=machine_from_vector(m0, r), nominal=m0, success=success, message=msg, nfev=nfev,
            residuals=res, estimated=est, frame_translation_mm=t_g, frame_rotation=R_g, lam=float(st.lam),
            delta_mm=float(delta_mm), delta_estimated=estimated_delta, lambda_gcv=float(st.lam_gcv),
            lambda_lcurve=float(st.lam_lc), lever_mm=self.lever_mm, n_poses=len(data),
            fit_time_s=time.perf_counter() - t0, history=history, param_scale=M,
            lcurve={**st.curve, "initial_frame": frame0}, lambda_rule=self.lambda_rule,
            lambda_morozov=float(st.lam_mz), discrepancy_reached=bool(st.reached), n_gauge=int(G.shape[1]),
            iterations=n_jac, **self._uncertainty(Jr_full, est, M, P, G, st, delta_mm))

    def _uncertainty(self, Jr_full, est, M, P, G, st: "_GNStep", delta_mm: float) -> dict:
        """The report's conditioning and uncertainty at the last linearisation: singular values on the
        identifiable subspace (gauge fixed, structural nulls removed) and of the raw frame-projected
        Jacobian over all estimated parameters (gauge directions included), the unidentifiable
        combinations, standard errors."""
        s, Vt, lam = st.s, st.Vt, st.lam
        cond = float(s.max() / s.min())
        Ar = Jr_full[:, est] @ M
        if self.register:
            Ar = Ar - st.Qg @ (st.Qg.T @ Ar)
        _, s_raw, Vt_raw = svd(Ar, full_matrices=False)
        cond_raw = float(s_raw.max() / s_raw.min()) if s_raw.min() > 0 else float("inf")
        names_all = parameter_names(self.machine, scales=True)
        names = [n for n, e in zip(names_all, est) if e]
        unident = []
        for j in np.flatnonzero(s_raw < self.rcond * s_raw.max()):
            v = Vt_raw[j]
            top = np.argsort(-np.abs(v))[:6]
            in_gauge = bool(G.size) and float(np.linalg.norm(G.T @ v)) > 0.5
            unident.append({"singular_value": float(s_raw[j]),
                            "fixed_by": "gauge (orthogonal to the machine's rigid motion)" if in_gauge
                            else "minimum norm (no component along it)",
                            "combination": {names[i]: round(float(v[i]), 4) for i in top if abs(v[i]) > 0.05}})
        filt = s / (s ** 2 + lam)
        Vw = Vt @ P.T                                               # (rank, n_est) right singular vectors in w
        cov_w = (delta_mm ** 2) * (Vw.T * filt ** 2 * s ** 2) @ Vw
        se = np.sqrt(np.maximum(np.diag(M @ cov_w @ M.T), 0))
        return {"names": names, "std_error": se, "singular_values": s, "condition_number": cond,
                "unidentifiable": unident, "right_singular_vectors": Vw, "condition_number_raw": cond_raw,
                "singular_values_raw": s_raw}


@dataclass
class _GNStep:
    """One linearised step of :meth:`PKMCalibrator._fit` (what the line search, the stopping
    rule, the noise estimate and the report read of it)."""

    Qg: np.ndarray | None
    s: np.ndarray
    Vt: np.ndarray
    beta: np.ndarray
    b_out2: float
    lam: float
    lam_gcv: float
    lam_lc: float
    lam_mz: float
    reached: bool
    curve: dict
    dy: np.ndarray
    dg: np.ndarray
    phi0: float
    pred: float
    full_step_mm: float
    done: bool


def _with(r0: np.ndarray, est: np.ndarray, delta: np.ndarray) -> np.ndarray:
    r = r0.copy()
    r[est] += delta
    return r
