"""Subprograms, macros and parameters (compensation/nc_expand.py): expanded where the program determines
them, refused by name, line and column where it does not.

The programs in tests/data/nc_macros/ are written for these tests from the controllers' manuals (LinuxCNC
O-codes and parameters; Fanuc Custom Macro B, M98/M99, G65), each with its expected flat program worked
out by hand (``*.expected.*``): the expansion must equal it line for line, and the reader must find the
same programmed points in both."""
from pathlib import Path

import numpy as np
import pytest
from compensation import nc_expand
from compensation.gcode import AxisWords, parse_program, render_program
from compensation.nc_expand import expand_if_needed, expand_program
from errormap.io import InputError
from errormap.machine import load_machine

DATA = Path(__file__).parent / "data" / "nc_macros"
MILL = AxisWords.of(load_machine("mill-xyz"))
ACCEPTED = [("linuxcnc_osub.ngc", "linuxcnc_osub.expected.ngc", "linuxcnc"),
            ("fanuc_macro_b.nc", "fanuc_macro_b.expected.nc", "fanuc"),
            ("linuxcnc_blanks.ngc", "linuxcnc_blanks.expected.ngc", "linuxcnc"),
            ("fanuc_nested_loops.nc", "fanuc_nested_loops.expected.nc", "fanuc")]


def _ends(prog):
    return np.array([m.end for m in prog.moves])


@pytest.mark.parametrize("src,expected,dialect", ACCEPTED)
def test_accepted_programs_expand_to_the_hand_worked_flat_program(src, expected, dialect):
    text = (DATA / src).read_text(encoding="latin-1")
    e = expand_program(text, DATA / src)
    assert e.dialect == dialect
    assert e.text == (DATA / expected).read_text(encoding="latin-1")
    # every output line maps to a source line: verbatim ones are that line byte for byte
    src_lines = text.split("\n")
    for out, (ln, verbatim, _) in zip(e.text.split("\n"), e.origin):
        assert (out == src_lines[ln - 1]) == verbatim
    # the reader finds the same programmed points in the expanded program as in the hand-worked one
    prog, flat = parse_program(DATA / src, axis_words=MILL), parse_program(DATA / expected, axis_words=MILL)
    assert prog.expanded is not None and flat.expanded is None
    assert len(prog.moves) == len(flat.moves) and np.array_equal(_ends(prog), _ends(flat), equal_nan=True)


@pytest.mark.parametrize("fast", [True, False])
def test_written_program_is_the_expanded_one_with_a_note(fast):
    prog = parse_program(DATA / "fanuc_macro_b.nc", axis_words=MILL, fast=fast)
    comp = [m for m in prog.moves if m.compensate]
    text, _ = render_program(prog, [m.end[None, :] for m in comp])
    lines = text.splitlines(keepends=True)
    assert lines[2].startswith("(volcomp: subprograms, macros and parameters expanded by fanuc rules")
    flat = (DATA / "fanuc_macro_b.expected.nc").read_text(encoding="latin-1").splitlines(keepends=True)
    del lines[2]
    moved = {m.index for m in comp}
    assert [ln for i, ln in enumerate(lines) if i not in moved] == [ln for i, ln in enumerate(flat) if i not in moved]


def test_a_program_without_marks_is_not_touched():
    data = (Path(__file__).parent / "data" / "mill_pocket.nc").read_bytes()
    assert not nc_expand.needs_expansion(data)
    assert expand_if_needed(data, "p.nc") is None
    # a mark in a comment only: expanded to the same text, so read as it is
    assert expand_if_needed(b"G21 G90 (see #5 and IF)\nG0 X1 Y2 Z3\nM30\n", "p.nc") is None


REFUSED = [
    # (program, the refusal must contain)
    ("G21 G90\nG0 X0 Y0 Z5\nG1 X#5061 Y0\nM30\n", "line 3, column 5: #5061 (probe result"),
    ("G21\n#1 = #4120\nG0 X#1 Y0 Z0\nM30\n", "line 2, column 6: #4120 (modal information (#4120: current tool)"),
    ("G21\nG0 X0 Y0 Z0\nG1 X[#5420 + 1] Y0\n", "line 3, column 6: #5420 (current position)"),
    ("G21\no1 if [#<_current_tool> EQ 3]\nG0 X1 Y0 Z0\no1 endif\n",
     "line 2, column 8: #<_current_tool> is the controller's run-time state"),
    ("G21\nG0 X#<_x> Y0 Z0\n", "line 2, column 5: #<_x>: the X position is not known here"),
    ("G21\nG0 X#<depth> Y0 Z0\n", "line 2, column 5: #<depth> is not set by the program"),
    ("G21\n#500 = #500 + 1\nG0 X#500 Y0 Z0\n", "line 2, column 8: #500 is controller state"),
    ("G21\n#5221 = 10\nG0 X0 Y0 Z0\n", "line 2, column 1: #5221 = ...: #5221 (work offset"),
    ("G21\n#3000 = 1 (TOOL BROKEN)\n", "line 2, column 1: #3000 = ...: the program raises an alarm"),
    ("G21\nG0 X[1/0] Y0 Z0\n", "line 2, column 7: / by zero"),
    ("G21\nG0 X[0 ** -1] Y0 Z0\n", "line 2, column 8: 0 ** -1: zero to a negative power"),
    ("G21\nG0 X[SQRT[-1]] Y0 Z0\n", "line 2, column 6: SQRT of a negative number"),
    ("O1\nG0 X0 Y0 Z0\nM98 P2000\nM30\n", "line 3, column 5: M98 P2000: program O2000 is not in this file"),
    ("O1\nG0 X0 Y0 Z0\nM98 P20010\nM30\nO10\nG1 X1\nM99\n", "line 3, column 5: M98 P20010: on Fanuc the digits"),
    ("O1\nG0 X0 Y0 Z0\nM99\n", "line 3, column 1: M99 in the main program"),
    ("G21\no<probe> call [1]\nM2\n", "line 2, column 1: o<probe> call: the subroutine is not defined in this file"),
    ("G21\n/#1 = 2\n", "line 2, column 1: block delete"),
    ("%\n//O0001 SLOT (SHOP NOTE)\nG70\nG0 X1\n", "line 2, column 1: '//' is not a comment in G-code"),
    ("G21\n#1 = [1 + 2\n", "line 2, column 6: '[' without its ']'"),
    ("G21\n#1 = FOO[2]\n", "line 2, column 6: 'FOO' is not a function"),
    ("G21\n#1 = -2.5\nG0 X[FIX[#1]] Y0 Z0\n", "line 3, column 6: FIX of a negative number rounds one way"),
    ("O1\n#1 = 2.5\nG0 X[ROUND[#1]] Y0 Z0\nM30\n", "line 3, column 6: ROUND inside an address"),
    ("G21\no1 sub\nG1 X1\nM2\n", "line 2, column 1: o1 sub without its o1 endsub"),
    ("O1\nWHILE [1 EQ 1] DO1\nG1 X1\nM30\n", "line 2, column 1: WHILE .. DO1 without its END1"),
    ("O1\nGOTO 7\nM30\n", "line 2, column 1: GOTO 7: no block N7"),
]


@pytest.mark.parametrize("text,fragment", REFUSED)
def test_refusals_name_the_name_line_and_column(tmp_path, text, fragment):
    p = tmp_path / "prog.nc"
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        parse_program(p, axis_words=MILL)
    assert str(exc.value).startswith(f"{p}: line ") and fragment in str(exc.value), str(exc.value)


def test_a_refusal_inside_a_subprogram_names_the_source_line_and_the_call(tmp_path):
    p = tmp_path / "prog.nc"
    p.write_text("O1\nG21 G90\nG0 X0 Y0 Z0\nM98 P2 L2\nM30\nO2\nG91 G1 X5. H1\nM99\n")
    with pytest.raises(InputError, match=r"prog.nc: line 7, column 12 \(called from line 4\): 'H1'"):
        parse_program(p, axis_words=MILL)
    q = tmp_path / "q.nc"  # a line with values written in place: the column is the expanded line's
    q.write_text("#1 = 2\nG0 X#1 Y0 Z0 G43\n")
    with pytest.raises(InputError, match=r"q.nc: line 2 \(expanded as 'G0 X2 Y0 Z0 G43'\), column 13 of that"):
        parse_program(q, axis_words=MILL)


def test_endless_loops_and_recursion_are_refused_not_followed(tmp_path, monkeypatch):
    monkeypatch.setattr(nc_expand, "MAX_EXECUTED_LINES", 10_000)  # the bound, made small for a fast test
    with pytest.raises(InputError, match=r"p.ngc: line [234]: more than 10,000 lines executed"):
        expand_program("G21\no1 while [1]\nG1 X1\no1 endwhile\n", "p.ngc")
    with pytest.raises(InputError, match="p.nc: line [34]: more than 10,000 lines executed"):
        expand_program("O1\n#1 = 0\nN5 G1 X#1\nGOTO 5\n", "p.nc")
    with pytest.raises(InputError, match=rf"calls nested more than {nc_expand.MAX_CALL_DEPTH} deep"):
        expand_program("o<r> sub\nG1 X1\no<r> call\no<r> endsub\no<r> call\nM2\n", "p.ngc")


def test_call_site_moves_each_call_where_it_cuts():
    """Incremental subprogram moves land where each call starts them (every call expanded, not shared)."""
    text = "O1\nG21 G90\nG0 X0 Y0 Z0\nM98 P7 L3\nG0 X100\nM98 P7\nM30\nO7\nG91 G1 X10.\nG90\nM99\n"
    e = expand_program(text, "p.nc")
    assert e.text.count("G91 G1 X10.\n") == 4
    assert [o[2] for o in e.origin if o[0] == 9] == [(4,), (4,), (4,), (6,)]


def test_dialect_rules_where_the_controllers_differ():
    # FIX / FUP of a negative number, MOD, ATAN's range: LinuxCNC vs Fanuc
    lc = expand_program("o1 if [1]\no1 endif\nG1 X[FIX[-2.5]] Y[-7 MOD 3] Z[ATAN[-1]/[-1]]\n", "p.ngc")
    assert lc.text.splitlines()[0] == "G1 X-3 Y2 Z-135"
    fa = expand_program("O1\nG1 X[FIX[-2.5]] Y[-7 MOD 3] Z[ATAN[-1]/[-1]]\nM30\n", "p.nc")
    assert fa.text.splitlines()[1] == "G1 X-2 Y-1 Z225"
    # M98 P with more than four digits: the repeat count in front on Fanuc, a program number on Haas
    prog = "O1\nM98 P20010\nM30\nO10\nG1 X1\nM99\nO20010\nG1 X2\nM99\n"
    assert expand_program(prog, "p.nc", dialect="fanuc").text.count("G1 X1") == 2
    assert expand_program(prog, "p.nc", dialect="haas").text.count("G1 X2") == 1


def test_haas_m97_local_subprogram_and_g65_arguments():
    text = ("O1\nG21 G90\nG0 X0 Y0 Z5\nM97 P100 L2\nG65 P9 X7. Y[2*3]\nM30\nN100 G91 G1 X5.\nG90\nM99\n"
            "O9\nG1 X#24 Y#25 Z[#24 - #25]\nM99\n")
    e = expand_program(text, "p.nc")
    assert e.text == "O1\nG21 G90\nG0 X0 Y0 Z5\nN100 G91 G1 X5.\nG90\nN100 G91 G1 X5.\nG90\nG1 X7 Y6 Z1\nM30\n"
    assert [o[2] for o in e.origin] == [(), (), (), (4,), (4,), (4,), (4,), (5,), ()]


def test_a_guard_refusal_inside_a_call_names_the_source_line(tmp_path, capsys):
    from compensation.app.cli import main
    from test_chain_compensate import chain_elements
    el = chain_elements(load_machine("mill-xyz"), 5).save(tmp_path / "el.json")
    p = tmp_path / "sub.nc"  # the second call's incremental move leaves the X stroke [0, 600]
    p.write_text("O1\nG21 G90 G17\nG0 X100. Y100. Z-300.\nM98 P2 L2\nM30\nO2\nG91 G1 X300. F100.\nG90\nM99\n")
    assert main(["compensate", "--work-offsets", "machine",
                 str(p), "--machine", "mill-xyz", "--model", str(el), "--method", "exact",
                 "--out", str(tmp_path / "o")]) == 3
    err = capsys.readouterr().err
    assert "(line 7 (expanded line 6, called from line 4)): stroke: x_mm" in err
    assert "expanded line 4," not in err  # the first call stays inside the strokes


def test_linuxcnc_indirect_o_number_call(tmp_path):
    """LinuxCNC's manual (O-codes, "Computing values in O-words"): ``o[expr] call`` calls the subroutine numbered by
    the expression's value; written here: o[100+#1] with #1 = 20 calls o120, whose G1 moves to its arguments."""
    text = ("#1 = 20\no120 sub\nG1 X#1 Y#2 Z0 F100\no120 endsub\nG0 X0 Y0 Z0\no[100+#1] call [3] [4]\n"
            "o[100+#1] call [5] [6]\nM2\n")
    p = tmp_path / "ind.ngc"
    p.write_text(text)
    prog = parse_program(p, axis_words=MILL, dialect="linuxcnc")
    assert np.array_equal(_ends(prog), np.array([[0, 0, 0], [3, 4, 0], [5, 6, 0]], float))


@pytest.mark.parametrize("line,fragment", [
    ("o<sub> callsub", "line 2, column 12: 'o<sub> callsub': LinuxCNC reads the keyword 'call' and stops at 'sub' "
                       "(\"Unexpected character after O-word\""),
    ("o<sub> else iff", "line 2, column 15: 'o<sub> else iff': LinuxCNC reads the keyword 'elseif' and stops at 'f'"),
    ("o<sub> fetch", "line 2, column 8: 'o<sub> fetch': 'fetch' is not an O-word keyword"),
    ("o1 if [1] G0 X5", "line 2, column 11: unexpected 'G0 X5' after the statement (LinuxCNC: \"Unexpected character "
                        "after O-word\""),
    ("o[100] if [1]", "line 2, column 2: 'o[100] if': a computed O-number is read only with call"),
    ("o[2.5] call", "line 2, column 1: o[...] call: the O-number 2.5 is not a whole number"),
])
def test_o_word_keyword_and_indirect_number_refusals(tmp_path, line, fragment):
    p = tmp_path / "bad.ngc"
    p.write_text(f"G0 X0 Y0 Z0\n{line}\nM2\n")
    with pytest.raises(InputError) as e:
        parse_program(p, axis_words=MILL, dialect="linuxcnc")
    assert fragment in str(e.value), str(e.value)


@pytest.mark.parametrize("text,fragment", [
    # LinuxCNC and Fanuc read a function's argument only in '[ ]'; '(' opens a comment
    ("G21\n#<d> = [80/SQRT(2)/2]\nG0 X#<d> Y0 Z0\n", "line 2, column 12: SQRT needs its argument in '[ ]' ('(' opens a "
     "comment; LinuxCNC stops here too: \"Left bracket missing after unary operation name\"); write SQRT[...]"),
    # a macro word's first letters are not the word
    ("O1\n#1 = 0\nWH[#1 LT 2]DO1\n#1 = #1 + 1\nEND1\nM30\n", "line 3, column 1: 'WH' is not a macro word"),
    ("O1\n#1 = AB[-2]\nM30\n", "line 2, column 6: 'AB' is not a macro word"),
    # a named parameter is #<name> to LinuxCNC; '#$name$' it does not read
    ("#$level$ = 5\nG0 X#$level$ Y0 Z0\nM2\n", "line 1, column 1: '#$level$': LinuxCNC reads a named parameter only as "
     "#<name>"),
    # Custom Macro B's IF [..] THEN takes a statement on its line; a block form is not read
    ("O1\n#1 = 1\nIF [#1 EQ 2] THEN\nG0 X1 Y0 Z0\nENDIF\nM30\n", "line 3, column 13: IF [..] THEN with no statement"),
    # a '%' line frames the program (LinuxCNC ends it at the second one): text after it is no comment
    ("%\nG21 G90\n% vfd enable\nG0 X1 Y0 Z0\n%\n", "line 3, column 1: text after '%': 'vfd enable' ('%' on a line "
     "frames the program: LinuxCNC ends the program at a second '%' line"),
    # ':' is the program-number address, at a line's start only
    (": G90 G40 G94\nG17\nG0 X1 Y1 Z1\n", "line 1, column 1: unexpected character ':' (not an RS274 word; in ISO code "
     "':' is the program-number address, read only as ':1234'"),
    ("O1\n#1 = 2\n#2 = #1 - 1:\nG0 X#2 Y0 Z0\nM30\n", "line 3, column 12: unexpected character ':' (in ISO code ':' "
     "is the program-number address"),
])
def test_what_the_controllers_refuse_is_refused_naming_their_rule(tmp_path, text, fragment):
    p = tmp_path / "prog.nc"
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        parse_program(p, axis_words=MILL)
    msg = str(exc.value)
    assert fragment in msg and len(msg) - len(str(p)) < 300, msg


@pytest.mark.slow
@pytest.mark.parametrize("src", ["linuxcnc_blanks.ngc", "fanuc_nested_loops.nc"])
def test_expanded_macro_programs_are_compensated_where_they_cut(tmp_path, src):
    """Compensated on mill-xyz with the TRUE machine as the model and G54 from the shop's table, then judged by the
    independent check (benchmarks/suite/gcode_checks.py ``independent_check``: the lines that are not compensated moves
    the reader's flat program's byte for byte, every programmed point reached by the TRUE machine within
    ``TOL_POINT_UM``)."""
    from benchmarks.suite.gcode_checks import independent_check
    from benchmarks.suite.gcode_corpus import STYLE_TABLES, style_tables
    from compensation.app.cli import main
    from errormap.chain_elements import ChainElementSet
    from program_checks import TOL_POINT_UM
    mill = load_machine("mill-xyz")
    truth = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")  # ±10 μm / μrad, seed 11
    out = tmp_path / "o"
    assert main(["compensate", str(DATA / src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(out), "--work-offsets", str(STYLE_TABLES / "offsets.csv")]) == 0
    import json
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["true_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check below has teeth
    verdict = independent_check(DATA / src, out / src, "auto", truth, *style_tables())
    assert verdict.startswith("ok: "), verdict
    assert float(verdict.split()[2]) <= TOL_POINT_UM
