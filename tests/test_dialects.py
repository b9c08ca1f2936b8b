"""Controller dialects (compensation/dialects.py): one program per dialect, written from its manual's
syntax, recognised from its content or named, compensated on mill-xyz with its offset and tool tables
and checked independently (tests/program_checks.py: non-motion lines byte-identical, every programmed
point by the TRUE machine within 1 μm); the words of one dialect refused in another, naming the option."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.dialects import RS274, detect_dialect
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import machine_with_tool
from errormap.io import InputError
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from program_checks import TOL_POINT_UM, true_point_errors_um

DATA = Path(__file__).resolve().parent / "data"
DIALECTS = DATA / "dialects"
OFFSETS = DATA / "controller" / "offsets.csv"
TOOLS = DATA / "controller" / "tools.csv"
G55 = (200, 100, -150)

CASES = [  # file, --dialect, dialect in the summary, the offsets / tools the program uses (for the check)
    ("fanuc.nc", "auto", "fanuc", {"G55": G55}, {1: 150.0}),
    ("haas.nc", "auto", "haas", {"G55": G55}, {1: 150.0}),
    ("linuxcnc.ngc", "linuxcnc", "linuxcnc", {"G59.1": (150, 50, -200)}, {2: 100.0}),
    ("siemens_iso.nc", "auto", "siemens-iso", {"G55": G55}, {1: 150.0}),
    ("mach3.tap", "mach3", "mach3", {"G55": G55}, {1: 150.0}),
    ("grbl.gcode", "grbl", "grbl", {"G55": G55}, {}),
    ("tormach.ngc", "linuxcnc", "linuxcnc", {"G55": G55}, {1: 150.0}),  # G50 safe start, G28 via a point
    ("fanuc_home.nc", "fanuc", "fanuc", {"G55": G55}, {1: 150.0}),  # G28 X Y Z through a point, G50
    ("fanuc_modes.nc", "fanuc", "fanuc", {"G55": G55}, {1: 150.0}),  # G50.1 X Y, G08 P1, G05 P10000
    ("haas_modes.nc", "auto", "haas", {"G55": G55}, {1: 150.0}),  # G103 P, G50.1
]


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture()
def truth_file(tmp_path, mill):
    return ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")


@pytest.mark.parametrize("name, option, named, offsets, tools", CASES, ids=[c[0] for c in CASES])
def test_each_dialect_is_compensated_where_the_part_is_cut(tmp_path, mill, truth_file, capsys, name, option, named,
                                                           offsets, tools):
    prog = DIALECTS / name
    out = tmp_path / "o"
    assert main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(truth_file), "--method", "exact",
                 "--out", str(out), "--truth", str(truth_file), "--dialect", option, "--work-offsets", str(OFFSETS),
                 "--tool-table", str(TOOLS)]) == 0
    printed = capsys.readouterr().out
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["dialect"] == named and f"dialect {named}" in printed
    assert ("recognised from its content" in e["dialect_evidence"]) == (option == "auto")
    assert e["true"]["max_um"] < TOL_POINT_UM
    errs = true_point_errors_um(prog, out / name, mill, ChainElementSet.load(truth_file, mill), offsets, tools,
                                dialect=named)
    assert len(errs) >= 5 and errs.max() < TOL_POINT_UM


TOL_GRADIENT_REL = 0.01
"""Central differences of 0.5 mm vs the analytic Jacobian of the cubic-spline elements: within 1 %."""


def test_fanuc_extras_are_reported(tmp_path, mill, truth_file, capsys):
    out = tmp_path / "o"
    assert main(["compensate", str(DIALECTS / "fanuc.nc"), "--machine", "mill-xyz", "--model", str(truth_file),
                 "--method", "exact", "--out", str(out), "--work-offsets", str(OFFSETS), "--tool-table",
                 str(TOOLS)]) == 0
    printed = capsys.readouterr().out
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["g53_lines"] == [22] and "G53 (machine coordinates) on line(s) 22: passed through unchanged" in printed
    assert e["dialect_modes"] == ["G5.1"]
    # G41 D01, tool 1 of radius 5 mm and length 150 mm: the bound is the largest |dE/dp|·r over the points
    # under G41; at least that of its programmed end points (the field's analytic Jacobian, independently)
    mt = machine_with_tool(mill, 150.0)
    ends = np.array([[20, 20], [60, 20], [60, 50], [40, 70], [20, 70]], float)
    q = np.column_stack([ends + [200, 100], np.full(5, -45.0 - 150 + 150)])
    J = ChainField(mt, ChainElementSet.load(truth_file, mill)).jacobian(q)
    at_ends = float((np.linalg.norm(J, ord=2, axis=(1, 2)) * 5.0).max())
    assert at_ends * (1 - TOL_GRADIENT_REL) <= e["cutter_radius_bound_um"] and at_ends > 0.1
    assert "cutter radius compensation" in printed


@pytest.mark.parametrize("text, dialect, col, what", [
    ("N6 M31\n", None, 4, "'M31': M code not on the rs274 allow-list (may move or call a program); haas: chip auger"),
    ("N6 M31\n", "fanuc", 4, "not on the fanuc allow-list"),
    (":1234\n", None, 1, "unexpected character ':'"),
    ("N5 G05.1 Q1\n", None, 4, "'G5.1' (dialect-dependent: a spline or look-ahead) is not supported; on fanuc, haas, "
                               "siemens-iso it is look-ahead / AI contour control; on linuxcnc it is a quadratic spline"),
    ("N5 G05.1 Q2 X0 Y0 Z0\n", "fanuc", 4, "Q2 smooth interpolation changes the path"),
    ("N5 G80 G0 X1\n", "linuxcnc", 8, "'G0' and 'G80' on one line"),
    ("/N5 M1\n", "grbl", 1, "grbl has no block-delete switch"),
    ("M62 P1\n", "fanuc", 1, "'M62': M code not on the fanuc allow-list"),
    ("N5 G50 X0 Y0\n", "fanuc", 8, "'X0' with G50 (a mode, not a move)"),  # a lathe's coordinate setting
    ("N5 G50\n", "grbl", 4, "is not supported; on linuxcnc, fanuc, haas, siemens-iso, mach3 it is scaling off: name the "
                           "controller with --dialect"),
    ("N5 G05 P1\n", "fanuc", 4, "another P is high-speed cycle machining (a stored cycle), not supported"),
    ("N5 G08 P2\n", "fanuc", 4, "'G8' needs P1 (look-ahead on) or P0 (off)"),
    ("N5 G103 P20\n", "haas", 4, "'G103' needs P0-P15"),
    ("N5 G50.1 X0\n", "linuxcnc", 4, "'G50.1' (mirror off) is not supported; on fanuc, haas, siemens-iso it is mirror"),
    ("N5 G103 P1\n", "fanuc", 4, "unknown G code (not on the allow-list); on haas it is limit look-ahead blocks"),
    ("N5 G05 P10000\n", "haas", 4, "'G5' (dialect-dependent: a spline or a machining mode) is not supported; on fanuc "
                                   "it is high-precision contour control; on linuxcnc it is a cubic spline"),
    ("N5 G71\n", None, 4, "'G71' (lathe cycle on Fanuc, Haas, LinuxCNC; mm input in Fanuc lathe G-code system C, "
                          "Sinumerik native, NX generic posts: no dialect here says which; post units as G20/G21)"),
    ("N5 G05 P10000\n", "linuxcnc", 8, "'P10000' on a G5 line without X or Y"),  # LinuxCNC: a spline
])
def test_words_of_another_dialect_are_refused(tmp_path, mill, text, dialect, col, what):
    p = tmp_path / "p.nc"
    p.write_text("G21 G90 G17\nG0 X10 Y10 Z-20\nG1 X20 F100\n" + text + "G1 X30\nM30\n", encoding="latin-1")
    with pytest.raises(InputError) as err:
        parse_program(p, axis_words=AxisWords.of(mill), dialect=dialect)
    assert str(err.value).startswith(f"{p}: line 4, column {col}: ") and what in str(err.value), str(err.value)


def test_detection_reads_content_not_names(tmp_path):
    assert detect_dialect((DIALECTS / "haas.nc").read_text()) == ("haas", "G187 smoothness")
    assert detect_dialect((DIALECTS / "siemens_iso.nc").read_text())[0] == "siemens-iso"
    assert detect_dialect((DIALECTS / "fanuc.nc").read_text()) == ("fanuc", "G05.1 Q look-ahead")
    assert detect_dialect((DIALECTS / "mach3.tap").read_text()) == (RS274, "")
    with pytest.raises(ValueError, match="linuxcnc.*haas.*several dialects|haas.*linuxcnc.*several dialects"):
        detect_dialect("o<sub> sub\nG187 P1\n")
    p = tmp_path / "two.nc"  # the refusal names the later marker's line and column, and the other's line
    p.write_text("G21 G90\no<sub> sub\nG0 X1\n  N20 G187 P1\nM2\n")
    with pytest.raises(InputError) as err:
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="auto")
    assert str(err.value).startswith(f"{p}: line 4, column 7: G187 smoothness (haas) in a program that holds words "
                                     "of another dialect too (linuxcnc: o<name> subroutine, line 2)"), str(err.value)
    assert str(err.value).endswith("name its dialect with --dialect")
    p = tmp_path / "haas.ngc"  # a Haas program named like a LinuxCNC file: still Haas
    p.write_bytes((DIALECTS / "haas.nc").read_bytes())
    assert parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="auto").dialect == "haas"
