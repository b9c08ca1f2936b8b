"""The explanation pages' pictures: tools/docs_figures.py makes exactly the images the pages show, each page shows
at least one, and every committed PNG is small. The heavy generation is not run here (about a CPU minute of
volcomp runs): only the script's list is read."""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = ROOT / "docs" / "explanation"
IMAGE = re.compile(r"\]\((img/[\w.-]+\.png)\)")


def _script():
    spec = importlib.util.spec_from_file_location("docs_figures", ROOT / "tools" / "docs_figures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)   # the module only defines functions at import: no figure is made
    return module


def _referenced() -> dict:
    """{image path relative to docs/explanation: page name} of every image an explanation page shows."""
    return {m.group(1): page.name for page in sorted(PAGES.glob("*.md"))
            for m in IMAGE.finditer(page.read_text(encoding="utf-8"))}


def test_the_script_makes_exactly_the_images_the_pages_show():
    figures = _script().FIGURES
    made = {f"img/{name}.png": page for name, page in figures.items()}
    assert made == _referenced()


def test_every_explanation_page_shows_a_figure():
    shown = set(_referenced().values())
    pages = {p.name for p in PAGES.glob("*.md")} - {"index.md"}
    assert pages - shown == set()


def test_every_image_is_committed_small_and_made_by_the_script():
    module = _script()
    on_disk = {p.stem for p in (PAGES / "img").glob("*.png")}
    assert on_disk == set(module.FIGURES)
    sizes = {p.name: p.stat().st_size for p in (PAGES / "img").glob("*.png")}
    assert all(0 < s <= module.MAX_BYTES for s in sizes.values()), sizes


def test_every_figure_has_its_maker():
    module = _script()
    assert set(module.MAKERS) == set(module.FIGURES)
