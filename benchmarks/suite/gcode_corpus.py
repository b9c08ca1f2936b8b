"""Real programs from public repositories: how many ``volcomp compensate`` reads, and why it refuses the rest.

The programs are not stored here (several are GPL or carry no licence): ``program_corpus/MANIFEST.csv``
names each (repository, path, commit, sha256 of the bytes counted), the built-in machine it runs on
and the controller it was written for; fetch them into a folder (file names as in the manifest's
``file`` column) and count:

    python -m benchmarks.suite.gcode_corpus --corpus DIR [--root CHECKOUT] [--json OUT] [--expand-cycles]

In the suite (``python -m benchmarks.run gcode_corpus``) the corpus folder is ``$VOLCOMP_PROGRAM_CORPUS`` (counted,
compensated and checked: ``--check`` below); without it only the programs written in the shops' and CAM posts'
styles (``benchmarks/nc_styles/``, :func:`style_counts`) are counted, compensated and checked, and the reading
speed of a long program is measured.

``benchmarks/nc_styles/``: 31 programs written for this project (not copies) from the posts' and controllers'
manual wording, one or more per family (``FAMILIES.csv``: file, family, expect accept/refuse, the words it uses):
Fusion 360 for Haas, Fanuc, Mach3, grbl and Tormach; Mastercam, SOLIDWORKS CAM, NX, FeatureCAM and Makino Fanuc
posts; NX's generic post (``G70`` inch); Siemens 840D ISO mode; Mach3; grbl; Haas, Fanuc and LinuxCNC shop programs; and seven programs that no
controller-independent reading makes exact (probe results, run-time tool, NURBS, a spline with no dialect word, an
external subroutine, a ``#5241`` offset write, an endless ``M99``), which must be refused. Each is read with
``--dialect auto`` and the shop's tables ``nc_styles/tables/offsets.csv`` (G54, G55, G54.1 P1/P2, G154 P1 at
distinct part zeros) and ``tools.csv``.

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
``--check`` (implies ``--compensate``): every compensated ``mill-xyz`` program is then checked independently of
the reader's frames (benchmarks/suite/gcode_checks.py ``independent_check``, with tests/program_checks.py), every
``lathe-xzc`` one in turning mode by ``gcode_checks.lathe_check`` (at the tool offset in force; a point on the
spindle axis, which no X reaches where the tool is off centre height, judged against the least radius any X reaches
there: the model residual when the model is the truth): a program off by more than 1 um at a programmed point, or
with a non-motion line changed, is counted silently wrong. A file that moves nothing when run
(subroutine libraries whose subroutines it never calls, tool-change and probing macros) is counted ``no motion``.

``--manifest program_corpus/NC_FILES.csv``: LinuxCNC's ``nc_files`` as Debian ships them (package
``linuxcnc-uspace`` 2.9.0~pre1+git20230208.f1270d6ed7-1+deb12u2, its 185 ``.ngc`` under
``usr/share/linuxcnc/ncfiles``; GPL-2.0). Fetch with the package client and lay them out by the manifest:

    apt-get download linuxcnc-uspace=2.9.0~pre1+git20230208.f1270d6ed7-1+deb12u2
    dpkg -x linuxcnc-uspace_*.deb ROOT
    python -m benchmarks.suite.gcode_corpus --from-package ROOT --corpus DIR --manifest \
        benchmarks/program_corpus/NC_FILES.csv --check

In the suite, the folder ``$VOLCOMP_PROGRAM_CORPUS`` may hold both manifests' files: each manifest is counted over the
files it finds there (the ``nc_files`` with cycles kept and with ``--expand-cycles``: :func:`nc_files_figures`).
The counts, the refusals by reason and the checks are in BENCHMARKS.md; how they moved, change by change, in the
repository's history.
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

import numpy as np

from .gcode_checks import PART_ZERO_MM, TOOL_LENGTH_MM, independent_check, lathe_check

HERE = Path(__file__).resolve().parents[1]
MANIFEST = HERE / "program_corpus" / "MANIFEST.csv"
NC_FILES = HERE / "program_corpus" / "NC_FILES.csv"
STYLES = HERE / "nc_styles"
TOOL_RADIUS_MM = 5.0


NO_MOTION = "no G0/G1/G2/G3 motion"
"""The refusal of a file that moves nothing when run (subroutine libraries whose subroutines it never calls,
tool-change and probing macros, demonstrations of messages and parameters): counted apart, as ``no motion``."""


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
    msg = re.sub(r"^\s*line \d+(?: \(expanded as .*?\))?(?:, column \d+)?(?: of that)?"
                 r"(?: \(called from line \d+(?: of [^)]*)?\))*: ", "", msg.strip())
    msg = re.sub(r"^\s*line \d+: ", "", msg)
    return msg[:110]



def compensate_accepted(root: Path, corpus: Path, out: dict, tmp: Path, check: bool = False,
                        manifest: Path = MANIFEST, cycles: str = "keep") -> None:
    """``--compensate``: TRUE max before/after of each accepted program (module docstring)."""
    from compensation.app.cli import main
    from errormap.machine import load_machine
    from errormap.chain_elements import ChainElementSet
    rows = {r["file"]: r for r in csv.DictReader(manifest.open(encoding="utf-8"))}
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
                   "--tool-table", str(tmp / "tools.csv")] + (["--expand-cycles"] if cycles == "expand" else []))
        summary = dest / "compensate_summary.json"
        e = json.loads(summary.read_text())["files"][0] if rc == 0 and summary.is_file() else {}
        r["compensated"] = {"exit": rc, "true_max_um": e.get("true", {}).get("max_um"),
                            "uncompensated_max_um": e.get("true_uncompensated", {}).get("max_um"),
                            "points": e.get("points")}
        if check and rc == 0 and m["machine"] == "mill-xyz":
            r["check"] = independent_check(corpus / r["file"], dest / r["file"], m["dialect"], truths["mill-xyz"])
        elif check and rc == 0 and m["machine"] == "lathe-xzc":
            r["check"] = lathe_check(corpus / r["file"], dest / r["file"], m["dialect"], truths["lathe-xzc"])


def count(root: Path, corpus: Path, compensate: bool = False, check: bool = False, manifest: Path = MANIFEST,
          cycles: str = "keep") -> dict:
    sys.path.insert(0, str(root))
    from compensation.app.validate import UsageError
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.nc_state import read_tool_table, read_work_offsets
    from errormap.io import InputError
    from errormap.machine import load_machine
    rows = list(csv.DictReader(manifest.open(encoding="utf-8")))
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
            s = CompensateSettings("exact", "", Path(tmp), dialect=r["dialect"], work_offsets=offsets, tool_table=tools,
                                   cycles=cycles)
            try:
                read_tool_path(p, machines[r["machine"]], s)
                results.append((r, "accepted", ""))
            except (InputError, UsageError) as exc:
                why = reason_of(str(exc), p.name)
                results.append((r, "no motion" if why.startswith(NO_MOTION) else "refused", why))
            except Exception as exc:  # noqa: BLE001 - a crash is what this counts
                results.append((r, "crashed", f"{type(exc).__name__}: {exc}"[:110]))
        out["results"] = [{"file": r["file"], "kind": r["kind"], "outcome": o, "reason": why,
                           "sample": sample_of(r.get("licence", ""))} for r, o, why in results]
        if compensate:
            compensate_accepted(root, corpus, out, Path(tmp), check, manifest, cycles)
    return out


def lay_out(root: Path, corpus: Path, manifest: Path) -> None:
    """Copy each manifest row's ``path`` under ``root`` (an unpacked package) to ``corpus/file``."""
    corpus.mkdir(parents=True, exist_ok=True)
    for r in csv.DictReader(manifest.open(encoding="utf-8")):
        src = root / r["path"]
        if src.is_file():
            (corpus / r["file"]).write_bytes(src.read_bytes())


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
            lines.append(f"  compensated {r['file']}: {r['compensated']}" + (f"; check {r['check']}" if "check" in r
                                                                              else ""))
    return "\n".join(lines)


TITLE = "G-code programs as shops write them: how many `volcomp compensate` reads, and how fast"
DATA = ("`benchmarks/nc_styles/` (31 programs in CAM posts' and shops' styles, `FAMILIES.csv`, with their offset and "
        "tool tables) and, where fetched "
        "(`$VOLCOMP_PROGRAM_CORPUS`), the 169 public programs of `benchmarks/program_corpus/MANIFEST.csv` (blind "
        "samples of 40 and 27 3-axis mill programs and 1 4/5-axis program among them, counted apart too) and the 185 "
        "LinuxCNC `nc_files` of `benchmarks/program_corpus/NC_FILES.csv` (Debian's `linuxcnc-uspace` 2.9.0~pre1); "
        "a 1,000,000-line 3-axis program (quick: 20,000 lines)")


FAMILIES = STYLES / "FAMILIES.csv"
STYLE_TABLES = STYLES / "tables"
"""The shop's tables the style programs run with (``offsets.csv``: G54, G55, G54.1 P1/P2, G154 P1 at distinct part
zeros; ``tools.csv``: the tools they load), given to the reader as ``--work-offsets`` / ``--tool-table``."""


def style_tables() -> tuple:
    """``(offsets {system: (x, y, z) mm}, tools {number: length mm})`` of :data:`STYLE_TABLES`, read by ``csv`` (the
    checks' own reading, not the product's)."""
    with (STYLE_TABLES / "offsets.csv").open(encoding="utf-8") as f:
        offs = {r["system"]: tuple(float(r[k]) for k in ("x_mm", "y_mm", "z_mm")) for r in csv.DictReader(f)}
    with (STYLE_TABLES / "tools.csv").open(encoding="utf-8") as f:
        tools = {int(r["tool"]): float(r["length_mm"]) for r in csv.DictReader(f)}
    return offs, tools


def style_counts(check: bool = False) -> list:
    """Each row of ``nc_styles/FAMILIES.csv`` (file, CAM post or controller family, expect accept/refuse) read as
    ``volcomp compensate`` reads it (``read_tool_path`` on ``mill-xyz``, ``--dialect auto``, the tables of
    :data:`STYLE_TABLES`): the row with ``outcome`` (accepted / refused / crashed) and ``reason``; ``check``: each
    accepted program compensated (``--method exact``, the count's seeded truth as model and ``--truth``) and judged
    by ``gcode_checks.independent_check`` with those tables (``check``: ``ok: ...``, ``WRONG: ...`` or ``not checkable``)."""
    from compensation.app.cli import main
    from compensation.app.validate import UsageError
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.nc_state import read_tool_table, read_work_offsets
    from errormap.chain_elements import ChainElementSet
    from errormap.io import InputError
    from errormap.machine import load_machine
    mill = load_machine("mill-xyz")
    off_csv, tool_csv = STYLE_TABLES / "offsets.csv", STYLE_TABLES / "tools.csv"
    offs, tools = read_work_offsets(off_csv), read_tool_table(tool_csv)
    rows = list(csv.DictReader(FAMILIES.open(encoding="utf-8")))
    with tempfile.TemporaryDirectory() as tmp:
        truth = ChainElementSet.random(mill, 101, 10.0, 11).save(Path(tmp) / "truth.json")
        for r in rows:
            p = STYLES / r["file"]
            s = CompensateSettings("exact", "", Path(tmp), dialect="auto", work_offsets=offs, tool_table=tools)
            try:
                read_tool_path(p, mill, s)
                r["outcome"], r["reason"] = "accepted", ""
            except (InputError, UsageError) as exc:
                r["outcome"], r["reason"] = "refused", reason_of(str(exc), p.name)
            except Exception as exc:  # noqa: BLE001 - a crash is what this counts
                r["outcome"], r["reason"] = "crashed", f"{type(exc).__name__}: {exc}"[:110]
            if check and r["outcome"] == "accepted":
                dest = Path(tmp) / ("out-" + r["file"])
                rc = main(["compensate", str(p), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                           "--method", "exact", "--out", str(dest), "--dialect", "auto", "--work-offsets", str(off_csv),
                           "--tool-table", str(tool_csv)])
                summary = dest / "compensate_summary.json"
                e = json.loads(summary.read_text())["files"][0] if rc == 0 and summary.is_file() else {}
                r["dialect"] = e.get("dialect", "")
                r["check"] = (independent_check(p, dest / r["file"], "auto", truth, *style_tables()) if rc == 0
                              else f"not checkable: compensate exited {rc}")
    return rows


def style_figures(rows: list) -> tuple:
    """``(figures, notes)`` of :func:`style_counts` rows: accepted of all, of those a shop runs (expect accept), the
    right refusals, silently wrong among the checked; a note per family."""
    c = Counter(r["outcome"] for r in rows)
    run = [r for r in rows if r["expect"] == "accept"]
    right = [r for r in rows if r["expect"] == "refuse"]
    checked = [r for r in rows if r.get("check", "").startswith(("ok", "WRONG"))]
    wrong = [r for r in checked if r["check"].startswith("WRONG")]
    figs = [{"what": "shop-style programs accepted", "value": f"{c['accepted']}/{len(rows)}", "unit": "",
             "residual": "none", "anchor": "crashed (any exception but a refusal)", "anchor_value": c["crashed"]},
            {"what": "of them CAM-post and shop programs a controller runs exactly, accepted",
             "value": f"{sum(r['outcome'] == 'accepted' for r in run)}/{len(run)}", "unit": "", "residual": "none",
             "anchor": "not interpretable exactly, refused", "anchor_value":
                 f"{sum(r['outcome'] == 'refused' for r in right)}/{len(right)}"}]
    if any("check" in r for r in rows):
        figs.append({"what": "accepted style programs silently wrong (independent check, 1 um)",
                     "value": len(wrong), "unit": "", "residual": "true",
                     "anchor": "checked (the rest: not checkable)", "anchor_value": len(checked)})
    fam = defaultdict(Counter)
    for r in run:
        fam[r["family"]][r["outcome"]] += 1
    notes = ["Per family, of the programs a controller runs exactly (accepted/programs): " + "; ".join(
        f"{k} {v['accepted']}/{sum(v.values())}" for k, v in sorted(fam.items())) + "."]
    notes += [f"`{r['file']}` ({r['family']}) {r['outcome']}: {r['reason']}" for r in rows
              if (r["outcome"] == "accepted") != (r["expect"] == "accept")]
    notes += [f"`{r['file']}`: {r['check']}" for r in wrong]
    return figs, notes


SAMPLE_MARK = "blind sample"
"""The manifest's licence column of the rows drawn blind (program_corpus/README.md, "The blind sample" and "The
second blind sample")."""
SAMPLES = {"blind sample": "blind sample of public 3-axis mill programs (CAM posts and shops)",
           "blind sample 2": "second blind sample of public 3-axis mill programs (generators other than Fusion 360)",
           "blind sample rotary": "4/5-axis blind sample of public programs (rotary-axis words on motion lines)"}
"""Each blind sample's mark in the licence column and the words its figures are reported under."""


def sample_of(licence: str) -> str | None:
    """The blind sample a manifest row belongs to (a key of :data:`SAMPLES`), None for the others."""
    marks = [m for m in SAMPLES if m + " (" in licence]
    return max(marks, key=len) if marks else None


def sample_figures(res: list) -> list:
    """Each blind sample's own figures from :func:`count` results (``sample``: its key in :data:`SAMPLES`): its
    3-axis mill programs accepted by the reader of all of them, and silently wrong among those compensated and
    checked."""
    figs = []
    for key, what in SAMPLES.items():
        rows = [r for r in res if r.get("sample") == key]
        if not rows:
            continue
        checked = [r for r in rows if r.get("check", "").startswith(("ok", "WRONG"))]
        short = what.split(" of public")[0]
        figs += [{"what": f"{what}, accepted", "value": f"{sum(r['outcome'] == 'accepted' for r in rows)}/{len(rows)}",
                  "unit": "", "residual": "none", "anchor": "crashed",
                  "anchor_value": sum(r["outcome"] == "crashed" for r in rows)},
                 {"what": f"{short} compensated and checked, silently wrong (independent check, 1 um)",
                  "value": sum(r["check"].startswith("WRONG") for r in checked), "unit": "", "residual": "true",
                  "anchor": "checked", "anchor_value": len(checked)}]
    return figs


def nc_files_figures(corpus: Path) -> tuple:
    """``(figures, notes)`` of LinuxCNC's ``nc_files`` (:data:`NC_FILES`) found in ``corpus``, counted, compensated and
    checked (:func:`count` with ``check``) with cycles kept and with ``--expand-cycles``: of the programs that move,
    accepted; crashed; silently wrong of the checked; the refusals by reason (cycles kept) and the programs only
    ``--expand-cycles`` reads. Empty where none of them is there."""
    figs, notes, by_mode = [], [], {}
    for cycles in ("keep", "expand"):
        res = [r for r in count(HERE.parent, corpus, compensate=True, check=True, manifest=NC_FILES,
                                cycles=cycles)["results"] if r["outcome"] != "missing or changed"]
        if not res:
            return [], []
        by_mode[cycles] = res
        c = Counter(r["outcome"] for r in res)
        moving = len(res) - c["no motion"]
        checked = [r for r in res if r.get("check", "").startswith(("ok", "WRONG"))]
        how = "cycles kept" if cycles == "keep" else "`--expand-cycles`"
        figs += [{"what": f"LinuxCNC `nc_files` programs that move, accepted ({how})",
                  "value": f"{c['accepted']}/{moving}", "unit": "", "residual": "none",
                  "anchor": f"crashed (of {len(res)} files; {c['no motion']} move nothing when run)",
                  "anchor_value": c["crashed"]},
                 {"what": f"LinuxCNC `nc_files` compensated and checked, silently wrong ({how}; independent check, "
                          "1 um)", "value": sum(r["check"].startswith("WRONG") for r in checked), "unit": "",
                  "residual": "true", "anchor": "checked", "anchor_value": len(checked)}]
    why = Counter(r["reason"] for r in by_mode["keep"] if r["outcome"] == "refused")
    notes.append("LinuxCNC `nc_files` refusals by reason (cycles kept): "
                 + "; ".join(f"{n} x {w}" for w, n in why.most_common()))
    kept = {r["file"] for r in by_mode["keep"] if r["outcome"] == "accepted"}
    more = [r["file"] for r in by_mode["expand"] if r["outcome"] == "accepted" and r["file"] not in kept]
    if more:
        notes.append("LinuxCNC `nc_files` read only with `--expand-cycles`: " + ", ".join(f"`{f}`" for f in more) + ".")
    return figs, notes


def parse_cpu_s(n: int) -> tuple:
    """``(user, system)`` CPU seconds of reading an ``n``-line 3-axis program once (after a warm-up on another file:
    imports, compiled kernels). Apart, because the system part is the kernel handing the process its first
    hundreds of MB (page faults), which varies by tens of times between runs and machines (measured 0.08-3.1 s on
    one machine, the lower figures on a second read in the same process) while the reader's own work does not
    (0.41-0.45 s)."""
    import os
    from compensation.gcode import AxisWords, parse_program
    from errormap.machine import load_machine
    ax = AxisWords.of(load_machine("mill-xyz"))
    v = np.random.default_rng(0).uniform(0, 100, (n, 3))
    with tempfile.TemporaryDirectory() as d:
        p, w = Path(d) / "big.nc", Path(d) / "warm.nc"
        p.write_text("G21 G90\n" + "".join(f"G1 X{a:.4f} Y{b:.4f} Z{c:.4f} F500\n" for a, b, c in v) + "M30\n")
        w.write_text("G21 G90\nG1 X1 Y2 Z3 F500\nG1 X2\nM30\n")
        parse_program(w, axis_words=ax)                   # warm-up (imports, compilation) on another file
        t = os.times()
        parse_program(p, axis_words=ax)
        u = os.times()
        return u.user - t.user, u.system - t.system


def run(quick: bool, seed: int) -> dict:
    import os
    figs, notes = style_figures(style_counts(check=True))
    n_lines = 20_000 if quick else 1_000_000
    corpus = os.environ.get("VOLCOMP_PROGRAM_CORPUS")
    if corpus and Path(corpus).is_dir():
        res = count(HERE.parent, Path(corpus), compensate=True, check=True)["results"]
        missing = [r["file"] for r in res if r["outcome"] == "missing or changed"]
        res = [r for r in res if r["outcome"] != "missing or changed"]
        if missing:
            notes.append(f"{len(missing)} of the manifest's {len(res) + len(missing)} programs were not in the folder "
                         f"(or not the bytes counted) on this run and are left out of every figure: "
                         + ", ".join(f"`{f}`" for f in missing) + ".")
        c = Counter(r["outcome"] for r in res)
        mill = [r for r in res if r["kind"] == "mill" and r["outcome"] != "no motion"]
        checked = [r for r in res if r.get("check", "").startswith(("ok", "WRONG"))]
        figs += [{"what": "public programs accepted", "value": f"{c['accepted']}/{len(res)}", "unit": "",
                  "residual": "none", "anchor": "crashed", "anchor_value": c["crashed"]},
                 {"what": "public 3-axis mill programs that move, accepted",
                  "value": f"{sum(r['outcome'] == 'accepted' for r in mill)}/{len(mill)}", "unit": "",
                  "residual": "none", "anchor": "refused", "anchor_value": sum(r["outcome"] == "refused" for r in mill)},
                 {"what": "public programs compensated and checked, silently wrong (independent check, 1 um)",
                  "value": sum(r["check"].startswith("WRONG") for r in checked), "unit": "", "residual": "true",
                  "anchor": "checked", "anchor_value": len(checked)}]
        figs += sample_figures(res)
        per = []
        for key in SAMPLES:
            sample_why = Counter(r["reason"] for r in res if r.get("sample") == key and r["outcome"] != "accepted")
            if sample_why:
                per.append(f"{key}: " + "; ".join(f"{n} x {w}" for w, n in sample_why.most_common()))
        if per:
            notes.append("Blind samples' refusals by reason — " + " — ".join(per))
        why = Counter(r["reason"] for r in mill if r["outcome"] == "refused")
        notes.append("Public 3-axis mill refusals by reason: " + "; ".join(f"{n} x {w}" for w, n in why.most_common()))
        more_figs, more_notes = nc_files_figures(Path(corpus))
        figs, notes = figs + more_figs, notes + more_notes
    else:
        notes.append("The public corpus was not fetched on this machine (`$VOLCOMP_PROGRAM_CORPUS`): its count is "
                     "not in this run.")
    user, system = parse_cpu_s(n_lines)
    figs.append({"what": f"reading a {n_lines:,}-line program, user CPU (the reader's own work)", "value": user,
                 "unit": "s", "residual": "none", "anchor": "system CPU beside it (the kernel giving the process its "
                 "memory: varies by machine)", "anchor_value": round(system, 2)})
    return {"figures": figs, "notes": notes}


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--corpus", required=True, help="folder holding the manifest's files")
    ap.add_argument("--root", default=str(HERE.parent), help="the checkout to count (default: this one)")
    ap.add_argument("--json", help="write the per-program outcomes here")
    ap.add_argument("--compensate", action="store_true", help="compensate every accepted program on a simulated truth")
    ap.add_argument("--check", action="store_true", help="--compensate, then check every compensated mill program "
                                                         "independently (tests/program_checks.py)")
    ap.add_argument("--from-package", help="lay out DIR (--corpus) from an unpacked Debian package ROOT: each "
                                           "manifest row's path copied to its file name")
    ap.add_argument("--manifest", default=str(MANIFEST), help="the manifest to count (default: MANIFEST.csv; "
                                                               "program_corpus/NC_FILES.csv: LinuxCNC's nc_files)")
    ap.add_argument("--expand-cycles", action="store_true", help="read and compensate as with --expand-cycles")
    a = ap.parse_args()
    if a.from_package:
        lay_out(Path(a.from_package), Path(a.corpus), Path(a.manifest))
    result = count(Path(a.root).resolve(), Path(a.corpus), a.compensate or a.check, a.check, Path(a.manifest),
                   "expand" if a.expand_cycles else "keep")
    print(report(result))
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1))
