"""The solver registry (compensation/solvers/__init__.py SOLVERS): the CLI's choices, the batch
runner, the comparison and the docs read it; an unknown name is refused in one place."""
import argparse
import importlib
import re
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import build_parser
from compensation.app.options import parse_methods
from compensation.app.validate import UsageError
from compensation.app.workflows.compare import compare_methods
from compensation.batch import GA_METHODS
from compensation.solvers import METHODS, SOLVERS, get_solver, solve, solver_spec
from errormap.field import CAPABILITIES

ROOT = Path(__file__).resolve().parents[1]
UNKNOWN = "simplex"
REFUSAL = re.escape(f"Expected method in {list(METHODS)}, got {UNKNOWN!r}")


def _subparser(command: str) -> argparse.ArgumentParser:
    parser = build_parser(commands=[command])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[command]


def _action(parser, option: str):
    return next(a for a in parser._actions if option in a.option_strings)


def test_the_cli_choices_are_the_registry():
    assert tuple(_action(_subparser("compensate"), "--method").choices) == METHODS == tuple(SOLVERS)
    for command in ("report", "demo"):
        assert _action(_subparser(command), "--methods").default == ",".join(METHODS)
    assert parse_methods(",".join(reversed(METHODS))) == tuple(reversed(METHODS))
    with pytest.raises(UsageError, match=UNKNOWN):
        parse_methods(f"exact,{UNKNOWN}")


def test_each_entry_matches_its_function():
    """Name → ``module:function``; the flags the batch runner passes options by agree with
    the function's keywords; the capabilities it names exist; its kernel modules import."""
    assert GA_METHODS == tuple(n for n, s in SOLVERS.items() if s.seeded) == ("ga", "batched-ga")
    for name, spec in SOLVERS.items():
        assert spec.name == name
        fn = spec.function()
        assert fn.__name__ == spec.entry.split(":")[1] and get_solver(name) is fn
        opts = spec.options()
        assert spec.seeded == ("seed" in opts)
        assert spec.progress == ("progress" in opts)
        assert spec.blockwise == (spec.seeded and "chunk" in opts)
        assert spec.uses <= CAPABILITIES, spec.uses - CAPABILITIES
        for mod in spec.kernels:
            importlib.import_module(mod)


def test_an_unknown_name_is_refused_in_one_place(grinder):
    with pytest.raises(ValueError, match=REFUSAL):
        solver_spec(UNKNOWN)
    with pytest.raises(ValueError, match=REFUSAL):
        get_solver(UNKNOWN)
    with pytest.raises(ValueError, match=REFUSAL):
        solve(UNKNOWN, None, np.zeros((1, 3)), grinder)
    with pytest.raises(ValueError, match=REFUSAL):
        compare_methods(None, np.zeros((1, 3)) + grinder.stroke_lo, grinder, methods=("exact", UNKNOWN))


def test_the_solver_docs_name_every_solver():
    text = (ROOT / "docs" / "explanation" / "solvers.md").read_text(encoding="utf-8")
    for name in METHODS:
        assert f"| `{name}` |" in text, name
