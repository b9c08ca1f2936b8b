"""Issue 13, part 5: Monte Carlo coverage of the reported 95 % bands.

Each test repeats "simulate with a known truth → estimate → report a 95 % band" with fixed
seeds and counts how often the band holds the truth. The issue asks for 90–98 %.

* effect parameters as the effect search reports them (:meth:`EffectSelector.joint_fit`,
  the periods by nonlinear least squares), one known effect at a time on the check layout;
* effect parameters of the joint screen (GLS against the model update,
  :func:`errormap.diagnosis.joint.joint_screen`), with the elements' deviation drawn from
  the update's own prior;
* predictions of the smoothed identification (``J Σ Jᵀ`` band), over seeded truths of both
  families (slow: each repetition is a whole bootstrap identification).
"""
import numpy as np
import pytest
from threadpoolctl import threadpool_limits  # comes with scikit-learn (a dependency)

from errormap.diagnosis.checks import CheckData
from errormap.diagnosis.effects import Candidate, Context, EffectTerm, basis, design, reference
from errormap.diagnosis.joint import joint_screen
from errormap.diagnosis.selection import EffectSelector
from errormap.diagnosis.update import update_elements
from errormap.htm import HTMField
from errormap.simulator import random_axes, random_truth
from errormap.sweeps import simulate_sweeps
from errormap.truth_families import make_truth
from errormap.uncertainty import smooth_identify

Z95 = 1.959963984540054
COVERAGE_LO, COVERAGE_HI = 0.90, 0.98   # issue 13: "contain the truth 90–98 % of the time"


@pytest.fixture(autouse=True)
def one_blas_thread():
    """The repetitions' matrices are small: one BLAS thread (several spin on a shared machine:
    measured 10× the CPU time for the GLS screen)."""
    with threadpool_limits(1, user_api="blas"):
        yield


N_REP = 300          # binomial SE of a 95 % coverage over 300 repetitions: 1.3 %; the range is ≥ 2.3 SE from 0.95
NOISE_UM = 1.0       # check noise per component, as in the benchmark
N_CHECKS = 480       # the fitting part of 800 checks

# (candidate, true linear coefficients, period_mm or order); magnitudes as the simulators draw them
EFFECTS = {
    "thermal": (Candidate("thermal", "x", "dx_x"), [0.0115], None),
    "reversal": (Candidate("reversal", "z", "dz_z"), [8.0], None),
    "interaction": (Candidate("interaction", "x*z", "dx_x"), [6.0], None),
    "pitch": (Candidate("periodic", "x", "dx_x"), [3.0, -2.0], 10.0),
    "worm": (Candidate("harmonic", "a", "ex_a"), [60.0, 80.0], 40),
}


@pytest.fixture(scope="module")
def layout(grinder):
    truth = random_truth(grinder, 0)
    c = truth.check_measurements(N_CHECKS, 1.0, seed=3)
    checks = CheckData.from_columns(c)
    ctx = Context.build(grinder, checks.axes, checks.conditions, reference(grinder, checks.conditions))
    return checks, ctx


def _truth_params(cand, coef, per):
    """The reported parameters' true values (names as EffectTerm.parameters gives them)."""
    t = EffectTerm(cand, np.asarray(coef, float), {}, per if cand.kind == "periodic" else None,
                   per if cand.kind == "harmonic" else None, np.zeros((3, 3)))
    p = t.parameters()
    return {k: v["value"] for k, v in p.items() if k != "order"}


@pytest.mark.parametrize("name", list(EFFECTS))
def test_effect_parameter_bands_cover_the_truth(layout, name):
    _, ctx = layout
    cand, coef, per = EFFECTS[name]
    period = per if cand.kind == "periodic" else None
    order = per if cand.kind == "harmonic" else None
    signal = (ctx.column(cand.element) * (basis(cand, ctx, period, order) @ np.asarray(coef, float))[:, None])
    truth = _truth_params(cand, coef, per)
    rng = np.random.default_rng(np.random.SeedSequence(1300).spawn(len(EFFECTS))[list(EFFECTS).index(name)])
    sel = EffectSelector()
    hits = {k: 0 for k in truth}
    for _ in range(N_REP):
        r = signal + rng.normal(0.0, NOISE_UM, signal.shape)
        found_per, found_order = sel._search(cand, ctx, r)  # the period/order as the search finds it
        (term,), _, _ = EffectSelector.joint_fit(ctx, r, [(cand, found_per, found_order)])
        for k, p in term.parameters().items():
            if k in hits:
                v, t = p["value"], truth[k]
                if k == "phase_rad":
                    v = t + np.angle(np.exp(1j * (v - t)))  # same branch as the truth
                hits[k] += abs(v - t) <= Z95 * p["se"]
    for k, h in hits.items():
        assert COVERAGE_LO <= h / N_REP <= COVERAGE_HI, f"{name} {k}: coverage {h / N_REP:.3f}"


@pytest.mark.slow
def test_joint_screen_bands_cover_the_truth(grinder):
    """GLS against the update: the elements' deviation from the sweep estimate drawn from the
    update's own prior, the thermal term known; its 95 % interval must hold the truth."""
    truth = random_truth(grinder, 4)
    sm = smooth_identify(simulate_sweeps(truth, noise_um=2.0, seed=54), grinder, n_boot=40)
    checks = CheckData.from_columns(truth.check_measurements(N_CHECKS, NOISE_UM, seed=5))
    ctx = Context.build(grinder, checks.axes, checks.conditions, reference(grinder, checks.conditions))
    r_id = checks.measured_um - HTMField(grinder, sm.elements_).predict(checks.axes)
    upd = update_elements(grinder, sm.covariance_, checks.axes, r_id, sigma_um=NOISE_UM)
    cand = Candidate("thermal", "x", "dx_x")
    k_true = 0.0115
    term_um = (design(cand, ctx)[:, 0] * k_true)
    L = np.linalg.cholesky(upd.prior_cov + 1e-9 * np.eye(upd.prior_cov.shape[0]))
    rng = np.random.default_rng(np.random.SeedSequence(1301).spawn(1)[0])
    hits = found = 0
    for _ in range(N_REP // 3):  # 100 repetitions: each is one GLS screen over the library
        y = upd.design_ @ (L @ rng.standard_normal(L.shape[0])) + term_um + rng.normal(0, NOISE_UM, term_um.size)
        terms, _ = joint_screen(upd, ctx, y.reshape(-1, 3))
        t = next((t for t in terms if t.cand == cand), None)
        if t is None:
            continue
        found += 1
        p = t.parameters()["k_um_per_mm_c"]
        hits += abs(p["value"] - k_true) <= Z95 * p["se"]
    assert found >= 0.9 * (N_REP // 3)
    assert COVERAGE_LO <= hits / found <= COVERAGE_HI, f"coverage {hits / found:.3f} over {found}"


PRED_SEEDS = {"default": (0, 1, 2), "independent": (0, 1, 2)}
N_POINTS = 400


@pytest.mark.slow
def test_prediction_bands_cover_the_truth(grinder):
    """Pooled over seeded truths of both families, points and components: the identification's
    95 % band holds the true spatial error 90–98 % of the time."""
    inside = total = 0
    for fam, seeds in PRED_SEEDS.items():
        for s in seeds:
            truth = make_truth(grinder, s, family=fam)
            sm = smooth_identify(simulate_sweeps(truth, noise_um=2.0, seed=s + 500), grinder, n_boot=100, seed=s)
            pts = random_axes(grinder, N_POINTS, np.random.default_rng(s + 7))
            err = HTMField(grinder, sm.elements_).predict(pts) - HTMField(grinder, truth.elements).predict(pts)
            sd = np.sqrt(np.diagonal(sm.covariance_.prediction_cov(grinder, pts), axis1=1, axis2=2))
            inside += int(np.sum(np.abs(err) <= Z95 * sd))
            total += err.size
    assert COVERAGE_LO <= inside / total <= COVERAGE_HI, f"coverage {inside / total:.3f}"


N_REFIT = 100   # joint refits (each four model updates); binomial SE of a 95 % coverage: 2.2 %


@pytest.mark.slow
def test_joint_refit_bands_cover_the_truth(grinder):
    """The loop's final estimate of kept terms (:func:`errormap.diagnosis.joint.joint_refit`):
    thermal growth and an X·Z coupling, both of which the elements can imitate, with the
    elements' deviation from the sweep estimate drawn from the update's own prior and σc
    estimated (not given); both terms' 95 % intervals must hold the truth 90–98 % of the time.
    (The effect search's own band, on what the update left, covered the interaction 6/19 and
    thermal 13/20 in the loop benchmark.)"""
    from errormap.diagnosis.joint import joint_refit
    truth = random_truth(grinder, 4)
    sm = smooth_identify(simulate_sweeps(truth, noise_um=2.0, seed=54), grinder, n_boot=40)
    checks = CheckData.from_columns(truth.check_measurements(N_CHECKS, NOISE_UM, seed=5))
    ctx = Context.build(grinder, checks.axes, checks.conditions, reference(grinder, checks.conditions))
    r_id = checks.measured_um - HTMField(grinder, sm.elements_).predict(checks.axes)
    upd = update_elements(grinder, sm.covariance_, checks.axes, r_id, sigma_um=NOISE_UM)
    cands = {"k_um_per_mm_c": (Candidate("thermal", "x", "dx_x"), 0.0115),
             "corner_um": (Candidate("interaction", "x*z", "dx_x"), 6.0)}
    signal = sum(design(c, ctx)[:, 0] * v for c, v in cands.values())
    L = np.linalg.cholesky(upd.prior_cov + 1e-9 * np.eye(upd.prior_cov.shape[0]))
    rng = np.random.default_rng(np.random.SeedSequence(1302).spawn(1)[0])
    hits = {k: 0 for k in cands}
    for _ in range(N_REFIT):
        y = upd.design_ @ (L @ rng.standard_normal(L.shape[0])) + signal + rng.normal(0, NOISE_UM, signal.size)
        start = [EffectTerm(c, np.zeros(1), ctx.ref) for c, _ in cands.values()]
        terms, _ = joint_refit(grinder, sm.covariance_, checks.axes, y.reshape(-1, 3), ctx, start)
        for t, (k, (_, v)) in zip(terms, cands.items()):
            p = t.parameters()[k]
            hits[k] += abs(p["value"] - v) <= Z95 * p["se"]
    for k, h in hits.items():
        assert COVERAGE_LO <= h / N_REFIT <= COVERAGE_HI, f"{k}: coverage {h / N_REFIT:.3f}"
