"""No GA point handed over unconverged: retries after the paper's generations, then a Newton polish.

The paper's GA (400 generations of 40) reaches the 0.265 μm tolerance on nearly every point,
but not on all: on the demo's flute one point of 2,800 was left at 6.26 μm model residual
. A GA solver (:func:`compensation.solvers.chain_ga`'s retry and polish) after its generations

1. measures every point's float64 model residual ``|p_r + 1e-3·E(axes(p_r)) − p_d|``;
2. re-runs the GA (``rerun``) on the points above ``tol_um``, up to :data:`RETRY_ROUNDS`
   times, each from a fresh population around the point's best so far (the best itself in
   slot 0, so the elite never gets worse): uniform in a ball of radius
   ``max(RETRY_MIN_RADIUS_UM, RETRY_RADIUS_FACTOR·|residual|)`` on the first retry, times
   :data:`RETRY_RADIUS_GROWTH` per further round (clipped to the search ball);
3. polishes the points still above the tolerance with the exact solver's Newton iteration
   (the field's Jacobian, or forward differences where the field declares none), starting
   from the GA's best;
4. keeps, per point, whichever candidate has the smaller float64 residual.

A point still above the tolerance keeps ``success = False``: the ``convergence`` guard
(:mod:`compensation.guards`) refuses the file. ``stats``: how many points were retried and
polished, how many stayed unconverged, the worst residual before and after, and the seconds
spent (the retry's cost). This module holds the retry radii and the stats' sum over chunks.
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
