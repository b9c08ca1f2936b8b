"""A model whose diagnosis verdict failed is never used silently: ``compensate``, ``predict`` and
``export`` refuse it (exit 2, one line naming the file and the verdict's reasons) unless
``--allow failed-verdict``, and then the override is recorded in the output
(compensation/fields.py check_verdict)."""
from __future__ import annotations

import contextlib
import io
import json

import pytest

from compensation.app.cli import MAX_ERROR_CHARS, main
from compensation.fields import FAILED_VERDICT, check_verdict
from errormap.io import InputError, read_table, sidecar_path

REASON = "the kept model (51.7 um) loses to the plain baseline baseline_ols_linear (33.0 um)"
"""A failed verdict's reason as volcomp diagnose writes it (the swapped-headers case of the probe)."""


def run_cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def refused(rc, err, *needles):
    lines = [ln for ln in err.splitlines() if "error" in ln.lower()]
    assert rc == 2 and "Traceback" not in err and len(lines) == 1, (rc, err)
    assert len(lines[0]) <= MAX_ERROR_CHARS + 40
    for n in needles:
        assert n in lines[0], (n, lines[0])


def _verdict(status):
    return {"status": status, "reasons": [REASON] if status == "failed" else []}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """A diagnose folder of the grinder: updated_elements.json with a failed diagnosis.json beside it."""
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    d = tmp_path_factory.mktemp("diag")
    el = make_chain_truth(load_machine("grinder"), 3).elements.save(d / "updated_elements.json")
    (d / "diagnosis.json").write_text(json.dumps({"verdict": _verdict("failed")}))
    (d / "pts.csv").write_text("x_mm,z_mm,a_deg\n10,20,30\n11,21,31\n12,22,32\n")
    return d, el


@pytest.fixture(scope="module")
def chain_model(tmp_path_factory):
    """A mill's diagnosed model.json that carries its own failed verdict (no diagnosis.json beside)."""
    from errormap.diagnosis.loop_model import save_chain_model
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    mill = load_machine("mill-xyz")
    d = tmp_path_factory.mktemp("chain")
    el = make_chain_truth(mill, 3, family="independent").elements.save(d / "updated_elements.json")
    model = save_chain_model(d / "model.json", mill, el, [], "elements", {"verdict": _verdict("failed")})
    (d / "pts.csv").write_text("x_mm,y_mm,z_mm\n10,20,-30\n11,21,-31\n")
    return d, model


def test_predict_refuses_a_failed_verdict_naming_file_and_reasons(diagnosed, tmp_path):
    d, el = diagnosed
    rc, _, err = run_cli(["predict", "--model", el, d / "pts.csv", "--out", tmp_path / "p.csv"])
    refused(rc, err, str(d / "diagnosis.json"), "verdict", "failed", REASON, f"--allow {FAILED_VERDICT}")
    assert not (tmp_path / "p.csv").exists()


def test_predict_with_the_override_records_it_in_the_header(diagnosed, tmp_path):
    d, el = diagnosed
    rc, _, err = run_cli(["predict", "--model", el, d / "pts.csv", "--out", tmp_path / "p.csv",
                          "--allow", FAILED_VERDICT])
    assert rc == 0, err
    assert "warning:" in err and REASON in err
    head = json.loads(sidecar_path(tmp_path / "p.csv").read_text())["lines"]   # the provenance sidecar
    assert any(ln.startswith(f"allowed: {FAILED_VERDICT}") and REASON in ln for ln in head), head


def test_compensate_refuses_then_records_the_override_in_the_summary(diagnosed, tmp_path):
    d, el = diagnosed
    argv = ["compensate", d / "pts.csv", "--model", el, "--method", "exact", "--out", tmp_path / "c"]
    rc, _, err = run_cli(argv)
    refused(rc, err, str(d / "diagnosis.json"), REASON)
    assert not (tmp_path / "c").exists()   # nothing written, no folder left
    rc, _, err = run_cli(argv + ["--allow", FAILED_VERDICT])
    assert rc == 0, err
    summary = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())
    assert summary["model_verdict"]["status"] == "failed"
    assert summary["model_verdict"]["overridden_by"] == f"--allow {FAILED_VERDICT}"
    assert summary["allow"] == [FAILED_VERDICT]
    assert "MODEL DIAGNOSIS VERDICT FAILED" in " ".join(read_table(tmp_path / "c" / "pts.csv").comments)  # its sidecar says so


def test_a_bare_allow_does_not_override_the_verdict(diagnosed, tmp_path):
    d, el = diagnosed
    rc, _, err = run_cli(["compensate", d / "pts.csv", "--model", el, "--method", "exact", "--out", tmp_path / "c",
                          "--allow"])
    refused(rc, err, REASON)


def test_export_refuses_then_records_the_override_in_export_json(diagnosed, tmp_path):
    d, el = diagnosed
    argv = ["export", el, "--format", "iso-tables", "--out", tmp_path / "e"]
    rc, _, err = run_cli(argv)
    refused(rc, err, str(d / "diagnosis.json"), REASON)
    assert not (tmp_path / "e").exists()
    rc, _, err = run_cli(argv + ["--allow", FAILED_VERDICT])
    assert rc == 0, err
    info = json.loads((tmp_path / "e" / "export.json").read_text())
    assert info["model_verdict"]["overridden_by"] == f"--allow {FAILED_VERDICT}"
    assert info["model_verdict"]["reasons"] == [REASON]


def test_a_chain_model_json_with_its_own_failed_verdict_is_refused(chain_model, tmp_path):
    d, model = chain_model
    rc, _, err = run_cli(["predict", "--machine", "mill-xyz", "--model", model, d / "pts.csv",
                          "--out", tmp_path / "p.csv"])
    refused(rc, err, str(model), REASON)
    rc, _, err = run_cli(["compensate", d / "pts.csv", "--machine", "mill-xyz", "--model", model,
                          "--method", "exact", "--out", tmp_path / "c"])
    refused(rc, err, str(model), REASON)
    rc, _, err = run_cli(["predict", "--machine", "mill-xyz", "--model", model, d / "pts.csv",
                          "--out", tmp_path / "p.csv", "--allow", FAILED_VERDICT])
    assert rc == 0, err
    assert any(ln.startswith(f"allowed: {FAILED_VERDICT}") for ln in read_table(tmp_path / "p.csv").comments)
    rc, _, err = run_cli(["compensate", d / "pts.csv", "--machine", "mill-xyz", "--model", model,
                          "--method", "exact", "--out", tmp_path / "c", "--allow", FAILED_VERDICT])
    assert rc == 0, err
    assert "MODEL DIAGNOSIS VERDICT FAILED" in " ".join(read_table(tmp_path / "c" / "pts.csv").comments)
    summary = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())
    assert summary["model_verdict"]["overridden_by"] == f"--allow {FAILED_VERDICT}"


def test_a_passed_verdict_or_none_is_used_without_a_word(tmp_path, capsys):
    (tmp_path / "m.json").write_text(json.dumps({"format": "x", "verdict": _verdict("passed")}))
    assert check_verdict(tmp_path / "m.json", allowed=False)["status"] == "passed"
    (tmp_path / "n").mkdir()
    (tmp_path / "n" / "e.json").write_text(json.dumps({"format": "x"}))
    assert check_verdict(tmp_path / "n" / "e.json", allowed=False) is None
    assert capsys.readouterr().err == ""


def test_an_unreadable_diagnosis_beside_the_model_is_refused_naming_it(tmp_path):
    (tmp_path / "e.json").write_text(json.dumps({"format": "x"}))
    (tmp_path / "diagnosis.json").write_text('{"verdict": ')
    with pytest.raises(InputError, match=r"diagnosis\.json: row 1: column 13: not JSON"):
        check_verdict(tmp_path / "e.json", allowed=False)


def test_a_real_failed_diagnosis_stops_predict_and_compensate(tmp_path):
    """End to end: checks with a 20 μm setup offset on dx (20x the noise, what the plain OLS baseline
    removes and the loop does not) diagnosed with --no-learned → verdict failed, exit 1; its model.json
    given to predict and compensate is refused (exit 2), naming model.json and the baseline it loses to."""
    from errormap.io import write_csv
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    noise_um, offset_um = 1.0, 20.0
    t = make_chain_truth(load_machine("mill-xyz"), 3, family="independent")
    t.elements.save(tmp_path / "elements.json")
    ck = t.check_measurements(200, noise_um=noise_um, seed=4)
    checks = write_csv(tmp_path / "checks.csv", {**ck, "dx_um": ck["dx_um"] + offset_um},
                       header_comments=[f"noise_um: {noise_um}"])
    rc, _, err = run_cli(["diagnose", checks, "--machine", "mill-xyz", "--model", tmp_path / "elements.json",
                          "--no-learned", "--out", tmp_path / "d"])
    assert rc == 1, err
    model = tmp_path / "d" / "model.json"
    (tmp_path / "pts.csv").write_text("x_mm,y_mm,z_mm\n10,20,-30\n")
    rc, _, err = run_cli(["predict", "--machine", "mill-xyz", "--model", model, tmp_path / "pts.csv",
                          "--out", tmp_path / "p.csv"])
    refused(rc, err, str(model), "loses to the plain baseline")
    rc, _, err = run_cli(["compensate", tmp_path / "pts.csv", "--machine", "mill-xyz", "--model", model,
                          "--method", "exact", "--out", tmp_path / "c"])
    refused(rc, err, str(model), "loses to the plain baseline")
    assert not (tmp_path / "p.csv").exists() and not (tmp_path / "c").exists()


def _report_argv(d, el, out):
    return ["report", "--model", el, "--path", d / "pts.csv", "--methods", "exact", "--out", out]


def test_report_refuses_a_failed_verdict_before_any_work(diagnosed, tmp_path):
    d, el = diagnosed
    rc, _, err = run_cli(_report_argv(d, el, tmp_path / "r"))
    refused(rc, err, str(d / "diagnosis.json"), REASON, f"--allow {FAILED_VERDICT}")
    assert not (tmp_path / "r").exists()


@pytest.mark.slow   # the exact solver's first compile
def test_report_with_the_override_records_it_in_metrics_and_page(diagnosed, tmp_path):
    d, el = diagnosed
    argv = _report_argv(d, el, tmp_path / "r")
    rc, _, err = run_cli(argv + ["--allow", FAILED_VERDICT])
    assert rc == 0, err
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    found = json.dumps(metrics)
    assert '"overridden_by": "--allow failed-verdict"' in found and REASON in found
    assert "model verdict" in (tmp_path / "r" / "report.html").read_text()


@pytest.fixture(scope="module")
def drift_failed(tmp_path_factory):
    """A drift_model.json (one OLS channel on one temperature) with a failed diagnosis.json beside it, and a log."""
    import numpy as np
    from errormap.diagnosis.drift_models import ChannelFit, DriftModel, Feature
    from errormap.io import write_csv
    d = tmp_path_factory.mktemp("drift")
    model = DriftModel({"ch1": ChannelFit("ols", "", [Feature("temp_s1_c")], 1.0, np.array([2.0]))})
    model.save(d / "drift_model.json")
    (d / "diagnosis.json").write_text(json.dumps({"verdict": _verdict("failed")}))
    t = np.arange(0.0, 7200.0, 60.0)
    write_csv(d / "log.csv", {"time_s": t, "temp_s1_c": 20.0 + 2.0 * np.sin(t / 3600.0)})
    return d


def test_drift_predict_refuses_then_records_the_override_in_the_header(drift_failed, tmp_path):
    d = drift_failed
    argv = ["drift-predict", d / "drift_model.json", d / "log.csv", "--out", tmp_path / "p.csv"]
    rc, _, err = run_cli(argv)
    refused(rc, err, str(d / "diagnosis.json"), REASON, f"--allow {FAILED_VERDICT}")
    assert not (tmp_path / "p.csv").exists()
    rc, _, err = run_cli(argv + ["--allow", FAILED_VERDICT])
    assert rc == 0, err
    head = json.loads(sidecar_path(tmp_path / "p.csv").read_text())["lines"]   # the provenance sidecar
    assert any(ln.startswith(f"allowed: {FAILED_VERDICT}") and REASON in ln for ln in head), head
