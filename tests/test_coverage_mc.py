"""Monte Carlo coverage of the 95 % bands the one loop reports for effect terms.

Each repetition is "simulate with a known truth → estimate → report a 95 % band", with fixed seeds, on the
grinder's chain (``volcomp diagnose``'s one loop, errormap/diagnosis/chain_loop.py): the element parameters'
deviation from the sweep estimate drawn from the update's own prior, one known effect, check noise; the estimate
is the loop's joint fit of the term with the element update and the band that fit's posterior covariance
(:func:`benchmarks.suite.statistical.effect_sweep`). The range asked is 90–98 %.

The rate needs the full sweep (300 repetitions per effect: binomial SE 1.3 %), about 0.25 CPU s a repetition,
so it is judged by the full sweep, ``python -m benchmarks.run statistical`` (figures in BENCHMARKS.md); here each effect runs its first repetitions with the sweep's own code and seeds, and what
must hold on every repetition is asserted. The joint refit of two accepted terms and the smoothed
identification's prediction band are sweeps of the same benchmark (its quick run: tests/test_benchmarks_suite.py).

Gone with the grinder's own loop: the GLS joint screen (the one loop has no screen: its search is the
held-out gated forward search) and the bands of a period or an order (the one loop reports the coefficients'
band given the shape; the searched shape's effect on coverage is recorded by the sweep, not judged).
"""
import numpy as np
import pytest
from threadpoolctl import threadpool_limits  # comes with scikit-learn (a dependency)

from benchmarks.suite import statistical as bench

N_FIRST = 4
"""Repetitions per effect here (about 1 CPU s with the shape search); the rate is the benchmark's (300)."""


SE_SCALE_RTOL = 0.05
"""The band scales with σ̂, estimated from the residual: the same draws with a 10× larger term change σ̂ only
through the fit (measured: equal to 4 digits, 0.0981 μm both); 5 % allows the GCV weight to move one grid step."""


@pytest.fixture(autouse=True)
def one_blas_thread():
    """The repetitions' matrices are small: one BLAS thread (several spin on a shared machine)."""
    with threadpool_limits(1, user_api="blas"):
        yield


@pytest.fixture(scope="module")
def sim():
    with threadpool_limits(1, user_api="blas"):
        return bench.ChainSimulator(bench.chain_setting())


def test_the_sweep_judges_the_asked_range():
    assert (bench.COVERAGE_LO, bench.COVERAGE_HI) == (0.90, 0.98)
    assert bench.SWEEPS["effect_band_coverage"][1] == 300   # binomial SE of a 95 % coverage over 300: 1.3 %


def test_effect_terms_are_ones_the_loop_fits(sim):
    """Each simulated term is one the loop searches on this chain (not represented by the element slots)."""
    from errormap.diagnosis.chain_loop import representable_terms
    rep = {(t["kind"], t["axis"]): t["represented"]
           for t in representable_terms(sim.mt, sim.el, sim.checks.axes, sim.checks.conditions)}
    for name, (kind, words, *_rest) in bench.EFFECT_TRUTHS.items():
        assert not rep.get((kind, "*".join(words)), False), name


@pytest.mark.parametrize("name", list(bench.EFFECT_TRUTHS))
def test_first_repetitions_of_the_effect_band_sweep(sim, name):
    r = bench.effect_sweep(name, N_FIRST, sim)
    assert r["repetitions"] == N_FIRST
    coef = bench.EFFECT_TRUTHS[name][4]
    assert len(r["rates"]) == len(coef)
    assert all(0.0 <= v <= 1.0 for v in r["rates"].values())
    if bench.EFFECT_TRUTHS[name][3]:             # a shape: the search must find it on these first seeds
        assert r["shape_found"] >= 0.5, f"{name}: the search found the true shape in {r['shape_found']:.2f}"


def test_band_is_the_joint_fits_posterior(sim):
    """The band judged is finite and positive, and the same for the same draws with a 10× larger term: in the
    loop's linear Gaussian model a coefficient's band does not depend on the truth's size (a fit that left part
    of the term in the residual would inflate σ̂ and the band with it)."""
    from errormap.diagnosis.chain_loop import EffectTerm
    kind, words, element, shape, coef = bench.EFFECT_TRUTHS["reversal"]
    t = EffectTerm(kind, words, element, shape, np.zeros(1))
    E, S = sim.columns([t])
    se = []
    for scale in (1.0, 10.0):
        rng = np.random.default_rng(1303)
        b, cv = sim.joint_fit([t], sim.residual(E, S, scale * np.asarray(coef), rng))
        se.append(float(np.sqrt(cv[0, 0])))
        assert np.isfinite(b).all() and se[-1] > 0
    assert se[1] == pytest.approx(se[0], rel=SE_SCALE_RTOL)

