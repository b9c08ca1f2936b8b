"""The two fit figures of the grinder paper (matplotlib, Agg backend).

* ``fit_error_xz.png`` — fit error (network minus reference, μm) over the plane of the first two axes at
  the lowest training value of the others (the grinder's X–Z plane at A = a0, the paper's Fig. 13): on a
  dense 41 × 31 grid against the HTM reference model when one is given, otherwise at the feature points of
  that plane.
* ``fit_featurepoints.png`` — original vs fitted error per feature point and their
  difference, per axis (the paper's Fig. 12).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

AXES = ("dx", "dy", "dz")


def _figure(**kw):
    """A figure on matplotlib's Agg canvas, without pyplot (no global backend state)."""
    from matplotlib.figure import Figure
    return Figure(**kw)


def _save(fig, path: Path) -> Path:
    from errormap.io import atomic_write
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    return path


def plot_fit_error_xz(field, axes, errors_um, path, reference=None, columns=("x_mm", "z_mm", "a_deg")) -> Path:
    """Fit error over the plane of the first two axis ``columns`` at the lowest training value of the
    others (axes (n, k)); returns the PNG path."""
    rest = axes[:, 2:].min(axis=0)
    at = ", ".join(f"{c} = {v:g}" for c, v in zip(columns[2:], rest))

    def plane(X, Z):
        return np.column_stack([X.ravel(), Z.ravel(), np.broadcast_to(rest, (X.size, len(rest)))])
    if reference is not None:
        xs = np.linspace(axes[:, 0].min(), axes[:, 0].max(), 41)
        zs = np.linspace(axes[:, 1].min(), axes[:, 1].max(), 31)
        X, Z = np.meshgrid(xs, zs, indexing="ij")
        pts = plane(X, Z)
        d = field.predict(pts) - reference.predict(pts)
        title = f"fit error (network − HTM model) at {at}, 41×31 grid"
    else:
        sel = np.all(np.isclose(axes[:, 2:], rest), axis=1)
        xs, zs = np.unique(axes[sel, 0]), np.unique(axes[sel, 1])
        X, Z = np.meshgrid(xs, zs, indexing="ij")
        pts = plane(X, Z)
        lut = {(round(p[0], 9), round(p[1], 9)): e for p, e in zip(axes[sel], errors_um[sel])}
        ref = np.array([lut.get((round(p[0], 9), round(p[1], 9)), [np.nan] * 3) for p in pts])
        d = field.predict(pts) - ref
        title = f"fit error (network − feature points) at {at}"
    fig = _figure(figsize=(14, 4.2), layout="constrained")
    axs = fig.subplots(1, 3)
    for j, ax in enumerate(axs):
        D = d[:, j].reshape(X.shape)
        m = ax.pcolormesh(X, Z, D, shading="auto", cmap="RdBu_r")
        fig.colorbar(m, ax=ax, label=f"{AXES[j]} fit error (μm)")
        ax.set_xlabel(columns[0])
        ax.set_ylabel(columns[1])
        ax.set_title(f"{AXES[j]}: [{np.nanmin(D):.3g}, {np.nanmax(D):.3g}] μm")
    fig.suptitle(title)
    out = _save(fig, Path(path))
    return out


def plot_featurepoints(field, axes, errors_um, path) -> Path:
    """Original vs fitted error per feature point (top) and their difference (bottom), per axis."""
    fit = field.predict(axes)
    idx = np.arange(len(axes))
    fig = _figure(figsize=(15, 6.5), layout="constrained")
    axs = fig.subplots(2, 3, sharex=True)
    for j in range(3):
        axs[0, j].plot(idx, errors_um[:, j], "o", ms=2.5, label="original (feature points)")
        axs[0, j].plot(idx, fit[:, j], "-", lw=0.7, label="fitted (network)")
        axs[0, j].set_ylabel(f"{AXES[j]} (μm)")
        axs[0, j].legend(loc="upper right", fontsize=7)
        d = fit[:, j] - errors_um[:, j]
        axs[1, j].plot(idx, d, ".", ms=2)
        axs[1, j].set_ylabel(f"{AXES[j]} fitted − original (μm)")
        axs[1, j].set_xlabel("feature point")
        axs[1, j].set_title(f"max |fit error| {np.abs(d).max():.4g} μm")
    fig.suptitle("original vs fitted error at the feature points")
    out = _save(fig, Path(path))
    return out


def fit_plots(field, axes, errors_um, out_dir, columns, reference=None) -> list:
    """Both figures into ``out_dir`` (``columns``: the machine's axis columns of ``axes``); returns their paths."""
    d = Path(out_dir)
    return [plot_fit_error_xz(field, axes, errors_um, d / "fit_error_xz.png", reference, tuple(columns)),
            plot_featurepoints(field, axes, errors_um, d / "fit_featurepoints.png")]
