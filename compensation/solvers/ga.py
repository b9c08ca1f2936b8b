"""The paper's genetic algorithm: its settings, as PyGAD runs them (the ``ga`` solver, one point at a time
through PyGAD itself, and the ``batched-ga`` solver's compiled generations,
:func:`compensation.solvers.chain_ga.solve_ga_chain` / :func:`~compensation.solvers.chain_ga.solve_batched_ga_chain`).

Three genes per target ``p_d`` in the 250 μm ball (the offsets ``d`` μm of the commanded target, or the solved
axes' scaled offsets where a rotary axis is solved); fitness minus the squared model residual (μm², PyGAD
maximises). :data:`PAPER_GA`: population 40, 400 generations, 28 mating parents (selection probability 0.7 as
steady-state selection), single-point crossover 0.7, random additive mutation 0.2 per gene of U(-1, 1) μm,
elitism 1, offspring projected onto the ball. The paper-to-PyGAD table: docs/explanation/solvers.md.
"""
from __future__ import annotations

import numpy as np

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
