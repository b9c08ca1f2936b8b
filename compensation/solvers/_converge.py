"""No GA point handed over unconverged: retries after the paper's generations, then a Newton polish.

After its generations a GA solver (:mod:`compensation.solvers.chain_ga`) re-runs the points whose float64
model residual ``|p_r + 1e-3·E(axes(p_r)) − p_d|`` (μm) is above ``tol_um``, up to :data:`RETRY_ROUNDS`
times, from a population around the point's best (radius :func:`retry_radius_um`), then polishes the rest
with the exact solver's Newton iteration and keeps per point the candidate with the smaller residual; a
point still above the tolerance keeps ``success = False`` (the ``convergence`` guard refuses the file).
This module holds the retry radii and the stats' sum over chunks. The procedure and its measurements:
docs/explanation/solvers.md ("No point handed over unconverged").
"""
from __future__ import annotations

import numpy as np

RETRY_ROUNDS = 2
"""GA re-runs (each the paper's full generations) for the points above the tolerance."""
RETRY_RADIUS_FACTOR = 4.0
"""The first retry's population lies within this many residuals of the best offset: the root is
about one residual away (the field's slope is small against 1), so 4× covers it with margin."""
RETRY_MIN_RADIUS_UM = 1.0
"""Smallest retry radius: the GA's own mutation step (±1 μm)."""
RETRY_RADIUS_GROWTH = 8.0
"""Each further retry widens the population's ball by this factor (out of a local minimum)."""


def retry_radius_um(residual_um, round_: int, ball_um: float) -> np.ndarray:
    """Radius (μm) of the fresh population around the best for retry ``round_`` (0-based); (s,) -> (s,)."""
    r = np.maximum(RETRY_MIN_RADIUS_UM, RETRY_RADIUS_FACTOR * np.asarray(residual_um, dtype=float))
    return np.minimum(r * RETRY_RADIUS_GROWTH ** round_, ball_um)


def merge_stats(parts) -> dict:
    """Sum of a GA's retry stats over chunks (``retry_rounds`` and the worst residuals: the
    largest of any chunk)."""
    keys = ("retried", "retry_rounds", "polished", "unconverged", "retry_seconds", "worst_before_um", "worst_after_um")
    out = {}
    for k in (k for k in keys if any(k in s for s in parts)):  # the keys the solver counts (a chain GA: four)
        most = k in ("retry_rounds", "worst_before_um", "worst_after_um")
        vals = [s[k] for s in parts if k in s]
        out[k] = max(vals) if most else sum(vals)
    return out
