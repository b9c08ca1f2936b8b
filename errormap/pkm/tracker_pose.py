"""Pose of a (mobile) PKM measured with a laser tracker (mobile-pkm-pose paper).

* **Reference frame by origin translation**: the origin is the mean of repeated measurements of the
  reference point R with the head at the reference point O; ``x`` is the direction of a line fitted
  to points measured during an X move; ``n`` that of a Y move; ``z = x × n``, ``y = z × x``.
* **Head-centre offset by rotation fitting**: the head rotates about X and then about Y through the
  head centre S; the reference point R traces two circles. Each circle's axis (through its centre,
  along its plane normal) passes through S in theory; with errors the two axes are skew, and S is
  the midpoint of their common perpendicular. The offset ``SR = R - S`` expressed in the machine
  axes is repeated N times and the mean of the distribution is the estimate (the paper: 400 times,
  SR = [189.124, -74.836, 281.648] mm).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import svd
from scipy.spatial.transform import Rotation


def fit_line(points_mm: np.ndarray):
    """Least-squares 3-D line: ``(point (3,), unit direction (3,))``, the direction pointing along the sequence."""
    p = np.asarray(points_mm, float)
    c = p.mean(0)
    d = svd(p - c, full_matrices=False)[2][0]
    if (p[-1] - p[0]) @ d < 0:
        d = -d
    return c, d


def fit_circle_3d(points_mm: np.ndarray):
    """Circle through points (n, 3): plane by SVD, then the algebraic (Kasa) circle fit in the plane.

    Returns ``(centre (3,), unit normal (3,), radius)``.
    """
    p = np.asarray(points_mm, float)
    c0 = p.mean(0)
    _, _, Vt = svd(p - c0, full_matrices=False)
    e1, e2, nrm = Vt
    uv = np.stack([(p - c0) @ e1, (p - c0) @ e2], 1)
    A = np.c_[2 * uv, np.ones(len(p))]
    sol = np.linalg.lstsq(A, (uv ** 2).sum(1), rcond=None)[0]
    centre = c0 + sol[0] * e1 + sol[1] * e2
    radius = float(np.sqrt(sol[2] + sol[0] ** 2 + sol[1] ** 2))
    return centre, nrm, radius


def common_perpendicular_midpoint(p1, d1, p2, d2) -> np.ndarray:
    """Midpoint of the common perpendicular of lines ``p1 + s d1`` and ``p2 + t d2``, shape (3,)."""
    d1, d2 = np.asarray(d1, float), np.asarray(d2, float)
    w = np.asarray(p1, float) - np.asarray(p2, float)
    a, b, c, d, e = d1 @ d1, d1 @ d2, d2 @ d2, d1 @ w, d2 @ w
    den = a * c - b * b
    if abs(den) < 1e-12:
        raise ValueError("the circle axes are parallel: no unique common perpendicular")
    s = (b * e - c * d) / den
    t = (a * e - b * d) / den
    return 0.5 * ((p1 + s * d1) + (p2 + t * d2))


def reference_frame(origin_points_mm, x_move_points_mm, y_move_points_mm):
    """Machine reference frame in the tracker frame: ``(origin (3,), machine2tracker (3, 3))``."""
    o = np.asarray(origin_points_mm, float).mean(0)
    _, x = fit_line(x_move_points_mm)
    _, n = fit_line(y_move_points_mm)
    z = np.cross(x, n)
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    return o, np.stack([x, y, z], 1)


def head_offset_from_circles(circle_x_mm, circle_y_mm, r_point_mm, machine2tracker) -> np.ndarray:
    """``SR = R - S`` in machine axes from the two rotation circles (tracker frame points), shape (3,)."""
    c1, n1, _ = fit_circle_3d(circle_x_mm)
    c2, n2, _ = fit_circle_3d(circle_y_mm)
    S = common_perpendicular_midpoint(c1, n1, c2, n2)
    return np.asarray(machine2tracker).T @ (np.asarray(r_point_mm) - S)


@dataclass
class RotationFitResult:
    """``x``: the estimate of SR (mean of the repeats), shape (3,); ``estimates`` (N, 3); ``std_mm`` (3,);
    ``success``, ``message``, ``nfev`` (repeats)."""

    x: np.ndarray
    estimates: np.ndarray
    std_mm: np.ndarray
    success: bool
    message: str
    nfev: int


class TrackerSimulator:
    """Simulated tracker measurements of the mobile PKM's head (noise ``noise_um`` per axis, isotropic).

    ``sr_mm``: true offset SR (machine axes); ``reference_point_mm``: O in machine coordinates
    (the paper: (0, 0, 410)); the machine frame sits in the tracker frame at ``machine_origin_mm`` with
    rotation ``machine2tracker``.
    """

    def __init__(self, sr_mm=(189.124, -74.836, 281.648), reference_point_mm=(0.0, 0.0, 410.0),
                 machine_origin_mm=(2500.0, -800.0, 300.0), machine2tracker=None, noise_um: float = 10.0,
                 n_circle: int = 19, sweep_deg: float = 30.0, n_line: int = 11, line_mm: float = 200.0,
                 n_origin: int = 10):
        self.sr = np.asarray(sr_mm, float)
        self.o_ref = np.asarray(reference_point_mm, float)
        self.origin = np.asarray(machine_origin_mm, float)
        self.R = Rotation.from_euler("xyz", [1.0, -2.0, 35.0], degrees=True).as_matrix() \
            if machine2tracker is None else np.asarray(machine2tracker)
        self.noise = noise_um * 1e-3
        self.n_circle, self.sweep, self.n_line, self.line, self.n_origin = n_circle, sweep_deg, n_line, line_mm, n_origin

    def _to_tracker(self, p_machine):
        return p_machine @ self.R.T + self.origin

    def measure(self, rng):
        """One measurement campaign: dict of tracker-frame point sets (origin, x_move, y_move, circle_x, circle_y, r_point)."""
        S = self.o_ref
        noisy = lambda p: self._to_tracker(p) + rng.normal(0, self.noise, p.shape)
        Rpt = S + self.sr
        ang = np.radians(np.linspace(-self.sweep, self.sweep, self.n_circle))
        cx = S + Rotation.from_rotvec(ang[:, None] * [1, 0, 0]).apply(self.sr)
        cy = S + Rotation.from_rotvec(ang[:, None] * [0, 1, 0]).apply(self.sr)
        s = np.linspace(-self.line / 2, self.line / 2, self.n_line)
        xm = Rpt + s[:, None] * [1, 0, 0]
        ym = Rpt + s[:, None] * [0, 1, 0]
        return {"origin": noisy(np.broadcast_to(Rpt, (self.n_origin, 3)).copy()), "x_move": noisy(xm),
                "y_move": noisy(ym), "circle_x": noisy(cx), "circle_y": noisy(cy)}


def estimate_head_offset(simulator: TrackerSimulator, n_repeats: int, seed) -> RotationFitResult:
    """Repeat the rotation-fitting calibration ``n_repeats`` times; the estimate is the mean."""
    if n_repeats < 1:
        raise ValueError("n_repeats must be >= 1")
    rng = np.random.default_rng(seed)
    est = np.empty((n_repeats, 3))
    for i in range(n_repeats):  # one campaign per repeat (each is a small fit)
        m = simulator.measure(rng)
        o, R = reference_frame(m["origin"], m["x_move"], m["y_move"])
        est[i] = head_offset_from_circles(m["circle_x"], m["circle_y"], o, R)
    return RotationFitResult(est.mean(0), est, est.std(0, ddof=1) if n_repeats > 1 else np.zeros(3), True,
                             f"mean of {n_repeats} rotation fits", n_repeats)
