"""The paper's GA with PyGAD's operators, evolving every point's population at once: the engine of the
``batched-ga`` solver (:func:`compensation.solvers.chain_ga.solve_batched_ga_chain`).

The paper's parameters (:mod:`compensation.solvers.ga`); the populations are
one float32 array of shape (n_points, 40, 3) (genes in μm) and one generation is one
compiled pass over all points (:func:`._ga_kernels.breed`: selection, crossover, mutation,
ball repair, fitness inheritance) plus one field evaluation over all new offspring of all
points.

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
   (``mutation_by_replacement=False``, ``s = mutation_step_um``, PyGAD's default ±1). One
   uniform u per gene decides and sizes it: the gene mutates when u < p, by
   ``(2u/p - 1)·s`` (given u < p, u/p is uniform on [0, 1)).
5. **Ball repair**: offspring projected radially onto the 250 μm ball (the ``ga`` solver's
   ``on_mutation``).
6. **Fitness** minus the squared model residual of the genes; an offspring identical to one of its
   parents (not crossed, not mutated) inherits the parent's fitness, as PyGAD's fitness
   cache does, so ``nfev`` counts the same kind of evaluations.

Fitness: the caller's (``fitness(points (k,) int64, genes (3, k) float32) -> (k,) float32``;
:func:`compensation.solvers.chain_ga.chain_fitness`), evaluated in blocks of :data:`FITNESS_BLOCK`.

Differences from PyGAD: the random streams differ (one numpy Generator per chunk of
points, its raw 32-bit words feeding the compiled step, instead of one RandomState/Random
pair per point), so single runs differ point by point while their distributions are the
same; ties in fitness are broken by index, not PyGAD's reversed stable sort (tied
individuals are almost always identical copies, so the choice is immaterial); PyGAD's
fitness cache also matches offspring against all 28 parents, this one against the
offspring's own two (≈ 2 % more evaluations late in a run, docs/explanation/solvers.md).
"""
from __future__ import annotations

import threading

import numpy as np

from errormap.progress import Progress

from ._common import project_to_ball
from ._ga_kernels import breed, scatter
from .ga import uniform_in_ball


FITNESS_BLOCK = 65_536
"""Offspring per fitness call (a multiple of the fused kernel's own 16,384-column blocks, so the
values are the same as in one call): bounds the time between two interruption polls (≈ 0.2 s
on the HTM field's ≈ 3 μs per evaluation, ≈ 10 ms on the network's)."""


def _blocked(fitness, pts, dT, F, stop) -> np.ndarray:
    """``fitness(pts[:F], dT[:, :F])`` in blocks of :data:`FITNESS_BLOCK`, polling ``stop`` between."""
    if F <= FITNESS_BLOCK:
        return fitness(pts[:F], dT[:, :F])
    out = np.empty(F, dtype=np.float32)
    for a in range(0, F, FITNESS_BLOCK):
        if stop is not None and stop.is_set():
            raise KeyboardInterrupt("batched-ga stopped")
        b = min(F, a + FITNESS_BLOCK)
        out[a:b] = fitness(pts[a:b], np.ascontiguousarray(dT[:, a:b]))
    return out


class _LockedProgress(Progress):
    """:class:`Progress` whose updates may come from several threads."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._lock = threading.Lock()

    def update(self, k: int = 1, extra: str = "") -> None:
        with self._lock:
            super().update(k, extra)


class _BatchGA:
    """The generation loop over (m, P, 3) float32 populations; settings only, no state between runs."""

    def __init__(self, ball_um, population, n_parents, crossover_probability, mutation_probability,
                 mutation_step_um):
        self.ball_um = float(ball_um)
        self.P, self.M = population, n_parents
        self.K = population - 1  # keep_elitism = 1: the other slots are offspring
        self.pc, self.pm, self.step = crossover_probability, mutation_probability, mutation_step_um
        # P(K = 0) and P(K = 1) for the crossover pool size K ~ Binomial(M, pc)
        q = 1.0 - crossover_probability
        self.p0 = q ** n_parents
        self.p1 = n_parents * crossover_probability * q ** (n_parents - 1)

    def run(self, fitness, m, rng, generations, bar, init=None, stop=None):
        """Evolve the populations of m points; returns (best offsets (m, 3) μm float64, evaluations).

        ``init`` (m, P, 3) float32: the initial populations (default uniform in the ball);
        ``bar``: a progress bar or None; ``stop``: an Event polled every generation and
        every fitness block (raises KeyboardInterrupt when set).

        Randomness per generation, all from ``rng`` (numpy's PCG64 raw output): one 31-bit
        uniform per offspring picks the first parent, the cut point and the second parent as
        the digits of ``u·M``, then of the fractional rest times 3, then times M - 1 (each
        digit keeps ≥ 20 bits of resolution: bias < 1e-5); three 24-bit uniforms per
        offspring drive the mutation;
        the rare crossover pools of size 0 or 1 (probability ``p0 + p1``, 1.7e-13 with the
        paper's settings) are drawn as a binomial count and placed at random, so their
        probability is exact. The generation itself is :func:`._ga_kernels.breed`.
        """
        if stop is not None and stop.is_set():
            raise KeyboardInterrupt("batched-ga stopped")
        P, M, K = self.P, self.M, self.K
        pop = (uniform_in_ball(rng, (m, P), self.ball_um).astype(np.float32) if init is None
               else np.ascontiguousarray(init, dtype=np.float32))
        fit = _blocked(fitness, np.repeat(np.arange(m), P), np.ascontiguousarray(pop.reshape(-1, 3).T), m * P,
                       stop).reshape(m, P)
        nfev = m * P
        new_pop, new_fit = np.empty_like(pop), np.empty_like(fit)
        fresh_at = np.empty(m * K + 1, dtype=np.int64)
        fresh_pt = np.empty(m * K + 1, dtype=np.int64)
        fresh_d = np.empty((3, m * K + 1), dtype=np.float32)
        odd = np.zeros((m, K), dtype=np.int8)
        lonely_p = self.p0 + self.p1
        pm, step, ball = np.float32(self.pm), np.float32(self.step), np.float32(self.ball_um)
        for _ in range(generations):
            if stop is not None and stop.is_set():
                raise KeyboardInterrupt("batched-ga stopped")
            words = rng.bit_generator.random_raw(2 * m * K).view(np.uint32).reshape(m, K, 4)
            n_odd = int(rng.binomial(m * K, lonely_p)) if lonely_p > 0.0 else 0
            if n_odd:  # pools of one mate with themselves; empty pools take parent k mod M
                at = rng.choice(m * K, n_odd, replace=False)
                odd.reshape(-1)[at] = np.where(rng.random(n_odd) < self.p0 / lonely_p, 2, 1)
            F = breed(pop, fit, words, odd, M, pm, step, ball, new_pop, new_fit, fresh_at, fresh_pt, fresh_d)
            if n_odd:
                odd.reshape(-1)[at] = 0
            if F:
                scatter(new_fit.reshape(-1), fresh_at, _blocked(fitness, fresh_pt, fresh_d, F, stop), F)
                nfev += F
            pop, new_pop = new_pop, pop
            fit, new_fit = new_fit, fit
            if bar is not None:
                bar.update(m)
        best = pop[np.arange(m), np.argmax(fit, axis=1)].astype(float)
        return project_to_ball(best, self.ball_um), nfev
