"""Simulated "truth" PKMs and simulated pose measurements (for tests and benchmarks).

A truth machine is the nominal one with perturbed joints, leg zero lengths and (optionally) leg scales, the
rigid-motion part of the base-joint perturbation removed (it is a change of the machine frame, the gauge the
identification uses too); the instrument frame is a rigid transform of the machine frame. Default errors:
:class:`MachineErrors` (scales ±5 %, zero lengths ±30 mm, joints 1 mm, orientation noise of a marker cluster
of ``cluster_radius_mm``, optionally an unmodelled leg nonlinearity ``nonlinearity_mm``); a number
``pose_error_mm`` keeps the older small-error model scaled to that RMS tool-tip error."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..io import write_csv
from .poses import PoseData
from .pose_model import rigid_motion_basis
from .hexapod import forward_kinematics, inverse_kinematics, rotation_to_angles, workspace_poses
from .machine_file import PKM


NONLINEARITY_SPAN_MM = 150.0   # the leg nonlinearity's amplitude is its size 150 mm of leg travel from home


@dataclass(frozen=True)
class MachineErrors:
    """Sizes of the simulated machine errors (see the module docstring).

    ``joint_sd_mm``: joint centre errors (normal, per component); ``offset_range_mm``: leg zero-length
    errors (uniform +-); ``scale_range``: relative leg scale errors (uniform +-); ``nonlinearity_mm``:
    amplitude of the unmodelled leg nonlinearity: its size at
    ``NONLINEARITY_SPAN_MM`` of leg travel from the home pose's leg length (0: none);
    ``nonlinearity_shape``: ``"poly"`` (quadratic + cubic in the normalised command) or ``"sine"``
    (one slow sine period over the leg range, the second generator's shape).
    """

    joint_sd_mm: float = 1.0
    offset_range_mm: float = 30.0
    scale_range: float = 0.05
    nonlinearity_mm: float = 0.0
    nonlinearity_shape: str = "poly"


@dataclass
class Truth:
    """The simulated machine: ``machine`` (perturbed parameters) and the instrument frame
    (``frame_translation_mm`` (3,), ``frame_rotation`` (3, 3): instrument <- machine).
    ``leg_error``: the unmodelled leg nonlinearity, None or ``(shape, coefficients (k, 2))`` (see
    :meth:`leg_error_mm`)."""

    machine: PKM
    nominal: PKM
    frame_translation_mm: np.ndarray
    frame_rotation: np.ndarray
    leg_error: tuple | None = None

    def leg_error_mm(self, q: np.ndarray) -> np.ndarray:
        """Unmodelled leg-length error (mm) at drive commands ``q`` (n, k) -> (n, k); zeros without one."""
        q = np.atleast_2d(np.asarray(q, float))
        if self.leg_error is None:
            return np.zeros_like(q)
        shape, c = self.leg_error
        u = self._leg_u(q)
        if shape == "poly":
            return c[:, 0] * (u ** 2 - 1 / 3) + c[:, 1] * u ** 3
        return c[:, 0] * np.sin(np.pi * u) + c[:, 1] * np.cos(np.pi * u)

    def _leg_u(self, q: np.ndarray) -> np.ndarray:
        """Commanded leg length relative to the home pose's, over ``NONLINEARITY_SPAN_MM``: shape (n, k)."""
        home = inverse_kinematics(self.nominal, self.nominal.home_tool_tip_mm[None])[0]
        return (self.nominal.drive_to_legs(q) - home) / NONLINEARITY_SPAN_MM

    def legs_mm(self, q: np.ndarray) -> np.ndarray:
        """The true leg lengths (n, k) at drive commands ``q`` (n, k)."""
        return self.machine.drive_to_legs(q) + self.leg_error_mm(q)


@dataclass
class SimulatedPoses:
    """Simulated calibration data: ``truth``, ``data`` (:class:`PoseData` as a reader would give it),
    ``columns`` (the CSV columns), ``true_tip_mm`` (n, 3) machine frame, ``noise_um``."""

    truth: Truth
    data: PoseData
    columns: dict
    true_tip_mm: np.ndarray
    noise_um: float

    def write_csv(self, path, comments=()):
        """Write the measurement table (PKM pose-measurement schema) atomically; ``comments``: more header lines."""
        return write_csv(path, self.columns, header_comments=[
            f"simulated {self.truth.machine.kind} poses: noise_um: {self.noise_um}",
            "orientation: fixed-axis X-Y-Z angles (deg) or quaternion qx qy qz qw", *comments])


def _remove_rigid(delta: np.ndarray, points: np.ndarray) -> np.ndarray:
    Q = rigid_motion_basis(points)
    v = delta.ravel()
    return (v - Q @ (Q.T @ v)).reshape(delta.shape)


def perturb_machine(machine: PKM, pose_error_mm: float, seed, scales: bool = True,
                    n_check: int = 200) -> PKM:
    """A truth machine whose RMS tool-tip error (nominal commands, workspace poses) is ``pose_error_mm``.

    Joint, offset and scale perturbations are drawn from ``seed`` with fixed relative sizes
    (joints 1, offsets 1, scales 1e-3 relative to 1 mm) and scaled to the requested error.
    """
    rng = np.random.default_rng(seed)
    k = machine.n_legs
    db = rng.normal(0, 1, (k, 3))
    da = rng.normal(0, 1, (k, 3))
    if machine.kind == "tripod":
        db = da + _remove_rigid(db - da, machine.base_joints_mm - machine.platform_joints_mm)
    else:
        db = _remove_rigid(db, machine.base_joints_mm)
    do = rng.normal(0, 1, k)
    ds = rng.normal(0, 1e-3, k) if scales else np.zeros(k)
    tips, Rs = workspace_poses(machine, n_check, rng)
    q = machine.legs_to_drive(inverse_kinematics(machine, tips, Rs))

    def build(f):
        return replace(machine, base_joints_mm=machine.base_joints_mm + f * db,
                       platform_joints_mm=machine.platform_joints_mm + f * da,
                       leg_offset_mm=machine.leg_offset_mm + f * do, leg_scale=machine.leg_scale * (1 + f * ds))

    f = 1.0
    for _ in range(3):  # nearly linear: a few secant steps
        fk = forward_kinematics(build(f), build(f).drive_to_legs(q), check_limits=False)
        rms = np.sqrt(np.mean(np.sum((fk.x - tips) ** 2, axis=1)))
        f *= pose_error_mm / rms
    return build(f)


def realistic_machine(machine: PKM, seed, errors: MachineErrors = MachineErrors()) -> tuple[PKM, tuple | None]:
    """A truth machine with :class:`MachineErrors` and its leg nonlinearity: ``(PKM, leg_error or None)``."""
    rng = np.random.default_rng(seed)
    k = machine.n_legs
    db = rng.normal(0, errors.joint_sd_mm, (k, 3))
    da = rng.normal(0, errors.joint_sd_mm, (k, 3))
    if machine.kind == "tripod":
        db = da + _remove_rigid(db - da, machine.base_joints_mm - machine.platform_joints_mm)
    else:
        db = _remove_rigid(db, machine.base_joints_mm)
    do = rng.uniform(-errors.offset_range_mm, errors.offset_range_mm, k)
    ds = rng.uniform(-errors.scale_range, errors.scale_range, k)
    truth = replace(machine, base_joints_mm=machine.base_joints_mm + db,
                    platform_joints_mm=machine.platform_joints_mm + da,
                    leg_offset_mm=machine.leg_offset_mm + do, leg_scale=machine.leg_scale * (1 + ds))
    leg_error = None
    if errors.nonlinearity_mm > 0:
        if errors.nonlinearity_shape not in ("poly", "sine"):
            raise ValueError(f"nonlinearity_shape must be 'poly' or 'sine', got {errors.nonlinearity_shape!r}")
        c = errors.nonlinearity_mm * rng.uniform(0.5, 1.0, (k, 2)) * rng.choice([-1.0, 1.0], (k, 2))
        leg_error = (errors.nonlinearity_shape, c)
    return truth, leg_error


def random_frame(seed, translation_mm: float = 500.0, angle_deg: float = 3.0):
    """An instrument frame: translation of ~``translation_mm`` and rotation of ``angle_deg``: (t (3,), R (3, 3))."""
    rng = np.random.default_rng(seed)
    t = rng.normal(0, 1, 3)
    t *= translation_mm / np.linalg.norm(t)
    ax = rng.normal(0, 1, 3)
    R = Rotation.from_rotvec(np.radians(angle_deg) * ax / np.linalg.norm(ax)).as_matrix()
    return t, R


def simulate_poses(machine: PKM, n_poses: int, noise_um: float, seed, pose_error_mm: float | None = None,
                   truth: Truth | None = None, frame: str | tuple = "random", orientation: str = "quat",
                   drive_units: bool = True, lever_mm: float | None = None, scales: bool = True,
                   half_width_mm=(150.0, 150.0, 100.0), max_tilt_deg: float = 15.0,
                   errors: MachineErrors = MachineErrors(), cluster_radius_mm: float = 100.0,
                   noise_seed=None) -> SimulatedPoses:
    """Simulate a calibration campaign on a truth machine.

    ``n_poses`` random workspace poses are commanded with the nominal inverse kinematics; the truth
    machine's forward kinematics gives the reached poses, which are expressed in the instrument frame
    (``frame``: ``"random"``, ``"identity"`` or a ``(t, R)`` pair) and get Gaussian noise of
    ``noise_um`` per position component and ``noise_um / lever_mm`` (rad) per rotation component
    (``lever_mm`` None: ``cluster_radius_mm``, the motion-capture-like default).
    ``pose_error_mm`` None: the truth has the realistic :class:`MachineErrors` ``errors``; a number:
    the older small-error model scaled to that RMS tool-tip error.
    ``orientation``: ``"quat"`` (qx qy qz qw), ``"angles"`` (fixed-axis X-Y-Z deg) or ``"none"``.
    Commands are written as drive units ``q1..`` when ``drive_units`` else as ``l1_mm..``.
    ``noise_seed``: None (default) the noise from the same stream as the poses, after them; a seed redraws only
    the noise (the same truth and poses).
    """
    if n_poses < 1 or noise_um < 0:
        raise ValueError("n_poses must be >= 1 and noise_um >= 0")
    rng = np.random.default_rng(seed)
    if truth is None:
        t, R = (np.zeros(3), np.eye(3)) if frame == "identity" else \
            random_frame(rng) if frame == "random" else frame
        if pose_error_mm is None:
            tm, leg_error = realistic_machine(machine, rng, errors if scales else replace(errors, scale_range=0.0))
        else:
            tm, leg_error = perturb_machine(machine, pose_error_mm, rng, scales=scales), None
        truth = Truth(tm, machine, np.asarray(t), np.asarray(R), leg_error)
    if lever_mm is None:
        lever_mm = cluster_radius_mm
    tips, Rs = workspace_poses(machine, n_poses, rng, half_width_mm, max_tilt_deg)
    legs_cmd = inverse_kinematics(machine, tips, Rs)
    q = machine.legs_to_drive(legs_cmd)
    fk = forward_kinematics(truth.machine, truth.legs_mm(q), guess_tip_mm=tips,
                            guess_platform2base=Rs, check_limits=False)
    noise = noise_um * 1e-3
    Rf, tf = truth.frame_rotation, truth.frame_translation_mm
    r_noise = rng if noise_seed is None else np.random.default_rng(noise_seed)
    meas_tip = fk.x @ Rf.T + tf + r_noise.normal(0, noise, (n_poses, 3))
    k = machine.n_legs
    cols = {}
    if drive_units:
        cols.update({f"q{i + 1}": q[:, i] for i in range(k)})
    else:
        cols.update({f"l{i + 1}_mm": legs_cmd[:, i] for i in range(k)})
    cols.update({"x_mm": meas_tip[:, 0], "y_mm": meas_tip[:, 1], "z_mm": meas_tip[:, 2]})
    meas_R = None
    if machine.kind == "hexapod" and orientation != "none":
        rv_noise = r_noise.normal(0, noise / lever_mm, (n_poses, 3))
        meas_R = Rotation.from_rotvec(rv_noise).as_matrix() @ np.einsum("ij,njk->nik", Rf, fk.platform2base)
        if orientation == "quat":
            qq = Rotation.from_matrix(meas_R).as_quat()
            cols.update({"qx": qq[:, 0], "qy": qq[:, 1], "qz": qq[:, 2], "qw": qq[:, 3]})
        elif orientation == "angles":
            a = rotation_to_angles(meas_R)
            cols.update({"rx_deg": a[:, 0], "ry_deg": a[:, 1], "rz_deg": a[:, 2]})
        else:
            raise ValueError(f"orientation must be 'quat', 'angles' or 'none', got {orientation!r}")
    data = PoseData(q, meas_tip, meas_R, "simulated", np.arange(n_poses) + 2)
    return SimulatedPoses(truth, data, cols, fk.x, noise_um)


def simulate_hexapod_poses(machine: PKM, n_poses: int, noise_um: float, seed, pose_error_mm: float | None = None,
                           **kw) -> SimulatedPoses:
    """:func:`simulate_poses` for a hexapod (full pose, quaternions, drive units by default)."""
    if machine.kind != "hexapod":
        raise ValueError(f"expected a hexapod machine, got {machine.kind!r}")
    return simulate_poses(machine, n_poses, noise_um, seed, pose_error_mm, **kw)


def simulate_tripod_poses(machine: PKM, n_poses: int, noise_um: float, seed, pose_error_mm: float | None = None,
                          **kw) -> SimulatedPoses:
    """:func:`simulate_poses` for a tripod (positions only)."""
    if machine.kind != "tripod":
        raise ValueError(f"expected a tripod machine, got {machine.kind!r}")
    kw.setdefault("orientation", "none")
    kw.setdefault("max_tilt_deg", 0.0)
    return simulate_poses(machine, n_poses, noise_um, seed, pose_error_mm, **kw)
