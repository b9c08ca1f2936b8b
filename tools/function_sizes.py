"""The largest functions of the package, as a markdown table.

Size is ``end_lineno - lineno + 1`` of each ``def`` (methods and nested
functions counted on their own, decorators not counted), measured with
``ast`` over the three packages ``errormap``, ``training`` and
``compensation``.

Usage::

    python tools/function_sizes.py [--root DIR] [--top N]
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

PACKAGES = ("errormap", "training", "compensation")


def function_sizes(root: Path) -> list[tuple[int, str, str]]:
    """Return ``(lines, qualified name, path)`` for every function, largest first."""
    rows: list[tuple[int, str, str]] = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            rel = path.relative_to(root).as_posix()

            def visit(node: ast.AST, prefix: str) -> None:
                for child in ast.iter_child_nodes(node):
                    if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        name = f"{prefix}{child.name}"
                        rows.append((child.end_lineno - child.lineno + 1, name, rel))
                        visit(child, name + ".")
                    elif isinstance(child, ast.ClassDef):
                        visit(child, f"{prefix}{child.name}.")
                    else:
                        visit(child, prefix)

            visit(tree, "")
    rows.sort(key=lambda r: (-r[0], r[2], r[1]))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                        help="repository root (default: this checkout)")
    parser.add_argument("--top", type=int, default=15, help="rows to print (default 15)")
    args = parser.parse_args(argv)
    print("| lines | function | file |")
    print("|---:|---|---|")
    for lines, name, path in function_sizes(args.root)[: args.top]:
        print(f"| {lines} | `{name}` | {path} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
