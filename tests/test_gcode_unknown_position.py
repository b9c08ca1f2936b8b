"""Where the program position is not known, as the controllers' manuals say, and what the reader does there:
a ``G0`` rapid before every axis is known is written as programmed and listed (RS274NGC / LinuxCNC / Fanuc: an
axis the line does not name stays where the machine stands, which the program does not say; a rapid cuts
nothing), a feed move there is refused; a probe move ``G38.2``-``G38.5`` (RS274NGC v3 "Straight Probe", LinuxCNC
"G38.x", grbl v1.1) is written as programmed and leaves the axes it names unknown (it stops where the probe
trips), its result ``#5061``... refused by name; a file with CR-only line ends (old Mac style) is read with CR as
the line end and written with CR again. The programs are this project's, written from the manuals' wording.
Accepted ones are compensated and checked independently (tests/program_checks.py: every non-motion line
byte-identical, every programmed point of a compensated move reproduced by the TRUE machine within 1 μm)."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.chain_gcode import parse_chain_program
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import program_frames, read_work_offsets
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, true_point_errors_um

PART_ZERO_MM = (300.0, 200.0, -300.0)
"""The one work system (G54) of these programs: inside mill-xyz's strokes (the corpus count's part zero)."""
ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), a real mill's size (tests/test_work_offsets.py)."""
MAX_MESSAGE = 300
"""A refusal is one line of fewer than 300 characters besides the file's path."""


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture()
def offsets(tmp_path):
    p = tmp_path / "offsets.csv"
    p.write_text("system,x_mm,y_mm,z_mm\nG54," + ",".join(str(v) for v in PART_ZERO_MM) + "\n")
    return p


@pytest.fixture()
def truth_file(tmp_path, mill):
    return ChainElementSet.random(mill, 101, ELEMENT_SCALE_UM, 11).save(tmp_path / "truth.json")


def _read(tmp_path, text, mill, **kw):
    p = tmp_path / "p.ngc"
    p.write_bytes(text.encode("latin-1"))
    progs = [parse_program(p, axis_words=AxisWords.of(mill), fast=fast, **kw) for fast in (True, False)]
    a, b = ([(m.index, m.kind, m.compensate, tuple(np.nan_to_num(m.end, nan=-1e9))) for m in q.moves] for q in progs)
    assert a == b  # the block-wise reader and the per-line reference agree
    return progs[1]


def _refusal(tmp_path, text, mill, **kw) -> str:
    p = tmp_path / "p.ngc"
    p.write_bytes(text.encode("latin-1"))
    msgs = set()
    for fast in (True, False):
        with pytest.raises(InputError) as e:
            parse_program(p, axis_words=AxisWords.of(mill), fast=fast, **kw)
        msgs.add(str(e.value))
    assert len(msgs) == 1
    msg = msgs.pop()
    assert "\n" not in msg and len(msg) - len(str(p)) < MAX_MESSAGE, msg
    return msg


def _compensated(tmp_path, src, offsets, truth_file, *extra):
    out = tmp_path / "o"
    rc = main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth_file), "--truth",
               str(truth_file), "--method", "exact", "--out", str(out), "--work-offsets", str(offsets), *extra])
    assert rc == 0
    return out / src.name, json.loads((out / "compensate_summary.json").read_text())["files"][0]


def _checked(src, written, mill, truth_file, dialect=None, rapids="keep"):
    errs = true_point_errors_um(src, written, mill, ChainElementSet.load(truth_file, mill),
                                {"G54": PART_ZERO_MM}, {}, dialect=dialect, rapids=rapids)
    assert errs.size and errs.max() < TOL_POINT_UM, errs
    return errs


# ---------------------------------------------------------------------------- rapids before the position is known
RAPIDS_FIRST = "G21 G90 G54\nG0 X10.\nG0 Y5.\nG0 Z5.\nG1 Z-1. F100\nG1 X20. Y8.\nG0 Z5.\n"


def test_a_rapid_before_every_axis_is_known_is_written_as_programmed_and_listed(tmp_path, mill):
    """``--rapids compensate``: the first rapids (X alone, then Y) leave the other axes where the machine stands;
    written as programmed, listed, not compensated; from the first line where all three are known on, every move
    is compensated."""
    prog = _read(tmp_path, RAPIDS_FIRST, mill, rapids="compensate", dialect="auto")
    assert [(m.index + 1, m.compensate) for m in prog.moves] == [(2, False), (3, False), (4, True), (5, True),
                                                                 (6, True), (7, True)]
    frames = program_frames(prog, read_work_offsets_csv(tmp_path), None)
    assert frames.notes["moves_before_position_known"] == [2, 3]


def read_work_offsets_csv(tmp_path):
    p = tmp_path / "offsets_g54.csv"
    p.write_text("system,x_mm,y_mm,z_mm\nG54,300,200,-300\n")
    return read_work_offsets(p)


@pytest.mark.parametrize("text, line, word, why", [
    # a feed before Z is known: the controller would cut at a Z the program does not say
    ("G21 G90 G54\nG0 X10.\nG1 Y5. F100\n", 3, "'Y5.'", "no value yet for Z"),
    ("G21 G90 G54\nG0 X10. Y5.\nG2 X12. Y7. I1. J1. F100\n", 3, "'X12.'", "no value yet for Z"),
    # a lathe-like X before the others: an X feed alone is not the Z-alone first retract
    ("G21 G90 G54\nG0 Z5.\nG1 X1. F100\n", 3, "'X1.'", "no value yet for Y"),
])
def test_a_feed_move_before_every_axis_is_known_is_refused_saying_why(tmp_path, mill, text, line, word, why):
    for rapids in ("keep", "compensate"):
        msg = _refusal(tmp_path, text, mill, rapids=rapids, dialect="auto")
        assert f"line {line}, column" in msg and word in msg and why in msg, msg
        assert "a feed may cut: only a G0 is kept" in msg and "give" in msg, msg


def test_rapids_before_the_position_is_known_compensated_and_checked(tmp_path, mill, offsets, truth_file):
    src = tmp_path / "rapids.ngc"
    src.write_text(RAPIDS_FIRST)
    written, entry = _compensated(tmp_path, src, offsets, truth_file, "--rapids", "compensate")
    src_lines, out_lines = src.read_text().splitlines(), written.read_text().splitlines()
    assert src_lines[1] in out_lines and src_lines[2] in out_lines  # the two first rapids, byte for byte
    assert len(_checked(src, written, mill, truth_file, rapids="compensate")) == 4  # every compensated end (4-7)


# ---------------------------------------------------------------------------- probing
PROBING = ("G21 G90 G54 G40\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\nG0 Z5.\nG38.3 X30. F50\nX35.\nG0 X10.\n"
           "G1 Z-1. F100\nG1 X20. Y8.\nG0 Z5.\nM2\n")


def test_a_probe_move_is_written_as_programmed_and_leaves_its_axes_unknown(tmp_path, mill):
    """LinuxCNC "G38.x": straight probe, motion group 1 (``X35.`` after ``G38.3`` probes again); the probe lines
    are not moves of the path (written unchanged, recorded as probe events); after each the named axis must be
    given absolutely, and it is (``G0 Z5.``, ``G0 X10.``), so every later move is compensated."""
    for dialect in ("linuxcnc", "grbl", "auto", None):
        prog = _read(tmp_path, PROBING, mill, dialect=dialect)
        assert [prog.classes[i] for i in (2, 4, 5)] == ["state"] * 3
        assert [(e[0] + 1, e[3], e[4]) for e in prog.events if e[2] == "probe"] == [
            (3, ("Z",), "G38.2"), (5, ("X",), "G38.3"), (6, ("X",), "G38.3")]
        assert [m.index + 1 for m in prog.moves if m.compensate] == [8, 9]
    assert program_frames(prog, read_work_offsets_csv(tmp_path), None).notes["probe_lines"] == [3, 5, 6]


@pytest.mark.parametrize("text, line, words", [
    # the probed Z not given again: a feed there is refused, naming the probe line
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\nG1 X20. F100\n", 4, ("line 3 probed Z", "G38.2")),
    # an incremental move from the probed position
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\nG91 G1 Z1. F100\n", 4, ("incremental", "before Z is known")),
    # an offset set from the probed position (the usual touch-off): its value is known only at run time
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\nG10 L20 P1 Z0\n", 4, ("'G10 L20 P1' sets Z", "not known")),
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\nG92 Z0\n", 4, ("'G92 Z0' sets Z", "not known")),
    # the probe result read: refused by name
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\n#1 = #5063\nG0 Z[#1 + 5]\nG1 X20. F100\n", 4,
     ("#5063", "probe result")),
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.3 Z-20. F50\no1 if [#5070 EQ 0]\nM2\no1 endif\n", 4, ("#5070",)),
    # as LinuxCNC refuses it: probing with cutter radius compensation on; arc words on a probe line
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG41 D1\nG38.2 Z-20. F50\n", 4, ("cutter radius compensation (G41) on",)),
    ("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. I1. F50\n", 3, ("'I1.'", "arc words")),
])
def test_what_depends_on_the_probed_position_is_refused(tmp_path, mill, text, line, words):
    msg = _refusal(tmp_path, text, mill, dialect="linuxcnc")
    assert f"line {line}" in msg and all(w in msg for w in words), msg


def test_probing_on_a_controller_that_probes_with_g31_is_refused_naming_the_dialects(tmp_path, mill):
    for dialect in ("fanuc", "haas", "siemens-iso", "mach3"):
        msg = _refusal(tmp_path, PROBING, mill, dialect=dialect)
        assert "line 3, column 1: 'G38.2'" in msg and "on linuxcnc, grbl it is a probe move" in msg, msg


def test_a_canned_cycle_after_a_probe_needs_its_z_again(mill, tmp_path):
    p = tmp_path / "c.ngc"
    p.write_text("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\nG81 X1. Y1. Z-2. R1. F100\nG80\n")
    for cycles in ("keep", "expand"):
        with pytest.raises(InputError, match=r"line 4, column 1: G81: the Z before the cycle .* not known after a "
                                             r"probe move"):
            parse_chain_program(p, mill, dialect="linuxcnc", cycles=cycles)
    p.write_text("G21 G90 G54\nG0 X10. Y5. Z5.\nG38.2 Z-20. F50\nG0 Z5.\nG81 X1. Y1. Z-2. R1. F100\nG80\n")
    assert any(m.compensate for m in parse_chain_program(p, mill, dialect="linuxcnc", cycles="keep").moves)


def test_a_probing_program_compensated_and_checked(tmp_path, mill, offsets, truth_file):
    src = tmp_path / "probe.ngc"
    src.write_text(PROBING)
    written, entry = _compensated(tmp_path, src, offsets, truth_file, "--dialect", "linuxcnc")
    out = written.read_text().splitlines()
    for ln in PROBING.splitlines()[2:6]:  # the probe lines and the rapid between them, byte for byte
        assert ln in out
    assert len(_checked(src, written, mill, truth_file, dialect="linuxcnc")) == 2


# ---------------------------------------------------------------------------- CR-only line ends
CR_PROGRAM = "%\nO1001 (MAC)\nG21 G90 G54\nG0 X10. Y5. Z5.\nG1 Z-1. F100\nG1 X40. Y25.\nG0 Z5.\nM30\n%\n"


def test_cr_only_line_ends_are_read_and_written_back_with_cr(tmp_path, mill, offsets, truth_file):
    """CR is the line end of a file that has no LF (old Mac style; the controllers end a block at CR as at LF):
    read line by line, compensated, and written with CR line ends; every non-motion line byte-identical."""
    src = tmp_path / "mac.nc"
    src.write_bytes(CR_PROGRAM.replace("\n", "\r").encode())
    prog = _read(tmp_path, CR_PROGRAM.replace("\n", "\r"), mill, dialect="auto")
    assert prog.line_end == "\r" and len(prog.lines) == CR_PROGRAM.count("\n")
    written, entry = _compensated(tmp_path, src, offsets, truth_file)
    raw = written.read_bytes()
    assert b"\n" not in raw and raw.endswith(b"%\r")
    moves = (b"G1", b"X", b"(volcomp")  # compensated moves, the vertices added to them, the header
    assert [ln for ln in raw.split(b"\r") if not ln.startswith(moves)] == [
        ln for ln in src.read_bytes().split(b"\r") if not ln.startswith(moves)]
    assert len(_checked(src, written, mill, truth_file)) == 2  # the two G1 ends (rapids kept)


def test_mixed_line_ends_are_refused(tmp_path, mill):
    text = "G21 G90 G54\r" + "G0 X1. Y1. Z1.\r" * 5000 + "G1 X2. F100\n"  # CR-only over 64 KiB, then LF
    msg = _refusal(tmp_path, text, mill)
    assert "CR-only line endings" in msg and "mixed line ends" in msg and "convert" in msg, msg
