"""The paper's genetic algorithm through PyGAD, one point at a time (the reference solver).

For each target ``p_d`` PyGAD evolves offsets ``d`` (μm, 3 genes) of the commanded target
``p_r = p_d + 1e-3·d``; the fitness is ``-|d + E(IK(p_r))|²`` (μm², PyGAD maximises), i.e.
minus the squared model residual, the paper's objective.

The paper's parameters and how they map onto PyGAD (docs/solvers.md has the full table):

================================  =========================================================
paper                             PyGAD
================================  =========================================================
population 40                     ``sol_per_pop=40``
400 generations                   ``num_generations=400``
3 variables                       ``num_genes=3`` (the offset d_x, d_y, d_z in μm)
selection probability 0.7         ``num_parents_mating=28`` (0.7·40) with PyGAD's default
                                  steady-state selection (``parent_selection_type="sss"``)
crossover probability 0.7         ``crossover_probability=0.7``, ``crossover_type="single_point"``
mutation probability 0.2          ``mutation_probability=0.2`` per gene, ``mutation_type="random"``
                                  (PyGAD default: adds U(-1, 1) gene units, here μm)
search region: the 250 μm ball    initial population uniform in the ball; offspring projected
                                  radially onto the ball after mutation (``on_mutation``)
(not in the paper)                ``keep_elitism=1`` (PyGAD default), ``fitness_batch_size=40``
================================  =========================================================

Each point gets a child Generator (``Generator.spawn`` of ``default_rng(seed)``), which draws
its initial population and its PyGAD ``random_seed``: point i's run depends only on
``(seed, i)``. This solver loops over points in Python on purpose: it exists to be compared.
"""
from __future__ import annotations

import time

import numpy as np
import pygad

from errormap.kinematics import inverse
from errormap.progress import Progress

from .base import BALL_RADIUS_UM, SolveResult
from ._common import MM_PER_UM, check_inputs, field_error_um, ga_result, project_to_ball
from ._converge import RETRY_ROUNDS, converge

PAPER_GA = {
    "population": 40,
    "generations": 400,
    "selection_probability": 0.7,
    "crossover_probability": 0.7,
    "mutation_probability": 0.2,
    "mutation_step_um": 1.0,
}
"""The paper's GA settings (Sec. 3.1) plus PyGAD's default random-mutation range (±1 gene unit)."""

DEFAULT_TOL_UM = 0.265
"""``success`` threshold on |model residual| for the GA solvers: the paper's worst GA
residual (max squared residual 0.07048 μm²)."""


def uniform_in_ball(rng: np.random.Generator, shape, radius_um) -> np.ndarray:
    """Points uniform in the ball of ``radius_um``, shape ``shape + (3,)``."""
    v = rng.normal(size=tuple(shape) + (3,))
    v /= np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)
    r = radius_um * rng.random(tuple(shape) + (1,)) ** (1.0 / 3.0)
    return v * r


def check_ga_options(population, generations, selection_probability, crossover_probability,
                     mutation_probability, mutation_step_um, tol_um) -> int:
    """Validate the GA settings; returns the number of mating parents."""
    if not (isinstance(population, (int, np.integer)) and population >= 2):
        raise ValueError(f"Expected population ≥ 2, got {population!r}")
    if not (isinstance(generations, (int, np.integer)) and generations >= 1):
        raise ValueError(f"Expected generations ≥ 1, got {generations!r}")
    for name, p in (("selection_probability", selection_probability), ("crossover_probability", crossover_probability),
                    ("mutation_probability", mutation_probability)):
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"Expected {name} in [0, 1], got {p!r}")
    if not mutation_step_um > 0 or not tol_um > 0:
        raise ValueError(f"Expected mutation_step_um > 0 and tol_um > 0, got {mutation_step_um!r}, {tol_um!r}")
    parents = int(round(selection_probability * population))
    if not 2 <= parents <= population:
        raise ValueError(f"Expected selection_probability·population to give 2..{population} parents, got {parents}")
    return parents


def solve_ga(field, targets_mm, machine, *, target_axes=None, a_start_deg=None, ball_um: float = BALL_RADIUS_UM,
             seed: int | np.random.Generator = 0, population: int = PAPER_GA["population"],
             generations: int = PAPER_GA["generations"],
             selection_probability: float = PAPER_GA["selection_probability"],
             crossover_probability: float = PAPER_GA["crossover_probability"],
             mutation_probability: float = PAPER_GA["mutation_probability"],
             mutation_step_um: float = PAPER_GA["mutation_step_um"], tol_um: float = DEFAULT_TOL_UM,
             progress: bool = True, retries: int = RETRY_ROUNDS, polish: bool = True) -> SolveResult:
    """PyGAD GA per target, WCS targets shape (n, 3) mm.

    ``success``: |model residual| ≤ ``tol_um`` and inside the ball. Points above ``tol_um``
    after ``generations`` are retried (``retries`` PyGAD runs from a fresh population around
    their best, drawn from the point's own Generator) and then, with ``polish``,
    Newton-polished (:mod:`._converge`); ``info["retry"]`` says how many and at what cost.
    """
    t0 = time.perf_counter()
    targets, axes_d = check_inputs(field, targets_mm, machine, target_axes, a_start_deg, ball_um)
    n_parents = check_ga_options(population, generations, selection_probability, crossover_probability,
                                 mutation_probability, mutation_step_um, tol_um)
    if not (isinstance(retries, (int, np.integer)) and 0 <= retries <= 10):
        raise ValueError(f"Expected retries in 0..10, got {retries!r}")
    # one child Generator per point: point i's run depends only on (seed, i), not on n
    point_rngs = np.random.default_rng(seed).spawn(len(targets))
    best = np.empty((len(targets), 3))
    nfev = 0
    bar = Progress(len(targets), "ga (PyGAD)", enabled=progress)
    for i in range(len(targets)):  # the per-point reference: a loop on purpose
        counter = [0]
        rng = point_rngs[i]
        best[i] = _run_one(field, machine, targets[i], rng, int(rng.integers(0, 2**31 - 1)), ball_um, population, generations,
                           n_parents, crossover_probability, mutation_probability, mutation_step_um, counter)
        nfev += counter[0]
        bar.update()

    def rerun(sub, radius_um):
        out, counter = np.empty((sub.size, 3)), [0]
        for j, (i, r) in enumerate(zip(sub.tolist(), radius_um.tolist())):
            rng = point_rngs[i]  # the point's own stream: its result still depends on (seed, i) only
            init = best[i] + r * uniform_in_ball(rng, (population,), 1.0)
            init[0] = best[i]  # the best so far survives (elitism)
            out[j] = _run_one(field, machine, targets[i], rng, int(rng.integers(0, 2**31 - 1)), ball_um, population,
                              generations, n_parents, crossover_probability, mutation_probability, mutation_step_um,
                              counter, init=project_to_ball(init, ball_um))
        return out, counter[0]

    best, fe, retry = converge(field, machine, targets, axes_d, best, tol_um, ball_um, rerun, retries, polish)
    return ga_result("ga", field, machine, targets, best, axes_d, nfev + fe, t0, ball_um, tol_um, seed,
                     pygad_version=pygad.__version__, parents=n_parents, retry=retry)


def _run_one(field, machine, target, rng, seed, ball_um, population, generations, n_parents,
             crossover_probability, mutation_probability, mutation_step_um, counter, init=None) -> np.ndarray:
    """One PyGAD run for one target; returns the best offset d (3,) μm, inside the ball.
    ``init`` (population, 3) μm: the initial population (default uniform in the ball)."""

    def fitness(ga, solutions, indices):
        d = np.asarray(solutions, dtype=float).reshape(-1, 3)
        q = inverse(machine, target + MM_PER_UM * d, unwrap=False)
        r = d + field_error_um(field, q, machine, fast=True)
        counter[0] += len(d)
        return list(-np.einsum("ij,ij->i", r, r))

    def on_mutation(ga, offspring):
        return project_to_ball(np.asarray(offspring, dtype=float), ball_um)

    ga = pygad.GA(num_generations=generations, num_parents_mating=n_parents, fitness_func=fitness,
                  fitness_batch_size=population,
                  initial_population=uniform_in_ball(rng, (population,), ball_um) if init is None else init,
                  gene_type=float, parent_selection_type="sss", keep_elitism=1,
                  crossover_type="single_point", crossover_probability=crossover_probability,
                  mutation_type="random", mutation_probability=mutation_probability,
                  mutation_by_replacement=False, random_mutation_min_val=-mutation_step_um,
                  random_mutation_max_val=mutation_step_um, on_mutation=on_mutation,
                  random_seed=seed, suppress_warnings=True)
    ga.run()
    solution, _, _ = ga.best_solution(ga.last_generation_fitness)
    return project_to_ball(np.asarray(solution, dtype=float), ball_um)
