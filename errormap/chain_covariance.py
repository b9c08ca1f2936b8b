"""The covariance file beside a machine tool's element set, as the closed loop reads it.

``NAME.cov.npz`` of ``volcomp identify`` (``format``, ``slot``, ``station``, ``cov`` and the smoother's
``prior_extra``), or an older ``kind = "grinder"`` identification's (``layout_element``, ``layout_station``,
``theta``, ``cov``: its 23 element names are the chain's slots). The closed loop's element update takes Σ plus
``prior_extra`` on the diagonal as its prior; the band at points is :func:`band_sd`."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .identification import COV_FORMAT, parameter_vector
from .io import NPY_ERRORS, InputError, atomic_write, check_document_size, companion_path


PRIOR_EXTRA_KEY = "prior_extra"
"""The covariance file's key of the smoother's per-parameter variance to add on the diagonal when the set
seeds an update (:func:`errormap.smoothing.smooth_blocks`: the whole mean-square change smoothing made, a
conservative bound on its bias, so that the checks can correct what smoothing took away)."""
COMPANION_THETA_TOL = 1e-9
"""Relative: an older grinder covariance file holds the values (``theta``) of the element set it was
saved with, and the element-set JSON keeps every float exactly; a larger difference is another
identification's file."""
BAND_BATCH = 4096
"""Points per block of the band: the parameter Jacobian is (n, 3, N), N up to ~10^3 parameters
(32 MB a block)."""


def covariance_path(elements_path) -> Path:
    """Where the covariance of an element-set file lives: ``NAME.cov.npz`` beside it
    (:func:`errormap.io.companion_path`)."""
    return companion_path(elements_path, ".cov.npz")


def save_chain_covariance(res, path) -> Path:
    """The identification's covariance file (``format``, ``slot``, ``station``, ``cov``, as
    :func:`read_chain_covariance` reads it) with the smoother's :data:`PRIOR_EXTRA_KEY`
    (zeros for an unsmoothed set); written whole."""
    extra = np.zeros(len(res.param_slot)) if res.prior_extra is None else np.asarray(res.prior_extra, float)
    with atomic_write(path, "wb") as fh:
        np.savez(fh, format=np.array(COV_FORMAT), slot=np.array(res.param_slot), station=res.param_station,
                 cov=res.cov, **{PRIOR_EXTRA_KEY: extra})
    return Path(path)


def read_chain_covariance(cov_path, elements, prior: bool = False) -> tuple:
    """``(slot names, stations, Σ)`` from a covariance file beside ``elements`` (the
    :class:`errormap.chain_elements.ChainElementSet` beside it): a chain's (:func:`save_chain_covariance`)
    or an older grinder identification's, whose ``theta`` must be ``elements``' values. ``prior``: Σ plus the
    file's ``prior_extra`` on the diagonal (none in the file: Σ)."""
    if not Path(cov_path).is_file():
        raise InputError(f"{cov_path}: no such covariance file (written by `volcomp identify` beside the "
                         "elements)")
    check_document_size(cov_path, "an element covariance")
    try:
        with np.load(cov_path, allow_pickle=False) as d:
            files = set(d.files)
            extra = np.asarray(d[PRIOR_EXTRA_KEY], float) if PRIOR_EXTRA_KEY in files else None
            old = "format" not in files and "layout_element" in files   # an older grinder identification's
            if not old and str(d["format"]) != COV_FORMAT:
                raise InputError(f"{cov_path}: key 'format': expected {COV_FORMAT!r}, "
                                 f"got {str(d['format'])!r}")
            slots = [str(k) for k in d["layout_element" if old else "slot"]]
            stations, C = d["layout_station" if old else "station"].astype(int), d["cov"].astype(float)
            if old:
                _check_theta(cov_path, elements, slots, stations, d["theta"])
    except NPY_ERRORS as exc:
        raise InputError(f"{cov_path}: not a readable covariance file ({exc}); a truncated or damaged copy? "
                         "Run `volcomp identify` again to write it") from None
    if prior and extra is not None:
        if extra.shape != (len(slots),) or not np.all(np.isfinite(extra)) or np.any(extra < 0):
            raise InputError(f"{cov_path}: key '{PRIOR_EXTRA_KEY}': expected {len(slots)} finite variances >= 0, "
                             f"got shape {extra.shape}")
        C = C + np.diag(extra)
    return slots, stations, C


def _check_theta(cov_path, elements, slots, stations, theta) -> None:
    """Refuse an older grinder covariance file whose layout or values (``theta``) are not ``elements``'."""
    try:
        own = parameter_vector(elements, slots, stations)
    except (KeyError, IndexError):
        own = None
    if own is None or own.shape != theta.shape:
        raise InputError(f"{cov_path}: its parameter layout does not match the element set's stations")
    k = int(np.argmax(np.abs(theta - own)))
    if abs(theta[k] - own[k]) > COMPANION_THETA_TOL * max(1.0, float(np.abs(own).max())):
        where = slots[k] + ("" if stations[k] < 0 else f" station {stations[k]}")
        raise InputError(f"{cov_path}: not the covariance of this element set: its values differ at {where} "
                         f"({theta[k]:.6g} vs {own[k]:.6g}); a companion left from another identification? "
                         "Identify again or move the right one beside it")


def band_sd(machine, elements, cov, axes) -> np.ndarray:
    """Standard deviation (n, 3) μm of the element set's tool-point error at ``axes`` (n, k) from the
    identification's covariance ``cov`` = ``(slot names, stations, Σ)``: the diagonal of ``J Σ Jᵀ`` per point,
    ``J`` (3, N) the parameter Jacobian (:func:`errormap.diagnosis.chain_update.parameter_matrix`,
    linearised at ``elements``)."""
    from .diagnosis.chain_update import parameter_matrix
    slots, stations, C = cov
    axes = np.atleast_2d(np.asarray(axes, float))
    out = np.empty((axes.shape[0], 3))
    for i in range(0, axes.shape[0], BAND_BATCH):
        M = parameter_matrix(machine, elements, axes[i:i + BAND_BATCH], slots, stations)   # (b, 3, N)
        out[i:i + BAND_BATCH] = np.sqrt(np.maximum(np.einsum("bij,jk,bik->bi", M, C, M, optimize=True), 0.0))
    return out
