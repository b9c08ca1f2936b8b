"""The pyarrow fast path of :func:`errormap.io.read_table` (issue 20) reads exactly what the
per-row reader reads: on tables built from awkward cells (number spellings Python's ``float``
accepts or refuses, spaces, words, empty cells, blank rows, quotes, wrong cell counts), the
fast and the slow reader give the same values bit for bit, the same rows and raw cells, or
the same error message (file, row, column)."""
import numpy as np
import pytest

import errormap.io as eio
from errormap.io import InputError, read_table

CELLS = ["1", "-2.5", "1e3", "-0", "007", "1.", ".5", "+2", "123456789012345678", "0.1", "2.2250738585072014e-308",
         "1_000", " 1.5", "1.5 ", "nan", "NaN", "inf", "-inf", "1e500", "1e13", "abc", "", "0x10", "١٢", "1,5",
         '"3"', "TRUE", "2024-01-01", "N/A", "null"]
PLAIN = CELLS[:11]


def _outcome(path, monkeypatch, fast: bool, allow_nan: bool):
    monkeypatch.setattr(eio, "FAST_MIN_ROWS", 0 if fast else 10**9)
    try:
        t = read_table(path)
        vals = []
        for c in t.names:
            try:
                vals.append(t.float(c, allow_nan=allow_nan).tobytes())
            except InputError as exc:
                vals.append(str(exc))
        return ("ok", len(t), t.names, t.comments, vals, t.rows)
    except InputError as exc:
        return ("error", str(exc))


@pytest.mark.parametrize("seed", range(40))
def test_fast_reader_equals_row_reader(tmp_path, monkeypatch, seed):
    rng = np.random.default_rng(seed)
    n_rows, n_cols = int(rng.integers(1, 40)), int(rng.integers(1, 4))
    pool = PLAIN if seed % 2 == 0 else CELLS  # half the tables plainly numeric (the fast path taken)
    lines = ["# machine: test", ",".join(f"c{j}" for j in range(n_cols))]
    for _ in range(n_rows):
        r = rng.random()
        if r < 0.03 and seed % 2:
            lines.append("")  # blank line
        elif r < 0.05 and seed % 2:
            lines.append("," * (n_cols - 1))  # a row of empty cells
        else:
            lines.append(",".join(pool[int(rng.integers(len(pool)))] for _ in range(n_cols)))
    p = tmp_path / "t.csv"
    p.write_text("\n".join(lines) + ("\n" if seed % 3 else ""), encoding="utf-8")
    for allow_nan in (False, True):
        assert _outcome(p, monkeypatch, True, allow_nan) == _outcome(p, monkeypatch, False, allow_nan)


def test_fast_path_is_taken_and_exact(tmp_path, monkeypatch):
    """A large plain table goes the fast way (no rows parsed until asked) with values equal to
    Python's float of every cell; a bad cell far down is still named by row and column."""
    rng = np.random.default_rng(3)
    v = rng.normal(0, 100, (5000, 3))
    text = "x_mm,z_mm,a_deg\n" + "\n".join(",".join(repr(float(c)) for c in r) for r in v) + "\n"
    p = tmp_path / "big.csv"
    p.write_text(text)
    t = read_table(p)
    assert t._rows is None and len(t) == 5000
    np.testing.assert_array_equal(np.stack([t.float(c) for c in t.names], axis=1), v)
    assert t._rows is None  # values came without the per-row reader
    assert t.raw("a_deg")[4999] == repr(float(v[4999, 2]))
    p.write_text(text.replace(repr(float(v[4321, 1])), "1e13"))
    with pytest.raises(InputError, match=r"row 4323, column 'z_mm': '1e13' is beyond"):
        read_table(p).float("z_mm")
