"""Issue 30 (G-code part): block delete on every piece, T offset words, bounded planning.

Each test is the reproduction of one reported defect."""
import time

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.nc_state import MACHINE, read_work_offsets
from compensation.chain_gcode import MAX_PATH_POINTS, MAX_SEGMENTS_PER_MOVE
from compensation.pathio import stroke_diagonal_mm
from errormap.io import InputError
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth
from path_files import read_as_compensate, render_gcode

MCS = read_work_offsets(MACHINE)
"""The G-code programs here are written in machine coordinates (the grinder's axes): read with
--work-offsets machine (a program is never read at an assumed zero)."""

REFUSAL_S = 5.0
"""A refused plan must come back at once (it used to allocate for minutes): 5 s is generous for
parsing a few lines and one vectorised check on a loaded 2-core machine."""


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def _write(tmp_path, text, name="prog.nc"):
    p = tmp_path / name
    p.write_text(text, encoding="latin-1")
    return p


def test_block_delete_slash_is_on_every_piece_of_a_split_move(tmp_path, machine):
    src = _write(tmp_path, "G21 G90 G18\nG1 X10 Z1 A0 F100\n/G1 X30\nG1 X31\n")
    tp = read_as_compensate(src, machine, block_delete="off", max_segment_mm=2.0, work_offsets=MCS)
    _, groups = render_gcode(tp, tp.axes)
    assert len(groups[2]) == 10  # 20 mm in 2 mm pieces
    assert all(g.startswith("/") for g in groups[2]), groups[2]
    assert not any(g.startswith("/") for g in groups[3])
    # a controller with block delete switched on skips the whole move, not only its first piece
    out = _write(tmp_path, "".join(ln for g in groups for ln in g), "out.nc")
    skipped = read_as_compensate(out, machine, block_delete="on", work_offsets=MCS)
    assert skipped.lines.tolist() == [2, 13]
    assert np.allclose(skipped.axes[:, 0], [10.0, 31.0])


def test_block_delete_slash_is_on_every_chord_of_an_arc(tmp_path, machine):
    src = _write(tmp_path, "G21 G90 G18\nG1 X20 Z5 A0 F100\n/G2 X25 Z10 I5 K0\nG1 X26\n")
    tp = read_as_compensate(src, machine, block_delete="off", work_offsets=MCS)
    _, groups = render_gcode(tp, tp.axes)
    assert len(groups[2]) > 1 and all(g.startswith("/") for g in groups[2]), groups[2]
    assert groups[2][0].startswith("/G1 ")
    out = _write(tmp_path, "".join(ln for g in groups for ln in g), "out.nc")
    assert len(read_as_compensate(out, machine, block_delete="on", work_offsets=MCS)) == 2


@pytest.mark.parametrize("word", ["T0101", "T101", "T01 01", "T1.5", "T-1"])
def test_t_word_that_may_select_an_offset_is_refused_like_g43(tmp_path, machine, word):
    src = _write(tmp_path, f"G21 G90 G18\nG1 X10 Z1 A0 F100\n{word} M6\nG1 X11\n")
    with pytest.raises(InputError, match=r"prog\.nc: line 3, column 1: 'T.*offset.*G43"):
        read_as_compensate(src, machine, work_offsets=MCS)


@pytest.mark.parametrize("word", ["T1", "T01", "T12"])
def test_a_plain_tool_number_passes(tmp_path, machine, word):
    src = _write(tmp_path, f"G21 G90 G18\nG1 X10 Z1 A0 F100\n{word} M6\nG1 X11\n")
    tp = read_as_compensate(src, machine, work_offsets=MCS)
    _, groups = render_gcode(tp, tp.axes)
    assert groups[2] == [f"{word} M6\n"]


def test_no_decimal_typo_is_refused_as_a_unit_typo_before_any_work(tmp_path, machine):
    src = _write(tmp_path, "G21 G90 G18\nG1 X100. Z0.3 A0 F100\nG01 X110000 Z35000 A30000\n")
    diag = stroke_diagonal_mm(machine)
    for seg in (None, "auto", 1e-6):
        t0 = time.process_time()
        kw = {"field_": _field(machine)} if seg == "auto" else {}
        with pytest.raises(InputError) as exc:
            read_as_compensate(src, machine, max_segment_mm=seg, **kw, work_offsets=MCS)
        assert time.process_time() - t0 < REFUSAL_S
        msg = str(exc.value)
        assert msg.startswith(f"{src}: line 3, column 5: 'X110000'"), msg
        assert f"stroke diagonal {diag:.6g} mm" in msg and "unit typo" in msg and "mm (G21" in msg
        assert "\n" not in msg


def test_inch_typo_names_the_inch_unit(tmp_path, machine):
    src = _write(tmp_path, "G20 G90 G18\nG1 X4. Z0.1 A0 F10\nG1 X4000\n")
    with pytest.raises(InputError, match=r"line 3, column 4: 'X4000'.*inch \(G20\)"):
        read_as_compensate(src, machine, work_offsets=MCS)


def test_first_move_far_outside_the_strokes_is_refused(tmp_path, machine):
    src = _write(tmp_path, "G21 G90 G18\nG01 X110000 Z35000 A30000\nG1 X110001\n")
    with pytest.raises(InputError, match=r"line 2, column 5: 'X110000': an end .* outside the X/Z strokes"):
        read_as_compensate(src, machine, work_offsets=MCS)


def test_a_move_inside_the_strokes_is_not_refused(tmp_path, machine):
    lo, hi = machine.stroke_lo, machine.stroke_hi
    src = _write(tmp_path, f"G21 G90 G18\nG1 X{lo[0]:.3f} Z{lo[1]:.3f} A0 F100\nG1 X{hi[0]:.3f} Z{hi[1]:.3f} A720\n")
    assert len(read_as_compensate(src, machine, max_segment_mm=10.0, work_offsets=MCS)) > 1


def test_tiny_max_segment_is_refused_with_the_limit_before_allocation(tmp_path, machine):
    src = _write(tmp_path, "G21 G90 G18\nG1 X100. Z0.3 A0 F100\nG1 X110 Z0.5 A30\n")
    t0 = time.process_time()
    with pytest.raises(InputError, match=rf"line 3: the move needs .* pieces for no piece longer than 1e-06 mm "
                       rf"\(more than {MAX_SEGMENTS_PER_MOVE:,}\); give a larger --max-segment-mm"):
        read_as_compensate(src, machine, max_segment_mm=1e-6, work_offsets=MCS)
    assert time.process_time() - t0 < REFUSAL_S


def test_too_many_points_per_file_are_refused_with_the_limit(tmp_path, machine):
    # moves of 10 mm in 0.7 × the per-move limit of pieces each: each under the per-move limit, together over the file's
    n = int(MAX_PATH_POINTS / (0.7 * MAX_SEGMENTS_PER_MOVE)) + 1
    moves = "".join(f"G1 X{100 + 10 * (k % 2)}\n" for k in range(1, n + 1))
    src = _write(tmp_path, "G21 G90 G18\nG1 X100. Z0.3 A0 F100\n" + moves)
    seg = 10.0 / (0.7 * MAX_SEGMENTS_PER_MOVE)
    assert n * 10.0 / seg > MAX_PATH_POINTS
    with pytest.raises(InputError, match=rf"more than the limit of {MAX_PATH_POINTS:,} points per file"):
        read_as_compensate(src, machine, max_segment_mm=seg, work_offsets=MCS)


def test_compensate_refuses_the_typo_in_one_line_exit_2(tmp_path, machine, capsys):
    el = make_chain_truth(machine, 3).elements.save(tmp_path / "elements.json")
    src = _write(tmp_path, "G21 G90 G18\nG1 X100. Z0.3 A0 F100\nG01 X110000 Z35000 A30000\n", "typo.nc")
    rc = main(["compensate", "--work-offsets", "machine",
               str(src), "--model", str(el), "--method", "traditional", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "typo.nc: line 3, column 5: 'X110000'" in err
    ok = _write(tmp_path, "G21 G90 G18\nG1 X100. Z0.3 A0 F100\nG1 X110 Z0.5 A30\n", "ok.nc")
    rc = main(["compensate", "--work-offsets", "machine",
               str(ok), "--model", str(el), "--method", "traditional", "--out", str(tmp_path / "o2"),
               "--max-segment-mm", "1e-6"])
    err = capsys.readouterr().err
    # the reading-path line ("compensate: model element set (...): PATH") may come first; the error is one line
    errors = [ln for ln in err.splitlines() if ": error: " in ln]
    # the option's range refuses it before the file is read (the per-move limit above guards the library)
    assert rc == 2 and len(errors) == 1 and "--max-segment-mm: expected 'auto', 'none' or a number in [0.01, 100] mm, " \
        "got '1e-6'" in errors[0]
    assert not (tmp_path / "o").exists() and not (tmp_path / "o2").exists()


def _field(machine):
    from errormap.chain_field import ChainField
    return ChainField(machine, make_chain_truth(machine, 3).elements)
