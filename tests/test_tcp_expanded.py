"""G93 inverse-time feed inside a LinuxCNC subroutine (compensation/tcp.py ``flat_prepass``): the pre-pass runs on
the flat program the subroutine expander writes, so every G93 block executed in a call has its own line and F; each
split block's F is recomputed so its time is kept (tests/test_tcp.py's checks, on the flat program). Tool-centre-point
control in such a program stays refused. Program written here from the LinuxCNC G-code reference ("G93 Inverse Time
Mode": F is the inverse of the block's time in minutes, on every feed block; "O Codes": sub, call with [arguments]),
not copied."""
import re

import pytest
from test_tcp import TIME_REL_TOL, TRUE_EXACT_UM, g93_block_times, models, run  # noqa: F401 (models: fixture)

from compensation.app.cli import main
from compensation.nc_expand import expand_program

PROGRAM = """(G93 in a subroutine called twice, LinuxCNC)
G21 G90 G17
G54
T1 M6
G43 H1
o100 sub
  G93 G1 X[#1] Y10 Z-150 A-10 C[#2] F30
  X[#1 + 20] Y-10 Z-153 A-20 C[#2 + 30] F20
  G94
o100 endsub
G0 X0 Y0 Z-145 A0 C0
o100 call [0] [0]
o100 call [-15] [90]
G0 Z-145
M2
"""
"""Four G93 feed blocks (two per call), the second call's in another place: each block's time 1/F (1/30, 1/20 min).
Joint mode (no TCP): the machine's Z is the program's + the G54 offset (20 mm) + the tool (120 mm), inside its
stroke for Z ≤ -140."""


def test_g93_in_a_called_subroutine_keeps_every_block_time(models):
    rc, entry, prog, out = run(models, PROGRAM, "linuxcnc", "sub93.ngc")
    assert rc == 0 and entry["true"]["max_um"] <= TRUE_EXACT_UM
    flat = expand_program(PROGRAM, prog, "linuxcnc").text
    pairs = g93_block_times(flat, out.read_text())
    assert len(pairs) == 4
    for want, got in pairs:
        assert abs(got - want) <= TIME_REL_TOL * want
    written = out.read_text()
    assert len(re.findall(r"F", written)) > len(re.findall(r"F", flat))  # blocks split, each piece its F
    assert written.startswith("(volcomp: subprograms, macros and parameters expanded by linuxcnc rules")
    bare = lambda text: [ln for ln in text.splitlines() if not re.search(r"[XYZAC]\s*[-\d.]", ln.split("(")[0])]  # noqa
    assert bare(written)[1:] == bare(flat)  # the lines that move nothing, as the flat program writes them


def test_tcp_in_a_called_subroutine_is_refused_at_its_source_line(models, capsys):
    mt, truth, _, d = models
    prog = d / "subtcp.ngc"
    prog.write_text(PROGRAM.replace("G43 H1\n", "G43 H1\nM428\n"))
    rc = main(["compensate", str(prog), "--machine", "five-axis-ac", "--model", str(truth), "--method", "exact",
               "--out", str(d / "tcp"), "--work-offsets", str(d / "wo.csv"), "--tool-table", str(d / "tt.csv"),
               "--dialect", "linuxcnc"])
    err = capsys.readouterr().err
    assert rc != 0 and not (d / "tcp" / "subtcp.ngc").exists()
    assert "subtcp.ngc: line 6, column 1: tool-centre-point control in a program whose subprograms" in err, err


@pytest.mark.parametrize("word, where", [("M428", "line 4, column 1: 'M428': "), ("G93", "line 4, column 1: 'G93': "),
                                         ("M429", "line 4: ")])
def test_tcp_or_g93_with_expanded_cycles_is_refused_at_its_source_line(models, capsys, word, where):
    """--expand-cycles writes a flat program, in which TCP and G93 are not supported: the refusal names the first such
    word's line and column (it named the file alone); a TCP-off word alone, its line."""
    mt, truth, _, d = models
    prog = d / f"cyc{word}.ngc"
    prog.write_text(f"G21 G90 G17\nG54\nT1 M6\n{word}\nG94\nG0 X0 Y0 Z-145 A0 C0\nG81 R-140 Z-146 F100\nX5\nG80\nM2\n")
    rc = main(["compensate", str(prog), "--machine", "five-axis-ac", "--model", str(truth), "--method", "exact",
               "--out", str(d / f"cyc{word}"), "--work-offsets", str(d / "wo.csv"), "--tool-table", str(d / "tt.csv"),
               "--dialect", "linuxcnc", "--expand-cycles"])
    err = capsys.readouterr().err
    assert rc != 0 and not (d / f"cyc{word}" / prog.name).exists()
    assert f"{prog.name}: {where}tool-centre-point or G93 words in a program whose canned cycles" in err, err
