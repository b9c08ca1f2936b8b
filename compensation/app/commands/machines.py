"""``volcomp machines``: the built-in machines, read from their files (``errormap/machines/*.toml``).

Each row: the name ``--machine NAME`` takes, the ``[machine] kind``, the machine's own name and its
commanded axes with their strokes or limits and units (:func:`errormap.machine.machine_axes`).
``--json`` prints the same as one JSON list on stdout.
"""
from __future__ import annotations

import json

from errormap.machine import builtin_machines, load_machine, machine_axes


def register(sub):
    p = sub.add_parser("machines", help="list the built-in machines: name, kind and axes with strokes/limits",
                       description="List every built-in machine (errormap/machines/*.toml), read from its file: "
                                   "the name --machine takes, its kind, its own name and its axes with their "
                                   "strokes or limits and units.")
    p.add_argument("--json", action="store_true", help="print the list as JSON (machine-readable)")
    p.set_defaults(func=run)


def listing() -> list:
    """``[{"name", "kind", "title", "file", "axes": [{"name", "type", "unit", "lo", "hi"}]}]``, by name."""
    out = []
    for name, path in builtin_machines().items():
        m = load_machine(path)
        out.append({"name": name, "kind": m.kind, "title": m.name, "file": path.name,
                    "axes": [a.to_dict() for a in machine_axes(m)]})
    return out


def _axis_text(a: dict) -> str:
    return f"{a['name']} [{a['lo']:g}, {a['hi']:g}] {a['unit']}"


def run(args) -> int:
    rows = listing()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    w_name = max(len("NAME"), *(len(r["name"]) for r in rows))
    w_kind = max(len("KIND"), *(len(r["kind"]) for r in rows))
    print(f"{'NAME':<{w_name}}  {'KIND':<{w_kind}}  AXES (stroke or limits)  —  machine")
    for r in rows:
        print(f"{r['name']:<{w_name}}  {r['kind']:<{w_kind}}  {', '.join(_axis_text(a) for a in r['axes'])}  —  "
              f"{r['title']}")
    return 0
