"""``volcomp report RUN`` on a machine-tool chain's diagnose run: the page of the closed loop (stages, held-out
MEASURED against the noise floor, effects named, per-axis elements from the chain's slot names).
The page's rendering in Chromium is in tests/test_report_pages.py (kind ``diagnose-chain``)."""
from __future__ import annotations

import json
import re

import pytest

from compensation.app.cli import main
from compensation.app.reports.toolkit import num
from shared_runs import private_copy

@pytest.fixture
def chain_run(mill_reversal, tmp_path):
    """simulate mill-xyz with reversal:Z (200 checks: enough for its 8 μm backlash to pass the held-out gate,
    z ≈ 15 at 400, 1 μm noise) → diagnose against the truth's element set (no covariance: no update): the
    shared run (tests/shared_runs.py), copied, since ``volcomp report RUN`` writes into RUN."""
    private_copy(mill_reversal.root / "diag", tmp_path / "run" / "diag")
    return tmp_path / "run"


def _text(page):
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page))


@pytest.mark.slow
def test_the_page_shows_the_runs_stages_effects_and_elements(chain_run, capsys):
    run = chain_run / "diag"
    assert main(["report", str(run)]) == 0
    assert f"wrote html: {run / 'report.html'}" in capsys.readouterr().out
    page = (run / "report.html").read_text(encoding="utf-8")
    doc = json.loads((run / "diagnosis.json").read_text())
    text = _text(page)
    for section in ("summary", "stages", "effects", "elements"):
        assert f'<h2 id="{section}">' in page
    for stage, v in doc["stages"].items():   # every stage with its held-out MEASURED RMS as the page formats it
        if "held_out" in v:
            assert re.search(rf"{stage} {re.escape(num(v['held_out']['rms_um']))} ", text), stage
    assert f"held-out / floor {num(doc['held_out_over_floor'])}" in text
    assert [e["kind"] for e in doc["effects"]] == ["reversal"] and "reversal Z dz_z (EZZ)" in text
    alts = re.findall(r'<img[^>]* alt="([^"]+)"', page)
    assert alts == ["stages", "elements of axis X", "elements of axis Y", "elements of axis Z"]
    assert "s_xy EC0Y μrad" in text   # the constant slots by the chain's names and their ISO 230 names


@pytest.mark.slow
def test_out_writes_the_page_elsewhere_and_checks_the_machine(chain_run, tmp_path, capsys):
    run = chain_run / "diag"
    assert main(["report", str(run), "--out", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / "report.html").is_file()
    capsys.readouterr()
    assert main(["report", str(run), "--machine", "five-axis-ac", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "machine_sha256" in err[0] and not (tmp_path / "p").exists()


def test_refusals_are_one_line(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "model.json").write_text(json.dumps({"format": "volcomp-elements/1"}))
    for argv, word in ((["report", str(tmp_path / "other"), "--model", "E.json"], "--model"),
                       (["report", str(tmp_path / "empty")], "model.json: no such file"),
                       (["report", str(tmp_path / "other")], "key 'format'"),
                       (["report", str(tmp_path / "nothing")], "not a folder"),
                       (["report", "--model", "E.json"], "--path or --flute")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and word in err[0], (argv, err)
    assert not (tmp_path / "other" / "report.html").exists()


def test_report_into_run_takes_the_run_folders_lock(tmp_path, capsys):
    """``report RUN`` without --out writes RUN/report.html under RUN's lock: while another run holds it (a diagnose
    still writing there, this test's own live pid standing in for it) the page is refused in one line naming the
    holder and RUN, nothing is written and the holder's lock stays."""
    import os
    import socket
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.json").write_text(json.dumps({"format": "volcomp-chain-model/1", "machine": "mill-xyz"}))
    lock = run / ".volcomp.lock"
    lock.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "command": "diagnose",
                                "started_utc": "2026-12-02T00:00:00Z"}))
    assert main(["report", str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"RUN {run}: in use by volcomp diagnose (pid {os.getpid()}" in err[0], err
    assert sorted(p.name for p in run.iterdir()) == [".volcomp.lock", "model.json"]


@pytest.mark.slow
def test_report_into_run_releases_its_lock(chain_run, capsys):
    """The page written into RUN leaves no lock behind, and a second report into RUN then runs (replaces it)."""
    run = chain_run / "diag"
    for _ in range(2):
        assert main(["report", str(run)]) == 0
        assert (run / "report.html").is_file() and not (run / ".volcomp.lock").exists()
    capsys.readouterr()
