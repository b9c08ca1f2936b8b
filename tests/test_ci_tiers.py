"""`.ci/run` runs the fast tier and the slow tier; `.ci/tiers.py` writes the closing line for both."""
import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]

FAST = ('<?xml version="1.0"?><testsuites><testsuite name="pytest" errors="0" failures="1" skipped="2" '
        'tests="10" time="12.5"></testsuite></testsuites>')
SLOW = ('<?xml version="1.0"?><testsuites><testsuite name="pytest" errors="0" failures="0" skipped="0" '
        'tests="3" time="30.25"></testsuite></testsuites>')


def test_closing_line_adds_both_tiers(tmp_path):
    (tmp_path / "f.xml").write_text(FAST)
    (tmp_path / "s.xml").write_text(SLOW)
    r = subprocess.run([sys.executable, str(ROOT / ".ci" / "tiers.py"), str(tmp_path / "f.xml"),
                        str(tmp_path / "s.xml")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0
    assert r.stdout.strip() == ("1 failed, 10 passed, 2 skipped in 42.75s (fast tier: 1 failed, 7 passed, "
                                "2 skipped in 12.50s; slow tier: 3 passed in 30.25s)")


def test_a_missing_tier_is_named(tmp_path):
    (tmp_path / "f.xml").write_text(FAST)
    r = subprocess.run([sys.executable, str(ROOT / ".ci" / "tiers.py"), str(tmp_path / "f.xml"),
                        str(tmp_path / "none.xml")], capture_output=True, text=True, timeout=60)
    assert "slow tier: no result file" in r.stdout


def test_ci_runs_both_tiers_and_the_readme_names_the_fast_one():
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'pytest -q -n 2 -m "not slow"' in ci and "pytest -q -n 2 -m slow" in ci
    assert '-ne 5' in ci  # "no tests collected" is not a failure
    readme = (ROOT / "README.md").read_text()
    assert 'python -m pytest -q -n 2 -m "not slow"' in readme.split("\n## ")[0]


def test_ci_warms_the_kernel_cache_before_the_tiers_and_only_waits_for_it():
    """Chromium's install starts in the background before the Python packages' (the two overlap); the kernel warm-up
    (.ci/warm_kernels.py) starts in the background after them; both are waited for before the fast tier, and a
    failure of either is printed, never CI's exit status (the tests compile what the warm-up missed; the browser
    check skips)."""
    ci = (ROOT / ".ci" / "run").read_text()
    apt, pip, warm, wait_apt, wait_warm, fast = (ci.index(s) for s in (
        "apt-get install", "pip install", "python .ci/warm_kernels.py", 'wait "$chromium"', 'wait "$warm"',
        '-m "not slow"'))
    assert apt < pip < warm < wait_apt < fast and warm < wait_warm < fast
    assert ci[apt:pip].count(" &\n") == 1   # in the background
    assert 'if ! wait "$warm"' in ci and '! wait "$chromium"' in ci


def test_a_worker_sorts_the_slow_tiers_units_longest_first():
    """xdist runs its workers with ``--dist no`` and hands out the units in a worker's collection order: the
    controller's ``--dist`` reaches the workers through ``workerinput`` (conftest.pytest_configure_node), so a worker
    sorts the units longest first (``UNIT_WALL_S``; the Ray unit, then the benchmark suite, then the rest), each
    unit's tests in their order. Without it the units ran alphabetically (the tutorials, 74 s, last)."""
    import conftest

    class Node:
        def __init__(self):
            self.config, self.workerinput = Config("loadscope", None), {}

    class Config:
        def __init__(self, dist, workerinput):
            self.dist = dist
            if workerinput is not None:
                self.workerinput = workerinput

        def getvalue(self, name):
            assert name == "dist"
            return self.dist

    class Item:
        def __init__(self, nodeid):
            self.nodeid = nodeid

    node = Node()
    conftest.pytest_configure_node(node)
    assert node.workerinput == {"volcomp_dist": "loadscope"}
    ids = ["tests/test_api_example.py::test_a", "tests/test_benchmarks_suite.py::test_b",
           "tests/test_cluster.py::test_c", "tests/test_api_example.py::test_d", "tests/test_cluster.py::test_e"]
    items = [Item(i) for i in ids]
    conftest.pytest_collection_modifyitems(Config("no", node.workerinput), items)
    assert [i.nodeid for i in items] == [ids[2], ids[4], ids[1], ids[0], ids[3]]
    unsorted = [Item(i) for i in ids]   # the fast tier (--dist load) keeps the collection order
    conftest.pytest_collection_modifyitems(Config("no", {"volcomp_dist": "load"}), unsorted)
    assert [i.nodeid for i in unsorted] == ids
