"""Calibration poses from several measurement sessions in one file (the poses' ``session`` column).

:func:`align_sessions` brings every session's points into the frame of the reference session (the most
poses) by registering each session's base frame on a plain calibration, twice
(``docs/reference/arm-calibration.md``). :func:`expanded_params` / :func:`fit_expansion`: a uniform expansion
α·ΔT of the arm moves a base-frame point p_b to (1 + α·ΔT)·p_b exactly; α (1/K) is fitted to the residuals of
sessions logged at different mean temperatures (whether it is used is decided in
``compensation.app.workflows.arm_sessions``). Lengths mm, angles rad, temperatures °C."""
from __future__ import annotations

import numpy as np

from .arm_calibration import fit_plain_lsq
from .arm_frames import base_transform
from .arm_register import MIN_POSES, fit_frame
from .io import InputError

ALIGN_PASSES = 2
"""Passes of :func:`align_sessions` (the first against the reference session's plain calibration, the second
against the plain calibration of every aligned pose)."""


def session_groups(poses) -> list:
    """[(label, indices (m,))] of ``poses`` by their ``session`` labels, in order of first appearance; one group
    labelled None for a file without the column."""
    if poses.session is None:
        return [(None, np.arange(len(poses)))]
    lab = np.asarray(poses.session)
    _, first = np.unique(lab, return_index=True)
    return [(lab[i], np.flatnonzero(lab == lab[i])) for i in np.sort(first)]


def _move(poses, T):
    """A copy of ``poses`` with points (and orientations) moved by the transform T (4, 4)."""
    out = poses.subset(np.arange(len(poses)))
    out.xyz_mm = poses.xyz_mm @ T[:3, :3].T + T[:3, 3]
    if poses.rot is not None:
        out.rot = np.einsum("ij,njk->nik", T[:3, :3], poses.rot)
    return out


def apply_alignment(poses, moves: dict, what: str = "poses"):
    """``poses`` with each session's points moved by ``moves[label]`` (4, 4) (:func:`align_sessions`); InputError for
    a label the calibration poses do not have."""
    if poses.session is None:
        raise InputError(f"{poses.source}: no column 'session': the calibration poses come from several sessions, so "
                         f"the {what}' session must be named (column 'session', one of {sorted(moves)})")
    out = poses.subset(np.arange(len(poses)))
    for lab, idx in session_groups(poses):
        if lab not in moves:
            raise InputError(f"{poses.source}: row {poses.rows[idx[0]]}, column 'session': {lab!r} is not a session "
                             f"of the calibration poses ({sorted(moves)})")
        m = _move(poses.subset(idx), moves[lab])
        out.xyz_mm[idx] = m.xyz_mm
        if out.rot is not None:
            out.rot[idx] = m.rot
    return out


def align_sessions(chain, poses):
    """(aligned poses, moves {label: (4, 4)}, rows [{"session", "n", "reference", "fit_rms_mm", "base"}]) of a pose set
    with at least two sessions: every session moved into the reference session's frame (module docstring)."""
    groups = session_groups(poses)
    for lab, idx in groups:
        if len(idx) < MIN_POSES:
            raise InputError(f"{poses.source}: row {poses.rows[idx[0]]}, column 'session': session {lab!r} has "
                             f"{len(idx)} pose(s); each session needs at least {MIN_POSES} to register its frame")
    ref = max(range(len(groups)), key=lambda k: (len(groups[k][1]), -k))
    model = fit_plain_lsq(chain, poses.subset(groups[ref][1]))
    aligned = poses
    for _ in range(ALIGN_PASSES):
        T_ref = base_transform(chain, model.params)
        moves, rows = {}, []
        for k, (lab, idx) in enumerate(groups):
            sess = poses.subset(idx)
            x, *_ = fit_frame(chain, model.params, sess)
            moves[lab] = T_ref @ np.linalg.inv(base_transform(chain, x))
            r = sess.xyz_mm - chain.tool_point(sess.q, x)
            rows.append({"session": str(lab), "n": int(len(idx)), "reference": k == ref,
                         "fit_rms_mm": float(np.sqrt(np.mean(np.sum(r ** 2, 1)))),
                         "base": {n: float(x[list(chain.param_names).index(n)]) for n in chain.param_names
                                  if n.startswith("base.")}})
        aligned = apply_alignment(poses, moves)
        model = fit_plain_lsq(chain, aligned)
    return aligned, moves, rows


def expanded_params(chain, params, s: float) -> np.ndarray:
    """Slot values (n_params,) of ``chain`` at ``params`` with every translation after the base (links, tool) scaled
    by (1 + s): the base-frame tool point becomes (1 + s)·p_b. InputError for a translation without a slot."""
    names = list(chain.param_names)
    out = np.array(params, float).copy()
    for e in chain.ets:
        if e.kind != "t" or e.joint is not None or (e.slot or "").startswith("base."):
            continue
        if e.slot is None:
            if e.value != 0.0:
                raise InputError(f"machine {chain.name!r}: a translation without an error slot cannot be expanded")
            continue
        k = names.index(e.slot)
        out[k] += s * (e.value + e.coef * out[k]) / e.coef
    return out


def expansion_direction(chain, params, q) -> np.ndarray:
    """d p / d s (n, 3) mm of the tool point in the instrument's frame under :func:`expanded_params` (exactly linear)."""
    return chain.tool_point(q, expanded_params(chain, params, 1.0)) - chain.tool_point(q, params)


def session_temperatures(poses) -> np.ndarray | None:
    """(n,) °C: the mean logged temperature of each pose's session (None without ``temp_c``)."""
    if poses.temp_c is None:
        return None
    out = np.empty(len(poses))
    for _, idx in session_groups(poses):
        out[idx] = poses.temp_c[idx].mean()
    return out


def fit_expansion(chain, params, poses, residual_mm, t_ref_c: float) -> float:
    """α (1/K): least squares of ``residual_mm`` (n, 3) on ΔT·(d p / d s), ΔT each pose's session mean temperature
    minus ``t_ref_c``."""
    dT = session_temperatures(poses) - t_ref_c
    f = dT[:, None] * expansion_direction(chain, params, poses.q)
    den = float(np.sum(f * f))
    return 0.0 if den == 0.0 else float(np.sum(f * residual_mm) / den)
