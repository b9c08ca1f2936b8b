"""Real programs from public repositories: how many ``volcomp compensate`` reads, and why it refuses the rest.

The programs are not stored here (several are GPL or carry no licence): ``program_corpus/MANIFEST.csv``
names each (repository, path, commit, sha256 of the bytes counted), the built-in machine it runs on
and the controller it was written for; fetch them into a folder (file names as in the manifest's
``file`` column) and count:

    python benchmarks/bench_program_corpus.py --corpus DIR [--root CHECKOUT] [--json OUT]

Each program is read as ``volcomp compensate`` reads it before solving (``read_tool_path``: parse,
subprogram/macro expansion, canned cycles kept, frames from the tables, plan) on its machine with its
controller's dialect, with the tables a shop has: a work-offset CSV giving every work system
(``G54``-``G59.3``, ``G54.1 P1``-``P48``, and ``G154 P1``-``P99`` where the revision reads them) and a
tool table of tools 1-99 (100 mm long, radius 5 mm). Outcomes: accepted, refused (the product's message,
grouped by its reason), crashed (an exception other than the refusals), and a sha256 mismatch (the file
is not the one counted). ``--root`` counts another checkout (main, for the before figure).
``--compensate``: every accepted program is then compensated (``volcomp compensate --method exact``) on a
seeded simulated truth (element set of the machine, ±10 μm / μrad 1 σ, seed 101) used as the model and as
``--truth``: the TRUE residual at its points before and after (the product's own frames: this shows the
accepted programs run end to end, not that their frames are right — the tests check those independently).
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import json
import re
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
MANIFEST = HERE / "program_corpus" / "MANIFEST.csv"
TOOL_LENGTH_MM = 100.0
TOOL_RADIUS_MM = 5.0
PART_ZERO_MM = {"mill-xyz": (300.0, 200.0, -300.0), "lathe-xzc": (0.0, 0.0, 0.0), "five-axis-ac": (0.0, 0.0, 40.0)}
"""Where the tables put every work system: a part zero inside the machine's strokes (mill: the middle of X
and Y, 100 mm above the bottom of Z's stroke; lathe: the spindle axis; five-axis: on the C axis, 40 mm above
the C table top)."""


def _tables(tmp: Path, read_work_offsets, read_tool_table, InputError):
    """(work offsets, tool table) for the counted revision: every system it can read."""
    systems = ["G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"]
    systems += [f"G54.1P{n}" for n in range(1, 49)]
    probe = tmp / "probe.csv"
    probe.write_text("system,x_mm,y_mm,z_mm\nG154P1,0,0,0\n")
    try:
        read_work_offsets(probe)
        systems += [f"G154P{n}" for n in range(1, 100)]
    except InputError:
        pass  # the revision reads no Haas G154 table
    out = {}
    for machine, zero in PART_ZERO_MM.items():
        p = tmp / f"offsets-{machine}.csv"
        p.write_text("system,x_mm,y_mm,z_mm\n" + "".join(f"{s},{zero[0]},{zero[1]},{zero[2]}\n" for s in systems))
        t = tmp / "tools.csv"
        t.write_text("tool,length_mm,radius_mm\n" + "".join(f"{n},{TOOL_LENGTH_MM},{TOOL_RADIUS_MM}\n"
                                                            for n in range(1, 100)))
        out[machine] = (read_work_offsets(p), read_tool_table(t))
    return out


def reason_of(message: str, name: str) -> str:
    """The product's refusal without its file, line and column; numbers of the program's own words
    kept, call sites dropped (one reason per kind of refusal)."""
    msg = message.split(name + ":", 1)[-1]
    msg = re.sub(r"^\s*line \d+(?: \(expanded as .*?\))?(?:, column \d+)?(?: of that)?(?: \(called from line \d+\))*: ",
                 "", msg.strip())
    msg = re.sub(r"^\s*line \d+: ", "", msg)
    return msg[:110]


def compensate_accepted(root: Path, corpus: Path, out: dict, tmp: Path) -> None:
    """``--compensate``: TRUE max before/after of each accepted program (module docstring)."""
    from compensation.app.cli import main
    from errormap.machine import load_machine
    from errormap.chain_elements import ChainElementSet
    rows = {r["file"]: r for r in csv.DictReader(MANIFEST.open(encoding="utf-8"))}
    truths = {}
    for r in out["results"]:
        if r["outcome"] != "accepted":
            continue
        m = rows[r["file"]]
        if m["machine"] not in truths:
            mt = load_machine(m["machine"])
            truths[m["machine"]] = ChainElementSet.random(mt, 101, 10.0, 11).save(tmp / f"truth-{m['machine']}.json")
        dest = tmp / ("out-" + r["file"])
        rc = main(["compensate", str(corpus / r["file"]), "--machine", m["machine"], "--model",
                   str(truths[m["machine"]]), "--truth", str(truths[m["machine"]]), "--method", "exact", "--out",
                   str(dest), "--dialect", m["dialect"], "--work-offsets", str(tmp / f"offsets-{m['machine']}.csv"),
                   "--tool-table", str(tmp / "tools.csv")])
        summary = dest / "compensate_summary.json"
        e = json.loads(summary.read_text())["files"][0] if rc == 0 and summary.is_file() else {}
        r["compensated"] = {"exit": rc, "true_max_um": e.get("true", {}).get("max_um"),
                            "uncompensated_max_um": e.get("true_uncompensated", {}).get("max_um"),
                            "points": e.get("points")}


def count(root: Path, corpus: Path, compensate: bool = False) -> dict:
    sys.path.insert(0, str(root))
    from compensation.app.validate import UsageError
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.nc_state import read_tool_table, read_work_offsets
    from errormap.io import InputError
    from errormap.machine import load_machine
    rows = list(csv.DictReader(MANIFEST.open(encoding="utf-8")))
    machines = {m: load_machine(m) for m in {r["machine"] for r in rows}}
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        out = {"root": str(root)}
        tables = _tables(Path(tmp), read_work_offsets, read_tool_table, InputError)
        for r in rows:
            p = corpus / r["file"]
            if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != r["sha256"]:
                results.append((r, "missing or changed", ""))
                continue
            offsets, tools = tables[r["machine"]]
            s = CompensateSettings("exact", "", Path(tmp), dialect=r["dialect"], work_offsets=offsets, tool_table=tools)
            try:
                read_tool_path(p, machines[r["machine"]], s)
                results.append((r, "accepted", ""))
            except (InputError, UsageError) as exc:
                results.append((r, "refused", reason_of(str(exc), p.name)))
            except Exception as exc:  # noqa: BLE001 - a crash is what this counts
                results.append((r, "crashed", f"{type(exc).__name__}: {exc}"[:110]))
        out["results"] = [{"file": r["file"], "kind": r["kind"], "outcome": o, "reason": why} for r, o, why in results]
        if compensate:
            compensate_accepted(root, corpus, out, Path(tmp))
    return out


def report(out: dict) -> str:
    res = out["results"]
    n = Counter(r["outcome"] for r in res)
    by_kind = defaultdict(Counter)
    for r in res:
        by_kind[r["kind"]][r["outcome"]] += 1
    lines = [f"{len(res)} programs: " + ", ".join(f"{k} {v}" for k, v in sorted(n.items()))]
    for kind, c in sorted(by_kind.items()):
        lines.append(f"  {kind}: " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())))
    reasons = defaultdict(list)
    for r in res:
        if r["outcome"] != "accepted":
            reasons[r["reason"]].append(r["file"])
    for why, files in sorted(reasons.items(), key=lambda kv: (-len(kv[1]), kv[0])):
        lines.append(f"  {len(files)} x {why}  [{', '.join(files)}]")
    lines.append("  accepted: " + ", ".join(r["file"] for r in res if r["outcome"] == "accepted"))
    for r in res:
        if "compensated" in r:
            lines.append(f"  compensated {r['file']}: {r['compensated']}")
    return "\n".join(lines)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--corpus", required=True, help="folder holding the manifest's files")
    ap.add_argument("--root", default=str(HERE.parent), help="the checkout to count (default: this one)")
    ap.add_argument("--json", help="write the per-program outcomes here")
    ap.add_argument("--compensate", action="store_true", help="compensate every accepted program on a simulated truth")
    a = ap.parse_args()
    result = count(Path(a.root).resolve(), Path(a.corpus), a.compensate)
    print(report(result))
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1))
