"""Is numba's on-disk cache cold? (a one-line notice before the first compilation after install).

The compiled kernels (``@njit(cache=True)`` in :mod:`errormap.htm`, the solvers, the G-code
planner) are compiled on their first call after an install or an edit and read from numba's
cache afterwards. The first compilation takes tens of seconds with nothing to show for it, so
a command that is about to call kernels whose cache holds nothing yet says so first
(:func:`notice_cold_kernels`). The check only looks for numba's cache index files; it
compiles nothing and changes nothing.
"""
from __future__ import annotations

import sys
from pathlib import Path

COLD_NOTICE = ("compiling the numba kernels once after install (about 20 s on 2 cores; cached for every "
               "later run) ...")


def _dispatchers(module):
    """The module's cached numba kernels that are compiled on their own (inlined helpers are
    compiled into their callers and never get a cache entry of their own)."""
    try:
        from numba.core.registry import CPUDispatcher
    except ImportError:  # pragma: no cover - numba is a dependency
        return []
    out = []
    for name, obj in sorted(vars(module).items()):
        if isinstance(obj, CPUDispatcher) and getattr(obj.py_func, "__module__", None) == module.__name__ \
                and obj.targetoptions.get("inline") != "always":
            out.append((name, obj))
    return out


def cold_kernels(*modules) -> list[str]:
    """``module.kernel`` names among ``modules`` whose numba cache index file does not exist
    yet (their first call compiles). A kernel whose cache location cannot be read is left out:
    the notice is a courtesy and never guesses."""
    cold = []
    for module in modules:
        for name, disp in _dispatchers(module):
            try:
                index = Path(disp._cache._cache_file._index_path)  # numba's FunctionCache (0.5x–0.6x)
            except AttributeError:
                continue
            if not disp.signatures and not index.is_file():
                cold.append(f"{module.__name__}.{name}")
    return cold


def notice_cold_kernels(*modules, log=None) -> bool:
    """Print :data:`COLD_NOTICE` (one line, ``log``: stderr) when any kernel of ``modules``
    is cold (:func:`cold_kernels`); returns whether it did."""
    if not cold_kernels(*modules):
        return False
    print(COLD_NOTICE, file=sys.stderr if log is None else log, flush=True)
    return True
