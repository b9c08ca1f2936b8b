"""A Fanuc/Haas lathe's words as shops write them (compensation/turning.py, gcode_classify.py, gcode_state.py).

* X as a diameter or a radius is a parameter of the control (Fanuc 0i-TF: parameter 1006 bit 3, "the move
  command for each axis is based on diameter specification"), so it is set once in the machine's file
  (``[spindle] x_words``); ``--lathe-x`` overrides it for one run and the summary records which decided. The
  built-in ``lathe-xzc`` leaves it unset (no manual settles its control): such a program's X is refused naming
  both the option and the key.
* ``TttOO`` (tool ``tt``, offset register ``OO``): a word's leading zeros may be left out, so ``T202`` is
  ``T0202``; one or two digits (``T2``) are refused (the control takes the offset register from them by a
  machine setting: the station's own geometry offset, or register ``OO``), five or more are no ``TttOO``.

Every program here is written from that wording, not copied."""
import json

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError
from errormap.machine_checks import MachineFileError
from errormap.machine import builtin_machine_path, load_machine

LATHE = "lathe-xzc"
PROGRAM = "G18 G21 G40\nG0 X60. Z310.\nS500 M3\nG1 X50. Z300. F0.2\nG1 Z280.\nG0 X80.\nM5\nM30\n"
"""A Fanuc turning program in machine coordinates (Z along the bed, inside its stroke): X 60, 50, 80 (diameters
or radii by the control's parameter)."""
PROGRAM_X = [60.0, 50.0, 50.0, 80.0]
"""The X word in force at each move of :data:`PROGRAM`, as written."""
TOL_MM = 1e-12
"""The X read is the written value or its half: exact to round-off."""
MAX_MESSAGE = 300


def _machine_file(tmp_path, line: str):
    """``lathe-xzc``'s file with ``line`` added to its ``[spindle]`` table."""
    text = builtin_machine_path(LATHE).read_text()
    path = tmp_path / "lathe.toml"
    path.write_text(text.replace('turning_off = ["M5"]', f'turning_off = ["M5"]\n{line}'))
    return path


def _x_read(tmp_path, machine, dialect="fanuc", lathe_x=None, text=PROGRAM):
    p = tmp_path / "p.nc"
    p.write_text(text)
    prog, _ = parse_lathe_program(p, machine, "keep", None, dialect, lathe_x=lathe_x)
    return [m.end[0] for m in prog.moves]


@pytest.mark.parametrize("dialect", ["fanuc", "haas", "siemens-iso"])
def test_the_machine_files_x_words_is_read_and_the_option_overrides_it(tmp_path, dialect):
    dia = load_machine(_machine_file(tmp_path, 'x_words = "diameter"'))
    assert dia.spindle["x_words"] == "diameter"
    assert np.abs(np.array(_x_read(tmp_path, dia, dialect)) - np.array(PROGRAM_X) / 2).max() <= TOL_MM
    assert np.abs(np.array(_x_read(tmp_path, dia, dialect, "radius")) - PROGRAM_X).max() <= TOL_MM
    rad = load_machine(_machine_file(tmp_path, 'x_words = "radius"'))
    assert np.abs(np.array(_x_read(tmp_path, rad, dialect)) - PROGRAM_X).max() <= TOL_MM
    assert np.abs(np.array(_x_read(tmp_path, rad, dialect, "diameter")) - np.array(PROGRAM_X) / 2).max() <= TOL_MM


def test_the_builtin_lathe_leaves_x_unset_and_the_refusal_names_option_and_key(tmp_path):
    with pytest.raises(InputError) as err:
        _x_read(tmp_path, load_machine(LATHE))
    msg = str(err.value)
    assert "line 2, column 4: 'X60.'" in msg and "--lathe-x diameter|radius" in msg and "[spindle] x_words" in msg
    assert len(msg) - len(str(tmp_path)) < MAX_MESSAGE, msg


@pytest.mark.parametrize("value", ['"diam"', '"Diameter"', "2", "true"])
def test_an_invalid_x_words_is_refused_naming_file_and_key(tmp_path, value):
    path = _machine_file(tmp_path, f"x_words = {value}")
    with pytest.raises(MachineFileError) as err:
        load_machine(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: key 'spindle.x_words': expected \"diameter\" or \"radius\", got"), msg


def test_a_linuxcnc_program_says_it_with_g7_g8_and_the_key_is_not_read(tmp_path):
    """LinuxCNC starts in radius mode (G8) and switches with G7: the machine file's key changes nothing there."""
    dia = load_machine(_machine_file(tmp_path, 'x_words = "diameter"'))
    text = PROGRAM.replace("G18 G21 G40", "G18 G21 G40 G8")
    assert np.abs(np.array(_x_read(tmp_path, dia, "linuxcnc", text=text)) - PROGRAM_X).max() <= TOL_MM
    text = PROGRAM.replace("G18 G21 G40", "G18 G21 G40 G7")
    assert np.abs(np.array(_x_read(tmp_path, dia, "linuxcnc", text=text)) - np.array(PROGRAM_X) / 2).max() <= TOL_MM


def test_the_summary_records_who_decided(tmp_path):
    path = _machine_file(tmp_path, 'x_words = "diameter"')
    machine = load_machine(path)
    truth = tmp_path / "truth.json"
    ChainElementSet.random(machine, 101, 10.0, 11).save(truth)
    src = tmp_path / "p.nc"
    src.write_text(PROGRAM)
    args = ["compensate", str(src), "--machine", str(path), "--model", str(truth), "--method", "exact",
            "--dialect", "fanuc", "--work-offsets", "machine"]
    got = {}
    for name, extra in (("file", []), ("option", ["--lathe-x", "radius"]), ("same", ["--lathe-x", "diameter"])):
        assert main(args + extra + ["--out", str(tmp_path / name)]) == 0
        entry = json.loads((tmp_path / name / "compensate_summary.json").read_text())["files"][0]
        got[name] = (entry["lathe_x"], entry["lathe_x_source"])
    assert got == {"file": ("diameter", "machine file [spindle] x_words"), "option": ("radius", "--lathe-x"),
                   "same": ("diameter", "--lathe-x")}
    written = {n: (tmp_path / n / src.name).read_text() for n in got}
    assert written["file"] == written["same"] != written["option"]  # the key reads as the option does


# ---------------------------------------------------------------------------- TttOO with leading zeros left out
T_PROGRAM = "G18 G21 G40\n{t}\nG0 X60. Z10.\nG1 Z-20. F0.2\nM30\n"
XZ = AxisWords(LATHE, ("X", "Z"), ())


def _tool_events(tmp_path, t, dialect, axis_words=XZ):
    p = tmp_path / "t.nc"
    p.write_text(T_PROGRAM.format(t=t))
    prog = parse_program(p, axis_words=axis_words, dialect=dialect, lathe_x="radius")
    return [(e[0], e[1], e[3]) for e in prog.events if e[2] == "tool"]


@pytest.mark.parametrize("dialect", ["fanuc", "haas"])
def test_a_three_digit_t_word_is_its_four_digit_form(tmp_path, dialect):
    """T202 = T0202 (tool 02, register 02); T1000 and T100 (register 00) cancel the offset alike."""
    assert _tool_events(tmp_path, "T202", dialect) == _tool_events(tmp_path, "T0202", dialect) == [(1, 1, 2)]
    assert _tool_events(tmp_path, "T112", dialect) == _tool_events(tmp_path, "T0112", dialect) == [(1, 1, 12)]
    assert _tool_events(tmp_path, "T100", dialect) == _tool_events(tmp_path, "T0100", dialect) == [(1, 1, None)]


@pytest.mark.parametrize("dialect", ["fanuc", "haas"])
@pytest.mark.parametrize("word, why", [("T2", "1 or 2 digits leave the offset register to a machine setting"),
                                       ("T02", "1 or 2 digits leave the offset register to a machine setting"),
                                       ("T20200", "not four digits"), ("T2.5", "not four digits")])
def test_other_lathe_t_words_are_refused_naming_the_word(tmp_path, dialect, word, why):
    p = tmp_path / "t.nc"
    with pytest.raises(InputError) as err:
        _tool_events(tmp_path, f"G0 {word}", dialect)
    msg = str(err.value)
    assert msg.startswith(f"{p}: line 2, column 4: '{word}': a {dialect} lathe's T word is TttOO") and why in msg \
        and "T0202" in msg and len(msg) - len(str(tmp_path)) < MAX_MESSAGE, msg


def test_on_a_mill_the_t_word_stays_a_tool_number(tmp_path):
    """X, Y and Z: T only selects the tool (its length comes from G43 H), however many digits."""
    mill = AxisWords.of(load_machine("mill-xyz"))
    p = tmp_path / "m.nc"
    for t in ("T2", "T202", "T20200"):
        p.write_text(f"G21 G90\n{t} M6\nG0 X1 Y1 Z1\nG1 X2 F100\nM30\n")
        assert [e for e in parse_program(p, axis_words=mill, dialect="fanuc").events if e[2] == "tool"] == []


def test_a_lathe_keeps_the_machine_files_harmless_m_codes(tmp_path):
    """The turning reader (X and Z words, C left out) keeps ``[controller] harmless_m``: a vendor's code the file
    lists passes, the same code without the file's word is refused naming it."""
    text = PROGRAM.replace("S500 M3", "S500 M3\nM155")
    with pytest.raises(InputError, match=r"line 4, column 1: 'M155': M code not on the fanuc allow-list"):
        _x_read(tmp_path, load_machine(LATHE), lathe_x="radius", text=text)
    listed = load_machine(_machine_file(tmp_path, '\n[controller]\nharmless_m = ["M155"]'))
    assert np.abs(np.array(_x_read(tmp_path, listed, lathe_x="radius", text=text)) - PROGRAM_X).max() <= TOL_MM
