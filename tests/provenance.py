"""A volcomp CSV as a reader sees it: its text and its provenance lines (the sidecar ``NAME.meta.json``, or leading
``#`` lines of an older file), for tests that look for a provenance line of an output."""
from __future__ import annotations

from pathlib import Path

from errormap.io import read_table


def text_and_provenance(path) -> str:
    """The CSV's text followed by its provenance lines (``read_table(path).comments``), one per line."""
    return Path(path).read_text(encoding="utf-8") + "\n" + "\n".join(read_table(path).comments)
