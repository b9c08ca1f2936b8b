"""The machine-kind registry (errormap/machine.py machine_kinds), the built-in machines (the files
in errormap/machines/) and `volcomp machines`, checked against the TOML files read here directly."""
import json
import tomllib
from pathlib import Path

import pytest

from compensation.app.cli import main
from errormap.machine import (MachineFileError, builtin_machines, load_machine, machine_axes, machine_kind,
                              machine_kinds)

MACHINES_DIR = Path(__file__).resolve().parents[1] / "errormap" / "machines"
BUILTIN_KINDS = {"grinder", "hexapod", "tripod", "serial", "machine-tool"}
CANONICAL_AXIS_ORDER = "XYZUVWABC"  # docs/how-to/machine-file.md: axis columns follow the words in this order


def _file_axes(doc: dict) -> list:
    """(name, unit, lo, hi) of each axis as the TOML states it, per kind — a reading independent of
    the parsers (strokes, leg limits, joint limits)."""
    kind = doc["machine"]["kind"]
    if kind == "grinder":
        return [(k.split("_")[0].upper(), k.split("_")[1], *v) for k, v in doc["strokes"].items()]
    if kind in ("hexapod", "tripod"):
        legs = doc["legs"]
        n = 6 if kind == "hexapod" else 3
        return [(f"leg{i + 1}", "mm", legs["min_mm"], legs["max_mm"]) for i in range(n)]
    if kind == "machine-tool":
        joints = [d for d in doc.get("work", []) + doc.get("tool", []) if "joint" in d]
        joints.sort(key=lambda d: CANONICAL_AXIS_ORDER.index(d["axis"]))
        return [(d["axis"], "mm" if d["joint"] == "linear" else "deg", *d["stroke"]) for d in joints]
    links = doc.get("link") or doc.get("et")
    return [(d["joint"], "mm" if d.get("type") == "prismatic" else "deg", *d["limits"])
            for d in links if "joint" in d]


def test_the_registry_has_the_built_in_kinds():
    kinds = machine_kinds()
    assert BUILTIN_KINDS <= set(kinds)
    for k, entry in kinds.items():
        assert entry.kind == k and callable(entry.parse) and callable(entry.axes)
        assert (MACHINES_DIR.parents[1] / entry.schema_doc).is_file()
    with pytest.raises(ValueError, match="unknown machine kind 'gantry'"):
        machine_kind("gantry")


def test_built_ins_are_the_files():
    assert builtin_machines() == {p.stem: p for p in sorted(MACHINES_DIR.glob("*.toml"))}
    assert {"grinder", "hexapod", "tripod", "ur5", "ur10", "wam"} <= set(builtin_machines())


def test_a_path_wins_over_a_built_in_name(tmp_path, monkeypatch):
    """A name is looked up among the built-ins only when no such path exists."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ur5").write_bytes((MACHINES_DIR / "grinder.toml").read_bytes())
    assert load_machine("ur5").name == "micro-drill flute grinder"
    assert load_machine("wam").kind == "serial"
    with pytest.raises(MachineFileError, match="no such machine file"):
        load_machine("no-such-machine")


def test_machines_lists_every_built_in_from_its_file(capsys):
    assert main(["machines", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == list(builtin_machines())
    for r in rows:
        doc = tomllib.loads((MACHINES_DIR / r["file"]).read_text(encoding="utf-8"))
        assert r["kind"] == doc["machine"]["kind"] and r["kind"] in machine_kinds()
        assert r["title"] == doc["machine"].get("name", r["name"])
        listed = [(a["name"], a["unit"], a["lo"], a["hi"]) for a in r["axes"]]
        assert listed == _file_axes(doc), r["name"]
        assert all(a["type"] == ("rotary" if a["unit"] == "deg" else "linear") for a in r["axes"])
    assert main(["machines"]) == 0
    text = capsys.readouterr().out.splitlines()
    assert len(text) == 1 + len(rows)
    for r, line in zip(rows, text[1:]):
        assert line.split()[:2] == [r["name"], r["kind"]]
        assert all(f"{a['name']} [{a['lo']:g}, {a['hi']:g}] {a['unit']}" in line for a in r["axes"])


def test_machine_axes_of_a_loaded_grinder():
    m = load_machine(None)
    assert [(a.name, a.unit, a.lo, a.hi) for a in machine_axes(m)] == [
        ("X", "mm", *m.strokes["x_mm"]), ("Z", "mm", *m.strokes["z_mm"]), ("A", "deg", *m.strokes["a_deg"])]
