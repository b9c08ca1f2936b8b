import os
import resource
import signal
import subprocess
import time
import urllib.request

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

# The tier rule (README "Tests and benchmarks"): a test that needs more than this many CPU seconds
# (its own process and the subprocesses it starts, setup included; on 2 quiet cores that is about
# its wall time under `-n 2`) is marked @pytest.mark.slow and runs in the slow tier, which
# `.ci/run` runs after the fast one. CPU time, not wall time, so a loaded machine does not move it.
SLOW_TIER_CPU_S = 5.0


def _cpu_s() -> float:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    item._cpu_start_s = _cpu_s()
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    if call.when == "call" and hasattr(item, "_cpu_start_s"):
        rep.user_properties.append(("cpu_s", round(_cpu_s() - item._cpu_start_s, 2)))
        rep.user_properties.append(("slow", item.get_closest_marker("slow") is not None))


def pytest_terminal_summary(terminalreporter):
    """Name the unmarked tests that broke the tier rule (a reminder; it fails nothing)."""
    over = []
    for rep in terminalreporter.stats.get("passed", []) + terminalreporter.stats.get("failed", []):
        props = dict(getattr(rep, "user_properties", ()) or ())
        if not props.get("slow", True) and props.get("cpu_s", 0.0) > SLOW_TIER_CPU_S:
            over.append((props["cpu_s"], rep.nodeid))
    if over:
        terminalreporter.write_line(f"fast-tier tests over {SLOW_TIER_CPU_S:g} CPU s (mark them @pytest.mark.slow): "
                                    + "; ".join(f"{n} {c:.1f} s" for c, n in sorted(over, reverse=True)[:10]))


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Slow-tier tests that share a module-scoped fixture of their own file run on one worker: each such
    test gets ``xdist_group(<file>)`` unless it names its group itself (a run shared across files,
    tests/shared_runs.py). Under ``--dist loadgroup`` (.ci/run's slow tier) the fixture — a fitted model,
    a simulated machine, a Ray instance, a browser — is then built once, not once per worker; without
    xdist the mark does nothing. (tryfirst: before xdist reads the marks.)"""
    for item in items:
        if item.get_closest_marker("slow") is None or item.get_closest_marker("xdist_group") is not None:
            continue
        module_id = item.nodeid.split("::")[0]
        info = getattr(item, "_fixtureinfo", None)
        defs = [d for ds in (info.name2fixturedefs.values() if info else ()) for d in ds]
        if any(d.scope == "module" and d.baseid == module_id for d in defs):
            item.add_marker(pytest.mark.xdist_group(module_id))


@pytest.fixture(scope="session")
def grinder():
    from errormap.machine import load_machine
    return load_machine()


@pytest.fixture(scope="session")
def bump_user_path(tmp_path_factory):
    """The grinder's user's path on a bump, diagnosed with --track (tests/shared_runs.py): run once
    for the tests marked ``SHARED_GROUP["bump_user_path"]``."""
    import shared_runs
    return shared_runs.bump_user_path(tmp_path_factory.mktemp("bump-user-path"))


@pytest.fixture(scope="session")
def mill_reversal(tmp_path_factory):
    """mill-xyz with reversal:Z simulated and diagnosed (tests/shared_runs.py): run once for the tests
    marked ``SHARED_GROUP["mill_reversal"]``."""
    import shared_runs
    return shared_runs.mill_reversal(tmp_path_factory.mktemp("mill-reversal"))


@pytest.fixture(scope="session")
def tiny_demo(tmp_path_factory):
    """``volcomp demo`` with tiny settings (tests/shared_runs.py): run once for the tests marked
    ``SHARED_GROUP["tiny_demo"]``."""
    import shared_runs
    return shared_runs.tiny_demo(tmp_path_factory.mktemp("tiny-demo"))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def wait_until_serving(proc, url: str, limit_s: float, log_path, what: str) -> None:
    """Poll ``url`` until it answers 200, failing the test if ``proc`` exits first or ``limit_s``
    passes (a local server started by a test; bounded, never unbounded waiting)."""
    deadline = time.monotonic() + limit_s
    while True:
        if proc.poll() is not None:
            pytest.fail(f"{what} exited with {proc.returncode}: {log_path.read_text()[-2000:]}")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            pass
        if time.monotonic() > deadline:
            pytest.fail(f"{what} did not answer within {limit_s} s")
        time.sleep(0.5)


def stop_process_group(proc) -> None:
    """End a server a test started in its own session: SIGTERM to its process group, then
    SIGKILL if it has not exited within 20 s."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=10)
