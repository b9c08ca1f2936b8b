"""The machine-family registry (``compensation/app/families.py``) is the one place in the application that knows
machine kinds: no command, workflow or report tests a machine's kind outside it (read from the source with
``ast``), every parser's kind has one family, every command's runners cover the registry's targets, and the
gaps the registry refuses are the gaps ``docs/reference/features.md`` states (the same word in the same cell)."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from compensation.app.families import FAMILIES, GAP_WORDS, PARALLEL, family_of
from errormap.machine import load_machine, machine_kinds
from tests.test_features_table import FAMILIES as COLUMNS
from tests.test_features_table import _parser_names, _rows, _subparsers

ROOT = Path(__file__).resolve().parents[1]
APP = ROOT / "compensation" / "app"
REGISTRY = "compensation/app/families.py"
NOT_YET_CONVERTED = frozenset({"compensation/app/workflows/measurement.py"})
"""Modules being rewritten elsewhere that still test kinds; the count outside them is 0, and goes to 0 in them
as they move to the registry (delete each entry then)."""
MACHINE_NAMES = {"machine", "chain", "m", "mach", "robot", "pkm"}
"""Variable names that hold a loaded machine: their ``.kind`` compared with anything is a kind test."""


def _is_kind(node) -> bool:
    """``kind``, ``x.kind``, ``x["kind"]`` / ``x["machine_kind"]``, ``x.get("kind")``, ``getattr(x, "kind")``."""
    keys = ("kind", "machine_kind")
    if isinstance(node, ast.Name):
        return node.id == "kind"
    if isinstance(node, ast.Attribute):
        return node.attr == "kind"
    if isinstance(node, ast.Subscript):
        return isinstance(node.slice, ast.Constant) and node.slice.value in keys
    if isinstance(node, ast.Call):
        fn = _name(node.func)
        key = node.args[0] if fn == "get" and node.args else node.args[1] if fn == "getattr" and len(node.args) > 1 \
            else None
        return isinstance(key, ast.Constant) and key.value in keys
    return False


def _name(func) -> str:
    return func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""


def _strings(node) -> set:
    return {n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)}


def kind_tests(text: str) -> list:
    """``(line, source)`` of every test of a machine's kind in ``text``: a comparison (``==``, ``!=``, ``in``,
    ``not in``) of a kind (:func:`_is_kind`) with a machine kind's name, or of a machine's ``.kind``
    (:data:`MACHINE_NAMES`) with anything but another kind (a recorded kind checked against the machine's is no
    branch on kinds); a call of ``check_machine_kind``; ``expect_kind=`` a kind's name."""
    kinds = set(machine_kinds())
    found = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Compare) and any(isinstance(o, (ast.Eq, ast.NotEq, ast.In, ast.NotIn))
                                                 for o in node.ops):
            operands = [node.left, *node.comparators]
            for k in (o for o in operands if _is_kind(o)):
                others = [o for o in operands if o is not k]
                on_machine = (isinstance(k, ast.Attribute) and isinstance(k.value, ast.Name)
                              and k.value.id in MACHINE_NAMES and not any(_is_kind(o) for o in others))
                if on_machine or any(_strings(o) & kinds for o in others):
                    found.append((node.lineno, ast.unparse(node)))
                    break
        elif isinstance(node, ast.Call):
            if _name(node.func) == "check_machine_kind" or any(
                    kw.arg == "expect_kind" and _strings(kw.value) & kinds for kw in node.keywords):
                found.append((node.lineno, ast.unparse(node)))
    return found


def test_the_counter_finds_every_form_and_nothing_else():
    """The rule below is only as good as this: each form of a kind test is found, and the other things called
    ``kind`` (a tool path's format, a model's kind, an axis type, a loop over kinds) are not."""
    text = ("if machine.kind == 'serial': pass\nif m.kind not in BY_KIND: pass\nif kind in ('hexapod', 'tripod'): pass\n"
            "if chain.kind != x: pass\nif doc.get('kind') != 'serial': pass\nif r['machine_kind'] == 'tripod': pass\n"
            "load_machine(p, expect_kind='grinder')\ncheck_machine_kind(p, k, 'grinder')\n"
            "if getattr(machine, 'kind', None) == 'machine-tool': pass\n"
            "if tp.kind == 'gcode': pass\nif src.kind != 'elements': pass\nfor kind in ('hexapod', 'tripod'): pass\n"
            "if a.kind == 'rotary': pass\nload_machine(p, expect_kind=None)\nif doc.get('kind') != chain.kind: pass\n")
    assert [line for line, _ in kind_tests(text)] == list(range(1, 10))


def test_no_kind_test_outside_the_registry():
    files = sorted(APP.rglob("*.py"))
    assert len(files) > 20
    found = {}
    for f in files:
        rel = f.relative_to(ROOT).as_posix()
        if rel == REGISTRY or rel in NOT_YET_CONVERTED:
            continue
        hits = kind_tests(f.read_text(encoding="utf-8"))
        if hits:
            found[rel] = hits
    assert found == {}, "ask family_of(machine) (compensation/app/families.py) instead: " + "; ".join(
        f"{rel}:{line}: {src}" for rel, hits in found.items() for line, src in hits)


def test_every_kind_has_one_family():
    held = [k for f in FAMILIES for k in f.kinds]
    read_as_chain = {"grinder"}   # a kind = "grinder" file is read as its machine-tool chain (errormap/grinder_file.py)
    assert sorted(held) == sorted(set(held)) == sorted(set(machine_kinds()) - read_as_chain)
    assert [f.column for f in FAMILIES] == list(COLUMNS)


def test_every_family_runs_a_command_or_names_its_gap():
    commands = {c for f in FAMILIES for c in (*f.targets, *f.gaps)}
    for f in FAMILIES:
        for c in commands:
            conditional = c in f.gaps and f.gaps[c].unless   # a gap of the machines without that fact
            assert (c in f.targets) != (c in f.gaps) or conditional, f"{f.column} / {c}: a target or a gap, exactly one"
        for c, g in f.gaps.items():
            assert g.word in GAP_WORDS and len(g.reason) >= 8, (f.column, c, g)


@pytest.mark.parametrize("module, table", [
    ("simulate", "RUNNERS"), ("predict", "RUNNERS"), ("sweeps", "RUNNERS"), ("calibrate", "RUNNERS"),
    ("featurepoints", "FIELDS")])
def test_each_command_runs_every_target_the_registry_names(module, table):
    import importlib
    runners = getattr(importlib.import_module(f"compensation.app.commands.{module}"), table)
    assert set(runners) == {f.targets[module] for f in FAMILIES if module in f.targets}


def _cell(command: str, option: str, column: str) -> str:
    k = 2 + COLUMNS.index(column)
    cells = [c for c in _rows() if c[0].strip("`") == command and f"`{option}`" in c[1]]
    assert len(cells) == 1, f"docs/reference/features.md: {command} {option}: {len(cells)} rows"
    return cells[0][k]


MAIN_OPTION = {"train": "featurepoints", "report run": "run", "fleet": "fleet"}
"""The option whose row states a command's gap (its first row: ``--machine`` unless named here)."""


def test_every_refusal_of_the_registry_is_a_gap_the_table_states():
    """The same word in the same cell: an option a family refuses, and a command it does not run."""
    subs = _subparsers()
    for f in FAMILIES:
        for r in f.refusals:
            for o in r.options:
                assert o.flag in _parser_names(subs[r.command]), f"{r.command} has no {o.flag}"
                cell = _cell(r.command, o.flag, f.column)
                assert f"{o.word}:" in cell, f"{f.column} / {r.command} {o.flag}: refused as {o.word!r}; table: {cell!r}"
        for command, gap in f.gaps.items():
            cmd = command.split()[0]
            cell = _cell(cmd, MAIN_OPTION.get(command, "--machine"), f.column)
            said = f"{gap.word}:" in cell if gap.unless else cell.startswith(f"{gap.word}:")
            assert said, f"{f.column} / {command}: {gap.word!r} here; table: {cell!r}"


CONVERTED = ("simulate", "sweeps", "featurepoints", "train", "predict", "calibrate", "register", "report",
             "interpolate", "fleet", "demo", "identify", "export", "compensate", "diagnose")


def test_every_not_yet_or_physics_cell_of_a_converted_command_is_refused():
    """A cell that opens with "not yet:" or "physics:" is an option the family refuses (with that word), or a
    command it does not run at all."""
    checked = 0
    for cells in _rows():
        command = cells[0].strip("`")
        if command not in CONVERTED:
            continue
        options = re.findall(r"`([a-z][a-z_-]*|--[a-z0-9-]+)`", cells[1])
        for f in FAMILIES:
            cell = cells[2 + COLUMNS.index(f.column)]
            word = next((w for w in ("not yet", "physics") if cell.startswith(f"{w}:")), None)
            if word is None:
                continue
            for opt in options:
                said, _ = f.support(command, opt)
                assert said != "yes", f"{f.column} / {command} {opt}: the table says {word!r}, the registry yes"
                refused_by_option = any(o.flag == opt for r in f.refusals if r.command == command for o in r.options)
                assert said == word or not refused_by_option, (f.column, command, opt, said, word)
                checked += 1
    assert checked > 30


def test_a_machine_gets_its_family_and_facts():
    hexapod, tripod = family_of(load_machine("hexapod")), family_of(load_machine("tripod"))
    assert hexapod.column == tripod.column == PARALLEL.column
    assert hexapod.facts.platform_orientation and not tripod.facts.platform_orientation
    assert tripod.facts.sensitivity_study and not hexapod.facts.sensitivity_study
    grinder, chain = family_of(load_machine(None)), family_of(load_machine("mill-xyz"))
    assert grinder.column == chain.column == "Machine tool" and grinder.kind == chain.kind == "machine-tool"
    from tests.chain_fixtures import OLD_GRINDER_FILE
    old = family_of(load_machine(str(OLD_GRINDER_FILE)))   # a kind = "grinder" file: the grinder's family and facts
    assert (old.column, old.kind, old.facts) == (grinder.column, grinder.kind, grinder.facts) == (old.column, "machine-tool", old.facts)
    five, lathe = family_of(load_machine("five-axis-ac")), family_of(load_machine("lathe-xzc"))
    assert grinder.facts.flute_axes and not any(f.facts.flute_axes for f in (chain, five, lathe))
    assert grinder.runs("demo") and not chain.runs("demo") and grinder.runs("report run") and chain.runs("report run")
    assert grinder.facts.fixed_tool_axis and lathe.facts.fixed_tool_axis
    assert not chain.facts.fixed_tool_axis and not five.facts.fixed_tool_axis   # no rotary axis / two of five
    assert family_of(load_machine("ur5")).facts.poses


MAX_MESSAGE_CHARS = 300
REFUSED = [   # (argv, words the one line names): the registry's refusals on the command line
    (["simulate", "--machine", "hexapod", "--effect", "sag"], ["--effect:", "parallel machine"]),
    (["simulate", "--machine", "ur5", "--family", "independent"], ["--family independent:", "serial arm"]),
    (["simulate", "--machine", "mill-xyz", "--poses", "10"], ["--poses:", "--checks"]),
    (["sweeps", "--machine", "ur5", "--seed", "1"], ["volcomp sweeps", "serial arm", "other path:", "calibrate"]),
    (["featurepoints", "--machine", "tripod", "--elements", "E.json"], ["parallel machine", "not yet:"]),
    (["predict", "p.csv", "--machine", "tripod", "--model", "c.json", "--band", "95", "--units", "as-written"],
     ["--band, --units:", "parallel machine"]),
    (["calibrate", "p.csv", "--machine", "mill-xyz"], ["volcomp calibrate", "other path:", "identify"]),
    (["register", "p.csv", "--machine", "hexapod", "--model", "c.json"], ["other path:", "instrument frame"]),
    (["interpolate", "sphere", "--machine", "hexapod", "--sensitivity-plot", "k.png"], ["needs a tripod", "hexapod"]),
    (["report", "--machine", "mill-xyz", "--model", "E.json", "--flute"], ["--flute:", "flute needs", "--path"]),
    (["report", "--machine", "ur5", "--model", "E.json", "--path", "p.csv"], ["volcomp report", "not yet:"]),
    (["export", "E.json", "--format", "grid", "--machine", "hexapod"],
     ["volcomp export", "parallel machine", "not yet:", "interpolate"]),
    (["identify", "s.csv", "--machine", "ur5"], ["volcomp identify", "serial arm", "other path:", "calibrate"]),
    (["compensate", "p.nc", "--machine", "hexapod", "--model", "c.json"],
     ["volcomp compensate", "parallel machine", "other path:", "interpolate"]),
    (["compensate", "p.csv", "--machine", "ur5", "--model", "c.json", "--rapids", "compensate"],
     ["--rapids", "joint angles"]),
    (["compensate", "p.csv", "--machine", "ur5", "--model", "c.json", "--workers", "2", "--chunk-points", "7"],
     ["--workers, --chunk-points:", "one process"]),
    (["compensate", "p.csv", "--machine", "ur5", "--model", "c.json", "--temp-c", "20"], ["--temp-c:", "joints"]),
    (["compensate", "p.csv", "--machine", "ur5", "--model", "c.json", "--compensate-orientation"],
     ["--compensate-orientation:", "not yet"]),
    (["compensate", "p.nc", "--model", "E.json", "--method", "exact", "--compensate-orientation"],
     ["--compensate-orientation:", "grinder", "tool axis"]),
    (["compensate", "p.nc", "--machine", "lathe-xzc", "--model", "E.json", "--compensate-orientation"],
     ["--compensate-orientation:", "lathe-xzc", "tool axis"]),   # three axes, one rotary: the grinder's physics
    (["demo", "--machine", "five-axis-ac"], ["volcomp demo", "machine tool", "not yet:", "flute"]),
]


@pytest.mark.parametrize("argv, words", REFUSED, ids=lambda a: " ".join(a[:3]) if isinstance(a, list) else "")
def test_refusals_are_one_line_naming_the_option_and_nothing_is_written(argv, words, tmp_path, capsys):
    from compensation.app.cli import main
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out)]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if ln]
    # the budget is for volcomp's words: a file's absolute path (the checkout's or the install's) counts as 'FILE'
    words_only = re.sub(r"/\S+\.(?:toml|json|csv)", "FILE", err[0]) if err else ""
    assert len(err) == 1 and len(words_only) < MAX_MESSAGE_CHARS, err
    assert all(w in err[0] for w in words), err[0]
    assert not out.exists()


@pytest.mark.parametrize("family, argv, words", [
    ("arm", ["export", "M", "--format", "grid"], ["serial arm", "not yet:", "controller format"]),
    ("parallel", ["export", "M", "--format", "linuxcnc"], ["parallel machine", "not yet:", "interpolate"]),
    ("arm", ["report", "--model", "M", "--flute"], ["serial arm", "not yet:", "compensate --machine"]),
    ("parallel", ["report", "--model", "M", "--flute"], ["parallel machine", "not yet:", "leg-command"]),
])
def test_an_arm_or_parallel_model_to_export_or_report_is_refused_by_its_family(family, argv, words, tmp_path,
                                                                               capsys):
    """Without --machine the model file tells the family: its gap in one line, not a machine mismatch."""
    from compensation.app.cli import main
    model = tmp_path / "model.json"
    model.write_text('{"format": "volcomp-model/1", "family": "%s"}' % family)
    out = tmp_path / "out"
    assert main([str(model) if a == "M" else a for a in argv] + ["--out", str(out)]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if ln]
    assert len(err) == 1 and str(model) in err[0] and all(w in err[0] for w in words), err
    assert not out.exists()
