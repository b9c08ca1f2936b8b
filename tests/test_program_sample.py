"""The blind sample of public milling programs (benchmarks/program_corpus/MANIFEST.csv rows marked "blind sample";
README "The blind sample"): its rows are fresh and countable, the count's independent check compares the bytes a
controller reads (a CRLF program stays CRLF), the suite reports the sample's own figures, and the commonest refusal
of the sample (a move whose Z a G53 line set in machine coordinates) names the line that left Z unknown."""
import csv
import re
import json

import pytest

from benchmarks.suite.gcode_checks import independent_check
from benchmarks.suite.gcode_corpus import (HERE, MANIFEST, SAMPLE_MARK, STYLE_TABLES, sample_figures, sample_of,
                                           style_tables)
from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM
from test_rotary_machines import ROTARY_SAMPLE

SAMPLE_MIN = 40
"""The brief's sample size: at least 40 programs drawn by the written rule."""
ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), as the corpus count."""

# Written for this test from a Fusion 360 Fanuc post's wording (N numbers, G53 home, G43 H, an arc), CRLF line ends
# as Windows CAM stations save them.
CRLF_PROGRAM = "\r\n".join([
    "%", "O1001 (CRLF CHECK)", "(T1 D=6. - FLAT END MILL)", "N10 G90 G94 G17", "N15 G21", "N20 G53 G0 Z0.",
    "N25 T1 M6", "N30 S5000 M3", "N35 G54", "N40 G0 X10. Y10.", "N45 G43 Z15. H1", "N50 G1 Z-1. F300.", "N55 X40.",
    "N60 G2 X50. Y20. I0. J10.", "N65 G1 Y40.", "N70 G0 Z15.", "N75 M5", "N80 G53 G0 Z0.", "N85 M30", "%", ""])


def _sample_rows():  # the mill samples (the 4/5-axis one: tests/test_rotary_machines.py)
    return [r for r in csv.DictReader(MANIFEST.open(encoding="utf-8"))
            if SAMPLE_MARK in r["licence"] and sample_of(r["licence"]) != ROTARY_SAMPLE]


@pytest.fixture(scope="module")
def truth_file(tmp_path_factory):
    return ChainElementSet.random(load_machine("mill-xyz"), 101, ELEMENT_SCALE_UM, 11).save(
        tmp_path_factory.mktemp("t") / "truth.json")


def test_sample_rows_are_fresh_mill_programs_with_their_bytes_named():
    rows = _sample_rows()
    rest = [r for r in csv.DictReader(MANIFEST.open(encoding="utf-8")) if SAMPLE_MARK not in r["licence"]]
    assert len(rows) >= SAMPLE_MIN
    assert all(r["kind"] == "mill" and r["machine"] == "mill-xyz" and r["dialect"] == "auto" for r in rows)
    assert all(re.fullmatch(r"[0-9a-f]{64}", r["sha256"]) and re.fullmatch(r"[0-9a-f]{40}", r["commit"]) for r in rows)
    assert len({r["file"] for r in rows}) == len(rows)
    assert not {(r["repository"], r["path"]) for r in rows} & {(r["repository"], r["path"]) for r in rest}
    assert not {r["repository"] for r in rows} & {r["repository"] for r in rest}  # fresh repositories only
    assert all(r["file"].split("__", 1)[0].isidentifier() for r in rows)  # owner__path, as the README says
    readme = (HERE / "program_corpus" / "README.md").read_text(encoding="utf-8")
    assert "The blind sample" in readme and f"{len(rows)} " in readme


def test_sample_figures_count_only_the_sample_rows():
    one, two = "blind sample", "blind sample 2"
    res = [{"sample": one, "outcome": "accepted", "check": "ok: max 0.001 um at 3 points"},
           {"sample": one, "outcome": "accepted", "check": "WRONG: a line that is not a compensated move changed"},
           {"sample": one, "outcome": "refused", "reason": "x"},
           {"sample": one, "outcome": "crashed", "reason": "y"},
           {"sample": two, "outcome": "accepted", "check": "ok: max 0.002 um at 2 points"},
           {"sample": None, "outcome": "accepted", "check": "WRONG: z"}]
    acc, wrong, acc2, wrong2 = sample_figures(res)
    assert (acc["value"], acc["anchor_value"]) == ("2/4", 1)
    assert (wrong["value"], wrong["anchor_value"]) == (1, 2)
    assert (acc2["value"], wrong2["value"], wrong2["anchor_value"]) == ("1/1", 0, 1) and "second" in acc2["what"]
    assert sample_figures([{"sample": None, "outcome": "accepted"}]) == []
    assert [sample_of(f"no licence checked; not copied; {m} (program_corpus/README.md); x") for m in (one, two)] \
        == [one, two] and sample_of("GPL-2.0 (LinuxCNC)") is None


def test_a_crlf_program_is_checked_byte_for_byte(tmp_path, truth_file):
    """Its non-motion lines come back CRLF, byte for byte: the check passes; one line's CR dropped: WRONG."""
    prog = tmp_path / "crlf.nc"
    prog.write_bytes(CRLF_PROGRAM.encode("latin-1"))
    out = tmp_path / "o"
    assert main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(truth_file), "--truth",
                 str(truth_file), "--method", "exact", "--out", str(out), "--dialect", "auto", "--work-offsets",
                 str(STYLE_TABLES / "offsets.csv"), "--tool-table", str(STYLE_TABLES / "tools.csv")]) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["true_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check below has teeth
    written = (out / prog.name).read_bytes()
    assert b"N75 M5\r\n" in written
    verdict = independent_check(prog, out / prog.name, "auto", truth_file, *style_tables())
    assert verdict.startswith("ok: "), verdict
    bad = tmp_path / "bad" / prog.name
    bad.parent.mkdir()
    bad.write_bytes(written.replace(b"N75 M5\r\n", b"N75 M5\n"))
    assert independent_check(prog, bad, "auto", truth_file, *style_tables()).startswith("WRONG")


@pytest.mark.parametrize("text, line, col, why", [
    # Fusion 360 for Personal Use: "Using high feed G1 F5000. instead of G0." after its G53 home, before G43
    ("G90 G94 G17\nG21\nG53 G0 Z0.\nT1 M6\nG54\nG1 X7.392 Y-58.862 F5000.\nG0 G43 Z16. H1\n", 6, 4,
     "line 3 moved Z in machine coordinates (G53)"),
    ("G21 G90 G54\nG1 X1 Y2 F100\n", 2, 4, "give Z in the program (absolute) before this move"),
    # Z given after the G53 and then unknown by the G54 selection: the G53 is not why
    ("G21 G90\nG53 G0 Z0.\nG0 Z5.\nG54\nG1 X1 Y2 F100\n", 5, 4, "give Z in the program (absolute) before this move"),
])
def test_a_move_before_z_is_known_names_why(tmp_path, text, line, col, why):
    p = tmp_path / "p.nc"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="auto")
    msg = str(e.value)
    assert f"line {line}, column {col}:" in msg and "no value yet for Z" in msg and why in msg, msg
    assert ("G53" in msg) == ("G53" in why)
    assert len(msg) - len(str(p)) < 300


@pytest.mark.parametrize("text, kept", [
    # grbl / LinuxCNC / Fanuc: a G0 or G1 with Z alone moves Z and keeps X, Y where the machine stands (the
    # position at cycle start when the program has not given them): written as programmed, listed, not compensated
    ("G21 G90 G54\nG0 Z5.\nG0 X1. Y2.\nG1 Z-1. F100\n", [2]),
    ("G90\nG21\nM3 S10000\nG1 F1200.0 Z4.0\nG1 F1200.0 X3.08 Y-22.95\nG1 F100.0 Z-3.0\n", [4]),
])
def test_z_alone_before_x_y_are_given_is_written_as_programmed(tmp_path, text, kept):
    from compensation.nc_state import program_frames, read_work_offsets
    p = tmp_path / "p.nc"
    p.write_text(text)
    prog = parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="auto")
    assert all(not m.compensate for m in prog.moves if m.index + 1 in kept)
    assert all(m.compensate for m in prog.moves if m.kind == "linear" and m.index + 1 not in kept)
    frames = program_frames(prog, read_work_offsets(STYLE_TABLES / "offsets.csv"), None)
    assert frames.notes["moves_before_position_known"] == kept


@pytest.mark.parametrize("text, line, why", [
    ("G21 G90 G54\nG1 X1. Y2. Z3. F100\nG55\nG1 Z5.\n", 4, "no value yet for X, Y"),  # given, then a new system
    ("G21 G90\nG53 G0 X0 Y0\nG1 Z5. F100\nG54\n", 3, "moved X, Y in machine coordinates (G53)"),
    ("G21 G90 G54\nG1 Z5. X1. F100\n", 2, "no value yet for Y"),              # not Z alone
])
def test_z_alone_is_refused_once_x_or_y_was_given(tmp_path, text, line, why):
    p = tmp_path / "p.nc"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="auto")
    assert f"line {line}," in str(e.value) and why in str(e.value), str(e.value)


def test_a_machine_files_harmless_m_codes_pass_and_are_listed(tmp_path):
    """``[controller] harmless_m`` of a machine file: its M codes pass (the file says they move nothing) and the
    frames' notes list where; the built-in machine still refuses them; a malformed list names its key."""
    from errormap.machine_tool_file import MachineFileError
    from compensation.nc_state import program_frames, read_work_offsets
    base = (HERE.parent / "errormap" / "machines" / "mill-xyz.toml").read_text(encoding="utf-8")
    (tmp_path / "m.toml").write_text(base + '\n[controller]\nharmless_m = ["M252"]\n', encoding="utf-8")
    p = tmp_path / "p.nc"
    p.write_text("G21 G90 G54\nM252\nG0 X1. Y2. Z5.\nG1 Z-1. F100\nM30\n")
    machine = load_machine(tmp_path / "m.toml")
    prog = parse_program(p, axis_words=AxisWords.of(machine), dialect="auto")
    frames = program_frames(prog, read_work_offsets(STYLE_TABLES / "offsets.csv"), None)
    assert frames.notes["machine_m_codes"] == ["line 2: M252"]
    with pytest.raises(InputError, match="line 2, column 1: 'M252': M code not on"):
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="auto")
    (tmp_path / "bad.toml").write_text(base + '\n[controller]\nharmless_m = [252]\n', encoding="utf-8")
    with pytest.raises(MachineFileError, match="controller.harmless_m"):
        load_machine(tmp_path / "bad.toml")
