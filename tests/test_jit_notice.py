"""The one-line notice before numba's first compilation after install (errormap/jit.py)."""
import os
import subprocess
import sys
import textwrap
from pathlib import Path


KERNEL = textwrap.dedent('''
    from numba import njit

    @njit(cache=True)
    def twice(x):
        return 2.0 * x

    @njit(cache=True, inline="always")
    def helper(x):
        return x

    @njit(cache=True)
    def never_called(x):
        return x
''')

PROBE = textwrap.dedent('''
    import sys
    import kern
    from errormap.jit import cold_kernels, notice_cold_kernels
    print("cold:", ",".join(cold_kernels(kern)))
    notice_cold_kernels(kern)
    if sys.argv[1] == "call":
        kern.twice(1.0)
        print("after call:", ",".join(cold_kernels(kern)))
''')


def _run(tmp_path: Path, cache: Path, what: str):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), str(Path(__file__).resolve().parents[1]),
                                          os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, str(tmp_path / "probe.py"), what], capture_output=True, text=True,
                          env=env, timeout=120)


def test_cold_cache_is_named_once_and_warm_cache_is_silent(tmp_path):
    """A fresh numba cache: the module's kernels are named cold and ONE notice line goes to stderr;
    after one of them is called (compiled, cached) the module is warm — also for the kernel this
    run never called, which would otherwise announce a compilation on every run — and a new
    process says nothing."""
    from errormap.jit import COLD_NOTICE
    (tmp_path / "kern.py").write_text(KERNEL)
    (tmp_path / "probe.py").write_text(PROBE)
    cache = tmp_path / "numba-cache"
    first = _run(tmp_path, cache, "call")
    assert first.returncode == 0, first.stderr
    assert "cold: kern.never_called,kern.twice\n" in first.stdout  # the inlined helper has no cache entry
    assert "after call: \n" in first.stdout
    assert first.stderr.strip().splitlines() == [COLD_NOTICE]
    second = _run(tmp_path, cache, "look")
    assert second.returncode == 0, second.stderr
    assert "cold: \n" in second.stdout and second.stderr.strip() == ""


def test_the_compensate_kernel_modules_are_real_numba_modules():
    """kernel_modules names importable modules that do hold cached kernels (a renamed module would
    silently turn the notice off)."""
    from compensation.app.workflows.compensate import kernel_modules
    from errormap.jit import _dispatchers
    for method in ("traditional", "ga", "batched-ga", "exact"):
        mods = kernel_modules(method)
        assert mods and all(_dispatchers(m) for m in mods), method
