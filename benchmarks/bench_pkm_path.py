"""PKM parametric-path benchmark: simulate -> calibrate -> compensate -> true residual.

Hexapod with ~1 mm RMS pose error before calibration, Gaussian measurement noise ``noise_um`` per
component (orientation noise noise/500 mm rad), poses in a 300 x 300 x 200 mm box, tilts <= 15 deg.
The true residual is the tool tip the simulated truth machine reaches with the compensated leg
commands minus the target, along the sphere (R 100, 60 deg, apex 980 mm) and hyperboloid (R 100,
20 deg) passes at f = 0.5 mm. Two frame cases: instrument frame = machine frame (known), and an
instrument frame ~500 mm / 3 deg away, estimated (path located in the instrument frame).
Per configuration: median and worst over the seeds (seed s -> simulation seed 1000 + s).
Then, with delta unknown: Morozov (delta estimated by GCV) vs GCV vs the L-curve corner.
Also writes the tripod sensitivity plot (``--plot``).
Usage: python benchmarks/bench_pkm_path.py [--seeds 5] [--out benchmarks/pkm_path_results.md]

The issue-7 benchmark (small errors: ~1 mm RMS, scales estimated, Morozov lambda, 500 mm lever; all pinned
explicitly since issue 15 changed the defaults). The realistic-platform benchmark is benchmarks/suite/pkm.py.
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from compensation.app.reports.tripod_sensitivity import plot_tripod_sensitivity
from compensation.pkm_interpolation import PosePath, builtin_path, true_path_residual
from errormap.io import atomic_write
from errormap.machine import load_machine
from errormap.pkm.calibration import PKMCalibrator
from errormap.pkm.hexapod import workspace_poses
from errormap.pkm.simulate import simulate_hexapod_poses, simulate_tripod_poses
from errormap.pkm.tracker_pose import TrackerSimulator, estimate_head_offset
from errormap.pkm.tripod import sensitivity_vs_lambda


def _fit_and_measure(m, sim, paths, frame, **settings):
    t0 = time.perf_counter()
    settings.setdefault("lambda_rule", "morozov")
    res = PKMCalibrator(m, estimate_scales=True, register=frame != "identity", lever_mm=500.0, **settings).fit(sim.data)
    fit_s = time.perf_counter() - t0
    fr = "machine" if frame == "identity" else "instrument"
    out = {}
    for k, p in paths.items():
        b = true_path_residual(sim.truth, res, p, fr, use_nominal=True) if fr == "instrument" \
            else true_path_residual(sim.truth, None, p)
        a = true_path_residual(sim.truth, res, p, fr)
        out[k] = (b["rms_um"], b["max_um"], a["rms_um"], a["max_um"])
    return res, fit_s, out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="benchmarks/pkm_path_results.md")
    ap.add_argument("--plot", default="benchmarks/pkm_tripod_sensitivity.png")
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    m = load_machine(expect_kind="hexapod")
    paths = {n: builtin_path(n, 0.5) for n in ("sphere", "hyperboloid")}
    seeds = [1000 + s for s in range(args.seeds)]
    lines = ["# PKM parametric path: measured figures", "",
             "Hexapod (built-in machine), ~1 mm RMS tool-tip error before calibration (perturbed joints, leg zero "
             "lengths, leg scales), full-pose measurements (tip + quaternion) with Gaussian noise; identification "
             "of 48 parameters (joints, zero lengths, scales; with an estimated frame 6 of them are the gauge, "
             "fixed explicitly), Tikhonov + Morozov (delta = the noise). "
             "**True residual** (simulated truth machine, compensated commands) along the sphere "
             f"({len(paths['sphere'])} points) and hyperboloid ({len(paths['hyperboloid'])} points) passes; "
             f"{args.seeds} seeds ({seeds[0]}..{seeds[-1]}): RMS as median / worst seed, max as the worst seed. "
             "conv = fits that converged; it = Gauss-Newton iterations (max over seeds); cond = condition number "
             "on the identifiable subspace (median), raw = with the gauge directions (median).", "",
             "| frame | noise um | poses | pass | before RMS um | after RMS median / worst um | after max worst um "
             "| worst RMS / noise | conv | it | cond (raw) | fit s median |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for frame in ("identity", "random"):
        for noise in (5.0, 1.0):
            for n in (30, 60, 120, 240):
                acc = {k: [] for k in paths}
                fit_s, conv, its, cond, cond_raw = [], 0, [], [], []
                for seed in seeds:
                    sim = simulate_hexapod_poses(m, n, noise, seed=seed, frame=frame, pose_error_mm=1.0, lever_mm=500.0)
                    res, fs, out = _fit_and_measure(m, sim, paths, frame, noise_um=noise)
                    fit_s.append(fs)
                    conv += res.success
                    its.append(res.iterations)
                    cond.append(res.condition_number)
                    cond_raw.append(res.condition_number_raw)
                    for k in paths:
                        acc[k].append(out[k])
                for k, v in acc.items():
                    v = np.array(v)
                    lines.append(f"| {'known' if frame == 'identity' else 'estimated'} | {noise:g} | {n} | {k} | "
                                 f"{np.median(v[:, 0]):.0f} | {np.median(v[:, 2]):.2f} / {v[:, 2].max():.2f} | "
                                 f"{v[:, 3].max():.2f} | {v[:, 2].max() / noise:.2f} | {conv}/{len(seeds)} | "
                                 f"{max(its)} | {np.median(cond):.3g} ({np.median(cond_raw):.2g}) | "
                                 f"{np.median(fit_s):.2f} |")
                print(lines[-2], "\n", lines[-1], flush=True)
    # lambda rules with delta unknown
    lines += ["", "Choice of lambda with the noise level unknown (estimated frame; delta estimated from the GCV fit, "
              "delta^2 = RSS / (m - trace H), for Morozov). True residual along the sphere pass, median / worst "
              f"over the {args.seeds} seeds; lambda and estimated delta as medians.", "",
              "| noise um | poses | rule | lambda median | delta est. um median | after RMS median / worst um "
              "| after max worst um | conv |", "|---|---|---|---|---|---|---|---|"]
    sph = {"sphere": paths["sphere"]}
    for noise in (5.0, 1.0):
        for n in (60, 120, 240):
            sims = [simulate_hexapod_poses(m, n, noise, seed=seed, frame="random", pose_error_mm=1.0, lever_mm=500.0)
                    for seed in seeds]
            for rule in PKMCalibrator.RULES:
                lam, dl, v, conv = [], [], [], 0
                for sim in sims:
                    res, _, out = _fit_and_measure(m, sim, sph, "random", lambda_rule=rule)
                    lam.append(res.lam)
                    dl.append(res.delta_mm * 1e3)
                    v.append(out["sphere"])
                    conv += res.success
                v = np.array(v)
                lines.append(f"| {noise:g} | {n} | {rule} | {np.median(lam):.3g} | {np.median(dl):.2f} | "
                             f"{np.median(v[:, 2]):.2f} / {v[:, 2].max():.2f} | {v[:, 3].max():.2f} | {conv}/{len(sims)} |")
                print(lines[-1], flush=True)
    # tripod
    tri = load_machine(expect_kind="tripod")
    lines += ["", "Tripod (3-TPT): leg zero lengths + hinge + scale identification, positions only, known frame, "
              "true residual at 200 random workspace points (seed 3):", "",
              "| noise um | poses | before RMS um | after RMS / max um |", "|---|---|---|---|"]
    tips, _ = workspace_poses(tri, 200, seed=7)
    grid = PosePath(tips, np.broadcast_to(np.eye(3), (200, 3, 3)), np.zeros(200, int), None, "grid")
    for n in (30, 60, 120):
        sim = simulate_tripod_poses(tri, n, 5.0, seed=3, frame="identity", pose_error_mm=1.0)
        res = PKMCalibrator(tri, estimate_scales=True, register=False, noise_um=5.0, lambda_rule="morozov").fit(sim.data)
        b, a = true_path_residual(sim.truth, None, grid), true_path_residual(sim.truth, res, grid)
        lines.append(f"| 5 | {n} | {b['rms_um']:.0f} | {a['rms_um']:.2f} / {a['max_um']:.2f} |")
    lam = np.array([4.25, 5.0, 5.5, 6.0, 6.5])
    K = sensitivity_vs_lambda(tri, lam)
    st = plot_tripod_sensitivity(tri, args.plot)
    Km = st["K_map"]
    col = Km[0]
    ok = np.isfinite(col)
    lines += ["", "Tripod sensitivity K = ||A^-1||_inf at the workspace centre against lambda = l / c: "
              + ", ".join(f"lambda {l:g}: {k:.2f}" for l, k in zip(lam, K))
              + f". On the axis K goes from {col[ok][0]:.2f} at {st['heights_mm'][ok][0]:.0f} mm from the fixed "
              f"platform to {col[ok][-1]:.2f} at {st['heights_mm'][ok][-1]:.0f} mm; over the section "
              f"{np.nanmin(Km):.2f}..{np.nanmax(Km):.2f}. Plot: `{args.plot}` (`volcomp interpolate --machine "
              "tripod.toml --sensitivity-plot FILE`).", ""]
    sim = TrackerSimulator(noise_um=20.0)
    lines.append("Rotation fitting (tracker noise 20 um, true SR = [189.124, -74.836, 281.648] mm): "
                 + ", ".join(f"N={n}: |error| {1e3 * np.linalg.norm(estimate_head_offset(sim, n, seed=3).x - sim.sr):.1f} um"
                             for n in (1, 10, 100, 400)))
    lines += ["", "Notes: every fit converged (3-4 Gauss-Newton iterations). Before the gauge fix (explicit elimination "
              "of the 6 frame <-> base-joint rigid-motion directions, truncation of structural null directions, "
              "Armijo line search), seed 1001 at 120 poses / estimated frame did not converge in 30 iterations "
              "(true residual 60-130 um): its least-squares residual lay above the Morozov target, lambda fell to "
              "~0 and the rounding-level gauge singular values amplified noise into 20-60 mm steps. With delta "
              "unknown the GCV estimate of delta is within a few % of the truth; Morozov with tau = 1 and that "
              "delta over-regularises (target tau*delta*sqrt(m), while the attainable residual is about "
              "delta*sqrt(m - p)), so GCV (and at 1 um the L-curve corner) give the lower true residual here."]
    lines += ["", f"Measured with `python benchmarks/bench_pkm_path.py --seeds {args.seeds}` on {platform.machine()} "
              f"({os.cpu_count()} CPUs, shared with other jobs; BLAS single-threaded inside the fit); fit times "
              "include the first call's torch warm-up."]
    with atomic_write(args.out) as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
