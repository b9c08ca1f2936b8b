"""Residual statistics: one function, one key scheme, for the whole project.

:func:`residual_stats` gives ``{"n", "max_um", "rms_um", "mean_um", "p95_um"}`` of the per-point magnitude
``|r|`` (the norm of each row of an ``(n, k)`` residual, or ``|r|`` of a 1-D one; p95 by linear
interpolation); with ``columns`` (names of the ``k`` columns) each adds ``{name: {"max_abs_um", "rms_um",
"mean_um"}}``. A non-finite entry makes the statistics NaN (a diverged fit cannot hide) unless
``drop_nonfinite=True`` leaves its row out. Unit-free: the ``_um`` keys carry the residual's unit. Callers
publishing other key names derive them from this dictionary, never computing a statistic of their own."""
from __future__ import annotations

from typing import Sequence

import numpy as np

P95 = 95.0  # percentile reported as p95_um

__all__ = ["residual_stats", "STAT_KEYS", "COLUMN_KEYS"]

STAT_KEYS = ("n", "max_um", "rms_um", "mean_um", "p95_um")
COLUMN_KEYS = ("max_abs_um", "rms_um", "mean_um")


def residual_stats(residual_um, columns: Sequence[str] | None = None, drop_nonfinite: bool = False) -> dict:
    """Statistics of a residual in μm (see the module doc for the key scheme).

    ``residual_um``: shape ``(n, k)`` (statistics of the row norms) or ``(n,)`` (of ``|r|``).
    ``columns``: names of the ``k`` columns for per-column statistics (2-D input only).
    ``drop_nonfinite``: leave out rows with a NaN/inf entry instead of returning NaN statistics.
    """
    r = np.asarray(residual_um, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    if r.ndim != 2:
        raise ValueError(f"Expected a residual of shape (n,) or (n, k), got {r.shape}")
    if columns is not None and len(columns) != r.shape[1]:
        raise ValueError(f"Expected {r.shape[1]} column names, got {len(columns)}")
    if drop_nonfinite:
        r = r[np.all(np.isfinite(r), axis=1)]
    n = int(r.shape[0])
    out: dict = {"n": n}
    if n == 0:
        out.update(dict.fromkeys(STAT_KEYS[1:]))
        if columns is not None:
            out.update({c: dict.fromkeys(COLUMN_KEYS) for c in columns})
        return out
    norm = np.linalg.norm(r, axis=1)
    out.update({"max_um": float(norm.max()), "rms_um": float(np.sqrt(np.mean(norm**2))),
                "mean_um": float(norm.mean()), "p95_um": float(np.percentile(norm, P95))})
    for j, c in enumerate(columns or ()):
        col = r[:, j]
        out[c] = {"max_abs_um": float(np.abs(col).max()), "rms_um": float(np.sqrt(np.mean(col**2))),
                  "mean_um": float(col.mean())}
    return out
