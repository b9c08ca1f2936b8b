"""The import rules of the house (docs/explanation/architecture.md), read from the source with ``ast``.

Layers import one way, ``errormap`` ← ``training`` ← ``compensation``, and the application wing
``compensation/app`` sits on top: nothing outside it imports it, and its command modules do not
import one another (what two commands share lives in ``app/options.py`` or a workflow), and no two
modules import each other, even through a chain. Every import counts, at module level or inside a
function, absolute or relative.
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
    assert imports_of("from .chain_loop import closed_loop_chain\n", "errormap.diagnosis", is_package=True) >= {
        "errormap.diagnosis.chain_loop"}
    bad = [m for m in found if m.startswith(COMMANDS + ".") and m != "compensation.app.commands.demo"]
    assert bad == ["compensation.app.commands.simulate"]


def test_every_package_has_sources():
    for p in PACKAGES + (APP, COMMANDS):
        assert sources(p), p


def test_errormap_imports_neither_training_nor_compensation():
    assert offenders(sources("errormap"), ("training", "compensation")) == []


def test_training_does_not_import_compensation():
    assert offenders(sources("training"), ("compensation",)) == []


FACADE = ("compensation.compensate",)
"""The public Python API's program entry (``compensate_program``, docs/reference/python-api.md): a peer of the CLI over
the same workflows, so it sits in the outer layer beside ``compensation.app``, not in the library."""


def test_nothing_outside_the_app_wing_imports_it():
    outside = [f for p in PACKAGES for f in sources(p)
               if not module_name(f).startswith(APP) and module_name(f) not in FACADE]
    assert outside
    assert offenders(outside, (APP,)) == []


def test_no_library_module_imports_the_facade():
    """The facade may import the workflows only because nothing below it imports the facade (the
    packages' ``__init__`` re-export it lazily for users)."""
    library = [f for p in PACKAGES for f in sources(p) if not module_name(f).startswith(APP)
               and module_name(f) not in FACADE and f.name != "__init__.py"]
    assert library
    assert offenders(library, FACADE) == []


@pytest.mark.parametrize("path", sources(COMMANDS), ids=lambda p: p.name)
def test_commands_do_not_import_one_another(path):
    others = [module_name(f) for f in sources(COMMANDS) if f != path and f.name != "__init__.py"]
    assert offenders([path], others) == []


def module_graph() -> dict:
    """{module: set of project modules it imports} over the three packages (imports of a package's
    ``__init__`` re-exports count as imports of that package; ``a.b`` naming a symbol, not a
    module, is dropped)."""
    files = [f for p in PACKAGES for f in sources(p)]
    names = {module_name(f) for f in files}
    graph = {module_name(f): {m for m in imported_modules(f) if m in names and m != module_name(f)} for f in files}
    graph[CLI] |= dynamic_command_imports()
    return graph


CLI = "compensation.app.cli"


def dynamic_command_imports() -> set:
    """The command modules ``compensation/app/cli.py`` imports by name (``importlib``, one per
    ``COMMAND_HELP`` entry): invisible to ``ast``, they are edges of the graph all the same, so a
    command or workflow importing the cli back is a cycle."""
    from compensation.app.cli import COMMAND_HELP, command_module
    mods = {command_module(name) for name in COMMAND_HELP}
    present = {module_name(f) for f in sources(COMMANDS)}
    assert mods <= present, sorted(mods - present)
    return mods


def cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_two_modules_import_each_other():
    """No import cycle between modules, even through an import inside a function (one of them
    then only works because of the order things happen to be imported in). A package's
    ``__init__`` that re-exports its submodules is left out: it is the package's front door."""
    graph = {m: deps - PACKAGE_INITS for m, deps in module_graph().items() if m not in PACKAGE_INITS}
    assert cycles(graph) == []


PACKAGE_INITS = {module_name(f) for p in PACKAGES for f in sources(p) if f.name == "__init__.py"}


def test_the_cycle_check_sees_the_cli_importing_its_commands():
    """A command that imports ``compensation.app.cli`` (for ``UsageError``, say) closes a cycle
    through the cli's by-name import of every command; the graph carries those edges."""
    graph = module_graph()
    assert "compensation.app.commands.simulate" in graph[CLI]
    graph["compensation.app.commands.simulate"] = graph["compensation.app.commands.simulate"] | {CLI}
    assert any(CLI in c and "compensation.app.commands.simulate" in c for c in cycles(graph))


def test_nothing_imports_the_cli():
    """``compensation/app/cli.py`` is the top of the house: what commands share with it
    (``UsageError``, ``one_line``) lives in ``compensation/app/validate.py``."""
    files = [f for p in PACKAGES for f in sources(p) if module_name(f) != CLI]
    assert offenders(files, (CLI,)) == []
