"""The import rules of the house (docs/architecture.md), read from the source with ``ast``.

Layers import one way, ``errormap`` ← ``training`` ← ``compensation``, and the application wing
``compensation/app`` sits on top: nothing outside it imports it, and its command modules do not
import one another (what two commands share lives in ``app/options.py`` or a workflow). Every
import counts, at module level or inside a function, absolute or relative.
"""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("errormap", "training", "compensation")
APP = "compensation.app"
COMMANDS = "compensation.app.commands"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path) -> set:
    """Every module the source file ``path`` imports (see :func:`imports_of`)."""
    return imports_of(path.read_text(encoding="utf-8"), module_name(path), path.name == "__init__.py")


def imports_of(text: str, name: str, is_package: bool = False) -> set:
    """Every module the source ``text`` of module ``name`` imports, as absolute dotted names
    (``from a import b`` gives both ``a`` and ``a.b``: ``b`` may be a submodule)."""
    package = name if is_package else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            found.add(mod)
            found.update(f"{mod}.{a.name}" for a in node.names if a.name != "*")
    return found


def sources(package: str):
    return sorted((ROOT / package.replace(".", "/")).rglob("*.py"))


def offenders(files, forbidden) -> list:
    """``(module, imported)`` for every import in ``files`` that is ``forbidden`` or inside it."""
    bad = []
    for f in files:
        for mod in sorted(imported_modules(f)):
            if any(mod == p or mod.startswith(p + ".") for p in forbidden):
                bad.append((module_name(f), mod))
    return bad


def test_the_walker_resolves_relative_and_nested_imports():
    """The rules below are only as good as this: relative imports resolve to the real names,
    imports inside functions count, and a command importing a sibling is caught."""
    text = ("from . import simulate\nfrom ..workflows.compare import compare_methods\n"
            "def run():\n    from ...evaluate import load_truth\n    import compensation.app.cli\n")
    found = imports_of(text, "compensation.app.commands.demo")
    assert {"compensation.app.commands.simulate", "compensation.app.workflows.compare",
            "compensation.evaluate", "compensation.app.cli"} <= found
    assert imports_of("from .pipeline import diagnose\n", "errormap.diagnosis", is_package=True) >= {
        "errormap.diagnosis.pipeline"}
    bad = [m for m in found if m.startswith(COMMANDS + ".") and m != "compensation.app.commands.demo"]
    assert bad == ["compensation.app.commands.simulate"]


def test_every_package_has_sources():
    for p in PACKAGES + (APP, COMMANDS):
        assert sources(p), p


def test_errormap_imports_neither_training_nor_compensation():
    assert offenders(sources("errormap"), ("training", "compensation")) == []


def test_training_does_not_import_compensation():
    assert offenders(sources("training"), ("compensation",)) == []


def test_nothing_outside_the_app_wing_imports_it():
    outside = [f for p in PACKAGES for f in sources(p) if not module_name(f).startswith(APP)]
    assert outside
    assert offenders(outside, (APP,)) == []


@pytest.mark.parametrize("path", sources(COMMANDS), ids=lambda p: p.name)
def test_commands_do_not_import_one_another(path):
    others = [module_name(f) for f in sources(COMMANDS) if f != path and f.name != "__init__.py"]
    assert offenders([path], others) == []
