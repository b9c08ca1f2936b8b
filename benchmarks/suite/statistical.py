"""Statistical checks over many seeds: band coverage and decline rates, each a sweep of fixed seeds.

Each sweep repeats "simulate with a known truth → estimate → report a 95 % band (or a decision)" and
compares the rate over its seeds with the range the project states for it. These sweeps were slow-tier
tests; the full sweep, whose rate is the figure, runs here, and CI runs each once on its first seeds through
the suite's quick run (tests/test_benchmarks_suite.py, which also checks the quick record's sizes).

    python -m benchmarks.run statistical            # every sweep, full: each rate beside its range
    python -m benchmarks.run statistical --quick    # the same code on the first seeds (rates recorded, not judged)

The per-repetition invariants (an identifiable set that matches the truth's, a reference fit that reproduces
the truth) are asserted in both modes. Ranges and seeds are those the tests used:

* arm link bands (20 seeds of a simulated UR5 without sag; share of identifiable slots inside their 95 %
  band ≥ 0.90) and the same with sag, fitted with the compliance slots (≥ 0.90, and the DH-only fit below);
* the one loop's 95 % bands of effect coefficients (errormap/diagnosis/chain_loop.py, the grinder through its
  chain): one known term at a time (300 repetitions per term, 90–98 %, :func:`effect_band_coverage`) and two
  accepted terms refitted jointly with the update (100 repetitions, 90–98 %, :func:`joint_refit_coverage`);
  the smoothed identification's prediction band (3 truths of each family, 90–98 %);
* the learned residual declines pure noise in at least 19 of 20 seeds;
* a machine-tool chain's ``predict --band 95`` through the user's path (8 seeds of mill-xyz, within 0.035 of
  0.95; the naive ±1.96 σ̂ band ≤ 0.75).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

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


def chain_setting():
    """The one loop's setting on the grinder's chain: truth seed 4, a 40-draw bootstrap identification of its
    sweeps (2 μm) read as ``volcomp diagnose`` reads it (elements; covariance with its prior_extra), N_CHECKS
    checks → (chain, identified elements, (slot names, stations, prior Σ), checks)."""
    import tempfile
    from compensation.app.workflows.measurement import load_chain_model
    from errormap.diagnosis.chain_loop import ChainChecks
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    from errormap.chain_sweeps import simulated_sweeps
    from errormap.chain_covariance import covariance_path, save_chain_covariance
    from errormap.estimators import Identification
    from errormap.sweeps import sweeps_from_columns
    grinder = load_machine()
    mt = grinder
    truth = make_chain_truth(grinder, 4)
    sm = Identification(grinder, n_boot=40).fit(sweeps_from_columns(simulated_sweeps(truth, noise_um=2.0, seed=54)))
    with tempfile.TemporaryDirectory() as tmp:
        el_path = sm.elements_.save(Path(tmp) / "el.json")
        save_chain_covariance(sm.result_, covariance_path(el_path))
        el, cov, _ = load_chain_model(el_path, mt, prior=True)
    checks = ChainChecks.from_columns(mt, truth.check_measurements(N_CHECKS, CHECK_NOISE_UM, seed=5))
    return mt, el, cov, checks


class ChainSimulator:
    """Repetitions under the one loop's update model on ``chain_setting()``: the element parameters' deviation
    from the sweep estimate drawn from the update's own prior, effect terms with known coefficients, check noise
    N(0, CHECK_NOISE_UM²) per component; the estimate is the loop's joint fit of the terms with the update."""

    def __init__(self, setting):
        from errormap.diagnosis.chain_loop import parameter_matrix
        self.mt, self.el, self.cov, self.checks = setting
        names, stations, C = self.cov
        lam, U = np.linalg.eigh(0.5 * (C + C.T))
        self.L = U * np.sqrt(np.clip(lam, 0.0, None))                       # Δθ = L·z, z ~ N(0, I)
        self.M = parameter_matrix(self.mt, self.el, self.checks.axes, names, stations)   # (n, 3, N)

    def columns(self, terms):
        """The terms' columns at the checks (n, 3, c) and what their coefficients put into the identified
        parameters through the sweeps (N, c), as the loop's joint fit builds them."""
        from errormap.diagnosis.chain_loop import effect_columns, sweep_shift
        ck = self.checks
        E = np.concatenate([effect_columns(self.mt, t.kind, t.axes, ck.axes, ck.conditions, t.shape or None)[0]
                            for t in terms], axis=2)
        S = np.concatenate([sweep_shift(self.mt, self.el, t, *self.cov) for t in terms], axis=1)
        return E, S

    def residual(self, E, S, coef, rng):
        """One repetition's identified-model residual at the checks (n, 3) μm: ``M·(L·z − S·b) + E·b + noise``
        (the sweeps measured the elements with the terms' samples ``S·b`` in them)."""
        d = self.L @ rng.standard_normal(self.L.shape[1]) - S @ coef
        return (np.einsum("nij,j->ni", self.M, d) + np.einsum("nic,c->ni", E, coef)
                + rng.normal(0.0, CHECK_NOISE_UM, E.shape[:2]))

    def joint_fit(self, terms, r):
        """The loop's joint fit (``closed_loop_chain``'s ``joint``: the terms' columns free, the elements with the
        sweep prior and the GCV smoothness prior, σ estimated) on every check → (coefficients (c,), their
        posterior covariance (c, c): the band the loop's Wald χ² uses)."""
        from errormap.diagnosis.chain_loop import update_elements
        E, S = self.columns(terms)
        u = update_elements(self.el, *self.cov, self.checks.axes, r, extra=E, extra_shift=S)
        return u.extra_coef, u.extra_cov


def prediction_coverage(seeds_per_family: int) -> dict:
    """Pooled over seeded truths of both families (seeds 0..n−1 each), 400 random points and three
    components: the identification's 95 % band (J Σ Jᵀ, 100 bootstrap draws) holds the true spatial error."""
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    from errormap.chain_truth import random_axes
    from errormap.chain_sweeps import simulated_sweeps
    from errormap.chain_truth import make_chain_truth
    from errormap.chain_covariance import band_sd
    from errormap.estimators import Identification
    from errormap.sweeps import sweeps_from_columns
    grinder = load_machine()
    inside = total = 0
    for fam in ("default", "independent"):
        for s in range(seeds_per_family):
            truth = make_chain_truth(grinder, s, family=fam)
            sw = sweeps_from_columns(simulated_sweeps(truth, noise_um=2.0, seed=s + 500))
            sm = Identification(grinder, n_boot=100, seed=s).fit(sw)
            pts = random_axes(grinder, 400, np.random.default_rng(s + 7))
            err = ChainField(grinder, sm.elements_).predict(pts) - ChainField(grinder, truth.elements).predict(pts)
            sd = band_sd(grinder, sm.elements_, sm.covariance_, pts)
            inside += int(np.sum(np.abs(err) <= Z95 * sd))
            total += err.size
    rate = inside / total
    return {"rate": rate, "units": total, "seeds": 2 * seeds_per_family, "range": [COVERAGE_LO, COVERAGE_HI],
            "within": COVERAGE_LO <= rate <= COVERAGE_HI}


EFFECT_TRUTHS = {   # name -> (kind, axis words, element, shape, true coefficients); magnitudes as the simulators draw them
    "thermal": ("thermal", ("X",), "dx_x", {}, [0.0115]),
    "reversal": ("reversal", ("Z",), "dz_z", {}, [8.0]),
    "interaction": ("interaction", ("Z", "X"), "dz_z", {}, [6.0]),   # X·Z is represented by the slots: absorbed
    "pitch": ("periodic", ("X",), "dx_x", {"period_mm": 10.0}, [3.0, -2.0]),
    "worm": ("harmonic", ("A",), "ex_a", {"order": 40}, [60.0, 80.0]),
}
PERIOD_MATCH_REL = 0.01
"""A searched period counts as the true one within 1 % (recorded, not judged: :func:`effect_sweep`)."""


def effect_sweep(name: str, n_rep: int, sim: "ChainSimulator | None" = None) -> dict:
    """One known effect at a time on the checks, fitted as the loop fits a term: its joint fit with the update
    at its shape; each coefficient's 95 % interval (the joint fit's posterior covariance) must hold the truth
    90–98 % of the time (``rates``). The loop's band is that of the coefficients GIVEN the shape (it has no band
    for a period or an order), so the judged rates are at the true shape; for a periodic or harmonic term the
    loop's shape search (:func:`_fit_shape`, within the shapes the stations do not resolve) is run on the same
    residual as well and recorded, not judged: the share of repetitions it finds the true shape
    (``shape_found``, a period within :data:`PERIOD_MATCH_REL`) and the coefficients' coverage at the searched
    shape (``rates_at_searched_shape``, a miss where the shape differs)."""
    from errormap.diagnosis.chain_effects import _fit_shape
    from errormap.diagnosis.chain_loop import EffectTerm, shape_band
    sim = sim or ChainSimulator(chain_setting())
    kind, words, element, shape, coef = EFFECT_TRUTHS[name]
    coef = np.asarray(coef, float)
    true_term = EffectTerm(kind, words, element, shape, coef)
    E, S = sim.columns([true_term])
    band = shape_band(sim.el).get(words[0])
    Je = sim.mt.error_jacobian(sim.checks.axes)
    fit_idx = np.arange(len(sim.checks))
    rng = np.random.default_rng(np.random.SeedSequence(1300).spawn(len(EFFECT_TRUTHS))[list(EFFECT_TRUTHS).index(name)])
    hits, hits_searched, found = np.zeros(coef.size, int), np.zeros(coef.size, int), 0
    for _ in range(n_rep):
        r = sim.residual(E, S, coef, rng)
        b, cv = sim.joint_fit([EffectTerm(kind, words, element, shape, np.zeros(coef.size))], r)
        hits += np.abs(b - coef) <= Z95 * np.sqrt(np.diag(cv))
        if not shape:
            continue
        got = _fit_shape(sim.mt, kind, words, sim.checks, fit_idx, r, Je, band=band)[1]
        if got.get("order") != shape.get("order") or abs(got.get("period_mm", 0.0) - shape.get("period_mm", 0.0)) > \
                PERIOD_MATCH_REL * shape.get("period_mm", 0.0):
            continue
        found += 1
        b, cv = sim.joint_fit([EffectTerm(kind, words, element, got, np.zeros(coef.size))], r)
        hits_searched += np.abs(b - coef) <= Z95 * np.sqrt(np.diag(cv))
    out = {"rates": {f"c{i}": float(h / n_rep) for i, h in enumerate(hits)}, "repetitions": n_rep}
    if shape:
        out.update(shape_found=found / n_rep,
                   rates_at_searched_shape={f"c{i}": float(h / n_rep) for i, h in enumerate(hits_searched)})
    return out


def effect_band_coverage(n_rep: int, sim: "ChainSimulator | None" = None) -> dict:
    """:func:`effect_sweep` for every effect of :data:`EFFECT_TRUTHS` (``n_rep`` repetitions each, seeds 1300's
    spawns), the coefficients' 95 % bands pooled by the worst: every rate within 90–98 %. ``sim``: the
    simulator on ``chain_setting()`` (built here when None)."""
    sim = sim or ChainSimulator(chain_setting())
    per = {name: effect_sweep(name, n_rep, sim) for name in EFFECT_TRUTHS}
    rates = [r for v in per.values() for r in v["rates"].values()]
    return {"rate": min(rates), "rate_max": max(rates), "effects": per, "repetitions": n_rep,
            "range": [COVERAGE_LO, COVERAGE_HI], "within": all(COVERAGE_LO <= r <= COVERAGE_HI for r in rates)}


def joint_refit_coverage(n_refit: int, sim: "ChainSimulator | None" = None) -> dict:
    """The loop's final estimate of kept terms (its joint fit with the update): thermal growth on X and a Z·X
    coupling (on Z's own element; X·Z is represented by the grinder's element slots, so the loop absorbs it
    and never fits it), both of which the update alone takes up in part, the elements' deviation drawn from the
    update's own prior and σ estimated; both terms' 95 % intervals (from the joint fit's posterior covariance)
    must hold the truth 90–98 % of the time. ``sim``: the simulator on ``chain_setting()`` (built here when None)."""
    from errormap.diagnosis.chain_loop import EffectTerm
    sim = sim or ChainSimulator(chain_setting())
    truth = {"thermal_x_um_per_mm_c": (EffectTerm("thermal", ("X",), "dx_x", {}, np.zeros(1)), 0.0115),
             "interaction_zx_corner_um": (EffectTerm("interaction", ("Z", "X"), "dz_z", {}, np.zeros(1)), 6.0)}
    terms = [t for t, _ in truth.values()]
    coef = np.array([v for _, v in truth.values()])
    E, S = sim.columns(terms)
    rng = np.random.default_rng(np.random.SeedSequence(1302).spawn(1)[0])
    hits = np.zeros(coef.size, int)
    for _ in range(n_refit):
        b, cv = sim.joint_fit(terms, sim.residual(E, S, coef, rng))
        hits += np.abs(b - coef) <= Z95 * np.sqrt(np.diag(cv))
    rates = {k: float(h / n_refit) for k, h in zip(truth, hits)}
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
    "prediction_coverage": (prediction_coverage, 3, 1),
    "effect_band_coverage": (effect_band_coverage, 300, 1),
    "joint_refit_coverage": (joint_refit_coverage, 100, 1),
    "residual_declines_noise": (residual_declines_noise, 20, 2),
    "mt_band_coverage": (mt_band_coverage, 8, 1),
}
"""Per sweep: its function, the full size (the figure's) and the quick size (the suite's smoke run, not judged).
The two chain sweeps run one repetition quick (were 2 and 5: 3.4 and 1.1 CPU s, now 1.7 and 0.3): each branch of
their code runs in it, the shape search of the periodic and the harmonic term included (both find the true shape
at the first repetition of their fixed seeds, so the refit at the searched shape runs too)."""
ON_CHAIN_SIMULATOR = ("effect_band_coverage", "joint_refit_coverage")
"""The sweeps whose repetitions run on the one loop's setting (:func:`chain_setting`, a 40-draw bootstrap
identification, ~3 CPU s): :func:`run_sweeps` builds its :class:`ChainSimulator` once and hands it to each (its
draws come from each sweep's own seeds; the simulator holds no state that a repetition changes)."""


TITLE = "Statistical sweeps: 95 % band coverage and decline rates over fixed seeds"
DATA = ("simulated UR5 arms (200 poses, 20 μm tracker noise), the grinder's chain with known effect terms on 480 "
        "checks at 1 μm, smoothed identifications of both truth families, pure noise for the learned residual, "
        "mill-xyz's user's path (simulate → sweeps → identify → predict --band 95); seeds fixed per sweep")

WHAT = {
    "arm_link_bands": ("UR5 link slots inside their 95 % band (no sag)", "true"),
    "arm_compliance_bands": ("UR5 link slots inside their 95 % band (sag, compliance slots fitted)", "true"),
    "prediction_coverage": ("smoothed identification's 95 % prediction band holds the truth", "true"),
    "effect_band_coverage": ("one loop's 95 % band of a known effect term's coefficients, lowest of 5 effects", "true"),
    "joint_refit_coverage": ("95 % bands of two terms refitted jointly with the update, lowest coefficient", "true"),
    "residual_declines_noise": ("learned residual declines pure noise (share of seeds)", "none"),
    "mt_band_coverage": ("mill-xyz `predict --band 95` holds the truth", "true"),
}
"""Per sweep: the figure's words and its residual kind (a band judged against the hidden truth, or a decision)."""


def run_sweeps(names=None, quick: bool = False) -> dict:
    """Run the named sweeps (all by default) → {"quick": bool, "sweeps": {name: result + size, cpu_s}}.
    One BLAS thread: the repetitions' matrices are small (several threads spin on a shared machine)."""
    from threadpoolctl import threadpool_limits
    out, shared = {"quick": quick, "sweeps": {}}, {}
    for name in names or SWEEPS:
        fn, full, small = SWEEPS[name]
        t0 = time.process_time()   # the shared simulator's build counts to the first sweep that uses it
        with threadpool_limits(1, user_api="blas"):
            if name in ON_CHAIN_SIMULATOR and "sim" not in shared:
                shared["sim"] = ChainSimulator(chain_setting())
            res = fn(small if quick else full, **({"sim": shared["sim"]} if name in ON_CHAIN_SIMULATOR else {}))
        out["sweeps"][name] = dict(res, size=small if quick else full, cpu_s=round(time.process_time() - t0, 1))
    return out


def run(quick: bool, seed: int) -> dict:
    """The suite's entry: every sweep (its own fixed seeds; ``seed`` is not used) → figures, one per sweep: the
    rate beside the range stated for it; quick rates are recorded, not judged."""
    doc = run_sweeps(quick=quick)
    figures, out_of_range = [], []
    for name, r in doc["sweeps"].items():
        what, residual = WHAT[name]
        lo, hi = r["range"]
        n = r.get("seeds", r.get("repetitions"))
        count = f"{n} {'seed' if 'seeds' in r else 'repetition'}{'s' if n != 1 else ''}"
        figures.append({"what": f"{what} ({count})",
                        "value": round(r["rate"], 3), "unit": "", "residual": residual,
                        "anchor": f"range stated {lo:.3g}–{hi:.3g}", "anchor_value": None,
                        "size": r["size"], "within": bool(r["within"]), "sweep": name})
        if not r["within"]:
            out_of_range.append(name)
    notes = (["Quick: each sweep on its first seeds; rates recorded, not judged."] if quick else
             ["Every rate within its range." if not out_of_range else
              f"Outside its range: {', '.join(out_of_range)}."])
    return {"figures": figures, "notes": notes}
