"""Drilling canned cycles on a machine-tool chain (compensation/nc_cycles.py): the controller's moves
written out exactly as hand-expanded from the LinuxCNC manual; kept cycles compensated so that the TRUE
machine reaches every hole bottom (checked independently from the written numbers), with the tilt left
along the hole reported and seen at the R point; every other line byte-identical; what the controllers
do differently or what has no plain-move form refused by line and column with the option that reads it."""
import json
import re
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_cycles import cycle_pass, expand_cycles
from compensation.nc_state import machine_with_tool
from errormap.io import InputError
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from program_checks import TOL_POINT_UM, true_point_errors_um

DATA = Path(__file__).resolve().parent / "data" / "cycles"
OFFSETS = Path(__file__).resolve().parent / "data" / "controller" / "offsets.csv"
G55_MM = np.array([200.0, 100.0, -150.0])
"""The G55 row of offsets.csv (the test programs' part zero), read here independently of the reader."""
ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), as tests/test_work_offsets.py."""
TOL_TILT_UM = 0.01
"""The TRUE error at a kept cycle's written R point is the tilt (the XY correction it lacks) up to the
field's change over that correction: gradient (< 1e-3 μm/μm here) x tilt (< 30 μm) < 0.03 μm; observed < 1e-3."""


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture()
def truth_file(tmp_path, mill):
    return ChainElementSet.random(mill, 101, ELEMENT_SCALE_UM, 11).save(tmp_path / "truth.json")


def _compensate(prog, out, model, *extra):
    return main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(model), "--method", "exact",
                 "--out", str(out), "--work-offsets", str(OFFSETS), *extra])


def _z(v):
    return f"Z{v:.6f}"


def test_expanded_moves_equal_the_hand_expanded_list():
    exp = expand_cycles((DATA / "drill_incremental.ngc").read_text(), "p", "expand")
    a, b = exp.spans[5]  # line 6: G91 G99 G81 X10. Y0. Z-20. R-15. L3 F200. from Z-20: R -35, bottom -55
    def hole(x):
        return [f"G90 G0 X{x:.6f} Y10.000000", "G0 Z-35.000000", "G1 Z-55.000000 F200.", "G0 Z-35.000000"]
    assert [ln.rstrip("\n") for ln in exp.text.splitlines()[a:b]] == hole(20) + hole(30) + hole(40) + ["G91"]
    exp = expand_cycles((DATA / "drill_linuxcnc.ngc").read_text(), "p", "expand", dialect="linuxcnc")
    lines = exp.text.splitlines()
    g83 = ["G90 G0 X80.000000 Y20.000000", "G0 Z-40.000000"]  # R-40 Q6 Z-75, G98: back to Z-20
    for k, d in enumerate((-46, -52, -58, -64, -70)):
        g83 += [f"G1 {_z(d)}" + (" F150." if k == 0 else ""), "G0 Z-40.000000", f"G0 {_z(d + 0.254)}"]
    g83 += ["G1 Z-75.000000", "G0 Z-20.000000"]
    assert lines[slice(*exp.spans[14])] == [g83[0].replace("G90", "N30 G90")] + g83[1:]
    g73 = ["G90 G0 X100.000000 Y20.000000", "G0 Z-41.000000"]  # R-41 Q4 Z-62: chip breaks of 0.254 mm
    for k, d in enumerate((-45, -49, -53, -57, -61)):
        g73 += [f"G1 {_z(d)}" + (" F150." if k == 0 else ""), f"G0 {_z(d + 0.254)}"]
    assert lines[slice(*exp.spans[15])] == g73 + ["G1 Z-62.000000", "G0 Z-20.000000"]
    assert lines[slice(*exp.spans[16])] == ["G90 G0 X120.000000 Y30.000000", "G0 Z-40.000000",  # G85: feed out to R
                                            "G1 Z-66.000000 F100.", "G1 Z-40.000000", "G0 Z-20.000000"]
    assert lines[slice(*exp.spans[17])] == ["G90 G0 X140.000000 Y30.000000", "G0 Z-40.000000",  # G89: dwell, feed out
                                            "G1 Z-68.000000 F100.", "G4 P1.", "G1 Z-20.000000"]
    assert lines[slice(*exp.spans[11])] == ["N20 G90 G0 X60.000000 Y40.000000", "G0 Z-42.000000",  # G99 G82
                                            "G1 Z-70.000000 F200.", "G4 P0.5", "G0 Z-42.000000"]


def test_incremental_r_is_measured_from_the_series_initial_level():
    exp = expand_cycles("G0 X0 Y0 Z10\nG91 G99 G81 X5 R-5 Z-3 F100\nX5\n", "p", "expand")
    lines = exp.text.splitlines()  # initial level 10 on both lines (not the R plane the first hole left at)
    hole = ["G0 Z5.000000", "G1 Z2.000000 F100", "G0 Z5.000000", "G91"]
    assert lines[slice(*exp.spans[1])] == ["G90 G0 X5.000000 Y0.000000"] + hole
    assert lines[slice(*exp.spans[2])] == ["G90 G0 X10.000000 Y0.000000"] + hole


def _cycle_words(line):
    return {a: float(v) for a, v in re.findall(r"([XYZR])(-?[\d.]+)", re.sub(r"\(.*?\)", "", line))}


def test_kept_cycles_reach_every_hole_bottom_on_the_true_machine(tmp_path, mill, truth_file):
    prog = DATA / "drill_linuxcnc.ngc"
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file)) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    cyc = e["cycles"]
    assert cyc["mode"] == "keep" and cyc["holes"] == 8 and cyc["true_bottom"]["max_um"] < TOL_POINT_UM
    src = prog.read_text().splitlines()
    dst = [ln for ln in (out / prog.name).read_text().splitlines() if not ln.startswith("(volcomp:")]
    assert len(dst) == len(src)
    truth = ChainField(mill, ChainElementSet.load(truth_file, mill))
    state, errs = {}, []
    for i, (s, d) in enumerate(zip(src, dst)):
        if not re.search(r"G8[1-9]|G73|^[XY]", re.sub(r"\(.*?\)", "", s)):
            assert d == s  # every non-cycle line byte-identical
            continue
        state.update(_cycle_words(s))  # the programmed hole (Z, R sticky)
        w = _cycle_words(d)  # the written hole, run as the shop would (+ G55)
        assert set(w) == set("XYZR")
        run_b = np.array([w["X"], w["Y"], w["Z"]]) + G55_MM
        run_r = np.array([w["X"], w["Y"], w["R"]]) + G55_MM
        tgt_b = np.array([state["X"], state["Y"], state["Z"]]) + G55_MM
        tgt_r = np.array([state["X"], state["Y"], state["R"]]) + G55_MM
        tip = lambda q: mill.nominal(q[None])[0] * 1e3 + truth.predict(q[None])[0]  # noqa: E731
        errs.append(np.linalg.norm(tip(run_b) - mill.nominal(tgt_b[None])[0] * 1e3))
        at_r = np.linalg.norm(tip(run_r) - mill.nominal(tgt_r[None])[0] * 1e3)
        assert abs(at_r - cyc["tilt_um"][str(i + 1)]) < TOL_TILT_UM
    assert len(errs) == 8 and max(errs) < TOL_POINT_UM
    assert cyc["true_bottom_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check has teeth


def test_expanded_cycles_are_compensated_point_by_point(tmp_path, mill, truth_file):
    prog = DATA / "drill_linuxcnc.ngc"
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file), "--expand-cycles",
                       "--dialect", "linuxcnc") == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["cycles"] == {"mode": "expand", "holes": 8} and e["true"]["max_um"] < TOL_POINT_UM
    flat = tmp_path / "flat.ngc"  # the hand-checked expansion, then the written program without its header
    flat.write_text(expand_cycles(prog.read_text(), "p", "expand", dialect="linuxcnc").text)
    written = tmp_path / "written.ngc"
    written.write_text("".join(ln for ln in (out / prog.name).read_text().splitlines(keepends=True)
                               if not ln.startswith("(volcomp:")))
    errs = true_point_errors_um(flat, written, mill, ChainElementSet.load(truth_file, mill),
                                {"G55": G55_MM}, {})
    n_moves = sum(1 for m in parse_program(flat, axis_words=AxisWords.of(mill)).moves if m.compensate)
    # feeds: G81 3 holes x 1, G82 1, G83 5 pecks + 1, G73 5 + 1, G85 in and out 2, G89 2
    assert len(errs) == n_moves == 20 and errs.max() < TOL_POINT_UM


REFUSED = [  # program lines, mode, dialect, (line, column), words of the reason
    ("G0 X0 Y0 Z5\nG83 X1 Z-9 R1 Q2\n", "expand", None, (2, 1), "--dialect linuxcnc"),
    ("G0 X0 Y0 Z5\nG84 X1 Z-9 R1\n", "expand", "linuxcnc", (2, 1), "leave --expand-cycles out"),
    ("G0 X0 Y0 Z5\nG81 X1 R1\n", "keep", None, (2, 1), "without Z"),
    ("G0 X0 Y0 Z5\nG28\nG81 X1 Z-1 R1\n", "keep", None, (3, 1), "not known after G28"),
    ("G0 X0 Y0 Z0\nG81 X1 Z-3 R1\n", "keep", None, (2, 1), "below R"),
    ("G0 X0 Y0 Z5\nG99 G81 X1 Z-3 R1\nG98 X2\n", "keep", None, (3, 1), "G98 after a G99"),
    ("G0 X0 Y0 Z5\nG18\nG81 X1 Z-3 R1\n", "keep", None, (3, 1), "only G17"),
    ("G0 X0 Y0 Z5\nG81 X1 Z-3 R1 G43 H1\n", "keep", None, (2, 15), "'G43' on a canned-cycle line"),
    ("G0 X0 Y0 Z5\nG81 X1 Z-3 R1 F9\nG82 X2 P1\n", "keep", None, (3, 1), "G82 after G81 without Z R"),
    ("G0 X0 Y0 Z5\nG82 X1 Z-3 R1 F9\n", "keep", None, (2, 1), "without P"),
    ("G0 X0 Y0 Z5\nG81 X1 Z3 R1 F9\n", "keep", None, (2, 1), "above R"),
]


@pytest.mark.parametrize("text, mode, dialect, where, why", REFUSED, ids=[r[4] for r in REFUSED])
def test_what_is_not_exact_is_refused_by_line_and_column(text, mode, dialect, where, why):
    with pytest.raises(InputError) as exc:
        expand_cycles(text, "p.nc", mode, dialect=dialect)
    assert f"p.nc: line {where[0]}, column {where[1]}: " in str(exc.value) and why in str(exc.value)


def test_without_a_chain_the_reader_still_refuses_cycles(tmp_path):
    p = tmp_path / "p.nc"
    p.write_text("G0 X0 Z5\nG81 X1 Z-3 R1 F100\nG80\n")
    with pytest.raises(InputError, match=r"line 2, column 1: 'G81' \(canned cycle"):
        parse_program(p)


def test_a_cycle_in_a_subroutine_is_a_hole_per_call(tmp_path, truth_file):
    prog = DATA / "hole_sub_linuxcnc.ngc"
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file)) == 0
    cyc = json.loads((out / "compensate_summary.json").read_text())["files"][0]["cycles"]
    assert cyc["holes"] == 2 and list(cyc["tilt_um"]) == ["4"] and cyc["true_bottom"]["max_um"] < TOL_POINT_UM
    written = [_cycle_words(ln) for ln in (out / prog.name).read_text().splitlines() if "G81" in ln]
    assert [round(w["X"]) for w in written] == [10, 30] and all(set(w) == set("XYZR") for w in written)


def test_a_block_delete_cycle_line_is_refused():
    with pytest.raises(InputError, match=r"p.nc: line 3, column 1: '/' \(block delete\) on a canned-cycle line"):
        expand_cycles("G0 X0 Y0 Z5\nG81 X1 Z-3 R1\n/X2\n", "p.nc", "keep")


def test_tapping_is_kept_as_a_cycle_its_hole_compensated_like_any():
    exp = expand_cycles("G0 X0 Y0 Z5\nG84 X1 Y2 Z-3 R1 F9\nG80\n", "p", "keep")
    assert [(h.code, h.xyz, h.r) for h in exp.holes] == [("G84", (1.0, 2.0, -3.0), 1.0)]
    assert exp.text.splitlines()[slice(*exp.spans[1])] == [  # the R point, the bottom, the retract (not written)
        "G90 G1 X1.000000 Y2.000000 Z1.000000 F9", "G1 Z-3.000000", "G0 Z5.000000"]


def test_kept_incremental_cycles_reach_every_hole_bottom_on_the_true_machine(tmp_path, mill, truth_file):
    """G91 kept cycles (LinuxCNC / Fanuc: X Y increments from the current position, R from the series' initial
    level, Z from R): the written increments, run from where the controller really is, reach every
    compensated hole bottom. The check interprets the written program with those rules itself."""
    prog = DATA / "drill_g91_kept.ngc"
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file)) == 0
    src = prog.read_text().splitlines()
    dst = [ln for ln in (out / prog.name).read_text().splitlines() if not ln.startswith("(volcomp:")]
    assert len(dst) == len(src)
    truth = ChainField(mill, ChainElementSet.load(truth_file, mill))
    tip = lambda q: mill.nominal(q[None])[0] * 1e3 + truth.predict(q[None])[0]  # noqa: E731
    # programmed holes, worked by hand: start (10, 10), initial level Z-20; G99 series: R -35, bottom -55
    # at (20, 15), (30, 15), (30, 25); the G82 line changes the cycle in the same series: R -30, Z -55 at (15, 30)
    targets = [(20, 15, -55), (30, 15, -55), (30, 25, -55), (15, 30, -55)]
    ctrl, z0, errs = np.array([10.0, 10.0]), -20.0, []
    for s, d in zip(src, dst):
        if not re.search(r"G8[12]|^[XY]", s):
            assert d == s
            continue
        w = _cycle_words(d)
        ctrl = ctrl + [w["X"], w["Y"]]
        bottom = z0 + w["R"] + w["Z"]
        q = np.array([*ctrl, bottom]) + G55_MM
        errs.append(np.linalg.norm(tip(q) - mill.nominal((np.array(targets[len(errs)]) + G55_MM)[None])[0] * 1e3))
    assert len(errs) == 4 and max(errs) < TOL_POINT_UM
    cyc = json.loads((out / "compensate_summary.json").read_text())["files"][0]["cycles"]
    assert cyc["holes"] == 4 and cyc["true_bottom_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # teeth


KEPT_G91_REPEATS = """(G91 G81 with L3: three holes at equal steps, LinuxCNC manual "G81 ... L")
G21 G90 G17 G55
T1 M6
G0 X10 Y10 Z-20
G91 G99 G81 X10 Y5 Z-20 R-15 L3 F200
G80 G90
G0 Z20
M2
"""


def test_kept_incremental_repeats_are_written_one_line_per_hole(tmp_path, mill, truth_file):
    """L3 under G91 (LinuxCNC / Fanuc: each repeat steps by X Y from the last hole; R from the initial level, Z from
    R): kept, the line is written without L and two modal-repeat lines follow, each hole with its own compensated
    increments. The check runs the written lines with those rules itself and finds every hole bottom reached on
    the truth."""
    prog = tmp_path / "rep.ngc"
    prog.write_text(KEPT_G91_REPEATS)
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file), "--dialect", "linuxcnc") == 0
    dst = [ln for ln in (out / prog.name).read_text().splitlines() if not ln.startswith("(volcomp:")]
    src = KEPT_G91_REPEATS.splitlines()
    k = src.index("G91 G99 G81 X10 Y5 Z-20 R-15 L3 F200")
    assert dst[:k] == src[:k] and dst[k + 3:] == src[k + 1:]  # every other line byte-identical
    assert "L" not in re.sub(r"\(.*?\)", "", dst[k]) and dst[k].startswith("G91 G99 G81 ")
    assert all(re.fullmatch(r"X-?[\d.]+ Y-?[\d.]+ Z-?[\d.]+ R-?[\d.]+", d) for d in dst[k + 1:k + 3])
    truth = ChainField(mill, ChainElementSet.load(truth_file, mill))
    tip = lambda q: mill.nominal(q[None])[0] * 1e3 + truth.predict(q[None])[0]  # noqa: E731
    # by hand: start (10, 10), initial level Z-20; holes at (20, 15), (30, 20), (40, 25): R -35, bottom -55
    targets = [(20, 15, -55), (30, 20, -55), (40, 25, -55)]
    ctrl, z0, errs = np.array([10.0, 10.0]), -20.0, []
    for d in dst[k:k + 3]:
        w = _cycle_words(d)
        ctrl = ctrl + [w["X"], w["Y"]]
        q = np.array([*ctrl, z0 + w["R"] + w["Z"]]) + G55_MM
        errs.append(np.linalg.norm(tip(q) - mill.nominal((np.array(targets[len(errs)]) + G55_MM)[None])[0] * 1e3))
    assert max(errs) < TOL_POINT_UM
    cyc = json.loads((out / "compensate_summary.json").read_text())["files"][0]["cycles"]
    assert cyc["holes"] == 3 and cyc["true_bottom_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # teeth


G80_PROGRAM = """%
O0100 (G80 KEEPS THE MOTION MODE)
N10 G90 G17 G21 G54
N20 T1 M06
N30 G00 X10. Y10.
N40 G43 Z50. H01
{before}N50 G99 G81 X10. Y10. Z-5. R2. F100.
N60 X20.
N70 G80
N80 Z50.
N90 X0. Y0.
N100 M30
%
"""


@pytest.mark.parametrize("before, kind", [("", "rapid"), ("N45 G01 Z10. F200.\n", "linear")])
def test_fanuc_g80_leaves_the_motion_mode_written_before_the_cycle(tmp_path, before, kind):
    """Fanuc 0i (and Haas, Siemens ISO) manuals: the drilling cycles and G80 are G-code group 09, G00-G03 group
    01; G80 cancels the cycle and leaves group 01 as it was, so the bare 'Z50.' after G80 moves in the mode
    written before the cycle (G00, or G01 where the program fed down first), as CAM posts rely on."""
    p = tmp_path / "p.nc"
    p.write_text(G80_PROGRAM.format(before=before))
    prog = parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="fanuc",
                         cycles=lambda text, path, dia, inner: expand_cycles(text, path, "keep", dia, inner))
    after = prog.moves[-2:]  # N80, N90: the moves after G80
    assert [m.kind for m in after] == [kind, kind] and [m.motion_word for m in after] == [None, None]
    assert np.allclose([m.end[2] for m in after], [50.0, 50.0]) and np.allclose(after[-1].end[:2], [0.0, 0.0])
    with pytest.raises(InputError, match=rf"p.nc: line {11 if before else 10}, column 5: axis word 'Z50.' but no "
                                         r"motion mode"):  # LinuxCNC: G80 is group 1 and ends the motion mode
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="linuxcnc",
                      cycles=lambda text, path, dia, inner: expand_cycles(text, path, "keep", dia, inner))


def test_a_fanuc_post_drill_and_tap_program_reaches_its_holes(tmp_path, truth_file):
    """A program in the form Fanuc posts write (written here from the Fanuc 0i manual): inch, G81 and a rigid tap
    (M29 S then G84), each ended by G80 and a bare 'Z1.' retract in the G00 of before the cycle, and a 4-decimal
    inch arc whose radii differ by the last digit. Compensated on mill-xyz (G55, tools 3 and 4 of the table);
    every hole bottom within TOL_POINT_UM on the TRUE machine, every line but the holes byte-identical."""
    prog = DATA / "fanuc_post_drill_tap.nc"
    tools = tmp_path / "tools.csv"
    tools.write_text("tool,length_mm,radius_mm\n3,120,3.175\n4,110,3.175\n")
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file), "--dialect", "fanuc",
                       "--tool-table", str(tools)) == 0
    entry = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    cyc = entry["cycles"]
    assert cyc["holes"] == 4 and cyc["true_bottom"]["max_um"] < TOL_POINT_UM
    # the XY rapids before Z is known (N50, N135) named by the source's lines: kept cycles are written line for line
    assert entry["moves_before_position_known"] == [14, 33]
    src = prog.read_text().splitlines()
    dst = [ln for ln in (out / prog.name).read_text().splitlines() if not ln.startswith("(volcomp:")]
    at = 0  # every line but the holes and the feed moves (split where long) written as it was, in order
    for line in (ln for ln in src if not re.search(r"G8[14]|^N(70|160) X2.5|G0[13] X", ln)):
        at = dst.index(line, at) + 1
    assert "N80 Z1." in dst and "N170 Z1." in dst  # the G00 retracts after G80: rapids, kept as written


def test_without_a_dialect_a_bare_axis_word_after_g80_names_the_option(tmp_path):
    """RS274NGC (and the reader without a dialect word in the program): G80 ends the motion mode; the refusal
    names the dialects whose G80 keeps it and the option."""
    p = tmp_path / "p.nc"
    p.write_text(G80_PROGRAM.format(before=""))
    with pytest.raises(InputError, match=r"p.nc: line 10, column 5: axis word 'Z50.' but no motion mode .* after G80 "
                                         r"\(Fanuc, Haas, Siemens ISO keep .* --dialect\)"):
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")),
                      cycles=lambda text, path, dia, inner: expand_cycles(text, path, "keep", dia, inner))


G09_NOTE = ("read as the controllers that run it read it (G80, G28 or G30 with a G0-G3 on one line; G80 keeps the G0-G3 "
            "of before the cycle; a bare G70/G71 is inch/mm; first at line {}); --dialect names the controller")
"""The words the summary and the output's header use (written out here, not imported from the library)."""


def _read(p, dialect):
    return parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect=dialect,
                         cycles=partial(cycle_pass, mode="keep"))


@pytest.mark.parametrize("before, line", [("", 10), ("N45 G01 Z10. F200.\n", 11)])
def test_auto_with_no_dialect_word_reads_g80_as_group_09_and_says_so(tmp_path, before, line):
    """No word of any dialect in the program: LinuxCNC, Mach3 and grbl refuse the bare 'Z50.' after G80, so the
    group-09 reading (the G00 or G01 of before the cycle) is the only one under which it runs: under --dialect
    auto it gives the moves --dialect fanuc gives, and the evidence and the output's header name the line."""
    p = tmp_path / "p.nc"
    p.write_text(G80_PROGRAM.format(before=before))
    auto, fanuc = _read(p, "auto"), _read(p, "fanuc")
    assert [m.kind for m in auto.moves] == [m.kind for m in fanuc.moves]
    assert np.array_equal([m.end for m in auto.moves], [m.end for m in fanuc.moves], equal_nan=True)
    assert auto.dialect == "rs274" and auto.g80_line == line and fanuc.g80_line == 0
    assert auto.dialect_evidence == "no dialect word found: rs274; " + G09_NOTE.format(line)
    assert "volcomp: " + G09_NOTE.format(line) in auto.notes() and not any("group-09" in n for n in fanuc.notes())


def test_a_program_recognised_as_linuxcnc_still_refuses_a_bare_axis_word_after_g80(tmp_path):
    """A LinuxCNC named parameter makes auto detection say linuxcnc, whose G80 ends the motion mode: refused."""
    p = tmp_path / "p.ngc"
    p.write_text("(LINUXCNC STYLE)\n#<clear> = 50.\nG90 G17 G21 G54\nG0 X10. Y10. Z#<clear>\n"
                 "G99 G81 X10. Y10. Z-5. R2. F100.\nX20.\nG80\nZ#<clear>\nM2\n")
    with pytest.raises(InputError, match=r"p.ngc: line 8 .*axis word 'Z50' but no motion mode .* after G80"):
        _read(p, "auto")


FUSION_TOOL_MM = 100.0
"""Tool 1's length in the table given with the Fusion-style program (its G43 H01)."""


def test_a_fusion_fanuc_post_drilling_program_runs_with_defaults(tmp_path, mill, truth_file, capsys):
    """A program in the form Fusion 360's Fanuc post writes (written here from the Fanuc 0i manual: G81 series, G80,
    a bare 'Z15.' retract in the G00 of before the cycle; no ':' number, no G05.1, so no dialect is recognised).
    With the default --dialect auto it is compensated, the summary and the output's header saying how G80 was read;
    every hole bottom, run as the shop would (written + G55 + the tool length, on the TRUE machine with that tool),
    within TOL_POINT_UM; every other line byte-identical. With --dialect linuxcnc it is refused."""
    prog = DATA / "fusion_fanuc_drill.nc"
    tools = tmp_path / "tools.csv"
    tools.write_text(f"tool,length_mm,radius_mm\n1,{FUSION_TOOL_MM},3\n")
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file), "--tool-table", str(tools)) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["dialect"] == "rs274" and e["dialect_evidence"].endswith(G09_NOTE.format(22))
    assert G09_NOTE.format(22) in capsys.readouterr().out
    text = (out / prog.name).read_text()
    assert "(volcomp: " + G09_NOTE.format(22).replace("(", "[").replace(")", "]") + ")" in text.splitlines()
    src = prog.read_text().splitlines()
    dst = [ln for ln in text.splitlines() if not ln.startswith("(volcomp:")]
    assert len(dst) == len(src)
    mt = machine_with_tool(mill, FUSION_TOOL_MM)
    truth = ChainField(mt, ChainElementSet.load(truth_file, mill))
    shift = G55_MM + [0.0, 0.0, FUSION_TOOL_MM]
    state, errs = {}, []
    for s, d in zip(src, dst):
        if not re.search(r"G81|^N(70|75|80) ", s):
            assert d == s  # every line but the holes byte-identical (N90 Z15. among them)
            continue
        state.update(_cycle_words(s))
        w = _cycle_words(d)
        q = np.array([w["X"], w["Y"], w["Z"]]) + shift
        tip = mt.nominal(q[None])[0] + truth.predict(q[None])[0] * 1e-3
        target = mt.nominal((np.array([state["X"], state["Y"], state["Z"]]) + shift)[None])[0]
        errs.append(np.linalg.norm(tip - target) * 1e3)
    assert len(errs) == 4 and max(errs) < TOL_POINT_UM
    assert e["cycles"]["true_bottom_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check has teeth
    assert _compensate(prog, tmp_path / "l", truth_file, "--tool-table", str(tools), "--dialect", "linuxcnc") != 0
    assert re.search(r"line 22, column 5: axis word 'Z15.' but no motion mode .* after G80 .*--dialect",
                     capsys.readouterr().err)


@pytest.mark.parametrize("dialect", ["linuxcnc", "mach3", "grbl"])
def test_named_controllers_whose_g80_ends_the_motion_mode_still_refuse(tmp_path, dialect):
    """Named, LinuxCNC, Mach3 (its G-code manual: G80 cancels the motion mode, RS274NGC group 1) and grbl keep
    the refusal, naming the line, the word and the option."""
    p = tmp_path / "p.nc"
    p.write_text(G80_PROGRAM.format(before="").replace("O0100 (G80 KEEPS THE MOTION MODE)\n", "(G80)\n"))
    with pytest.raises(InputError, match=r"p.nc: line 10, column 5: axis word 'Z50.' but no motion mode .* --dialect"):
        _read(p, dialect)
