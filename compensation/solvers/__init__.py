"""Compensation solvers behind one interface, listed in ONE registry (:data:`SOLVERS`).

``solve(method, field, targets_mm, machine, **options) -> SolveResult`` where ``method`` is a name of
:data:`SOLVERS` (``traditional``, ``ga``, ``batched-ga``, ``exact``) and ``machine`` a machine tool (its
chain). Each entry names its function ``"module:function"`` in ``compensation/solvers/``; the CLI's
``--method``/``--methods`` choices, the batch runner, the method comparison, the kernel warm-up, the
benchmark and docs/explanation/solvers.md read this table; a name not in it is refused in one place,
:func:`solver_spec`. A field is anything with ``predict(axes) -> (n, 3) μm`` over the machine's axis
columns; its optional capabilities (``errormap.field``) are used where it declares them."""
from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass

from .base import BALL_RADIUS_UM, SolveResult

COMMON_ARGUMENTS = ("field", "targets_mm", "machine", "target_axes")
"""What every solve function takes; the rest of its keywords are its options (:meth:`Solver.options`)."""


@dataclass(frozen=True)
class Solver:
    """One solver: its name (``--method``), its function (``"module:function"`` in
    ``compensation/solvers/``), a one-line summary, the field capabilities it uses when the field
    declares them (``errormap.field``; none is required: every solver runs on ``predict`` alone),
    whether it is stochastic (takes ``seed``), shows progress (takes ``progress``), evolves a whole
    chunk as one block (a seeded solver taking ``chunk``), and the modules whose numba kernels it compiles on first use."""

    name: str
    entry: str
    summary: str
    uses: frozenset = frozenset()
    seeded: bool = False
    progress: bool = True
    blockwise: bool = False
    kernels: tuple = ()

    def function(self):
        """The solve function (its module imported on first use: numba kernels load with it)."""
        module, func = self.entry.split(":")
        return getattr(importlib.import_module(f"compensation.solvers.{module}"), func)

    def options(self) -> dict:
        """``{option: default}``: the solve function's keywords beyond :data:`COMMON_ARGUMENTS`."""
        sig = inspect.signature(self.function())
        return {k: p.default for k, p in sig.parameters.items() if k not in COMMON_ARGUMENTS}


SOLVERS = {s.name: s for s in (
    Solver("traditional", "chain_traditional:solve_traditional_chain",
           "subtract the field's error at the nominal axes once (no iteration)", progress=True),
    Solver("ga", "chain_ga:solve_ga_chain", "the paper's genetic algorithm through PyGAD, one point at a time",
           seeded=True),
    Solver("batched-ga", "chain_ga:solve_batched_ga_chain",
           "the same GA evolved for a block of points at once (numba breeding kernels)", seeded=True, blockwise=True,
           kernels=("compensation.solvers._ga_kernels",)),
    Solver("exact", "chain_exact:solve_exact_chain",
           "Newton on the field's own error (analytic Jacobian where the field declares it)",
           uses=frozenset({"jacobian", "predict_and_jacobian", "float32", "predict_columns"}),
           kernels=("compensation.solvers.exact",)),
)}
METHODS = tuple(SOLVERS)
"""The solver names, in the order reports list them."""
GA_METHODS = tuple(n for n, s in SOLVERS.items() if s.seeded)


def solver_spec(method: str) -> Solver:
    """The registry entry of ``method``; raises ValueError naming the allowed methods (the one place
    an unknown name is refused)."""
    if not isinstance(method, str) or method not in SOLVERS:
        raise ValueError(f"Expected method in {list(METHODS)}, got {method!r}")
    return SOLVERS[method]


def get_solver(method: str):
    """The solve function for ``method``; raises ValueError naming the allowed methods."""
    return solver_spec(method).function()


def solve(method: str, field, targets_mm, machine, **options) -> SolveResult:
    """Run solver ``method`` on WCS targets, shape (n, 3) mm, on the machine tool ``machine`` (a grinder
    file on its chain); ValueError for an unknown method."""
    return get_solver(method)(field, targets_mm, machine, **options)


__all__ = ["BALL_RADIUS_UM", "GA_METHODS", "METHODS", "SOLVERS", "SolveResult", "Solver", "get_solver", "solve",
           "solver_spec"]
