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
        props = [("cpu_s", round(_cpu_s() - item._cpu_start_s, 2)), ("slow", item.get_closest_marker("slow") is not None)]
        rep.user_properties.extend(props)
        item.user_properties.extend(props)   # the teardown report copies them: --junitxml writes them per test case


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


SAME_WORKER = {
    "tests/test_demo.py": "tiny demo, mill-xyz reversal:Z diagnosis, mill-xyz quick benchmark",
    "tests/test_report_pages.py": "tiny demo, mill-xyz reversal:Z diagnosis, mill-xyz quick benchmark",
    "tests/test_chain_report.py": "tiny demo, mill-xyz reversal:Z diagnosis, mill-xyz quick benchmark",
    "tests/test_diagnose_chain_output.py": "tiny demo, mill-xyz reversal:Z diagnosis, mill-xyz quick benchmark",
    "tests/test_hybrid_user_path.py": "bump user path",
    "tests/test_tracking_learned_residual.py": "bump user path",
    "tests/test_cluster.py": "Ray, MLflow tracking server",
    "tests/test_chain_cluster.py": "Ray, MLflow tracking server",
    "tests/test_mlflow_server.py": "Ray, MLflow tracking server",
    "tests/test_benchmark.py": "tiny demo, mill-xyz reversal:Z diagnosis, mill-xyz quick benchmark",
    "tests/test_plain_csv_outputs.py": "tiny demo, mill-xyz reversal:Z diagnosis, mill-xyz quick benchmark",
}
"""Test files whose tests read one session-shared run (tests/shared_runs.py): one unit of work under
``--dist loadscope``, so the run happens once, on one worker."""

EACH_TEST_ITS_OWN_UNIT = {
    "tests/test_chain_loop_terms.py",        # two independent five-axis user's paths (one ~200 CPU s)
    "tests/test_hybrid_condition_terms.py",
    "tests/test_hybrid_backfit.py",
}
"""Slow-tier files whose slow tests share no module fixture worth keeping on one worker (each builds its own
data): each test is its own unit of ``--dist loadscope``, so a file of long tests does not keep one worker busy
while the other idles."""

UNIT_WALL_S = {
    "tiny demo, mill-xyz reversal:Z diagnosis, mill-xyz quick benchmark": 117.0,
    "Ray, MLflow tracking server": 84.0,   # mostly waiting on Ray's processes and the server
    "tests/test_benchmarks_suite.py": 55.0,
    "bump user path": 54.0,
    "tests/test_tutorials.py": 38.0,
    "tests/test_hybrid_chain.py": 30.0,
    "tests/test_hybrid.py": 26.0,
    "tests/test_arm_calibration.py": 24.0,
    "tests/test_drift_models.py": 20.0,
    "tests/test_hybrid_backfit.py::test_user_path_backfits_the_learned_part_with_the_update_on_an_a_axis_tilt": 17.0,
    "tests/test_new_machine_is_a_file.py": 17.0,
    "tests/test_cli_robust.py": 16.0,
}
"""The slow tier's longest units of work, handed out first (longest first: with a long unit last, one worker would
run it alone at the end while the other idles). Their wall seconds in the last full slow-tier run (`-n 2 --dist
loadscope`, one BLAS thread, quiet machine, 2026-12-04, 252 tests in 419 s; the units' walls summed 794 s): the
sizes, not CPU seconds — the Ray unit's tests wait on Ray's processes. Units not named follow, most tests first."""


def _unit(nodeid: str) -> str:
    """The ``--dist loadscope`` unit of work of a test: its file, the group of ``SAME_WORKER``, or itself
    (``EACH_TEST_ITS_OWN_UNIT``)."""
    module = nodeid.split("::", 1)[0]
    return nodeid if module in EACH_TEST_ITS_OWN_UNIT else SAME_WORKER.get(module, module)


def _unit_wall_s(unit: str) -> float:
    """``UNIT_WALL_S`` of a unit (a parametrized test's cases: the test's), 0 for one not named."""
    return UNIT_WALL_S.get(unit, UNIT_WALL_S.get(unit.split("[", 1)[0], 0.0))


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """The controller's ``--dist`` handed to each xdist worker (``workerinput``): a worker's own option reads
    ``"no"`` (xdist sets it so), and the worker's collection order is the one the scheduler hands out."""
    node.workerinput["volcomp_dist"] = node.config.getvalue("dist")


def _dist(config) -> str:
    """The run's ``--dist``, in the controller or in a worker (:func:`pytest_configure_node`)."""
    return getattr(config, "workerinput", {}).get("volcomp_dist", config.getvalue("dist"))


def pytest_collection_modifyitems(config, items):
    """Under ``--dist loadscope`` the units are handed out in the workers' collection order: the longest ones
    first (``UNIT_WALL_S``), then the others by their number of tests (xdist's own order), each unit's tests in
    their order (a stable sort)."""
    if _dist(config) == "loadscope":
        units = [_unit(item.nodeid) for item in items]
        n_tests = {u: units.count(u) for u in set(units)}
        key = {id(item): (-_unit_wall_s(u), -n_tests[u]) for item, u in zip(items, units)}
        items.sort(key=lambda item: key[id(item)])


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope`` (.ci/run's slow tier): every test file is one unit of work for one worker, so a
    module-scoped fixture (a fitted model, a simulated machine, a Ray instance, a browser) is built once, not
    once per worker; the files of ``SAME_WORKER`` are one unit together, each test of ``EACH_TEST_ITS_OWN_UNIT``
    one unit alone. The units are handed out in collection order (xdist's reordering by number of tests per
    unit is switched off: :func:`pytest_collection_modifyitems` puts the longest first). (xdist's ``loadgroup``
    marks do not take with pytest 9: xdist renames ``item._nodeid``, which pytest 9 no longer reads.)"""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling
    config.option.loadscopereorder = False

    class SharedRunScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _unit(nodeid)
    return SharedRunScheduling(config, log)


@pytest.fixture(scope="session")
def grinder():
    from errormap.machine import load_machine
    return load_machine()


@pytest.fixture(scope="session")
def bump_user_path(tmp_path_factory):
    """The grinder's user's path on a bump, diagnosed with --track (tests/shared_runs.py): run once
    for the tests that read it (``SAME_WORKER``)."""
    import shared_runs
    return shared_runs.bump_user_path(tmp_path_factory.mktemp("bump-user-path"))


@pytest.fixture(scope="session")
def mill_reversal(tmp_path_factory):
    """mill-xyz with reversal:Z simulated and diagnosed (tests/shared_runs.py): run once for the tests
    that read it (``SAME_WORKER``)."""
    import shared_runs
    return shared_runs.mill_reversal(tmp_path_factory.mktemp("mill-reversal"))


@pytest.fixture(scope="session")
def tiny_demo(tmp_path_factory):
    """``volcomp demo`` with tiny settings (tests/shared_runs.py): run once for the tests marked
    read it (``SAME_WORKER``)."""
    import shared_runs
    return shared_runs.tiny_demo(tmp_path_factory.mktemp("tiny-demo"))


MLFLOW_STARTUP_LIMIT_S = 120.0
"""Bounded poll for a test's ``mlflow server`` to answer /health."""


MLFLOW_SERVER_ENV = {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
"""The test server's environment: MLflow's job execution off. On by default (mlflow 3), it starts a job runner and
seven Huey consumer processes beside the web server (GenAI scorer jobs; nothing a tracked run or an artifact uses):
~25 of the server's ~31 CPU s over the Ray/MLflow unit (measured 2026-12-04 in a cpuacct cgroup), and they made
its SIGTERM take ~10 s."""


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def mlflow_server(tmp_path_factory):
    """A real ``mlflow server`` (own SQLite store, artifact folder ``art``, in a temp dir), started once for the
    tests that track on a server (``SAME_WORKER``): ``(url, folder)``. A test finds its own runs' artifacts under
    ``folder/art`` by their run ids."""
    import shutil
    import sys
    from pathlib import Path
    tmp = tmp_path_factory.mktemp("mlflow-server")
    exe = Path(sys.executable).with_name("mlflow")
    exe = str(exe) if exe.is_file() else (shutil.which("mlflow") or "mlflow")
    port = free_port()
    log = open(tmp / "server.log", "wb")
    cmd = [exe, "server", "--backend-store-uri", f"sqlite:///{tmp / 'db.sqlite'}",
           "--artifacts-destination", str(tmp / "art"), "--serve-artifacts",
           "--host", "127.0.0.1", "--port", str(port), "--workers", "1"]
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                            env={**os.environ, "MLFLOW_TRACKING_URI": "", **MLFLOW_SERVER_ENV})
    url = f"http://127.0.0.1:{port}"
    try:
        wait_until_serving(proc, url + "/health", MLFLOW_STARTUP_LIMIT_S, tmp / "server.log", "mlflow server")
        yield url, tmp
    finally:
        stop_process_group(proc)   # the server runs in its own session: end exactly that process group
        log.close()


@pytest.fixture(scope="session")
def mill_quick_benchmark(tmp_path_factory):
    """``volcomp benchmark --machine mill-xyz --quick --no-track`` (tests/shared_runs.py): run once for the tests
    that read it (``SAME_WORKER``)."""
    import shared_runs
    return shared_runs.mill_quick_benchmark(tmp_path_factory.mktemp("mill-quick-benchmark"))


RAY_STARTED = pytest.StashKey[tuple]()
"""``config.stash``: ``(PYTHONPATH before,)`` while a Ray instance started by :func:`ray_session` runs."""


@pytest.fixture
def ray_session(request):
    """A local 2-CPU Ray instance for the tests that run on Ray (tests/test_cluster.py, tests/test_chain_cluster.py:
    one unit of ``SAME_WORKER``, so two instances never run at once and ``--dist loadscope`` starts one): started by
    the first of them, kept while the next test is of the same unit, ended after the unit's last one
    (:func:`pytest_runtest_teardown`; an idle instance takes ~6 % of a core). The workers import this tree
    (``PYTHONPATH``)."""
    ray = pytest.importorskip("ray")
    stash = request.config.stash
    if RAY_STARTED not in stash:
        from pathlib import Path
        root = str(Path(__file__).resolve().parents[1])
        old = os.environ.get("PYTHONPATH")
        os.environ["PYTHONPATH"] = root + (os.pathsep + old if old else "")
        stash[RAY_STARTED] = (old,)
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield


def _stop_ray(config) -> None:
    """End the Ray instance :func:`ray_session` started, if one runs, and restore ``PYTHONPATH``."""
    if RAY_STARTED not in config.stash:
        return
    (old,) = config.stash[RAY_STARTED]
    del config.stash[RAY_STARTED]
    import ray
    ray.shutdown()
    if old is None:
        os.environ.pop("PYTHONPATH", None)
    else:
        os.environ["PYTHONPATH"] = old


def pytest_runtest_teardown(item, nextitem):
    """After the last test of a unit of work (``_unit``) that started Ray: end it."""
    if nextitem is None or _unit(nextitem.nodeid) != _unit(item.nodeid):
        _stop_ray(item.config)


def pytest_sessionfinish(session):
    _stop_ray(session.config)


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
