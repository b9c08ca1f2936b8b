"""MkDocs hooks (``mkdocs.yml`` ``hooks:``): the pages that are generated, never hand-copied.

* ``reference/cli.md`` — every command and option, read from ``compensation.app.cli.build_parser()``;
* ``reference/api/<package>.md`` — one mkdocstrings block per public name of ``errormap``,
  ``compensation`` and ``training`` (their ``__all__``, resolved through each package's ``_LAZY`` map).

``python tools/docs_hooks.py`` prints the command reference (the same text the site shows).
"""
from __future__ import annotations

import argparse
import importlib

PACKAGES = ("errormap", "compensation", "training")
GENERATED_PAGES = ("reference/cli.md", *(f"reference/api/{package}.md" for package in PACKAGES))
"""The pages these hooks add, relative to docs/ (tests/test_docs.py counts links to them as resolved)."""


def _cell(text) -> str:
    return " ".join(str(text).split()).replace("|", "\\|").replace("[", "\\[")


def _subcommands(parser) -> tuple:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    return sub.choices, helps


def _option_row(sp, action) -> str:
    name = ", ".join(f"`{o}`" for o in action.option_strings) or f"`{action.dest}`"
    if action.option_strings and action.nargs != 0:
        name += f" `{action.metavar or action.dest.upper()}`" if not action.choices else ""
    if action.choices:
        name += " `{" + ",".join(str(c) for c in action.choices) + "}`"
    default = action.default
    shown = "" if default in (None, False, argparse.SUPPRESS) or action.nargs == 0 else f"`{default}`"
    if action.required:
        shown = "required"
    help_text = sp._get_formatter()._expand_help(action) if action.help else ""
    return f"| {name} | {_cell(shown)} | {_cell(help_text)} |"


def cli_markdown() -> str:
    """The command reference as Markdown: one section per command, its usage and one table row per option."""
    from compensation.app.cli import build_parser
    choices, helps = _subcommands(build_parser())
    out = ["# Command reference", "",
           "Generated from `volcomp`'s argument parser when the site is built (`tools/docs_hooks.py`); "
           "`volcomp CMD --help` prints the same text. Which command and option serve which machine family: "
           "[features](features.md).", ""]
    out += ["| command | what it does |", "|---|---|"]
    out += [f"| [`{name}`](#{name}) | {_cell(helps.get(name) or '')} |" for name in choices]
    for name, sp in choices.items():
        out += ["", f"## volcomp {name} {{ #{name} }}", "", _cell(helps.get(name) or ""), ""]
        if sp.description:
            out += [sp.description.strip(), ""]
        out += ["```text", sp.format_usage().strip(), "```", ""]
        for group in sp._action_groups:
            actions = [a for a in group._group_actions if a.help != argparse.SUPPRESS and a.dest != "help"]
            if not actions:
                continue
            out += [f"**{group.title}**", "", "| argument | default | meaning |", "|---|---|---|"]
            out += [_option_row(sp, a) for a in actions] + [""]
    return "\n".join(out) + "\n"


def api_markdown(package: str) -> str:
    """One page of docstrings: a ``::: module.name`` block per public name of ``package``."""
    pkg = importlib.import_module(package)
    first = (pkg.__doc__ or "").strip().split("\n", 1)[0]
    out = [f"# `{package}`", "", first, "",
           "Generated from the docstrings (mkdocstrings); the overview with an example: [Python API](../python-api.md).", ""]
    for name in pkg.__all__:
        out += [f"::: {pkg._LAZY[name]}.{name}", "    options:", "      heading_level: 2",
                "      show_root_full_path: false", ""]
    return "\n".join(out)


def on_files(files, config):
    """MkDocs event: add the generated pages to the site's files."""
    from mkdocs.structure.files import File
    files.append(File.generated(config, GENERATED_PAGES[0], content=cli_markdown()))
    for package, page in zip(PACKAGES, GENERATED_PAGES[1:]):
        files.append(File.generated(config, page, content=api_markdown(package)))
    return files


if __name__ == "__main__":
    print(cli_markdown())
