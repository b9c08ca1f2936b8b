"""Shared I/O helpers: atomic writes and validated CSV tables.

Every writer in volcomp goes through :func:`atomic_write` (temporary file in the
target folder, then ``os.replace``), so an interrupted job never leaves half a file.
Every CSV reader goes through :func:`read_table`, whose errors name the file,
the row (1-based, the header is row 1) and the column.
"""
from __future__ import annotations

import collections
import contextlib
import errno
import csv
import hashlib
import io
import json
import math
import os
import re
import shutil
import stat
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np


class InputError(ValueError):
    """Bad input data: the message names the file, and where known the row and column."""


# Largest magnitude any numeric CSV cell may have unless its reader says otherwise: far past
# every plausible mm, μm, deg, s or °C value, far below where float64 arithmetic overflows.
MAX_ABS_VALUE = 1e12


def _short(s: str, n: int = 40) -> str:
    """``repr`` of a cell, cut to about ``n`` characters."""
    return repr(s) if len(s) <= n else repr(s[:n]) + f"... ({len(s)} characters)"


def wide_encoding(raw: bytes) -> str | None:
    """``"UTF-16"`` or ``"UTF-32"`` when ``raw`` is text in one of them (its byte-order mark, or, without
    one, a NUL byte in every second byte of its start, as ASCII text saved as UTF-16 has),
    else None. Such a file is not UTF-8, Latin-1 or any other byte encoding volcomp reads."""
    if raw.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")):
        return "UTF-32"
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "UTF-16"
    head = raw[:4096]
    even, odd = head[0::2], head[1::2]
    if len(head) >= 8 and (even.count(0) >= 0.9 * len(even) or odd.count(0) >= 0.9 * len(odd)):
        return "UTF-16"
    return None


def check_not_wide(raw: bytes, path) -> None:
    """Refuse UTF-16/UTF-32 text (:func:`wide_encoding`) naming the file and the encoding."""
    enc = wide_encoding(raw)
    if enc is not None:
        raise InputError(f"{path}: {enc} text detected (a Windows \"Unicode\" save); re-save it as UTF-8")


MAX_DOCUMENT_BYTES = 64 * 2**20
"""Bytes of a JSON or TOML input (element sets, model files, machine files, diagnoses), checked
before it is read: the largest volcomp writes are a diagnosed model with its learned residual and a
drift model (of the order of 100 kB: a learned residual keeps its few hundred fitting checks), an
element set is ~10 kB (mill-xyz), a chain diagnosis.json ~16 kB and a machine file a few kB, so 64 MiB is over 600
times the largest real one, and reading one at the bound stays near 1 s and a third of a GB (measured:
a 55 MiB JSON of float rows parses in 1.1 s at 285 MB peak, about 5x its size; docs/decisions/020-benchmark-notebook.md). A
larger file is not one of these documents."""


def check_document_size(path, what: str = "a document") -> None:
    """Refuse (InputError, one line naming the file) the JSON/TOML/NPZ input ``path`` past
    :data:`MAX_DOCUMENT_BYTES`, before it is read; ``what``: what the file was expected to be."""
    size = os.stat(path).st_size
    if size > MAX_DOCUMENT_BYTES:
        raise InputError(f"{path}: {size:,} bytes exceeds the limit of {MAX_DOCUMENT_BYTES >> 20} MiB for {what} "
                         "(the largest volcomp writes is ~100 kB); not read")


def read_document_bytes(path, what: str = "a document") -> bytes:
    """The bytes of the JSON/TOML file ``path``, sized first (:func:`check_document_size`)."""
    check_document_size(path, what)
    return Path(path).read_bytes()


def read_document_text(path, what: str = "a document") -> str:
    """The UTF-8 text (:func:`decode_text`) of the JSON/TOML file ``path``, sized first."""
    return decode_text(read_document_bytes(path, what), path)


def read_json(path, what: str = "a JSON document"):
    """The JSON document in ``path``: size-bounded (:func:`read_document_bytes`), UTF-8
    (:func:`decode_text`); not JSON (or nested past Python's recursion limit) → InputError naming
    the file, line and column."""
    path = Path(path)
    text = read_document_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: row {exc.lineno}: column {exc.colno}: not JSON ({exc.msg}); expected {what}") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply to be {what}") from None


def read_json_object(path, what: str = "a JSON object") -> dict:
    """:func:`read_json` of a JSON object; a missing file or another JSON value: InputError naming the file."""
    try:
        d = read_json(path, what)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file ({what})") from None
    if not isinstance(d, dict):
        raise InputError(f"{path}: expected a JSON object ({what}), got {type(d).__name__}")
    return d


def decode_text(raw: bytes, path) -> str:
    """UTF-8 text of a file's bytes; a leading UTF-8 BOM (Excel's "CSV UTF-8") is dropped.

    A byte that is not UTF-8 raises :class:`InputError` naming the row (line) and the
    character position, e.g. ``ü`` saved in Latin-1 / Windows-1252.
    """
    check_not_wide(raw, path)
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        pos = exc.start
        row = raw.count(b"\n", 0, pos) + 1
        line_start = raw.rfind(b"\n", 0, pos) + 1
        col = len(raw[line_start:pos].decode("utf-8", errors="replace")) + 1
        raise InputError(f"{path}: row {row}, character {col}: byte 0x{raw[pos]:02x} is not UTF-8 (is the file in "
                         "Latin-1 / Windows-1252?); save it as UTF-8") from None


NPY_ERRORS = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error)
"""What ``np.load`` and reading an ``.npz`` member raise for a damaged file (truncated, not a zip,
a bad CRC): every reader catches these and names the file (:class:`InputError`)."""


def load_array(path, what: str = "array file"):
    """``np.load(path)`` of an ``.npy`` (no pickles), fully read; a damaged file is one
    :class:`InputError` naming it."""
    try:
        return np.asarray(np.load(path, allow_pickle=False))
    except NPY_ERRORS as exc:
        raise InputError(f"{path}: not a readable {what} ({exc}); write it again") from None


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


OUTPUT_LOCK_NAME = ".volcomp.lock"
"""The lock file a run holds in its output folder (compensation/app/outputs.py): never an output,
so a folder replaced whole or checked for foreign files does not count it."""

_SPECIAL_KINDS = ((stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"), (stat.S_ISFIFO, "FIFO (named pipe)"),
                  (stat.S_ISSOCK, "socket"))


def check_output_target(path, kind: str = "file") -> None:
    """Refuse to write an output onto ``path`` unless it is absent or a ``kind`` (``"file"``: a
    regular file, ``"dir"``: a folder), a symbolic link followed: a device (``/dev/null``,
    ``/dev/full``), a FIFO or a socket would be replaced by a regular file by the rename of
    :func:`atomic_write` (as root, ``/dev/null`` itself), or block the writer. One
    :class:`InputError` naming the path and what it is.
    """
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return  # absent (or a dangling link, which the rename replaces): written as a new file
    except OSError as exc:
        raise InputError(f"{path}: cannot be examined as an output ({exc.strerror or type(exc).__name__})") from None
    link = " (through a symbolic link)" if path.is_symlink() else ""
    for test, what in _SPECIAL_KINDS:
        if test(mode):
            raise InputError(f"{path}: is a {what}{link}; volcomp writes outputs only as regular files and folders "
                             f"(give a file or folder path)")
    if kind == "file" and stat.S_ISDIR(mode):
        raise InputError(f"{path}: is a folder{link}; expected a file name")
    if kind == "dir" and not stat.S_ISDIR(mode):
        raise InputError(f"{path}: is a file{link}; expected a folder")


@contextlib.contextmanager
def atomic_write(path, mode: str = "w", **kwargs) -> Iterator[io.IOBase]:
    """Open a temporary file beside ``path``; rename it onto ``path`` only on success.

    Every output of volcomp is written here: ``path`` must be absent or a regular file
    (:func:`check_output_target`, checked before the temporary file is made and again before the
    rename); an OS error while writing (a full disk) names ``path``, not the temporary file.
    """
    path = Path(path)
    check_output_target(path, "file")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        try:
            with os.fdopen(fd, mode, **kwargs) as fh:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual mode
            check_output_target(path, "file")
            os.replace(tmp, path)
        except OSError as exc:
            if exc.errno is None or exc.filename not in (None, tmp, str(tmp)):
                raise
            raise OSError(exc.errno, f"{exc.strerror or type(exc).__name__} (while writing it)", str(path)) from exc
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def replace_dir(src, dst) -> Path:
    """Move the finished folder ``src`` onto ``dst`` (same file system), replacing any old ``dst``.

    The old folder is first renamed aside, then ``src`` renamed onto ``dst``, then the old one
    removed: at every instant ``dst`` is either the whole old set, absent, or the whole new set.
    """
    src, dst = Path(src), Path(dst)
    if not dst.exists():
        os.replace(src, dst)
        return dst
    old = Path(tempfile.mkdtemp(prefix=f".{dst.name}.", suffix=".old", dir=dst.parent))
    os.replace(dst, old / dst.name)
    try:
        os.replace(src, dst)
    except BaseException:
        os.replace(old / dst.name, dst)  # put the old set back
        raise
    finally:
        shutil.rmtree(old, ignore_errors=True)
    return dst


@contextlib.contextmanager
def atomic_dir(path) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``path``; on success it replaces ``path`` whole.

    Files that belong together (a model's config, scalers and weights; a run folder) are
    written into the yielded folder; an exception (or a crash) leaves ``path`` as it was and
    no partial set under its name.
    """
    path = Path(path)
    check_output_target(path, "dir")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700
        replace_dir(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_json(path, obj) -> Path:
    """Write ``obj`` as indented JSON, atomically. NaN/inf are written as null."""
    def clean(o):
        if isinstance(o, dict):
            return {str(k): clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        if isinstance(o, np.ndarray):
            return clean(o.tolist())
        if isinstance(o, (np.floating, float)):
            f = float(o)
            return f if math.isfinite(f) else None
        if isinstance(o, np.integer):
            return int(o)
        if isinstance(o, np.bool_):
            return bool(o)
        if isinstance(o, Path):
            return str(o)
        return o
    with atomic_write(path, "w", encoding="utf-8") as fh:
        json.dump(clean(obj), fh, indent=2)
        fh.write("\n")
    return Path(path)


CSV_META_FORMAT = "volcomp-csv-meta/1"
"""The format of a CSV's provenance sidecar (:func:`sidecar_path`)."""


def sidecar_path(path) -> Path:
    """The provenance sidecar of the CSV ``path``: ``NAME.csv`` -> ``NAME.meta.json`` beside it (any other
    name gets ``.meta.json`` appended: ``f.txt`` -> ``f.txt.meta.json``)."""
    path = Path(path)
    stem = path.name[:-4] if path.name.lower().endswith(".csv") else path.name
    return path.with_name(stem + ".meta.json")


def write_csv(path, columns: dict, header_comments: Sequence[str] = (), float_fmt: str = "%.9g") -> Path:
    """Write named 1-D columns (equal length) as a plain CSV (the header is its first line) and its provenance
    sidecar (:func:`sidecar_path`), each atomically, the sidecar renamed into place just before the CSV.

    ``header_comments``: the provenance lines (``key: value`` or free text); the sidecar holds them as written
    (``lines``), their ``key: value`` pairs (``provenance``), the columns and the row count. :func:`read_table`
    gives them back as :attr:`Table.comments`.
    """
    names = list(columns)
    arrays = [np.asarray(columns[k]) for k in names]
    n = {len(a) for a in arrays}
    if len(n) > 1:
        raise ValueError(f"Expected columns of equal length, got lengths {[len(a) for a in arrays]}")
    rows = len(arrays[0]) if arrays else 0
    with atomic_write(path, "w", encoding="utf-8", newline="") as fh, \
            atomic_write(sidecar_path(path), "w", encoding="utf-8") as side:
        w = csv.writer(fh)
        w.writerow(names)
        fmt = []
        for a in arrays:
            if a.dtype.kind == "f":
                fmt.append(lambda v, f=float_fmt: (f % v) if np.isfinite(v) else "nan")
            else:
                fmt.append(str)
        for i in range(rows):
            w.writerow([f(a[i]) for f, a in zip(fmt, arrays)])
        side.write(sidecar_json(path, names, rows, header_comments))
    return Path(path)


def sidecar_json(path, names: Sequence[str], rows: int, lines: Sequence[str]) -> str:
    """The text of the sidecar (:func:`sidecar_path`) of the CSV ``path`` with columns ``names`` and ``rows`` data
    rows whose provenance is ``lines``: JSON with ``format``, ``csv`` (the file's name), ``columns``, ``rows``,
    ``written_by``, ``provenance`` (the ``key: value`` pairs) and ``lines`` (as given)."""
    from . import __version__
    lines = [str(c) for c in lines]
    meta = {"format": CSV_META_FORMAT, "csv": Path(path).name, "columns": list(names), "rows": int(rows),
            "written_by": f"volcomp {__version__}", "provenance": _pairs(lines), "lines": lines}
    return json.dumps(meta, indent=1) + "\n"


def _pairs(lines: Sequence[str]) -> dict:
    """``key: value`` pairs of provenance lines (a line without ``:`` is not a pair)."""
    out = {}
    for c in lines:
        if ":" in c:
            k, v = c.split(":", 1)
            out[k.strip()] = v.strip()
    return out


def provenance_lines(path, header: list, comments: list) -> list:
    """The provenance lines of the CSV ``path`` whose header is ``header``: its sidecar's (:func:`sidecar_path`)
    when one names this file and these columns, else the leading ``#`` lines ``comments`` (a file written before
    the sidecar, or by hand). The one place a reader of volcomp's CSVs finds their provenance."""
    side = sidecar_path(path)
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return comments
    if (not isinstance(meta, dict) or meta.get("format") != CSV_META_FORMAT or meta.get("csv") != Path(path).name
            or meta.get("columns") != header or not isinstance(meta.get("lines"), list)):
        return comments
    return comments + [str(c) for c in meta["lines"]]


class Table:
    """A CSV table read by :func:`read_table`: named columns plus provenance.

    ``columns`` maps name -> list of raw strings; ``float(name)`` converts a column
    with errors naming file, row and column. ``comments`` holds the provenance lines: the leading ``#``
    lines of a file written by hand or by an older volcomp, then its sidecar's (:func:`provenance_lines`).
    """

    def __init__(self, path: Path, names: list[str], rows: list[list[str]] | None, first_row: int, comments: list[str],
                 numeric: dict | None = None, lines: str | None = None, row_lines: list[int] | None = None):
        self.path = path
        self.names = names
        self._rows = rows
        self.first_row = first_row  # file line number of the line after the header
        # file line number of each data row when blank lines were skipped between them (else None:
        # row k is on line first_row + k)
        self._row_lines = row_lines
        self.comments = comments
        self._index = {n: i for i, n in enumerate(names)}
        # fast path (read_table on a large, plain numeric table): every column already parsed
        # as float64 (``numeric``), the raw cells parsed from the body text ``lines`` only when asked for
        self._numeric = numeric or {}
        self._lines = lines
        self._n = len(rows) if rows is not None else len(next(iter(self._numeric.values())))

    @property
    def rows(self) -> list[list[str]]:
        """The raw cells, stripped, one list per data row (parsed on first use after the fast path)."""
        if self._rows is None:
            self._rows, self._row_lines = _parse_rows(self.path, self._lines.split("\n"), self.names, self.first_row)
            self._lines = None
        return self._rows

    def __len__(self) -> int:
        return self._n

    def __contains__(self, name: str) -> bool:
        return name in self._index

    def require(self, *names: str) -> None:
        missing = [n for n in names if n not in self._index]
        if missing:
            raise InputError(f"{self.path}: missing required column(s) {missing}; found columns {self.names}")

    def raw(self, name: str) -> list[str]:
        self.require(name)
        i = self._index[name]
        return [r[i] for r in self.rows]

    def row_number(self, k: int) -> int:
        """File line number (1-based) of data row ``k`` (0-based); blank lines between rows count."""
        return self._row_lines[k] if self._row_lines is not None else self.first_row + k

    def float(self, name: str, allow_nan: bool = False, limit: float = MAX_ABS_VALUE) -> np.ndarray:
        """Column ``name`` as float64, shape (n,); bad cells raise naming row and column.

        ``limit``: the largest plausible magnitude (default :data:`MAX_ABS_VALUE`); a larger
        value is a unit or typing mistake and is refused before any arithmetic overflows.
        """
        self.require(name)
        fast = self._numeric.get(name)
        if fast is not None:
            bad = np.abs(fast) > limit
            if not allow_nan:
                bad |= ~np.isfinite(fast)
            if not bad.any():
                return fast.copy()
            # the per-cell checker below writes the message (row, column, cell as written)
        vals = self.raw(name)
        out = np.empty(len(vals))
        for k, s in enumerate(vals):
            try:
                v = float(s)
            except ValueError:
                raise InputError(
                    f"{self.path}: row {self.row_number(k)}, column '{name}': expected a number, got {_short(s)}"
                ) from None
            if not allow_nan and not math.isfinite(v):
                raise InputError(
                    f"{self.path}: row {self.row_number(k)}, column '{name}': expected a finite number, got {_short(s)}"
                )
            if abs(v) > limit:
                raise InputError(
                    f"{self.path}: row {self.row_number(k)}, column '{name}': {_short(s)} is beyond the plausible "
                    f"magnitude {limit:g}; wrong unit or a typing mistake?"
                )
            out[k] = v
        return out

    def int(self, name: str, allowed: Iterable[int] | None = None) -> np.ndarray:
        """Column ``name`` as int64; optional set of allowed values."""
        vals = self.float(name)
        allowed_set = set(allowed) if allowed is not None else None
        for k, v in enumerate(vals):
            if v != round(v) or (allowed_set is not None and int(v) not in allowed_set):
                want = f"one of {sorted(allowed_set)}" if allowed_set is not None else "an integer"
                raise InputError(
                    f"{self.path}: row {self.row_number(k)}, column '{name}': expected {want}, got {_short(self.raw(name)[k])}"
                )
        return vals.astype(np.int64)

    def meta(self) -> dict:
        """``key: value`` pairs of the provenance lines (:attr:`comments`)."""
        return _pairs(self.comments)


def not_a_file(path) -> str:
    """Why ``path`` cannot be read as an input file, for a refusal: ``"PATH: no such file"``, or what it is instead
    (a folder, a device, a FIFO or socket, a symbolic-link loop, a link to nothing)."""
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except OSError as exc:
        if os.path.islink(p):
            why = "a symbolic-link loop" if exc.errno == errno.ELOOP else "a symbolic link to nothing"
            return f"{p}: is {why}; expected a file"
        return f"{p}: no such file"
    what = ("a folder" if stat.S_ISDIR(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a file")
    return f"{p}: is {what}; expected a regular file"


def read_table(path, kind: str | None = None) -> Table:
    """Read a CSV with a header row (leading ``#`` comment lines allowed: skipped, kept as provenance).

    Raises :class:`InputError` naming the file (and row) for a missing file, an
    empty file, a duplicated column name or a row with the wrong number of cells.
    Extra columns are kept. ``kind``: what the table holds (a key of
    :data:`errormap.input_bounds.BOUNDS`): its rows are bounded before it is read.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(not_a_file(path))
    raw = _read_bounded(path, kind)
    text = decode_text(raw, path)
    del raw
    if "\x00" in text:
        row = text.count("\n", 0, text.index("\x00")) + 1
        raise InputError(f"{path}: row {row}: contains a NUL byte; expected a text (CSV) file")
    # rows are the lines an editor shows: split at \n, \r\n or \r only
    if "\r" in text:  # one pass for the common \r\n, a second only for a bare \r left over
        text = text.replace("\r\n", "\n")
        if "\r" in text:
            text = text.replace("\r", "\n")
    # leading comment and blank lines, then the header line (line i, 0-based), then the body
    comments = []
    i, pos = 0, 0
    while True:
        end = text.find("\n", pos)
        line = text[pos:] if end < 0 else text[pos:end]
        if not (line.startswith("#") or not line.strip()):
            break
        if line.startswith("#"):
            comments.append(line[1:].strip())
        if end < 0:
            raise InputError(f"{path}: empty file (no header row)")
        i, pos = i + 1, end + 1
    # lines are split at \n: a quoted cell cannot span lines, and csv's field-size limit
    # must not turn a long line into a traceback
    header = _read_header(path, line, i + 1)
    _check_separator(path, i + 1, header, text[end + 1:end + 1 + 4096] if end >= 0 else "")
    _check_cells(path, header, text.count("\n", end + 1) + 1 if end >= 0 else 0)
    dup = sorted(h for h, k in collections.Counter(header).items() if k > 1)
    if dup:
        raise InputError(f"{path}: row {i + 1}: duplicated column name(s) {dup}")
    body = "" if end < 0 else text[end + 1:]
    # the fast path only where rows follow one another line by line (a blank line inside the body
    # would shift the row numbers its messages give)
    if end >= 0 and _at_least_lines(body, FAST_MIN_ROWS) and "\n\n" not in body.rstrip("\n"):
        numeric = _parse_numeric_fast(body, header)
        if numeric is not None:
            return Table(path, header, None, i + 2, provenance_lines(path, header, comments), numeric=numeric,
                         lines=body)
    n_lines = body.count("\n") + 1 if end >= 0 else 0
    check_table_memory(path, TABLE_READ_BYTES_PER_CELL * n_lines * len(header) + 2 * len(body),
                       "cell by cell (it is not plainly numeric: a quote, a word or an empty cell)")
    rows, row_lines = _parse_rows(path, body.split("\n") if end >= 0 else [], header, i + 2)
    return Table(path, header, rows, i + 2, provenance_lines(path, header, comments), row_lines=row_lines)


# --- bounded work: a table is sized from its bytes, header and line count before it is parsed ---
MAX_TABLE_COLUMNS = 1000
"""Columns a table may have. volcomp's widest schema (an arm's pose file with its conditions) has
under 30: a header of thousands of names is not one of its files (a 2M-column file kept ``predict``
busy for over 15 minutes)."""
MAX_TABLE_ROWS = 5_000_000
"""Data lines a table may have: the largest feature-point set volcomp writes (``--grid 170``,
4.9e6 points, validate.MAX_GRID_POINTS). ``predict`` peaks at about
:data:`TABLE_BYTES_PER_ROW` per row (10M rows took 702 s and 5.6 GB), so the limit bounds it
at about 2.8 GB and 6 minutes."""
TABLE_BYTES_PER_ROW = 560
"""Peak memory per row of a command that reads a table and writes one (``predict``, measured)."""
MAX_TABLE_CELLS = 40_000_000
"""Cells (rows x columns) a table may have: the per-row reader holds each cell as a string
(about 60 B), so this bounds it at about 2.4 GB (the feature-point set at its limit has 29e6)."""
MAX_TABLE_BYTES = 2 * 2**30
"""Bytes of a table file, checked before it is read: 40e6 cells of up to ~50 characters."""


TABLE_READ_BYTES_PER_BYTE = 6.0
"""Peak memory of reading a plainly numeric table (the pyarrow path) per byte of the file: its bytes, the decoded
text, the body handed to pyarrow, the parsed columns. Measured: 5e6 rows x 3 columns, 158 MB, 929 MiB peak
resident (of which ~100 MiB the interpreter and its libraries) — 5.5 per byte (docs/decisions/020-benchmark-notebook.md, "Huge tables")."""
TABLE_READ_BYTES_PER_CELL = 170
"""Peak memory of reading a table cell by cell (a quote, a word or an empty cell anywhere: the per-row reader) per
cell. Measured: the same 5e6 x 3 table with one quoted cell, 2,378 MiB peak resident — 152 B per cell."""
TABLE_MEMORY_FRACTION = 0.5
"""A table is read only when its estimated peak memory is at most this fraction of the memory the system has
available (``MemAvailable``) when it is opened: the rest is for what the command does with it."""
_COUNT_CHUNK = 8 * 2**20


def available_memory_bytes() -> int | None:
    """The memory available now, bytes: the system's (Linux ``/proc/meminfo`` MemAvailable, else the free physical
    pages), and no more than a cgroup v2 memory limit leaves (``memory.max`` − ``memory.current``: a container is
    killed at its limit, whatever the host has); None when none of them can be read (no bound applied)."""
    avail = None
    try:
        with open("/proc/meminfo", "rb") as fh:
            for line in fh:
                if line.startswith(b"MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            pass
    try:
        cap = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if cap != "max":
            left = int(cap) - int(Path("/sys/fs/cgroup/memory.current").read_text())
            avail = left if avail is None else min(avail, left)
    except (OSError, ValueError):
        pass
    return avail


def check_table_memory(path, need_bytes: float, how: str) -> None:
    """Refuse (InputError naming the file, the estimate and the bound) a table whose reading ``how`` would need
    ``need_bytes`` at its peak, over :data:`TABLE_MEMORY_FRACTION` of the available memory."""
    avail = available_memory_bytes()
    if avail is None or need_bytes <= TABLE_MEMORY_FRACTION * avail:
        return
    raise InputError(f"{path}: {path.stat().st_size / 1e6:,.0f} MB would need about {need_bytes / 1e9:.3g} GB to "
                     f"read {how}, over the bound of {TABLE_MEMORY_FRACTION:g} x the {avail / 1e9:.3g} GB available; "
                     "split the file")


def _count_lines(path: Path) -> int:
    """Line breaks of the file (``\\n``, ``\\r\\n`` or a lone ``\\r``), counted in chunks: never held whole."""
    n, prev_cr = 0, False
    with open(path, "rb") as fh:
        while chunk := fh.read(_COUNT_CHUNK):
            n += chunk.count(b"\n") + chunk.count(b"\r") - chunk.count(b"\r\n")
            if prev_cr and chunk.startswith(b"\n"):
                n -= 1       # a \r\n split across two chunks: one break, counted twice
            prev_cr = chunk.endswith(b"\r")
    return n


def _read_bounded(path: Path, kind: str | None = None) -> bytes:
    """The file's bytes, refused unread past :data:`MAX_TABLE_BYTES`, by its line count (counted in chunks) past
    :data:`MAX_TABLE_ROWS` or its ``kind``'s bound (:func:`errormap.input_bounds.refusal`), and past the memory
    bound (:func:`check_table_memory`, the pyarrow path's estimate :data:`TABLE_READ_BYTES_PER_BYTE`) — all before
    it is read whole or parsed."""
    size = path.stat().st_size
    if size > MAX_TABLE_BYTES:
        raise InputError(f"{path}: {size / 2**30:.3g} GiB exceeds the limit of {MAX_TABLE_BYTES / 2**30:g} GiB per "
                         "table file; split it")
    lines = _count_lines(path)
    if lines > MAX_TABLE_ROWS + 1000:  # room for the header and comment lines
        raise InputError(f"{path}: about {lines:,} rows exceed the limit of {MAX_TABLE_ROWS:,} rows per table (about "
                         f"{lines * TABLE_BYTES_PER_ROW / 1e9:.3g} GB of memory for predict at {TABLE_BYTES_PER_ROW} B "
                         "per row); split the file")
    if kind is not None:
        from .input_bounds import refusal
        why = refusal(path, kind, max(lines - 1, 0))   # the header line is no data row
        if why:
            raise InputError(why)
    check_table_memory(path, TABLE_READ_BYTES_PER_BYTE * size, "as numbers")
    return _read_all(path)


def _read_all(path: Path) -> bytes:
    """The whole file (after every bound passed)."""
    return path.read_bytes()


def _read_header(path: Path, line: str, row: int) -> list[str]:
    """The header row's names, refused past :data:`MAX_TABLE_COLUMNS` before the row is parsed."""
    n = line.count(",") + 1
    if n > MAX_TABLE_COLUMNS:
        head = ", ".join(c.strip() for c in line[:120].split(",")[:4])
        raise InputError(f"{path}: row {row}: the header has about {n:,} columns ({head}, ...), over the limit of "
                         f"{MAX_TABLE_COLUMNS:,}; volcomp's tables have a few named columns (docs/reference/file-formats.md)")
    return [h.strip() for h in _csv_row(line, path, row)]


def _check_cells(path: Path, header: list[str], lines: int) -> None:
    if lines * len(header) > MAX_TABLE_CELLS:
        raise InputError(f"{path}: {lines:,} rows x {len(header)} columns = {lines * len(header):,} cells exceed the "
                         f"limit of {MAX_TABLE_CELLS:,} per table; split the file or drop columns")


_OTHER_SEPARATORS = ((";", "semicolon"), ("\t", "tab"))
_DECIMAL_COMMA = re.compile(r"\d,\d")


def _check_separator(path, row: int, header: list[str], body_head: str) -> None:
    """Refuse a table whose header is one cell holding column names split by ``;`` or a tab — a
    spreadsheet's export in a locale with a decimal comma (Excel writes ``x_mm;z_mm`` and ``1,5``) —
    naming the separator, instead of a cell count that misleads ("expected 1 cells … got 2")."""
    if len(header) != 1:
        return
    for sep, name in _OTHER_SEPARATORS:
        names = [h.strip() for h in header[0].split(sep)]
        if len(names) >= 2 and all(names):
            first = next((ln for ln in body_head.split("\n") if ln.strip()), "")
            comma = (" with decimal commas" if _DECIMAL_COMMA.search(first) else "")
            raise InputError(f"{path}: row {row}: cells separated by {name}s ({names[:3]}"
                             f"{' …' if len(names) > 3 else ''}){comma}: a spreadsheet export; save it as CSV "
                             "with ',' separators and '.' decimals")


def _at_least_lines(text: str, k: int) -> bool:
    """``text.count("\\n") + 1 >= k`` without counting a long text to its end."""
    pos = -1
    for _ in range(k - 1):
        pos = text.find("\n", pos + 1)
        if pos < 0:
            return False
    return True


FAST_MIN_ROWS = 2000
"""Tables with at least this many data lines try the pyarrow parser first (below it, the
per-row reader is as fast and needs no import)."""


def _parse_rows(path, body: list[str], header: list[str], first_row: int) -> tuple[list[list[str]], list[int] | None]:
    """The per-row reader: cells stripped, blank rows skipped; a row with the wrong number of
    cells or broken quoting raises :class:`InputError` naming its row. Returns the rows and,
    when blank rows were skipped before the last of them, each row's file line number (else None)."""
    rows, lines = [], []
    for k, line in enumerate(body):
        r = _csv_row(line, path, first_row + k)
        if not r or all(not c.strip() for c in r):
            continue
        if len(r) != len(header):
            hint = ("; decimal commas? (write 1.5, not 1,5)" if len(header) < len(r) <= 2 * len(header)
                    and _DECIMAL_COMMA.search(line)
                    else "")
            raise InputError(
                f"{path}: row {first_row + k}: expected {len(header)} cells (columns {header}), got {len(r)}{hint}"
            )
        rows.append([c.strip() for c in r])
        lines.append(first_row + k)
    contiguous = not lines or lines[-1] - lines[0] == len(lines) - 1 and lines[0] == first_row
    return rows, None if contiguous else lines


def _parse_numeric_fast(text: str, header: list[str]) -> dict | None:
    """Every column as float64 by pyarrow's CSV reader, or None when the table is not plainly
    numeric (then :func:`_parse_rows` reads it, and its checks write any error message).

    Taken only when nothing could read differently from the per-row reader: no quote
    character anywhere (no CSV quoting to interpret), pyarrow finds exactly ``len(header)``
    cells on every line, every column comes out as float64 or int64 (a cell with spaces, a
    word, a date or an empty cell makes it another type or null, and the table goes the slow
    way), and no null (so no blank row was kept). pyarrow parses decimal numbers correctly
    rounded, as Python's ``float`` does; only the empty cell counts as null here.
    """
    if '"' in text:
        return None
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        return None
    try:
        tbl = pacsv.read_csv(
            io.BytesIO(text.encode("utf-8")),
            read_options=pacsv.ReadOptions(column_names=header, use_threads=True),
            parse_options=pacsv.ParseOptions(delimiter=",", quote_char=False, escape_char=False,
                                              newlines_in_values=False, ignore_empty_lines=True),
            convert_options=pacsv.ConvertOptions(null_values=[""], true_values=[], false_values=[],
                                                 strings_can_be_null=False, timestamp_parsers=[],
                                                 decimal_point="."))
    except (pa.ArrowInvalid, pa.ArrowException):
        return None
    out = {}
    for name, col in zip(header, tbl.columns):
        if col.null_count or not (pa.types.is_float64(col.type) or pa.types.is_int64(col.type)):
            return None
        out[name] = col.to_numpy().astype(np.float64)
    return out


def _csv_row(line: str, path, row: int) -> list[str]:
    try:
        return next(csv.reader([line], strict=True), [])
    except csv.Error as exc:
        raise InputError(f"{path}: row {row}: not a CSV row ({exc})") from None


def companion_path(path, tail: str) -> Path:
    """The companion file of ``path`` (an element set's covariance ``tail = ".cov.npz"``, its
    identification report ``".report.json"``): beside it, named after it whatever its suffix. Only a
    ``.json`` suffix (any case) is replaced (``E.json`` → ``E.cov.npz``); any other name keeps its
    whole name (``elements`` → ``elements.cov.npz``, ``E.v2`` → ``E.v2.cov.npz``), so two files
    that differ only in their suffix never share a companion."""
    p = Path(path)
    base = p.name[:-len(".json")] if p.suffix.lower() == ".json" else p.name
    return p.with_name(base + tail)


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
