"""PKM pose measurements: the file (:func:`read_poses` → :class:`PoseData`) and the plausibility checks
before a calibration (refuse what we cannot interpret).

Each check compares the measurements with the nominal forward kinematics of the commands, independent of the
unknown instrument frame: position units (:func:`check_position_units`, the tips' spread against the
nominal's, ``UNIT_RATIO_RANGE``), orientation convention (:func:`check_orientation_convention`: the scatter
of ``R_measured R_nominalᵀ`` scored against w-x-y-z, radians and the inverse rotation) and degenerate pose
sets (:func:`check_pose_set`). Thresholds and examples: ``docs/explanation/parallel-kinematics.md``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..io import InputError, read_table
from ..units import length_unit_guess
from .hexapod import angles_to_rotation, forward_kinematics, quat_to_rotation
from .machine_file import PKM

UNIT_RATIO_RANGE = (0.8, 1.25)   # measured / nominal tip spread; machine errors change it by a few % at most
ORIENT_SCATTER_MIN_DEG = 3.0     # the right convention scatters by the machine's orientation errors (< ~1 deg)
ORIENT_RATIO = 3.0               # ... and an alternative must be this much more consistent to be named
MIN_LEG_SPREAD = 0.01            # a leg's commands must span >= 1 % of its range


def _spread(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((x - x.mean(0)) ** 2, axis=1))))


def check_position_units(source, machine: PKM, tip_mm: np.ndarray, nominal_tip_mm: np.ndarray) -> None:
    """Refuse tips whose spread does not match the nominal kinematics' (wrong length unit)."""
    sn = _spread(nominal_tip_mm)
    if sn < 1e-6:
        return
    ratio = _spread(tip_mm) / sn
    if UNIT_RATIO_RANGE[0] <= ratio <= UNIT_RATIO_RANGE[1]:
        return
    guess = length_unit_guess(ratio)  # the shared unit names (errormap/units.py)
    raise InputError(f"{source}: columns 'x_mm', 'y_mm', 'z_mm': the measured tips spread {ratio:.4g} times as far as "
                     f"the commanded poses do (expected 1 for mm){guess}")


def orientation_scatter_deg(R_meas: np.ndarray, R_nom: np.ndarray) -> float:
    """RMS angle (deg) of ``R_meas,i R_nom,i^T`` about their mean rotation (the frame rotation)."""
    Q = Rotation.from_matrix(np.einsum("nij,nkj->nik", R_meas, R_nom))
    mean = Q.mean()
    return float(np.degrees(np.sqrt(np.mean((mean.inv() * Q).magnitude() ** 2))))


def check_orientation_convention(source, R_nom: np.ndarray, candidates: dict) -> None:
    """``candidates``: {label: rotations (n, 3, 3)}, the file's own interpretation first. Refuse when an
    alternative fits the commanded poses much better than the file's stated convention."""
    labels = list(candidates)
    sc = {k: orientation_scatter_deg(v, R_nom) for k, v in candidates.items()}
    own = sc[labels[0]]
    best = min(labels[1:], key=lambda k: sc[k]) if len(labels) > 1 else None
    if best is not None and own > ORIENT_SCATTER_MIN_DEG and own > ORIENT_RATIO * sc[best]:
        raise InputError(f"{source}: orientation columns: read as {labels[0]} the orientations scatter by "
                         f"{own:.3g} deg about the commanded poses, read as {best} by {sc[best]:.3g} deg: "
                         f"this file looks like {best}; convert it to {labels[0]}")


def quaternion_candidates(quat_as_read: np.ndarray) -> dict:
    """The file's x-y-z-w reading and the alternatives: w-x-y-z order, the conjugate (inverse rotation)."""
    q = quat_as_read / np.linalg.norm(quat_as_read, axis=1, keepdims=True)
    return {"qx qy qz qw (x-y-z-w)": Rotation.from_quat(q).as_matrix(),
            "w-x-y-z": Rotation.from_quat(np.roll(q, -1, axis=1)).as_matrix(),
            "the inverse rotation (instrument2platform)": Rotation.from_quat(q).inv().as_matrix()}


def angle_candidates(angles: np.ndarray) -> dict:
    """The file's degrees reading and the alternatives: radians, intrinsic x-y-z."""
    return {"fixed-axis X-Y-Z degrees": angles_to_rotation(angles),
            "radians": Rotation.from_euler("xyz", angles).as_matrix(),
            "intrinsic X-Y-Z degrees": Rotation.from_euler("XYZ", angles, degrees=True).as_matrix()}


def check_pose_set(source, machine: PKM, q: np.ndarray, n_unknowns: int, d: int, rows=None) -> None:
    """Refuse identical or degenerate pose sets (one line naming the file)."""
    n, k = q.shape
    distinct = np.unique(np.round(q, 9), axis=0)
    if len(distinct) == 1:
        raise InputError(f"{source}: all {n} poses have the same leg commands: a calibration needs poses spread "
                         "over the workspace")
    if len(distinct) * d < n_unknowns:
        raise InputError(f"{source}: only {len(distinct)} distinct poses among {n} rows give {len(distinct) * d} "
                         f"equations for {n_unknowns} unknowns; measure more, different poses")
    rng = np.abs(machine.legs_to_drive(machine.leg_max_mm[None])[0] - machine.legs_to_drive(machine.leg_min_mm[None])[0])
    still = np.flatnonzero(np.ptp(q, axis=0) < MIN_LEG_SPREAD * rng)
    if still.size:
        raise InputError(f"{source}: column 'q{still[0] + 1}' (or 'l{still[0] + 1}_mm'): the leg's commands span "
                         f"{np.ptp(q[:, still[0]]):.3g} drive units, under {MIN_LEG_SPREAD:.0%} of its range: "
                         "its zero length and scale cannot be identified")


def check_measurements(source, machine: PKM, q: np.ndarray, tip_mm: np.ndarray, orientation_candidates: dict | None):
    """All input checks that need the nominal kinematics (units, orientation convention)."""
    fk = forward_kinematics(machine, machine.drive_to_legs(q), check_limits=False, raise_on_failure=False)
    ok = fk.success
    if ok.sum() < 3:
        return
    check_position_units(source, machine, tip_mm[ok], fk.x[ok])
    if orientation_candidates:
        check_orientation_convention(source, fk.platform2base[ok], {k: v[ok] for k, v in orientation_candidates.items()})



@dataclass
class PoseData:
    """Calibration measurements.

    ``q``: drive commands, shape (n, k); ``tip_mm``: measured tool tip (instrument frame), shape
    (n, 3); ``rotation``: measured orientation (``platform2instrument``), shape (n, 3, 3), or None
    (position only); ``source``: where it came from; ``rows``: file row numbers, shape (n,);
    ``leg_correction_mm``: fixed leg-length terms (n, k) added to ``s q + o`` in the fit (accepted leg terms).
    """

    q: np.ndarray
    tip_mm: np.ndarray
    rotation: np.ndarray | None = None
    source: str = ""
    rows: np.ndarray | None = None
    leg_correction_mm: np.ndarray | None = None

    def __len__(self):
        return len(self.q)

    def subset(self, idx) -> "PoseData":
        return PoseData(self.q[idx], self.tip_mm[idx], None if self.rotation is None else self.rotation[idx],
                        self.source, None if self.rows is None else self.rows[idx],
                        None if self.leg_correction_mm is None else self.leg_correction_mm[idx])


def read_poses(path, machine: PKM) -> PoseData:
    """Read a PKM pose-measurement CSV (schema in docs/reference/file-formats.md / docs/explanation/parallel-kinematics.md).

    Legs: ``l1_mm..lk_mm`` (commanded lengths, converted to drive units with the machine file's
    nominal scale/offset) or ``q1..qk``; pose: ``x_mm, y_mm, z_mm`` plus, for the hexapod,
    ``rx_deg, ry_deg, rz_deg`` (fixed-axis X-Y-Z) or ``qx, qy, qz, qw``, or neither (position only).
    Errors name the file, row and column.
    """
    t = read_table(path, "poses")
    k = machine.n_legs
    lcols, qcols = [f"l{i + 1}_mm" for i in range(k)], [f"q{i + 1}" for i in range(k)]
    if all(c in t for c in qcols):
        q = np.stack([t.float(c) for c in qcols], 1)
    elif all(c in t for c in lcols):
        q = machine.legs_to_drive(np.stack([t.float(c) for c in lcols], 1))
    else:
        raise InputError(f"{t.path}: missing leg columns: need {lcols} or {qcols}; found columns {t.names}")
    t.require("x_mm", "y_mm", "z_mm")
    tip = np.stack([t.float(c) for c in ("x_mm", "y_mm", "z_mm")], 1)
    rot, cands = None, None
    if machine.kind == "hexapod":
        if all(c in t for c in ("qx", "qy", "qz", "qw")):
            quat = np.stack([t.float(c) for c in ("qx", "qy", "qz", "qw")], 1)
            norm = np.linalg.norm(quat, axis=1)
            bad = np.flatnonzero(np.abs(norm - 1) > 1e-3)
            if bad.size:
                raise InputError(f"{t.path}: row {t.row_number(bad[0])}, columns 'qx'..'qw': expected a unit "
                                 f"quaternion (order qx qy qz qw), got norm {norm[bad[0]]:.6g}")
            rot = quat_to_rotation(quat / norm[:, None])
            cands = quaternion_candidates(quat)
        elif all(c in t for c in ("rx_deg", "ry_deg", "rz_deg")):
            ang = np.stack([t.float(c) for c in ("rx_deg", "ry_deg", "rz_deg")], 1)
            rot = angles_to_rotation(ang)
            cands = angle_candidates(ang)
        elif any(c in t for c in ("qx", "qy", "qz", "qw", "rx_deg", "ry_deg", "rz_deg")):
            raise InputError(f"{t.path}: incomplete orientation columns: need all of qx qy qz qw or of "
                             f"rx_deg ry_deg rz_deg; found columns {t.names}")
    if len(t) == 0:
        raise InputError(f"{t.path}: no data rows")
    check_measurements(t.path, machine, q, tip, cands)
    return PoseData(q, tip, rot, str(t.path), np.array([t.row_number(i) for i in range(len(t))]))
