"""LinuxCNC's ``G41.1``/``G42.1 D<diameter> [L<orientation>]`` dynamic cutter radius compensation
(compensation/gcode_state.py ``dynamic_cutter``, compensation/nc_state.py): read as ``G41``/``G42`` with a tool table's
radius are read, the radius D/2 in program units (LinuxCNC G-code reference, "G41.1, G42.1 Dynamic Cutter
Compensation"; its interpreter's ``convert_cutter_compensation_on``: no D, a plane other than XY/XZ, compensation
already on, L outside G18 are errors). Programs written here from the reference, not copied.

Checked independently: every programmed point reproduced by the TRUE machine within 1 μm, non-motion lines byte for
byte (tests/program_checks.py); the written program and the reported bound the same as the ``G41 D2`` program's whose
tool table gives tool 2 a radius of 3 mm (``G41.1 D6``), the bound twice as large with ``D12`` (it is linear in the
radius over the same points); the radius per line in mm, inch programs converted."""
import json

import numpy as np
import pytest
from program_checks import TOL_POINT_UM, true_point_errors_um

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import program_frames, read_tool_table, read_work_offsets
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError
from errormap.machine import load_machine
from test_dialects import OFFSETS, TOOLS

SEED = 101
"""The truth: ChainElementSet.random(mill-xyz, SEED, 10 um/urad, 11 stations), also the model."""
PROGRAM = ("(LinuxCNC G41.1: the cutter diameter on the line)\nG21 G90 G17\nG55\nT2 M6\nG43 H2\nG0 X0 Y0 Z-20\n"
           "{comp}\nN1 G1 X20 Y20 F300\nN2 X60\nN3 G2 X60 Y60 I0 J20\nN4 G1 X20\nN5 Y20\nG40 G0 X0 Y0\nG49\nM2\n")
"""Tool 2 of tests/data/controller/tools.csv: 100 mm long, radius 3 mm; G55 at (200, 100, -150)."""
TOL_SAME_MM = 1e-9
"""Two written programs are the same where every written axis agrees within this (the words' 6 decimals)."""
TOL_BOUND_REL = 1e-9
"""The bound of two programs on the same points: equal (or in the ratio of their radii) to rounding."""


def _compensate(tmp_path, comp, name):
    truth = tmp_path / "truth.json"
    if not truth.exists():
        ChainElementSet.random(load_machine("mill-xyz"), SEED, 10.0, 11).save(truth)
    src = tmp_path / f"{name}.ngc"
    src.write_text(PROGRAM.format(comp=comp))
    out = tmp_path / f"out-{name}"
    assert main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--dialect", "linuxcnc", "--out", str(out), "--work-offsets", str(OFFSETS),
                 "--tool-table", str(TOOLS)]) == 0
    entry = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    written = parse_program(out / src.name, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="linuxcnc")
    return src, out / src.name, entry, np.array([m.end for m in written.moves]), truth


@pytest.mark.parametrize("code", ["G41.1", "G42.1"])
def test_g41_1_is_read_as_g41_with_the_tool_table_radius(tmp_path, capsys, code):
    mill = load_machine("mill-xyz")
    src, out, dyn, dyn_axes, truth = _compensate(tmp_path, f"{code} D6", "dyn")
    errs = true_point_errors_um(src, out, mill, ChainElementSet.load(truth, mill), {"G55": (200, 100, -150)},
                                {2: 100.0}, dialect="linuxcnc")
    assert len(errs) == 5 and errs.max() < TOL_POINT_UM  # N1-N5 (rapids kept); other lines byte for byte
    assert dyn["dynamic_cutter_radii_mm"] == ["line 7: 3"]
    assert "G41.1/G42.1 radius D/2 (mm) at line 7: 3" in capsys.readouterr().out
    _, _, table, table_axes, _ = _compensate(tmp_path, f"{code[:3]} D2", "table")
    assert np.abs(dyn_axes - table_axes).max() <= TOL_SAME_MM
    assert abs(dyn["cutter_radius_bound_um"] - table["cutter_radius_bound_um"]) <= \
        TOL_BOUND_REL * table["cutter_radius_bound_um"]
    _, _, twice, twice_axes, _ = _compensate(tmp_path, f"{code} D12", "twice")
    assert np.abs(twice_axes - dyn_axes).max() <= TOL_SAME_MM  # the path is compensated as programmed
    assert abs(twice["cutter_radius_bound_um"] - 2 * dyn["cutter_radius_bound_um"]) <= \
        TOL_BOUND_REL * twice["cutter_radius_bound_um"] and dyn["cutter_radius_bound_um"] > 0.1


@pytest.mark.parametrize("units, comp, radius_mm", [("G21", "G41.1 D6", 3.0), ("G20", "G42.1 D0.25", 0.125 * 25.4),
                                                    ("G21", "G41.1 D0", 0.0)])
def test_the_radius_is_half_d_in_program_units(tmp_path, units, comp, radius_mm):
    src = tmp_path / "p.ngc"
    src.write_text(PROGRAM.format(comp=comp).replace("G21", units))
    prog = parse_program(src, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="linuxcnc")
    (tmp_path / "t.csv").write_text("tool,length_mm\n2,100\n")  # no radius: G41.1 needs none
    frames = program_frames(prog, read_work_offsets(OFFSETS), read_tool_table(tmp_path / "t.csv"))
    got = frames.radius([m.index for m in prog.moves])
    on = np.array([7 <= m.index < 12 for m in prog.moves])  # 0-based lines 7-11: after G41.1, before G40
    assert np.all(got[on] == radius_mm) and np.all(np.isnan(got[~on]))


@pytest.mark.parametrize("comp, dialect, where", [
    ("G41.1", "linuxcnc", "column 1: 'G41.1' without D (the cutter diameter): LinuxCNC's error ('G41.1 with no D "
                          "word'); write the diameter, like 'G41.1 D6'"),
    ("G42.1 D-6", "linuxcnc", "column 7: 'D-6' with G42.1: D is the cutter diameter (≥ 0)"),
    ("G41.1 D6 L2", "linuxcnc", "column 10: 'L2' with G41.1 in G17: LinuxCNC's error"),
    ("G18 G41.1 D6 L10", "linuxcnc", "column 14: 'L10' with G41.1: the tool orientation is a whole number 0-9"),
    ("G18 G41.1 D6 L1.5", "linuxcnc", "column 14: 'L1.5' with G41.1: the tool orientation is a whole number 0-9"),
    ("G19 G41.1 D6", "linuxcnc", "column 5: 'G41.1' in the plane G19: LinuxCNC compensates"),
    ("G41 D2\nG42.1 D6", "linuxcnc", "column 1: 'G42.1' while G41 is on: LinuxCNC's error"),
    ("G41.1 D6 H2", "linuxcnc", "column 10: 'H2' outside G43"),
    ("G41.1 D6", "fanuc", "column 1: 'G41.1' (dynamic cutter radius compensation, D the diameter (LinuxCNC's, read "
                          "with --dialect linuxcnc; Fanuc's G41.1/G42.1 is normal direction control)) is not supported"),
    ("G41.1 D6", None, "column 1: 'G41.1' (dynamic cutter radius compensation"),
])
def test_g41_1_refusals_name_line_column_word(tmp_path, comp, dialect, where):
    src = tmp_path / "p.ngc"
    src.write_text(PROGRAM.format(comp=comp))
    with pytest.raises(InputError) as exc:
        parse_program(src, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect=dialect)
    line = 8 if comp.startswith("G41 D2") else 7
    assert f"line {line}, {where}" in str(exc.value), str(exc.value)
