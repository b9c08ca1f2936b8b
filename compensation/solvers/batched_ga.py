"""The paper's GA with PyGAD's operators, evolving every point's population at once (numpy).

Same problem, parameters and fitness as :mod:`compensation.solvers.ga`; the population is
an array of shape (n_points, 40, 3) (offsets d in μm) and one generation is a handful of
array operations plus one field evaluation over all new offspring of all points.

Operators, as PyGAD 3.9 runs them with the ``ga`` solver's configuration (one generation):

1. **Steady-state selection** (``sss``): the 28 fittest of 40 are the mating parents.
2. **Elitism** (``keep_elitism=1``): the fittest individual goes to slot 0 of the next
   population unchanged; the other 39 slots are offspring.
3. **Single-point crossover with crossover_probability p** (PyGAD's semantics): for each
   offspring a point ``c`` is drawn uniformly from {0, 1, 2}; each of the 28 parents joins
   a candidate pool with probability p; with ≥ 2 candidates two distinct ones are drawn at
   random (first, second), with one candidate it mates with itself, with none the child is
   parent ``k mod 28``. The child takes genes ``[:c]`` from the first, ``[c:]`` from the
   second. Here the pool is not materialised: its size K ~ Binomial(28, p) decides the
   case, and for K ≥ 2 the ordered pair is uniform over distinct parents, which is exactly
   the marginal law of PyGAD's draw (by symmetry). Same distribution, two draws instead
   of 28.
4. **Random mutation**, ``mutation_probability`` per gene, additive U(-s, s) μm
   (``mutation_by_replacement=False``, ``s = mutation_step_um``, PyGAD's default ±1).
5. **Ball repair**: offspring projected radially onto the 250 μm ball (the ``ga`` solver's
   ``on_mutation``).
6. **Fitness** ``-|d + E(IK(p_d + 1e-3·d))|²``; an offspring identical to one of its
   parents (not crossed, not mutated) inherits the parent's fitness, as PyGAD's fitness
   cache does, so ``nfev`` counts the same kind of evaluations.

Differences from PyGAD: the random streams differ (one numpy Generator for the whole
batch instead of one RandomState/Random pair per point), so single runs differ point by
point while their distributions are the same; ties in fitness are broken by
``argpartition`` order, not PyGAD's reversed stable sort (tied individuals are almost
always identical copies, so the choice is immaterial).
"""
from __future__ import annotations

import time

import numpy as np

from errormap.kinematics import inverse
from errormap.progress import Progress

from .base import BALL_RADIUS_UM, SolveResult
from ._common import MM_PER_UM, check_inputs, field_error_um, ga_result, project_to_ball
from .ga import DEFAULT_TOL_UM, PAPER_GA, check_ga_options, uniform_in_ball


def solve_batched_ga(field, targets_mm, machine, *, target_axes=None, a_start_deg=None,
                     ball_um: float = BALL_RADIUS_UM, seed: int | np.random.Generator = 0,
                     population: int = PAPER_GA["population"], generations: int = PAPER_GA["generations"],
                     selection_probability: float = PAPER_GA["selection_probability"],
                     crossover_probability: float = PAPER_GA["crossover_probability"],
                     mutation_probability: float = PAPER_GA["mutation_probability"],
                     mutation_step_um: float = PAPER_GA["mutation_step_um"], tol_um: float = DEFAULT_TOL_UM,
                     chunk: int = 4096, progress: bool = True) -> SolveResult:
    """Batched GA over WCS targets, shape (n, 3) mm; points evolve in chunks of ``chunk``.

    ``success``: |model residual| ≤ ``tol_um`` and inside the ball.
    """
    t0 = time.perf_counter()
    targets, axes_d = check_inputs(field, targets_mm, machine, target_axes, a_start_deg, ball_um)
    n_parents = check_ga_options(population, generations, selection_probability, crossover_probability,
                                 mutation_probability, mutation_step_um, tol_um)
    if not chunk >= 1:
        raise ValueError(f"Expected chunk ≥ 1, got {chunk!r}")
    rng = np.random.default_rng(seed)
    n = len(targets)
    best = np.empty((n, 3))
    nfev = 0
    bar = Progress(n * generations, "batched-ga (point-generations)", enabled=progress)
    ga = _BatchGA(field, machine, ball_um, population, n_parents, crossover_probability, mutation_probability,
                  mutation_step_um)
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        best[sl], fe = ga.run(targets[sl], rng, generations, bar)
        nfev += fe
    return ga_result("batched-ga", field, machine, targets, best, axes_d, nfev, t0, ball_um, tol_um, seed,
                     parents=n_parents)


class _BatchGA:
    """The generation step over (m, P, 3) populations; no state between runs."""

    def __init__(self, field, machine, ball_um, population, n_parents, crossover_probability,
                 mutation_probability, mutation_step_um):
        self.field, self.machine, self.ball_um = field, machine, ball_um
        self.P, self.M = population, n_parents
        self.n_off = population - 1  # keep_elitism = 1
        self.pc, self.pm, self.step = crossover_probability, mutation_probability, mutation_step_um
        # P(K = 0) and P(K = 1) for the crossover pool size K ~ Binomial(M, pc)
        q = 1.0 - crossover_probability
        self.p0 = q ** n_parents
        self.p1 = n_parents * crossover_probability * q ** (n_parents - 1)

    def fitness(self, targets, d) -> np.ndarray:
        """``-|d + E(IK(p_d + 1e-3 d))|²`` for offsets d (k, 3) μm of targets (k, 3) mm; (k,)."""
        q = inverse(self.machine, targets + MM_PER_UM * d, unwrap=False)
        r = d + field_error_um(self.field, q, self.machine, fast=True)
        return -np.einsum("ij,ij->i", r, r)

    def run(self, targets, rng, generations, bar):
        """Evolve one chunk of targets (m, 3); returns (best offsets (m, 3) μm, evaluations)."""
        m, P, M, K = len(targets), self.P, self.M, self.n_off
        pop = uniform_in_ball(rng, (m, P), self.ball_um)
        fit = self.fitness(np.repeat(targets, P, axis=0), pop.reshape(-1, 3)).reshape(m, P)
        nfev = m * P
        rows = np.arange(m)
        base = (rows * P)[:, None]  # flat index of each point's first individual
        kmod = (np.arange(K) % M)[None, :]
        ball2 = self.ball_um ** 2
        for _ in range(generations):
            # 1-2: parents = the M fittest (unordered), elite = the fittest
            par_idx = np.argpartition(-fit, M - 1, axis=1)[:, :M]
            elite = np.argmax(fit, axis=1)
            # 3: single-point crossover, PyGAD's pool semantics
            u = rng.random((m, K, 7))
            cut = (u[..., 0] * 3).astype(np.intp)  # 0, 1 or 2 (u < 1)
            first = (u[..., 1] * M).astype(np.intp)
            second = (u[..., 2] * (M - 1)).astype(np.intp)
            second += second >= first
            if self.p0 + self.p1 > 0.0:
                lonely = u[..., 3] < self.p0 + self.p1  # pool of one (mates with itself) or none
                none = u[..., 3] < self.p0
                second = np.where(lonely, first, second)
                first = np.where(none, kmod, first)
                second = np.where(none, kmod, second)
            i1 = np.take_along_axis(par_idx, first, axis=1)
            i2 = np.take_along_axis(par_idx, second, axis=1)
            flat_pop = pop.reshape(-1, 3)
            g1, g2 = flat_pop[base + i1], flat_pop[base + i2]  # (m, K, 3)
            child = g2.copy()
            child[..., 0] = np.where(cut >= 1, g1[..., 0], g2[..., 0])
            child[..., 1] = np.where(cut >= 2, g1[..., 1], g2[..., 1])
            # 4: additive random mutation per gene
            mut = u[..., 4:7] < self.pm
            child += mut * (self.step * (2.0 * rng.random((m, K, 3)) - 1.0))
            # 5: ball repair (only the few offspring outside the ball change)
            r2 = np.einsum("mki,mki->mk", child, child)
            out = np.nonzero(r2 > ball2)
            if out[0].size:
                child[out] *= (self.ball_um / np.sqrt(r2[out]))[:, None]
            # 6: fitness; unchanged copies of a parent inherit the parent's fitness
            fresh = np.ones((m, K), dtype=bool)
            quiet = ~mut.any(axis=2)
            same2 = quiet & np.all(child == g2, axis=2)
            same1 = quiet & ~same2 & np.all(child == g1, axis=2)
            fresh &= ~(same1 | same2)
            cfit = np.where(same2, fit[rows[:, None], i2], fit[rows[:, None], i1])
            idx = np.nonzero(fresh)
            if idx[0].size:
                cfit[idx] = self.fitness(targets[idx[0]], child[idx])
                nfev += idx[0].size
            new_pop = np.empty_like(pop)
            new_pop[:, 0] = pop[rows, elite]
            new_pop[:, 1:] = child
            new_fit = np.empty_like(fit)
            new_fit[:, 0] = fit[rows, elite]
            new_fit[:, 1:] = cfit
            pop, fit = new_pop, new_fit
            bar.update(m)
        best = pop[rows, np.argmax(fit, axis=1)]
        return project_to_ball(best, self.ball_um), nfev
