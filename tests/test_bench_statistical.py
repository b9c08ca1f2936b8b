"""The statistical sweeps of benchmarks/bench_statistical.py (band coverage and decline rates over many seeds,
formerly slow-tier tests) run here on their first seeds: the same code as the full sweep, its per-repetition
invariants asserted (an identifiable set matching the truth's, a reference fit reproducing the truth, a declined
fit predicting exactly zero). The rates are judged against their ranges by the full run
(``python benchmarks/bench_statistical.py``, figures in docs/decisions/020-benchmark-notebook.md), not on a few seeds."""
import importlib.util
import json
from pathlib import Path

import pytest

SPEC = importlib.util.spec_from_file_location(
    "bench_statistical", Path(__file__).resolve().parents[1] / "benchmarks" / "bench_statistical.py")
bench = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(bench)


@pytest.mark.slow
def test_quick_run_of_every_sweep_writes_its_rates(tmp_path, capsys):
    out = tmp_path / "stat.json"
    assert bench.main(["--quick", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["quick"] is True and set(doc["sweeps"]) == set(bench.SWEEPS)
    for name, r in doc["sweeps"].items():
        assert r["size"] == bench.SWEEPS[name][2], name
        assert 0.0 <= r["rate"] <= 1.0, name        # a rate over at least one unit (nan would fail here)
        assert r["cpu_s"] >= 0
    assert "not judged (quick)" in out.with_suffix(".md").read_text()

