"""``volcomp demo`` end to end with tiny settings."""
import json

import pytest

from compensation.cli import main

REQUIRED = {"model_max_um", "model_mean_sq_um2", "true_max_um", "seconds", "points"}


@pytest.mark.slow
def test_demo_tiny_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo"
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    rc = main(["demo", "--out", str(out), "--tracking-uri", uri, "--turns", "1", "--points-per-turn", "24",
               "--train-s", "8", "--hidden", "8,8", "--ga-points", "3", "--seed", "1"])
    assert rc == 0
    printed = capsys.readouterr()
    assert "report.html" in printed.out and "per-point GA on 3 of 24" in printed.err
    for name in ("report.html", "metrics.json", "residuals.csv", "demo.json", "sim/truth_elements.json",
                 "sim/featurepoints.csv"):
        assert (out / name).is_file(), name
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["methods"]) == {"traditional", "ga", "batched-ga", "exact"}
    for name, v in m["methods"].items():
        assert REQUIRED <= set(v), name
    assert m["methods"]["ga"]["points"] == 3 and m["methods"]["exact"]["points"] == 24
    # the exact solver satisfies its own field far better than the traditional one-shot
    assert m["methods"]["exact"]["model_max_um"] < m["methods"]["traditional"]["model_max_um"]
    assert "MODEL" in (out / "report.html").read_text()
