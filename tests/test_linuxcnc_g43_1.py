"""LinuxCNC's ``G43.1`` dynamic tool length offset (compensation/gcode_state.py ``dynamic_length``,
compensation/nc_state.py): the program gives the tool's offsets (LinuxCNC G-code reference, "G43.1 Dynamic Tool
Length Offset": ``G43.1 axes`` replaces the current offset along the axes given, moves nothing; an error with motion
on the line). Programs written here from the reference, not copied.

Checked against the reader's ``G43 H`` path with a tool table holding the same offsets: the written programs are the
same move for move (the tool length enters the chain as the same Abbe arm), and a different length writes other
axes on this truth (the length matters)."""
import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError
from errormap.machine import load_machine

SEED = 5
"""The truth: ChainElementSet.random(machine, SEED, 10 um/urad, 11 stations), also the model."""
MILL = "(G43.1 on a mill)\nG21 G90 G17\nG54\n{tool}\nG0 X10 Y20 Z50\nG1 Z5 F300\nX60 Y40\nG49\nG0 Z200\nM2\n"
LATHE = "(G43.1 on a lathe)\nG21 G18 G90 G8\nG54\nS500 M3\n{tool}\nG0 X30 Z5\nG1 Z-20 F100\nX40\nM5\nM2\n"
TOL_SAME_MM = 1e-9
"""Two written programs are the same where every written axis agrees within this (the words' 6 decimals)."""
DIFFERENT_MM = 1e-4
"""A tool length of 100 mm vs 0 on this truth moves some written axis by more than this (0.1 um)."""


def _written(tmp_path, machine, text, name, tools="tool,length_mm,radius_mm\n1,100,5\n"):
    truth = tmp_path / f"truth-{machine}.json"
    if not truth.exists():
        ChainElementSet.random(load_machine(machine), SEED, 10.0, 11).save(truth)
    (tmp_path / "off.csv").write_text("system,x_mm,y_mm,z_mm\nG54,300,200,-300\n" if machine == "mill-xyz" else
                                      "system,x_mm,y_mm,z_mm\nG54,0,0,200\n")
    (tmp_path / "tools.csv").write_text(tools)
    src = tmp_path / f"{name}.ngc"
    src.write_text(text)
    rc = main(["compensate", str(src), "--machine", machine, "--model", str(truth), "--truth", str(truth), "--method",
               "exact", "--dialect", "linuxcnc", "--out", str(tmp_path / f"out-{name}"), "--work-offsets",
               str(tmp_path / "off.csv"), "--tool-table", str(tmp_path / "tools.csv")])
    assert rc == 0
    out, m = tmp_path / f"out-{name}" / src.name, load_machine(machine)
    prog = parse_program(out, axis_words=AxisWords.of(m), dialect="linuxcnc") if machine == "mill-xyz" else \
        parse_lathe_program(out, m, "keep", None, "linuxcnc")[0]
    return np.array([m.end for m in prog.moves]), prog


def test_g43_1_writes_the_g43_h_program_of_the_same_length_on_a_mill(tmp_path):
    dyn, _ = _written(tmp_path, "mill-xyz", MILL.format(tool="G43.1 Z100"), "dyn")
    table, _ = _written(tmp_path, "mill-xyz", MILL.format(tool="T1 M6 G43 H1"), "table")
    zero, _ = _written(tmp_path, "mill-xyz", MILL.format(tool="G43.1 Z0"), "zero")
    finite = np.isfinite(dyn)
    assert dyn.shape == table.shape and np.array_equal(finite, np.isfinite(table))
    assert np.abs(dyn[finite] - table[finite]).max() <= TOL_SAME_MM
    assert np.abs(dyn[finite] - zero[finite]).max() > DIFFERENT_MM  # the length's Abbe arm matters here


def test_g43_1_x_z_on_a_lathe_is_the_tool_table_offset(tmp_path):
    tools = "tool,x_mm,z_mm,radius_mm\n1,2,50,0\n"
    dyn, _ = _written(tmp_path, "lathe-xzc", LATHE.format(tool="G43.1 X2 Z50"), "dyn", tools)
    table, _ = _written(tmp_path, "lathe-xzc", LATHE.format(tool="T1 M6 G43"), "table", tools)
    only_z, _ = _written(tmp_path, "lathe-xzc", LATHE.format(tool="T1 M6 G43\nG43.1 Z50"), "z", tools)
    finite = np.isfinite(dyn)
    assert np.abs(dyn[finite] - table[finite]).max() <= TOL_SAME_MM
    assert np.abs(only_z[np.isfinite(only_z)] - table[np.isfinite(table)]).max() <= TOL_SAME_MM  # X kept (replaced Z)
    no_x, _ = _written(tmp_path, "lathe-xzc", LATHE.format(tool="G43.1 Z50"), "nox", tools)
    assert np.abs(no_x[np.isfinite(no_x)] - table[np.isfinite(table)]).max() > DIFFERENT_MM  # the X offset matters


@pytest.mark.parametrize("machine, line, dialect, where", [
    ("mill-xyz", "G0 G43.1 Z100", "linuxcnc", "column 1: 'G0' on a G43.1 line: LinuxCNC's error"),
    ("mill-xyz", "G43.1 Y1 Z100", "linuxcnc", "column 7: 'Y1' with G43.1: a tool offset along Z is read here"),
    ("mill-xyz", "G43.1", "linuxcnc", "column 1: 'G43.1' without a tool offset along Z"),
    ("mill-xyz", "G43.1 Z100", "fanuc", "column 1: 'G43.1' (dynamic tool length offset (LinuxCNC's read with"),
    ("lathe-xzc", "G7 G43.1 X2 Z50", "linuxcnc", "column 10: 'X2' with G43.1 under G7"),
])
def test_g43_1_refusals_name_line_column_word(tmp_path, machine, line, dialect, where):
    src = tmp_path / "p.ngc"
    src.write_text((MILL if machine == "mill-xyz" else LATHE).format(tool=line))
    with pytest.raises(InputError) as exc:
        parse_program(src, axis_words=AxisWords.of(load_machine(machine)), dialect=dialect)
    assert f"line {4 if machine == 'mill-xyz' else 5}, {where}" in str(exc.value), str(exc.value)
