"""The physical part of the residual-on-physics surrogate: an element set fitted to feature points.

``volcomp train --physics first-order`` trains the network on what a cheap physical model leaves:
the 23-element HTM model whose elements are fitted, by ONE linear least-squares solve, to the
same feature points the network sees (never to the element set the points were computed from):

    E(x, z, a) ≈ J(x, z, a) · v(x, z, a)       (first-order error transfer, errormap.htm.error_jacobian)

with each of the 18 axis-motion elements a cubic interpolating B-spline through ``n_stations``
equally spaced stations of its axis (periodic in A; zero at the first station, the axes'
reference) and the 5 constants. The unknowns are the station values (18·(n−1) − 6 + 5; the A
profiles close) and the solve is minimum-norm, so the gauge combinations the grid cannot see
(e.g. a constant X offset carried by two elements) take no value. The fitted set is evaluated
with the EXACT HTM model (:class:`errormap.htm.HTMField`), so the network learns the second-order
terms the linear fit cannot carry plus whatever the element model does not represent.

What this part knows of the machine: its kinematic chain (the machine file) and the feature
points; the stations are the feature-point grid's own nodes by default (``n_stations = None``:
the number of distinct values per axis, at most :data:`MAX_STATIONS`).
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import make_interp_spline

from errormap.elements import AXIS_OF, CONSTANT_ELEMENTS, FUNCTION_ELEMENTS, ElementSet, default_stations
from errormap.htm import IDX, error_jacobian

PHYSICS = ("none", "first-order")
"""``--physics`` choices: no physical part (the paper's network alone), or the fitted element set."""
MIN_STATIONS, MAX_STATIONS = 4, 61
_AXIS_COL = {"x_mm": 0, "z_mm": 1, "a_deg": 2}
RCOND = 1e-10  # relative singular-value cut of the minimum-norm solve: drops the grid's gauge directions only


def grid_stations(axes) -> int:
    """Stations per axis for a feature-point grid: the fewest distinct values over the three axes,
    clipped to [MIN_STATIONS, MAX_STATIONS] (a regular n×n×n grid gives n)."""
    a = np.asarray(axes, float)
    n = min(np.unique(np.round(a[:, k], 9)).size for k in range(3))
    return int(np.clip(n, MIN_STATIONS, MAX_STATIONS))


def _basis(stations, x, periodic: bool) -> np.ndarray:
    """Values at ``x`` (m,) of the cubic interpolating spline of each free station, shape (m, k):
    station 0 is the reference (zero); in A the last station repeats the first."""
    s = stations.size
    free = range(1, s - 1) if periodic else range(1, s)
    eye = np.zeros((s, len(free)))
    for c, j in enumerate(free):
        eye[j, c] = 1.0
    return make_interp_spline(stations, eye, k=3, bc_type="periodic" if periodic else None)(x)


def fit_physics_elements(machine, axes, errors_um, n_stations: int | None = None) -> ElementSet:
    """The element set (``n_stations`` per axis) whose first-order field best fits ``errors_um``.

    ``axes`` shape (n, 3) (x_mm, z_mm, a_deg), ``errors_um`` shape (n, 3). One minimum-norm
    linear least-squares solve (module doc); returns an :class:`ElementSet` on the machine's strokes.
    """
    axes = np.asarray(axes, float)
    e = np.asarray(errors_um, float)
    m = grid_stations(axes) if n_stations is None else int(n_stations)
    if not MIN_STATIONS <= m <= MAX_STATIONS:
        raise ValueError(f"Expected n_stations in [{MIN_STATIONS}, {MAX_STATIONS}], got {m}")
    st = default_stations(machine, m)
    a0 = st["a_deg"][0]
    J = error_jacobian(machine, axes)                                  # (n, 3, 23)
    x_of = {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": a0 + np.mod(axes[:, 2] - a0, 360.0)}
    bases = {ax: _basis(st[ax], x_of[ax], ax == "a_deg") for ax in st}
    cols, sizes = [], []
    for k in FUNCTION_ELEMENTS:
        B = bases[AXIS_OF[k]]
        cols.append(J[:, :, IDX[k], None] * B[:, None, :])
        sizes.append(B.shape[1])
    for k in CONSTANT_ELEMENTS:
        cols.append(J[:, :, IDX[k], None])
        sizes.append(1)
    A = np.concatenate(cols, axis=2).reshape(3 * len(axes), -1)
    # minimum norm in the elements' own units (μm, μrad): the gauge combinations the grid cannot see
    # stay near zero, so they add nothing through the exact model's second-order terms (scaling the
    # columns to unit norm first moved them and raised the exact model's misfit 0.027 → 0.16 μm)
    p = np.linalg.lstsq(A, e.reshape(-1), rcond=RCOND)[0]
    functions, constants, i = {}, {}, 0
    for k, size in zip(FUNCTION_ELEMENTS + CONSTANT_ELEMENTS, sizes):
        if k in CONSTANT_ELEMENTS:
            constants[k] = float(p[i])
        else:
            v = np.zeros(st[AXIS_OF[k]].size)
            v[1:1 + size] = p[i:i + size]
            if AXIS_OF[k] == "a_deg":
                v[-1] = v[0]
            functions[k] = v
        i += size
    return ElementSet(st, functions, constants, machine.name, machine.sha256)
