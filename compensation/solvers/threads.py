"""Torch's thread count while a solver feeds the field small batches."""
from __future__ import annotations

import contextlib

from errormap.threads import limit_threads

SMALL_BATCH_POINTS = 500
"""Paths shorter than this are solved with one torch thread (see :func:`small_batch_threads`)."""


@contextlib.contextmanager
def small_batch_threads(method: str, n_points: int | None = None):
    """One torch thread while the field sees small batches (if torch is loaded).

    The per-point ``ga`` calls the field on 40 points at a time (and every solver does so on
    a short path); on a busy 2-core machine torch's intra-op threads then spin against each
    other and a call costs ~100× more than on one thread (measured: 81 ms vs 0.8 ms for
    40 points). Long paths in the batched solvers keep the default.
    """
    small = method == "ga" or (n_points is not None and n_points < SMALL_BATCH_POINTS)
    with limit_threads(1 if small else None):
        yield
