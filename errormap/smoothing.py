"""The smoother and the bootstrap loop every machine family's identification shares.

:func:`smooth_blocks`: per block of station values (one element or slot, in station order, periodic for a
full-turn axis) a Whittaker smoother ``f = (W + λ DᵀD)⁻¹ W y`` (second differences, ``W`` the inverse of
the station variances), λ chosen by the unbiased risk estimate with the known covariance (Mallows' C_p /
UBRE), and the smoother's estimated squared bias. :func:`bootstrap_draws`: the seeded loop of a bootstrap.
Used by :mod:`errormap.identification` (machine tools).
"""
from __future__ import annotations

import numpy as np

LAMBDA_GRID = np.logspace(-4, 8, 49)
"""Smoothing parameters searched (dimensionless: the penalty is on second differences of the
station values, the data term weighted by their inverse variance)."""


def _second_differences(m: int, periodic: bool) -> np.ndarray:
    if periodic:
        D = -2.0 * np.eye(m) + np.roll(np.eye(m), 1, axis=1) + np.roll(np.eye(m), -1, axis=1)
        return D
    return np.diff(np.eye(m), 2, axis=0)


def _smoother(y, Sigma, periodic: bool):
    """UBRE-optimal Whittaker smoother for station values y (m,) with covariance Sigma (m, m):
    returns (H (m, m), λ, effective degrees of freedom)."""
    m = y.size
    var = np.diag(Sigma).copy()
    if var.max() <= 0:
        return np.eye(m), 0.0, float(m)
    var = np.maximum(var, 1e-3 * var.max())  # gauge stations (exactly zero) get a finite weight
    W = np.diag(1.0 / var)
    D = _second_differences(m, periodic)
    DtD = D.T @ D
    I = np.eye(m)
    best = None
    for lam in LAMBDA_GRID:
        H = np.linalg.solve(W + lam * DtD, W)
        res = y - H @ y
        risk = res @ W @ res - np.trace(W @ (I - H) @ Sigma @ (I - H).T) + np.trace(W @ H @ Sigma @ H.T)
        if best is None or risk < best[0] - 1e-12 * abs(best[0]):
            best = (risk, lam, H)
    return best[2], float(best[1]), float(np.trace(best[2]))


def smooth_blocks(y, S, blocks: dict) -> tuple:
    """The UBRE smoother of every machine family's station values (module doc, steps 3–4): per block
    ``name -> (indices (m,) into y in station order, periodic)`` the Whittaker smoother :func:`_smoother` with
    the block of the covariance ``S`` (P, P) of ``y`` (P,). Returns ``({name: H_k (m, m)}, {name: {lambda, edf}},
    bias_var (P,), prior_extra (P,))``: the smoothed vector is ``H y`` with ``H`` the identity but for the blocks
    (:func:`apply_blocks`); the smoother's squared bias is not in ``H S Hᵀ``, so per block the mean square of what
    it removed, less what noise alone explains (E|(I−H)y|² = |(I−H)f|² + tr((I−H)Σ(I−H)ᵀ)), is ``bias_var`` (to add
    on the diagonal), and ``prior_extra`` the rest of the whole mean-square change
    (``prior_extra`` of :mod:`errormap.chain_covariance`)."""
    P = y.size
    Hb, smoothing = {}, {}
    bias_var, prior_extra = np.zeros(P), np.zeros(P)
    for k, (idx, periodic) in blocks.items():
        Sk = S[np.ix_(idx, idx)]
        Hk, lam, edf = _smoother(y[idx], Sk, periodic=periodic)
        Hb[k] = Hk
        smoothing[k] = {"lambda": lam, "edf": edf}
        B = np.eye(idx.size) - Hk
        noise = np.trace(B @ Sk @ B.T) / idx.size
        change2 = np.mean((y[idx] - Hk @ y[idx]) ** 2)
        bias_var[idx] = max(0.0, change2 - noise)
        prior_extra[idx] = change2 - bias_var[idx]  # total: the whole mean-square change
    return Hb, smoothing, bias_var, prior_extra


def apply_blocks(Hb: dict, blocks: dict, y, S, copies=()) -> tuple:
    """``(H y, H S Hᵀ)`` for ``H`` the identity but for the blocks ``Hb`` (:func:`smooth_blocks`) on ``blocks``'
    indices, and rows ``dst`` equal to rows ``src`` for every ``(src, dst)`` of ``copies`` (a full turn's last
    station is its first pose); block by block, never a dense (P, P) ``H``."""
    y, C = np.array(y, float), np.array(S, float)
    for k, (idx, _) in blocks.items():
        y[idx] = Hb[k] @ y[idx]
        C[idx, :] = Hb[k] @ C[idx, :]
    for src, dst in copies:
        y[dst], C[dst, :] = y[src], C[src, :]
    for k, (idx, _) in blocks.items():
        C[:, idx] = C[:, idx] @ Hb[k].T
    for src, dst in copies:
        C[:, dst] = C[:, src]
    return y, C


def bootstrap_draws(draw, n_boot: int, seed: int, n_params: int) -> np.ndarray:
    """The bootstrap loop of every machine family's identification: ``draw(s)`` identifies again from one
    resampled measurement set seeded by the integer ``s`` and returns its parameter vector (n_params,);
    draw ``b`` is seeded by the ``b``-th child of ``SeedSequence(seed)``. Returns (n_boot, n_params)."""
    if n_boot < 0:
        raise ValueError(f"Expected n_boot >= 0, got {n_boot}")
    Y = np.empty((n_boot, n_params))
    for b, ss in enumerate(np.random.SeedSequence(seed).spawn(n_boot)):
        Y[b] = draw(int(ss.generate_state(1)[0]))
    return Y
