"""Leg-space tools for PKM calibration: measured leg lengths, the plain baseline fit, and the loop on
leg residuals.

Leg residual (mm, (n, k)): the leg lengths a measured pose implies by inverse kinematics (through the
registration) minus the model's ``s q + o`` (plus accepted leg terms). :func:`plain_leg_fit`: unregularised
least squares over the raw parameters and the instrument frame. :func:`leg_residual_loop`: per-leg
``nonlinearity`` and ``direction`` terms of the drive commands, accepted one at a time by K-fold CV and a
Bonferroni F-test. Rules and ``calibration.json`` keys: ``docs/explanation/parallel-kinematics.md``."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from .hexapod import forward_kinematics
from .machine_file import PKM
from .pose_model import machine_from_vector, parameter_vector, pose_errors_um, robust_registration

LOOP_ALPHA = 0.01           # family-wise significance level of the loop (Bonferroni over candidates)
LOOP_MIN_CV_GAIN = 0.05     # a term must cut the cross-validated leg RSS of its leg by >= 5 %
LOOP_FOLDS = 5
LOOP_MAX_TERMS = 12


# ---------------------------------------------------------------------------------------------
# leg lengths from measured poses
# ---------------------------------------------------------------------------------------------

def measured_legs_mm(machine: PKM, tip_mm: np.ndarray, rotation: np.ndarray | None, t_g, R_g) -> np.ndarray:
    """Leg lengths (n, k) implied by measured poses (instrument frame) for ``machine``'s joints.

    ``tip_mm`` (n, 3), ``rotation`` (n, 3, 3) ``platform2instrument`` (None for the tripod, whose
    platform keeps the base orientation); ``t_g`` (3,), ``R_g`` (3, 3): instrument <- machine.
    """
    tip_m = (np.asarray(tip_mm, float) - t_g) @ R_g
    if rotation is None:
        if machine.kind == "hexapod":
            raise ValueError("leg lengths of a hexapod need measured orientations")
        R_m = np.broadcast_to(np.eye(3), (len(tip_m), 3, 3))
    else:
        R_m = np.einsum("ji,njk->nik", R_g, rotation)
    a = machine.platform_joints_mm - machine.tool_in_platform_mm
    v = tip_m[:, None, :] + np.einsum("nij,kj->nki", R_m, a) - machine.base_joints_mm[None]
    return np.linalg.norm(v, axis=-1)


def normalised_command(machine: PKM, q: np.ndarray) -> np.ndarray:
    """Drive commands (n, k) mapped to [-1, 1] over each leg's nominal range (``min_mm``..``max_mm``)."""
    lo = machine.legs_to_drive(machine.leg_min_mm[None])[0]
    hi = machine.legs_to_drive(machine.leg_max_mm[None])[0]
    return (2 * np.asarray(q, float) - (lo + hi)) / (hi - lo)


# ---------------------------------------------------------------------------------------------
# leg terms (the loop's candidates and accepted terms)
# ---------------------------------------------------------------------------------------------

FAMILIES = {"nonlinearity": ("u^2 - 1/3", "u^3"),
            "direction": ("nx^2", "ny^2", "nx*ny", "nx*nz", "ny*nz"),
            "scale": ("u",)}                 # only searched when the scales are not fitted (--no-scales)


def leg_features(nominal: PKM, q: np.ndarray, family: str, directions: np.ndarray | None = None) -> np.ndarray:
    """Candidate columns of ``family`` at drive commands ``q`` (n, k): shape (n, k, c).

    ``nonlinearity``: ``u^2 - 1/3, u^3`` of the normalised command; ``direction``: second-order terms of
    each leg's unit direction in the base frame at the nominal forward kinematics of the commands
    (``directions`` (n, k, 3) may be passed to avoid recomputing them).
    """
    if family == "nonlinearity":
        u = normalised_command(nominal, q)
        return np.stack([u ** 2 - 1 / 3, u ** 3], -1)
    if family == "scale":
        return normalised_command(nominal, q)[..., None]
    if family == "direction":
        n = leg_directions(nominal, q) if directions is None else directions
        x, y, z = n[..., 0], n[..., 1], n[..., 2]
        return np.stack([x * x, y * y, x * y, x * z, y * z], -1)
    raise ValueError(f"unknown leg-term family {family!r}; expected one of {sorted(FAMILIES)}")


def leg_directions(nominal: PKM, q: np.ndarray, with_rotation: bool = False):
    """Unit leg directions (n, k, 3), base frame, at the nominal forward kinematics of commands ``q``
    (and the platform rotations (n, 3, 3) when ``with_rotation``)."""
    fk = forward_kinematics(nominal, nominal.drive_to_legs(q), check_limits=False)
    a = nominal.platform_joints_mm - nominal.tool_in_platform_mm
    v = fk.x[:, None, :] + np.einsum("nij,kj->nki", fk.platform2base, a) - nominal.base_joints_mm[None]
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return (n, fk.platform2base) if with_rotation else n


def rigid_leg_columns(nominal: PKM, q: np.ndarray, directions=None, rotations=None, scales: bool = True) -> np.ndarray:
    """Per leg, the rigid model's own leg-space columns (n, k, 8): constant (zero length), command
    (scale; left out with ``scales=False``), ``-n`` (base joint), ``R^T n`` (platform joint). A candidate term counts only for what it
    explains beyond these (else a direction term would re-fit joint errors)."""
    if directions is None or rotations is None:
        directions, rotations = leg_directions(nominal, q, with_rotation=True)
    n = directions
    rtn = np.einsum("nji,nkj->nki", rotations, n)
    ones = np.ones(q.shape + (1,))
    cols = [ones, np.asarray(q, float)[..., None]] if scales else [ones]
    return np.concatenate(cols + [-n, rtn], -1)


@dataclass
class LegTerms:
    """Accepted leg terms: a list of ``(family, leg index, coefficients (c,))``; leg length correction
    ``sum_c coef_c * feature_c`` (mm) added to ``s q + o`` of that leg."""

    terms: list = field(default_factory=list)

    def __bool__(self):
        return bool(self.terms)

    def correction_mm(self, nominal: PKM, q: np.ndarray) -> np.ndarray:
        """Leg-length correction (n, k) in mm at drive commands ``q`` (n, k)."""
        q = np.atleast_2d(np.asarray(q, float))
        out = np.zeros_like(q)
        feats = {}
        for fam, leg, coef in self.terms:
            if fam not in feats:
                feats[fam] = leg_features(nominal, q, fam)
            out[:, leg] += feats[fam][:, leg] @ np.asarray(coef, float)
        return out

    @classmethod
    def from_list(cls, items, k: int, source="") -> "LegTerms":
        """Inverse of :meth:`to_list` (the calibration's ``leg_terms``); errors name ``source``."""
        terms = []
        for i, t in enumerate(items or []):
            try:
                fam, leg, coef = t["family"], int(t["leg"]) - 1, np.asarray(t["coefficients_mm"], float)
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"{source}: key 'leg_terms[{i}]': {exc}") from None
            if fam not in FAMILIES or not 0 <= leg < k or coef.shape != (len(FAMILIES[fam]),):
                raise ValueError(f"{source}: key 'leg_terms[{i}]': expected a family of {sorted(FAMILIES)}, leg 1..{k} "
                                 f"and {len(FAMILIES.get(fam, ()))} coefficients, got {t}")
            terms.append((fam, leg, coef))
        return cls(terms)

    def drive_for_legs(self, machine: PKM, nominal: PKM, legs_mm: np.ndarray, n_iter: int = 8) -> np.ndarray:
        """Drive commands (n, k) that give leg lengths ``legs_mm`` (n, k) with ``machine``'s scale/offset plus
        these terms: fixed point ``q = (l - o - g(q)) / s`` (the terms are slow: converges in a few steps)."""
        q = machine.legs_to_drive(legs_mm)
        for _ in range(n_iter):
            q = machine.legs_to_drive(legs_mm - self.correction_mm(nominal, q))
        return q

    def to_list(self) -> list:
        return [{"family": fam, "leg": int(leg) + 1, "columns": list(FAMILIES[fam]),
                 "coefficients_mm": [float(c) for c in coef]} for fam, leg, coef in self.terms]


def _cv_rss(F: np.ndarray, e: np.ndarray, folds: np.ndarray) -> float:
    """K-fold cross-validated RSS of the least-squares fit ``e ~ F`` (F (n, c), e (n,))."""
    rss = 0.0
    for f in np.unique(folds):
        tr, te = folds != f, folds == f
        c = np.linalg.lstsq(F[tr], e[tr], rcond=None)[0]
        rss += float(np.sum((e[te] - F[te] @ c) ** 2))
    return rss


def scan_terms(nominal: PKM, q: np.ndarray, leg_res_mm: np.ndarray, seed=0,
               families=("nonlinearity", "direction"), directions=None, rigid=None) -> list[dict]:
    """Test every candidate (family x leg) on the leg residuals (n, k) of the fit poses.

    Each candidate's columns are fitted by least squares together with the leg's rigid columns
    (:func:`rigid_leg_columns`; ``rigid`` (n, k, 8) may be passed), against the rigid columns alone; reported: RSS before/after, 5-fold cross-validated RSS before (constant only) and after,
    the F statistic and its p-value, and whether it passes (p < ``LOOP_ALPHA`` / number of candidates and a
    cross-validated gain >= ``LOOP_MIN_CV_GAIN``).
    """
    from scipy.stats import f as f_dist  # scipy.stats (~0.5 s to import) loads for the F test, not with the module
    n, k = leg_res_mm.shape
    folds = np.random.default_rng(seed).permutation(n) % LOOP_FOLDS
    if rigid is None:
        rigid = rigid_leg_columns(nominal, q)
    rows = []
    n_cand = len(families) * k
    for fam in families:
        X = leg_features(nominal, q, fam, directions if fam == "direction" else None)
        for leg in range(k):
            e = leg_res_mm[:, leg]
            F0 = rigid[:, leg]
            F = np.c_[F0, X[:, leg]]
            c = X.shape[-1]
            rss0 = float(np.sum((e - F0 @ np.linalg.lstsq(F0, e, rcond=None)[0]) ** 2))
            coef = np.linalg.lstsq(F, e, rcond=None)[0]
            rss1 = float(np.sum((e - F @ coef) ** 2))
            dof = n - np.linalg.matrix_rank(F)
            fstat = ((rss0 - rss1) / c) / max(rss1 / max(dof, 1), 1e-300)
            p = float(f_dist.sf(fstat, c, max(dof, 1)))
            cv0, cv1 = _cv_rss(F0, e, folds), _cv_rss(F, e, folds)
            gain = 1 - cv1 / max(cv0, 1e-300)
            rows.append({"family": fam, "leg": leg, "rss_before_mm2": rss0, "rss_after_mm2": rss1,
                         "cv_rss_before_mm2": cv0, "cv_rss_after_mm2": cv1, "cv_gain": gain,
                         "F": float(fstat), "p_value": p, "coefficients": coef[F0.shape[1]:],
                         "passes": bool(p < LOOP_ALPHA / n_cand and gain >= LOOP_MIN_CV_GAIN)})
    return rows


def leg_residual_loop(nominal: PKM, q: np.ndarray, leg_res_fn, seed=0, max_terms: int = LOOP_MAX_TERMS,
                      scales_fitted: bool = True):
    """Greedy search for leg terms on the leg residuals.

    ``leg_res_fn(terms)`` returns the leg residuals (n, k) of the fit poses for the model with ``terms``
    (a :class:`LegTerms`; the caller refits the rigid parameters with them). Each round scans all
    candidates not yet accepted (:func:`scan_terms`; the ``scale`` family only when ``scales_fitted`` is
    False, i.e. a scale error the user chose not to fit shows up as a term), accepts the one with the largest cross-validated
    gain among those that pass, and refits. Returns ``(LegTerms, rounds)`` with ``rounds`` the scans
    (a list of lists of rows, for the report).
    """
    terms = LegTerms()
    rounds = []
    directions, rotations = leg_directions(nominal, q, with_rotation=True)
    rigid = rigid_leg_columns(nominal, q, directions, rotations, scales=scales_fitted)
    families = tuple(f for f in FAMILIES if f != "scale" or not scales_fitted)
    while len(terms.terms) < max_terms:
        res = leg_res_fn(terms)
        have = {(fam, leg) for fam, leg, _ in terms.terms}
        rows = [r for r in scan_terms(nominal, q, res, seed, families, directions=directions, rigid=rigid)
                if (r["family"], r["leg"]) not in have]
        rounds.append(rows)
        ok = [r for r in rows if r["passes"]]
        if not ok:
            break
        best = max(ok, key=lambda r: r["cv_gain"])
        terms.terms.append((best["family"], best["leg"], np.asarray(best["coefficients"], float)))
        # re-estimate all accepted coefficients on the residual of the rigid model alone (joint fit by
        # alternation: the rigid refit inside leg_res_fn sees the current terms)
        terms = _refit_coefficients(nominal, q, leg_res_fn, terms, directions, rigid)
    return terms, rounds


def _refit_coefficients(nominal, q, leg_res_fn, terms: LegTerms, directions, rigid, n_alt: int = 2) -> LegTerms:
    """Alternate: rigid refit with the terms fixed, then all term coefficients by least squares on
    the leg residual with the terms' contribution added back."""
    for _ in range(n_alt):
        res = leg_res_fn(terms) + terms.correction_mm(nominal, q)
        by_leg = {}
        for fam, leg, _ in terms.terms:
            by_leg.setdefault(leg, []).append(fam)
        coefs = {}
        for leg, fams in by_leg.items():
            F = np.concatenate([rigid[:, leg]] + [
                leg_features(nominal, q, fam, directions if fam == "direction" else None)[:, leg] for fam in fams], 1)
            c = np.linalg.lstsq(F, res[:, leg], rcond=None)[0][rigid.shape[-1]:]
            i = 0
            for fam in fams:
                w = len(FAMILIES[fam])
                coefs[(fam, leg)] = c[i:i + w]
                i += w
        new = [(fam, leg, coefs[(fam, leg)]) for fam, leg, _ in terms.terms]
        terms = LegTerms(new)
    return terms


def fit_leg_terms(calibrator, fit, rigid):
    """The loop on leg residuals around a calibrator: ``(LegTerms, rounds, result)``.

    ``calibrator``: a :class:`~errormap.pkm.calibration.PKMCalibrator` (best with ``lever_mm`` fixed at
    the rigid fit's); ``fit``: the fit :class:`PoseData` (full poses); ``rigid``: its rigid-model result.
    Each candidate set of terms is evaluated by refitting the rigid parameters with the terms' leg
    corrections fixed; ``result`` is the final refit (``leg_terms`` set) or ``rigid`` when none is accepted.
    """
    from dataclasses import replace
    machine = calibrator.machine
    state = {"res": rigid}

    def leg_res(terms):
        data = fit if not terms else replace(fit, leg_correction_mm=terms.correction_mm(machine, fit.q))
        r = calibrator.fit(data) if terms else rigid
        if terms:
            r.leg_terms = terms
        state["res"] = r
        rot = None if machine.kind == "tripod" else fit.rotation
        legs = measured_legs_mm(r.machine, fit.tip_mm, rot, r.frame_translation_mm, r.frame_rotation)
        corr = 0.0 if not terms else data.leg_correction_mm
        return legs - r.machine.drive_to_legs(fit.q) - corr

    terms, rounds = leg_residual_loop(machine, fit.q, leg_res, scales_fitted=calibrator.estimate_scales)
    if terms:
        leg_res(terms)
    return terms, rounds, state["res"] if terms else rigid


# ---------------------------------------------------------------------------------------------
# the plain baseline
# ---------------------------------------------------------------------------------------------

@dataclass
class PlainFit:
    """Result of :func:`plain_leg_fit`: ``machine``, the frame (instrument <- machine), the objective
    used (``"leg"`` or ``"pose"``), the fit RMS (mm) of that objective, scipy's status/message."""

    machine: PKM
    frame_translation_mm: np.ndarray
    frame_rotation: np.ndarray
    objective: str
    fit_rms_mm: float
    success: bool
    message: str
    nfev: int
    leg_terms: LegTerms = field(default_factory=LegTerms)

    def pose_errors_um(self, data, nominal: PKM) -> dict:
        """Measured residual on ``data`` (see :func:`errormap.pkm.calibration.pose_errors_um`)."""
        return pose_errors_um(self.machine, (self.frame_translation_mm, self.frame_rotation), data,
                              self.leg_terms, nominal)


def _unpack(machine: PKM, p: np.ndarray, scales: bool, R0: np.ndarray):
    k = machine.n_legs
    n = 8 * k if scales else 7 * k
    r = parameter_vector(machine)
    r[:n] = p[:n]
    t = p[n:n + 3]
    R = Rotation.from_rotvec(p[n + 3:n + 6]).as_matrix() @ R0
    return machine_from_vector(machine, r), t, R


def plain_leg_fit(machine: PKM, data, scales: bool = True, register: bool = True, leg_terms: LegTerms | None = None,
                  objective: str | None = None) -> PlainFit:
    """Plain least squares (scipy ``least_squares``, LM, no regularisation) of the same parameters.

    ``objective`` ``"leg"`` (default when the pose set has orientations or the machine is a tripod) or
    ``"pose"`` (forward-kinematics pose residual, orientation rows in rad times 500 mm).
    ``leg_terms``: fixed leg terms added to the model legs (their coefficients are not refitted).
    """
    k = machine.n_legs
    has_rot = data.rotation is not None or machine.kind == "tripod"
    objective = objective or ("leg" if has_rot else "pose")
    if objective == "leg" and not has_rot:
        raise ValueError("the leg-space objective needs measured orientations")
    corr = np.zeros_like(data.q) if not leg_terms else leg_terms.correction_mm(machine, data.q)
    fk0 = forward_kinematics(machine, machine.drive_to_legs(data.q), check_limits=False)
    t0, R0, _ = robust_registration(fk0.x, data.tip_mm) if register else (np.zeros(3), np.eye(3), None)
    n = 8 * k if scales else 7 * k
    p0 = np.r_[parameter_vector(machine)[:n], t0, np.zeros(3)]

    def full(p):
        return p if register else np.r_[p, t0, np.zeros(3)]

    def fun_leg(p):
        m, t, R = _unpack(machine, full(p), scales, R0)
        rot = None if machine.kind == "tripod" else data.rotation
        return (measured_legs_mm(m, data.tip_mm, rot, t, R) - m.drive_to_legs(data.q) - corr).ravel()

    state = {"guess": (fk0.x, fk0.platform2base)}

    def fun_pose(p):
        m, t, R = _unpack(machine, full(p), scales, R0)
        fk = forward_kinematics(m, m.drive_to_legs(data.q) + corr, guess_tip_mm=state["guess"][0],
                                guess_platform2base=state["guess"][1], check_limits=False, raise_on_failure=False)
        if not fk.success.all():
            return np.full(data.q.shape[0] * (6 if data.rotation is not None else 3), 1e3)
        res = [fk.x @ R.T + t - data.tip_mm]
        if data.rotation is not None and machine.kind == "hexapod":
            Rp = np.einsum("ij,njk->nik", R, fk.platform2base)
            res.append(500.0 * Rotation.from_matrix(np.einsum("nij,nkj->nik", Rp, data.rotation)).as_rotvec())
        return np.concatenate(res, 1).ravel()

    fun = fun_leg if objective == "leg" else fun_pose
    x0 = p0 if register else p0[:n]
    sol = least_squares(fun, x0, method="lm", x_scale="jac", max_nfev=200 * (len(x0) + 1))
    m, t, R = _unpack(machine, full(sol.x), scales, R0)
    rms = float(np.sqrt(np.mean(sol.fun ** 2)))
    return PlainFit(m, t, R, objective, rms, bool(sol.success), str(sol.message), int(sol.nfev),
                    leg_terms or LegTerms())
