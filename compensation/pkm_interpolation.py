"""Time-division interpolation for the PKMs (stewart-interpolation paper) and compensated leg commands.

Each interpolation period advances the tool tip by the contour step ``f = feed * period`` along a line (or
the arc angle by ``f / r``); each step's end pose goes through the inverse kinematics, and the leg
increments between steps are the leg-command program. With a calibration, the *identified* parameters are
used in the inverse kinematics and in the drive conversion (``q = (l - offset) / scale``): the compensated
commands. The test paths (the paper's sphere and hyperboloid passes) and their constants:
docs/explanation/parallel-kinematics.md ("Interpolation"). ``true_path_residual`` is the *true residual*
(docs/explanation/kinematics.md): the tool tip the simulated truth machine reaches with the (compensated)
commands, minus the target, in um."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from errormap.io import InputError, read_table, write_csv
from errormap.pkm.hexapod import (angles_to_rotation, check_leg_limits, forward_kinematics,
                                  inverse_kinematics, tool_axis_to_rotation)
from errormap.pkm.machine_file import PKM
from errormap.stats import residual_stats


@dataclass
class PosePath:
    """A sampled PKM tool path, tool tip and orientation per step: ``tip_mm`` (n, 3), ``platform2base`` (n, 3, 3), ``move`` (n,) move index,
    ``tool_length_mm`` (None: the machine file's)."""

    tip_mm: np.ndarray
    platform2base: np.ndarray
    move: np.ndarray
    tool_length_mm: float | None = None
    name: str = ""

    def __len__(self):
        return len(self.tip_mm)


def contour_step_mm(feed_mm_min: float, period_ms: float) -> float:
    """``f = feed * period`` (mm per interpolation period)."""
    if feed_mm_min <= 0 or period_ms <= 0:
        raise ValueError("feed and interpolation period must be positive")
    return feed_mm_min / 60.0 * period_ms / 1000.0


def _n_steps(length_mm, step_mm):
    return max(1, int(np.ceil(length_mm / step_mm - 1e-9)))


def linear_move(start_mm, end_mm, step_mm: float, R_start=None, R_end=None, include_start: bool = False):
    """Linear interpolation: tips (s, 3) every ``step_mm`` (last step shorter), orientations (s, 3, 3).

    Fixed orientation when ``R_end`` is None, else slerped from ``R_start`` to ``R_end``.
    """
    a, b = np.asarray(start_mm, float), np.asarray(end_mm, float)
    n = _n_steps(np.linalg.norm(b - a), step_mm)
    u = np.minimum(np.arange(0 if include_start else 1, n + 1) * step_mm / max(np.linalg.norm(b - a), 1e-300), 1.0)
    u[-1] = 1.0
    tips = a + u[:, None] * (b - a)
    R0 = np.eye(3) if R_start is None else np.asarray(R_start)
    if R_end is None:
        Rs = np.broadcast_to(R0, (len(u), 3, 3)).copy()
    else:
        Rs = Slerp([0, 1], Rotation.from_matrix(np.stack([R0, R_end])))(u).as_matrix()
    return tips, Rs


def circular_move(centre_mm, start_mm, normal, angle_deg: float, step_mm: float, include_start: bool = False):
    """Circular interpolation about ``normal`` through ``centre_mm``: arc angle step ``f / r``; tips (s, 3)."""
    c, p0 = np.asarray(centre_mm, float), np.asarray(start_mm, float)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    r_vec = p0 - c
    r = np.linalg.norm(r_vec)
    total = np.radians(angle_deg)
    k = _n_steps(abs(total) * r, step_mm)
    ang = np.minimum(np.arange(0 if include_start else 1, k + 1) * step_mm / r, abs(total)) * np.sign(total)
    ang[-1] = total
    return c + Rotation.from_rotvec(ang[:, None] * n).apply(r_vec)


def sphere_pass(step_mm: float = 0.5, radius_mm: float = 100.0, angle_deg: float = 60.0, apex_z_mm: float = 980.0,
                n_meridians: int = 6, tool_length_mm: float = 30.0) -> PosePath:
    """Spherical cap pass: ``n_meridians`` circular moves through the apex (from -angle/2 to +angle/2),
    joined by circular moves along the cap's rim; tool axis along the outward surface normal."""
    centre = np.array([0.0, 0.0, apex_z_mm - radius_mm])
    half = np.radians(angle_deg / 2)
    tips, move = [], []
    for j, az in enumerate(np.arange(n_meridians) * np.pi / n_meridians):
        d = np.array([np.cos(az), np.sin(az), 0.0]) * (-1) ** j   # alternate direction
        start = centre + radius_mm * (np.cos(half) * np.array([0, 0, 1.0]) - np.sin(half) * d)
        normal = np.cross(d, [0, 0, 1.0])  # rotating from -d towards +d through the apex
        if tips:  # circular move along the cap's rim to the next meridian's start
            rim_c = np.array([0.0, 0.0, start[2]])
            a, b = tips[-1][-1] - rim_c, start - rim_c
            turn = np.degrees(np.arctan2(np.cross(a, b)[2], a @ b))
            p = circular_move(rim_c, tips[-1][-1], [0, 0, 1.0], turn, step_mm)
            tips.append(p)
            move.append(np.full(len(p), 2 * j - 1))
        p = circular_move(centre, start, -normal, angle_deg, step_mm, include_start=not tips)
        tips.append(p)
        move.append(np.full(len(p), 2 * j))
    tips = np.concatenate(tips)
    axis = (tips - centre) / radius_mm
    return PosePath(tips, tool_axis_to_rotation(axis), np.concatenate(move), tool_length_mm, "sphere")


def hyperboloid_pass(step_mm: float = 0.5, radius_mm: float = 100.0, angle_deg: float = 20.0,
                     centre_z_mm: float = 980.0, height_mm: float = 80.0, n_rulings: int = 12,
                     tool_length_mm: float = 200.0) -> PosePath:
    """One-sheet hyperboloid pass: linear moves along ``n_rulings`` rulings (straight lines tilted
    ``angle_deg`` from the axis, tangent to the waist circle of ``radius_mm``), ``height_mm`` tall,
    alternating direction, joined by linear moves; fixed vertical tool orientation."""
    t = np.tan(np.radians(angle_deg))
    pts, move = [], []
    prev = None
    for j, az in enumerate(np.arange(n_rulings) * 2 * np.pi / n_rulings):
        w = radius_mm * np.array([np.cos(az), np.sin(az), 0.0])
        tang = np.array([-np.sin(az), np.cos(az), 0.0])
        h = height_mm / 2
        a = w + np.array([0, 0, centre_z_mm]) + tang * t * (-h) + np.array([0, 0, -h])
        b = w + np.array([0, 0, centre_z_mm]) + tang * t * h + np.array([0, 0, h])
        if j % 2:
            a, b = b, a
        if prev is not None:
            p, _ = linear_move(prev, a, step_mm)
            pts.append(p)
            move.append(np.full(len(p), 2 * j - 1))
        p, _ = linear_move(a, b, step_mm, include_start=prev is None)
        pts.append(p)
        move.append(np.full(len(p), 2 * j))
        prev = b
    tips = np.concatenate(pts)
    return PosePath(tips, np.broadcast_to(np.eye(3), (len(tips), 3, 3)).copy(), np.concatenate(move),
                    tool_length_mm, "hyperboloid")


def builtin_path(name: str, step_mm: float = 0.5) -> PosePath:
    """``"sphere"`` or ``"hyperboloid"``: the paper's test parts."""
    if name == "sphere":
        return sphere_pass(step_mm)
    if name == "hyperboloid":
        return hyperboloid_pass(step_mm)
    raise ValueError(f"unknown built-in path {name!r} (sphere, hyperboloid)")


def read_waypoints(path, step_mm: float) -> PosePath:
    """Read a waypoint CSV and interpolate it.

    Columns: ``px_mm, py_mm, pz_mm`` (tool tip, machine frame); orientation optional as the tool
    axis ``nx, ny, nz`` (paper's Euler convention) or fixed-axis X-Y-Z angles ``rx_deg, ry_deg,
    rz_deg``; optional ``move`` (``L`` linear, default, or ``C`` circular from the previous waypoint
    about ``cx_mm, cy_mm, cz_mm``, the shorter arc). Orientation is slerped along each move.
    """
    t = read_table(path, "waypoints")
    t.require("px_mm", "py_mm", "pz_mm")
    P = np.stack([t.float(c) for c in ("px_mm", "py_mm", "pz_mm")], 1)
    if len(P) < 2:
        raise InputError(f"{t.path}: need at least 2 waypoints, got {len(P)}")
    if all(c in t for c in ("nx", "ny", "nz")):
        n = np.stack([t.float(c) for c in ("nx", "ny", "nz")], 1)
        bad = np.flatnonzero(np.linalg.norm(n, axis=1) < 1e-9)
        if bad.size:
            raise InputError(f"{t.path}: row {t.row_number(bad[0])}, columns 'nx'..'nz': zero tool axis")
        R = tool_axis_to_rotation(n)
    elif all(c in t for c in ("rx_deg", "ry_deg", "rz_deg")):
        R = angles_to_rotation(np.stack([t.float(c) for c in ("rx_deg", "ry_deg", "rz_deg")], 1))
    else:
        R = np.broadcast_to(np.eye(3), (len(P), 3, 3)).copy()
    kinds = [s.upper() for s in t.raw("move")] if "move" in t else ["L"] * len(P)
    tips, Rs, move = [P[:1]], [R[:1]], [np.zeros(1, int)]
    for i in range(1, len(P)):
        if kinds[i] == "L":
            p, r = linear_move(P[i - 1], P[i], step_mm, R[i - 1], R[i])
        elif kinds[i] == "C":
            for c in ("cx_mm", "cy_mm", "cz_mm"):
                t.require(c)
            c = np.array([t.float(cc)[i] for cc in ("cx_mm", "cy_mm", "cz_mm")])
            a, b = P[i - 1] - c, P[i] - c
            if abs(np.linalg.norm(a) - np.linalg.norm(b)) > 1e-3 * max(np.linalg.norm(a), 1):
                raise InputError(f"{t.path}: row {t.row_number(i)}, column 'move': arc end is not on the circle "
                                 f"about (cx_mm, cy_mm, cz_mm)")
            nrm = np.cross(a, b)
            ang = np.degrees(np.arctan2(np.linalg.norm(nrm), a @ b))
            if np.linalg.norm(nrm) < 1e-12:
                raise InputError(f"{t.path}: row {t.row_number(i)}, column 'move': arc plane undefined (0 or 180 deg)")
            p = circular_move(c, P[i - 1], nrm, ang, step_mm)
            u = np.linspace(0, 1, len(p) + 1)[1:]
            r = Slerp([0, 1], Rotation.from_matrix(np.stack([R[i - 1], R[i]])))(u).as_matrix()
        else:
            raise InputError(f"{t.path}: row {t.row_number(i)}, column 'move': expected L or C, got {kinds[i]!r}")
        tips.append(p)
        Rs.append(r)
        move.append(np.full(len(p), i))
    return PosePath(np.concatenate(tips), np.concatenate(Rs), np.concatenate(move), None, Path(path).stem)


def _with_tool(machine: PKM, path: PosePath) -> PKM:
    if path.tool_length_mm is None or machine.kind != "hexapod":
        return machine
    return replace(machine, tool_in_platform_mm=np.array([0.0, 0.0, -path.tool_length_mm]))


@dataclass
class LegProgram:
    """Leg-command program: ``legs_mm`` (n, k), ``increments_mm`` (n, k) (first row from the first
    pose, i.e. zero), ``q`` (n, k) drive commands, the ``path``, and whether it is ``compensated``."""

    legs_mm: np.ndarray
    increments_mm: np.ndarray
    q: np.ndarray
    path: PosePath
    compensated: bool

    def write_csv(self, out) -> Path:
        k = self.legs_mm.shape[1]
        cols = {"step": np.arange(len(self.q)), "move": self.path.move,
                "px_mm": self.path.tip_mm[:, 0], "py_mm": self.path.tip_mm[:, 1], "pz_mm": self.path.tip_mm[:, 2]}
        cols.update({f"q{i + 1}": self.q[:, i] for i in range(k)})
        cols.update({f"l{i + 1}_mm": self.legs_mm[:, i] for i in range(k)})
        cols.update({f"dl{i + 1}_mm": self.increments_mm[:, i] for i in range(k)})
        return write_csv(out, cols, header_comments=[
            f"leg-command program: path {self.path.name}, {len(self.q)} steps, "
            f"compensated: {self.compensated}", "q = (l - offset) / scale in drive units; l in mm"])


def leg_program(machine: PKM, path: PosePath, calibrated: PKM | None = None, check_limits: bool = True) -> LegProgram:
    """Commands for ``path``: inverse kinematics of each step's end pose with the nominal machine or,
    when given, the ``calibrated`` one (compensation); drive units with that model's scale/offset."""
    model = _with_tool(calibrated if calibrated is not None else machine, path)
    legs = inverse_kinematics(model, path.tip_mm, path.platform2base if model.kind == "hexapod" else None)
    if check_limits:
        check_leg_limits(machine, legs, "path step")
    inc = np.vstack([np.zeros((1, legs.shape[1])), np.diff(legs, axis=0)])
    terms = model.extra.get("leg_terms")
    q = model.legs_to_drive(legs) if not terms else terms.drive_for_legs(model, model.extra["leg_terms_nominal"], legs)
    return LegProgram(legs, inc, q, path, calibrated is not None)


def true_path_residual(truth, calibration_or_none, path: PosePath, frame: str = "machine",
                       use_nominal: bool = False) -> dict:
    """True residual along ``path`` on the simulated truth machine, per point.

    ``truth``: a :class:`errormap.pkm.simulate.Truth` (or its PKM); ``calibration_or_none``: None
    (nominal commands), a ``CalibrationResult`` or an identified PKM. ``frame``: ``"machine"`` (the
    path is in the machine frame defined by the joints) or ``"instrument"`` (the path is in the
    measuring instrument's frame, where the part is located; commands go through the identified
    registration); ``use_nominal`` with a ``CalibrationResult``: uncompensated commands (nominal
    machine; in the instrument frame with the initial robust registration of the nominal model). Returns
    ``position_um`` (n,), ``error_um`` (n, 3), ``angle_urad`` (n,) (hexapod), ``rms_um``/``max_um``.
    """
    tm = getattr(truth, "machine", truth)
    nominal = getattr(truth, "nominal", None) or tm
    cal = None if use_nominal else getattr(calibration_or_none, "machine", calibration_or_none)
    tip, R = path.tip_mm, path.platform2base
    if frame == "instrument":
        tf, Rf = truth.frame_translation_mm, truth.frame_rotation
        tip_i, R_i = tip @ Rf.T + tf, np.einsum("ij,njk->nik", Rf, R)   # the part, located by the instrument
        if not hasattr(calibration_or_none, "frame_rotation"):
            raise ValueError("frame='instrument' needs a CalibrationResult (it holds the registration)")
        if use_nominal:
            tg, Rg = calibration_or_none.lcurve["initial_frame"]
        else:
            tg, Rg = calibration_or_none.frame_translation_mm, calibration_or_none.frame_rotation
        cmd_path = replace(path, tip_mm=(tip_i - tg) @ Rg, platform2base=np.einsum("ji,njk->nik", Rg, R_i))
    elif frame == "machine":
        cmd_path = path
    else:
        raise ValueError(f"frame must be 'machine' or 'instrument', got {frame!r}")
    prog = leg_program(nominal, cmd_path, cal, check_limits=False)
    tt = _with_tool(tm, path)
    fk = forward_kinematics(tt, tt.drive_to_legs(prog.q), guess_tip_mm=tip, guess_platform2base=R,
                            check_limits=False)
    err = (fk.x - tip) * 1e3
    pos = np.linalg.norm(err, axis=1)
    st = residual_stats(pos)
    out = {"position_um": pos, "error_um": err, "rms_um": st["rms_um"],
           "max_um": st["max_um"], "n_points": len(pos), "frame": frame}
    if tm.kind == "hexapod":
        rv = Rotation.from_matrix(np.einsum("nij,nkj->nik", fk.platform2base, R)).as_rotvec()
        out["angle_urad"] = 1e6 * np.linalg.norm(rv, axis=1)
    return out

