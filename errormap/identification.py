"""Identification of the grinder's 23 error elements from laser-tracker sweeps.

The method is the grinder paper's (section 2.1), made exact and gauge-consistent; the
full derivation, what is observable and what is a gauge choice: ``docs/identification.md``.

1. **Checks first** (cheap, before any fitting): all three axes present, every station
   with its three targets, A stations spanning one turn, no coincident or collinear
   balls (machine-file mounts and every measured station), ball distances matching the
   nominal mounts, measured travel / rotation matching the commands (these catch mixed
   units), each naming the axis and station.
2. **Reference frame per axis**: X and Z: a least-squares line (SVD) through the
   triangles' centroids is the reference x direction (oriented with increasing command);
   A: a least-squares plane + circle per ball, the mean of the three axes is the
   reference x. The reference y passes through ball 1's initial position, perpendicular
   to x; the moving frame starts equal to the reference frame.
3. **Six errors per station**: the three ball displacements give 9 equations in the
   body's 3 translations + 3 small rotations (rank 6 when the balls are not collinear);
   solved by least squares (SVD) and re-linearised about the current estimate until the
   update is below ``tol`` (so the result is the exact rigid motion, not first order).
   The conditioning of each station's 9×6 system (δ in μm, ε in μrad) and the residual
   are reported.
4. **Assembly in one machine frame**: each station's rigid motion maps the body's
   initial pose (from the nominal mounts, SVD) to its pose at the station; all bodies are
   then expressed in one estimated machine frame ``machine_in_tracker`` and the element
   transforms are peeled off the chains of :mod:`errormap.htm` exactly:
   ``E_x = N_x⁻¹·G⁻¹·T_X``, ``E_z = N_z(s)⁻¹·G⁻¹·T_Z``, ``E_oa·Rot(a)·E_a = (T_X(x0)·Trans(l7,0,l8))⁻¹·G⁻¹·T_A``,
   ``Rot(a)`` the rotary joint of the machine's chain file (its axis and direction, :func:`rotary_line`;
   RotX(a) on the grinder), ``E_oa`` its location slots (the chain's ETs between the carriage and the
   joint: δ and ε across the rotary axis).
   Squareness ``s_xz = asin(u_X·u_Z)`` from the fitted X and Z lines (the paper); the
   A-axis line ``E_oa`` from the rotary body's initial state (the paper), the rest of the
   initial state (its axial and roll parts, zero on a machine the model describes) stays
   in ``E_a``. Each element is then a cubic B-spline through its stations
   (:class:`errormap.elements.ElementSet`).

Gauges (``gauge=``): ``"first-station"`` (the estimator's default) puts the machine frame on the X
carriage at its first station, so every axis-motion element is zero at its first station,
as :class:`~errormap.elements.ElementSet` documents; ``"reference-line"`` puts it on the
fitted X line (x) and the X-Z plane (z), the paper's reference frame, so the X
straightness has no linear trend. Both give the same tool-point error: a rigid change of
the machine frame moves constants and linear trends between elements, and the tool point
in the WCS is invariant under a rotation seen by both chains. The squareness is not
observable apart from a linear trend of the Z straightness along the MCS x direction:
:func:`move_squareness` moves it exactly. ``"station-mean"`` (the default of the smoothed
identification, :func:`errormap.uncertainty.smooth_identify`) starts from the first-station
result and moves, exactly, the machine frame to the mean pose of the X carriage over all its
stations (:func:`frame_to_station_mean`) and the A-axis line to its mean over the turn
(:func:`a_line_to_turn_mean`): both are then averages of 21 (20) stations instead of one
station's tracker noise, which a smoother cannot remove (it is a constant or a linear trend).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .elements import A_ELEMENTS, CONSTANT_ELEMENTS, ElementSet, X_ELEMENTS, Z_ELEMENTS
from .htm import UM, URAD
from .io import InputError
from .machine import Grinder
from .sweeps import (SWEEP_AXES, Sweeps, a_line_offset, compose, error_transform, invert, read_sweeps,
                     sweeps_from_columns, x_carriage_nominal, z_carriage_nominal)
from .transforms import apply, rot_x, rot_y, rot_z, skew

GAUGES = ("first-station", "reference-line", "station-mean")


# -- geometric fits ----------------------------------------------------------------------------
def rigid_fit(src, dst):
    """Least-squares rigid transform (SVD, Kabsch) with ``R·src + t ≈ dst``.

    ``src`` shape (k, 3) or (n, k, 3), ``dst`` shape (n, k, 3) -> (R (n,3,3), t (n,3)).
    """
    dst = np.asarray(dst, dtype=float)
    src = np.broadcast_to(np.asarray(src, dtype=float), dst.shape)
    cs, cd = src.mean(axis=-2), dst.mean(axis=-2)
    H = np.einsum("nki,nkj->nij", src - cs[:, None], dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    return R, cd - apply(R, cs)


def fit_line(points):
    """Least-squares line through points (m, 3): ``(point (3,), unit direction (3,))`` (SVD)."""
    p = np.asarray(points, dtype=float)
    c = p.mean(axis=0)
    _, _, Vt = np.linalg.svd(p - c)
    return c, Vt[0]


def fit_plane(points):
    """Least-squares plane through points (m, 3): ``(centroid (3,), unit normal (3,))`` (SVD)."""
    p = np.asarray(points, dtype=float)
    c = p.mean(axis=0)
    _, _, Vt = np.linalg.svd(p - c)
    return c, Vt[2]


def fit_circle(points):
    """Least-squares circle through points (m, 3) in 3-D: plane fit (SVD), then the
    algebraic circle fit in the plane (``numpy.linalg.lstsq``).

    Returns ``(centre (3,), unit normal (3,), radius, rms residual)`` (mm); the normal is
    oriented so that the points run counter-clockwise about it.
    """
    p = np.asarray(points, dtype=float)
    c, n = fit_plane(p)
    _, _, Vt = np.linalg.svd(p - c)
    e1, e2 = Vt[0], Vt[1]
    u, v = (p - c) @ e1, (p - c) @ e2
    A = np.stack([2 * u, 2 * v, np.ones_like(u)], axis=1)
    (a, b, k), *_ = np.linalg.lstsq(A, u**2 + v**2, rcond=None)
    r = np.sqrt(k + a**2 + b**2)
    centre = c + a * e1 + b * e2
    ang = np.unwrap(np.arctan2(v - b, u - a))
    normal = np.cross(e1, e2) * (1.0 if ang[-1] >= ang[0] else -1.0)
    dist = np.hypot(u - a, v - b) - r
    return centre, normal, float(r), float(np.sqrt(np.mean(dist**2 + ((p - c) @ n) ** 2)))


def layout_problem(points_mm, min_separation_mm: float = 1.0):
    """``None`` if three ball centres (3, 3) form a usable triangle, else why not (a string)."""
    p = np.asarray(points_mm, dtype=float)
    pairs = ((0, 1), (0, 2), (1, 2))
    dist = [np.linalg.norm(p[i] - p[j]) for i, j in pairs]
    for (i, j), d in zip(pairs, dist):
        if d < min_separation_mm:
            return f"targets {i + 1} and {j + 1} coincide ({d:.3g} mm apart)"
    height = np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0])) / max(dist)
    if height < min_separation_mm:
        return (f"targets are collinear (triangle height {height:.3g} mm); the rotation about their line "
                "cannot be observed")
    return None


def _check_length_unit(sw, ax: str, mounts) -> None:
    """Refuse (InputError naming the file, the axis and the columns) sweeps whose ball distances are
    a unit factor off the nominal mounts' (metres, centimetres, inches, μm written as mm): the median
    measured/nominal distance ratio outside :data:`errormap.units.LENGTH_RATIO_BAND`, with a unit named."""
    from .units import LENGTH_RATIO_BAND, length_unit_guess
    b = np.asarray(sw.balls_mm, dtype=float)
    pairs = ((0, 1), (0, 2), (1, 2))
    nominal = np.array([np.linalg.norm(np.asarray(mounts[i]) - np.asarray(mounts[j])) for i, j in pairs])
    measured = np.stack([np.linalg.norm(b[:, i] - b[:, j], axis=1) for i, j in pairs], axis=1)
    ratio = float(np.median(measured / nominal))
    guess = length_unit_guess(ratio)
    if guess and not LENGTH_RATIO_BAND[0] <= ratio <= LENGTH_RATIO_BAND[1]:
        raise InputError(f"{sw.source}: axis {ax}, columns 'x_mm', 'y_mm', 'z_mm': units do not fit: the balls lie "
                         f"{ratio:.4g} times as far apart as the machine file's [targets] mounts (expected 1 for "
                         f"mm){guess}")


def _layout_suspects(balls_mm, min_separation_mm: float) -> np.ndarray:
    """Indices of the stations (balls (m, 3, 3)) that :func:`layout_problem` may refuse, in order:
    the same tests at every station at once, with a 1 % margin so that rounding cannot hide one."""
    b = np.asarray(balls_mm, dtype=float)
    dist = np.stack([np.linalg.norm(b[:, i] - b[:, j], axis=1) for i, j in ((0, 1), (0, 2), (1, 2))], axis=1)
    height = np.linalg.norm(np.cross(b[:, 1] - b[:, 0], b[:, 2] - b[:, 0]), axis=1) / dist.max(axis=1)
    return np.flatnonzero((dist.min(axis=1) < 1.01 * min_separation_mm) | ~(height >= 0.99 * min_separation_mm))


def station_jacobian(q_mm, Rn=None) -> np.ndarray:
    """The paper's 9×6 system: ∂(ball positions, μm)/∂(δ μm, ε μrad) for balls q (n, 3, 3).

    ``Rn`` (n, 3, 3): the nominal rotation applied after the error (A axis); default identity.
    Returns shape (n, 9, 6).
    """
    q = np.asarray(q_mm, dtype=float)
    n = q.shape[0]
    Rn = np.broadcast_to(np.eye(3), (n, 3, 3)) if Rn is None else Rn
    J = np.empty((n, 3, 3, 6))
    J[..., :3] = Rn[:, None]
    J[..., 3:] = -(Rn[:, None] @ skew(q)) * (URAD / UM)
    return J.reshape(n, 9, 6)


def _euler_urad(R) -> np.ndarray:
    """ε (n, 3) μrad with ``R = RotX(εx)·RotY(εy)·RotZ(εz)`` (intrinsic XYZ)."""
    return Rotation.from_matrix(R).as_euler("XYZ") / URAD


def move_squareness(elements: ElementSet, s_xz_urad: float, machine: Grinder) -> ElementSet:
    """An equivalent element set with squareness ``s_xz_urad``: the difference moves exactly
    into the Z straightness/positioning (``d_z += RotZ(-θ1)·z·(u(s_old) - u(s_new))``,
    ``u(s) = (sin s, 0, cos s)``), which leaves every Z-carriage pose, hence the tool point,
    unchanged. This is the one combination the sweeps cannot separate. The Z body's nominal
    frames with either squareness come from the grinder's chain (:func:`z_carriage_nominal`):
    ``d_z += R⁻¹·(t(s_old) - t(s_new))``."""
    out = elements.copy()
    z = out.stations["z_mm"]
    R, t_old = z_carriage_nominal(machine, z, elements.constants["s_xz"])
    _, t_new = z_carriage_nominal(machine, z, s_xz_urad)
    delta_um = np.einsum("nji,nj->ni", R, t_old - t_new) / UM
    for j, k in enumerate(("dx_z", "dy_z", "dz_z")):
        out.functions[k] = out.functions[k] + delta_um[:, j]
    out.constants["s_xz"] = float(s_xz_urad)
    out._splines = {}
    return out


def _element_transforms(elements: ElementSet, names) -> tuple:
    """``Trans(δ)·Rot(ε)`` of one body's six elements at its stations -> (R (m,3,3), t (m,3) mm)."""
    f = elements.functions
    return error_transform(np.stack([f[k] for k in names[:3]], axis=1), np.stack([f[k] for k in names[3:]], axis=1))


def _element_values(E) -> np.ndarray:
    """The six element values (δ μm, ε μrad) of rigid transforms E = (R (m,3,3), t (m,3) mm), shape (m, 6)."""
    return np.hstack([E[1] / UM, _euler_urad(E[0])])


def _put_elements(out: ElementSet, names, E, closed: bool = False) -> None:
    vals = _element_values(E)
    for j, k in enumerate(names):
        v = vals[:, j].copy()
        if closed:
            v[-1] = v[0]
        out.functions[k] = v
    out._splines = {}


def frame_to_station_mean(elements: ElementSet, machine: Grinder) -> tuple:
    """The same machine in the gauge whose frame is the X carriage's mean pose over its stations:
    ``(elements, Γ)``, Γ = (R (3,3), t (3,) mm) the new machine frame in the old one.

    With ``M(x) = N_X(x)·E_x(x)·N_X(x)⁻¹`` the carriage's error motion in the MCS, the frame
    change Γ is the mean rotation of ``M`` and the translation that makes the mean of the new
    ``E_x`` translations zero; ``E_x ← N_X⁻¹·Γ⁻¹·N_X·E_x`` and ``E_z ← N_Z⁻¹·Γ⁻¹·N_Z·E_z``
    exactly. The A chain hangs on the X carriage at its first station and is unchanged; every
    tool point in the WCS is unchanged (a rigid change seen by both chains)."""
    cx, cz = elements.stations["x_mm"], elements.stations["z_mm"]
    NX = x_carriage_nominal(machine, cx)
    M = compose(compose(NX, _element_transforms(elements, X_ELEMENTS)), invert(NX))
    GR = Rotation.from_matrix(M[0]).mean().as_matrix()
    Gt = (apply(M[0], NX[1]) + M[1] - apply(GR, NX[1])).mean(axis=0)
    Gi = invert((GR[None], Gt[None]))
    out = elements.copy()
    _put_elements(out, X_ELEMENTS, compose(compose(compose(invert(NX), Gi), NX), _element_transforms(elements, X_ELEMENTS)))
    NZ = z_carriage_nominal(machine, cz, elements.constants["s_xz"])
    _put_elements(out, Z_ELEMENTS, compose(compose(compose(invert(NZ), Gi), NZ), _element_transforms(elements, Z_ELEMENTS)))
    return out, (GR, Gt)


@dataclass(frozen=True)
class RotaryLine:
    """The rotary joint of a machine's chain file as the identification needs it.

    ``word`` its axis word; ``along`` the joint frame's axis it turns about (0 x, 1 y, 2 z);
    ``direction`` ±1; ``slots`` the location slots between the carriage and the joint, in chain
    order: ``(name, kind, axis)`` with kind ``"t"`` (δ, μm) or ``"r"`` (ε, μrad) along ``axis``."""

    word: str
    along: int
    direction: float
    slots: tuple

    def turn(self, angle_deg) -> np.ndarray:
        """The joint's rotation at ``angle_deg`` (n,) -> (n, 3, 3)."""
        return (rot_x, rot_y, rot_z)[self.along](np.deg2rad(self.direction * np.asarray(angle_deg, dtype=float)))

    def transform(self, values: dict) -> tuple:
        """``Trans(δ)·Rot(ε)`` of the line slots' ``values`` ({name: μm or μrad}) -> (R (1,3,3), t (1,3) mm)."""
        d, e = np.zeros((1, 3)), np.zeros((1, 3))
        for name, kind, axis in self.slots:
            (d if kind == "t" else e)[0, axis] = values[name]
        return error_transform(d, e)

    def values(self, d_um, e_urad) -> dict:
        """The line slots' values read from a displacement (3,) μm and rotation (3,) μrad."""
        return {name: float((d_um if kind == "t" else e_urad)[axis]) for name, kind, axis in self.slots}


def rotary_line(machine: Grinder) -> RotaryLine:
    """The rotary joint of the machine's chain file (:func:`errormap.grinder_file.grinder_chain`): the one
    rotary axis, its direction, and the constant slots of the work chain between the carriage before
    it and the joint (the A-axis line on the grinder: δy, δz, εy, εz across A, which turns about x)."""
    from .grinder_file import grinder_chain
    mt = grinder_chain(machine)
    rotary = [a for a in mt.axes if a.kind == "rotary"]
    if len(rotary) != 1:
        raise ValueError(f"expected one rotary axis in {machine.name!r}, got {[a.word for a in rotary]}")
    ax = rotary[0]
    ets = mt.work_ets if ax.side == "work" else mt.tool_ets
    col = mt.axis_words.index(ax.word)
    at = next(m for m, e in enumerate(ets) if e.joint == col)
    before = next((m for m in range(at - 1, -1, -1) if ets[m].joint is not None), -1)
    const = set(CONSTANT_ELEMENTS)
    slots = tuple((e.slot, e.kind, e.axis) for e in ets[before + 1:at] if e.slot in const)
    return RotaryLine(ax.word, ax.along, float(ax.direction), slots)


def _a_line(constants, line: RotaryLine) -> tuple:
    return line.transform(constants)


def a_line_to_turn_mean(elements: ElementSet, machine: Grinder, n_iter: int = 4) -> ElementSet:
    """The same machine with the rotary axis' line at its mean over the turn: the rotary chain
    ``W(a) = E_oa·Rot(a)·E_a(a)`` (``Rot`` the chain file's joint, :func:`rotary_line`) at the A
    stations is split again, the line chosen so that the part of ``E_a`` that turns with the axis
    (its δ and ε across the axis, the line's slots, rotated back by a) averages to zero over the
    turn's distinct stations (a fixed-point iteration on the exact split; the turning part is what a
    change of the line adds). ``W``, hence every tool point, is unchanged."""
    rl = rotary_line(machine)
    ca = elements.stations["a_deg"]
    W = compose(compose(_a_line(elements.constants, rl), (rl.turn(ca), np.zeros((ca.size, 3)))),
                _element_transforms(elements, A_ELEMENTS))
    back = rl.turn(ca)[:-1]
    c = elements.constants
    names = [s[0] for s in rl.slots]
    rows = [(0 if kind == "t" else 1, axis) for _, kind, axis in rl.slots]  # rows δ, ε of `turning`
    p = np.array([c[k] for k in names], dtype=float)
    unrot = (rl.turn(-ca), np.zeros((ca.size, 3)))
    for _ in range(n_iter + 1):
        line = dict(zip(names, p.tolist()))
        E_a = compose(unrot, compose(invert(_a_line(line, rl)), W))
        turning = apply(back[:, None], _element_values(E_a)[:-1].reshape(-1, 2, 3)).mean(axis=0)  # rows δ, ε
        p = p + np.array([turning[r, a] for r, a in rows])
    out = elements.copy()
    _put_elements(out, A_ELEMENTS, E_a, closed=True)
    out.constants.update(line)
    return out


# -- results --------------------------------------------------------------------------------
@dataclass
class AxisReport:
    """Per-axis diagnostics; arrays have one entry per station.

    ``conditioning``: condition number of the station's 9×6 system (δ μm, ε μrad);
    ``residual_rms_um`` / ``residual_max_um``: ball residuals after the solve;
    ``errors_in_reference``: (m, 6) the paper's six errors (δ μm, ε μrad) in the axis'
    reference frame, relative to the initial station; ``reversal_um``: RMS ball-position
    difference between the + and - runs where both exist; ``fit``: the reference fit.
    """

    axis: str
    command: np.ndarray
    conditioning: np.ndarray
    residual_rms_um: np.ndarray
    residual_max_um: np.ndarray
    errors_in_reference: np.ndarray
    reference_in_tracker: tuple
    iterations: int
    fit: dict
    reversal_um: np.ndarray | None = None

    def to_dict(self) -> dict:
        return {"axis": self.axis, "command": self.command, "conditioning": self.conditioning,
                "residual_rms_um": self.residual_rms_um, "residual_max_um": self.residual_max_um,
                "errors_in_reference": {"columns": ["dx_um", "dy_um", "dz_um", "ex_urad", "ey_urad", "ez_urad"],
                                        "values": self.errors_in_reference},
                "reference_in_tracker": {"R": self.reference_in_tracker[0], "t_mm": self.reference_in_tracker[1]},
                "iterations": self.iterations, "fit": self.fit,
                "reversal_um": self.reversal_um}


@dataclass
class IdentificationResult:
    """What :func:`identify` found: ``elements_`` (the element set), per-axis reports,
    the estimated ``machine_in_tracker`` pose, the gauge, and warnings."""

    elements_: ElementSet
    axes: dict
    machine_in_tracker: tuple
    gauge: str
    warnings: list = field(default_factory=list)

    @property
    def conditioning(self) -> dict:
        """Axis -> condition number of each station's 9×6 system, shape (m,)."""
        return {k: v.conditioning for k, v in self.axes.items()}

    @property
    def residuals_um(self) -> dict:
        """Axis -> RMS ball residual of each station (μm), shape (m,)."""
        return {k: v.residual_rms_um for k, v in self.axes.items()}

    def summary_lines(self) -> list[str]:
        lines = []
        for ax, r in self.axes.items():
            w = int(np.argmax(r.conditioning))
            lines.append(f"axis {ax}: {r.command.size} stations, 9x6 conditioning {r.conditioning.min():.3g}.."
                         f"{r.conditioning.max():.3g} (worst station {w}), ball residual RMS max "
                         f"{r.residual_rms_um.max():.3g} um, {r.iterations} iterations")
            if r.reversal_um is not None:
                lines.append(f"axis {ax}: bidirectional, runs averaged; +/- difference up to "
                             f"{r.reversal_um.max():.3g} um RMS (not representable by the 23 elements)")
        c = self.elements_.constants
        lines.append("s_xz {:.4g} urad; A line dy_oa {:.4g} um, dz_oa {:.4g} um, ey_oa {:.4g} urad, "
                     "ez_oa {:.4g} urad (gauge: {})".format(c["s_xz"], c["dy_oa"], c["dz_oa"], c["ey_oa"],
                                                             c["ez_oa"], self.gauge))
        return lines + [f"warning: {w}" for w in self.warnings]

    def to_dict(self) -> dict:
        return {"format": "volcomp-identification/1", "gauge": self.gauge,
                "machine_in_tracker": {"R": self.machine_in_tracker[0], "t_mm": self.machine_in_tracker[1]},
                "constants": self.elements_.constants, "warnings": self.warnings,
                "axes": {k: v.to_dict() for k, v in self.axes.items()}}


def check_ball_distances(sw, axis_word: str, mounts_mm, tol_mm: float) -> None:
    """Refuse a sweep whose measured ball-to-ball distances differ from the nominal mounts' by more
    than ``tol_mm`` at any station (mixed units, or a wrong [targets] entry), naming axis and station.
    ``sw.balls_mm`` (m, 3, 3), ``mounts_mm`` (3, 3)."""
    mounts = np.asarray(mounts_mm, dtype=float)
    pairs = ((0, 1), (0, 2), (1, 2))
    nominal = np.array([np.linalg.norm(mounts[i] - mounts[j]) for i, j in pairs])
    measured = np.stack([np.linalg.norm(sw.balls_mm[:, i] - sw.balls_mm[:, j], axis=1) for i, j in pairs], axis=1)
    bad = np.abs(measured - nominal).max(axis=1) > tol_mm
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"{sw.source}: axis {axis_word}, station {sw.stations[i]}: ball distances "
                         f"{np.round(measured[i], 3).tolist()} mm do not match the nominal mounts' "
                         f"{np.round(nominal, 3).tolist()} mm (mixed units, or a wrong [targets] entry?)")


# -- the estimator --------------------------------------------------------------------------
class TrackerIdentification:
    """The paper's tracker identification as an estimator: ``fit(sweeps, machine)`` returns
    self with ``elements_`` and ``result_`` (an :class:`IdentificationResult`).

    Settings: ``gauge`` (see module doc); ``max_iter`` / ``tol`` of the re-linearised
    9×6 solve (update size, μm and μrad); ``max_condition``: a station whose 9×6 system is
    worse is refused; ``min_separation_mm``: balls closer than this coincide, a triangle
    lower than this is collinear; ``distance_tol_mm``: allowed difference between measured
    and nominal ball distances; ``travel_tol_mm`` / ``angle_tol_deg``: allowed difference
    between measured and commanded travel (mixed units show here).
    """

    def __init__(self, gauge: str = "first-station", max_iter: int = 20, tol: float = 1e-9,
                 max_condition: float = 1e6, min_separation_mm: float = 1.0, distance_tol_mm: float = 2.0,
                 travel_tol_mm: float = 1.0, angle_tol_deg: float = 0.5):
        self.gauge = gauge
        self.max_iter = max_iter
        self.tol = tol
        self.max_condition = max_condition
        self.min_separation_mm = min_separation_mm
        self.distance_tol_mm = distance_tol_mm
        self.travel_tol_mm = travel_tol_mm
        self.angle_tol_deg = angle_tol_deg

    # validation ------------------------------------------------------------------------
    def _check(self, sweeps: Sweeps, machine: Grinder) -> list[str]:
        if self.gauge not in GAUGES:
            raise ValueError(f"Expected gauge in {GAUGES}, got {self.gauge!r}")
        src = ", ".join(sweeps.sources) or "sweeps"
        missing = [a for a in SWEEP_AXES if a not in sweeps]
        if missing:
            raise InputError(f"{src}: axis/axes {missing} missing; X, Z and A are all needed from one tracker "
                             "set-up (squareness and the A-axis line relate the bodies through it)")
        warnings = []
        rotary = rotary_line(machine).word
        for ax in SWEEP_AXES:
            mounts = machine.targets[ax]
            why = layout_problem(mounts, self.min_separation_mm)
            if why:
                raise InputError(f"{machine.path or 'machine'}: key 'targets.{ax}': degenerate target layout for "
                                 f"axis {ax}: {why}")
            sw = sweeps[ax]
            _check_length_unit(sw, ax, mounts)  # metres, inches, μm for mm: named before the layout tests
            for i in _layout_suspects(sw.balls_mm, self.min_separation_mm):  # vectorised screen, then the message
                why = layout_problem(sw.balls_mm[i], self.min_separation_mm)
                if why:
                    raise InputError(f"{sw.source}: axis {ax}, station {sw.stations[i]}: degenerate target layout: {why}")
            check_ball_distances(sw, ax, mounts, self.distance_tol_mm)
            lo, hi = machine.strokes[{"X": "x_mm", "Z": "z_mm", "A": "a_deg"}[ax]]
            if ax == rotary:
                span = sw.command[-1] - sw.command[0]
                if abs(span - 360.0) > 1e-6:
                    raise InputError(f"{sw.source}: axis A: stations must span one turn (360 deg), got "
                                     f"{sw.command[0]:g}..{sw.command[-1]:g} deg (mixed units?)")
            elif sw.command[0] > lo + 1e-9 or sw.command[-1] < hi - 1e-9:
                warnings.append(f"axis {ax}: stations cover {sw.command[0]:g}..{sw.command[-1]:g} of the stroke "
                                f"{lo:g}..{hi:g}; elements are extrapolated outside")
            for name, arr, unit in (("temp_c", sw.temp_c, "degC"),):
                if arr is not None and np.ptp(arr) > 1.0:
                    warnings.append(f"axis {ax}: temperature varied by {np.ptp(arr):.2g} {unit} during the sweep; "
                                    "thermal drift is identified as geometry")
        return warnings

    # per-axis solve -----------------------------------------------------------------------
    def _reference(self, sw, rl: RotaryLine) -> tuple:
        """Reference frame (tracker <- reference) and fit details for one axis (``rl``: the rotary one)."""
        b = sw.balls_mm
        ball1 = b[0, 0]
        if sw.axis == rl.word:
            circles = [fit_circle(b[:, k]) for k in range(3)]
            normals = np.array([c[1] for c in circles])
            x_dir = normals.mean(axis=0)
            x_dir /= np.linalg.norm(x_dir)
            point = np.mean([c[0] for c in circles], axis=0)
            fit = {"circle_centres_mm": [c[0] for c in circles], "circle_normals": normals,
                   "circle_radii_mm": [c[2] for c in circles], "circle_rms_mm": [c[3] for c in circles]}
            for k, c in enumerate(circles):
                if c[2] < self.min_separation_mm:
                    raise InputError(f"{sw.source}: axis A, target {k + 1}: the ball lies on the rotation axis "
                                     f"(circle radius {c[2]:.3g} mm); its circle cannot be fitted")
        else:
            point, x_dir = fit_line(b.mean(axis=1))
            if (b[-1].mean(axis=0) - b[0].mean(axis=0)) @ x_dir < 0:
                x_dir = -x_dir
            fit = {"line_point_mm": point, "line_direction": x_dir,
                   "line_rms_mm": float(np.sqrt(np.mean(np.sum(((b.mean(axis=1) - point)
                                                                - np.outer((b.mean(axis=1) - point) @ x_dir, x_dir))**2, axis=1))))}
        foot = point + ((ball1 - point) @ x_dir) * x_dir
        y_dir = ball1 - foot
        if np.linalg.norm(y_dir) < 1e-9:  # ball 1 on the reference line: any perpendicular
            y_dir = np.cross(x_dir, np.eye(3)[np.argmin(np.abs(x_dir))])
        y_dir /= np.linalg.norm(y_dir)
        R = np.stack([x_dir, y_dir, np.cross(x_dir, y_dir)], axis=1)
        return (R, foot), fit

    def _solve_axis(self, sw, ref, rl: RotaryLine):
        """Re-linearised least squares of the 9×6 system at every station (vectorised); ``rl`` the
        machine's rotary joint (the nominal motion of its sweep)."""
        R_ref, t_ref = ref
        P = np.einsum("ji,mkj->mki", R_ref, sw.balls_mm - t_ref)  # reference coordinates (m, 3, 3)
        m = P.shape[0]
        d_cmd = sw.command - sw.command[0]
        if sw.axis == rl.word:
            Rn, tn = rl.turn(d_cmd), np.zeros((m, 3))
        else:
            Rn, tn = np.broadcast_to(np.eye(3), (m, 3, 3)).copy(), d_cmd[:, None] * np.eye(3)[0]
        R = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
        t = np.zeros((m, 3))
        P0 = P[0]
        for it in range(1, self.max_iter + 1):
            q = np.einsum("mij,kj->mki", R, P0) + t[:, None]
            r_um = ((P - (np.einsum("mij,mkj->mki", Rn, q) + tn[:, None])) / UM).reshape(m, 9)
            J = station_jacobian(q, Rn)
            U, S, Vt = np.linalg.svd(J, full_matrices=False)
            cond = S[:, 0] / S[:, -1]
            if np.any(cond > self.max_condition) or np.any(S[:, -1] == 0):
                i = int(np.argmax(np.where(S[:, -1] == 0, np.inf, cond)))
                raise InputError(f"{sw.source}: axis {sw.axis}, station {sw.stations[i]}: the 9x6 system is "
                                 f"singular or ill-conditioned (condition {cond[i]:.3g}); targets collinear?")
            x = np.einsum("mji,mj->mi", Vt, np.einsum("mji,mj->mi", U, r_um) / S)
            dR = Rotation.from_rotvec(x[:, 3:] * URAD).as_matrix()
            R = dR @ R
            t = apply(dR, t) + x[:, :3] * UM
            if np.abs(x).max() < self.tol:
                break
        q = np.einsum("mij,kj->mki", R, P0) + t[:, None]
        res = np.linalg.norm(P - (np.einsum("mij,mkj->mki", Rn, q) + tn[:, None]), axis=2) / UM
        err = np.hstack([t / UM, _euler_urad(R)])
        # full motion from the initial station, in tracker coordinates
        D = compose((Rn, tn), (R, t))
        D_tr = compose(compose((R_ref[None], t_ref[None]), D), invert((R_ref[None], t_ref[None])))
        # the measured rotation/travel must match the command (mixed units show here)
        if sw.axis == rl.word:
            ang = np.rad2deg(np.linalg.norm(Rotation.from_matrix(D[0]).as_rotvec(), axis=1))
            want = np.abs((d_cmd + 180.0) % 360.0 - 180.0)
            bad = np.abs(ang - want) > self.angle_tol_deg
            if bad.any():
                i = int(np.argmax(bad))
                raise InputError(f"{sw.source}: axis A, station {sw.stations[i]}: measured rotation {ang[i]:.4g} deg "
                                 f"from the first station, commanded {d_cmd[i]:.4g} deg (mixed units?)")
        else:
            travel = P.mean(axis=1)[:, 0] - P0.mean(axis=0)[0]  # centroid along the reference line
            bad = np.abs(travel - d_cmd) > self.travel_tol_mm
            if bad.any():
                i = int(np.argmax(bad))
                raise InputError(f"{sw.source}: axis {sw.axis}, station {sw.stations[i]}: measured travel "
                                 f"{travel[i]:.4g} mm from the first station, commanded {d_cmd[i]:.4g} mm "
                                 "(mixed units?)")
        return D_tr, cond, np.sqrt(np.mean(res**2, axis=1)), res.max(axis=1), err, it

    # the method ---------------------------------------------------------------------------
    def fit(self, sweeps, machine: Grinder) -> "TrackerIdentification":
        """Identify the 23 elements; ``sweeps``: :class:`Sweeps`, a dict of sweep columns, or
        sweep file path(s) of one set-up."""
        if not isinstance(sweeps, Sweeps):
            sweeps = sweeps_from_columns(sweeps) if isinstance(sweeps, dict) else read_sweeps(sweeps)
        warnings = self._check(sweeps, machine)
        rl = rotary_line(machine)
        poses, reports, lines = {}, {}, {}
        for ax in SWEEP_AXES:
            sw = sweeps[ax]
            ref, fit = self._reference(sw, rl)
            D_tr, cond, rms, rmax, err, it = self._solve_axis(sw, ref, rl)
            T0 = rigid_fit(machine.targets[ax], sw.balls_mm[:1])
            poses[ax] = compose(D_tr, T0)
            reversal = None
            if len(sw.by_direction) == 2:
                reversal = np.sqrt(np.mean(np.sum((sw.by_direction[1] - sw.by_direction[-1]) ** 2, axis=2), axis=1)) / UM
            reports[ax] = AxisReport(ax, sw.command.copy(), cond, rms, rmax, err, ref, it, fit, reversal)
            if ax != rl.word:
                lines[ax] = fit["line_direction"]
        cx, cz, ca = sweeps["X"].command, sweeps["Z"].command, sweeps[rl.word].command
        NX = x_carriage_nominal(machine, cx)
        TX = poses["X"]
        u_x, u_z = lines["X"], lines["Z"]
        if self.gauge in ("first-station", "station-mean"):
            G = compose((TX[0][:1], TX[1][:1]), invert((NX[0][:1], NX[1][:1])))
        else:
            z_dir = u_z - (u_z @ u_x) * u_x
            z_dir /= np.linalg.norm(z_dir)
            RG = np.stack([u_x, np.cross(z_dir, u_x), z_dir], axis=1)[None]
            G = (RG, TX[1][:1] - apply(RG, NX[1][:1]))
        Gi = invert(G)
        s_urad = float(np.arcsin(np.clip(u_x @ u_z, -1.0, 1.0)) / URAD)
        E_x = compose(invert(NX), compose(Gi, TX))
        E_z = compose(invert(z_carriage_nominal(machine, cz, s_urad)), compose(Gi, poses["Z"]))
        pre = compose(compose((NX[0][:1], NX[1][:1]), (E_x[0][:1], E_x[1][:1])), a_line_offset(machine, 1))
        W_R, W_t = compose(invert(pre), compose(Gi, poses[rl.word]))
        # first and last A stations are the same physical pose: average them
        W_R[0] = W_R[-1] = Rotation.from_matrix(W_R[[0, -1]]).mean().as_matrix()
        W_t[0] = W_t[-1] = W_t[[0, -1]].mean(axis=0)
        M0 = compose((W_R[:1], W_t[:1]), (rl.turn(-ca[:1]), np.zeros((1, 3))))
        line = rl.values(M0[1][0] / UM, _euler_urad(M0[0])[0])  # the initial state across the axis
        E_oa = rl.transform(line)
        E_a = compose((rl.turn(-ca), np.zeros((ca.size, 3))), compose(invert(E_oa), (W_R, W_t)))
        functions = {}
        for names, E in ((X_ELEMENTS, E_x), (Z_ELEMENTS, E_z), (A_ELEMENTS, E_a)):
            vals = _element_values(E)
            for j, k in enumerate(names):
                functions[k] = vals[:, j]
        for k in A_ELEMENTS:
            functions[k][-1] = functions[k][0]
        constants = {**line, "s_xz": s_urad}
        assert set(constants) == set(CONSTANT_ELEMENTS)
        elements = ElementSet({"x_mm": cx, "z_mm": cz, "a_deg": ca}, functions, constants, machine.name,
                              machine.sha256)
        if self.gauge == "station-mean":
            elements, Gam = frame_to_station_mean(elements, machine)
            elements = a_line_to_turn_mean(elements, machine)
            G = compose(G, (Gam[0][None], Gam[1][None]))
        self.elements_ = elements
        self.result_ = IdentificationResult(elements, reports, (G[0][0], G[1][0]), self.gauge, warnings)
        return self


def identify(sweeps, machine: Grinder, **settings) -> IdentificationResult:
    """Identify the 23 elements from sweeps (see :class:`TrackerIdentification` for settings)."""
    return TrackerIdentification(**settings).fit(sweeps, machine).result_
