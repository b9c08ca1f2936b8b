"""PKM calibration on a realistic platform: the user's path, validated on held-out poses.

simulate measurements -> ``validated_calibration`` (what ``volcomp calibrate`` runs: rigid fit with the
scales by default, loop on leg residuals, plain baseline, returned model, success verdict) -> evaluate
against the hidden truth. Residuals: **true** = model prediction at the held-out commands minus the true
pose (noise-free, instrument frame), position norm, RMS over the held-out poses; **measured** = the
same against the noisy held-out measurements (what a user sees).

Two independent generators:

* **A** (the project's simulator, ``errormap.pkm.simulate``): the built-in hexapod (base 500 / platform
  400 mm, legs 600-1500 mm) commanded in motor revolutions (71-76 mm/rev, 100 mm offset); joint errors
  N(0, 1 mm), zero lengths U(+-30 mm), scales U(+-5 %) (real-like: 6 %), instrument frame 500 mm / 3 deg
  away, Gaussian position noise, orientation noise = position noise / 100 mm (a mocap marker cluster);
  real-like nonlinearity: per leg quadratic + cubic over 150 mm of travel.
* **B** (written here, sharing only the kinematics): a small platform (base 200 / platform 120 mm, legs
  250-480 mm, leadscrew drives 2 mm/rev, 200 mm offset), poses in a +-40/40/30 mm box, tilts <= 10 deg;
  joint errors U(+-1.5 mm), zero lengths N(0, 20 mm), scales N(0, 3 %) clipped to 6 %, frame anywhere
  in a 2 m box rotated up to 20 deg, Student-t (4 dof) position noise, orientation noise per quaternion
  component, real-like nonlinearity: per leg a slow sine over the leg travel (not in the loop's families).

(a) realistic errors, noise 5 um: default calibrate, true residual within 2x the noise (median, worst).
(b) real-like (scales up to 6 %, mocap-like noise 50 um, unmodelled nonlinearity 0.3 mm): default vs the
plain leg-space least squares and the plain pose-space least squares (objectives compared), the rigid
fit vs the loop's terms.

Usage: python -m benchmarks.run pkm [--quick]
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from errormap.machine import load_machine
from errormap.pkm.calibration import PoseData
from errormap.pkm.pose_model import pose_errors_um
from errormap.pkm.hexapod import forward_kinematics, inverse_kinematics, workspace_poses
from errormap.pkm.legspace import plain_leg_fit
from errormap.pkm.machine_file import hexapod_joints_from_radii
from errormap.pkm.pipeline import validated_calibration
from errormap.pkm.simulate import MachineErrors, simulate_hexapod_poses

N_FIT, N_CHECK = 120, 80
CLEAN_NOISE_UM = 5.0
REALLIKE_NOISE_UM = 50.0
REALLIKE = MachineErrors(scale_range=0.06, nonlinearity_mm=0.3)


def machine_a():
    return replace(load_machine(expect_kind="hexapod"), leg_scale=np.array([71.0, 73.0, 75.0, 72.0, 74.0, 76.0]),
                   leg_offset_mm=np.full(6, 100.0))


def machine_b():
    b, a = hexapod_joints_from_radii(200.0, 120.0, 20.0, 25.0)
    return replace(load_machine(expect_kind="hexapod"), name="small leadscrew hexapod (generator B)",
                   base_joints_mm=b, platform_joints_mm=a, tool_in_platform_mm=np.array([0.0, 0.0, -20.0]),
                   leg_min_mm=np.full(6, 250.0), leg_max_mm=np.full(6, 480.0), leg_scale=np.full(6, 2.0),
                   leg_offset_mm=np.full(6, 200.0), home_tool_tip_mm=np.array([0.0, 0.0, 330.0]))


# -- generator B ---------------------------------------------------------------------------------

def _b_truth(m, rng, nonlinearity_mm):
    k = m.n_legs
    tm = replace(m, base_joints_mm=m.base_joints_mm + rng.uniform(-1.5, 1.5, (k, 3)),
                 platform_joints_mm=m.platform_joints_mm + rng.uniform(-1.5, 1.5, (k, 3)),
                 leg_offset_mm=m.leg_offset_mm + rng.normal(0, 20.0, k),
                 leg_scale=m.leg_scale * (1 + np.clip(rng.normal(0, 0.03, k), -0.06, 0.06)))
    amp = nonlinearity_mm * rng.uniform(0.6, 1.0, k) * rng.choice([-1.0, 1.0], k)
    phase = rng.uniform(0, 2 * np.pi, k)
    home = inverse_kinematics(m, m.home_tool_tip_mm[None])[0]
    t = rng.uniform(-1000, 1000, 3)
    R = Rotation.from_rotvec(np.radians(rng.uniform(5, 20)) * _unit(rng.normal(size=3))).as_matrix()
    return {"machine": tm, "amp": amp, "phase": phase, "home": home, "t": t, "R": R}


def _unit(v):
    return v / np.linalg.norm(v)


def _b_poses(m, truth, n, noise_um, rng):
    tips, Rs = workspace_poses(m, n + 40, rng, (40.0, 40.0, 30.0), 10.0)
    q = m.legs_to_drive(inverse_kinematics(m, tips, Rs))
    tm = truth["machine"]
    legs = tm.drive_to_legs(q) + truth["amp"] * np.sin(2 * np.pi * (m.drive_to_legs(q) - truth["home"]) / 120.0
                                                       + truth["phase"]) - truth["amp"] * np.sin(truth["phase"])
    fk = forward_kinematics(tm, legs, guess_tip_mm=tips, guess_platform2base=Rs, check_limits=False,
                            raise_on_failure=False)
    ok = np.flatnonzero(fk.success)[:n]             # a pose the truth cannot reach is not measured
    if ok.size < n:
        raise RuntimeError("generator B: too many unreachable poses")
    q, fk = q[ok], replace(fk, x=fk.x[ok], platform2base=fk.platform2base[ok])
    tip = fk.x @ truth["R"].T + truth["t"]
    Rm = np.einsum("ij,njk->nik", truth["R"], fk.platform2base)
    s = noise_um * 1e-3 / np.sqrt(2.0)                 # Student-t with 4 dof has variance 2: scale to noise_um
    noisy_tip = tip + s * rng.standard_t(4, (n, 3))
    quat = Rotation.from_matrix(Rm).as_quat() + rng.normal(0, noise_um * 1e-3 / 80.0 / 2, (n, 4))
    noisy_R = Rotation.from_quat(quat / np.linalg.norm(quat, axis=1, keepdims=True)).as_matrix()
    return PoseData(q, noisy_tip, noisy_R, "generator B"), PoseData(q, tip, Rm, "generator B (true)")


def _data(gen, case, seed):
    """(machine, fit, check (noisy), check (true))."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 15, 0 if gen == "A" else 1]))
    noise = CLEAN_NOISE_UM if case == "a" else REALLIKE_NOISE_UM
    if gen == "A":
        m = machine_a()
        sim = simulate_hexapod_poses(m, N_FIT, noise, seed=rng, errors=MachineErrors() if case == "a" else REALLIKE)
        cseed = int(rng.integers(2 ** 31))
        chk = simulate_hexapod_poses(m, N_CHECK, noise, seed=cseed, truth=sim.truth)
        true = simulate_hexapod_poses(m, N_CHECK, 0.0, seed=cseed, truth=sim.truth)
        return m, sim.data, chk.data, true.data, noise, sim.truth.machine
    m = machine_b()
    truth = _b_truth(m, rng, 0.0 if case == "a" else 0.3)
    fit, _ = _b_poses(m, truth, N_FIT, noise, rng)
    chk, true = _b_poses(m, truth, N_CHECK, noise, rng)
    return m, fit, chk, true, noise, truth["machine"]


def run_case(args):
    """One seed of one case; an exception is recorded (``error``), not raised."""
    try:
        return _run_case(args)
    except Exception as exc:   # noqa: BLE001 -- a benchmark row, counted in the summary
        gen, case, seed = args
        return {"gen": gen, "case": case, "seed": seed, "error": f"{type(exc).__name__}: {exc}"}


def _run_case(args):
    gen, case, seed = args
    m, fit, chk, true, noise, tm = _data(gen, case, seed)
    t0 = time.perf_counter()
    v = validated_calibration(m, fit, chk)
    dt = time.perf_counter() - t0
    rms = lambda e: float(np.sqrt(np.mean(e["position_um"] ** 2)))
    base_true = rms(v.baseline.pose_errors_um(true, m))
    final_true = base_true if v.returned != "volcomp" else rms(v.result.pose_errors_um(true))
    out = {"gen": gen, "case": case, "seed": seed, "noise_um": noise, "time_s": dt,
           "before_true": rms(pose_errors_um(m, v.rigid.lcurve["initial_frame"], true)),
           "rigid_true": rms(v.rigid.pose_errors_um(true)), "final_true": final_true, "baseline_true": base_true,
           "final_meas": min(rms(v.after), rms(v.baseline_e)) if v.returned != "volcomp" else rms(v.after),
           "baseline_meas": rms(v.baseline_e), "returned": v.returned, "success": v.success,
           "reasons": v.reasons, "terms": v.loop.get("accepted_terms", []), "terms_kept": v.loop.get("kept"),
           "scale_err_rel": float(np.abs(v.result.machine.leg_scale / tm.leg_scale - 1).max()),
           "lever_mm": v.rigid.lever_mm}
    if case == "b":
        pose = plain_leg_fit(m, fit, objective="pose")
        out["pose_ls_true"] = rms(pose.pose_errors_um(true, m))
    return out


def _med_worst(v):
    v = np.asarray(v, float)
    return f"{np.median(v):.2f} / {v.max():.2f}"


TITLE = "Hexapod calibration (`volcomp calibrate`) against plain least squares, held-out poses"
DATA = (f"two independent generators (A: the built-in hexapod; B: a small leadscrew hexapod written here), {N_FIT} fit "
        f"/ {N_CHECK} held-out poses; (a) realistic errors, {CLEAN_NOISE_UM:g} μm noise, 10 seeds per generator; (b) "
        f"real-like: scales to 6 %, {REALLIKE_NOISE_UM:g} μm mocap-like noise, 0.3 mm unmodelled leg nonlinearity, 5 "
        "seeds per generator (quick: generator A, seed 0 of each case)")


def run(quick: bool, seed: int) -> dict:
    """Median over the seeds of the position RMS on held-out poses (TRUE: against the noise-free pose)."""
    gens = "A" if quick else "AB"
    tasks = [(g, "a", seed + s) for g in gens for s in range(1 if quick else 10)]
    tasks += [(g, "b", seed + s) for g in gens for s in range(1 if quick else 5)]
    rows = [run_case(t) for t in tasks]
    errors = [r for r in rows if "error" in r]
    if errors:
        raise RuntimeError(f"pkm case {errors[0]['gen']}{errors[0]['case']} seed {errors[0]['seed']}: {errors[0]['error']}")
    med = lambda case, k: float(np.median([r[k] for r in rows if r["case"] == case]))  # noqa: E731
    fig = lambda what, v, anchor, av: {"what": what, "value": v, "unit": "μm", "residual": "true",  # noqa: E731
                                       "anchor": anchor, "anchor_value": av}
    return {"figures": [
        fig(f"(a) {CLEAN_NOISE_UM:g} μm noise: returned model, median RMS", med("a", "final_true"),
            "before calibration (nominal, frame fitted)", med("a", "before_true")),
        fig(f"(b) real-like: returned model, median RMS", med("b", "final_true"),
            "plain leg-space least squares", med("b", "baseline_true")),
        fig("(b) real-like: plain pose-space least squares, median RMS", med("b", "pose_ls_true"),
            "plain leg-space least squares", med("b", "baseline_true")),
    ], "notes": [f"Returned the plain baseline instead of the loop's model in "
                 f"{sum(r['returned'] != 'volcomp' for r in rows)} of {len(rows)} cases."]}
