"""The batched GA's compiled generation step and fused float32 fitness (issue 4).

The operators are checked one by one on a single generation of many points (statistics
with binomial tolerances), the fused fitness against the generic float64 one, and the
network's column path against ``predict``.
"""
from __future__ import annotations


import numpy as np

from chain_fixtures import grinder_variant
import pytest
import torch

from compensation.solvers import solve
from compensation.solvers._ga_kernels import breed
from errormap.chain_kernel import forward, inverse
from errormap.machine import load_machine
from training.model import MLPField

TOL_COLUMNS64_REL = 1e-10  # predict_columns float64 (scalings folded into the layers) vs predict
TOL_F32_UM = 1e-3          # float32 paths vs float64 on a ~50 μm field (the GA resolves ~0.01 μm)
GA_TOL_UM = 0.265          # the paper's worst GA residual
SIGMAS = 5.0               # statistical checks: within 5 binomial standard deviations
P, M, K = 40, 28, 39       # the paper's population, mating parents (0.7·40), offspring per generation
PM = 0.2                   # mutation probability per gene


@pytest.fixture(scope="module")
def machine():
    return load_machine(None)


def make_model(enc="raw", seed=0):
    """A random (untrained) paper-sized network with scalers over the default grinder's strokes."""
    rng = np.random.default_rng(seed)
    axes = np.column_stack([rng.uniform(0, 200, 300), rng.uniform(0, 60, 300), rng.uniform(0, 360, 300)])
    axes[:2, 2] = [0.0, 360.0]
    m = MLPField((10, 15, 25, 15, 10), "sigmoid", enc).fit_scalers(axes, rng.normal(0.0, 20.0, (300, 3)))
    m.theta_ = m.init_params(seed)
    return m


def turn_axes(n, seed=1):
    rng = np.random.default_rng(seed)
    axes = np.column_stack([rng.uniform(0, 200, n), rng.uniform(0.5, 60, n), rng.uniform(0, 360, n)])
    k = n // 10
    axes[:k, 2] = rng.uniform(330.0, 360.0, k)  # the seam ramp, densely
    return axes


@pytest.mark.parametrize("enc", ["raw", "periodic"])
def test_predict_columns_equals_predict(enc):
    m = make_model(enc)
    axes = turn_axes(3000)
    ref = m.predict(axes)
    c64 = m.predict_columns(torch.from_numpy(np.ascontiguousarray(axes.T))).numpy().T
    c32 = m.predict_columns(torch.from_numpy(np.ascontiguousarray(axes.T, dtype=np.float32))).numpy().T
    assert c64.dtype == np.float64 and c32.dtype == np.float32
    assert np.abs(c64 - ref).max() <= TOL_COLUMNS64_REL * np.abs(ref).max()
    assert np.abs(c32 - ref).max() <= TOL_F32_UM


@pytest.mark.parametrize("theta1_deg", [None, 7.0])  # default (t_y = 0) and a tool off the XZ plane
def test_fused_fitness_equals_generic(machine, theta1_deg):
    mach = machine if theta1_deg is None else grinder_variant({"theta1_deg": theta1_deg})
    field = make_model()
    rng = np.random.default_rng(2)
    targets = forward(mach, turn_axes(500, seed=3))
    pts = rng.integers(0, len(targets), 4000)
    d = rng.normal(size=(3, 4000)).astype(np.float32)
    d *= (250.0 * rng.random(4000) ** (1 / 3) / np.linalg.norm(d, axis=0)).astype(np.float32)
    fused = field.offset_fitness(mach, targets)(pts, d)  # the network's fused kernel (training.ga_fitness)
    dd = d.T.astype(float)  # the fitness from its definition: -|d + E(IK(p_d + 1e-3 d))|², float64
    r = dd + field.predict(inverse(mach, targets[pts] + 1e-3 * dd, unwrap=False))
    generic = -np.einsum("ij,ij->i", r, r)
    # fitness is -|r|² with |r| up to ~300 μm: compare the residual norms
    assert np.abs(np.sqrt(-fused) - np.sqrt(-generic)).max() <= TOL_F32_UM


def one_generation(m_points=2000, seed=0, odd_value=0, radius_um=100.0):
    """One call of the compiled step on random populations inside a ball of ``radius_um``."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(m_points, P, 3))
    pop = (v / np.linalg.norm(v, axis=2, keepdims=True) * radius_um * rng.random((m_points, P, 1))).astype(np.float32)
    fit = -rng.random((m_points, P)).astype(np.float32)
    words = rng.bit_generator.random_raw(2 * m_points * K).view(np.uint32).reshape(m_points, K, 4)
    odd = np.full((m_points, K), odd_value, dtype=np.int8)
    new_pop, new_fit = np.empty_like(pop), np.empty_like(fit)
    n = m_points * K + 1
    at, pt, d = np.empty(n, np.int64), np.empty(n, np.int64), np.empty((3, n), np.float32)
    F = breed(pop, fit, words, odd, M, np.float32(PM), np.float32(1.0), np.float32(250.0), new_pop, new_fit, at, pt, d)
    return pop, fit, new_pop, new_fit, at[:F], pt[:F], d[:, :F]


def test_breed_elitism_selection_and_bookkeeping():
    pop, fit, new_pop, new_fit, at, pt, d = one_generation()
    m = len(fit)
    rows = np.arange(m)
    best = np.argmax(fit, axis=1)
    assert np.array_equal(new_pop[:, 0], pop[rows, best]) and np.array_equal(new_fit[:, 0], fit[rows, best])
    # every gene of an unmutated child comes from one of the M fittest (the mating parents)
    top = np.argsort(-fit, axis=1)[:, :M]
    parents = pop[rows[:, None], top]  # (m, M, 3)
    child = new_pop[:, 1:]  # (m, K, 3)
    from_parent = (child[:, :, None, :] == parents[:, None, :, :]).any(axis=2)  # (m, K, 3)
    # a gene matching no parent gene was mutated (nothing leaves a 100 μm ball by ±1 μm)
    mutated_frac = 1.0 - from_parent.mean()
    sd = np.sqrt(PM * (1 - PM) / from_parent.size)
    assert abs(mutated_frac - PM) <= SIGMAS * sd
    # the listed (fresh) offspring are exactly the ones not equal to a parent, with their offsets
    flat_pop = new_pop.reshape(-1, 3)
    assert np.array_equal(d.T, flat_pop[at]) and np.array_equal(pt, at // P)
    assert np.all(at % P >= 1)
    listed = np.zeros(m * P, dtype=bool)
    listed[at] = True
    listed = listed.reshape(m, P)[:, 1:]
    equal_any = (child[:, :, None, :] == pop[:, None, :, :]).all(axis=3)  # (m, K, P)
    quiet = from_parent.all(axis=2)
    assert np.array_equal(~listed, quiet & equal_any.any(axis=2))
    # inherited fitness is the fitness of the parent the child copies
    i, k = np.nonzero(~listed)
    j = np.argmax(equal_any[i, k], axis=1)
    assert np.array_equal(new_fit[i, k + 1], fit[i, j])
    # P(copy of a parent) = P(no mutation) · P(cut = 0) = 0.8³/3 with distinct individuals
    p_copy = (1 - PM) ** 3 / 3
    sd = np.sqrt(p_copy * (1 - p_copy) / (~listed).size)
    assert abs((~listed).mean() - p_copy) <= SIGMAS * sd


def test_breed_crossover_takes_a_prefix_from_the_first_parent():
    pop, fit, new_pop, *_ = one_generation(seed=1)
    m = len(fit)
    child = new_pop[:, 1:]
    # which individual each gene of an unmutated child comes from (populations are distinct)
    src = np.full(child.shape, -1)
    for g in range(3):
        eq = child[:, :, None, g] == pop[:, None, :, g]  # (m, K, P)
        src[..., g] = np.where(eq.any(axis=2), np.argmax(eq, axis=2), -1)
    ok = (src >= 0).all(axis=2)
    s = src[ok]
    # single point: genes [:c] from one parent and [c:] from the other, c uniform on {0, 1, 2}
    cut0 = (s[:, 0] == s[:, 1]) & (s[:, 1] == s[:, 2])
    cut1 = (s[:, 0] != s[:, 1]) & (s[:, 1] == s[:, 2])
    cut2 = (s[:, 0] == s[:, 1]) & (s[:, 1] != s[:, 2])
    assert np.all(cut0 | cut1 | cut2)  # never (a, b, a) or three different sources
    n = len(s)
    for frac in (cut0.mean(), cut1.mean(), cut2.mean()):
        assert abs(frac - 1 / 3) <= SIGMAS * np.sqrt(2 / 9 / n)
    del m


@pytest.mark.parametrize("odd_value", [1, 2])
def test_breed_small_crossover_pools(odd_value):
    """A pool of one (1): the child is that parent (mated with itself); empty (2): parent k mod M."""
    pop, fit, new_pop, new_fit, at, pt, d = one_generation(m_points=300, seed=2, odd_value=odd_value)
    m = len(fit)
    rows = np.arange(m)
    ranked = np.argsort(-fit, axis=1, kind="stable")
    listed = np.zeros(m * P, dtype=bool)
    listed[at] = True
    listed = listed.reshape(m, P)[:, 1:]
    child = new_pop[:, 1:]
    copies = ~listed  # unmutated: a whole copy of one parent
    equal = (child[:, :, None, :] == pop[:, None, :, :]).all(axis=3)
    assert np.all(equal[copies].sum(axis=1) == 1)
    j = np.argmax(equal, axis=2)
    rank_of = np.argsort(ranked, axis=1)[rows[:, None], j]  # rank of the copied individual
    if odd_value == 2:
        assert np.array_equal(rank_of[copies], np.broadcast_to(np.arange(K) % M, (m, K))[copies])
    else:
        assert rank_of[copies].max() < M
    p_quiet = (1 - PM) ** 3
    assert abs(copies.mean() - p_quiet) <= SIGMAS * np.sqrt(p_quiet * (1 - p_quiet) / copies.size)


def test_batched_ga_on_the_network_reaches_the_paper_residual(machine):
    """The learned field on the grinder's chain (the generic chain fitness through its ``predict``)."""
    field = make_model()
    targets = forward(machine, turn_axes(60, seed=4))
    r = solve("batched-ga", field, targets, machine, seed=3, progress=False)
    assert r.success.all() and r.residual_norm_um.max() <= GA_TOL_UM


def test_batched_ga_is_reproducible(machine):
    field = make_model()
    targets = forward(machine, turn_axes(80, seed=5))
    kw = dict(seed=9, generations=30, progress=False)
    a = solve("batched-ga", field, targets, machine, **kw)
    b = solve("batched-ga", field, targets, machine, **kw)
    assert np.array_equal(a.commands_mm, b.commands_mm) and a.nfev == b.nfev


def test_chain_ga_runs_the_fused_fitness_on_the_grinder_chain(machine):
    """The chain GA takes the network's fused float32 fitness on a chain of its closed form (the grinder's): the
    float64 ``axes`` put the nominal tool point on ``p_d + 1e-3·d`` (to round-off), the fused fitness equals the
    float64 one within TOL_F32_UM, and a field without the capability (or a rotary limit) keeps the generic one."""
    from compensation.solvers.chain_ga import ChainAxisFitness, FusedChainFitness, chain_fitness
    from errormap.chain_kernel import NominalChain
    mt = machine
    compiled = NominalChain(mt)
    axes = turn_axes(300, seed=4)
    targets = forward(machine, axes)
    field = make_model()
    fit = chain_fitness(field, mt, compiled, targets, axes, 250.0)[0]
    assert isinstance(fit, FusedChainFitness)
    rng = np.random.default_rng(3)
    pts = rng.integers(0, len(targets), 2000)
    d = (rng.normal(size=(2000, 3)) * 80.0).astype(np.float32)
    q = fit.axes(pts, d.astype(float))
    assert np.abs(compiled.forward(q) - (targets[pts] + 1e-3 * d.astype(float))).max() < 1e-9   # mm: closed form
    assert np.abs(q[:, 2] - axes[pts, 2]).max() < 90.0    # deg: on the program's turn (asin(b/r) ≤ 90° near the axis)
    f32, f64 = fit(pts, np.ascontiguousarray(d.T)), fit.fitness64(pts, d.astype(float))
    assert np.abs(np.sqrt(-f32) - np.sqrt(-f64)).max() <= TOL_F32_UM
    assert isinstance(chain_fitness(field, mt, compiled, targets, axes, 250.0, rotary_limit_deg=5.0)[0],
                      ChainAxisFitness)


class _Hidden:
    """``field`` without the ``offset_fitness`` capability: the GA falls back to the generic float64 chain fitness."""

    def __init__(self, field):
        from errormap.field import OFFSET_FITNESS
        self._f = field
        self.capabilities = field.capabilities - {OFFSET_FITNESS}
        self.calibrated_volume = field.calibrated_volume

    def predict(self, axes, *a, **k):
        return self._f.predict(axes, *a, **k)

    def __getattr__(self, name):
        return getattr(self._f, name)


@pytest.mark.slow   # ~15 s: two batched-GA solves of 40 points (the network compiles on first use)
def test_chain_ga_fused_results_equal_float64_within_ga_tolerance(machine):
    """Same targets, same seed: the batched GA with the fused float32 fitness against the generic float64 chain
    fitness (the capability hidden): both succeed, and their commands agree within the paper's GA_TOL_UM."""
    from compensation.solvers.chain_ga import solve_batched_ga_chain
    mt = machine
    axes = turn_axes(40, seed=6)
    targets = forward(machine, axes)
    field = make_model()
    fused = solve_batched_ga_chain(field, targets, mt, target_axes=axes, seed=0, progress=False)
    plain = solve_batched_ga_chain(_Hidden(field), targets, mt, target_axes=axes, seed=0, progress=False)
    assert fused.success.all() and plain.success.all()
    assert np.abs(fused.commands_mm - plain.commands_mm).max() * 1e3 <= GA_TOL_UM
