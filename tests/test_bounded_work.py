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
    from errormap.chain_truth import make_chain_truth
    return make_chain_truth(grinder, 3).elements.save(tmp_path_factory.mktemp("el") / "elements.json")


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
    from path_files import read_as_compensate
    monkeypatch.setattr(gcode, "MAX_PROGRAM_BYTES", 1000)
    src = tmp_path / "big.nc"
    src.write_text("G21 G90 G18\n" + "G1 X100. Z0.3 A0 F100\n" * 100)
    with pytest.raises(eio.InputError, match=r"big.nc: .* GiB exceeds the limit of .* per program"):
        read_as_compensate(src, grinder)


def test_a_table_over_the_memory_bound_is_refused_unread(tmp_path, monkeypatch):
    """The available memory lowered to 1 kB: the table is refused by its size and the bound, before its bytes are
    read (no Path.read_bytes) or parsed."""
    from pathlib import Path
    f = tmp_path / "t.csv"
    f.write_text("x_mm,z_mm,a_deg\n" + "10,20,30\n" * 100)
    monkeypatch.setattr(eio, "available_memory_bytes", lambda: 1000)
    read = []
    monkeypatch.setattr(Path, "read_bytes", lambda self: read.append(self))
    with pytest.raises(eio.InputError) as e:
        eio.read_table(f)
    msg = str(e.value)
    assert msg.startswith(f"{f}: 0 MB would need about ") and "to read as numbers" in msg
    assert f"over the bound of {eio.TABLE_MEMORY_FRACTION:g} x the 1e-06 GB available" in msg and len(msg) < 300
    assert not read


def test_a_table_read_cell_by_cell_is_bounded_by_its_own_estimate(tmp_path, monkeypatch):
    """A quoted cell sends the table to the per-row reader (~10x the memory of the numeric path per byte here): the
    bound is checked again with that estimate, and a table the numeric path could read is refused there, saying why."""
    n = 2000
    f = tmp_path / "q.csv"
    f.write_text('x_mm,z_mm,a_deg\n"10",20,30\n' + "10,20,30\n" * (n - 1))
    size = f.stat().st_size
    # the bound at 20 B per file byte: the numeric path's estimate is 6, cell by cell 3 x 170 B per 9-byte row + 2
    avail = size * 20 / eio.TABLE_MEMORY_FRACTION
    monkeypatch.setattr(eio, "available_memory_bytes", lambda: avail)
    with pytest.raises(eio.InputError, match=r"q\.csv: .* to read cell by cell \(it is not plainly numeric"):
        eio.read_table(f)
    f.write_text("x_mm,z_mm,a_deg\n" + "10,20,30\n" * n)   # the same table, plainly numeric: read
    assert len(eio.read_table(f)) == n


@pytest.mark.parametrize("chunk", [1, 2, 3, 4, 7, 1 << 20])
def test_lines_are_counted_in_chunks_as_in_one_piece(tmp_path, monkeypatch, chunk):
    raw = b"a\r\nbb\r\nc\rd\n\r\ne\r"
    f = tmp_path / "t.csv"
    f.write_bytes(raw)
    monkeypatch.setattr(eio, "_COUNT_CHUNK", chunk)
    assert eio._count_lines(f) == raw.count(b"\n") + raw.count(b"\r") - raw.count(b"\r\n") == 6
