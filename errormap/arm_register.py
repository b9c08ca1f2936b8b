"""Re-registering a calibrated arm in a new measurement session: only the tracker (world) → base frame (and,
when asked, the tool point) is fitted on a few poses; every link parameter, joint slot and learned stage is
kept.

:func:`register_frame` fits the six ``base.*`` slots (and the three ``tool.*`` with ``tool=True``): a
closed-form rigid fit (Kabsch), refined by Levenberg–Marquardt on the exact base transform; it reports the
frame's standard errors and the joint vectors that would pin it best (greedy A-optimal choice). Lengths mm,
angles rad; ``q`` (n, nq) in the joints' units."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arm_calibration import _lm
from .arm_frames import BASE_SLOTS, TOOL_SLOTS, base_rotation, initial_base
from .io import InputError

__all__ = ["BASE_SLOTS", "TOOL_SLOTS", "Registration", "choose_candidate", "fit_frame", "register_frame",
           "registered_point", "suggest_poses"]

MIN_POSES = 6
"""Fewest poses a registration takes: 18 coordinates for at most 9 slots, twice what the frame needs."""
SUGGEST_POSES = 6
SUGGEST_CANDIDATES = 2000
"""Joint vectors drawn (seeded) inside the limits, among which the poses that would pin the frame best are chosen."""


@dataclass
class Registration:
    """``params`` (n_params,) the calibrated slots with the registered frame; ``slots`` the fitted slot names,
    ``value`` / ``std`` (k,) their values and standard errors; ``cov`` (k, k); ``fit_rms_mm`` the 3-D RMS residual
    on the registration poses; ``suggest_q`` (m, nq) joint vectors that would pin the frame best, ``suggest_std``
    (k,) the standard errors with them added; ``learned_rotation`` (3, 3)."""

    params: np.ndarray
    slots: list
    value: np.ndarray
    std: np.ndarray
    cov: np.ndarray
    fit_rms_mm: float
    iterations: int
    converged: bool
    suggest_q: np.ndarray
    suggest_std: np.ndarray
    learned_rotation: np.ndarray
    """(3, 3) turning a learned residual from the calibration's instrument frame into this session's."""

    def to_dict(self, joint_columns) -> dict:
        return {"slots": [{"name": n, "value": float(v), "std": float(s)}
                          for n, v, s in zip(self.slots, self.value, self.std)],
                "covariance": self.cov.tolist(), "fit_rms_mm": self.fit_rms_mm, "iterations": self.iterations,
                "converged": self.converged, "learned_rotation": self.learned_rotation.tolist(),
                "poses_that_pin_it_best": {"joints": list(joint_columns), "q": self.suggest_q.tolist(),
                                           "std_with_them": self.suggest_std.tolist()}}


def fit_frame(chain, params, poses, learner=None, tool: bool = False):
    """The frame fit of :func:`register_frame` alone: (slots (n_params,), iterations, converged, learned_rotation
    (3, 3), the measurements less the turned learned residual (n, 3) mm, the fitted slots' mask (n_params,))."""
    names = list(BASE_SLOTS) + (list(TOOL_SLOTS) if tool else [])
    free = np.isin(np.array(chain.param_names), names)
    w = np.ones(len(poses)) if poses.sigma_mm is None else 1.0 / poses.sigma_mm
    params = np.asarray(params, float)
    R_cal = base_rotation(chain, params)
    res = None if learner is None else learner.predict(poses.q)
    R_learned = np.eye(3)
    for _ in range(1 if learner is None else 2):
        y = poses.xyz_mm - (0.0 if res is None else res @ R_learned.T)
        x0 = initial_base(chain, params, poses.q, y)
        x, it, conv = _lm(chain, poses.q, y, x0, free, w)
        R_learned = base_rotation(chain, x) @ R_cal.T
    return x, it, conv, R_learned, y, free


def register_frame(chain, params, poses, learner=None, tool: bool = False, seed=0) -> Registration:
    """Fit the base frame (and the tool point with ``tool``) of the calibrated chain ``chain`` (its slots
    ``params`` (n_params,), a learned residual ``learner`` or None, both kept) to the measured ``poses``
    (at least :data:`MIN_POSES`). The learned residual is subtracted from the measurements first (it is a
    function of the joints learned in the calibration's instrument frame: it is turned with the base frame, by
    ``learned_rotation`` = R_base,new · R_base,calibrationᵀ, one refit after the first estimate of it)."""
    if len(poses) < MIN_POSES:
        raise InputError(f"{poses.source}: {len(poses)} poses: a registration takes at least {MIN_POSES}")
    names = list(BASE_SLOTS) + (list(TOOL_SLOTS) if tool else [])
    x, it, conv, R_learned, y, free = fit_frame(chain, params, poses, learner, tool)
    w = np.ones(len(poses)) if poses.sigma_mm is None else 1.0 / poses.sigma_mm
    r = y - chain.tool_point(poses.q, x)
    J = chain.error_jacobian(poses.q, x)[:, :, free] * w[:, None, None]
    A = np.einsum("nik,nil->kl", J, J)
    k = int(free.sum())
    s2 = float(np.sum((r * w[:, None]) ** 2) / max(3 * len(poses) - k, 1)) if poses.sigma_mm is None else 1.0
    cov = s2 * np.linalg.pinv(A)
    sq, sstd = suggest_poses(chain, x, free, A, s2, seed)
    order = [list(np.array(chain.param_names)[free]).index(n) for n in names]
    cov = cov[np.ix_(order, order)]
    return Registration(x, names, x[free][order], np.sqrt(np.diag(cov)), cov,
                        float(np.sqrt(np.mean(np.sum(r ** 2, 1)))), it, conv, sq, sstd[order], R_learned)


def registered_point(chain, params, learner, R_learned, q) -> np.ndarray:
    """Tool points (n, 3) mm in the session's instrument frame of a registered model: the chain at ``params`` plus the
    learned residual (or None) turned by ``R_learned`` (3, 3)."""
    p = chain.tool_point(q, params)
    return p if learner is None else p + learner.predict(q) @ R_learned.T


DECIDE_MIN_POSES = MIN_POSES + 1
"""Fewest registration poses on which the candidates are weighed against each other: each leave-out fold must still
register on :data:`MIN_POSES`. With fewer, the plainest candidate (the plain calibration) is kept."""
DECIDE_FOLDS = 10
"""Folds of the CV inside the registration poses (leave-one-out up to this many poses)."""
FOLD_KINDS = ("interleaved", "blocked")
"""How the registration poses are dealt into folds (:func:`decision_folds`)."""
DECIDE_FOLD_KIND = "interleaved"
"""The fold kind register uses (docs/decisions/020-benchmark-notebook.md, "Sessions in one calibration file": blocked folds measured beside)."""


def decision_folds(n: int, k: int, kind: str = DECIDE_FOLD_KIND) -> np.ndarray:
    """Fold label (n,) of each of ``n`` registration poses in file order: ``"interleaved"`` pose i in fold i mod k;
    ``"blocked"`` k contiguous runs of (nearly) equal length."""
    if kind not in FOLD_KINDS:
        raise ValueError(f"fold kind must be one of {FOLD_KINDS}, got {kind!r}")
    return np.arange(n) % k if kind == "interleaved" else np.arange(n) * k // n


def choose_candidate(candidates, poses, tool: bool = False, fold_kind: str = DECIDE_FOLD_KIND) -> dict:
    """Which registered model to keep, decided inside the new session's registration ``poses`` alone.

    ``candidates``: list of (name, chain, params (n_params,), learner or None), plainest FIRST (the plain calibration
    the product must not lose to). Each is registered on every fold's other poses and judged on the fold's poses
    (:data:`DECIDE_FOLDS`-fold CV, folds by ``fold_kind`` (:func:`decision_folds`), measured residual, position
    norm); starting from the plainest, a richer candidate
    replaces the one kept only if its paired per-pose gain over it exceeds one standard error of that gain (a gain
    inside its own noise is not a gain). With fewer than :data:`DECIDE_MIN_POSES` poses nothing is weighed: the
    plainest is kept. Returns ``{"kept", "why", "n_folds", "cv": [{"name", "cv_mean_mm", "gain_mm", "gain_se_mm"}]}``
    (gain against the plainest)."""
    n = len(poses)
    plain = candidates[0][0]
    if n < DECIDE_MIN_POSES:
        return {"kept": plain, "n_folds": 0, "cv": [],
                "why": f"{n} registration poses: too few to weigh the models (a leave-out CV needs at least "
                       f"{DECIDE_MIN_POSES}); the plain calibration is kept as the fallback"}
    k = min(n, DECIDE_FOLDS)
    fold = decision_folds(n, k, fold_kind)
    err = {}
    for name, chain, params, learner in candidates:
        e = np.empty(n)
        for f in range(k):
            tr, te = poses.subset(np.flatnonzero(fold != f)), poses.subset(np.flatnonzero(fold == f))
            x, _, _, R, _, _ = fit_frame(chain, params, tr, learner, tool)
            e[fold == f] = np.linalg.norm(te.xyz_mm - registered_point(chain, x, learner, R, te.q), axis=1)
        err[name] = e

    def gain(a, b):                      # paired gain of b over a, its standard error
        g = err[a] - err[b]
        return float(g.mean()), float(g.std(ddof=1) / np.sqrt(n))
    kept = plain
    for name, *_ in candidates[1:]:
        g, se = gain(kept, name)
        if g > se:
            kept = name
    rows = [{"name": c[0], "cv_mean_mm": float(err[c[0]].mean()), "gain_mm": gain(plain, c[0])[0],
             "gain_se_mm": gain(plain, c[0])[1]} for c in candidates]
    text = ", ".join(f"{r['name']} {r['cv_mean_mm']:.4f}" for r in rows)
    why = (f"{k}-fold CV inside the {n} registration poses (each fold's frame registered on the other poses; mean "
           f"measured residual {text} mm): " + (f"'{kept}' kept, its gain over the plainer candidate beyond one "
                                                "standard error" if kept != plain else
                                                "no richer model gained more than one standard error over the plain "
                                                "calibration: the plain calibration is kept"))
    return {"kept": kept, "why": why, "n_folds": k, "cv": rows}


def suggest_poses(chain, params, free, A, s2, seed, m: int = SUGGEST_POSES):
    """(q (m, nq), the slots' standard errors (k,) with them added): greedy A-optimal choice among
    :data:`SUGGEST_CANDIDATES` seeded joint vectors inside the limits, ``A`` (k, k) the information already there."""
    from .arm_simulate import random_joints
    qc = random_joints(chain.joint_lo, chain.joint_hi, SUGGEST_CANDIDATES, seed)
    Jc = chain.error_jacobian(qc, params)[:, :, free]            # (c, 3, k)
    A = A.copy()
    pick = []
    for _ in range(m):
        Ainv = np.linalg.pinv(A)
        # trace of (A + JᵢᵀJᵢ)⁻¹ by the Woodbury identity, per candidate
        B = np.einsum("nik,kl->nil", Jc, Ainv)                    # (c, 3, k)
        S = np.eye(3)[None] + np.einsum("nik,njk->nij", B, Jc)
        red = np.einsum("nij,nji->n", np.linalg.solve(S, B), np.swapaxes(B, 1, 2))
        red[pick] = -np.inf
        i = int(np.argmax(red))
        pick.append(i)
        A = A + Jc[i].T @ Jc[i]
    return qc[pick], np.sqrt(s2 * np.diag(np.linalg.pinv(A)))
