"""Random sub-streams: the one way the project derives several streams from one seed.

Every consumer that needs more than one stream from a run's seed takes children of
``numpy.random.SeedSequence(seed)`` — never ``seed + k`` (neighbouring seeds of one run may
collide with another run's, and nothing says which is which). A child ``SeedSequence`` is
accepted wherever a seed is (``numpy.random.default_rng(child)``), so functions keep taking
``seed`` and callers hand them children.
"""
from __future__ import annotations

import numpy as np

__all__ = ["spawn_seeds", "spawn_rngs"]


def spawn_seeds(seed, n: int) -> list[np.random.SeedSequence]:
    """``n`` independent children of ``SeedSequence(seed)`` (``seed``: int or a SeedSequence)."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return ss.spawn(int(n))


def spawn_rngs(seed, n: int) -> list[np.random.Generator]:
    """``n`` independent Generators, one per child of ``SeedSequence(seed)``."""
    return [np.random.default_rng(s) for s in spawn_seeds(seed, n)]
