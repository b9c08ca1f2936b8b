"""The paper's GA with PyGAD's operators, evolving every point's population at once: the engine of the
``batched-ga`` solver (:func:`compensation.solvers.chain_ga.solve_batched_ga_chain`).

The populations are one float32 array (n_points, 40, 3) (genes in μm); one generation is one compiled pass
over all points (:func:`._ga_kernels.breed`) plus one evaluation of the caller's fitness (``fitness(points
(k,) int64, genes (3, k) float32) -> (k,) float32``) over all new offspring, in blocks of
:data:`FITNESS_BLOCK`. How each operator matches PyGAD 3.9's, and the documented differences:
docs/explanation/solvers.md ("The GA: the paper's parameters, PyGAD's and batched-ga's")."""
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
