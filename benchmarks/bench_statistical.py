"""Statistical checks over many seeds: band coverage and decline rates, each a sweep of fixed seeds.

Each sweep repeats "simulate with a known truth → estimate → report a 95 % band (or a decision)" and
compares the rate over its seeds with the range the project states for it. These sweeps were slow-tier
tests; they live here so that the test suite runs each of them once on its first seeds
(``--quick``, tests/test_bench_statistical.py) while the full sweep, whose rate is the figure, runs here.

    python benchmarks/bench_statistical.py                 # every sweep, full: exit 1 if a rate is outside its range
    python benchmarks/bench_statistical.py --quick         # the same code on the first seeds (a smoke run: rates recorded, not judged)
    python benchmarks/bench_statistical.py --only joint_refit_coverage --out /tmp/stat.json

Writes ``statistical_results.json`` (and ``.md``) beside this file unless ``--out`` is given. The
per-repetition invariants (an identifiable set that matches the truth's, a reference fit that reproduces
the truth) are asserted in both modes. Ranges and seeds are those the tests used:

* arm link bands (20 seeds of a simulated UR5 without sag; share of identifiable slots inside their 95 %
  band ≥ 0.90) and the same with sag, fitted with the compliance slots (≥ 0.90, and the DH-only fit below);
* the joint screen's and the joint refit's 95 % intervals of effect coefficients (100 repetitions each,
  90–98 %), the smoothed identification's prediction band (3 truths of each family, 90–98 %);
* the learned residual declines pure noise in at least 19 of 20 seeds;
* a machine-tool chain's ``predict --band 95`` through the user's path (8 seeds of mill-xyz, within 0.035 of
  0.95; the naive ±1.96 σ̂ band ≤ 0.75).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

Z95 = 1.959963984540054
COVERAGE_LO, COVERAGE_HI = 0.90, 0.98   # "contain the truth 90–98 % of the time"
ARM_BAND_COVERAGE_MIN = 0.90            # share of identifiable slots × seeds inside their 95 % band
DECLINE_MIN_SHARE = 19 / 20             # pure noise declined in at least 19 of 20 seeds

# the arm sweeps' setting (as tests/test_arm_calibration.py)
UR5_LO = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0])
UR5_HI = np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
ARM_NOISE_MM = 0.02
# the judge's reference fit reproduces the truth's link errors up to what the slots the fit holds cost: the fits hold
# the slots the data cannot tell apart at the arm's scale (IDENTIFY_RTOL), whose true values leave at most 3.4e-4 mm
# RMS over the 20 seeds (measured; 2e-13 mm with exact dependencies only held) — 1/60 of the tracker noise
REF_FIT_RMS_MAX_MM = 1e-3

CHECK_NOISE_UM = 1.0        # check noise per component (the closed-loop benchmark's)
N_CHECKS = 480              # the fitting part of 800 checks


def _arm_sim(chain, n, seed, sag):
    from errormap.arm_simulate import draw_truth, measure, random_joints
    t = draw_truth(chain, seed, compliance_rad_per_mm=None if sag else np.zeros(chain.n_joints))
    return t, measure(chain, t, random_joints(UR5_LO, UR5_HI, n, [seed, 0]), ARM_NOISE_MM, [seed, 1])


def _clean(chain, p, t):
    """The truth's noise-free, sag-free tool points at the same joints (the judge's side)."""
    from errormap.arm_poses import ArmPoses
    return ArmPoses(p.q, chain.tool_point(p.q, t.errors), None, None, None, p.rows, "truth", "schema")


def arm_link_bands(n_seeds: int) -> dict:
    """Seeds 0..n−1 of a simulated UR5 (link, base and tool errors, tracker noise, no sag; 200 poses): the
    identified slots inside their 95 % bands of the truth's identifiable equivalent (the same estimator on
    the truth's noise-free tool points)."""
    from errormap.estimators import ArmCalibration
    from errormap.machine import load_machine
    ur5 = load_machine("ur5")
    inside = []
    for seed in range(n_seeds):
        t, p = _arm_sim(ur5, 200, seed, sag=False)
        r = ArmCalibration(ur5).fit(p).result_
        eq = ArmCalibration(ur5).fit(_clean(ur5, p, t)).result_
        assert (eq.free == r.free).all(), f"seed {seed}: another identifiable set than the truth's"
        inside.extend(np.abs(r.params - eq.params)[r.free] <= Z95 * r.std[r.free])
    rate = float(np.mean(inside))
    return {"rate": rate, "units": len(inside), "seeds": n_seeds, "range": [ARM_BAND_COVERAGE_MIN, 1.0],
            "within": rate >= ARM_BAND_COVERAGE_MIN}


def arm_compliance_bands(n_seeds: int) -> dict:
    """Seeds 0..n−1 of a simulated UR5 with joint-stiffness sag (200 poses): with the compliance slots the
    link slots lie inside their 95 % bands of the truth's identifiable equivalent (fitted on the estimate's
    identified link slots) at ≥ 0.90; the DH-only fit, which absorbs the sag, does not."""
    from errormap.arm_calibration import fit_model, fit_slots
    from errormap.machine import load_machine
    ur5 = load_machine("ur5")
    inside = {"dh": [], "dh+compliance": []}
    for seed in range(n_seeds):
        t, p = _arm_sim(ur5, 200, seed, sag=True)
        clean = _clean(ur5, p, t)
        for m in inside:
            r = fit_model(ur5, p, m)
            ng = ur5.n_params
            ref = fit_slots(ur5, clean, r.free[:ng])
            assert ref.fit_rms_mm <= REF_FIT_RMS_MAX_MM, f"seed {seed} {m}: the reference fit misses the truth"
            inside[m].extend((np.abs(r.params[:ng] - ref.params) <= Z95 * r.std[:ng])[r.free[:ng]])
    rate, dh = float(np.mean(inside["dh+compliance"])), float(np.mean(inside["dh"]))
    return {"rate": rate, "rate_dh_only": dh, "units": len(inside["dh+compliance"]), "seeds": n_seeds,
            "range": [ARM_BAND_COVERAGE_MIN, 1.0], "within": rate >= ARM_BAND_COVERAGE_MIN > dh}


def _updated(grinder):
    """Truth seed 4, a 40-draw bootstrap identification of its sweeps (2 μm), N_CHECKS checks and the model
    update on them → (smoothed identification, checks, context, update)."""
    from errormap.diagnosis.checks import CheckData
    from errormap.diagnosis.effects import Context, reference
    from errormap.diagnosis.update import update_elements
    from errormap.htm import HTMField
    from errormap.simulator import random_truth
    from errormap.sweeps import simulate_sweeps
    from errormap.uncertainty import smooth_identify
    truth = random_truth(grinder, 4)
    sm = smooth_identify(simulate_sweeps(truth, noise_um=2.0, seed=54), grinder, n_boot=40)
    checks = CheckData.from_columns(truth.check_measurements(N_CHECKS, CHECK_NOISE_UM, seed=5))
    ctx = Context.build(grinder, checks.axes, checks.conditions, reference(grinder, checks.conditions))
    r_id = checks.measured_um - HTMField(grinder, sm.elements_).predict(checks.axes)
    return sm, checks, ctx, update_elements(grinder, sm.covariance_, checks.axes, r_id, sigma_um=CHECK_NOISE_UM)


def joint_screen_coverage(n_rep: int) -> dict:
    """GLS against the update: the elements' deviation from the sweep estimate drawn from the update's own
    prior, the thermal term known; its 95 % interval must hold the truth 90–98 % of the time (and the term
    be found in ≥ 90 % of the repetitions)."""
    from errormap.diagnosis.effects import Candidate, design
    from errormap.diagnosis.joint import joint_screen
    from errormap.machine import load_machine
    grinder = load_machine()
    _, _, ctx, upd = _updated(grinder)
    cand, k_true = Candidate("thermal", "x", "dx_x"), 0.0115
    term_um = design(cand, ctx)[:, 0] * k_true
    L = np.linalg.cholesky(upd.prior_cov + 1e-9 * np.eye(upd.prior_cov.shape[0]))
    rng = np.random.default_rng(np.random.SeedSequence(1301).spawn(1)[0])
    hits = found = 0
    for _ in range(n_rep):
        y = upd.design_ @ (L @ rng.standard_normal(L.shape[0])) + term_um + rng.normal(0, CHECK_NOISE_UM, term_um.size)
        terms, _ = joint_screen(upd, ctx, y.reshape(-1, 3))
        t = next((t for t in terms if t.cand == cand), None)
        if t is None:
            continue
        found += 1
        p = t.parameters()["k_um_per_mm_c"]
        hits += abs(p["value"] - k_true) <= Z95 * p["se"]
    rate = hits / found if found else float("nan")
    return {"rate": rate, "units": found, "repetitions": n_rep, "found_share": found / n_rep,
            "range": [COVERAGE_LO, COVERAGE_HI],
            "within": bool(found >= 0.9 * n_rep and COVERAGE_LO <= rate <= COVERAGE_HI)}


def prediction_coverage(seeds_per_family: int) -> dict:
    """Pooled over seeded truths of both families (seeds 0..n−1 each), 400 random points and three
    components: the identification's 95 % band (J Σ Jᵀ, 100 bootstrap draws) holds the true spatial error."""
    from errormap.htm import HTMField
    from errormap.machine import load_machine
    from errormap.simulator import random_axes
    from errormap.sweeps import simulate_sweeps
    from errormap.truth_families import make_truth
    from errormap.uncertainty import smooth_identify
    grinder = load_machine()
    inside = total = 0
    for fam in ("default", "independent"):
        for s in range(seeds_per_family):
            truth = make_truth(grinder, s, family=fam)
            sm = smooth_identify(simulate_sweeps(truth, noise_um=2.0, seed=s + 500), grinder, n_boot=100, seed=s)
            pts = random_axes(grinder, 400, np.random.default_rng(s + 7))
            err = HTMField(grinder, sm.elements_).predict(pts) - HTMField(grinder, truth.elements).predict(pts)
            sd = np.sqrt(np.diagonal(sm.covariance_.prediction_cov(grinder, pts), axis1=1, axis2=2))
            inside += int(np.sum(np.abs(err) <= Z95 * sd))
            total += err.size
    rate = inside / total
    return {"rate": rate, "units": total, "seeds": 2 * seeds_per_family, "range": [COVERAGE_LO, COVERAGE_HI],
            "within": COVERAGE_LO <= rate <= COVERAGE_HI}


def joint_refit_coverage(n_refit: int) -> dict:
    """The loop's final estimate of kept terms (joint_refit): thermal growth and an X·Z coupling, both of
    which the elements can imitate, the elements' deviation drawn from the update's own prior and σc
    estimated; both terms' 95 % intervals must hold the truth 90–98 % of the time."""
    from errormap.diagnosis.effects import Candidate, EffectTerm, design
    from errormap.diagnosis.joint import joint_refit
    from errormap.machine import load_machine
    grinder = load_machine()
    sm, checks, ctx, upd = _updated(grinder)
    cands = {"k_um_per_mm_c": (Candidate("thermal", "x", "dx_x"), 0.0115),
             "corner_um": (Candidate("interaction", "x*z", "dx_x"), 6.0)}
    signal = sum(design(c, ctx)[:, 0] * v for c, v in cands.values())
    L = np.linalg.cholesky(upd.prior_cov + 1e-9 * np.eye(upd.prior_cov.shape[0]))
    rng = np.random.default_rng(np.random.SeedSequence(1302).spawn(1)[0])
    hits = {k: 0 for k in cands}
    for _ in range(n_refit):
        y = upd.design_ @ (L @ rng.standard_normal(L.shape[0])) + signal + rng.normal(0, CHECK_NOISE_UM, signal.size)
        start = [EffectTerm(c, np.zeros(1), ctx.ref) for c, _ in cands.values()]
        terms, _ = joint_refit(grinder, sm.covariance_, checks.axes, y.reshape(-1, 3), ctx, start)
        for t, (k, (_, v)) in zip(terms, cands.items()):
            p = t.parameters()[k]
            hits[k] += abs(p["value"] - v) <= Z95 * p["se"]
    rates = {k: h / n_refit for k, h in hits.items()}
    return {"rate": min(rates.values()), "rates": rates, "repetitions": n_refit, "range": [COVERAGE_LO, COVERAGE_HI],
            "within": all(COVERAGE_LO <= r <= COVERAGE_HI for r in rates.values())}


def residual_declines_noise(n_seeds: int) -> dict:
    """ResidualRegressor on pure noise (120 points of 3 inputs, σ 0.1, seeds 100..): declined ('none', and
    then predicting exactly zero) in at least 19 of 20 seeds."""
    from training.residual import ResidualRegressor
    declined = 0
    for seed in range(n_seeds):
        rng = np.random.default_rng(100 + seed)
        X = rng.uniform(-1, 1, (120, 3))
        Y = 0.1 * rng.standard_normal((120, 3))
        r = ResidualRegressor(seed=seed).fit(X, Y)
        if r.chosen_ == "none":
            declined += 1
            assert np.all(r.predict(X) == 0.0), f"seed {seed}: declined but predicts non-zero"
    rate = declined / n_seeds
    return {"rate": rate, "declined": declined, "seeds": n_seeds, "range": [DECLINE_MIN_SHARE, 1.0],
            "within": rate >= DECLINE_MIN_SHARE}


MT_TARGET_COVERAGE, MT_COVERAGE_TOL = 0.95, 0.035
"""The chain band's pooled coverage over 8 seeds × 500 points × 3 components within 0.035 of 0.95: the points of
one seed share one identification error, so the seed is the unit (per seed measured 0.901–0.990, sd 0.028: the
pooled mean's standard error ≈ 0.010, 0.035 ≈ 3.5 of them)."""
MT_NAIVE_MAX_COVERAGE = 0.75
"""±1.96 σ̂ (the ball-residual noise) at every point ignores how the chain propagates the parameter errors
(measured 0.47–0.62 per seed): it must stay clearly below the J Σ Jᵀ band's coverage."""


def mt_band_coverage(n_seeds: int, work: Path | None = None) -> dict:
    """The user's path per seed on mill-xyz (simulate → sweeps with tracker-noise seed 100 + seed → identify →
    predict --band 95 at 500 points of the calibrated volume): the hidden truth's error inside [pred ± band] per
    component, pooled over seeds 0..n−1; the naive ±1.96 σ̂ band beside it."""
    import tempfile
    from compensation.app.cli import main
    from compensation.export import volume_points as check_points
    from errormap.io import read_table, write_csv
    from errormap.machine import load_machine
    from errormap.chain_elements import ChainElementSet
    m = load_machine("mill-xyz")
    inside = naive = total = 0
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        for seed in range(n_seeds):
            d = Path(tmp) / str(seed)
            s = ["--machine", "mill-xyz", "--seed", str(seed)]
            assert main(["simulate", *s, "--checks", "20", "--out", str(d / "sim")]) == 0
            # the tracker noise differs per seed: the identification error is the noise through the Gauss-Newton
            # system, nearly independent of the truth, so one noise seed would be one sample n times
            assert main(["sweeps", *s, "--seed-noise", str(100 + seed), "--out", str(d / "sw.csv")]) == 0
            assert main(["identify", str(d / "sw.csv"), "--machine", "mill-xyz", "--out", str(d / "E.json")]) == 0
            el = ChainElementSet.load(d / "E.json", m)
            q = check_points(el, 500, 1000 + seed)
            write_csv(d / "p.csv", {a.column: q[:, j] for j, a in enumerate(m.axes)})
            assert main(["predict", "--machine", "mill-xyz", "--model", str(d / "E.json"), str(d / "p.csv"),
                         "--band", "95", "--out", str(d / "pred.csv")]) == 0
            t = read_table(d / "pred.csv")
            pred = np.stack([t.float(f"{c}_um") for c in ("dx", "dy", "dz")], axis=1)
            band = np.stack([t.float(f"{c}_band95_um") for c in ("dx", "dy", "dz")], axis=1)
            truth = ChainElementSet.load(d / "sim" / "truth_elements.json", m)
            err = np.abs(m.spatial_error(q, truth.values(q)) - pred)
            sigma = json.loads((d / "E.report.json").read_text())["sigma_um"]
            inside += int((err <= band).sum())
            naive += int((err <= Z95 * sigma).sum())
            total += err.size
    rate, naive_rate = inside / total, naive / total
    return {"rate": rate, "rate_naive": naive_rate, "units": total, "seeds": n_seeds,
            "range": [MT_TARGET_COVERAGE - MT_COVERAGE_TOL, MT_TARGET_COVERAGE + MT_COVERAGE_TOL],
            "within": abs(rate - MT_TARGET_COVERAGE) <= MT_COVERAGE_TOL and naive_rate <= MT_NAIVE_MAX_COVERAGE}


SWEEPS = {   # name -> (function, full size, quick size)
    "arm_link_bands": (arm_link_bands, 20, 2),
    "arm_compliance_bands": (arm_compliance_bands, 20, 2),
    "joint_screen_coverage": (joint_screen_coverage, 100, 10),
    "prediction_coverage": (prediction_coverage, 3, 1),
    "joint_refit_coverage": (joint_refit_coverage, 100, 5),
    "residual_declines_noise": (residual_declines_noise, 20, 2),
    "mt_band_coverage": (mt_band_coverage, 8, 1),
}


def run(names=None, quick: bool = False) -> dict:
    """Run the named sweeps (all by default) → {"quick": bool, "sweeps": {name: result + size, cpu_s}}.
    One BLAS thread: the repetitions' matrices are small (several threads spin on a shared machine)."""
    from threadpoolctl import threadpool_limits
    out = {"quick": quick, "sweeps": {}}
    for name in names or SWEEPS:
        fn, full, small = SWEEPS[name]
        t0 = time.process_time()
        with threadpool_limits(1, user_api="blas"):
            res = fn(small if quick else full)
        out["sweeps"][name] = dict(res, size=small if quick else full, cpu_s=round(time.process_time() - t0, 1))
    return out


def _markdown(doc) -> str:
    lines = ["## Statistical sweeps (`python benchmarks/bench_statistical.py" + (" --quick" if doc["quick"] else "")
             + "`)", "", "| sweep | size | rate | range | within | CPU s (this process) |", "|---|---|---|---|---|---|"]
    for name, r in doc["sweeps"].items():
        within = "not judged (quick)" if doc["quick"] else ("yes" if r["within"] else "**no**")
        lines.append(f"| {name} | {r['size']} | {r['rate']:.3f} | {r['range'][0]:.2f}–{r['range'][1]:.2f} | "
                     f"{within} | {r['cpu_s']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="each sweep on its first seeds (a smoke run; rates not judged)")
    ap.add_argument("--only", action="append", choices=sorted(SWEEPS), help="run only this sweep (repeatable)")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("statistical_results.json"))
    a = ap.parse_args(argv)
    doc = run(a.only, a.quick)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    for path, text in ((a.out, json.dumps(doc, indent=2, default=float) + "\n"),
                       (a.out.with_suffix(".md"), _markdown(doc))):
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(path)
    print(_markdown(doc))
    if a.quick:
        return 0
    return 0 if all(r["within"] for r in doc["sweeps"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
