"""The parallel machines' rows of ``volcomp benchmark`` (hexapod, tripod): pose calibration (Tikhonov + Morozov)
against the learned pose field, judged by the TRUE residual along the test paths
(:mod:`compensation.app.workflows.benchmark`)."""
from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from errormap.stats import residual_stats

from ..families import family_of
from .benchmark_common import BenchmarkSettings, RowLog, Tracker, bench_row, rng_streams, say

def _rotvec(R) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_rotvec()


def _from_rotvec(v) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(v).as_matrix()


def _oriented(machine) -> bool:
    """Whether a pose of ``machine`` (a parallel machine) has a platform orientation (a hexapod's)."""
    return family_of(machine).facts.platform_orientation


def _tool(machine, tool_length_mm):
    if tool_length_mm is None or not _oriented(machine):
        return machine
    return replace(machine, tool_in_platform_mm=np.array([0.0, 0.0, -tool_length_mm]))


def pose_inputs(oriented: bool, tip_mm, R) -> np.ndarray:
    """Network inputs of commanded poses: with a platform orientation (a hexapod) tip and rotation vector, else
    (a tripod) the tip; (n, 6|3)."""
    return np.hstack([tip_mm, _rotvec(R)]) if oriented else np.asarray(tip_mm, float)


def measured_pose_errors(machine, data):
    """(inputs, outputs) for the learned PKM field from pose measurements (instrument frame = machine).

    Commanded pose: nominal forward kinematics of the commanded drives; error: measured minus
    commanded tip (μm), and for the hexapod the rotation vector of ``R_meas·R_cmdᵀ`` (μrad).
    """
    from errormap.pkm.hexapod import forward_kinematics
    fk = forward_kinematics(machine, machine.drive_to_legs(data.q), check_limits=False)
    d_tip = (data.tip_mm - fk.x) * 1e3
    if _oriented(machine):
        d_ang = _rotvec(np.einsum("nij,nkj->nik", data.rotation, fk.platform2base)) * 1e6
        return pose_inputs(True, fk.x, fk.platform2base), np.hstack([d_tip, d_ang])
    return pose_inputs(False, fk.x, None), d_tip


def learned_pkm_commands(field_, machine, tip_mm, R, tool_length_mm=None, iterations: int = 6):
    """Compensated commanded poses for target poses by iterating the commanded pose.

    The field predicts the pose error at the measurement tool (the machine file's); a path with
    another tool length (``tool_length_mm``) is handled exactly: the platform pose is the same,
    the tip moves by ``R·(t_path - t_meas)``. Fixed point: ``R_cmd = exp(-δθ(cmd))·R_d``,
    ``tip_cmd ← tip_cmd - (reached tip - target tip)``. Returns (tip_cmd (n,3), R_cmd (n,3,3)).
    """
    hexa = _oriented(machine)
    t_meas = machine.tool_in_platform_mm
    t_path = _tool(machine, tool_length_mm).tool_in_platform_mm
    tip_d = np.asarray(tip_mm, float)
    R_d = np.asarray(R, float) if hexa else None
    tip_c, R_c = tip_d.copy(), (R_d.copy() if hexa else None)
    for _ in range(iterations):
        if hexa:
            tip_meas = tip_c + np.einsum("nij,j->ni", R_c, t_meas - t_path)
            e = field_.predict(pose_inputs(True, tip_meas, R_c))
            dtip, dth = e[:, :3] * 1e-3, e[:, 3:] * 1e-6
            R_reach = _from_rotvec(dth) @ R_c
            reach = tip_meas + dtip + np.einsum("nij,j->ni", R_reach, t_path - t_meas)
            R_c = _from_rotvec(-dth) @ R_d
        else:
            reach = tip_c + field_.predict(pose_inputs(False, tip_c, None)) * 1e-3
        tip_c = tip_c - (reach - tip_d)
    return tip_c, R_c


def pkm_true_residual(truth, machine, tip_cmd, R_cmd, tip_target, tool_length_mm=None) -> np.ndarray:
    """True residual (μm), shape (n, 3): tip the truth machine reaches with the nominal inverse
    kinematics of the commanded poses, minus the target tip."""
    from errormap.pkm.hexapod import forward_kinematics, inverse_kinematics
    nom = _tool(machine, tool_length_mm)
    legs = inverse_kinematics(nom, tip_cmd, R_cmd if _oriented(machine) else None)
    q = nom.legs_to_drive(legs)
    tt = _tool(truth.machine, tool_length_mm)
    fk = forward_kinematics(tt, tt.drive_to_legs(q), guess_tip_mm=tip_target, guess_platform2base=R_cmd,
                            check_limits=False)
    return (fk.x - tip_target) * 1e3


def _pkm_paths(machine, s: BenchmarkSettings):
    from ...pkm_interpolation import PosePath, builtin_path
    if family_of(machine).facts.paper_paths:
        return {n: builtin_path(n, s.pkm_path_step_mm) for n in ("sphere", "hyperboloid")}
    from errormap.pkm.hexapod import workspace_poses
    tips, _ = workspace_poses(machine, 200 if not s.quick else 50, seed=rng_streams(s.seed)["pkm_paths"])
    return {"workspace": PosePath(tips, np.broadcast_to(np.eye(3), (len(tips), 3, 3)).copy(),
                                  np.zeros(len(tips), int), None, "workspace")}


def _pkm_conditions(s: BenchmarkSettings) -> dict:
    """``{(n_poses, noise_um): group}``: the pose-count and the noise series."""
    conditions = {}
    for n in s.pkm_poses:
        conditions.setdefault((n, s.pkm_base_noise_um), "poses")
    for nz in s.pkm_noises_um:
        conditions.setdefault((s.pkm_base_poses, nz), "noise")
    return conditions


def _pkm_parametric_row(machine, s: BenchmarkSettings, sim, paths, cname, common, unc) -> dict:
    """Regularised kinematic calibration -> corrected inverse kinematics; its true residual row."""
    from errormap.pkm.calibration import PKMCalibrator

    from ...pkm_interpolation import leg_program, true_path_residual
    kind = machine.kind
    try:
        t0 = time.perf_counter()
        cal = PKMCalibrator(machine, estimate_scales=True, register=False,
                            noise_um=max(common["noise_um"], 0.1)).fit(sim.data)
        fit_s = time.perf_counter() - t0
        per_path, allpos, comp_s, npts = {}, [], 0.0, 0
        for k, p in paths.items():
            t0 = time.perf_counter()
            leg_program(machine, p, cal.machine, check_limits=False)
            comp_s += time.perf_counter() - t0
            npts += len(p)
            r = true_path_residual(sim.truth, cal, p)
            per_path[k] = {"true_rms_um": r["rms_um"], "true_max_um": r["max_um"]}
            allpos.append(r["position_um"])
        st = residual_stats(np.concatenate(allpos))
        return bench_row(machine.name, kind, "parametric", cname, solver="corrected inverse kinematics",
                    fit_seconds=fit_s, compensate_seconds_per_point=comp_s / npts,
                    true_rms_um=st["rms_um"], true_max_um=st["max_um"],
                    per_path=per_path, calibration_success=bool(cal.success), calibration_lambda=float(cal.lam),
                    **common, **unc)
    except Exception as exc:
        return bench_row(machine.name, kind, "parametric", cname, available=False,
                    not_available=f"calibration failed: {type(exc).__name__}: {exc}", **common, **unc)


def _pkm_learned_row(machine, s: BenchmarkSettings, tracker: Tracker, sim, paths, cname, common, unc) -> dict:
    """Pose-error MLP -> iterated commanded pose; its true residual row."""
    from training.pose_field import fit_pose_field
    kind = machine.kind
    try:
        x, y = measured_pose_errors(machine, sim.data)
        fit = fit_pose_field(x, y, hidden=s.pkm_hidden, ridge=s.pkm_ridge, max_iter=s.pkm_train_iter,
                             max_time_s=math.inf if s.pkm_train_s is None else s.pkm_train_s, seed=s.seed)
        per_path, allpos, comp_s, npts = {}, [], 0.0, 0
        for k, p in paths.items():
            t0 = time.perf_counter()
            tip_c, R_c = learned_pkm_commands(fit.field, machine, p.tip_mm, p.platform2base, p.tool_length_mm)
            comp_s += time.perf_counter() - t0
            npts += len(p)
            err = pkm_true_residual(sim.truth, machine, tip_c, R_c, p.tip_mm, p.tool_length_mm)
            st = residual_stats(err)
            per_path[k] = {"true_rms_um": st["rms_um"], "true_max_um": st["max_um"]}
            allpos.append(np.linalg.norm(err, axis=1))
        st = residual_stats(np.concatenate(allpos))
        tr_id = tracker.child(f"{kind}/learned/train/{cname}", fit.params, fit.metrics,
                              {"benchmark_condition": cname})
        return bench_row(machine.name, kind, "learned", cname, solver="iterated commanded pose (6 steps)",
                    fit_seconds=fit.seconds, train_seconds=fit.seconds, training_run_id=tr_id,
                    train_rms_pos_um=fit.metrics["train_rms_pos_um"], train_iterations=fit.metrics["iterations"],
                    compensate_seconds_per_point=comp_s / npts,
                    true_rms_um=st["rms_um"], true_max_um=st["max_um"], per_path=per_path, **common, **unc)
    except Exception as exc:
        return bench_row(machine.name, kind, "learned", cname, available=False,
                    not_available=f"learned PKM path failed: {type(exc).__name__}: {exc}", **common, **unc)


def run_pkm(machine, s: BenchmarkSettings, log: RowLog, out_dir=None) -> list:
    """Both PKM paths on each (n_poses, noise) condition (one, the baseline, on a machine without the paper's
    test paths); true residual along the test paths. Nothing is skipped."""
    from errormap.pkm.simulate import simulate_poses

    from ...pkm_interpolation import true_path_residual
    kind, oriented = machine.kind, _oriented(machine)
    paths = _pkm_paths(machine, s)
    conditions = _pkm_conditions(s) if family_of(machine).facts.paper_paths else \
        {(s.pkm_base_poses, s.pkm_base_noise_um): "baseline"}
    for (n_poses, noise), group in conditions.items():
        cname = f"poses={n_poses}, noise={noise:g}um"
        sim = simulate_poses(machine, n_poses, noise, seed=rng_streams(s.seed)["pkm_poses"],
                             pose_error_mm=s.pkm_pose_error_mm, frame="identity",
                             half_width_mm=s.pkm_half_width_mm if oriented else (150.0, 150.0, 100.0),
                             max_tilt_deg=s.pkm_max_tilt_deg if oriented else 0.0,
                             orientation="quat" if oriented else "none")
        common = {"group": group, "n_poses": n_poses, "noise_um": noise, "n_measurements": n_poses,
                  "test_path": " + ".join(f"{k} ({len(p)} points)" for k, p in paths.items())}
        before = {k: true_path_residual(sim.truth, None, p) for k, p in paths.items()}
        unc = {"uncompensated_rms_um": residual_stats(np.concatenate([b["position_um"] for b in before.values()]))["rms_um"],
               "uncompensated_max_um": float(max(b["max_um"] for b in before.values()))}
        say(f"{kind}: parametric, {cname}")
        log.add(_pkm_parametric_row(machine, s, sim, paths, cname, common, unc))
        say(f"{kind}: learned, {cname}")
        log.add(_pkm_learned_row(machine, s, log.tracker, sim, paths, cname, common, unc))
    return []
