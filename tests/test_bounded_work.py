"""Bounded work: a table is sized (bytes, header columns, lines, cells) before it is parsed and
refused past the documented limits (errormap/io.py), naming the file: a 2M-column CSV kept
``predict`` busy for over 15 minutes, 10M rows took 702 s and 5.6 GB."""
from __future__ import annotations

import time

import pytest

from errormap import io as eio

from test_output_safety import one_line, run_cli

# the refusal reads the file once and counts its commas and lines: well under a second for the
# 20 MB header below on the loaded 2-core test machine; 10 s fails a parse that got started
REFUSE_WITHIN_S = 10.0


@pytest.fixture(scope="module")
def elements(tmp_path_factory, grinder):
    from errormap.simulator import random_truth
    return random_truth(grinder, 3).elements.save(tmp_path_factory.mktemp("el") / "elements.json")


def test_two_million_columns_refused_at_once(tmp_path, elements):
    n = 2_000_000
    wide = tmp_path / "wide.csv"
    wide.write_text(",".join(f"c{i}" for i in range(n)) + "\n" + ",".join("1" for _ in range(n)) + "\n")
    t0 = time.perf_counter()
    rc, _, err = run_cli(["predict", wide, "--model", elements, "--out", tmp_path / "p.csv"])
    assert time.perf_counter() - t0 < REFUSE_WITHIN_S
    one_line(rc, err, str(wide), "row 1", "2,000,000 columns", f"limit of {eio.MAX_TABLE_COLUMNS:,}")
    assert not (tmp_path / "p.csv").exists()


def test_a_row_of_two_million_cells_names_its_row_without_a_decimal_comma_hint(tmp_path, elements):
    f = tmp_path / "long_row.csv"
    f.write_text("x_mm,z_mm,a_deg\n" + ",".join("1" for _ in range(2_000_000)) + "\n")
    rc, _, err = run_cli(["predict", f, "--model", elements, "--out", tmp_path / "p.csv"])
    line = one_line(rc, err, str(f), "row 2", "expected 3 cells", "got 2000000")
    assert "decimal comma" not in line


def test_rows_over_the_limit_refused_before_parsing(tmp_path, elements, monkeypatch):
    """The limit lowered to 1,000 rows (the real one, 5e6, would need a 100 MB file): 3,000 rows
    are refused with the estimate of predict's memory, before any row is parsed."""
    monkeypatch.setattr(eio, "MAX_TABLE_ROWS", 1000)
    f = tmp_path / "tall.csv"
    f.write_text("x_mm,z_mm,a_deg\n" + "10,20,30\n" * 3000)
    parsed = []
    monkeypatch.setattr(eio, "_parse_rows", lambda *a: parsed.append(1))
    rc, _, err = run_cli(["predict", f, "--model", elements, "--out", tmp_path / "p.csv"])
    one_line(rc, err, str(f), "about 3,001 rows exceed the limit of 1,000 rows per table",
             f"{3001 * eio.TABLE_BYTES_PER_ROW / 1e9:.3g} GB")
    assert not parsed


def test_cells_over_the_limit_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(eio, "MAX_TABLE_CELLS", 100)
    f = tmp_path / "t.csv"
    f.write_text("a,b,c,d\n" + "1,2,3,4\n" * 30)
    with pytest.raises(eio.InputError, match=r"t.csv: 31 rows x 4 columns = 124 cells exceed the limit of 100"):
        eio.read_table(f)


def test_a_table_at_the_limits_is_read(tmp_path, monkeypatch):
    monkeypatch.setattr(eio, "MAX_TABLE_ROWS", 2000)
    f = tmp_path / "t.csv"
    f.write_text("x_mm,z_mm,a_deg\n" + "10,20,30\n" * 2000)
    assert len(eio.read_table(f)) == 2000


def test_a_program_over_the_byte_limit_is_refused_unread(tmp_path, grinder, monkeypatch):
    from compensation import gcode
    from compensation.pathio import read_path
    monkeypatch.setattr(gcode, "MAX_PROGRAM_BYTES", 1000)
    src = tmp_path / "big.nc"
    src.write_text("G21 G90 G18\n" + "G1 X100. Z0.3 A0 F100\n" * 100)
    with pytest.raises(eio.InputError, match=r"big.nc: .* GiB exceeds the limit of .* per program"):
        read_path(src, grinder)
