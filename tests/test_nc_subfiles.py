"""Subprograms kept outside the program (``compensate --subprograms DIR``, compensation/nc_subfiles.py).

Test programs written for this project from the controllers' manuals (not copied files): tests/data/nc_subfiles.
Fanuc: ``M98 P9100`` of program O9100 kept in the control's memory (the folder), found by its program-number
line; the folder's file named ``O9100.nc`` holds program O9200 (a file's name says nothing). LinuxCNC:
``o<drill_man> call`` reads ``drill_man.ngc`` (SUBROUTINE_PATH's rule). Judged against the same program with the
subprogram put in the file (what the reader already expands), and on mill-xyz by the independent check."""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from compensation.gcode import AxisWords, parse_program
from compensation.nc_expand import expand_program
from compensation.nc_subfiles import SubprogramFiles
from errormap.io import InputError
from errormap.machine import load_machine

DATA = Path(__file__).parent / "data" / "nc_subfiles"
CASES = [("fanuc_main.nc", "fanuc_memory", "slot_cycle.nc"), ("linuxcnc_main.ngc", "linuxcnc_subs", "drill_man.ngc")]


def in_file(main: str, sub: str) -> str:
    """The program with its subprogram put in the file, as the controllers' manuals allow: Fanuc's after the main
    program (before the closing '%'), LinuxCNC's o<> sub … endsub before the calls (its file's M2 left out)."""
    text, lines = (DATA / main).read_text(), [ln for ln in sub.splitlines(keepends=True) if ln.strip() != "%"]
    if main.endswith(".nc"):
        body = text.rstrip("\n").rsplit("\n", 1)[0] + "\n"  # without the closing '%'
        return body + "".join(lines) + "%\n"
    head, rest = text.split("o<drill_man> call", 1)
    first = next(k for k, ln in enumerate(lines) if ln.startswith("o<drill_man> sub"))
    last = next(k for k, ln in enumerate(lines) if ln.startswith("o<drill_man> endsub"))
    return head + "".join(lines[first:last + 1]) + "o<drill_man> call" + rest


@pytest.mark.parametrize("main,folder,name", CASES)
def test_a_call_reads_the_file_and_expands_as_in_the_file(main, folder, name):
    lib = SubprogramFiles([DATA / folder])
    e = expand_program((DATA / main).read_text(), DATA / main, None, None, lib)
    ref = expand_program(in_file(main, (DATA / folder / name).read_text()), "ref", None)
    assert e.text == ref.text  # the flat program a controller runs without the folder
    sha = hashlib.sha256((DATA / folder / name).read_bytes()).hexdigest()
    assert [(p, h) for _, p, h in e.files] == [(str(DATA / folder / name), sha)]
    assert sha[:16] in e.note()
    inner = [k for k, o in enumerate(e.origin) if o[2]]
    assert inner and all(e.at(e.origin[k][0])[0] == str(DATA / folder / name) for k in inner)


@pytest.mark.parametrize("main,folder,name", CASES)
def test_without_the_option_the_call_is_refused_naming_it(main, folder, name):
    with pytest.raises(InputError, match="--subprograms DIR") as exc:
        parse_program(DATA / main, axis_words=AxisWords.of(load_machine("mill-xyz")))
    assert len(str(exc.value)) - len(str(DATA / main)) < 300


def test_number_not_found_two_files_with_the_number_and_a_missing_ngc_are_refused(tmp_path):
    only_9200 = tmp_path / "a"
    only_9200.mkdir()
    shutil.copy(DATA / "fanuc_memory" / "O9100.nc", only_9200)  # holds O9200: its name is not its number
    text = (DATA / "fanuc_main.nc").read_text()
    with pytest.raises(InputError, match=r"line 5, column 5: M98 P9100: program O9100 is neither in this file nor in "
                                         r"--subprograms .*no file there has the program-number line O9100"):
        expand_program(text, "fanuc_main.nc", None, None, SubprogramFiles([only_9200]))
    twice = tmp_path / "b"
    twice.mkdir()
    shutil.copy(DATA / "fanuc_memory" / "slot_cycle.nc", twice / "one.nc")
    (twice / "two.txt").write_text(":9100 (SAME NUMBER, HAAS STYLE)\nG0 X1\nM99\n")
    with pytest.raises(InputError, match=r"program O9100 is in two files, .*one\.nc and .*two\.txt") as exc:
        expand_program(text, "fanuc_main.nc", None, None, SubprogramFiles([twice]))
    assert len(str(exc.value)) < 300 + len(str(twice)) * 2
    with pytest.raises(InputError, match=r"o<drill_man> call: not defined in this file and no drill_man\.ngc in "
                                         r"--subprograms"):
        expand_program((DATA / "linuxcnc_main.ngc").read_text(), "m.ngc", None, None, SubprogramFiles([twice]))
    (twice / "drill_man.ngc").write_text("o<other> sub\nG0 X1\no<other> endsub\nM2\n")
    with pytest.raises(InputError, match=r"drill_man\.ngc does not define o<drill_man> sub"):
        expand_program((DATA / "linuxcnc_main.ngc").read_text(), "m.ngc", None, None, SubprogramFiles([twice]))
    with pytest.raises(InputError, match="--subprograms .*: not a folder"):
        SubprogramFiles([tmp_path / "none"])


def test_a_refusal_inside_the_file_names_the_file_and_its_line(tmp_path):
    (tmp_path / "drill_man.ngc").write_text("o<drill_man> sub\nG0 X#7 Y0\no<drill_man> endsub\n")
    with pytest.raises(InputError, match=r"drill_man\.ngc: line 2, column 5 \(called from line 4\): #7 "):
        expand_program((DATA / "linuxcnc_main.ngc").read_text(), "m.ngc", None, None, SubprogramFiles([tmp_path]))


@pytest.mark.slow
@pytest.mark.parametrize("main,folder,name", CASES)
def test_compensated_on_mill_xyz_per_call_where_it_cuts(tmp_path, main, folder, name):
    """As tests/test_nc_expand.py's macro programs: the TRUE machine as the model, G54 from the shop's table, judged by
    the independent check (benchmarks/suite/gcode_checks.py ``independent_check``) against the program with its
    subprogram in the file: other lines byte for byte, every programmed point reached within ``TOL_POINT_UM``."""
    from benchmarks.suite.gcode_checks import independent_check
    from benchmarks.suite.gcode_corpus import STYLE_TABLES, style_tables
    from compensation.app.cli import main as cli
    from errormap.chain_elements import ChainElementSet
    from program_checks import TOL_POINT_UM
    truth = ChainElementSet.random(load_machine("mill-xyz"), 101, 10.0, 11).save(tmp_path / "truth.json")  # seed 11
    out = tmp_path / "o"
    assert cli(["compensate", str(DATA / main), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                "--method", "exact", "--out", str(out), "--work-offsets", str(STYLE_TABLES / "offsets.csv"),
                "--subprograms", str(DATA / folder)]) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    sha = hashlib.sha256((DATA / folder / name).read_bytes()).hexdigest()
    assert e["subprogram_files"] == [{"path": str(DATA / folder / name), "sha256": sha}]
    assert e["true_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check below has teeth
    ref = tmp_path / main
    ref.write_text(in_file(main, (DATA / folder / name).read_text()))
    verdict = independent_check(ref, out / main, "auto", truth, *style_tables())
    assert verdict.startswith("ok: "), verdict
    assert float(verdict.split()[2]) <= TOL_POINT_UM
