"""The benchmark's serial-arm rows (``volcomp benchmark --machine ur5``): the user's path, judged by the truth.

Per condition (:data:`compensation.app.workflows.simulate_serial.ARM_EFFECTS`, or none) a seeded truth arm is
measured by a simulated tracker, calibrated as ``volcomp calibrate --check`` does
(:func:`compensation.app.workflows.arm_calibration.calibrate_arm`), and the joint program compensated as
``volcomp compensate`` does; the TRUE residual is the truth's tool point at the compensated joints minus the
program's target (μm, the robot's base frame). Three rows per condition from the same measurements:
``plain LSQ`` (the plain baseline: every DH slot + base + tool), ``parametric`` (the CV-chosen geometric stage)
and ``hybrid`` (the stage ``calibrate`` keeps), each with the held-out MEASURED RMS and the noise floor √3 σ.
docs/reference/benchmark.md ("Serial arms").
"""
from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np

from .benchmark_common import bench_row, say

ARM_SOLVER = "Newton on the calibrated chain, tool orientation kept (volcomp compensate)"


def _landing_um(chain, truth, geo, learner, q_prog, target):
    """(TRUE landing error per program point (n,) μm, compensate seconds per point, converged (n,) bool): the
    base-frame ``target`` turned into the calibration's instrument frame as ``compensate`` does, the truth at the
    compensated joints judged in the robot's base frame (:meth:`errormap.arm_simulate.ArmTruth.base_frame_point`)."""
    from compensation.arm_compensation import solve_joints
    from errormap.arm_frames import from_base_frame
    t0 = time.process_time()
    sol = solve_joints(geo.chain, geo.params, learner, from_base_frame(chain, geo.params, target), q_prog)
    dt = (time.process_time() - t0) / len(q_prog)
    return 1000.0 * np.linalg.norm(truth.base_frame_point(chain, sol.q) - target, axis=1), dt, sol.converged


def run_arm(machine, s, log, out_dir) -> list:
    """Add the arm rows of ``machine`` (a serial chain) to ``log`` (:class:`RowLog`); a failing condition is a
    row marked not available, never skipped (returns no skipped condition)."""
    from errormap.arm_poses import read_arm_poses

    from .arm_calibration import calibrate_arm, errors_mm, held_out_verdict
    from .arm_compensate import nominal_base_points, read_program
    from .simulate_serial import load_serial_truth, simulate_serial
    base = Path(out_dir) / "arms" / machine.name
    floor_um = float(np.sqrt(3) * s.arm_noise_um)
    for k, effects in enumerate(s.arm_effects):
        cname = "+".join(effects) if effects else "none"
        d = base / cname
        say(f"{machine.name}: {cname}: simulate → calibrate → compensate")
        common = {"noise_um": s.arm_noise_um, "noise_floor_um": floor_um, "effect": cname,
                  "n_measurements": s.arm_poses, "n_held_out": s.arm_checks, "measurements_dir": str(d)}
        try:
            simulate_serial(machine, s.truth_seed + k, d, effects=effects, noise_um=s.arm_noise_um,
                            poses=s.arm_poses, checks=s.arm_checks)
            truth = load_serial_truth(d / "truth.json", machine)
            fit, check = read_arm_poses(d / "poses.csv", machine), read_arm_poses(d / "checks.csv", machine)
            q_prog, _ = read_program(d / "program.csv", machine)     # joints only: the targets are the nominal
            target = nominal_base_points(machine, q_prog)              # tool points, as `compensate` takes them
            unc = 1000.0 * np.linalg.norm(truth.base_frame_point(machine, q_prog) - target, axis=1)
            t0 = time.process_time()
            core = calibrate_arm(machine, fit, check, learned=s.arm_learned, k_folds=s.arm_k_folds, seed=s.seed,
                                 log=io.StringIO())
            fit_s = time.process_time() - t0
        except Exception as exc:  # a failing condition is reported, never faked
            for path in ("plain LSQ", "parametric", "hybrid"):
                log.add(bench_row(machine.name, "serial", path, cname, available=False,
                                  not_available=f"{type(exc).__name__}: {exc}", **common))
            continue
        unc_stats = {"uncompensated_rms_um": float(np.sqrt(np.mean(unc ** 2))), "uncompensated_max_um": float(unc.max())}
        kept = core["kept_stage"]
        # the verdict `calibrate` writes (the simulated tracker's σ stated): a failed one marks the hybrid row
        verdict = held_out_verdict(core, check, s.arm_noise_um / 1000.0)
        paths = (("plain LSQ", core["plain_model"], None, "plain geometric LSQ"),
                 ("parametric", core["volcomp_geometric_model"], None, core["geometric_stage"]),
                 ("hybrid", core["geometric_model"], core["kept_learner"], kept))
        for path, geo, learner, stage in paths:
            e, dt, ok = _landing_um(machine, truth, geo, learner, q_prog, target)
            pred = geo.predict(check.q) + (0 if learner is None else learner.predict(check.q))
            held = errors_mm(check, pred)
            extra = ({"learned_kept": learner is not None, "kept_stage": kept, "model_verdict": verdict}
                     if path == "hybrid" else {})
            if not ok.all():
                why = (f"{int((~ok).sum())} of {len(ok)} program points did not converge or left the "
                       "joint limits")
                log.add(bench_row(machine.name, "serial", path, cname, available=False, stage=stage,
                                  not_available=why, **common, **unc_stats, **extra))
                continue
            log.add(bench_row(machine.name, "serial", path, cname, solver=ARM_SOLVER, stage=stage,
                              test_path=f"joint program ({len(q_prog)} well-conditioned points)",
                              true_rms_um=float(np.sqrt(np.mean(e ** 2))), true_max_um=float(e.max()),
                              checks_rms_after_um=float(1000.0 * np.sqrt(np.mean(held ** 2))),
                              fit_seconds=fit_s, compensate_seconds_per_point=dt, **common, **unc_stats,
                              **extra))
    return []
