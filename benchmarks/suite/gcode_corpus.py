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
the reader's frames (:func:`independent_check`, tests/program_checks.py), every ``lathe-xzc`` one in turning mode
by :func:`lathe_check` (at the tool offset in force; a point on the spindle axis, which no X reaches where the tool
is off centre height, judged against the least radius any X reaches there: the model residual when the model is the
truth): a program off by more than 1 um at a programmed point, or with a non-motion line changed, is counted
silently wrong. A file that moves nothing when run
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
import shutil
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
MANIFEST = HERE / "program_corpus" / "MANIFEST.csv"
STYLES = HERE / "nc_styles"
TOOL_LENGTH_MM = 100.0
TOOL_RADIUS_MM = 5.0
PART_ZERO_MM = {"mill-xyz": (300.0, 200.0, -300.0), "lathe-xzc": (0.0, 0.0, 200.0), "five-axis-ac": (0.0, 0.0, 40.0),
                "mill-xyza": (300.0, 200.0, -425.0), "hmc-xyzb": (0.0, 150.0, -650.0),
                "five-axis-bc": (0.0, 0.0, -460.0)}
"""Where the tables put every work system: a part zero inside the machine's strokes (mill: the middle of X
and Y, 100 mm above the bottom of Z's stroke; lathe: the spindle axis, the part's face 200 mm along the bed, so
that turning towards the chuck (Z < 0) stays inside Z's stroke; five-axis: on the C axis, 40 mm above the C
table top). The rotary machines' zero is where 4/5-axis posts put it: mill-xyza on the A axis line (Y and Z
zero on it, as a 4th-axis program's radii and wrapped Y need), mid-X; hmc-xyzb on the B axis (X), 150 mm above
the pallet top (Y) and 200 mm from the B axis toward the spindle (Z: a face of a part on the pallet), so that
both the program's Z 0…+650 retracts and a G43 tool of :data:`TOOL_LENGTH_MM` stay in Z's stroke; five-axis-bc
on the C axis, 50 mm above the C table top (a part's top), the tip there at B = C = 0. These are joint-mode zeros
(machine axes = program + offset); under TCP the offset is the part zero in the workpiece frame, as five-axis-ac's
is (its corpus programs are TCP demos): a TCP program on the rotary machines would need (0, 0, 50) and the like."""


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


def _lines(path: Path) -> list:
    """The file's lines as a controller cuts them: its bytes as Latin-1, each line with its own ending kept (``\\n``
    ends a line: a CRLF file stays CRLF, so a check compares the bytes a controller reads; in a file with no
    ``\\n`` at all, old Mac style, ``\\r`` does)."""
    text = path.read_bytes().decode("latin-1")
    end = "\n" if "\n" in text or "\r" not in text else "\r"
    return re.findall(rf"[^{end}]*{end}|[^{end}]+$", text)


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


def independent_check(src: Path, written: Path, dialect: str, truth_file: Path, offsets: dict | None = None,
                      tools: dict | None = None) -> str:
    """``--check``: the written program run as the shop would, judged independently of the reader's frames:
    frames (work offset, tool length) per line from the program's own G54-G59 / G54.1 P / G154 P / G43 H /
    G49 words read by patterns (tests/program_checks.py ``_frame``; the controller's power-on G54 before any),
    the same for the written program. Passes when (1) the lines that are not compensated moves are the
    source's, byte for byte and in order, with the same line ends, (2) every move the reader leaves uncompensated
    is one it may leave so (a rapid, or a move of Z alone before X and Y were given: the position the controller
    starts it from is not the program's; any other is counted wrong), and (3) every programmed end point of a compensated move is reached,
    in order, by the TRUE machine at the end of some written move within 1 um. ``"ok: max E um at N points"``,
    ``"WRONG: ..."`` (silently wrong) or ``"not checkable: ..."``. A program the reader expanded (subprograms,
    macros: a flat program is written) is judged against the reader's flat program. ``offsets`` {system: (3,) mm}
    and ``tools`` {number: length mm}: the tables the program was compensated with (default: the count's, every
    system at :data:`PART_ZERO_MM`, every tool 100 mm). A program with canned cycles is judged by
    :func:`cycle_check`."""
    text = src.read_bytes().decode("latin-1")  # not read_text: universal newlines would make CR an LF
    lf_ends = "\n" in text  # none: CR-only line ends, which the written program must keep
    if re.search(CYCLE_RE, text):
        return cycle_check(src, written, dialect, truth_file, offsets, tools)
    if NURBS_RE.search(text):  # its control-point lines are written as comments, the curve as compensated chords
        return "not checkable: NURBS blocks (G5.2/G5.3) written as chords (tests/test_gcode_nurbs.py checks them)"
    sys.path.insert(0, str(HERE.parent / "tests"))
    from program_checks import TOL_POINT_UM, _frame
    from compensation.gcode import AxisWords, parse_program
    from compensation.nc_state import machine_with_tool
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    mill = load_machine("mill-xyz")
    if offsets is None:
        offsets, tools = _count_tables()
    aw, dia = AxisWords.of(mill), dialect  # "auto": detected from each file, as compensate does
    try:  # a program with canned cycles is read by compensate's cycle reader, not this plain parse
        placed = _g53_placed(src, written, offsets, tools)
        expanded = parse_program(placed or src, axis_words=aw, dialect=dialect).expanded
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        return f"not checkable: {type(exc).__name__}: {exc}"[:110]
    if expanded is not None and placed is not None:
        return "not checkable: G53 moves in a program the reader expands"
    out = [ln for ln in _lines(written) if not ln.startswith("(volcomp:")]  # the writer's header (after a '%' too)
    bare = written.with_suffix(written.suffix + ".bare")
    bare.write_bytes("".join(out).encode("latin-1"))
    placed_out = _g53_placed(bare, bare, offsets, tools) if placed is not None else None
    if expanded is not None:
        src = written.with_suffix(written.suffix + ".flat")
        src.write_text(expanded.text, encoding="latin-1")
    try:
        p_src, p_out = (parse_program(f, axis_words=aw, fast=False, dialect=dia) for f in (placed or src, placed_out or bare))
        f_src, f_out = (_frame(p.lines, offsets, tools, "G54") for p in (p_src, p_out))
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        return f"not checkable: {type(exc).__name__}: {exc}"[:110]
    src_lines = _lines(src) if placed is not None else p_src.lines  # the lines a controller reads
    if len(src_lines) != len(p_src.lines):
        return "not checkable: the G53 lines placed in the program's frame split into other lines"
    m_src = [m for m in p_src.moves if m.compensate]
    m_out = [m for m in p_out.moves if m.compensate]
    feed = next((m for m in p_src.moves if not m.compensate and m.kind != "rapid" and set(m.words) & set("XYZ") != {"Z"}),
                None)  # uncompensated by design: rapids, and a move of Z alone before X and Y were given
    if feed is not None:
        return f"WRONG: line {feed.index + 1} ({p_src.lines[feed.index].strip()[:40]!r}), a feed, left uncompensated"
    if lf_ends != (b"\n" in written.read_bytes()):
        return "WRONG: the line ends changed (CR-only and LF)"
    keep_src = [ln for i, ln in enumerate(src_lines) if i not in {m.index for m in m_src}]
    out_lines = _lines(bare) if placed_out is not None else p_out.lines
    keep_out = [ln for i, ln in enumerate(out_lines) if i not in {m.index for m in m_out}]
    if keep_src != keep_out:
        bad = next((s for s, o in zip(keep_src, keep_out) if s != o), "(line count)")
        return f"WRONG: a line that is not a compensated move changed: {bad.strip()[:50]!r}"
    truth_els, fields = ChainElementSet.load(truth_file, mill), {}

    def placed(m, frames):
        off, tool = frames[m.index]
        q = m.end + off + [0.0, 0.0, tool if tool is not None else 0.0]
        if tool not in fields:
            mt = machine_with_tool(mill, tool) if tool is not None else mill
            fields[tool] = (mt, ChainField(mt, truth_els))
        return q, fields[tool]

    errs, j, held, held_um = [], 0, _held_by_g53(src_lines), []
    for m in m_src:
        q, (mt, _) = placed(m, f_src)
        target = mt.nominal(q[None])[0]
        free = np.array([a not in held[m.index] for a in "XYZ"])  # a held axis: its error is stated, not judged
        while j < len(m_out):
            qo, (mto, truth) = placed(m_out[j], f_out)
            j += 1
            e = (mto.nominal(qo[None])[0] + truth.predict(qo[None])[0] * 1e-3 - target) * 1e3
            if np.linalg.norm(e[free]) <= TOL_POINT_UM:
                errs.append(float(np.linalg.norm(e[free])))
                held_um += [float(np.abs(e[~free]).max())] if not free.all() else []
                break
        else:
            return f"WRONG: line {m.index + 1} ({p_src.lines[m.index].strip()[:40]!r}) reached by no written move"
    held_note = f"; held at a G53 value: max {max(held_um):.3g} um along it at {len(held_um)} points" if held_um else ""
    return f"ok: max {max(errs):.3g} um at {len(errs)} points{held_note}" if errs else "not checkable: no compensated move"


def _held_by_g53(lines: list) -> list:
    """Per line, the axes (of X Y Z) a ``G53`` line set and no line gave since, read by pattern: a move there holds
    them at the machine value (the compensated axes are judged, the held one's error stated)."""
    held, out = set(), []
    for ln in lines:
        body = re.sub(r"\([^)]*\)|;.*", "", ln).upper()
        given = set(re.findall(r"(?<![A-Z#])([XYZ])\s*[-+.\d]", body))
        held = held | given if G53_RE.search(body) else held - given
        out.append(frozenset(held))
    return out


G53_RE = re.compile(r"G0*53(?![.\d])", re.IGNORECASE)
NURBS_RE = re.compile(r"^[^(;]*G0*5\.2(?!\d)", re.IGNORECASE | re.MULTILINE)


def _g53_placed(src: Path, written: Path, offsets: dict, tools: dict) -> Path | None:
    """``src`` with its ``G53`` moves placed in the program's frame (:func:`_g53_in_frame`), written beside
    ``written``; None where it has none, or one that is not a ``G0`` (the source is then read as written)."""
    if not G53_RE.search(src.read_bytes().decode("latin-1")):
        return None
    sys.path.insert(0, str(HERE.parent / "tests"))
    from program_checks import _frame
    lines = _lines(src)
    placed = _g53_in_frame(lines, _frame(lines, offsets, tools, "G54"))
    if placed is None or placed == lines:
        return None
    out = written.with_suffix(written.suffix + ".g53")
    out.write_bytes("".join(placed).encode("latin-1"))
    return out


def _g53_in_frame(lines: list, frames: list) -> list | None:
    """The source lines with each ``G53 G0`` move written in the program's frame, independently of the reader: its
    X Y Z words (in the line's units, ``G20``/``G21`` read by pattern) minus the line's work offset and tool length
    (``frames``, tests/program_checks.py ``_frame``), the G53 dropped, so that the moves after it start where the
    controller has them (the rewritten line is a rapid, kept as written: not a point the check asks for). None: a
    G53 move that is not a G0."""
    out, selected, inch = [], False, False
    for ln, (off, tool) in zip(lines, frames):
        code = re.sub(r"\(.*?\)|;.*", "", ln.rstrip("\r\n"))
        units = re.findall(r"G0*2([01])(?![.\d])", code, re.IGNORECASE)
        inch = units[-1] == "0" if units else inch
        if not G53_RE.search(code) or not re.search(r"[XYZ]", code, re.IGNORECASE):
            selected |= bool(re.search(r"(G154|G1[12]\d|G54\.1|G59\.[123]|G5[4-9])(?![.\d])", code.upper()))
            out.append(ln)
            continue
        if not re.search(r"G0*0(?![.\d])", G53_RE.sub("", code)):
            return None
        shift_mm = np.asarray(off, dtype=float) + [0.0, 0.0, tool if tool is not None else 0.0]
        unit_mm = 25.4 if inch else 1.0

        def in_frame(m):
            mm = float(m.group(2)) * unit_mm - shift_mm["XYZ".index(m.group(1).upper())]
            return f"{m.group(1)}{mm / unit_mm:.9f}"
        body = re.sub(r"([XYZ])\s*([-+]?[\d.]+)", in_frame, G53_RE.sub("", code), flags=re.IGNORECASE)
        body += "" if selected else " G54"  # placed in the power-on system (the frames' G54): selecting it is no change
        out.append(body + ln[len(ln.rstrip("\r\n")):])
    return out


def _count_tables() -> tuple:
    """The count's tables for the checks: every system at the mill's :data:`PART_ZERO_MM`, every tool 100 mm."""
    systems = ["G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"]
    systems += [f"G54.1P{n}" for n in range(1, 49)] + [f"G154P{n}" for n in range(1, 100)]
    systems += [f"G{n}" for n in range(110, 130)]
    return {s: PART_ZERO_MM["mill-xyz"] for s in systems}, {n: TOOL_LENGTH_MM for n in range(1, 100)}


CYCLE_RE = r"(?i)G0*(?:7[346]|8[1-9])(?![\d.])"
"""A drilling canned cycle's code (G73 G74 G76 G81-G89), found by pattern."""
_MOTION_RE = r"(?i)G0*(?:[0-3]|80)(?![\d.])"
_WORDS_RE = r"(?i)([XYZR])\s*([-+]?(?:\d+\.?\d*|\.\d+))"


def _cycle_lines(lines) -> list:
    """Indices of the lines that drill (a cycle code, or an X/Y/Z word while a cycle is the mode), by pattern."""
    out, on = [], False
    for i, ln in enumerate(lines):
        body = re.sub(r"\(.*?\)|;.*", "", ln)
        if re.search(CYCLE_RE, body):
            on = True
        elif re.search(_MOTION_RE, body):
            on = False
        if on and re.search(r"(?i)[XYZ]\s*[-+.\d]", body):
            out.append(i)
    return out


def cycle_check(src: Path, written: Path, dialect: str, truth_file: Path, offsets=None, tools=None) -> str:
    """``--check`` of a program with kept canned cycles, independently of the reader: the cycle lines (found by
    pattern) blanked in both programs, the rest judged by :func:`independent_check`; then every hole: the
    programmed bottom (X Y from the last absolute X Y, Z sticky, in the frame of its line read by
    tests/program_checks.py ``_frame``) reached within 1 um by the TRUE machine at the written line's X Y Z.
    Holes under G91 are not checkable."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from program_checks import TOL_POINT_UM, _frame
    from compensation.nc_state import machine_with_tool
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    mill = load_machine("mill-xyz")
    a = _lines(src)
    b = [ln for ln in _lines(written) if not ln.startswith("(volcomp:")]
    ca, cb = _cycle_lines(a), _cycle_lines(b)
    if len(ca) != len(cb):
        return "not checkable: the written program's cycle lines are not the source's (G91 repeats)"
    blank = lambda lines, c: "".join("(cycle)\n" if i in c else ln for i, ln in enumerate(lines))  # noqa: E731
    scratch = Path(tempfile.mkdtemp(prefix="volcomp-cycle-check-"))  # never beside the programs
    pa, pb = scratch / ("src" + src.suffix), scratch / ("written" + written.suffix)
    pa.write_bytes(blank(a, set(ca)).encode("latin-1"))
    pb.write_bytes(blank(b, set(cb)).encode("latin-1"))
    written_of = dict(zip(ca, cb))
    try:
        rest = independent_check(pa, pb, dialect, truth_file, offsets, tools)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    if rest.startswith("WRONG"):
        return rest
    if offsets is None:
        offsets, tools = _count_tables()
    frames = _frame(a, offsets, tools, "G54")
    els, state, inc, errs = ChainElementSet.load(truth_file, mill), {}, False, []
    for i, ln in enumerate(a):
        body = re.sub(r"\(.*?\)|;.*", "", ln).upper()
        inc = "G91" in body if re.search(r"G9[01](?![\d.])", body) else inc
        words = {k: float(v) for k, v in re.findall(_WORDS_RE, body)}
        if i not in ca:
            if not re.search(r"G(?:28|30|53)(?![\d.])", body):
                for k in "XY":
                    if k in words:
                        state[k] = state.get(k, np.nan) + words[k] if inc else words[k]
            continue
        if inc:
            return "not checkable: a canned cycle under G91"
        state.update(words)
        w = {k: float(v) for k, v in re.findall(_WORDS_RE, re.sub(r"\(.*?\)|;.*", "", b[written_of[i]]).upper())}
        off, tool = frames[i]
        mt = machine_with_tool(mill, tool) if tool is not None else mill
        shift = np.asarray(off, float) + [0.0, 0.0, tool or 0.0]
        scale = 25.4 if any(re.search(r"G20(?![\d.])", re.sub(r"\(.*?\)|;.*", "", t).upper()) for t in a[:i + 1]) else 1.0
        run = np.array([w["X"], w["Y"], w["Z"]]) * scale + shift
        tgt = np.array([state["X"], state["Y"], state["Z"]]) * scale + shift
        tip = mt.nominal(run[None])[0] + ChainField(mt, els).predict(run[None])[0] * 1e-3
        e_um = float(np.linalg.norm(tip - mt.nominal(tgt[None])[0]) * 1e3)
        if not e_um <= TOL_POINT_UM:
            return f"WRONG: hole of line {i + 1} ({a[i].strip()[:40]!r}) off by {e_um:.3g} um"
        errs.append(e_um)
    return f"ok: max {max(errs):.3g} um at {len(errs)} holes; rest {rest}" if errs else "not checkable: no hole"


def lathe_check(src: Path, written: Path, dialect: str, truth_file: Path) -> str:
    """``--check`` of a ``lathe-xzc`` program in turning mode, independently of the reader's frames: the part zero
    of the count's tables (:data:`PART_ZERO_MM`, every system), the lines that are not compensated moves the
    source's byte for byte, and every programmed end point (radius, Z) reached, in order, by some written move:
    the TRUE tool tip averaged over one turn of the spindle on the programmed surface of revolution within 1 um
    (``compensation.turning.surface_residual_um``), at the tool offset in force (``G43 H`` / ``G49`` read by pattern,
    tests/program_checks.py ``_frame``: the count's tool table, every tool :data:`TOOL_LENGTH_MM` along Z, no X
    offset). A point on the spindle axis: :func:`lathe_points_reached`. A program with C words is not checked here."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from program_checks import TOL_POINT_UM, _frame
    from compensation.turning import parse_lathe_program
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    lathe, zero = load_machine("lathe-xzc"), PART_ZERO_MM["lathe-xzc"]
    out = [ln for ln in _lines(written) if not ln.startswith("(volcomp:")]
    bare = written.with_suffix(written.suffix + ".bare")
    bare.write_bytes("".join(out).encode("latin-1"))
    try:
        (p_src, _), (p_out, _) = (parse_lathe_program(f, lathe, "keep", None, dialect) for f in (src, bare))
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        return f"not checkable: {type(exc).__name__}: {exc}"[:110]
    if len(p_src.axis_words.words) != 2:
        return "not checkable: C words (C-axis mode)"
    m_src = [m for m in p_src.moves if m.compensate]
    m_out = [m for m in p_out.moves if m.compensate]
    keep_src = [ln for i, ln in enumerate(p_src.lines) if i not in {m.index for m in m_src}]
    keep_out = [ln for i, ln in enumerate(p_out.lines) if i not in {m.index for m in m_out}]
    if keep_src != keep_out:
        return "WRONG: a line that is not a compensated move changed"
    systems, tools = _count_tables()
    try:
        f_src, f_out = (_frame(p.lines, {s: zero for s in systems}, tools, "G54") for p in (p_src, p_out))
    except KeyError as exc:  # a tool or work system the count's tables do not hold
        return f"not checkable: {exc} not in the count's tables"
    z_of = lambda frames, moves: [frames[m.index][1] or 0.0 for m in moves]  # noqa: E731 - the tool's Z offset
    field, on_axis = ChainField(lathe, ChainElementSet.load(truth_file, lathe)), []
    errs, missed = lathe_points_reached(field, lathe, m_src, m_out, (zero[0], zero[2]), TOL_POINT_UM, on_axis,
                                        (z_of(f_src, m_src), z_of(f_out, m_out)))
    if missed is not None:
        return f"WRONG: line {missed} reached by no written move"
    axis = (f" ({len(on_axis)} on the spindle axis: off it by the least radius any X reaches, up to "
            f"{max(f for _, f in on_axis):.3g} um)") if on_axis else ""
    return f"ok: max {max(errs):.3g} um at {len(errs)} points{axis}" if errs else "not checkable: no compensated move"


AXIS_ZONE_MM = 1.0
"""A programmed radius beyond this is reachable by X (a tool's centre-height error is tens of um): only nearer the
spindle axis does :func:`lathe_points_reached` look for the least radius the tip can reach."""


def least_radial_um(field, lathe, q, target) -> float:
    """The least radial deviation (um) from the programmed radius of ``target`` (1, 3) that any X reaches, Z as at
    ``q`` (1, 3) (bounded Brent over X within :data:`AXIS_ZONE_MM`; the tip's mean radius over the turn is convex
    in X near the axis); 0 where X reaches the programmed radius."""
    from scipy.optimize import minimize_scalar
    from compensation.turning import surface_residual_um

    def radial(x_mm):
        qx = q.copy()
        qx[0, 0] = x_mm
        return float(surface_residual_um(field, lathe, qx, target)[0][0, 0])
    best = minimize_scalar(radial, bounds=(target[0, 0] - AXIS_ZONE_MM, target[0, 0] + AXIS_ZONE_MM),
                           method="bounded", options={"xatol": 1e-7})
    return max(0.0, float(best.fun))


def lathe_points_reached(field, lathe, m_src, m_out, zero_xz_mm, tol_um: float, on_axis: list | None = None,
                         tools_z_mm: tuple | None = None) -> tuple:
    """``(errors um, missed line)``: per programmed move of ``m_src``, in order, the TRUE error of the first later move
    of ``m_out`` that reaches it within ``tol_um`` — the tool tip driven to the written (radius, Z), averaged over one
    turn of the spindle, against the programmed surface of revolution (``compensation.turning.surface_residual_um``);
    the moves' ends are in the work frame, ``zero_xz_mm`` the part zero's (X, Z) in the machine. ``missed``: the
    1-based line of the first programmed point no written move reaches (its errors so far), else None.
    ``tools_z_mm``: ``(per move of m_src, per move of m_out)`` the tool offset along Z in force (mm; 0: none): the
    machine's Z is the program's plus it, the tool tip that far back (``compensation.turning.at_tool``); a written
    move reaches only a point programmed with the same offset.

    A programmed radius nearer the spindle axis than the TRUE tip passes it (a point on the axis, X0; the tool's
    centre-height error) is reached by no X and Z: there the error left whatever is written is the least radial
    deviation any X reaches at the written Z (:func:`least_radial_um`, found here by a search over X, not by the
    compensator's closest approach; the model residual there when the model is the truth). Such a point counts as
    reached when its error less that floor (its radial deviation less the floor, its axial deviation in full) is within
    ``tol_um``; that is its error, and ``(line, floor um)`` is appended to ``on_axis`` (a list, when given)."""
    from compensation.turning import at_tool, surface_residual_um
    tz_src, tz_out = tools_z_mm if tools_z_mm is not None else ([0.0] * len(m_src), [0.0] * len(m_out))
    at = {}
    place = lambda e, tz: np.array([[e[0] + zero_xz_mm[0], e[1] + zero_xz_mm[1] + tz, 0.0]])  # noqa: E731 - X, Z, C
    errs, j = [], 0
    for m, tz in zip(m_src, tz_src):
        if tz not in at:
            at[tz] = at_tool(field, lathe, 0.0, tz) if tz else (field, lathe)
        f, mt = at[tz]
        target = place(m.end, tz)
        while j < len(m_out):
            q = place(m_out[j].end, tz)
            r = surface_residual_um(f, mt, q, target)[0][0] if tz_out[j] == tz else np.full(2, np.inf)
            near = np.isfinite(r).all() and np.hypot(*r) > tol_um and abs(target[0, 0]) < AXIS_ZONE_MM
            floor = least_radial_um(f, mt, q, target) if near else 0.0
            e = float(np.hypot(r[0] - floor, r[1]))  # the axial error in full: only the radius has a floor
            j += 1
            if np.isfinite(e) and e <= tol_um:
                errs.append(e)
                if floor > 0.0 and on_axis is not None:
                    on_axis.append((m.index + 1, floor))
                break
        else:
            return errs, m.index + 1
    return errs, None


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
    by :func:`independent_check` with those tables (``check``: ``ok: ...``, ``WRONG: ...`` or ``not checkable``)."""
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
