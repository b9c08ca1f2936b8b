"""Every tutorial runs as written (docs/tutorials/*.md): its files are saved from the blocks titled with their
name, its `volcomp` lines run in order in one fresh folder, and every figure it shows — a block titled "output"
(what the commands of the block before it print) or "NAME (excerpt)" (lines of a written file) — is found in what
the run printed or wrote, each number within REL_TOL · |number| + ABS_TOL.

The runs are seeded, so the figures repeat exactly on one machine; the tolerance covers what differs between
machines (BLAS, CPU kernels: the last printed digit of a fitted figure), not a change of result."""
from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = sorted(p for p in (ROOT / "docs" / "tutorials").glob("*.md") if p.name != "index.md")
REL_TOL = 0.02
"""Relative tolerance on each figure a tutorial shows (printed to 3-4 significant digits)."""
ABS_TOL = 0.01
"""Absolute tolerance, in the printed unit (μm, mm): a round-off-level figure such as a model residual of 1e-10 μm."""
NUMBER = re.compile(r"…|[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
"""A number, or "…" in a shown line: a value that depends on the computer (seconds), matched but not compared."""
BLOCK = re.compile(r"^```(\w+)(?:[ \t]+title=\"([^\"]+)\")?[ \t]*\n(.*?)^```[ \t]*$", re.M | re.S)


def blocks(page: Path) -> list:
    """(language, title or None, text) of every fenced block, in page order."""
    return [(m.group(1), m.group(2), m.group(3)) for m in BLOCK.finditer(page.read_text(encoding="utf-8"))]


def _skeleton(line: str) -> str:
    return NUMBER.sub("#", " ".join(line.split()))


def _numbers(line: str) -> list:
    return [None if x == "…" else float(x) for x in NUMBER.findall(line)]


def check_figures(expected: str, actual: str, where: str) -> None:
    """Each non-empty expected line has a line of the same words in ``actual`` whose numbers all agree."""
    lines = actual.splitlines()
    for want in filter(str.strip, expected.splitlines()):
        same = [got for got in lines if _skeleton(got) == _skeleton(want)]
        assert same, f"{where}: no line like {want!r}"
        ok = any(all(w is None or abs(g - w) <= REL_TOL * abs(w) + ABS_TOL
                     for g, w in zip(_numbers(got), _numbers(want)))
                 for got in same)
        assert ok, f"{where}: {want!r} shown, the run gave {same}"


def run_volcomp(line: str) -> tuple:
    from compensation.app.cli import main
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        status = main(shlex.split(line, comments=True)[1:])
    return status, out.getvalue()


@pytest.mark.slow  # each tutorial is a whole workflow: 10-30 CPU s
@pytest.mark.parametrize("page", TUTORIALS, ids=lambda p: p.stem)
def test_tutorial_runs_as_written_and_shows_its_figures(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    printed, ran = "", 0
    for lang, title, text in blocks(page):
        if title and title != "output" and not title.endswith("(excerpt)"):
            (tmp_path / title).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / title).write_text(text, encoding="utf-8")
        elif title == "output":
            check_figures(text, printed, f"{page.name}, output")
        elif title:
            name = title.removesuffix("(excerpt)").strip()
            check_figures(text, (tmp_path / name).read_text(encoding="utf-8"), f"{page.name}, {name}")
        elif lang == "bash":
            printed = ""
            for line in text.splitlines():
                if line.startswith("volcomp "):
                    status, out = run_volcomp(line)
                    assert status == 0, f"{page.name}: {line}: exit {status}\n{out[-2000:]}"
                    printed += out
                    ran += 1
    assert ran, f"{page.name} runs no volcomp command"


def test_every_tutorial_shows_figures_that_the_test_checks():
    """A tutorial without a checked figure would pass by running alone: each has an output block."""
    assert TUTORIALS
    for page in TUTORIALS:
        titles = [t for _, t, _ in blocks(page)]
        assert "output" in titles, page.name
