"""Atomic writes and validated CSV reading."""
import os
import stat

import numpy as np
import pytest

from errormap.io import InputError, atomic_write, read_table, write_csv


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(p) as fh:
            fh.write("half")
            raise RuntimeError("interrupted")
    assert p.read_text() == "old"
    assert [f.name for f in tmp_path.iterdir()] == ["out.txt"]  # no temporary left behind


def test_atomic_write_gives_usual_permissions(tmp_path):
    p = tmp_path / "prog.nc"
    with atomic_write(p) as fh:
        fh.write("G1 X0\n")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask


def test_read_table_errors_name_row_and_column(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("# a: b\nx_mm,z_mm\n1,2\n3,nan\n")
    t = read_table(p)
    assert t.meta() == {"a": "b"}
    with pytest.raises(InputError, match=r"row 4, column 'z_mm'"):
        t.float("z_mm")
    with pytest.raises(InputError, match="missing required column"):
        t.require("a_deg")
    p.write_text("x_mm,z_mm\n1,2,3\n")
    with pytest.raises(InputError, match="row 2: expected 2 cells"):
        read_table(p)


def test_write_csv_round_trip(tmp_path):
    p = write_csv(tmp_path / "c.csv", {"a": np.array([1.5, 2.25]), "n": np.array([1, 2])}, header_comments=["k: v"])
    t = read_table(p)
    np.testing.assert_array_equal(t.float("a"), [1.5, 2.25])
    assert t.int("n").tolist() == [1, 2] and t.meta()["k"] == "v"


def test_row_numbers_count_blank_lines_between_rows(tmp_path):
    """A bad cell after blank lines is named by the line an editor shows (both reader paths)."""
    from errormap.io import FAST_MIN_ROWS
    p = tmp_path / "gaps.csv"
    p.write_text("# c\nx_mm,z_mm\n1,2\n\n3,4\n\n\n5,oops\n")
    t = read_table(p)
    assert [t.row_number(k) for k in range(len(t))] == [3, 5, 8]
    with pytest.raises(InputError, match=r"row 8\b"):
        t.float("z_mm")
    # a long table (the pyarrow path's size) with one blank line: the rows after it keep their lines
    body = "\n".join(f"{k},{k}" for k in range(FAST_MIN_ROWS))
    q = tmp_path / "long.csv"
    q.write_text("x_mm,z_mm\n" + body.replace("\n10,10\n", "\n\n10,10\n") + "\nnan,1\n")
    t = read_table(q)
    assert t.row_number(10) == 13 and t.row_number(9) == 11
    with pytest.raises(InputError, match=rf"row {FAST_MIN_ROWS + 3}\b"):
        t.float("x_mm")
