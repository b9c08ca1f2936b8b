"""The paper's GA with PyGAD's operators, evolving every point's population at once.

Same problem, parameters and fitness as :mod:`compensation.solvers.ga`; the populations are
one float32 array of shape (n_points, 40, 3) (offsets d in μm) and one generation is one
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
6. **Fitness** ``-|d + E(IK(p_d + 1e-3·d))|²``; an offspring identical to one of its
   parents (not crossed, not mutated) inherits the parent's fitness, as PyGAD's fitness
   cache does, so ``nfev`` counts the same kind of evaluations.

Fitness evaluation, two paths with the same value:

* **fused** (fields declaring the ``offset_fitness`` capability, i.e. the learned MLP field):
  the field supplies the whole fitness as one compiled kernel
  (:class:`errormap.field.OffsetFitness`; for the network, nominal inverse kinematics and the
  network as one float32 torch pipeline, :mod:`training.ga_fitness`). float32 is ample here:
  the offsets resolve 1.5e-5 μm at 250 μm, and the field's float32 error is ~1e-4 μm
  (``tests/test_model_inference.py``) against the GA's ~0.01 μm resolution; the returned
  commands and residuals are recomputed in float64 (:func:`._common.ga_result`).
* **generic** (any field, e.g. the HTM field): float64 numpy through
  :func:`errormap.kinematics.inverse` and :func:`._common.field_error_um`.

Differences from PyGAD: the random streams differ (one numpy Generator per chunk of
points, its raw 32-bit words feeding the compiled step, instead of one RandomState/Random
pair per point), so single runs differ point by point while their distributions are the
same; ties in fitness are broken by index, not PyGAD's reversed stable sort (tied
individuals are almost always identical copies, so the choice is immaterial); PyGAD's
fitness cache also matches offspring against all 28 parents, this one against the
offspring's own two (≈ 2 % more evaluations late in a run, docs/solvers.md).
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from errormap.field import OFFSET_FITNESS
from errormap.kinematics import inverse
from errormap.progress import Progress
from errormap.threads import limit_threads

from .base import BALL_RADIUS_UM, SolveResult
from ._common import MM_PER_UM, check_inputs, field_error_um, ga_result, project_to_ball
from ._converge import RETRY_ROUNDS, converge, merge_stats
from ._ga_kernels import breed, scatter
from .ga import DEFAULT_TOL_UM, PAPER_GA, check_ga_options, uniform_in_ball


def solve_batched_ga(field, targets_mm, machine, *, target_axes=None, a_start_deg=None,
                     ball_um: float = BALL_RADIUS_UM, seed: int | np.random.Generator = 0,
                     population: int = PAPER_GA["population"], generations: int = PAPER_GA["generations"],
                     selection_probability: float = PAPER_GA["selection_probability"],
                     crossover_probability: float = PAPER_GA["crossover_probability"],
                     mutation_probability: float = PAPER_GA["mutation_probability"],
                     mutation_step_um: float = PAPER_GA["mutation_step_um"], tol_um: float = DEFAULT_TOL_UM,
                     chunk: int = 8192, workers: int | None = None, fused: bool | None = None,
                     progress: bool = True, retries: int = RETRY_ROUNDS, polish: bool = True,
                     stop: threading.Event | None = None) -> SolveResult:
    """Batched GA over WCS targets, shape (n, 3) mm.

    The points are split into equal chunks of at most ``chunk`` points, their number a
    multiple of ``workers``; each chunk evolves on its own (its own child Generator of
    ``seed``), ``workers`` chunks at a time in threads (each library on one thread per chunk
    meanwhile: :func:`errormap.threads.limit_threads`). ``workers``:
    None uses the fused kernel's own thread count (the cores it would use), 1 otherwise (a
    generic field's evaluation holds the GIL). The result depends on ``seed``, ``chunk`` and
    ``workers``, not on timing. ``fused``: None (default) uses the fused float32 fitness when
    the field declares ``offset_fitness``; False forces the generic path. ``success``:
    |model residual| ≤ ``tol_um`` and inside the ball.

    Points above ``tol_um`` after ``generations`` are retried (``retries`` GA re-runs from a
    fresh population around their best) and then, with ``polish``, Newton-polished
    (:mod:`._converge`); ``info["retry"]`` says how many and at what cost. Interruption: the
    generation loop polls ``stop`` (a :class:`threading.Event`, e.g. set by an executor on
    Ctrl-C) and the fitness runs in blocks of :data:`FITNESS_BLOCK` offspring, so a
    KeyboardInterrupt (main thread) or ``stop`` acts within one block's time; on
    KeyboardInterrupt in the main thread the chunk threads are stopped the same way.
    """
    t0 = time.perf_counter()
    targets, axes_d = check_inputs(field, targets_mm, machine, target_axes, a_start_deg, ball_um)
    n_parents = check_ga_options(population, generations, selection_probability, crossover_probability,
                                 mutation_probability, mutation_step_um, tol_um)
    if not (isinstance(chunk, (int, np.integer)) and chunk >= 1):
        raise ValueError(f"Expected chunk ≥ 1, got {chunk!r}")
    if workers is not None and not (isinstance(workers, (int, np.integer)) and workers >= 1):
        raise ValueError(f"Expected workers ≥ 1, got {workers!r}")
    if not (isinstance(retries, (int, np.integer)) and 0 <= retries <= 10):
        raise ValueError(f"Expected retries in 0..10, got {retries!r}")
    stop = threading.Event() if stop is None else stop
    has_kernel = OFFSET_FITNESS in field.capabilities
    use_fused = has_kernel if fused is None else bool(fused)
    if use_fused and not has_kernel:
        raise ValueError(f"Expected a field declaring the {OFFSET_FITNESS!r} capability for fused=True, "
                         f"got {type(field).__name__}")
    n = len(targets)
    # threads pay off where the work releases the GIL (the fused kernel and the compiled
    # step); a generic field's numpy/Python evaluation would only contend for it
    if workers is None:
        workers = field.offset_fitness(machine, targets[:0]).threads if use_fused else 1
    k = -(-n // chunk)
    k = max(1, -(-k // workers) * workers) if n >= workers else 1
    bounds = np.linspace(0, n, k + 1).round().astype(int)
    rngs = np.random.default_rng(seed).spawn(k)
    best = np.empty((n, 3))
    bar = _LockedProgress(n * generations, "batched-ga (point-generations)", enabled=progress)
    ga = _BatchGA(ball_um, population, n_parents, crossover_probability, mutation_probability, mutation_step_um)
    # every chunk's fitness is built here, before any thread starts
    fitness = [field.offset_fitness(machine, targets[bounds[i]:bounds[i + 1]]) if use_fused
               else _GenericFitness(field, machine, targets[bounds[i]:bounds[i + 1]]) for i in range(k)]

    def one(i):
        lo, hi = bounds[i], bounds[i + 1]
        b, fe = ga.run(fitness[i], hi - lo, rngs[i], generations, bar, stop=stop)

        def rerun(sub, radius_um):  # the chunk's own stream, so the result depends on the seed only
            init = b[sub][:, None, :] + radius_um[:, None, None] * uniform_in_ball(rngs[i], (sub.size, population), 1.0)
            init[:, 0] = b[sub]  # the best so far survives (elitism)
            init = project_to_ball(init, ball_um).astype(np.float32)
            return ga.run(lambda pts, dT: fitness[i](sub[pts], dT), sub.size, rngs[i], generations, None,
                          init=init, stop=stop)

        best[lo:hi], fe2, st = converge(field, machine, targets[lo:hi], axes_d[lo:hi], b, tol_um, ball_um, rerun,
                                        retries, polish)
        return fe + fe2, st

    if workers == 1 or k == 1:
        done = [one(i) for i in range(k)]
    else:
        with limit_threads(1), ThreadPoolExecutor(workers) as pool:
            try:
                done = list(pool.map(one, range(k)))
            except BaseException:
                stop.set()  # before the pool waits: its threads stop at their next generation or block
                raise
    nfev = sum(fe for fe, _ in done)
    return ga_result("batched-ga", field, machine, targets, best, axes_d, nfev, t0, ball_um, tol_um, seed,
                     parents=n_parents, fused=use_fused, chunks=k, workers=workers,
                     retry=merge_stats([st for _, st in done]))


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


class _GenericFitness:
    """``-|d + E(IK(p_d + 1e-3 d))|²`` through the field's ``predict`` (float64 numpy), any field."""

    def __init__(self, field, machine, targets):
        self.field, self.machine, self.targets = field, machine, targets

    def __call__(self, pts: np.ndarray, dT: np.ndarray) -> np.ndarray:
        """Fitness of offsets ``dT`` (3, k) μm (columns) of points ``pts`` (k,); returns (k,) float32."""
        d = dT.T.astype(float)
        q = inverse(self.machine, self.targets[pts] + MM_PER_UM * d, unwrap=False)
        r = d + field_error_um(self.field, q, self.machine, fast=True)
        f = -np.einsum("ij,ij->i", r, r).astype(np.float32)
        return np.where(np.isnan(f), -np.inf, f).astype(np.float32)


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
