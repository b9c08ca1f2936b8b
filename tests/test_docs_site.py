"""The documentation site (mkdocs.yml): it builds with warnings as errors — every internal link and anchor
resolves, the command reference is generated from the parser and the API pages from the docstrings — and its
product pages speak of the product only (the history of decisions is in docs/decisions/)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HISTORY_WORDS = re.compile(
    r"\brounds?[\s-]+\d|\b(?:this|that|next|earlier|previous|table's|the table)\s+rounds?\b"
    r"|\bissues?[\s-]*#?\d+|\bissue's\b|\b(?:this|that|next|earlier|previous|last)\s+sessions?\b", re.I)
"""Words of the build history: a numbered round ("round 11", "rounds 4-6", "this round"), an issue number, "this
session" (a working session). A measurement session of an arm (its own tracker set-up: the `session` column of a pose
file) is a word of the product. "Round" as a word of the product stays: round-off, a retry round, the ROUND function of a G-code dialect."""
BUILD_PHRASES = re.compile(
    r"\bmain's\b|\bcopy of main\b|\bformer(?:ly)?\b|\bused to (?:be|grow|write|run|take|give|read|hold)\b"
    r"|\bwritten before (?:this rule|the \w+ (?:existed|was))\b|\bnot yet run on\b|\bwas no(?:t)? yet\b"
    r"|\bstable; add, don't rename\b|\bas before\b|\bolder schema\b|\bthe \w+ replaced\b", re.I)
"""Phrases of the build history on a product page: the main branch ("main's targets", "a copy of main"), what the
product was ("the former kernel", "used to grow", "files written before this rule"), a note to developers ("stable;
add, don't rename"). A product page says what the product does; how it came to do it is a decision record."""
CITED_TITLE = re.compile(r'BENCHMARKS\.md, "[^"]*"')
"""A section of BENCHMARKS.md cited by its title, verbatim (that page is not a product page)."""


def _product_pages():
    return sorted(p for p in (ROOT / "docs").rglob("*.md") if "decisions" not in p.relative_to(ROOT / "docs").parts)


def test_product_pages_name_no_build_history():
    hits = [f"{p.relative_to(ROOT)}:{i}: {m.group(0)!r}" for p in _product_pages()
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
            for pattern in (HISTORY_WORDS, BUILD_PHRASES)
            for m in pattern.finditer(CITED_TITLE.sub("", line))]
    assert not hits, hits


SHARED_PATH = re.compile(r"\.\./shared\b|/work/shared\b|\bshared/data\b")
"""The development data folder beside the repository: a docs page never points into it (a figure drawn from it is a
committed PNG; tools/docs_figures.py takes its path as an option)."""


def test_docs_never_reference_the_development_data_folder():
    hits = [f"{p.relative_to(ROOT)}:{i}: {m.group(0)!r}" for p in sorted((ROOT / "docs").rglob("*.md"))
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
            for m in SHARED_PATH.finditer(line)]
    assert not hits, hits


def test_every_page_is_in_the_navigation():
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = [p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")]
    missing = [p for p in pages if p not in nav]
    assert not missing, missing


@pytest.mark.slow  # ~9 CPU s: the parser's command modules import torch; mkdocstrings reads three packages
def test_site_builds_strict_with_every_link_and_anchor_resolved(tmp_path):
    try:
        import material  # noqa: F401
        import mkdocs  # noqa: F401
        import mkdocstrings  # noqa: F401
    except ImportError as exc:
        if os.environ.get("CI"):
            raise  # CI installs the test extra, which has them: never skipped there
        pytest.skip(f"the site's tools are not installed ({exc}): pip install -e '.[test]'")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    cli = (tmp_path / "site" / "reference" / "cli.html").read_text(encoding="utf-8")
    from compensation.app.cli import build_parser
    import argparse
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name, sp in sub.choices.items():
        assert f'id="{name}"' in cli, name
        for a in sp._actions:
            if a.help == argparse.SUPPRESS:
                continue  # hidden from --help, so from the reference too
            for o in a.option_strings:
                if o.startswith("--") and o != "--help":
                    assert f"<code>{o}</code>" in cli, f"{name} {o}"
    for package in ("errormap", "compensation", "training"):
        page = (tmp_path / "site" / "reference" / "api" / f"{package}.html").read_text(encoding="utf-8")
        for name in __import__(package).__all__:
            assert f'id="{package}.' in page and name in page, f"{package}.{name}"
