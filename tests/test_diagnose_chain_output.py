"""What ``volcomp diagnose --machine CHAIN`` writes and prints (issue 26): its own report.html, as the
grinder's diagnose does, the same page ``volcomp report RUN`` builds; the terms the element update absorbs
printed only when an update ran and there are any, and kept in diagnosis.json either way."""
from __future__ import annotations

import json

import pytest

from compensation.app.workflows.measurement import diagnosis_lines

_STAGE = {"held_out": {"rms_um": 2.0}, "fitting": {"rms_um": 1.9}}
_ABSORBED = [{"kind": "interaction", "axis": "X*Z", "element": "ey_x", "note": "interaction X*Z on ey_x: represented"}]


def _summary(stages, absorbed):
    return {"stages": stages, "effects": [], "effects_absorbed": absorbed, "kept_stage": "identified",
            "kept_why": "test", "noise_floor_um": None}


def test_absorbed_terms_are_printed_only_when_an_update_absorbed_some():
    with_update = diagnosis_lines(_summary({"identified": _STAGE, "updated": _STAGE}, _ABSORBED))
    assert "absorbed by the update: interaction X*Z on ey_x: represented" in with_update
    for stages, absorbed in (({"identified": _STAGE, "updated": _STAGE}, []),          # none to print
                             ({"identified": _STAGE}, _ABSORBED),                      # no update ran
                             ({"identified": _STAGE, "updated": {"failed": "x"}}, _ABSORBED)):  # the update failed
        assert not [ln for ln in diagnosis_lines(_summary(stages, absorbed)) if "absorbed" in ln]


@pytest.mark.slow
def test_chain_diagnose_writes_its_report_page(mill_reversal):
    """simulate mill-xyz (reversal:Z, 200 checks) → diagnose: the shared run (tests/shared_runs.py) and what
    diagnose printed."""
    from compensation.app.reports.chain_diagnosis import chain_diagnosis_page
    from errormap.machine import load_machine
    run, out = mill_reversal.root / "diag", mill_reversal.out
    assert f"wrote {run / 'report.html'}" in out
    assert sorted(p.name for p in run.iterdir()) == ["diagnosis.json", "model.json", "report.html",
                                                     "updated_elements.json"]   # no temporary file left
    page = (run / "report.html").read_text(encoding="utf-8")
    assert page == chain_diagnosis_page(run, load_machine("mill-xyz"))
    doc = json.loads((run / "diagnosis.json").read_text())
    assert "effects_absorbed" in doc
    assert ("absorbed" in out) == bool(doc["effects_absorbed"] and "held_out" in doc["stages"].get("updated", {}))
