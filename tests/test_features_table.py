"""``docs/reference/features.md``, the table feature × machine family, checked against the command line: every option
of every command is in one of its command's rows, every option a row names exists, and every cell says
yes, or names its gap's kind (physics, other path, not yet) with a reason."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from compensation.app.cli import build_parser

DOC = Path(__file__).resolve().parents[1] / "docs" / "reference" / "features.md"
FAMILIES = ("Machine tool", "Serial arm", "Parallel (hexapod, tripod)")
WORDS = ("yes", "physics:", "other path:", "not yet:")
MIN_REASON_CHARS = 8
"""A gap's reason after its word: at least a few words ("as above" points at the row before)."""


def _subparsers() -> dict:
    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _parser_names(sp) -> set:
    names = {a.dest for a in sp._actions if not a.option_strings and a.dest != "help"}
    names |= {o for a in sp._actions for o in a.option_strings if o.startswith("--") and o != "--help"}
    return names


def _rows() -> list:
    lines = DOC.read_text(encoding="utf-8").splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("| Command |"))
    cols = [c.strip() for c in lines[head].strip("|").split("|")]
    assert cols == ["Command", "Options", *FAMILIES]
    rows = []
    for ln in lines[head + 2:]:
        if not ln.startswith("|"):
            break
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        assert len(cells) == len(cols), ln
        rows.append(cells)
    return rows


def test_every_option_of_every_command_is_in_the_table_and_nothing_else():
    subs = _subparsers()
    named: dict = {}
    for cells in _rows():
        cmd = cells[0].strip("`")
        assert cmd in subs, f"docs/reference/features.md names a command {cmd!r} that volcomp does not have"
        opts = set(re.findall(r"`([a-z][a-z_-]*|--[a-z0-9-]+)`", cells[1]))
        assert opts, f"{cmd}: a row without options"
        unknown = opts - _parser_names(subs[cmd])
        assert not unknown, f"{cmd}: docs/reference/features.md names {sorted(unknown)}, which the parser does not have"
        named.setdefault(cmd, set()).update(opts)
    for cmd, sp in subs.items():
        missing = _parser_names(sp) - named.get(cmd, set())
        assert not missing, f"{cmd}: {sorted(missing)} missing from docs/reference/features.md"


@pytest.mark.parametrize("family", FAMILIES)
def test_every_cell_says_yes_or_names_its_gap_with_a_reason(family):
    k = 2 + FAMILIES.index(family)
    for cells in _rows():
        cell = cells[k]
        word = next((w for w in WORDS if cell.startswith(w)), None)
        assert word is not None, f"{cells[0]} {cells[1][:40]} / {family}: {cell!r} starts with none of {WORDS}"
        if word != "yes":
            assert len(cell[len(word):].strip()) >= MIN_REASON_CHARS, \
                f"{cells[0]} / {family}: a gap without its reason: {cell!r}"


def test_the_docs_index_links_the_table():
    readme = (DOC.parents[2] / "README.md").read_text(encoding="utf-8")
    assert "`docs/reference/features.md`" in readme


REFUSED = [   # gaps of the table (not yet / other path) on the command line, and the word the refusal names
    (["simulate", "--machine", "ur5", "--family", "independent"], "--family"),
    (["simulate", "--machine", "mill-xyz", "--poses", "10"], "--poses"),
    (["identify", "sw.csv", "--machine", "mill-xyz", "--seed", "3"], "--seed"),
    (["identify", "sw.csv", "--machine", "mill-xyz", "--bootstrap", "20", "--noise-um", "1"], "--bootstrap"),
    (["diagnose", "c.csv", "--model", "E.json", "--alpha", "0.05"], "--alpha"),
    (["diagnose", "c.csv", "--model", "E.json", "--machine", "mill-xyz", "--alpha", "0.05"], "--alpha"),
    (["diagnose", "--drift", "log.csv", "--machine", "mill-xyz"], "--machine"),
]
MAX_MESSAGE_CHARS = 300


@pytest.mark.parametrize("argv, word", REFUSED)
def test_gaps_the_table_names_are_refused_in_one_line(argv, word, tmp_path, capsys):
    """A 'not yet' or 'other path' cell is an option the command refuses (exit 2, one line naming it), never one
    it ignores; nothing is written."""
    from compensation.app.cli import main
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out)]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if ln]
    assert len(err) == 1 and word in err[0] and len(err[0]) < MAX_MESSAGE_CHARS
    assert not out.exists()
