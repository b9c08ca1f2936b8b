"""The ``errormap`` package of another checkout, imported beside this one in the same process.

The grinder's hand-written kernels were deleted from ``errormap`` (the chain replaced them); benchmarks that keep
the old-vs-new ratio honest time the old kernels from a copy of main before that change, e.g.::

    git archive 0485cf2 | (mkdir -p /tmp/main-0485cf2 && tar -x -C /tmp/main-0485cf2)
    python benchmarks/bench_chain.py --baseline-root /tmp/main-0485cf2

:func:`baseline_module` loads ``ROOT/errormap`` as the package ``errormap_baseline`` (its modules
import each other relatively, so nothing of this checkout's ``errormap`` is mixed in) and returns
one of its modules.
"""
from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path

ALIAS = "errormap_baseline"


def baseline_module(root, name: str):
    """``errormap.<name>`` of the checkout at ``root`` (imported once as ``errormap_baseline``)."""
    pkg = Path(root).resolve() / "errormap"
    if not (pkg / "__init__.py").is_file():
        raise SystemExit(f"--baseline-root {root}: no errormap/__init__.py there (expected a checkout of main)")
    if ALIAS not in sys.modules:
        spec = importlib.util.spec_from_file_location(ALIAS, pkg / "__init__.py", submodule_search_locations=[str(pkg)])
        mod = importlib.util.module_from_spec(spec)
        sys.modules[ALIAS] = mod
        spec.loader.exec_module(mod)
    return importlib.import_module(f"{ALIAS}.{name}")
