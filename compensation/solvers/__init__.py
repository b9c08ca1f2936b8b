"""Compensation solvers behind one interface, listed in ONE registry (:data:`SOLVERS`).

``solve(method, field, targets_mm, machine, **options) -> SolveResult`` where ``method`` is a
name of :data:`SOLVERS` (``traditional``, ``ga``, ``batched-ga``, ``exact``). Each solver module
holds a function ``solve_<module>(field, targets_mm, machine, **options) -> SolveResult``. The
CLI's ``--method``/``--methods`` choices, the batch runner, the method comparison, the kernel
warm-up of ``compensate``, the benchmark and docs/solvers.md read this table; a name not in it
is refused in one place, :func:`solver_spec`.

A field is anything with ``predict(axes) -> (n, 3) μm``; a field may also offer
``jacobian(axes) -> (n, 3, 3)`` (μm per mm, mm, deg of x, z, a); solvers that need the
derivative fall back to central differences when it does not.
"""
from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass

from .base import BALL_RADIUS_UM, SolveResult

COMMON_ARGUMENTS = ("field", "targets_mm", "machine", "target_axes", "a_start_deg")
"""What every solve function takes; the rest of its keywords are its options (:meth:`Solver.options`)."""


@dataclass(frozen=True)
class Solver:
    """One solver: its name (``--method``), module (``compensation/solvers/<module>.py`` with
    ``solve_<module>``), a one-line summary, the field capabilities it uses when the field
    declares them (``errormap.field``; none is required: every solver runs on ``predict``
    alone), whether it is stochastic (takes ``seed``), shows progress (takes ``progress``),
    evolves a whole chunk as one block (takes ``workers``/``chunk``), and the modules whose
    numba kernels it compiles on first use."""

    name: str
    module: str
    summary: str
    uses: frozenset = frozenset()
    seeded: bool = False
    progress: bool = True
    blockwise: bool = False
    kernels: tuple = ()
    chain: str = ""
    """On a machine-tool chain (``machine.kind == "machine-tool"``): ``"module:function"`` in
    ``compensation/solvers/`` solving the tool tip with the chain's linear axes (rotary axes kept);
    empty: the solver is the grinder's only."""

    @property
    def function_name(self) -> str:
        return f"solve_{self.module}"

    def function(self):
        """The solve function (its module imported on first use: numba kernels load with it)."""
        return getattr(importlib.import_module(f"compensation.solvers.{self.module}"), self.function_name)

    def options(self) -> dict:
        """``{option: default}``: the solve function's keywords beyond :data:`COMMON_ARGUMENTS`."""
        sig = inspect.signature(self.function())
        return {k: p.default for k, p in sig.parameters.items() if k not in COMMON_ARGUMENTS}

    def chain_function(self):
        """The solve function on a machine-tool chain; ValueError when the solver has none."""
        if not self.chain:
            raise ValueError(f"method {self.name!r} is not available on a machine-tool chain; "
                             f"there: {', '.join(CHAIN_METHODS)}")
        module, func = self.chain.split(":")
        return getattr(importlib.import_module(f"compensation.solvers.{module}"), func)


SOLVERS = {s.name: s for s in (
    Solver("traditional", "traditional", "subtract the field's error at the nominal axes once (no iteration)",
           uses=frozenset({"predict_columns"}), progress=False, chain="chain_traditional:solve_traditional_chain"),
    Solver("ga", "ga", "the paper's genetic algorithm, one point at a time",
           uses=frozenset({"float32", "predict_columns"}), seeded=True, chain="chain_ga:solve_ga_chain"),
    Solver("batched-ga", "batched_ga", "the same GA evolved for a block of points at once (numba breeding kernels)",
           uses=frozenset({"float32", "offset_fitness", "predict_columns"}), seeded=True, blockwise=True,
           kernels=("compensation.solvers._ga_kernels",), chain="chain_ga:solve_batched_ga_chain"),
    Solver("exact", "exact", "Newton on the field's own error (analytic Jacobian where the field declares it)",
           uses=frozenset({"jacobian", "predict_and_jacobian", "float32", "predict_columns"}), kernels=("compensation.solvers.exact",),
           chain="chain_exact:solve_exact_chain"),
)}
METHODS = tuple(SOLVERS)
"""The solver names, in the order reports list them."""
GA_METHODS = tuple(n for n, s in SOLVERS.items() if s.seeded)
CHAIN_METHODS = tuple(n for n, s in SOLVERS.items() if s.chain)
"""The solvers available on a machine-tool chain (their ``chain`` entry)."""


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
    """Run solver ``method`` on WCS targets, shape (n, 3) mm. On a machine-tool chain
    (``machine.kind == "machine-tool"``) the solver's ``chain`` entry runs (``traditional``:
    :func:`compensation.solvers.chain_traditional.solve_traditional_chain`, ``exact``:
    :func:`compensation.solvers.chain_exact.solve_exact_chain`, ``batched-ga``:
    :func:`compensation.solvers.chain_ga.solve_batched_ga_chain`; the tool tip with the chain's three
    linear axes, rotary axes kept, or with exact every axis of a three-axis machine such as a lathe's
    X, Z, C); a method without one is refused (ValueError)."""
    from errormap.grinder_file import is_machine_tool, machine_tool_of
    if is_machine_tool(machine):  # a grinder file is solved on its chain
        machine = machine_tool_of(machine)
    return solve_function(method, machine)(field, targets_mm, machine, **options)


def solve_function(method: str, machine):
    """The function :func:`solve` runs for ``method`` on ``machine`` (the solver's ``chain`` entry on a
    machine-tool chain); ValueError for an unknown method or one the chain lacks."""
    from errormap.grinder_file import is_machine_tool
    spec = solver_spec(method)
    return spec.chain_function() if is_machine_tool(machine) else spec.function()


__all__ = ["BALL_RADIUS_UM", "CHAIN_METHODS", "GA_METHODS", "METHODS", "SOLVERS", "SolveResult", "Solver", "get_solver", "solve",
           "solve_function", "solver_spec"]
