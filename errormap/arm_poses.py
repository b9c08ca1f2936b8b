"""Measured-pose files of a serial chain (an arm): joint values and the measured tool point.

Schema: ``docs/reference/file-formats.md`` and ``docs/explanation/serial-arms.md`` (joint columns
``q1_deg … qN_deg``, the tool point ``x_mm, y_mm, z_mm``; optional ``sigma_mm``, ``temp_c``, ``time_s``,
``session``, a 6-DoF orientation as ``qw, qx, qy, qz`` or ``rx_rad, ry_rad, rz_rad`` with ``sigma_rad``).
Recognised by content: the schema's columns, or the laser-tracker grid layout read as measured = target + dif.
Refused, with one line naming file, row and column: metres where mm are
declared, radians where degrees are, joint values outside the machine's limits, non-positive ``sigma_mm``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .io import InputError, read_table, write_csv

XYZ = ("x_mm", "y_mm", "z_mm")
GRID_TARGET = ("x_t", "y_t", "z_t")
GRID_DIF = ("x_dif", "y_dif", "z_dif")
QUAT = ("qw", "qx", "qy", "qz")
ROTVEC = ("rx_rad", "ry_rad", "rz_rad")
QUAT_NORM_TOL = 1e-3             # a quaternion written with 4+ digits has |‖q‖ − 1| below this; beyond: no unit quaternion
ROTVEC_MAX_RAD = 2 * np.pi       # a rotation vector longer than a full turn is degrees, not radians
METRE_REACH_FRACTION = 1 / 100  # tool points all within 1/100 of the arm's reach (mm) are metres
RADIAN_SPAN = 0.5                # all revolute columns within ±2π and one spanning ≥ 0.5: radians
MIN_POSES = 3


@dataclass
class ArmPoses:
    """Measured poses: ``q`` (n, nq) joint values in the joints' units, ``xyz_mm`` (n, 3),
    ``sigma_mm`` (n,) or None, ``temp_c``/``time_s`` (n,) or None; ``rows`` file line per pose;
    ``rot`` (n, 3, 3) or None: the measured tool-frame orientation (tool axes in the measurement frame),
    ``sigma_rad`` (n,) or None its standard deviation per rotation component."""

    q: np.ndarray
    xyz_mm: np.ndarray
    sigma_mm: np.ndarray | None
    temp_c: np.ndarray | None
    time_s: np.ndarray | None
    rows: np.ndarray
    source: str
    layout: str
    rot: np.ndarray | None = None
    sigma_rad: np.ndarray | None = None
    session: np.ndarray | None = None
    """(n,) str: the measurement session of each pose (column ``session``), or None for a one-session file."""

    def __len__(self) -> int:
        return len(self.q)

    def subset(self, idx) -> "ArmPoses":
        idx = np.asarray(idx)
        pick = (lambda a: None if a is None else a[idx])
        return ArmPoses(self.q[idx], self.xyz_mm[idx], pick(self.sigma_mm), pick(self.temp_c), pick(self.time_s),
                        self.rows[idx], self.source, self.layout, pick(self.rot), pick(self.sigma_rad),
                        pick(self.session))


def temperature_summary(poses) -> dict | None:
    """The logged temperature of ``poses`` (their ``temp_c`` column): ``{"mean", "min", "max", "n"}`` in °C, or None
    for a file without it."""
    t = poses.temp_c
    if t is None:
        return None
    return {"mean": float(np.mean(t)), "min": float(np.min(t)), "max": float(np.max(t)), "n": int(len(t))}


def chain_reach_mm(chain) -> float:
    """Sum of the chain's constant translations (mm): an upper bound of its reach."""
    return float(sum(abs(e.value) for e in chain.ets if e.kind == "t"))


def check_joint_values(path, q, rows, chain, qcols=None) -> None:
    """Refuse joint values (``q`` (n, nq) in the joints' units, ``rows`` the file's row numbers) that
    look like radians where degrees are declared, or lie outside the joints' limits: one line naming
    file, row and column (InputError)."""
    qcols = list(chain.joint_columns if qcols is None else qcols)
    rev = np.array([j.type == "revolute" for j in chain.joints])
    if rev.any() and np.all(np.abs(q[:, rev]) <= 2 * np.pi + 1e-9) and np.ptp(q[:, rev], axis=0).max() >= RADIAN_SPAN:
        j = int(np.flatnonzero(rev)[np.argmax(np.ptp(q[:, rev], axis=0))])
        k = int(np.argmax(np.abs(q[:, j])))
        raise InputError(f"{path}: row {rows[k]}, column '{qcols[j]}': every revolute joint value lies within ±2π: "
                         "radians rather than degrees?")
    lo, hi = chain.joint_lo, chain.joint_hi
    bad = (q < lo) | (q > hi)
    if bad.any():
        k, j = np.argwhere(bad)[0]
        raise InputError(f"{path}: row {rows[k]}, column '{qcols[j]}': {q[k, j]:g} {chain.joints[j].unit} is outside "
                         f"the joint's limits [{lo[j]:g}, {hi[j]:g}] of machine {chain.name!r}")


def tracker_grid_columns(t, chain, path):
    """The joint columns ``joint_1 … joint_N`` of table ``t`` when it has the laser-tracker grid layout of
    ``chain`` (those columns in degrees with ``x_t…`` targets and ``x_dif…`` differences), else None;
    InputError where the layout is there but does not fit the chain (a prismatic joint, more joints)."""
    nq = chain.n_joints
    grid_cols = [f"joint_{i + 1}" for i in range(nq)]
    if not all(c in t for c in grid_cols + list(GRID_TARGET) + list(GRID_DIF)):
        return None
    if any(j.type != "revolute" for j in chain.joints):
        raise InputError(f"{path}: the tracker-grid layout (joint_k in degrees) needs an all-revolute chain")
    if f"joint_{nq + 1}" in t:
        raise InputError(f"{path}: column 'joint_{nq + 1}': the file has more joints than machine "
                         f"{chain.name!r} ({nq})")
    return grid_cols


def tracker_grid_points(t) -> np.ndarray:
    """The measured tool points (n, 3) mm of a tracker-grid table: target + difference, in the tracker's frame."""
    return np.stack([t.float(a) + t.float(b) for a, b in zip(GRID_TARGET, GRID_DIF)], 1)


def read_arm_poses(path, chain) -> ArmPoses:
    """Read and check a measured-pose file of ``chain`` (schema or tracker-grid layout)."""
    t = read_table(path, "poses")
    grid_cols = tracker_grid_columns(t, chain, path)
    if all(c in t for c in chain.joint_columns + list(XYZ)):
        layout, qcols = "schema", chain.joint_columns
        xyz = np.stack([t.float(c) for c in XYZ], 1)
    elif grid_cols is not None:
        layout, qcols = "tracker-grid", grid_cols
        xyz = tracker_grid_points(t)
    else:
        have = [c for c in chain.joint_columns + list(XYZ) if c not in t]
        raise InputError(f"{path}: not a measured-pose file of machine {chain.name!r}: missing column(s) {have} "
                         f"(expected {chain.joint_columns + list(XYZ)}, or the tracker-grid layout joint_1.., x_t.., "
                         f"x_dif..); found {t.names}")
    if len(t) < MIN_POSES:
        raise InputError(f"{path}: {len(t)} pose(s); calibration needs many more")
    q = np.stack([t.float(c) for c in qcols], 1)
    rows = np.array([t.row_number(k) for k in range(len(t))])
    reach = chain_reach_mm(chain)
    if np.abs(xyz).max() < METRE_REACH_FRACTION * reach:
        k = int(np.argmax(np.abs(xyz).max(1)))
        j = int(np.argmax(np.abs(xyz[k])))
        raise InputError(f"{path}: row {rows[k]}, column '{(XYZ if layout == 'schema' else GRID_TARGET)[j]}': every "
                         f"tool point lies within {np.abs(xyz).max():.3g} of the base, the arm reaches ~{reach:.0f} mm: "
                         "metres rather than mm?")
    check_joint_values(path, q, rows, chain, qcols)
    opt = {}
    for c in ("sigma_mm", "temp_c", "time_s"):
        opt[c] = t.float(c) if c in t else None
    if opt["sigma_mm"] is not None and np.any(opt["sigma_mm"] <= 0):
        k = int(np.argmax(opt["sigma_mm"] <= 0))
        raise InputError(f"{path}: row {rows[k]}, column 'sigma_mm': expected a positive standard deviation, "
                         f"got {opt['sigma_mm'][k]:g}")
    rot, sigma_rad = read_orientation(t, path, rows)
    return ArmPoses(q, xyz, opt["sigma_mm"], opt["temp_c"], opt["time_s"], rows, str(path), layout, rot, sigma_rad,
                    read_sessions(t, path, rows))


def read_sessions(t, path, rows) -> np.ndarray | None:
    """The ``session`` column (n,) str (labels stripped of blanks), or None without it; InputError on an empty label."""
    if "session" not in t:
        return None
    lab = np.array([v.strip() for v in t.raw("session")], dtype=object)
    empty = lab == ""
    if empty.any():
        k = int(np.argmax(empty))
        raise InputError(f"{path}: row {rows[k]}, column 'session': empty session label (name every row's session, "
                         "or drop the column for a one-session file)")
    return lab


def read_orientation(t, path, rows):
    """(rot (n, 3, 3) or None, sigma_rad (n,) or None) from a table's quaternion or rotation-vector columns."""
    from scipy.spatial.transform import Rotation
    have = {k: [c for c in cols if c in t] for k, cols in (("quaternion", QUAT), ("rotation vector", ROTVEC))}
    for k, cols in (("quaternion", QUAT), ("rotation vector", ROTVEC)):
        if have[k] and len(have[k]) < len(cols):
            raise InputError(f"{path}: column(s) {[c for c in cols if c not in t]} missing: the {k} columns are "
                             f"{list(cols)}, all or none")
    if have["quaternion"] and have["rotation vector"]:
        raise InputError(f"{path}: column '{ROTVEC[0]}': both quaternion {list(QUAT)} and rotation-vector "
                         f"{list(ROTVEC)} columns; give the orientation once")
    if "sigma_rad" in t and not (have["quaternion"] or have["rotation vector"]):
        raise InputError(f"{path}: column 'sigma_rad' without orientation columns {list(QUAT)} or {list(ROTVEC)}")
    if have["quaternion"]:
        wxyz = np.stack([t.float(c) for c in QUAT], 1)
        nrm = np.linalg.norm(wxyz, axis=1)
        bad = np.abs(nrm - 1) > QUAT_NORM_TOL
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(f"{path}: row {rows[k]}, column 'qw': quaternion norm {nrm[k]:.6g}, expected a unit "
                             f"quaternion (qw, qx, qy, qz; |‖q‖ − 1| ≤ {QUAT_NORM_TOL:g})")
        rot = Rotation.from_quat(wxyz[:, [1, 2, 3, 0]] / nrm[:, None]).as_matrix()
    elif have["rotation vector"]:
        rv = np.stack([t.float(c) for c in ROTVEC], 1)
        ang = np.linalg.norm(rv, axis=1)
        if (ang > ROTVEC_MAX_RAD).any():
            k = int(np.argmax(ang > ROTVEC_MAX_RAD))
            j = int(np.argmax(np.abs(rv[k])))
            raise InputError(f"{path}: row {rows[k]}, column '{ROTVEC[j]}': a rotation of {ang[k]:.4g} rad, more "
                             "than a full turn: degrees rather than radians?")
        rot = Rotation.from_rotvec(rv).as_matrix()
    else:
        return None, None
    if "sigma_rad" in t and "sigma_mm" not in t:
        raise InputError(f"{path}: column 'sigma_rad' without 'sigma_mm': the orientation's accuracy is weighed against "
                         "the position's, state both (or neither: σ_rad = σ_mm / ORIENTATION_LEVER_MM)")
    sig = t.float("sigma_rad") if "sigma_rad" in t else None
    if sig is not None and np.any(sig <= 0):
        k = int(np.argmax(sig <= 0))
        raise InputError(f"{path}: row {rows[k]}, column 'sigma_rad': expected a positive standard deviation, "
                         f"got {sig[k]:g}")
    return rot, sig


def write_arm_poses(path, chain, poses: ArmPoses, comments=()) -> None:
    """Write poses in the schema (``q1_deg … x_mm y_mm z_mm`` [+ optional columns]), atomically."""
    cols = {c: poses.q[:, i] for i, c in enumerate(chain.joint_columns)}
    cols.update({c: poses.xyz_mm[:, i] for i, c in enumerate(XYZ)})
    for c in ("sigma_mm", "temp_c", "time_s"):
        if getattr(poses, c) is not None:
            cols[c] = getattr(poses, c)
    if poses.session is not None:
        cols["session"] = np.asarray(poses.session, dtype=object)
    if poses.rot is not None:
        from scipy.spatial.transform import Rotation
        xyzw = Rotation.from_matrix(poses.rot).as_quat()
        cols.update({c: xyzw[:, i] for c, i in zip(QUAT, (3, 0, 1, 2))})
        if poses.sigma_rad is not None:
            cols["sigma_rad"] = poses.sigma_rad
    write_csv(path, cols, header_comments=comments, float_fmt="%.10g")
