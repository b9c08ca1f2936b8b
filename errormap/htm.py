"""The grinder's spatial error from its 23 elements by homogeneous transforms.

Where each element enters (every error transform is ``Trans(δ)·Rot(ε)`` with
``Rot(ε) = RotX(εx)·RotY(εy)·RotZ(εz)``, applied right after the nominal motion of its body,
at the body's reference point)::

    T_tool = RotZ(θ1)·Trans(l2,0,l1)·Trans(RotZ(-θ1)·z·(sin s_xz, 0, cos s_xz))
             ·E_z(z)·Trans(l3,0,l4)·Trans(0,0,-R)
             E_z = Trans(dx_z, dy_z, dz_z)·Rot(ex_z, ey_z, ez_z)        (Z carriage, frame {1-2})
    T_work = Trans(l5,0,l6)·Trans(x,0,0)·E_x(x)·Trans(l7,0,l8)·E_oa·RotX(a)·E_a(a)
             E_x  = Trans(dx_x, dy_x, dz_x)·Rot(ex_x, ey_x, ez_x)       (X carriage)
             E_oa = Trans(0, dy_oa, dz_oa)·Rot(0, ey_oa, ez_oa)          (A-axis line, before the rotation)
             E_a  = Trans(dx_a, dy_a, dz_a)·Rot(ex_a, ey_a, ez_a)       (A body, in the rotating frame)

Squareness ``s_xz`` tilts the Z direction about the machine Y axis (towards +X).
The spatial error is the actual tool point minus the nominal tool point, both in the
workpiece frame (WCS), in μm. Translations enter in μm, angles in μrad.

The first-order (small-error) form is linear in the elements: ``e ≈ J(axes) · v`` where
``J`` (shape (n, 3, 23), μm per μm or μm per μrad) is the error-transfer Jacobian.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .elements import CONSTANT_ELEMENTS, ELEMENT_NAMES, ElementSet
from .field import JACOBIAN, PREDICT_AND_JACOBIAN, CalibratedVolume
from .machine import Grinder
from .transforms import apply, apply_T, check_points, rot_x, rot_xyz, rot_z, skew

UM = 1e-3   # mm per μm (the compiled kernel writes 1e-3 and 1e-6 out)
URAD = 1e-6  # rad per μrad
IDX = {k: i for i, k in enumerate(ELEMENT_NAMES)}


def _split(values):
    v = np.asarray(values, dtype=float)
    def g(*names):
        return np.stack([v[:, IDX[k]] for k in names], axis=1)
    zeros = np.zeros(v.shape[0])
    return {
        "d_x": g("dx_x", "dy_x", "dz_x") * UM, "e_x": g("ex_x", "ey_x", "ez_x") * URAD,
        "d_z": g("dx_z", "dy_z", "dz_z") * UM, "e_z": g("ex_z", "ey_z", "ez_z") * URAD,
        "d_a": g("dx_a", "dy_a", "dz_a") * UM, "e_a": g("ex_a", "ey_a", "ez_a") * URAD,
        "d_oa": np.stack([zeros, v[:, IDX["dy_oa"]], v[:, IDX["dz_oa"]]], axis=1) * UM,
        "e_oa": np.stack([zeros, v[:, IDX["ey_oa"]], v[:, IDX["ez_oa"]]], axis=1) * URAD,
        "s": v[:, IDX["s_xz"]] * URAD,
    }


def tool_point_actual(machine: Grinder, axes, values) -> np.ndarray:
    """Actual tool point in the WCS (mm) with exact transforms.

    ``axes`` shape (n, 3) (x_mm, z_mm, a_deg); ``values`` shape (n, 23) element values
    at those axes (μm / μrad, ELEMENT_NAMES order). Returns shape (n, 3).
    """
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    e = _split(values)
    x, z, a = axes[:, 0], axes[:, 1], np.deg2rad(axes[:, 2])
    th = rot_z(np.deg2rad(machine.theta1_deg))[0]
    # tool chain, in the frame after RotZ(θ1)
    sq_in_mcs = np.stack([z * np.sin(e["s"]), np.zeros_like(z), z * np.cos(e["s"])], axis=1)
    sq_local = apply_T(th, sq_in_mcs)
    b = np.array([machine.l3, 0.0, machine.l4 - machine.R])
    local = np.array([machine.l2, 0.0, machine.l1]) + sq_local + e["d_z"] + apply(rot_xyz(e["e_z"]), np.broadcast_to(b, z.shape + (3,)))
    t = apply(th, local)
    # work chain inverse
    q = t - np.stack([machine.l5 + x, np.zeros_like(x), np.full_like(x, machine.l6)], axis=1)
    q = apply_T(rot_xyz(e["e_x"]), q - e["d_x"])
    q = q - np.array([machine.l7, 0.0, machine.l8])
    q = apply_T(rot_xyz(e["e_oa"]), q - e["d_oa"])
    q = apply_T(rot_x(a), q)
    return apply_T(rot_xyz(e["e_a"]), q - e["d_a"])


def nominal_frames(machine: Grinder, axes):
    """Intermediate nominal quantities shared by the first-order form and the Jacobian."""
    from .kinematics import forward, tool_in_machine_nominal
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    x, z, a = axes[:, 0], axes[:, 1], np.deg2rad(axes[:, 2])
    t = tool_in_machine_nominal(machine, z)
    q0 = t - np.stack([machine.l5 + x, np.zeros_like(x), np.full_like(x, machine.l6)], axis=1)
    q2 = q0 - np.array([machine.l7, 0.0, machine.l8])
    Ra = np.transpose(rot_x(a), (0, 2, 1))  # RotX(-a)
    return {"z": z, "q0": q0, "q2": q2, "Ra": Ra, "p": forward(machine, axes),
            "th": rot_z(np.deg2rad(machine.theta1_deg))[0],
            "b": np.array([machine.l3, 0.0, machine.l4 - machine.R])}


def error_jacobian(machine: Grinder, axes) -> np.ndarray:
    """Error-transfer Jacobian ∂(spatial error μm)/∂(element value), shape (n, 3, 23).

    Columns in ELEMENT_NAMES order; translation columns are μm/μm, angle columns μm/μrad.
    Derived from ``E⁻¹·q ≈ q - δ - ε×q``::

        dp = RotX(-a)·[RotZ(θ1)(δ_z + ε_z×b) + (s·z, 0, 0) - δ_x - ε_x×q0 - δ_oa - ε_oa×q2] - δ_a - ε_a×p
    """
    f = nominal_frames(machine, axes)
    n = f["z"].shape[0]
    Ra, th = f["Ra"], f["th"]
    J = np.zeros((n, 3, len(ELEMENT_NAMES)))
    RaTh = Ra @ th
    J[:, :, [IDX[k] for k in ("dx_z", "dy_z", "dz_z")]] = RaTh
    J[:, :, [IDX[k] for k in ("ex_z", "ey_z", "ez_z")]] = -(RaTh @ skew(f["b"])) * (URAD / UM)
    J[:, :, IDX["s_xz"]] = Ra[:, :, 0] * f["z"][:, None] * (URAD / UM)
    J[:, :, [IDX[k] for k in ("dx_x", "dy_x", "dz_x")]] = -Ra
    J[:, :, [IDX[k] for k in ("ex_x", "ey_x", "ez_x")]] = (Ra @ skew(f["q0"])) * (URAD / UM)
    J[:, :, IDX["dy_oa"]] = -Ra[:, :, 1]
    J[:, :, IDX["dz_oa"]] = -Ra[:, :, 2]
    RaQ2 = (Ra @ skew(f["q2"])) * (URAD / UM)
    J[:, :, IDX["ey_oa"]] = RaQ2[:, :, 1]
    J[:, :, IDX["ez_oa"]] = RaQ2[:, :, 2]
    J[:, :, [IDX[k] for k in ("dx_a", "dy_a", "dz_a")]] = -np.eye(3)
    J[:, :, [IDX[k] for k in ("ex_a", "ey_a", "ez_a")]] = skew(f["p"]) * (URAD / UM)
    return J


def spatial_error_exact_chain(machine: Grinder, axes, values, chunk: int = 50_000) -> np.ndarray:
    """The exact spatial error (μm) through the matrix chain :func:`tool_point_actual`;
    shapes as :func:`spatial_error_exact`. The readable reference that the closed form is
    tested against (and the benchmark's baseline); about 5× slower."""
    from .kinematics import forward
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    values = np.asarray(values, dtype=float)
    out = np.empty((axes.shape[0], 3))
    for s in range(0, axes.shape[0], chunk):
        sl = slice(s, s + chunk)
        out[sl] = (tool_point_actual(machine, axes[sl], values[sl]) - forward(machine, axes[sl])) / UM
    return out


@njit(cache=True, nogil=True, inline="always")
def _rot_entries(ex, ey, ez):
    """The 9 entries (row by row) of ``Rot(ε) = RotX(ex)·RotY(ey)·RotZ(ez)`` (rad), written out
    (:func:`rot_xyz` without its matrices)."""
    cx, sx, cy, sy, cz, sz = np.cos(ex), np.sin(ex), np.cos(ey), np.sin(ey), np.cos(ez), np.sin(ez)
    sxsy, cxsy = sx * sy, cx * sy
    return (cy * cz, -cy * sz, sy,
            sxsy * cz + cx * sz, cx * cz - sxsy * sz, -sx * cy,
            sx * sz - cxsy * cz, sx * cz + cxsy * sz, cx * cy)


@njit(cache=True, nogil=True, inline="always")
def _apply_inv(r, v0, v1, v2):
    """``Rᵀ·v`` with ``r`` the 9 entries of :func:`_rot_entries`."""
    return (r[0] * v0 + r[3] * v1 + r[6] * v2, r[1] * v0 + r[4] * v1 + r[7] * v2, r[2] * v0 + r[5] * v1 + r[8] * v2)


@njit(cache=True, nogil=True, inline="always")
def _inv_rot(ex, ey, ez, v0, v1, v2):
    """``Rot(ε)ᵀ·v`` for one point."""
    return _apply_inv(_rot_entries(ex, ey, ez), v0, v1, v2)


@njit(cache=True, nogil=True, inline="always")
def _chain_constants(v, geo):
    """The factors of the chain that no axis moves: ``(cos θ1, sin θ1, sin s_xz, cos s_xz, the 9
    entries of Rot(0, ey_oa, ez_oa))``; computed once per call of a field kernel."""
    th = geo[9]
    s_rad = v[22] * 1e-6
    return (np.cos(th), np.sin(th), np.sin(s_rad), np.cos(s_rad), _rot_entries(0.0, v[20] * 1e-6, v[21] * 1e-6))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _point_error(x, z, a_deg, v, geo):  # pragma: no cover - compiled
    """The chain of :func:`tool_point_actual` minus :func:`kinematics.forward` at one point, μm.

    ``v`` (23,) element values (μm / μrad, ELEMENT_NAMES order: the indices below, checked
    at import by ``_CHECK_IDX``), ``geo`` = (l1, l2, l3, l4, R, l5, l6, l7, l8, θ1 rad).
    """
    return _point_error_c(x, z, a_deg, v, geo, _chain_constants(v, geo))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _point_error_c(x, z, a_deg, v, geo, cc):  # pragma: no cover - compiled
    """:func:`_point_error` with its point-independent factors ``cc`` (:func:`_chain_constants`)
    given: the same operations on the same values, so the same result bit for bit."""
    l1, l2, l3, l4, R, l5, l6, l7, l8 = geo[0], geo[1], geo[2], geo[3], geo[4], geo[5], geo[6], geo[7], geo[8]
    ct, st, sin_s, cos_s, r_oa = cc
    a = a_deg * (np.pi / 180.0)
    # tool chain after RotZ(θ1): (l2, 0, l1) + RotZ(-θ1)·z·(sin s, 0, cos s) + δ_z + Rot(ε_z)·b, b = (l3, 0, l4 - R)
    b0, b2 = l3, l4 - R
    zs = z * sin_s
    ex, ey, ez = v[9] * 1e-6, v[10] * 1e-6, v[11] * 1e-6
    cx, sx, cy, sy, cz, sz = np.cos(ex), np.sin(ex), np.cos(ey), np.sin(ey), np.cos(ez), np.sin(ez)
    rb0 = cy * cz * b0 + sy * b2
    rb1 = (sx * sy * cz + cx * sz) * b0 - sx * cy * b2
    rb2 = (sx * sz - cx * sy * cz) * b0 + cx * cy * b2
    lx = l2 + ct * zs + v[6] * 1e-3 + rb0
    ly = -st * zs + v[7] * 1e-3 + rb1
    lz = l1 + z * cos_s + v[8] * 1e-3 + rb2
    # tool point in the MCS, then the work chain inverted: X carriage, A line, RotX(a), A body
    q0 = (ct * lx - st * ly) - (l5 + x) - v[0] * 1e-3
    q1 = (st * lx + ct * ly) - v[1] * 1e-3
    q2 = lz - l6 - v[2] * 1e-3
    q0, q1, q2 = _inv_rot(v[3] * 1e-6, v[4] * 1e-6, v[5] * 1e-6, q0, q1, q2)
    q0, q1, q2 = _apply_inv(r_oa, q0 - l7, q1 - v[18] * 1e-3, q2 - l8 - v[19] * 1e-3)
    ca, sa = np.cos(a), np.sin(a)
    q1, q2 = ca * q1 + sa * q2, ca * q2 - sa * q1
    q0, q1, q2 = _inv_rot(v[15] * 1e-6, v[16] * 1e-6, v[17] * 1e-6, q0 - v[12] * 1e-3, q1 - v[13] * 1e-3, q2 - v[14] * 1e-3)
    # minus the nominal tool point (kinematics.forward), in μm
    n0 = l2 + l3
    tx, ty = ct * n0, st * n0
    h = l1 + l4 - R + z - l6 - l8
    return (q0 - (tx - l5 - x - l7)) * 1e3, (q1 - (ca * ty + sa * h)) * 1e3, (q2 - (ca * h - sa * ty)) * 1e3


@njit(cache=True, nogil=True, error_model="numpy")
def _spatial_error_kernel(axes, v, geo, out):  # pragma: no cover - compiled
    """:func:`_point_error` over points: ``axes`` (n, 3), ``v`` (n, 23), ``out`` (n, 3) μm."""
    for k in range(axes.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = _point_error(axes[k, 0], axes[k, 1], axes[k, 2], v[k], geo)


@njit(cache=True, nogil=True)
def _knot_interval(t, x, k):  # pragma: no cover - compiled
    """The index ``i`` with ``t[i] ≤ x < t[i+1]`` as scipy finds it, clipped to the end intervals
    (points beyond them extrapolate the end polynomials)."""
    nc = t.shape[0] - k - 1
    i = np.searchsorted(t, x, side="right") - 1
    if i < k:
        i = k
    elif i > nc - 1:
        i = nc - 1
    return i


@njit(cache=True, nogil=True, error_model="numpy")
def _raise_degree(t, x, i, j, h, hh):  # pragma: no cover - compiled
    """One Cox–de Boor step (scipy's ``_deBoor_D``): ``h[0:j]`` the degree ``j - 1`` basis values
    of interval ``i`` at ``x`` → ``h[0:j + 1]`` those of degree ``j``; ``hh`` a work array."""
    for m in range(j):
        hh[m] = h[m]
    h[0] = 0.0
    for n in range(1, j + 1):
        xb = t[i + n]
        xa = t[i + n - j]
        if xb == xa:
            h[n] = 0.0
            continue
        w = hh[n - 1] / (xb - xa)
        h[n - 1] += w * (xb - x)
        h[n] = w * (x - xa)


@njit(cache=True, nogil=True, error_model="numpy")
def _combine(h, c, i, k, v, j0):  # pragma: no cover - compiled
    """``v[j0 + col] = Σ_m h[m] c[i - k + m, col]``: the spline's values from its basis values."""
    for col in range(c.shape[1]):
        acc = 0.0
        for m in range(k + 1):
            acc += h[m] * c[i - k + m, col]
        v[j0 + col] = acc


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bspline3(t, c, x, h, hh, v, j0):  # pragma: no cover - compiled
    """A cubic B-spline with vector coefficients ``c`` (m, 6) at ``x`` into ``v[j0:j0 + 6]``.

    The interval is found as scipy does (:func:`_knot_interval`) and the 4 non-zero basis values
    by the Cox–de Boor recursion (:func:`_raise_degree`); ``h``, ``hh`` are work arrays (4,).
    """
    k = 3
    i = _knot_interval(t, x, k)
    h[0] = 1.0
    for j in range(1, k + 1):
        _raise_degree(t, x, i, j, h, hh)
    _combine(h, c, i, k, v, j0)


@njit(cache=True, nogil=True, error_model="numpy")
def _field_kernel(axes, tx, cx, tz, cz, ta, ca, consts, a0, geo, out):  # pragma: no cover - compiled
    """The exact HTM field point by point: the 18 function elements from the per-axis splines
    (knots ``t*``, coefficients ``c*`` (m, 6); A folded into ``[a0, a0 + 360)`` for its spline
    only), the 5 constants, then :func:`_point_error`. ``out`` (n, 3) μm."""
    v = np.empty(23)
    h = np.empty(4)
    hh = np.empty(4)
    for j in range(5):
        v[18 + j] = consts[j]
    cc = _chain_constants(v, geo)
    for k in range(axes.shape[0]):
        x, z, a = axes[k, 0], axes[k, 1], axes[k, 2]
        _bspline3(tx, cx, x, h, hh, v, 0)
        _bspline3(tz, cz, z, h, hh, v, 6)
        _bspline3(ta, ca, a0 + np.mod(a - a0, 360.0), h, hh, v, 12)
        out[k, 0], out[k, 1], out[k, 2] = _point_error_c(x, z, a, v, geo, cc)


# -- the Jacobian dE/d(axes) in closed form: forward-mode differentiation written out ----------
# A "dual" is a tuple (value, d/dx_mm, d/dz_mm, d/da_deg): every quantity of the chain carries its
# derivatives along the three axes, and each operation applies the chain rule exactly (no step
# size, no truncation): the same closed form as :func:`_point_error`, differentiated term by term.

@njit(cache=True, nogil=True)
def _dadd(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3])


@njit(cache=True, nogil=True)
def _dsub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3])


@njit(cache=True, nogil=True)
def _dmul(a, b):
    return (a[0] * b[0], a[1] * b[0] + a[0] * b[1], a[2] * b[0] + a[0] * b[2], a[3] * b[0] + a[0] * b[3])


@njit(cache=True, nogil=True)
def _dscale(a, k):
    return (a[0] * k, a[1] * k, a[2] * k, a[3] * k)


@njit(cache=True, nogil=True)
def _dshift(a, k):
    return (a[0] + k, a[1], a[2], a[3])


@njit(cache=True, nogil=True)
def _dcos_sin(a):
    c, s = np.cos(a[0]), np.sin(a[0])
    return (c, -s * a[1], -s * a[2], -s * a[3]), (s, c * a[1], c * a[2], c * a[3])


@njit(cache=True, nogil=True)
def _inv_rot_dual(ex, ey, ez, v0, v1, v2):
    """:func:`_inv_rot` on duals (angles and vector)."""
    cx, sx = _dcos_sin(ex)
    cy, sy = _dcos_sin(ey)
    cz, sz = _dcos_sin(ez)
    sxsy, cxsy = _dmul(sx, sy), _dmul(cx, sy)
    r00, r01, r02 = _dmul(cy, cz), _dscale(_dmul(cy, sz), -1.0), sy
    r10, r11, r12 = _dadd(_dmul(sxsy, cz), _dmul(cx, sz)), _dsub(_dmul(cx, cz), _dmul(sxsy, sz)), _dscale(_dmul(sx, cy), -1.0)
    r20, r21, r22 = _dsub(_dmul(sx, sz), _dmul(cxsy, cz)), _dadd(_dmul(sx, cz), _dmul(cxsy, sz)), _dmul(cx, cy)
    return (_dadd(_dadd(_dmul(r00, v0), _dmul(r10, v1)), _dmul(r20, v2)),
            _dadd(_dadd(_dmul(r01, v0), _dmul(r11, v1)), _dmul(r21, v2)),
            _dadd(_dadd(_dmul(r02, v0), _dmul(r12, v1)), _dmul(r22, v2)))


@njit(cache=True, nogil=True)
def _el(v, dv, j, axis, k):
    """Element ``j`` as a dual scaled by ``k``: its value and its spline slope along its own axis."""
    g = dv[j] * k
    return (v[j] * k, g if axis == 0 else 0.0, g if axis == 1 else 0.0, g if axis == 2 else 0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def _point_error_dual(x, z, a_deg, v, dv, geo, cc):  # pragma: no cover - compiled
    """:func:`_point_error_c` with its derivatives: returns three duals (μm, μm per mm/mm/deg).

    ``dv`` (18,): d(element)/d(own axis) of the 18 function elements (per mm, per deg);
    ``cc``: :func:`_chain_constants` (no axis moves them: derivatives zero)."""
    l1, l2, l3, l4, R, l5, l6, l7, l8 = geo[0], geo[1], geo[2], geo[3], geo[4], geo[5], geo[6], geo[7], geo[8]
    ct, st, sin_s, cos_s, r = cc
    X = (x, 1.0, 0.0, 0.0)
    Z = (z, 0.0, 1.0, 0.0)
    A = (a_deg * (np.pi / 180.0), 0.0, 0.0, np.pi / 180.0)
    b0, b2 = l3, l4 - R
    zs = _dscale(Z, sin_s)
    ex, ey, ez = _el(v, dv, 9, 1, 1e-6), _el(v, dv, 10, 1, 1e-6), _el(v, dv, 11, 1, 1e-6)
    cx, sx = _dcos_sin(ex)
    cy, sy = _dcos_sin(ey)
    cz, sz = _dcos_sin(ez)
    rb0 = _dadd(_dscale(_dmul(cy, cz), b0), _dscale(sy, b2))
    rb1 = _dsub(_dscale(_dadd(_dmul(_dmul(sx, sy), cz), _dmul(cx, sz)), b0), _dscale(_dmul(sx, cy), b2))
    rb2 = _dadd(_dscale(_dsub(_dmul(sx, sz), _dmul(_dmul(cx, sy), cz)), b0), _dscale(_dmul(cx, cy), b2))
    lx = _dadd(_dadd(_dshift(_dscale(zs, ct), l2), _el(v, dv, 6, 1, 1e-3)), rb0)
    ly = _dadd(_dadd(_dscale(zs, -st), _el(v, dv, 7, 1, 1e-3)), rb1)
    lz = _dadd(_dadd(_dshift(_dscale(Z, cos_s), l1), _el(v, dv, 8, 1, 1e-3)), rb2)
    q0 = _dsub(_dsub(_dsub(_dscale(lx, ct), _dscale(ly, st)), _dshift(X, l5)), _el(v, dv, 0, 0, 1e-3))
    q1 = _dsub(_dadd(_dscale(lx, st), _dscale(ly, ct)), _el(v, dv, 1, 0, 1e-3))
    q2 = _dsub(_dshift(lz, -l6), _el(v, dv, 2, 0, 1e-3))
    q0, q1, q2 = _inv_rot_dual(_el(v, dv, 3, 0, 1e-6), _el(v, dv, 4, 0, 1e-6), _el(v, dv, 5, 0, 1e-6), q0, q1, q2)
    q0, q1, q2 = _dshift(q0, -l7), _dshift(q1, -v[18] * 1e-3), _dshift(q2, -l8 - v[19] * 1e-3)
    q0, q1, q2 = (_dadd(_dadd(_dscale(q0, r[0]), _dscale(q1, r[3])), _dscale(q2, r[6])),  # Rot(0, ey_oa, ez_oa)ᵀ·q
                  _dadd(_dadd(_dscale(q0, r[1]), _dscale(q1, r[4])), _dscale(q2, r[7])),
                  _dadd(_dadd(_dscale(q0, r[2]), _dscale(q1, r[5])), _dscale(q2, r[8])))
    ca, sa = _dcos_sin(A)
    q1, q2 = _dadd(_dmul(ca, q1), _dmul(sa, q2)), _dsub(_dmul(ca, q2), _dmul(sa, q1))
    q0, q1, q2 = _inv_rot_dual(_el(v, dv, 15, 2, 1e-6), _el(v, dv, 16, 2, 1e-6), _el(v, dv, 17, 2, 1e-6),
                               _dsub(q0, _el(v, dv, 12, 2, 1e-3)), _dsub(q1, _el(v, dv, 13, 2, 1e-3)),
                               _dsub(q2, _el(v, dv, 14, 2, 1e-3)))
    # minus the nominal tool point (kinematics.forward), in μm
    n0 = l2 + l3
    tx, ty = ct * n0, st * n0
    H = _dshift(Z, l1 + l4 - R - l6 - l8)
    e0 = _dscale(_dsub(q0, _dscale(_dshift(X, -(tx - l5 - l7)), -1.0)), 1e3)
    e1 = _dscale(_dsub(q1, _dadd(_dscale(ca, ty), _dmul(sa, H))), 1e3)
    e2 = _dscale(_dsub(q2, _dsub(_dmul(ca, H), _dscale(sa, ty))), 1e3)
    return e0, e1, e2


@njit(cache=True, nogil=True, error_model="numpy")
def _bspline3_d(t, c, x, h, hh, v, dv, j0):  # pragma: no cover - compiled
    """:func:`_bspline3` and its slope: values into ``v[j0:j0 + 6]``, d/dx into ``dv[j0:j0 + 6]``.

    The slope from the degree-2 basis of the same interval (``s' = Σ 3·(c_j - c_{j-1}) /
    (t_{j+3} - t_j)·N_{j,2}``, the derivative of a B-spline written in B-splines)."""
    k = 3
    i = _knot_interval(t, x, k)
    h[0] = 1.0
    for j in range(1, k + 1):
        if j == k:  # h[0:3] = N_{i-2..i, 2}(x): the slope's basis
            for col in range(c.shape[1]):
                acc = 0.0
                for m in range(k):
                    jj = i - 2 + m
                    den = t[jj + k] - t[jj]
                    if den != 0.0:
                        acc += h[m] * k * (c[jj, col] - c[jj - 1, col]) / den
                dv[j0 + col] = acc
        _raise_degree(t, x, i, j, h, hh)
    _combine(h, c, i, k, v, j0)


@njit(cache=True, nogil=True, error_model="numpy")
def _field_jac_kernel(axes, tx, cx, tz, cz, ta, ca, consts, a0, geo, out, jac):  # pragma: no cover - compiled
    """:func:`_field_kernel` with the Jacobian: ``out`` (n, 3) μm, ``jac`` (n, 3, 3) μm per (mm, mm, deg)."""
    v = np.empty(23)
    dv = np.empty(18)
    h = np.empty(4)
    hh = np.empty(4)
    for j in range(5):
        v[18 + j] = consts[j]
    cc = _chain_constants(v, geo)
    for k in range(axes.shape[0]):
        x, z, a = axes[k, 0], axes[k, 1], axes[k, 2]
        _bspline3_d(tx, cx, x, h, hh, v, dv, 0)
        _bspline3_d(tz, cz, z, h, hh, v, dv, 6)
        _bspline3_d(ta, ca, a0 + np.mod(a - a0, 360.0), h, hh, v, dv, 12)
        e0, e1, e2 = _point_error_dual(x, z, a, v, dv, geo, cc)
        out[k, 0], out[k, 1], out[k, 2] = e0[0], e1[0], e2[0]
        jac[k, 0, 0], jac[k, 0, 1], jac[k, 0, 2] = e0[1], e0[2], e0[3]
        jac[k, 1, 0], jac[k, 1, 1], jac[k, 1, 2] = e1[1], e1[2], e1[3]
        jac[k, 2, 0], jac[k, 2, 1], jac[k, 2, 2] = e2[1], e2[2], e2[3]


_CHECK_IDX = ("dx_x", "dy_x", "dz_x", "ex_x", "ey_x", "ez_x", "dx_z", "dy_z", "dz_z", "ex_z", "ey_z", "ez_z",
              "dx_a", "dy_a", "dz_a", "ex_a", "ey_a", "ez_a", "dy_oa", "dz_oa", "ey_oa", "ez_oa", "s_xz")
assert tuple(ELEMENT_NAMES) == _CHECK_IDX, "the kernel's column indices follow ELEMENT_NAMES"


def spatial_error_exact(machine: Grinder, axes, values, chunk: int = 50_000) -> np.ndarray:
    """Spatial error (μm) with exact transforms; ``values`` shape (n, 23) -> (n, 3).

    The transform chain of :func:`tool_point_actual` in closed form, compiled (numba) and
    evaluated point by point: every rotation written out entry by entry, float64 throughout,
    no small-angle step — the same exact transforms, equal to :func:`spatial_error_exact_chain`
    to round-off (tested), with no (n, 3, 3) temporaries. ``chunk`` is kept for the API
    (the kernel allocates nothing per point).
    """
    axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
    values = np.ascontiguousarray(values, dtype=float)
    if values.shape != (axes.shape[0], len(ELEMENT_NAMES)):
        raise ValueError(f"Expected element values of shape ({axes.shape[0]}, {len(ELEMENT_NAMES)}), got {values.shape}")
    out = np.empty((axes.shape[0], 3))
    _spatial_error_kernel(np.ascontiguousarray(axes), values, _geometry(machine), out)
    return out


def _geometry(machine: Grinder) -> np.ndarray:
    """The kernel's machine constants (l1, l2, l3, l4, R, l5, l6, l7, l8 mm, θ1 rad), shape (10,)."""
    return np.array([machine.l1, machine.l2, machine.l3, machine.l4, machine.R, machine.l5, machine.l6,
                     machine.l7, machine.l8, np.deg2rad(machine.theta1_deg)])


def spatial_error_first_order(machine: Grinder, axes, values) -> np.ndarray:
    """Spatial error (μm) in the first-order form ``J · v``; shapes as the exact form."""
    return np.einsum("nij,nj->ni", error_jacobian(machine, axes), np.asarray(values, dtype=float))


class HTMField:
    """The 23-element homogeneous-transform model as an error field (:class:`errormap.field.ErrorField`).

    ``predict(axes)`` maps axes (x_mm, z_mm, a_deg), shape (n, 3), to the spatial
    error (dx_um, dy_um, dz_um), shape (n, 3). ``exact=False`` uses the first-order form.
    Calibrated volume: the range of the element set's stations per axis. The exact form
    declares ``jacobian`` and ``predict_and_jacobian`` (closed form, :func:`_point_error_dual`);
    the first-order form declares nothing.
    """

    kind = "htm"

    def __init__(self, machine: Grinder, elements: ElementSet, exact: bool = True, chunk: int = 50_000):
        self.machine = machine
        self.elements = elements
        self.exact = exact
        self.chunk = chunk

    @property
    def capabilities(self) -> frozenset:
        """``{jacobian, predict_and_jacobian}`` for the exact form, none for the first-order form."""
        return frozenset({JACOBIAN, PREDICT_AND_JACOBIAN}) if self.exact else frozenset()

    @property
    def calibrated_volume(self) -> CalibratedVolume:
        """Where the elements were measured: per axis, the smallest to the largest station."""
        return CalibratedVolume.from_stations(self.elements.stations)

    def element_values(self, axes) -> np.ndarray:
        """The 23 element values at ``axes``, shape (n, 23)."""
        return self.elements.values(check_points(axes, "axes (x_mm, z_mm, a_deg)"))

    def _kernel_args(self):
        """The compiled kernels' spline and machine arguments (knots, coefficients (m, 6) per axis,
        the 5 constants, A's first station, the geometry)."""
        el = self.elements
        sx, sz, sa = (el._axis_spline(k) for k in ("x_mm", "z_mm", "a_deg"))
        consts = np.array([el.constants[k] for k in CONSTANT_ELEMENTS])
        return (sx.t, np.ascontiguousarray(sx.c), sz.t, np.ascontiguousarray(sz.c), sa.t, np.ascontiguousarray(sa.c),
                consts, float(el.stations["a_deg"][0]), _geometry(self.machine))

    def predict(self, axes) -> np.ndarray:
        """Spatial error (μm), shape (n, 3), at axes shape (n, 3).

        Exact: one compiled pass per point (the 18 function elements from the element set's
        per-axis vector splines, then the closed-form chain :func:`_point_error`), no (n, 23)
        or (n, 3, 3) arrays; equal to the element values pushed through
        :func:`spatial_error_exact_chain` to round-off (tested).
        """
        axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
        out = np.empty((axes.shape[0], 3))
        if self.exact:
            _field_kernel(np.ascontiguousarray(axes), *self._kernel_args(), out)
            return out
        for s in range(0, axes.shape[0], self.chunk):
            sl = slice(s, s + self.chunk)
            out[sl] = spatial_error_first_order(self.machine, axes[sl], self.elements.values(axes[sl]))
        return out

    __call__ = predict

    def predict_and_jacobian(self, axes, dtype=np.float64):
        """``(E (n, 3) μm, dE/d(axes) (n, 3, 3))`` in one compiled pass (exact form only).

        Rows of the Jacobian are the error components, columns μm per mm, μm per mm, μm per
        deg. Closed form: the spline slopes (:func:`_bspline3_d`) pushed through the chain
        differentiated term by term (:func:`_point_error_dual`), float64; the values equal
        :meth:`predict`'s to round-off, the Jacobian matches finite differences (tested).
        Float64 only (the field declares no ``float32``).
        """
        if not self.exact:
            raise TypeError("HTMField(exact=False) has no Jacobian (it declares no capabilities)")
        if np.dtype(dtype) != np.float64:
            raise ValueError(f"Expected dtype float64 (HTMField declares no float32), got {np.dtype(dtype)}")
        axes = check_points(axes, "axes (x_mm, z_mm, a_deg)")
        out = np.empty((axes.shape[0], 3))
        jac = np.empty((axes.shape[0], 3, 3))
        _field_jac_kernel(np.ascontiguousarray(axes), *self._kernel_args(), out, jac)
        return out, jac

    def jacobian(self, axes) -> np.ndarray:
        """dE/d(axes), shape (n, 3, 3) (:meth:`predict_and_jacobian`)."""
        return self.predict_and_jacobian(axes)[1]
