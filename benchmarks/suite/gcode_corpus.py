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
distinct part zeros) and ``tools.csv``. Counted (2026-12-02; before = main at the start of this work, the same 31
programs and tables): accepted 14/31 before (14 of the 24 a controller runs exactly; first stops: ``G187 P3
E0.01``, ``G98`` after ``G99`` holes, a ``G81`` after ``G43 H`` with X Y on the line before, ``G0 … G80`` on one
line (2), a grbl ``$H``, a bare ``G103``, ``G08 P1`` with no dialect word, NX's ``G70``, ``M29 S`` with no dialect word), 24/31 after
(24/24; the 7 refused are the 7 that must be); 0 crashed; 0 silently wrong of 23 checked (``r06``, cycles inside a loop, not checkable).

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

Counted (2026-12-02; before = main at the start of this work, after = this tree; the same manifest and tables):

| corpus | accepted | no motion | refused | crashed | silently wrong (``--check``) |
|---|---|---|---|---|---|
| NC_FILES.csv (185), before | 13 | 118 | 54 | 0 | - |
| NC_FILES.csv (185), after | 16 | 119 | 50 | 0 | 0 of 15 checked (13 mill, 2 lathe; max 0.49 um) |
| NC_FILES.csv (185), 2026-12-03 (lathe threading read: LinuxCNC G33 in pieces with their own K, G33.1 refused where its hole bends over the arc tolerance) | 20 | 125 | 40 | 0 | 0 of 16 checked (14 mill, 2 lathe; max 0.49 um); main before it: the same counts and checks, `threading.ngc` written with K unchanged and `mmount.ngc` refused by its guards instead of its G33.1 |
| NC_FILES.csv (185), 2026-12-03 (LinuxCNC lathe G70-G72 read, written with ``--expand-cycles`` as the interpreter's moves; G93 read in a program whose subroutines are expanded) | 21 | 125 | 39 | 0 | 0 of 16 checked (14 mill, 2 lathe; max 0.49 um); main before it: 20, 125, 40, 0, the same checks; newly read: `daisy.ngc` (G93 inside subroutines; compensating it at the count's part zero is refused by the stroke guard, Z below its stroke); the three G7x programs still refused, each at its own word: `lathe_g7x_quadrants` kept as a cycle (with ``--expand-cycles`` it reads, 786 moves; its X < 0 moves through the spindle axis, where the turning solve does not converge), `lathe_g70_71_demo` an `A` word in its contour, `lathe_g7x_face_boring` a REPEAT loop in its contour |
| NC_FILES.csv (185), 2026-12-03 (G7x contours read as ``Interp::read`` reads them: O-word lines not run, other axes' words skipped; on-axis turning points named) | 21 | 125 | 39 | 0 | 0 of 16 checked (max 0.49 um), as before; `lathe_g70_71_demo` now stops at its `G42.1`, `lathe_g7x_face_boring` at its contour's `#<_x>` (the position before the G72: the program's start) |
| the same, ``--expand-cycles`` | 24 | 125 | 36 | 0 | 0 of 16 checked (max 0.49 um); newly read: `g76`, `lathe-g76`, `lathe_g7x_quadrants`, whose compensation the convergence guard refuses at 9, 9 and 6 points on the spindle axis (as `lathecomp`'s 25 within 20 um of it): the tip passes the axis at its centre-height error (10-21 um on the count's truth), which X and Z cannot correct |
| NC_FILES.csv (185), 2026-12-04 (LinuxCNC ``G41.1``/``G42.1 D`` read, radius D/2; ``G70`` under cutter compensation read) | 21 | 125 | 39 | 0 | 0 of 16 checked (max 0.49 um), as before; `lathe_g70_71_demo` now stops at its `G71.1` kept as a cycle (naming ``--expand-cycles``) |
| the same, ``--expand-cycles`` | 25 | 125 | 35 | 0 | 0 of 16 checked (max 0.49 um); newly read: `lathe_g70_71_demo` (its `G42.1 D0.3 L2` and the `G70` under it; TRUE 8.8e-5 um at 1064 points vs 41 um uncompensated; ``lathe_check`` reads its source with the cycles kept, so not checkable here: checked apart (tool offsets 0), every one of its 150 compensated programmed points within 0.001 um, its non-moves byte for byte) |
| NC_FILES.csv (185), 2026-12-04 (a lathe's points on the spindle axis written where the tool tip passes nearest it, not refused; ``lathe_check`` at the tool offset in force, on-axis points against the least radius any X reaches) | 21 | 125 | 39 | 0 | 0 of 17 checked (14 mill, 3 lathe; max 0.49 um); `lathecomp` now compensated (main: refused by the convergence guard at its 25 on-axis points): 552 points, TRUE max 22.4 um (uncompensated 25.0 um), the largest at its on-axis points (centre height up to 21.2 um on the count's truth), checked: 19 programmed points within 0.021 um, 6 of them on the axis |
| the same, ``--expand-cycles`` | 25 | 125 | 35 | 0 | 0 of 17 checked (max 0.49 um); `g76`, `lathe-g76`, `lathe_g7x_quadrants` now compensated (9, 9 and 6 points on the axis; TRUE max 12.9, 12.9, 22.5 um vs 21.0, 21.0, 41.8 um uncompensated), not checkable here (``lathe_check`` reads the source with the cycles kept); checked apart against the reader's expansion of the source: `g76` 132 programmed points within 0.45 um (9 on the axis), `lathe_g7x_quadrants` 226 within 0.025 um (4 on the axis) |
| MANIFEST.csv (101), before | 40 | 25 | 36 | 0 | - |
| MANIFEST.csv (101), after | 42 | 25 | 34 | 0 | 0 of 34 checked (3 not checkable) |
| MANIFEST.csv (101), with CAM-post words (G80 with G0, bare G43 with the modal H, …; kept cycles checked) | 43 | 25 | 33 | 0 | 0 of 38 checked |

The 64 public 3-axis mill programs that move: 41 accepted (40 before the CAM-post words: ``gcodes__simple_mill``'s
``G0 … G80`` line and its bare ``G43 Z5`` after ``G43 Z100 H1``). Their 23 refusals, by first stop: 14 not
interpretable exactly as written (polar ``^``, probing ``G38.2`` (2), NURBS ``G5.2``, a ``G10 L2 R`` rotation,
subprograms in the controller's memory, ``M98`` with arguments, a ``G81`` without R, ``G43;`` whose H is commented
out, a typo ``:``, a motion before Z is known, MillMaster Pro's ``//`` comments with ``G70``/``G71`` units (2),
grbl-sender ``% vfd enable`` lines), 2 that do not fit the built-in mill (1372 mm and 1981 mm moves), and 7 gaps
left: Fanuc macro abbreviations (``WH[`` for WHILE), ``SQRT`` without brackets, LinuxCNC ``callsub``, ``if`` after
a statement, ``$`` in parameter names, an arc whose radii differ by 4.7 um (Fanuc's parameter 3410 decides), and a
Heidenhain-ISO-like ``:`` block format.

Blind sample (program_corpus/README.md "The blind sample": 40 public 3-axis milling programs drawn on 2026-12-03 by
a rule written before any fetch, from repositories with no other row; rows marked :data:`SAMPLE_MARK`, reported as
their own figures by :func:`sample_figures`): accepted 26/40 by the reader at first, 32/40 once a ``G53`` move's end
is placed in the program's frame from the tables (the 6 Fusion 360 for Personal Use programs whose ``G1 ...
F5000.`` ("instead of G0") follows ``G53 G0 Z0.`` before ``G43 Z H``); 0 crashed. Of the 32, 30 are compensated and
checked (silently wrong 0 of 30; one reported before was the check's own error: it read a CRLF program through
universal newlines); 2, an inch router program 11 in wide, are refused by the stroke guard at the count's part zero.
Second blind sample (README "The second blind sample": 27 programs of other generators, rows marked "blind sample 2",
reported apart by :func:`sample_figures`): 13/27 accepted by main's reader, 19/27 once a line moving Z alone before
X and Y were ever given is written as programmed and listed (``moves_before_position_known``); 0 crashed; 18 checked,
0 silently wrong.
The 6 G53 programs, whose first feed moves run at the Z home (machine Z 0, the top of the stroke), were refused by
the stroke guard while their Z was written with its correction (+Z there: past the stroke end); Z is now held at the
G53 value on those moves (compensation.held_axes): X Y within 0.0008 um by the independent check, the Z error left
there stated (4.5 to 40 um, TRUE = model here). The 8 refusals: 2 ``#600 = ?`` operator placeholders, a bare ``G43``, CR-only
line ends, an ``E1`` on a rapid, ``M252``, a template with ``M39`` and ``X___``, a training program's deliberate
``Y.3.75``.

Read since (2026-12-03; the same corpus, tables and checks): a file with CR-only line ends is read with CR as the
line end and written with CR again (``hahsfilip__1002.ngc``, blind sample: 32/40 -> 33/40, checked: its line ends
kept, every non-motion line byte-identical, 50 points within 0.0007 um); probe moves ``G38.2``-``G38.5`` are
written as programmed and leave the axes they name unknown (``crazyprobe``, ``gridprobe``: they now read, and move
only at rapids and probes, so count as ``no motion``: the mill programs that move 94/129 -> 95/127 accepted); a
``G0`` before every axis is known is written as programmed under ``--rapids compensate`` too (the corpus is counted
with rapids kept, so no count changes). Left refused, saying why: a feed move (``G1``-``G3``) before every axis is
known (the 3 ``blackjetrock`` programs' ``G1 X0`` before Y, ``comp311_2``'s arcs with no Z ever given, the lathe's
``G1 X0`` before Z). 0 crashed; 0 silently wrong of 87 checked. The check now also counts wrong a written program
whose line ends changed and a feed move the reader left uncompensated (only rapids and a first move of Z alone may be).

nc_files newly accepted: ``systems.ngc`` (G92.1), ``threading.ngc`` (G33 on the lathe), ``mmount.ngc`` (G33.1; its
compensation is then refused by the stroke guard: its three fixture stations G55-G57 all sit at the count's one
part zero); ``skeleton.ngc`` (G4 with a G0 on one line) now reads and moves only at rapids (no motion). The most
frequent refusals left: 18 plasma programs read the feed from a HAL pin and never give Z (``#<_hal[...]>``: run-time
state), 7 ngcgui subroutine files whose G or M code is a parameter, 5 probing macros with ``else if``, lathe cycles
(G70-G72, G76 threading passes), 4/5-axis programs whose B axis no built-in machine has, probing (G38.2, #5063,
#5070), polar ``@ ^`` words.
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
        "samples of 40 and 27 3-axis mill programs and 1 4/5-axis program among them, counted apart too); a "
        "1,000,000-line 3-axis program (quick: 20,000 lines)")


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


def parse_cpu_s(n: int) -> float:
    import time
    from compensation.gcode import AxisWords, parse_program
    from errormap.machine import load_machine
    ax = AxisWords.of(load_machine("mill-xyz"))
    v = np.random.default_rng(0).uniform(0, 100, (n, 3))
    with tempfile.TemporaryDirectory() as d:
        p, w = Path(d) / "big.nc", Path(d) / "warm.nc"
        p.write_text("G21 G90\n" + "".join(f"G1 X{a:.4f} Y{b:.4f} Z{c:.4f} F500\n" for a, b, c in v) + "M30\n")
        w.write_text("G21 G90\nG1 X1 Y2 Z3 F500\nG1 X2\nM30\n")
        parse_program(w, axis_words=ax)                   # warm-up (imports, compilation) on another file
        t = time.process_time()
        parse_program(p, axis_words=ax)
        return time.process_time() - t


def run(quick: bool, seed: int) -> dict:
    import os
    figs, notes = style_figures(style_counts(check=True))
    n_lines = 20_000 if quick else 1_000_000
    corpus = os.environ.get("VOLCOMP_PROGRAM_CORPUS")
    if corpus and Path(corpus).is_dir():
        res = count(HERE.parent, Path(corpus), compensate=True, check=True)["results"]
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
        for key in SAMPLES:
            sample_why = Counter(r["reason"] for r in res if r.get("sample") == key and r["outcome"] != "accepted")
            if sample_why:
                notes.append(f"{key.capitalize()} refusals by reason: "
                             + "; ".join(f"{n} x {w}" for w, n in sample_why.most_common()))
        why = Counter(r["reason"] for r in mill if r["outcome"] == "refused")
        notes.append("Public 3-axis mill refusals by reason: " + "; ".join(f"{n} x {w}" for w, n in why.most_common()))
    else:
        notes.append("The public corpus was not fetched on this machine (`$VOLCOMP_PROGRAM_CORPUS`): its count is "
                     "not in this run.")
    cpu = parse_cpu_s(n_lines)
    figs.append({"what": f"reading a {n_lines:,}-line program, CPU", "value": cpu, "unit": "s",
                 "residual": "none", "anchor": "per million lines", "anchor_value": round(cpu * 1e6 / n_lines, 2)})
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
