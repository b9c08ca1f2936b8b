"""Is numba's on-disk cache cold? (a one-line notice before the first compilation after install).

The compiled kernels (``@njit(cache=True)``) compile on their first call after an install or an edit, for tens
of seconds; a command about to call kernels whose cache holds nothing yet says so first
(:func:`notice_cold_kernels`). The check only looks for numba's cache index files; it compiles nothing."""
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
    """``module.kernel`` names of the modules among ``modules`` that have no kernel compiled
    yet, neither in this process nor in numba's cache (no cache index file): right after an
    install. A module with some kernels cached counts as warm (a run compiles only the kernels
    it calls; the rest would otherwise announce a compilation on every run). A kernel whose
    cache location cannot be read counts as warm: the notice is a courtesy and never guesses."""
    cold = []
    for module in modules:
        names, warm = [], False
        for name, disp in _dispatchers(module):
            try:
                index = Path(disp._cache._cache_file._index_path)  # numba's FunctionCache (0.5x–0.6x)
            except AttributeError:
                warm = True
                continue
            if disp.signatures or index.is_file():
                warm = True
            names.append(f"{module.__name__}.{name}")
        if names and not warm:
            cold += [n for n in names if n not in cold]
    return cold


def notice_cold_kernels(*modules, log=None) -> bool:
    """Print :data:`COLD_NOTICE` (one line, ``log``: stderr) when any kernel of ``modules``
    is cold (:func:`cold_kernels`); returns whether it did."""
    if not cold_kernels(*modules):
        return False
    print(COLD_NOTICE, file=sys.stderr if log is None else log, flush=True)
    return True
