"""Real programs from public repositories: how many ``volcomp compensate`` reads, and why it refuses the rest.

The programs are not stored here (several are GPL or carry no licence): ``program_corpus/MANIFEST.csv``
names each (repository, path, commit, sha256 of the bytes counted), the built-in machine it runs on
and the controller it was written for; fetch them into a folder (file names as in the manifest's
``file`` column) and count:

    python -m benchmarks.suite.gcode_corpus --corpus DIR [--root CHECKOUT] [--json OUT]

In the suite (``python -m benchmarks.run gcode_corpus``) the corpus folder is ``$VOLCOMP_PROGRAM_CORPUS``;
without it only the programs written in the shops' styles (``benchmarks/nc_styles/``) are counted, and the
reading speed of a long program is measured.

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
by :func:`lathe_check`: a program off by more than 1 um at a programmed point, or with a non-motion line changed,
is counted silently wrong. A file that moves nothing when run
(subroutine libraries whose subroutines it never calls, tool-change and probing macros) is counted ``no motion``.

``--manifest program_corpus/NC_FILES.csv``: LinuxCNC's ``nc_files`` as Debian ships them (package
``linuxcnc-uspace`` 2.9.0~pre1+git20230208.f1270d6ed7-1+deb12u2, its 185 ``.ngc`` under
``usr/share/linuxcnc/ncfiles``; GPL-2.0). Fetch with the package client and lay them out by the manifest:

    apt-get download linuxcnc-uspace=2.9.0~pre1+git20230208.f1270d6ed7-1+deb12u2
    dpkg -x linuxcnc-uspace_*.deb ROOT
    python benchmarks/bench_program_corpus.py --from-package ROOT --corpus DIR --manifest \
        benchmarks/program_corpus/NC_FILES.csv --check

Counted (2026-12-02; before = main at the start of this work, after = this tree; the same manifest and tables):

| corpus | accepted | no motion | refused | crashed | silently wrong (``--check``) |
|---|---|---|---|---|---|
| NC_FILES.csv (185), before | 13 | 118 | 54 | 0 | - |
| NC_FILES.csv (185), after | 16 | 119 | 50 | 0 | 0 of 15 checked (13 mill, 2 lathe; max 0.49 um) |
| MANIFEST.csv (101), before | 40 | 25 | 36 | 0 | - |
| MANIFEST.csv (101), after | 42 | 25 | 34 | 0 | 0 of 34 checked (3 not checkable) |

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

HERE = Path(__file__).resolve().parents[1]
MANIFEST = HERE / "program_corpus" / "MANIFEST.csv"
STYLES = HERE / "nc_styles"
TOOL_LENGTH_MM = 100.0
TOOL_RADIUS_MM = 5.0
PART_ZERO_MM = {"mill-xyz": (300.0, 200.0, -300.0), "lathe-xzc": (0.0, 0.0, 200.0), "five-axis-ac": (0.0, 0.0, 40.0)}
"""Where the tables put every work system: a part zero inside the machine's strokes (mill: the middle of X
and Y, 100 mm above the bottom of Z's stroke; lathe: the spindle axis, the part's face 200 mm along the bed, so
that turning towards the chuck (Z < 0) stays inside Z's stroke; five-axis: on the C axis, 40 mm above the C
table top)."""


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
    msg = re.sub(r"^\s*line \d+(?: \(expanded as .*?\))?(?:, column \d+)?(?: of that)?(?: \(called from line \d+\))*: ",
                 "", msg.strip())
    msg = re.sub(r"^\s*line \d+: ", "", msg)
    return msg[:110]


def compensate_accepted(root: Path, corpus: Path, out: dict, tmp: Path, check: bool = False,
                        manifest: Path = MANIFEST) -> None:
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
                   "--tool-table", str(tmp / "tools.csv")])
        summary = dest / "compensate_summary.json"
        e = json.loads(summary.read_text())["files"][0] if rc == 0 and summary.is_file() else {}
        r["compensated"] = {"exit": rc, "true_max_um": e.get("true", {}).get("max_um"),
                            "uncompensated_max_um": e.get("true_uncompensated", {}).get("max_um"),
                            "points": e.get("points")}
        if check and rc == 0 and m["machine"] == "mill-xyz":
            r["check"] = independent_check(corpus / r["file"], dest / r["file"], m["dialect"], truths["mill-xyz"])
        elif check and rc == 0 and m["machine"] == "lathe-xzc":
            r["check"] = lathe_check(corpus / r["file"], dest / r["file"], m["dialect"], truths["lathe-xzc"])


def independent_check(src: Path, written: Path, dialect: str, truth_file: Path) -> str:
    """``--check``: the written program run as the shop would, judged independently of the reader's frames:
    frames (work offset, tool length) per line from the program's own G54-G59 / G54.1 P / G154 P / G43 H /
    G49 words read by patterns (tests/program_checks.py ``_frame``; the controller's power-on G54 before any),
    the same for the written program. Passes when (1) the lines that are not compensated moves are the
    source's, byte for byte and in order, and (2) every programmed end point of a compensated move is reached,
    in order, by the TRUE machine at the end of some written move within 1 um. ``"ok: max E um at N points"``,
    ``"WRONG: ..."`` (silently wrong) or ``"not checkable: ..."``. A program the reader expanded (subprograms,
    macros: a flat program is written) is judged against the reader's flat program."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from program_checks import TOL_POINT_UM, _frame
    from compensation.gcode import AxisWords, parse_program
    from compensation.nc_state import machine_with_tool
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    mill = load_machine("mill-xyz")
    zero = PART_ZERO_MM["mill-xyz"]
    systems = ["G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"]
    systems += [f"G54.1P{n}" for n in range(1, 49)] + [f"G154P{n}" for n in range(1, 100)]
    systems += [f"G{n}" for n in range(110, 130)]
    offsets, tools = {s: zero for s in systems}, {n: TOOL_LENGTH_MM for n in range(1, 100)}
    aw, dia = AxisWords.of(mill), None if dialect == "auto" else dialect
    try:  # a program with canned cycles is read by compensate's cycle reader, not this plain parse
        expanded = parse_program(src, axis_words=aw, dialect=dialect).expanded
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        return f"not checkable: {type(exc).__name__}: {exc}"[:110]
    out = written.read_text(encoding="latin-1").splitlines(keepends=True)
    out = [ln for ln in out if not ln.startswith("(volcomp:")]  # the writer's header (after a leading '%' too)
    bare = written.with_suffix(written.suffix + ".bare")
    bare.write_text("".join(out), encoding="latin-1")
    if expanded is not None:
        src = written.with_suffix(written.suffix + ".flat")
        src.write_text(expanded.text, encoding="latin-1")
    try:
        p_src, p_out = (parse_program(f, axis_words=aw, fast=False, dialect=dia) for f in (src, bare))
        f_src, f_out = (_frame(p.lines, offsets, tools, "G54") for p in (p_src, p_out))
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        return f"not checkable: {type(exc).__name__}: {exc}"[:110]
    m_src = [m for m in p_src.moves if m.compensate]
    m_out = [m for m in p_out.moves if m.compensate]
    keep_src = [ln for i, ln in enumerate(p_src.lines) if i not in {m.index for m in m_src}]
    keep_out = [ln for i, ln in enumerate(p_out.lines) if i not in {m.index for m in m_out}]
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

    errs, j = [], 0
    for m in m_src:
        q, (mt, _) = placed(m, f_src)
        target = mt.nominal(q[None])[0]
        while j < len(m_out):
            qo, (mto, truth) = placed(m_out[j], f_out)
            j += 1
            e_um = np.linalg.norm(mto.nominal(qo[None])[0] + truth.predict(qo[None])[0] * 1e-3 - target) * 1e3
            if e_um <= TOL_POINT_UM:
                errs.append(e_um)
                break
        else:
            return f"WRONG: line {m.index + 1} ({p_src.lines[m.index].strip()[:40]!r}) reached by no written move"
    return f"ok: max {max(errs):.3g} um at {len(errs)} points" if errs else "not checkable: no compensated move"


def lathe_check(src: Path, written: Path, dialect: str, truth_file: Path) -> str:
    """``--check`` of a ``lathe-xzc`` program in turning mode, independently of the reader's frames: the part zero
    of the count's tables (:data:`PART_ZERO_MM`, every system), the lines that are not compensated moves the
    source's byte for byte, and every programmed end point (radius, Z) reached, in order, by some written move:
    the TRUE tool tip averaged over one turn of the spindle on the programmed surface of revolution within 1 um
    (``compensation.turning.surface_residual_um``). A program with C words is not checked here."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from program_checks import TOL_POINT_UM
    from compensation.turning import parse_lathe_program, surface_residual_um
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    lathe, zero = load_machine("lathe-xzc"), PART_ZERO_MM["lathe-xzc"]
    out = [ln for ln in written.read_text(encoding="latin-1").splitlines(keepends=True) if not ln.startswith("(volcomp:")]
    bare = written.with_suffix(written.suffix + ".bare")
    bare.write_text("".join(out), encoding="latin-1")
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
    field = ChainField(lathe, ChainElementSet.load(truth_file, lathe))
    place = lambda e: np.array([[e[0] + zero[0], e[1] + zero[2], 0.0]])  # noqa: E731 - X radius, Z, C
    errs, j = [], 0
    for m in m_src:
        while j < len(m_out):
            mean, _ = surface_residual_um(field, lathe, place(m_out[j].end), place(m.end))
            j += 1
            if np.linalg.norm(mean[0]) <= TOL_POINT_UM:
                errs.append(float(np.linalg.norm(mean[0])))
                break
        else:
            return f"WRONG: line {m.index + 1} reached by no written move"
    return f"ok: max {max(errs):.3g} um at {len(errs)} points" if errs else "not checkable: no compensated move"


def count(root: Path, corpus: Path, compensate: bool = False, check: bool = False, manifest: Path = MANIFEST) -> dict:
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
            s = CompensateSettings("exact", "", Path(tmp), dialect=r["dialect"], work_offsets=offsets, tool_table=tools)
            try:
                read_tool_path(p, machines[r["machine"]], s)
                results.append((r, "accepted", ""))
            except (InputError, UsageError) as exc:
                why = reason_of(str(exc), p.name)
                results.append((r, "no motion" if why.startswith(NO_MOTION) else "refused", why))
            except Exception as exc:  # noqa: BLE001 - a crash is what this counts
                results.append((r, "crashed", f"{type(exc).__name__}: {exc}"[:110]))
        out["results"] = [{"file": r["file"], "kind": r["kind"], "outcome": o, "reason": why} for r, o, why in results]
        if compensate:
            compensate_accepted(root, corpus, out, Path(tmp), check, manifest)
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
DATA = ("`benchmarks/nc_styles/` (14 programs in LinuxCNC's and Fanuc shops' styles) and, where fetched "
        "(`$VOLCOMP_PROGRAM_CORPUS`), the 101 public programs of `benchmarks/program_corpus/MANIFEST.csv`; a "
        "1,000,000-line 3-axis program (quick: 20,000 lines)")


def style_counts() -> Counter:
    from compensation.gcode import AxisWords, parse_program
    from errormap.io import InputError
    from errormap.machine import load_machine
    ax, out = AxisWords.of(load_machine("mill-xyz")), Counter()
    for p in sorted(STYLES.iterdir()):
        try:
            parse_program(p, axis_words=ax)
            out["accepted"] += 1
        except InputError:
            out["refused"] += 1
        except Exception:  # noqa: BLE001 - a crash is what this counts
            out["crashed"] += 1
    return out


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
    st = style_counts()
    n_lines = 20_000 if quick else 1_000_000
    figs = [{"what": "shop-style programs accepted", "value": f"{st['accepted']}/{sum(st.values())}", "unit": "",
             "residual": "none", "anchor": "crashed (any exception but a refusal)", "anchor_value": st["crashed"]}]
    corpus = os.environ.get("VOLCOMP_PROGRAM_CORPUS")
    notes = []
    if corpus and Path(corpus).is_dir():
        res = count(HERE.parent, Path(corpus))["results"]
        c = Counter(r["outcome"] for r in res)
        figs.append({"what": "public programs accepted", "value": f"{c['accepted']}/{len(res)}", "unit": "",
                     "residual": "none", "anchor": "crashed", "anchor_value": c["crashed"]})
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
    a = ap.parse_args()
    if a.from_package:
        lay_out(Path(a.from_package), Path(a.corpus), Path(a.manifest))
    result = count(Path(a.root).resolve(), Path(a.corpus), a.compensate or a.check, a.check, Path(a.manifest))
    print(report(result))
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1))
