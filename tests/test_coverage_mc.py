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

The joint screen's, the joint refit's and the prediction band's sweeps (the slow ones) are in
benchmarks/bench_statistical.py: tests/test_bench_statistical.py runs them on their first
repetitions, the full sweep judges the rate.
"""
import numpy as np
import pytest
from threadpoolctl import threadpool_limits  # comes with scikit-learn (a dependency)

from errormap.diagnosis.checks import CheckData
from errormap.diagnosis.effects import Candidate, Context, EffectTerm, basis, reference
from errormap.diagnosis.selection import EffectSelector
from errormap.simulator import random_truth

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
