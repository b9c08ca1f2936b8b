"""The rotary built-in machines (errormap/machines/mill-xyza.toml: a vertical mill with a 4th-axis A table;
hmc-xyzb.toml: a horizontal machining centre with a B table; five-axis-bc.toml: a B/C trunnion 5-axis machine):
each file read as written (axes, strokes, sides, the machines listing), and a program written for this project
in the manner of the controllers' manuals (Haas 4th-axis indexing and a wrapped move; a Fanuc horizontal
machine indexing B between work systems; a Haas UMC 3+2 cut and G93 simultaneous B/C moves; TCP programs: Haas
G234 on the B/C trunnion, Fanuc G43.4 on the 4th axis)
compensated on it and judged independently of the reader: frames from the program's own G54-G56 / G43 H words
(tests/program_checks.py ``_frame``), every line that is not a compensated move byte-identical, every programmed
end point reached by the TRUE machine at some written move within 1 μm (in order), the rotary words kept as
programmed and every linear correction inside the solver's ball, and G93 block times kept."""
import csv
import json
import os
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from benchmarks.suite.gcode_corpus import MANIFEST, SAMPLES, sample_of
from compensation.app.cli import main
from compensation.chain_gcode import parse_chain_program
from compensation.nc_state import machine_with_tool
from compensation.solvers.base import BALL_RADIUS_UM
from compensation.tcp_orientation import ORIENT_ROTARY_LIMIT_DEG
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import builtin_machines, load_machine
from program_checks import TOL_POINT_UM, _frame

MACHINES_DIR = Path(__file__).resolve().parents[1] / "errormap" / "machines"
ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), as the corpus count (benchmarks/suite/gcode_corpus.py)."""
TRUTH_SEED = 101
TOOL_MM = 100.0
"""Tool 1's length in the tool table (the corpus count's)."""
ROTARY_KEPT_DEG = 1e-6
"""The rotary words are kept as programmed: written back to their 6 decimals of a degree."""
G93_TIME_REL = 1e-5
"""A G93 block's time (1/F minutes) kept over its split pieces: F is written to 6 decimals
(compensation/tcp.py INVERSE_TIME_DECIMALS), so each piece's time is exact to < 5e-7 relative."""

AXES = {"mill-xyza": ("XYZA", "A", "work"), "hmc-xyzb": ("XYZB", "B", "work"), "five-axis-bc": ("XYZBC", "BC", "work")}
"""Per built-in: its axis words, its rotary words and the side the rotary axes are on."""

PROGRAMS = {
    # Haas 4th axis (HRT on a VF mill): index with the brake released (M11 G00 A.. M10), cut 3-axis faces, then a
    # wrapped move that turns A while X and Z feed; Y and Z zero on the A axis line.
    "mill-xyza": ("haas", {"G54": (300.0, 200.0, -425.0)}, """%
O01000 (4TH AXIS: INDEXED FACES THEN A WRAPPED MOVE)
T1 M06
G00 G17 G21 G40 G49 G80 G90
G54 G00 X0. Y0. A0.
S2000 M03
G43 H01 Z50.
M11
G00 A90.
M10
G00 X10. Y5.
Z27.
G01 Z23. F200.
X60.
Y-5.
X10.
G00 Z50.
M11
G00 A180.
M10
G00 X10. Y0.
Z27.
G01 Z22.5 F150.
X70.
G00 Z50.
M11
G00 A0.
G01 X20. Z23. F300.
G01 X40. A90.
G01 X60. A180.
G00 Z50.
M05
M30
%
"""),
    # Fanuc horizontal machining centre: one work system per face (G54 B0, G55 B90, G56 B180), the table clamped
    # (M10) while cutting; a pocket outline, an arc, a plunge.
    "hmc-xyzb": ("fanuc", {"G54": (0.0, 150.0, -650.0), "G55": (0.0, 150.0, -650.0), "G56": (0.0, 150.0, -650.0)},
                 """%
O02000 (HMC: FACES BY B INDEX)
T1 M06
G00 G17 G21 G40 G49 G80 G90
G54 G00 B0. X-40. Y20.
S3000 M03
G43 H01 Z20.
G01 Z-3. F250.
X40.
Y60.
X-40.
G00 Z50.
M11
G55 G00 B90.
M10
G00 X-30. Y30.
Z5.
G01 Z-2. F250.
G02 X30. R30.
G00 Z50.
M11
G56 G00 B180.
M10
G00 X0. Y40.
G01 Z-5. F100.
G00 Z50.
M05
M30
%
"""),
    # Haas UMC (B/C trunnion): a 3+2 cut at B30 C45, then simultaneous B/C moves in inverse time (G93: every block
    # its own F, the time of the block in 1/F minutes).
    "five-axis-bc": ("haas", {"G54": (0.0, 0.0, -460.0)}, """%
O03000 (B/C TRUNNION: 3+2 CUT, THEN SIMULTANEOUS B C IN G93)
T1 M06
G00 G17 G21 G40 G49 G80 G90
G54 G00 B0. C0. X0. Y0.
S8000 M03
G43 H01 Z60.
G00 B30. C45.
G00 X-20. Y-10.
Z5.
G01 Z-1. F400.
X20.
Y10.
X-20.
G00 Z60.
G00 B0. C0.
G00 X30. Y0. Z10.
G93 G01 X28. Y5. Z9. B10. C20. F60.
X25. Y10. Z8. B20. C40. F60.
X20. Y14. Z7. B30. C60. F45.
G94 G00 Z60.
M05
M30
%
"""),
}


@pytest.mark.parametrize("name", sorted(AXES))
def test_the_machine_file_is_read_as_written(name):
    """Axes, strokes and sides as the TOML states them (read here directly); a rotary stroke wide enough for
    its programs (the B/C trunnion's tilt is the UMC's -35..110 deg); the machine listed by ``volcomp machines``."""
    doc = tomllib.loads((MACHINES_DIR / f"{name}.toml").read_text(encoding="utf-8"))
    mt = load_machine(name)
    words, rotary, side = AXES[name]
    assert "".join(a.word for a in mt.axes) == words and mt.name == name == doc["machine"]["name"]
    joints = {d["axis"]: d for d in doc["work"] + doc["tool"] if "joint" in d}
    for a in mt.axes:
        assert a.stroke == tuple(joints[a.word]["stroke"]) and a.kind == joints[a.word]["joint"]
        assert (a.side == side) if a.word in rotary else a.kind == "linear"
    assert name in builtin_machines()
    # 6 component errors per axis, 4 location errors per rotary axis, 3 squareness constants
    assert len(mt.slot_names) == 6 * len(words) + 4 * len(rotary) + 3


def _write_tables(tmp_path, offsets):
    off = tmp_path / "offsets.csv"
    off.write_text("system,x_mm,y_mm,z_mm\n" + "".join(f"{s},{x},{y},{z}\n" for s, (x, y, z) in offsets.items()))
    tools = tmp_path / "tools.csv"
    tools.write_text(f"tool,length_mm,radius_mm\n1,{TOOL_MM},5\n")
    return off, tools


def _compensate(tmp_path, name, text, dialect, offsets, extra=()):
    mt = load_machine(name)
    truth = ChainElementSet.random(mt, TRUTH_SEED, ELEMENT_SCALE_UM, 11).save(tmp_path / "truth.json")
    prog = tmp_path / f"{name}.nc"
    prog.write_text(text, encoding="ascii")
    off, tools = _write_tables(tmp_path, offsets)
    out = tmp_path / "out"
    assert main(["compensate", str(prog), "--machine", name, "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(out), "--dialect", dialect, "--work-offsets", str(off),
                 "--tool-table", str(tools), *extra]) == 0
    summary = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    return mt, truth, prog, out / prog.name, summary


def _placed(mt, move, frame, fields, truth_els):
    """Machine axes of a move's end (offset on X Y Z, the tool length on Z) and the machine at its tool."""
    off, tool = frame[move.index]
    q = move.end.copy()
    q[:3] += off + [0.0, 0.0, tool if tool is not None else 0.0]
    if tool not in fields:
        at = machine_with_tool(mt, tool) if tool is not None else mt
        fields[tool] = (at, ChainField(at, truth_els))
    return q, fields[tool]


@pytest.mark.parametrize("name", sorted(PROGRAMS))
def test_a_manual_style_program_is_compensated_on_the_rotary_machine(tmp_path, name):
    dialect, offsets, text = PROGRAMS[name]
    mt, truth_file, prog, written, summary = _compensate(tmp_path, name, text, dialect, offsets)
    assert summary["true_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check below has teeth
    errs, blocks = _judge(name, mt, truth_file, prog, written)
    assert max(errs) <= TOL_POINT_UM
    assert blocks == (3 if name == "five-axis-bc" else 0)  # its three G93 blocks were split and checked


def test_the_check_sees_an_uncompensated_program(tmp_path):
    """The program itself as its 'compensated' output: its first cut is reached by no written move."""
    dialect, offsets, text = PROGRAMS["mill-xyza"]
    mt, truth_file, prog, _, _ = _compensate(tmp_path, "mill-xyza", text, dialect, offsets)
    with pytest.raises(AssertionError, match="line 13 .* reached by no written move"):
        _judge("mill-xyza", mt, truth_file, prog, prog)


def _judge(name, mt, truth_file, prog, written):
    """The independent check (module docstring): (errors μm per programmed end point, G93 blocks split and
    checked); an AssertionError names what failed."""
    dialect, offsets, _ = PROGRAMS[name]
    words, rotary, _ = AXES[name]
    p_src, p_out = (parse_chain_program(f, mt, dialect=dialect) for f in (prog, written))
    tables = {s: np.asarray(v) for s, v in offsets.items()}
    f_src, f_out = (_frame(p.lines, tables, {1: TOOL_MM}, "G54") for p in (p_src, p_out))
    m_src = [m for m in p_src.moves if m.compensate]
    m_out = [m for m in p_out.moves if m.compensate]
    assert m_src and {m.kind for m in p_src.moves if not m.compensate} <= {"rapid"}  # every feed compensated
    out_lines = [ln for ln in p_out.lines if not ln.startswith("(volcomp:")]
    keep_src = [ln for i, ln in enumerate(p_src.lines) if i not in {m.index for m in m_src}]
    keep_out = [ln for i, ln in enumerate(p_out.lines) if i not in {m.index for m in m_out} and ln in out_lines]
    assert keep_src == keep_out  # every line that is not a compensated move, byte for byte and in order
    truth_els, fields = ChainElementSet.load(truth_file, mt), {}
    jrot = [words.index(w) for w in rotary]
    g93, j, errs, blocks = _inverse_time(p_src.lines), 0, [], 0
    for m in m_src:
        q, (at, _) = _placed(mt, m, f_src, fields, truth_els)
        target = at.nominal(q[None])[0]
        first = j
        while j < len(m_out):
            qo, (ato, tf) = _placed(mt, m_out[j], f_out, fields, truth_els)
            j += 1
            e_um = np.linalg.norm(ato.nominal(qo[None])[0] + tf.predict(qo[None])[0] * 1e-3 - target) * 1e3
            if e_um <= TOL_POINT_UM:
                errs.append(e_um)
                assert np.abs(qo[jrot] - q[jrot]).max() <= ROTARY_KEPT_DEG  # the rotary words as programmed
                assert np.linalg.norm(qo[:3] - q[:3]) * 1e3 <= BALL_RADIUS_UM  # the linear correction in the ball
                if g93[m.index]:  # the block's time kept over its pieces
                    pieces = [p_out.lines[k.index] for k in m_out[first:j]]
                    t_src = _block_minutes([p_src.lines[m.index]])
                    assert abs(_block_minutes(pieces) - t_src) <= G93_TIME_REL * t_src
                    blocks += len(pieces) > 1
                break
        else:
            raise AssertionError(f"{name}: line {m.index + 1} ({p_src.lines[m.index].strip()!r}) reached by no "
                                 "written move")
    return errs, blocks


def _inverse_time(lines):
    """Per line, whether G93 (inverse-time feed) is in force there, read by pattern (G93 / G94 are modal)."""
    on, out = False, []
    for ln in lines:
        for g in re.findall(r"G9([34])(?![.\d])", re.sub(r"\(.*?\)", "", ln)):
            on = g == "3"
        out.append(on)
    return out


def _block_minutes(lines):
    """Minutes of G93 blocks: 1/F of each line (every G93 block carries its F)."""
    return sum(1.0 / float(re.search(r"F([\d.]+)", ln).group(1)) for ln in lines)


TCP_CASES = {
    # Haas UMC: TCPC (G234 Hn), the tip in the workpiece frame; its work offset: 50 mm above the C table top
    "five-axis-bc": ("haas", (0.0, 0.0, 50.0), """%
O03001 (B/C TRUNNION IN TCP: G234, THE TIP IN THE WORKPIECE FRAME)
T1 M06
G00 G17 G21 G40 G49 G80 G90
G54 G00 B0. C0. X0. Y0.
S8000 M03
G234 H01
G00 X30. Y0. Z10. B0. C0.
G01 X28. Y5. Z9. B10. C20. F300.
X25. Y10. Z8. B20. C40.
G49
G00 X0. Y0. Z-100. B0. C0.
M30
%
"""),
    # Fanuc 4th axis: G43.4 (tool-centre-point control) with A; the work offset on the A axis line
    "mill-xyza": ("fanuc", (0.0, 0.0, 0.0), """%
O1002 (4TH AXIS IN TCP: G43.4)
T1 M06
G00 G17 G21 G40 G49 G80 G90
G54 G00 X0. Y0. A0.
G43.4 H01
G00 X10. Y0. Z40. A0.
G01 X20. Y0. Z25. A30. F300.
X40. Y5. Z24. A90.
G49
G00 X0. Y0. Z-200. A0.
M30
%
"""),
}
"""Per machine: (dialect, work offset G54 (mm: under TCP the part zero in the workpiece frame), program)."""


@pytest.mark.parametrize("name", sorted(TCP_CASES))
def test_a_tcp_program_is_compensated_on_the_rotary_machine(tmp_path, name):
    """A TCP program (Haas G234 on five-axis-bc, Fanuc G43.4 on mill-xyza): the written tip, placed by the chain's
    nominal inverse (solved here: the tip is affine in X Y Z at fixed rotary axes), is where the TRUE machine puts
    the programmed tip, within 1 μm; the rotary words kept."""
    dialect, zero, text = TCP_CASES[name]
    mt, truth_file, prog, written, _ = _compensate(tmp_path, name, text, dialect, {"G54": zero})
    rotary = AXES[name][1]
    at = machine_with_tool(mt, TOOL_MM)
    truth = ChainField(at, ChainElementSet.load(truth_file, mt))
    src, out = prog.read_text().splitlines(), written.read_text().splitlines()
    on = [i for i, ln in enumerate(src) if ln.startswith(("G01", "X"))]
    tips = _words_modal(src[:on[0]])  # the modal tip and rotary words, as programmed
    start = out.index(src[on[0] - 1]) + 1  # the lines before the first TCP feed are the source's
    modal, k, checked, unc = _words_modal(out[:start]), start, 0, []
    for i in on:
        tips.update(_words(src[i]))
        target = np.array([tips[w] for w in "XYZ"]) + zero
        rot = [tips[w] for w in rotary]
        while k < len(out):  # the written piece that ends this block: its rotary words reach the block's
            modal.update(_words(out[k]))
            k += 1
            if max(abs(modal[w] - r) for w, r in zip(rotary, rot)) <= ROTARY_KEPT_DEG:
                break
        else:
            pytest.fail(f"line {i + 1}: no written piece ends at {rotary} {rot}")
        q = _nominal_inverse(at, np.array([modal[w] for w in "XYZ"]) + zero, rot)
        tip_um = (at.nominal(q[None])[0] + truth.predict(q[None])[0] * 1e-3 - target) * 1e3
        assert np.linalg.norm(tip_um) <= TOL_POINT_UM
        q0 = _nominal_inverse(at, target, rot)  # the block as programmed: the check has teeth
        unc.append(np.linalg.norm(at.nominal(q0[None])[0] + truth.predict(q0[None])[0] * 1e-3 - target) * 1e3)
        checked += 1
    assert checked == 2 and max(unc) > 10 * TOL_POINT_UM


ORIENT_URAD = 0.1
"""The TRUE tool axis after compensation within 0.1 μrad of the programmed one, as on five-axis-ac
(tests/test_tcp.py ORIENT_TRUE_URAD: with the truth as the model the orientation solve converges to 0.01 μrad;
the written 6 decimals of a degree are 0.02 μrad); the truth's own rotary errors tilt it by 14–20 μrad here."""
PROBE_MM = 10.0
"""The tool axis is read as the line between the tool point and a point 10 mm further up the tool."""


def test_tcp_with_orientation_turns_the_b_c_trunnion(tmp_path):
    """``--compensate-orientation`` on five-axis-bc: B and C are corrected too; at every block end the TRUE tool
    tip is the programmed one within 1 μm and the TRUE tool axis the programmed (nominal) one within 0.1 μrad, the
    rotary corrections inside the orientation solve's limit (compensation/tcp_orientation.py
    ORIENT_ROTARY_LIMIT_DEG)."""
    dialect, zero, text = TCP_CASES["five-axis-bc"]
    mt, truth_file, prog, written, _ = _compensate(tmp_path, "five-axis-bc", text, dialect, {"G54": zero},
                                                   ("--compensate-orientation",))
    els = ChainElementSet.load(truth_file, mt)
    at, up = (machine_with_tool(mt, TOOL_MM + d) for d in (0.0, PROBE_MM))
    f_at, f_up = ChainField(at, els), ChainField(up, els)

    def tool(q, true=True):  # (tip, unit tool axis) at axes q, TRUE or nominal
        tip, top = at.nominal(q[None])[0], up.nominal(q[None])[0]
        if true:
            tip, top = tip + f_at.predict(q[None])[0] * 1e-3, top + f_up.predict(q[None])[0] * 1e-3
        return tip, (top - tip) / np.linalg.norm(top - tip)

    src, out = prog.read_text().splitlines(), written.read_text().splitlines()
    on = [i for i, ln in enumerate(src) if ln.startswith(("G01", "X"))]
    tips = _words_modal(src[:on[0]])
    k = out.index(src[on[0] - 1]) + 1
    modal, checked, unc = _words_modal(out[:k]), 0, []
    for i in on:
        tips.update(_words(src[i]))
        target, rot = np.array([tips[w] for w in "XYZ"]) + zero, [tips["B"], tips["C"]]
        while k < len(out):  # the written piece that ends this block: its tip within 0.1 mm of the block's
            modal.update(_words(out[k]))
            k += 1
            if np.abs(np.array([modal[w] for w in "XYZ"]) + zero - target).max() < 0.1:
                break
        else:
            pytest.fail(f"line {i + 1}: no written piece ends at its tip")
        wrot = [modal["B"], modal["C"]]
        assert 0 < max(abs(a - b) for a, b in zip(wrot, rot)) <= ORIENT_ROTARY_LIMIT_DEG  # B, C corrected
        q = _nominal_inverse(at, np.array([modal[w] for w in "XYZ"]) + zero, wrot)
        q0 = _nominal_inverse(at, target, rot)
        _, axis_nominal = tool(q0, true=False)
        tip, axis = tool(q)
        assert np.linalg.norm(tip - target) * 1e3 <= TOL_POINT_UM
        assert np.arccos(min(1.0, axis @ axis_nominal)) * 1e6 <= ORIENT_URAD
        unc.append(np.arccos(min(1.0, tool(q0)[1] @ axis_nominal)) * 1e6)  # as programmed: the check has teeth
        checked += 1
    assert checked == 2 and max(unc) > 100 * ORIENT_URAD


def _words(line):
    return {m.group(1): float(m.group(2)) for m in re.finditer(r"([XYZABC])(-?[\d.]+)", re.sub(r"\(.*?\)", "", line))}


def _words_modal(lines):
    """The modal axis words after ``lines``."""
    out = {}
    for ln in lines:
        out.update(_words(ln))
    return out


def _nominal_inverse(mt, tip_mm, rot_deg):
    """Machine axes (3 + r,) whose nominal tool point is ``tip_mm`` at the rotary positions ``rot_deg`` (r,): the
    tool point is affine in the linear axes at fixed rotary axes, so four evaluations give it exactly."""
    base = np.array([[0.0, 0.0, 0.0, *rot_deg]])
    unit = base + np.hstack([np.eye(3), np.zeros((3, len(rot_deg)))])
    p0 = mt.nominal(base)[0]
    lin = np.linalg.solve((mt.nominal(unit) - p0).T, tip_mm - p0)
    return np.array([*lin, *rot_deg])


ROTARY_SAMPLE = "blind sample rotary"
"""The 4/5-axis blind sample's mark (benchmarks/suite/gcode_corpus.py SAMPLES; program_corpus/README.md)."""
MACHINE_OF_AXES = {"A": "mill-xyza", "B": "hmc-xyzb", "AC": "five-axis-ac", "BC": "five-axis-bc"}
"""The built-in whose rotary axes are a program's rotary words."""


def test_the_rotary_rows_run_on_the_built_in_of_their_axis_words():
    """MANIFEST.csv's 4/5-axis rows (the sample's among them, from fresh repositories) name a built-in with as many
    rotary axes as their kind, the sample is reported apart, and where the corpus is on this machine
    (``$VOLCOMP_PROGRAM_CORPUS``) each program's rotary words, read here by pattern, are that machine's axes."""
    rows = list(csv.DictReader(MANIFEST.open(encoding="utf-8")))
    rotary = [r for r in rows if r["kind"] in ("4-axis", "5-axis")]
    sample = [r for r in rotary if sample_of(r["licence"]) == ROTARY_SAMPLE]
    assert ROTARY_SAMPLE in SAMPLES and sample
    rest = {r["repository"] for r in rows if sample_of(r["licence"]) != ROTARY_SAMPLE}
    assert not {r["repository"] for r in sample} & rest  # fresh repositories only
    corpus = os.environ.get("VOLCOMP_PROGRAM_CORPUS")
    for r in rotary:
        mt = load_machine(r["machine"])
        words = "".join(a.word for a in mt.axes if a.kind == "rotary")
        assert MACHINE_OF_AXES[words] == r["machine"] and len(words) == int(r["kind"][0]) - 3, r["file"]
        if corpus and (Path(corpus) / r["file"]).is_file():
            text = re.sub(r"\([^)\n]*\)|;[^\n]*", "", (Path(corpus) / r["file"]).read_text(encoding="latin-1"))
            used = {w.upper() for w in re.findall(r"(?i)(?<![A-Z])([ABC])\s*[-+.\d#\[]", text)}
            assert "".join(sorted(used)) == words, r["file"]


def test_haas_dynamic_work_offset_is_refused_by_name(tmp_path):
    """G254 (Haas DWO: the work offset turned with B/C by the control's own settings) is refused naming the line,
    column and word and what to post instead; the trunnion's brake codes M10-M13 pass on five-axis-bc whatever the
    dialect (its [controller] table)."""
    text = "\n".join(["%", "O1004 (UMC 3+2 WITH DWO)", "T1 M06", "G00 G17 G21 G40 G49 G80 G90", "G54 G00 B0. C0.",
                      "M12", "M10", "G00 B30. C45.", "M11", "M13", "G254", "G00 X0. Y0.", "G43 H01 Z50.",
                      "G01 Z-1. F300.", "G00 Z50.", "G255", "M30", "%", ""])
    mt = load_machine("five-axis-bc")
    prog = tmp_path / "dwo.nc"
    prog.write_text(text)
    with pytest.raises(InputError, match=r"line 11, column 1: 'G254' \(Haas dynamic work offset .*TCPC \(G234\)"):
        parse_chain_program(prog, mt, dialect="fanuc")
    prog.write_text(text.replace("G254\n", "").replace("G255\n", ""))
    assert parse_chain_program(prog, mt, dialect="fanuc").moves
