"""The repository stands on its own: README and docs point to nothing outside it."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "BENCHMARKS.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if "decisions" not in p.parts)]

def _generated_pages() -> set:
    """The pages tools/docs_hooks.py adds when the site is built (no file in the tree)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "tools" / "docs_hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    return {ROOT / "docs" / page for page in hooks.GENERATED_PAGES}


OUTSIDE = re.compile(r"DESIGN\.md|\.\./shared|/shared/|/work/")


def test_docs_reference_nothing_outside_the_repository():
    bad = [f"{p.name}:{i}: {line.strip()}" for p in DOCS
           for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if OUTSIDE.search(line)]
    assert not bad, bad


def test_every_repository_path_the_docs_name_exists():
    """`docs/x.md`, `errormap/...` style paths in backticks and relative markdown links resolve."""
    missing, generated = [], _generated_pages()
    for p in DOCS:
        text = p.read_text(encoding="utf-8")
        for ref in re.findall(r"`((?:docs|errormap|training|compensation|benchmarks|tests)/[\w./-]+\.(?:md|py|toml))`", text):
            if not (ROOT / ref).exists():
                missing.append(f"{p.name}: {ref}")
        for ref in re.findall(r"\]\(([\w./-]+\.md)(?:#[\w-]+)?\)", text):
            target = (p.parent / ref.split("#")[0]).resolve()
            if not target.exists() and target not in generated:
                missing.append(f"{p.name}: {ref}")
    assert not missing, missing


def test_schemas_document_every_file_kind_with_an_example():
    text = (ROOT / "docs" / "reference" / "file-formats.md").read_text(encoding="utf-8")
    for heading in ("Machine file, grinder", "Machine file, hexapod and tripod", "Element set", "Feature points",
                    "Axis sweeps", "Check measurements", "Tool paths", "PKM pose measurements", "Drift logs",
                    "Model folder and training run"):
        section = text.split(f"## {heading}", 1)
        assert len(section) == 2, heading
        assert "```" in section[1].split("\n## ", 1)[0], f"{heading}: no example"


def test_machine_file_examples_in_the_docs_load(tmp_path):
    from errormap.machine import load_machine
    text = (ROOT / "docs" / "reference" / "file-formats.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```toml\n(.*?)```", text, flags=re.S)
    kinds = []
    (tmp_path / "ur5.urdf").write_bytes((ROOT / "tests" / "data" / "urdf" / "ur5.urdf").read_bytes())  # the urdf example's
    for i, b in enumerate(blocks):
        p = tmp_path / f"m{i}.toml"
        p.write_text(b, encoding="utf-8")
        kinds.append(load_machine(p).kind)
    assert kinds == ["machine-tool", "hexapod", "tripod", "serial", "serial", "machine-tool"]  # grinder: its chain
    grinder = load_machine(tmp_path / "m0.toml")
    assert grinder.sha256 != "" and 'kind = "grinder" read as its machine-tool chain' in grinder.read_as
