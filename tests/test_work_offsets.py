"""Programs with work offsets and tool lengths (compensation/nc_state.py): the tables read by content,
bad rows refused by file, row and column; a program with no table (whether or not it selects a work
system) refused unless --work-offsets machine says it is in machine coordinates (no assumed zero);
accepted programs compensated where the part is cut, checked independently: every
non-motion line byte-identical, every programmed point reproduced by the TRUE machine (its tool at the
table's length, the program placed by the offset) within 1 μm."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.nc_state import (MACHINE, field_with_tool, machine_with_tool, read_tool_table,
                                   read_work_offsets)
from errormap.io import InputError
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from program_checks import TOL_POINT_UM, true_point_errors_um

DATA = Path(__file__).resolve().parent / "data" / "controller"
TOL_NOMINAL_MM = 1e-9
"""Nominal tool tip of two tool lengths with the Z shift: round-off on ~1000 mm."""
ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), a real mill's size (tests/test_chain_compensate.py)."""
IGNORED_MIN_UM = 2.0
"""The same compensation computed with the tables ignored (G55 as machine zero, the file's 120 mm tool)
must leave more than this at the true tool point: the check above has teeth (observed 5-40 μm)."""


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture()
def truth_file(tmp_path, mill):
    return ChainElementSet.random(mill, 101, ELEMENT_SCALE_UM, 11).save(tmp_path / "truth.json")


# ---------------------------------------------------------------------------- tables
def test_tables_are_read_by_content_whatever_their_names(tmp_path):
    var = read_work_offsets(DATA / "offsets.var")
    csv_ = read_work_offsets(DATA / "offsets.csv")
    assert var.systems["G55"] == {w: v for w, v in zip("XYZABCUVWR", (200, 100, -150, 0, 0, 0, 0, 0, 0, 0))}
    assert set(var.systems) == {"G54", "G55"}
    assert csv_.systems["G55"] == {"X": 200.0, "Y": 100.0, "Z": -150.0}
    assert csv_.systems["G54.1P3"] == {"X": 300.5, "Y": 120.25, "Z": -80.0}
    assert read_work_offsets(MACHINE).machine_coordinates
    tbl, tcsv = read_tool_table(DATA / "tools.tbl"), read_tool_table(DATA / "tools.csv")
    assert tbl.tools == {1: (150.0, 5.0), 2: (100.0, 3.0), 3: (0.0, 0.0)} == tcsv.tools
    swapped = tmp_path / "offsets.tbl"  # a parameter file named like a tool table: read as what it is
    swapped.write_bytes((DATA / "offsets.var").read_bytes())
    assert read_work_offsets(swapped).systems == var.systems
    with pytest.raises(InputError, match="not a tool table"):
        read_tool_table(swapped)


@pytest.mark.parametrize("reader, text, where", [
    (read_work_offsets, "system,x_mm,y_mm,z_mm\nG54,0,0,0\nG55,1,abc,2\n", "row 3, column 3"),
    (read_work_offsets, "system,x_mm,y_mm,z_mm\nG60,0,0,0\n", "row 2, column 1"),
    (read_work_offsets, "system,x_mm,y_mm,z_mm,q_mm\nG54,0,0,0,1\n", "row 1, column 5"),
    (read_work_offsets, "5221 0.0\n5222 0.0\n5223 x\n", "row 3, column 6"),
    (read_work_offsets, "5211 3.0\n5221 0\n5222 0\n5223 0\n", "row 1, column 1: parameter 5211 (a G92 offset)"),
    (read_tool_table, "T1 P1 Z+150.0 D10.0\nT2 P2 Z1O0.0\n", "row 2, column 7"),
    (read_tool_table, "T1 P1 Y2.0 Z+150.0\n", "row 1, column 7: Y2"),
    (read_tool_table, "tool,length_mm,radius_mm\n1,150,5\n1,120,5\n", "row 3, column 1: tool 1 given twice"),
    (read_tool_table, "tool,length_mm,radius_mm\n1,150\n", "row 2, column 3"),
])
def test_bad_rows_are_refused_by_file_row_and_column(tmp_path, reader, text, where):
    p = tmp_path / "table"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as err:
        reader(p)
    assert str(err.value).startswith(f"{p}: {where}"), str(err.value)


# ---------------------------------------------------------------------------- the chain at a tool length
def test_tool_length_moves_the_tip_along_z_and_is_the_abbe_arm(mill):
    """machine Z = program Z + L with the chain's tool at L: the nominal tip does not depend on L, the
    error does (the angular errors of the tool side act on the arm L)."""
    rng = np.random.default_rng(7)
    ax = rng.uniform(mill.stroke_lo + [0, 0, 160.0], mill.stroke_hi - [0, 0, 160.0], (200, 3))
    els = ChainElementSet.random(mill, 3, ELEMENT_SCALE_UM, 11)
    f120 = ChainField(mill, els)
    for L in (0.0, 150.0):
        mt = machine_with_tool(mill, L)
        assert np.abs(mt.nominal(ax + [0, 0, L - 120.0]) - mill.nominal(ax)).max() < TOL_NOMINAL_MM
        f = field_with_tool(f120, mt)
        d = np.abs(f.predict(ax + [0, 0, L - 120.0]) - f120.predict(ax)).max()
        assert d > 0.1  # the arm matters (0.1 μm: far above round-off)
    with pytest.raises(ValueError, match="declares no \\[geometry\\] tool_length"):
        machine_with_tool(load_machine("lathe-xzc"), 100.0)


# ---------------------------------------------------------------------------- no assumed zero
def _compensate(prog, out, model, *extra):
    return main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(model), "--method", "exact",
                 "--out", str(out), *extra])


@pytest.mark.parametrize("name, line, col, word", [
    ("g55_tool_linuxcnc.ngc", 5, 1, "'G55'"),
    ("g54_1_extended.nc", 4, 5, "'G54.1 P3'"),
])
def test_a_program_selecting_a_work_system_without_a_table_is_refused(tmp_path, truth_file, capsys, name, line, col,
                                                                      word):
    assert _compensate(DATA / name, tmp_path / "o", truth_file) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{DATA / name}: line {line}, column {col}: {word}: selects the work offset" in err
    assert "--work-offsets FILE" in err and "--work-offsets machine" in err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_a_tool_or_system_missing_from_the_tables_is_refused(tmp_path, truth_file, capsys):
    prog = DATA / "g55_tool_linuxcnc.ngc"
    tools = tmp_path / "t.csv"
    tools.write_text("tool,length_mm\n2,100\n", encoding="utf-8")
    assert _compensate(prog, tmp_path / "o", truth_file, "--work-offsets", str(DATA / "offsets.var"),
                       "--tool-table", str(tools)) == 2
    err = capsys.readouterr().err
    assert f"{prog}: line 7, column 1: 'G43 H1': tool length offset H1: tool 1 is not known (the tool table" in err
    assert "give it in --tool-table FILE (.tbl or CSV) or G10 L1 P1 Z.. before it" in err
    assert _compensate(DATA / "g54_1_extended.nc", tmp_path / "o", truth_file, "--work-offsets",
                       str(DATA / "offsets.var"), "--tool-table", str(DATA / "tools.tbl")) == 2
    assert f"line 4, column 5: 'G54.1 P3': the work offset G54.1P3 is not in {DATA / 'offsets.var'}" in \
        capsys.readouterr().err


# ---------------------------------------------------------------------------- accepted, checked independently
CASES = [  # program, tables given, the tables' contents for the independent check
    ("g55_tool_linuxcnc.ngc", ("offsets.var", "tools.tbl"), {"G55": (200, 100, -150)}, {1: 150.0}),
    ("g10_in_program_fanuc.nc", (None, "tools.csv"), {}, {}),
    ("g54_1_extended.nc", ("offsets.csv", "tools.csv"), {"G54.1P3": (300.5, 120.25, -80)}, {3: 0.0}),
    ("two_tools.ngc", ("offsets.csv", "tools.tbl"), {"G55": (200, 100, -150)}, {1: 150.0, 2: 100.0}),
]


@pytest.mark.parametrize("name, tables, offsets, tools", CASES, ids=[c[0] for c in CASES])
def test_programs_with_offsets_and_tools_are_compensated_where_the_part_is_cut(tmp_path, mill, truth_file, name,
                                                                               tables, offsets, tools):
    prog = DATA / name
    extra = []
    for opt, f in zip(("--work-offsets", "--tool-table"), tables):
        if f is not None:
            extra += [opt, str(DATA / f)]
    out = tmp_path / "o"
    assert _compensate(prog, out, truth_file, "--truth", str(truth_file), *extra) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["model_max_um"] < 1e-6 and e["true"]["max_um"] < TOL_POINT_UM
    truth_els = ChainElementSet.load(truth_file, mill)
    errs = true_point_errors_um(prog, out / name, mill, truth_els, offsets, tools)
    assert len(errs) >= 4 and errs.max() < TOL_POINT_UM


def ignored_vs_used_um(prog, mill, truth_els, offsets, tools):
    """TRUE residual max (μm) at every vertex of ``prog`` run with its real work offset and tool, compensated
    (a) with the tables ignored (the program's axes taken as machine axes, the file's 120 mm tool: what
    the reader did before) and (b) with them used. The model is the truth (nothing else differs)."""
    from compensation.app.workflows.compensate import CompensateSettings, solve_paths
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.solvers import solve
    from compensation.solvers.chain_exact import nominal_and_jacobian
    s = CompensateSettings("exact", "", Path("."), work_offsets=offsets, tool_table=tools)
    field_ = ChainField(mill, truth_els)
    tp = read_tool_path(prog, mill, s, field_)
    res, _, true_used, _ = solve_paths([tp], field_, field_, mill, s)[0]
    prog_axes = tp.axes - tp.shift
    t0, _ = nominal_and_jacobian(mill, prog_axes)
    old = solve("exact", field_, t0, mill, target_axes=prog_axes, progress=False)  # tables ignored
    run = old.axes + tp.shift  # what the controller then drives
    err = np.empty((len(run), 3))
    for L in np.unique(tp.tool_mm):
        idx = np.flatnonzero(tp.tool_mm == L)
        mt = machine_with_tool(mill, L)
        err[idx] = (mt.nominal(run[idx]) - mt.nominal(tp.axes[idx])) * 1e3 + ChainField(mt, truth_els).predict(run[idx])
    return float(np.linalg.norm(err, axis=1).max()), float(np.linalg.norm(true_used, axis=1).max())


def test_the_tables_matter(mill, truth_file):
    """Compensated with the tables ignored, the true tool point misses by microns; with them, it does not."""
    truth_els = ChainElementSet.load(truth_file, mill)
    ignored, used = ignored_vs_used_um(DATA / "g55_tool_linuxcnc.ngc", mill, truth_els,
                                       read_work_offsets(DATA / "offsets.var"), read_tool_table(DATA / "tools.tbl"))
    assert used < TOL_POINT_UM < IGNORED_MIN_UM < ignored


def test_the_grinder_reads_a_g54_program_with_its_offsets(tmp_path, grinder, capsys):
    """The grinder (on its chain) reads a G54 program as every machine tool does: refused without
    --work-offsets; with a table, placed by it; with --work-offsets machine, compensated, recorded in the summary
    and as the output's first comment."""
    from errormap.chain_truth import make_chain_truth
    el = make_chain_truth(grinder, 7).elements.save(tmp_path / "elements.json")
    prog = Path(__file__).resolve().parent / "data" / "gcode_corpus" / "c01_linuxcnc_basic.ngc"
    base = ["compensate", str(prog), "--model", str(el), "--method", "exact"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err  # one line, cut in the middle where long
    assert f"{prog}: line 4, column 29: 'G54': sel" in err and "or --work-offsets machine" in err
    assert main([*base, "--out", str(tmp_path / "b"), "--work-offsets", str(DATA / "offsets.csv")]) == 0
    e = json.loads((tmp_path / "b" / "compensate_summary.json").read_text())["files"][0]
    assert e["work_offsets"] == str(DATA / "offsets.csv")
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "c"), "--work-offsets", MACHINE]) == 0
    out = (tmp_path / "c" / prog.name).read_text(encoding="latin-1").splitlines()
    assert out[:2] == ["%", "(volcomp: work offsets taken as machine zero [--work-offsets machine])"]
    e = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert e["work_offsets"] == MACHINE and e["dialect"] == "rs274"


def test_machine_coordinates_zero_every_system(tmp_path, truth_file):
    """--work-offsets machine: every work system, extended ones too, is machine zero (recorded)."""
    out = tmp_path / "o"
    assert _compensate(DATA / "g54_1_extended.nc", out, truth_file, "--work-offsets", MACHINE, "--tool-table",
                       str(DATA / "tools.csv")) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["work_offsets"] == MACHINE and e["offsets_mm_deg"] == {"G54.1P3": [0.0, 0.0, 0.0]}
    assert e["tools_used"] == {"3": 0.0}


MILL_NO_SYSTEM = "%\n(NO WORK SYSTEM WORD)\nG21 G90 G17\nG0 X5. Y5. Z-30.\nG1 Z-60. F250.\nG1 X80. Y30.\nM30\n%\n"
"""A mill program that selects no work system (no G54 word): a controller runs it in G54."""
GRINDER_NO_SYSTEM = "%\nG21 G90 G18 G40 G49 G80 G94\nG0 X90 Z5 A0\nG1 Z0.3 F120\nX90.2 A30\nX90.4 A60\nM30\n%\n"
"""A grinder program (the axes of tests/data/gcode_corpus/c01_linuxcnc_basic.ngc) with no G54 word."""


@pytest.mark.parametrize("machine_name, text, first_move, tables", [
    ("mill-xyz", MILL_NO_SYSTEM, 4, True),
    (None, GRINDER_NO_SYSTEM, 3, True),
])
def test_a_program_with_no_work_system_word_is_not_read_at_machine_zero(tmp_path, truth_file, grinder, capsys,
                                                                        machine_name, text, first_move, tables):
    """No G54 word and no table: refused at the first move naming the options (no assumed zero, on the
    grinder as on the chains); with --work-offsets machine: compensated, and the summary and the
    output's first comment record it."""
    from errormap.chain_truth import make_chain_truth
    prog = tmp_path / "part.nc"
    prog.write_text(text, encoding="ascii")
    model = truth_file if machine_name else make_chain_truth(grinder, 7).elements.save(tmp_path / "elements.json")
    base = ["compensate", str(prog), "--model", str(model), "--method", "exact"]
    base += ["--machine", machine_name] if machine_name else []
    assert main([*base, "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{prog}: line {first_move}: the first move, with no work offset table" in err
    assert "--work-offsets machine if the program is written in machine coordinates" in err
    assert ("--work-offsets FILE" in err) == tables
    assert not (tmp_path / "a").exists() or not any((tmp_path / "a").iterdir())
    assert main([*base, "--out", str(tmp_path / "b"), "--work-offsets", MACHINE]) == 0
    out = (tmp_path / "b" / prog.name).read_text(encoding="ascii").splitlines()
    assert out[:2] == ["%", "(volcomp: work offsets taken as machine zero [--work-offsets machine])"]
    assert out[2] == text.splitlines()[1] and out[-2:] == ["M30", "%"]  # non-motion lines kept as written
    e = json.loads((tmp_path / "b" / "compensate_summary.json").read_text())["files"][0]
    assert e["work_offsets"] == MACHINE


def test_the_api_refuses_a_program_without_offsets_like_the_cli(tmp_path, mill, truth_file):
    """compensate_program: work_offsets None (default) refuses as the CLI does; "machine" compensates
    and records it."""
    from compensation.compensate import compensate_program
    prog = tmp_path / "part.nc"
    prog.write_text(MILL_NO_SYSTEM, encoding="ascii")
    with pytest.raises(InputError, match=r"line 4: the first move, with no work offset table"):
        compensate_program(prog, mill, truth_file, tmp_path / "a")
    summary = compensate_program(prog, mill, truth_file, tmp_path / "b", work_offsets=MACHINE).summary
    assert summary["files"][0]["work_offsets"] == MACHINE and summary["files"][0]["output"]


def test_a_program_placing_itself_with_g10_needs_no_table(tmp_path, truth_file):
    """The program's own G10 L2 lines give its offset: accepted without a table (recorded so)."""
    out = tmp_path / "o"
    assert _compensate(DATA / "g10_in_program_fanuc.nc", out, truth_file) == 0
    assert json.loads((out / "compensate_summary.json").read_text())["files"][0]["work_offsets"] == "program G10 lines"


def test_report_reads_a_gcode_path_only_with_its_frame(tmp_path, grinder, capsys):
    """volcomp report --path: the same rule as compensate (refused at the first move without
    --work-offsets machine; with it the report records it in metrics.json)."""
    from errormap.chain_truth import make_chain_truth
    el = make_chain_truth(grinder, 7).elements.save(tmp_path / "elements.json")
    prog = tmp_path / "part.nc"
    prog.write_text(GRINDER_NO_SYSTEM, encoding="ascii")
    base = ["report", "--model", str(el), "--path", str(prog), "--methods", "traditional"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 2
    assert f"{prog}: line 3: the first move" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "b"), "--work-offsets", MACHINE]) == 0
    assert json.loads((tmp_path / "b" / "metrics.json").read_text())["work_offsets"] == MACHINE
