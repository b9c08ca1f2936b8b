"""LinuxCNC words read exactly (compensation/gcode_state.py, turning.py): the G92 coordinate offset and its
G92.1/G92.2/G92.3 (LinuxCNC G-code reference, "G92 Coordinate System Offset": the current point reads the
values given, every work system shifts by the same amount; G92.1 clears the offset and its stored values,
G92.2 clears the offset only, G92.3 restores the stored values). Each test program is written here from that
wording; accepted programs are compensated on a simulated truth and checked independently of the reader's
frames (the offsets by hand from the manual); what cannot be read exactly is refused naming file, line,
column, word and the option."""
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import program_frames, read_work_offsets
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, _groups

DATA = Path(__file__).resolve().parent / "data" / "linuxcnc_words"
WORK_MM = np.array([300.0, 200.0, -300.0])
"""G54 of the tests: a part zero inside mill-xyz's strokes."""
G92_BY_LINE = {**{n: (10.0, 10.0, 0.0) for n in range(4, 8)}, **{n: (0.0, 0.0, 0.0) for n in range(8, 12)},
               **{n: (10.0, 10.0, 0.0) for n in range(12, 17)}, **{n: (0.0, 0.0, 0.0) for n in range(17, 20)}}
"""g92_offsets.ngc by the manual's wording (1-based lines): line 3 ends at X10 Y10 and line 4's ``G92 X0 Y0``
makes that point read 0 0 (offset 10 10); ``G92.2`` (line 8) suspends it, ``G92.3`` (line 12) restores it,
``G92.1`` (line 17) clears it."""
MSG_MAX = 240
"""A refusal is one line under 300 characters with a plain path: its text past the test's temporary folder."""
TOL_FRAME_MM = 1e-12
"""Offsets are sums of the program's decimal values: exact to float round-off."""


@pytest.fixture()
def offsets(tmp_path):
    p = tmp_path / "offsets.csv"
    p.write_text("system,x_mm,y_mm,z_mm\nG54,%g,%g,%g\n" % tuple(WORK_MM))
    return p


def _read(text, tmp_path, dialect="linuxcnc", name="p.ngc"):
    p = tmp_path / name
    p.write_text(text)
    return p, parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect=dialect)


def test_g92_frames_follow_the_manual(offsets):
    prog = parse_program(DATA / "g92_offsets.ngc", axis_words=AxisWords.of(load_machine("mill-xyz")),
                         dialect="linuxcnc")
    frames = program_frames(prog, read_work_offsets(offsets), None)
    for m in prog.moves:
        want = WORK_MM + (G92_BY_LINE.get(m.index + 1, (0.0, 0.0, 0.0)))
        assert np.abs(frames.at([m.index])[0][0] - want).max() <= TOL_FRAME_MM, m.index + 1
    assert frames.notes["g92_lines"] == [4, 8, 12, 17]


def test_g92_program_compensated_reaches_every_point(tmp_path, offsets):
    """The written program run as LinuxCNC runs it: the G92 lines unchanged and preceded by the same kept
    rapids, so the controller takes the same offsets (by hand, :data:`G92_BY_LINE`); every programmed end
    point is reached by the TRUE machine within 1 um and every other line is byte-identical."""
    mill = load_machine("mill-xyz")
    truth = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")
    src = DATA / "g92_offsets.ngc"
    assert main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(tmp_path / "out"), "--dialect", "linuxcnc",
                 "--work-offsets", str(offsets)]) == 0
    aw = AxisWords.of(mill)
    p_src = parse_program(src, axis_words=aw, fast=False, dialect="linuxcnc")
    p_out = parse_program(tmp_path / "out" / src.name, axis_words=aw, fast=False, dialect="linuxcnc")
    comp = {m.index: m for m in p_src.moves if m.compensate}
    out_moves = {m.index: m for m in p_out.moves}
    field, errs = ChainField(mill, ChainElementSet.load(truth, mill)), []
    for i, g in enumerate(_groups(p_src.lines, p_out.lines)):
        if i not in comp:
            assert [p_out.lines[k] for k in g] == [p_src.lines[i]]
            continue
        shift = WORK_MM + G92_BY_LINE[i + 1]
        q = out_moves[g[-1]].end + shift
        tip = mill.nominal(q[None])[0] + field.predict(q[None])[0] * 1e-3
        errs.append(np.linalg.norm(tip - mill.nominal((comp[i].end + shift)[None])[0]) * 1e3)
    assert len(errs) == 6 and max(errs) <= TOL_POINT_UM, errs


@pytest.mark.parametrize("text, dialect, line, col, words", [
    ("G21 G90\nG0 X1 Y2 Z3\nG91\nG92 X0\nG90\nG1 X5 F100\n", "linuxcnc", 4, 1, ("'G92' under G91", "G90")),
    ("G21 G90\nG0 X1 Y2\nG92 Z0\nG1 X5 Z1 F100\n", "linuxcnc", 3, 5, ("'G92 Z0'", "not known")),
    ("G21 G90\nG0 X1 Y2 Z3\nG1 X4 F100\nG92 X0\nG1 X5\n", "linuxcnc", 4, 1,
     ("'G92' takes its offset", "line 3", "--rapids keep")),
    ("G21 G90\nG0 X1 Y2 Z3\nG92 X0\nG1 X5 F100\n", "fanuc", 3, 1, ("'G92'", "--dialect linuxcnc or grbl")),
    ("G21 G90\nG0 X1 Y2 Z3\nG92.2\nG1 X5 F100\n", "grbl", 3, 1, ("'G92.2'", "G92 and G92.1 only")),
    ("G21 G90\nG0 X1 Y2 Z3\nG92.1 X0\nG1 X5 F100\n", "linuxcnc", 3, 7, ("'X0' with G92.1",)),
])
def test_g92_refusals_name_line_column_word_and_option(tmp_path, offsets, text, dialect, line, col, words):
    with pytest.raises(InputError) as err:
        p, prog = _read(text, tmp_path, dialect)
        program_frames(prog, read_work_offsets(offsets), None)
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line {line}, column {col}: ") and len(msg) - len(str(tmp_path)) < MSG_MAX, msg
    assert all(w in msg for w in words), msg


def test_a_lathe_program_without_c_is_refused_for_its_own_word_not_for_c(tmp_path):
    """A turning program with no C word is read with X and Z: its refusal names its own word (here the
    G72 facing cycle's P, a word it does not read: compensation/nc_g7x.py), not the C it never uses."""
    from compensation.turning import parse_lathe_program
    p = tmp_path / "face.ngc"
    p.write_text("G18 G21 G90\nG0 X30 Z5\nS800 M3\nG1 X20 Z0 F0.2\nG72 X0 Z-2 P1 Q2\nM5\nM2\n")
    with pytest.raises(InputError) as err:
        parse_lathe_program(p, load_machine("lathe-xzc"), "keep", None, "linuxcnc")
    assert str(err.value).startswith(f"{p}: line 5, column 12: 'P1' on a G72 line"), str(err.value)


# ---------------------------------------------------------------------------- G33, G33.1, G4 with motion
SYNCED_TARGETS = {3: (20.0, 30.0, 5.0), 5: (20.0, 30.0, -12.0), 6: (60.0, 30.0, 5.0), 7: (60.0, 30.0, -12.0),
                  9: (10.0, 10.0, 5.0), 10: (10.0, 10.0, -20.0)}
"""tap_and_thread.ngc by the manual's wording (1-based lines): G33.1 moves synchronised from the current point
to the one given and back, so the rapid of line 6 starts at the first tap's start (X20 Y30 Z5) and only moves
X (the second tap from X60 Y30 Z5); G33 is a straight synchronised line to its end. The rapids to a synchronised
move's start (lines 3, 6, 9) are compensated: the spindle's index synchronises the move there."""
K_BY_CODE = {"G33.1": 1.25, "G33": 2.0}
"""The file's K per code."""
TAP_TOL_UM = 1.0
"""--arc-tolerance-um of the accepted run: the file's taps bend 0.725 um along the hole on this truth (refused at the
default 0.5 um)."""


def _compensated(tmp_path, src, offsets, extra=()):
    mill = load_machine("mill-xyz")
    truth = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")
    assert main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(tmp_path / "out"), "--dialect", "linuxcnc",
                 "--work-offsets", str(offsets), *extra]) == 0
    aw = AxisWords.of(mill)
    p_src = parse_program(src, axis_words=aw, fast=False, dialect="linuxcnc")
    p_out = parse_program(tmp_path / "out" / src.name, axis_words=aw, fast=False, dialect="linuxcnc")
    return mill, ChainField(mill, ChainElementSet.load(truth, mill)), p_src, p_out


def test_g33_pieces_and_g33_1_carry_k_prime_true_lead_k_and_reach_every_point(tmp_path, offsets, capsys):
    """LinuxCNC keeps the synchronisation along a chain of G33 moves (motion(9): the index is awaited "before the
    start of every chain of spindle-synchronized moves"): a G33 is split, each piece with K' = K x commanded / programmed
    length along the drive line; a G33.1 (a tap and its return) is one move with one K' from its compensated start and
    bottom, refused where the field bends more than --arc-tolerance-um along the hole. Judged here on the truth: every
    programmed point reached within 1 um, every written synchronised move's TRUE travel per revolution (K' x true /
    commanded length) equals K within LEAD_TOL_REL; I kept; every other line byte-identical."""
    from compensation.nc_thread import LEAD_TOL_REL
    src = DATA / "tap_and_thread.ngc"
    mill = load_machine("mill-xyz")
    truth = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")
    rc = main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
               "--method", "exact", "--out", str(tmp_path / "refused"), "--dialect", "linuxcnc", "--work-offsets",
               str(offsets)])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc != 0 and f"{src}: line 5: 'G33.1' (a tap and its return, one K): the field bends " in err
    assert float(err.split("bends ")[1].split(" um")[0]) > 0.5 and "more than --arc-tolerance-um 0.5;" in err
    mill, field, p_src, p_out = _compensated(tmp_path, src, offsets, ("--arc-tolerance-um", f"{TAP_TOL_UM:g}"))
    assert np.array_equal(next(m for m in p_src.moves if m.index == 5).start, [20.0, 30.0, 5.0])
    assert [ln for ln, c in zip(p_src.lines, p_src.classes) if c != "move"] == \
        [ln for ln, c in zip(p_out.lines, p_out.classes) if c != "move" and not ln.startswith("(volcomp:")]
    assert sum(ln.startswith("G33.1 ") and ln.rstrip().endswith(" I2") for ln in p_out.lines) == 1

    def tip(p):  # the TRUE tool point of program axes p (n, 3)
        q = np.asarray(p) + WORK_MM
        return mill.nominal(q) + field.predict(q) * 1e-3
    out = [m for m in p_out.moves if m.compensate]
    j = 0
    for line, target in SYNCED_TARGETS.items():  # in order: the first later written move that reaches it
        want = mill.nominal((np.array(target) + WORK_MM)[None])[0]
        while j < len(out) and np.linalg.norm(tip(out[j].end[None])[0] - want) * 1e3 > TOL_POINT_UM:
            j += 1
        assert j < len(out), f"line {line}'s point reached by no written move"
        j += 1
    synced = [m for m in out if m.synced]
    assert [m.synced for m in synced].count("G33.1") == 2 and [m.synced for m in synced].count("G33") >= 2
    true_len = np.linalg.norm(tip([m.end for m in synced]) - tip([m.start for m in synced]), axis=1)
    revs = np.array([np.linalg.norm(m.end - m.start) / m.lead[0] for m in synced])  # the written K'
    true_k = true_len / revs
    assert np.abs(true_k / [K_BY_CODE[m.synced] for m in synced] - 1.0).max() <= LEAD_TOL_REL


def test_a_synchronised_rotary_move_is_refused_naming_the_word(tmp_path):
    """K follows the drive line X Y Z (LinuxCNC G-code reference, G33's note): a G33 that also turns A is not read."""
    p = tmp_path / "p.ngc"
    p.write_text("G21 G90\nG0 X1 Y2 Z3 A0\nS500 M3\nG33 Z-5 A10 K1\nM2\n")
    with pytest.raises(InputError) as err:
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyza")), dialect="linuxcnc")
    assert str(err.value).startswith(f"{p}: line 4, column 9: 'A10' on a G33 line: K follows the drive line X Y Z")


def test_a_dwell_line_moves_in_the_motion_mode_on_linuxcnc(tmp_path, offsets):
    """RS274NGC / LinuxCNC: G4 uses no axis words, so 'G4 P0.5 G1 X20 ...' dwells, then moves (and 'G4 P0.2 X30'
    moves in the G1 mode in force): both compensated, their P kept."""
    src = DATA / "dwell_then_move.ngc"
    mill, field, p_src, p_out = _compensated(tmp_path, src, offsets)
    ends = {m.index + 1: m.end for m in p_src.moves if m.compensate}
    assert list(ends) == [3, 4] and np.array_equal(ends[4], [30.0, 15.0, 2.0])
    for i in (2, 3):
        assert p_out.lines[i].startswith(p_src.lines[i][:8])  # 'G4 P0.5 ' / 'G4 P0.2 '
        q = next(m for m in p_out.moves if m.index == i).end + WORK_MM
        tip = mill.nominal(q[None])[0] + field.predict(q[None])[0] * 1e-3
        assert np.linalg.norm(tip - mill.nominal((ends[i + 1] + WORK_MM)[None])[0]) * 1e3 <= TOL_POINT_UM


@pytest.mark.parametrize("text, dialect, line, col, words", [
    ("G21 G90\nG0 X1 Y2 Z3\nS500 M3\nG33.1 Z-5\nM2\n", "linuxcnc", 4, 1, ("'G33.1' needs K",)),
    ("G21 G90\nG0 X1 Y2 Z3\nS500 M3\nG33 Z-5 K1 I2\nM2\n", "linuxcnc", 4, 12, ("'I2' with G33",)),
    ("G21 G90\nG0 X1 Y2 Z3\nS500 M3\nG33.1 Z-5 K1\nM2\n", "fanuc", 4, 1, ("'G33.1'", "--dialect linuxcnc")),
    ("G21 G90\nG0 X1 Y2 Z3\nG04 X1.5\nG1 X5 F100\n", "haas", 3, 5, ("'X1.5' with G4", "--dialect")),
])
def test_synchronised_and_dwell_refusals_name_line_column_word_and_option(tmp_path, offsets, text, dialect, line,
                                                                          col, words):
    with pytest.raises(InputError) as err:
        _read(text, tmp_path, dialect)
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line {line}, column {col}: ") and len(msg) - len(str(tmp_path)) < MSG_MAX, msg
    assert all(w in msg for w in words), msg


# ---------------------------------------------------------------------------- G7 / G8 on the lathe
LATHE_Z_MM = 200.0
"""G54 Z of the lathe tests: the part's face 200 mm along the bed (inside Z's stroke)."""
DIAMETER_TARGETS = {5: (25.0, 0.0), 6: (25.0, -20.0), 7: (30.0, -25.0), 9: (32.0, -30.0), 11: (30.0, -30.0)}
"""diameter_mode.ngc by LinuxCNC's wording (1-based lines: radius, Z mm): under G7 every X is a diameter (X50 ->
25; the arc's R5 a radius), G8 (line 8) reads X32 as a radius, G7 again and 'G91 G1 X-4' moves the radius by -2."""


def test_diameter_mode_reads_x_halved_and_writes_it_doubled(tmp_path):
    """The written program run in LinuxCNC's modes (G7/G8 lines unchanged): the TRUE tool tip over one turn of the
    spindle is on the programmed surface of revolution within 1 um at every programmed end point; every other line
    byte-identical; the X numbers written in G7 are diameters (about twice the radius)."""
    from compensation.turning import parse_lathe_program, surface_residual_um
    lathe = load_machine("lathe-xzc")
    src = DATA / "diameter_mode.ngc"
    prog, _ = parse_lathe_program(src, lathe, "keep", None, "linuxcnc")
    ends = {m.index + 1: tuple(m.end) for m in prog.moves if m.compensate}
    assert ends == DIAMETER_TARGETS
    offsets = tmp_path / "offsets.csv"
    offsets.write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{LATHE_Z_MM}\n")
    truth = ChainElementSet.random(lathe, 101, 10.0, 11).save(tmp_path / "truth.json")
    assert main(["compensate", str(src), "--machine", "lathe-xzc", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(tmp_path / "out"), "--dialect", "linuxcnc",
                 "--work-offsets", str(offsets)]) == 0
    out, _ = parse_lathe_program(tmp_path / "out" / src.name, lathe, "keep", None, "linuxcnc")
    out_moves = {m.index: m for m in out.moves}
    axes, want = [], []
    for i, g in enumerate(_groups(prog.lines, out.lines)):
        if i + 1 not in DIAMETER_TARGETS:
            assert [out.lines[k] for k in g] == [prog.lines[i]]
            continue
        m = out_moves[g[-1]]
        axes.append([m.end[0], m.end[1] + LATHE_Z_MM, 0.0])
        want.append([DIAMETER_TARGETS[i + 1][0], DIAMETER_TARGETS[i + 1][1] + LATHE_Z_MM, 0.0])
        if m.diameter and not m.incremental:
            assert abs(float(m.words["X"].text) - 2 * m.end[0]) < 1e-9  # the number written is the diameter
    mean, _ = surface_residual_um(ChainField(lathe, ChainElementSet.load(truth, lathe)), lathe, np.array(axes),
                                  np.array(want))
    assert len(axes) == 5 and np.abs(mean).max() <= TOL_POINT_UM, mean


def test_x_of_a_fanuc_family_lathe_program_is_refused(tmp_path):
    """Fanuc, Haas, Siemens ISO lathes: X is a diameter or a radius by a machine parameter: refused naming the
    first X word, never guessed."""
    from compensation.turning import parse_lathe_program
    p = tmp_path / "t.nc"
    p.write_text("G18 G21 G90\nG0 X60. Z5.\nS800 M3\nG1 X50. Z0 F0.2\nM5\nM30\n")
    with pytest.raises(InputError) as err:
        parse_lathe_program(p, load_machine("lathe-xzc"), "keep", None, "fanuc")
    assert str(err.value).startswith(f"{p}: line 2, column 4: 'X60.': on a fanuc lathe X is a diameter or a radius"), \
        str(err.value)


# ---------------------------------------------------------------------------- #<_x> and the modes
PREDEFINED_TARGETS = {4: (15.0, 20.0, 5.0), 5: (15.0, 22.0, 5.0), 7: (15.0, 22.0, -2.0), 9: (17.54, 22.0, -2.0)}
"""predefined_parameters.ngc by the manual's wording (LinuxCNC "Predefined Named Parameters": #<_x> the current X in
the current coordinate system and units; #<_incremental>, #<_metric> 1 or 0), 1-based lines of the flat program
(mm): X[#<_x> + 5] after X10 is X15; #<inc> = 1 (read under G91); the if takes Z[#<_z> - 7] = -2; under G20
X[#<_x> + 0.1] is 15/25.4 + 0.1 inch = 17.54 mm and Y[#<_y> * 1] stays 22 mm."""
TOL_EXPANDED_MM = 1e-6
"""The flat program's numbers carry 10 decimals of an inch (2.5e-9 mm)."""


def test_predefined_parameters_are_read_from_the_lines_before(tmp_path, offsets):
    mill = load_machine("mill-xyz")
    src = DATA / "predefined_parameters.ngc"
    prog = parse_program(src, axis_words=AxisWords.of(mill), dialect="linuxcnc")
    ends = {m.index + 1: m.end for m in prog.moves if m.compensate}
    assert set(ends) == set(PREDEFINED_TARGETS)
    assert all(np.abs(ends[n] - PREDEFINED_TARGETS[n]).max() <= TOL_EXPANDED_MM for n in ends), ends
    mill_, field, p_src, p_out = _compensated(tmp_path, src, offsets)
    head = sum(1 for ln in p_out.lines if ln.startswith("(volcomp:"))  # the writer's note: a flat program
    assert head == 1 and p_out.lines[0].startswith("(volcomp: subprograms, macros and parameters expanded")
    out_moves = {m.index - head: m for m in p_out.moves}
    errs = []
    for i, g in enumerate(_groups(p_src.lines, p_out.lines[head:])):
        if i + 1 not in PREDEFINED_TARGETS:
            assert [p_out.lines[head + k] for k in g] == [p_src.lines[i]]
            continue
        q = out_moves[g[-1]].end + WORK_MM
        tip = mill.nominal(q[None])[0] + field.predict(q[None])[0] * 1e-3
        errs.append(np.linalg.norm(tip - mill.nominal((np.array(PREDEFINED_TARGETS[i + 1]) + WORK_MM)[None])[0]) * 1e3)
    assert len(errs) == 4 and max(errs) <= TOL_POINT_UM, errs


@pytest.mark.parametrize("text, line, col, words", [
    ("G21 G90\nG0 X1 Y2\nG1 Z[#<_z> - 1] F100\nM2\n", 3, 6, ("#<_z>", "Z position is not known")),
    # a probe move stops where the probe trips: the Z it moves is not known after it (its X is: the line keeps it)
    ("G21 G90\nG0 X1 Y2 Z3\nG38.2 Z-5 F50\nG1 X[#<_z> + 1]\nM2\n", 4, 6, ("#<_z>", "Z position is not known")),
    ("G18 G21 G90 G7\nG0 X20 Z3\nG1 X[#<_x> - 1] F100\nM2\n", 3, 6, ("#<_x>", "diameter mode")),
])
def test_predefined_parameters_refused_where_the_program_does_not_determine_them(tmp_path, text, line, col, words):
    with pytest.raises(InputError) as err:
        _read(text, tmp_path, "linuxcnc")
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line {line}, column {col}: ") and len(msg) - len(str(tmp_path)) < MSG_MAX, msg
    assert all(w in msg for w in words), msg


def test_a_dwell_between_splines_stays_a_dwell(tmp_path):
    """In G5 mode a 'G4 P0.5' line is a dwell (its P is not the spline's): no move; 'G4 P0.5 X1' is refused."""
    _, prog = _read("G21 G90 G17\nG0 X0 Y0 Z0\nG5 X10 Y0 I2 J2 P-2 Q2 F100\nG4 P0.5\nX20 Y0 P-2 Q2\nM2\n", tmp_path)
    assert [m.index + 1 for m in prog.moves if m.compensate] == [3, 5]
    with pytest.raises(InputError, match=r"line 4, column 1: a spline line with G4"):
        _read("G21 G90 G17\nG0 X0 Y0 Z0\nG5 X10 Y0 I2 J2 P-2 Q2 F100\nG4 P0.5 X1\nM2\n", tmp_path)
