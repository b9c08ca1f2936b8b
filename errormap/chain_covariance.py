"""The covariance file beside a machine tool's element set, as the closed loop reads it.

``NAME.cov.npz`` of ``volcomp identify``: a chain's (``format``, ``slot``, ``station``, ``cov`` and the
smoother's ``prior_extra``) or a ``kind = "grinder"`` identification's (its 23 element names are the chain's
slots). The closed loop's element update takes Σ plus ``prior_extra`` on the diagonal as its prior."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .identification import COV_FORMAT, load_covariance
from .io import NPY_ERRORS, InputError, atomic_write


PRIOR_EXTRA_KEY = "prior_extra"
"""The covariance file's key of the smoother's per-parameter variance to add on the diagonal when the set
seeds an update (:func:`errormap.smoothing.smooth_blocks`: the whole mean-square change smoothing made, a
conservative bound on its bias, so that the checks can correct what smoothing took away)."""


def save_chain_covariance(res, path) -> Path:
    """The identification's covariance file (``format``, ``slot``, ``station``, ``cov``, as
    :func:`errormap.identification.load_covariance` reads it) with the smoother's :data:`PRIOR_EXTRA_KEY`
    (zeros for an unsmoothed set); written whole."""
    extra = np.zeros(len(res.param_slot)) if res.prior_extra is None else np.asarray(res.prior_extra, float)
    with atomic_write(path, "wb") as fh:
        np.savez(fh, format=np.array(COV_FORMAT), slot=np.array(res.param_slot), station=res.param_station,
                 cov=res.cov, **{PRIOR_EXTRA_KEY: extra})
    return Path(path)


def read_chain_covariance(cov_path, elements, prior: bool = False) -> tuple:
    """``(slot names, stations, Σ)`` from a covariance file beside an element set: a chain's
    (:func:`save_chain_covariance`) or a ``kind = "grinder"`` identification's (its 23 element names are the
    chain's slots, its stations the same; :class:`errormap.uncertainty.ElementCovariance`, checked against
    ``elements``, the :class:`errormap.chain_elements.ChainElementSet` beside it). ``prior``: Σ plus the file's ``prior_extra`` on the diagonal (none in the file: Σ)."""
    try:
        with np.load(cov_path, allow_pickle=False) as d:
            files = set(d.files)
            extra = np.asarray(d[PRIOR_EXTRA_KEY], float) if PRIOR_EXTRA_KEY in files else None
    except NPY_ERRORS as exc:
        raise InputError(f"{cov_path}: not a readable covariance file ({exc}); run `volcomp identify` again") from None
    if "format" not in files and "layout_element" in files:   # a grinder identification's file
        from .uncertainty import ElementCovariance, theta_layout
        gc = ElementCovariance.load(cov_path, elements)
        lay = theta_layout(gc.elements)
        slots, stations, C = [k for k, _ in lay], np.array([i for _, i in lay], int), gc.cov
        extra = gc.prior_extra
    else:
        slots, stations, C = load_covariance(cov_path)
    if prior and extra is not None:
        if extra.shape != (len(slots),) or not np.all(np.isfinite(extra)) or np.any(extra < 0):
            raise InputError(f"{cov_path}: key '{PRIOR_EXTRA_KEY}': expected {len(slots)} finite variances >= 0, "
                             f"got shape {extra.shape}")
        C = C + np.diag(extra)
    return slots, stations, C
