"""The benchmark suite (benchmarks/run.py): BENCHMARKS.md is what the generator writes from the committed JSON and
fits on 400 lines; every registered benchmark has its module and its committed result; the whole suite runs
``--quick`` (slow tier: the CI smoke run of every benchmark)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import run as suite
from benchmarks.suite import REGISTRY

ROOT = Path(__file__).resolve().parents[1]


def test_page_is_generated_from_the_committed_results():
    text = suite.render(suite.RESULTS)
    assert (ROOT / "BENCHMARKS.md").read_text(encoding="utf-8") == text, \
        "BENCHMARKS.md differs from `python -m benchmarks.run --write-md`'s output: regenerate it"
    assert text.count("\n") <= suite.MAX_PAGE_LINES


def test_every_registered_benchmark_has_a_module_and_a_committed_result():
    for name in REGISTRY:
        assert (ROOT / "benchmarks" / "suite" / f"{name}.py").is_file(), name
        rec = json.loads((suite.RESULTS / f"{name}.json").read_text(encoding="utf-8"))
        assert rec["name"] == name and rec["command"].startswith(f"python -m benchmarks.run {name}")
        suite.check_result(name, rec)
    assert sorted(p.stem for p in suite.RESULTS.glob("*.json")) == sorted(REGISTRY)


def test_a_figure_without_its_residual_kind_is_refused():
    with pytest.raises(ValueError, match="benchmarks/suite/x.py: figure 0"):
        suite.check_result("x", {"figures": [{"what": "a", "value": 1.0, "unit": "μm", "residual": "maybe",
                                              "anchor": "", "anchor_value": None}]})


def test_the_page_refuses_more_than_its_line_limit(tmp_path, monkeypatch):
    rec = json.loads((suite.RESULTS / f"{REGISTRY[0]}.json").read_text(encoding="utf-8"))
    rec["notes"] = ["a note"] * (suite.MAX_PAGE_LINES + 1)
    (tmp_path / "big.json").write_text(json.dumps(rec), encoding="utf-8")
    page = tmp_path / "PAGE.md"
    assert suite.write_md(tmp_path, page) == 1 and not page.exists()


@pytest.mark.slow  # the whole suite, quick: 47 to 190 CPU s by the machine (README "Tests and benchmarks")
def test_the_whole_suite_runs_quick(tmp_path):
    """Every benchmark runs --quick and writes a valid record. Its CPU time is not asserted (a timed test on a noisy
    machine: the same tree measured 47 and 188 CPU s on two machines); each record's ``cpu_s`` says it, and CI's
    wall-time limit bounds the tier."""
    import os
    r = subprocess.run([sys.executable, "-m", "benchmarks.run", "--quick", "--out", str(tmp_path)], cwd=ROOT,
                       capture_output=True, text=True,
                       env={**os.environ, "OMP_NUM_THREADS": "1",     # a learned stage's run goes to tmp_path's store
                            "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}"})
    assert r.returncode == 0, r.stderr[-2000:]
    for name in REGISTRY:
        rec = json.loads((tmp_path / f"{name}.json").read_text(encoding="utf-8"))
        assert rec["quick"] is True
        suite.check_result(name, rec)
    _statistical_quick_record(json.loads((tmp_path / "statistical.json").read_text(encoding="utf-8")))
    assert json.loads((tmp_path / "demo.json").read_text(encoding="utf-8"))["figures"][0]["value"] is None


def _statistical_quick_record(rec):
    """The statistical sweeps' quick run: every sweep ran once on its first seeds, with the sweep's own code (its
    per-repetition invariants asserted inside), at its quick size; each rate is a share over at least one unit
    (nan would fail) and is recorded, not judged."""
    from benchmarks.suite import statistical
    assert {f["sweep"] for f in rec["figures"]} == set(statistical.SWEEPS)
    for f in rec["figures"]:
        assert f["size"] == statistical.SWEEPS[f["sweep"]][2], f["sweep"]
        assert 0.0 <= f["value"] <= 1.0, f["sweep"]
    assert any("not judged" in n for n in rec["notes"])
