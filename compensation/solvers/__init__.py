"""Compensation solvers behind one interface.

``solve(method, field, targets_mm, machine, **options) -> SolveResult`` where ``method`` is
one of ``traditional``, ``ga``, ``batched-ga``, ``exact``. Each solver module registers a
function ``solve_<name>(field, targets_mm, machine, **options) -> SolveResult``.

A field is anything with ``predict(axes) -> (n, 3) μm``; a field may also offer
``jacobian(axes) -> (n, 3, 3)`` (μm per mm, mm, deg of x, z, a); solvers that need the
derivative fall back to central differences when it does not.
"""
from __future__ import annotations

import importlib

from .base import BALL_RADIUS_UM, SolveResult

METHODS = ("traditional", "ga", "batched-ga", "exact")
_MODULES = {"traditional": "traditional", "ga": "ga", "batched-ga": "batched_ga", "exact": "exact"}


def get_solver(method: str):
    """The solve function for ``method``; raises ValueError naming the allowed methods."""
    if method not in _MODULES:
        raise ValueError(f"Expected method in {list(METHODS)}, got {method!r}")
    mod = importlib.import_module(f"compensation.solvers.{_MODULES[method]}")
    return getattr(mod, "solve_" + _MODULES[method])


def solve(method: str, field, targets_mm, machine, **options) -> SolveResult:
    """Run solver ``method`` on WCS targets, shape (n, 3) mm."""
    return get_solver(method)(field, targets_mm, machine, **options)


__all__ = ["BALL_RADIUS_UM", "METHODS", "SolveResult", "get_solver", "solve"]
