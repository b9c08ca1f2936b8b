"""Compiled kernels of the block-wise G-code reader and writer.

:func:`scan_lines` reads the whole file's bytes in one pass and puts each line in one of four kinds exactly as
the block-wise reader's two strict patterns (``gcode_table._bulk_move``, ``_BULK_PASS``) would: ``KIND_MOVE``
(a plain move line: spans and values out), ``KIND_PASS`` (blank or comment-only), ``KIND_OTHER`` (neither: the
per-line classifier reads it), ``KIND_ASK`` (the kernel does not decide: the patterns are asked). A number's
value is ``mantissa / 10**decimals`` in float64 when the mantissa is below 2**53 and there are at most 22
decimals: both operands are exact, so the one division is the correctly rounded value, what ``float(text)``
returns bit for bit; anything else is ``KIND_ASK`` (tests/test_gcode_blockwise.py checks the kernel against
the patterns). :func:`format_fixed` and :func:`render_lines` are the writer's side (numbers exactly as
``format(v, ".6f")``, the output bytes assembled line by line).
"""
from __future__ import annotations

import numpy as np
from numba import njit

KIND_OTHER, KIND_MOVE, KIND_PASS, KIND_ASK = 0, 1, 2, 3

_POW10 = np.array([10.0 ** k for k in range(23)])
_MANT_MAX = 2 ** 53

_SP, _TAB, _CR = 32, 9, 13
_ZERO, _NINE, _DOT, _PLUS, _MINUS = 48, 57, 46, 43, 45
_LP, _RP, _SEMI = 40, 41, 59
_N, _G = 78, 71


@njit(cache=True, nogil=True, inline="always")
def _blanks(buf, p, e):
    while p < e and (buf[p] == _SP or buf[p] == _TAB):
        p += 1
    return p


@njit(cache=True, nogil=True, inline="always")
def _number(buf, p, e, pow10):
    """``[+-]?(\\d+(\\.\\d*)?|\\.\\d+)`` at ``p`` (greedy, as the pattern reads it).
    Returns (status, end, value): status 0 no number, 1 number with value, 2 number the
    kernel does not value exactly (too many digits)."""
    q = p
    neg = False
    if q < e and (buf[q] == _PLUS or buf[q] == _MINUS):
        neg = buf[q] == _MINUS
        q += 1
    mant = 0
    ndig = 0
    nfrac = 0
    while q < e and _ZERO <= buf[q] <= _NINE:
        if ndig < 18:
            mant = mant * 10 + (buf[q] - _ZERO)
        ndig += 1
        q += 1
    nint = ndig
    if q < e and buf[q] == _DOT:
        q += 1
        while q < e and _ZERO <= buf[q] <= _NINE:
            if ndig < 18:
                mant = mant * 10 + (buf[q] - _ZERO)
            ndig += 1
            nfrac += 1
            q += 1
        if nint == 0 and nfrac == 0:
            return 0, p, 0.0
    elif nint == 0:
        return 0, p, 0.0
    if ndig > 17 or mant >= _MANT_MAX or nfrac > 22:
        return 2, q, 0.0
    v = mant / pow10[nfrac]
    return 1, q, -v if neg else v


@njit(cache=True, nogil=True, inline="always")
def _is_pass(buf, p, e):
    """``[ \\t]*(?:\\([^)]*\\)[ \\t]*)*(?:;.*)?`` over buf[p:e]."""
    p = _blanks(buf, p, e)
    while p < e:
        c = buf[p]
        if c == _SEMI:
            return True
        if c != _LP:
            return False
        q = p + 1
        while q < e and buf[q] != _RP:
            q += 1
        if q >= e:
            return False
        p = _blanks(buf, q + 1, e)
    return True


@njit(cache=True, nogil=True, inline="always")
def _scan_one(buf, s, e, pow10, letters, sp, v):
    """Kind of line buf[s:e] (body, no line ending); ``letters`` (4,) the axis words' bytes, in
    the order a plain line writes them, and F's; a move's spans (relative to s) go to ``sp`` (4, 2) and
    its values to ``v`` (3,) (scratch: copied out for moves only)."""
    if _is_pass(buf, s, e):
        return KIND_PASS
    p = _blanks(buf, s, e)
    if p < e and buf[p] == _N:
        q = p + 1
        while q < e and _ZERO <= buf[q] <= _NINE:
            q += 1
        if q == p + 1:
            return KIND_OTHER
        if q - p - 1 > 300:
            return KIND_ASK
        p = _blanks(buf, q, e)
    if p < e and buf[p] == _G:
        q = p + 1
        while q < e and _ZERO <= buf[q] <= _NINE:
            q += 1
        nd = q - p - 1
        ok = (nd == 1 and (buf[p + 1] == _ZERO or buf[p + 1] == _ZERO + 1)) or \
             (nd == 2 and buf[p + 1] == _ZERO and (buf[p + 2] == _ZERO or buf[p + 2] == _ZERO + 1))
        if not ok or (q < e and buf[q] == _DOT):
            return KIND_OTHER
        sp[0, 0] = p - s
        sp[0, 1] = q - s
        p = _blanks(buf, q, e)
    axes = 0
    for j in range(4):  # the three axis words, then F
        if p < e and buf[p] == letters[j]:
            st, q, x = _number(buf, p + 1, e, pow10)
            if st == 0:
                return KIND_OTHER
            if st == 2:
                return KIND_ASK
            if j < 3:
                sp[j + 1, 0] = p + 1 - s
                sp[j + 1, 1] = q - s
                v[j] = x
                axes += 1
            p = _blanks(buf, q, e)
    if p < e and buf[p] == _LP:
        q = p + 1
        while q < e and buf[q] != _RP:
            q += 1
        if q >= e:
            return KIND_OTHER
        p = _blanks(buf, q + 1, e)
    if p < e and buf[p] != _SEMI:
        return KIND_OTHER
    return KIND_MOVE if axes else KIND_OTHER


@njit(cache=True, nogil=True)
def _scan(buf, starts, ends, pow10, letters, kind, spans, vals):
    sp = np.empty((4, 2), np.int32)
    v = np.empty(3)
    for k in range(starts.size):
        s, e = starts[k], ends[k]
        while e > s and buf[e - 1] == _CR:
            e -= 1
        sp[:, :] = -1
        v[:] = np.nan
        kind[k] = _scan_one(buf, s, e, pow10, letters, sp, v)
        if kind[k] == KIND_MOVE:
            for a in range(4):
                spans[k, a, 0] = sp[a, 0]
                spans[k, a, 1] = sp[a, 1]
            for a in range(3):
                vals[k, a] = v[a]


KERNEL_BLOCK = 1 << 20
"""Lines (moves) per call of the scanning and path-length kernels: ≈ 0.1 s of CPU each (measured
0.11 s for 1,000,000 lines, 0.085 s for 1,000,000 X-Z-A path lengths through the chain), so a
KeyboardInterrupt, which Python can raise only between compiled calls, acts within that time
however long the file."""


def line_bounds(buf: np.ndarray):
    """Start and end (exclusive, before the ``\\n``) of every line of ``buf`` (uint8), as
    :func:`compensation.gcode.split_lines` cuts them: (n,), (n,) int64."""
    nl = np.flatnonzero(buf == 10)
    starts = np.concatenate([[0], nl + 1]).astype(np.int64)
    ends = np.concatenate([nl, [buf.size]]).astype(np.int64)
    if starts[-1] == buf.size:  # the text ends with '\n' (or is empty): no last partial line
        starts, ends = starts[:-1], ends[:-1]
    return starts, ends


def scan_lines(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, words):
    """Kinds (n,) int8, word spans (n, 4, 2) int32 (the G word and the three axis words
    ``words``, e.g. ``("X", "Z", "A")``, in that order; relative to the line start, -1 where
    absent) and the three axis values (n, 3) (NaN where absent) of every line."""
    if len(words) != 3 or not all(isinstance(w, str) and len(w) == 1 for w in words):
        raise ValueError(f"Expected three one-letter axis words, got {list(words)}")
    letters = np.frombuffer(("".join(words) + "F").encode("ascii"), np.uint8).copy()
    n = starts.size
    kind = np.empty(n, np.int8)
    spans = np.full((n, 4, 2), -1, np.int32)
    vals = np.full((n, 3), np.nan)
    for a in range(0, n, KERNEL_BLOCK):  # Python between blocks: Ctrl-C acts within one block
        b = min(n, a + KERNEL_BLOCK)
        _scan(buf, starts[a:b], ends[a:b], _POW10, letters, kind[a:b], spans[a:b], vals[a:b])
    return kind, spans, vals


# ---------------------------------------------------------------------------- writing

FIXED_MAX = 1e9
"""Largest magnitude :func:`format_fixed` takes (its integers hold 10**9 with 7 decimals);
:func:`compensation.gcode.render_table` writes a program with larger numbers line by line."""


def format_fixed(values, decimals):
    """Every value as ``compensation.gcode.fmt`` writes it (``format(v, f".{decimals}f")``, ``decimals`` an
    int or one per value; a negative zero without its sign): (magnitude in units of 10**-decimals (n,) int64,
    negative (n,) bool). Values within a few ulps of a tie, or above 2**50 scaled, go through Python's
    formatting one by one (``v * 10**decimals`` rounded is exact elsewhere)."""
    v = np.asarray(values, dtype=float)
    if not np.all(np.abs(v) < FIXED_MAX):
        raise ValueError(f"Expected finite values below {FIXED_MAX:g} in magnitude, got {v[~(np.abs(v) < FIXED_MAX)][0]}")
    dec = np.asarray(decimals, dtype=np.int64)
    q = v * 10.0 ** dec
    r = np.rint(q)
    fl = np.floor(q)
    aq = np.abs(q)
    doubt = ~(aq < 2.0 ** 50) | (np.abs((q - fl) - 0.5) <= np.maximum(1e-6, 8 * np.spacing(aq)))
    mag = np.abs(r).astype(np.int64, copy=False) if not doubt.any() else np.where(doubt, 0, np.abs(r)).astype(np.int64)
    for i in np.flatnonzero(doubt).tolist():
        s = format(float(v[i]), f".{int(np.broadcast_to(dec, v.shape)[i])}f")
        mag[i] = int(s.lstrip("-").replace(".", ""))
    neg = (v < 0) & (mag != 0)
    return mag, neg


@njit(cache=True, nogil=True, inline="always")
def _num_len(mag, neg, dec, pow10i):
    ip = mag // pow10i[dec]
    nd = 1
    while ip >= 10:
        ip //= 10
        nd += 1
    return nd + 1 + dec + (1 if neg else 0)


@njit(cache=True, nogil=True, inline="always")
def _put_num(out, o, mag, neg, dec, pow10i, write):
    """One number's digits at ``out[o:]`` (only its length counted where not ``write``); returns its end."""
    end = o + _num_len(mag, neg, dec, pow10i)
    if not write:
        return end
    q = end - 1
    m = mag
    for _ in range(dec):
        out[q] = _ZERO + m % 10
        m //= 10
        q -= 1
    out[q] = _DOT
    q -= 1
    while True:
        out[q] = _ZERO + m % 10
        m //= 10
        q -= 1
        if m == 0:
            break
    if neg:
        out[q] = _MINUS
    return end


@njit(cache=True, nogil=True, inline="always")
def _copy(out, o, buf, a, b, write):
    """``buf[a:b]`` at ``out[o:]`` (only counted where not ``write``); returns the end."""
    if not write:
        return o + (b - a)
    for q in range(a, b):
        out[o] = buf[q]
        o += 1
    return o


@njit(cache=True, nogil=True)
def _render(buf, starts, stops, mode, row_of_line, vert_of_row, spans, mags, negs, inch, decs,
            blob, blob_off, pow10i, out, out_off, write):
    """Output of every source line: ``mode`` 0 copy buf[starts:stops]; 1 the line with its three
    axis numbers (table row ``r = row_of_line[i]``, word spans ``spans[r]`` relative to the line
    start) replaced by vertex ``v = vert_of_row[r]``: ``mags[v]``/``negs[v]`` with ``decs[j]``
    (column ``j``: decimals on a mm line, on an inch line) decimals; 2 the bytes blob[blob_off[i]:blob_off[i + 1]]. First call
    (``write`` False) fills ``out_off`` (n + 1,); the second writes ``out``."""
    o = 0
    for i in range(starts.size):
        if not write:
            out_off[i] = o
        m = mode[i]
        if m == 0:
            o = _copy(out, o, buf, starts[i], stops[i], write)
        elif m == 2:
            o = _copy(out, o, blob, blob_off[i], blob_off[i + 1], write)
        else:
            r = row_of_line[i]
            v = vert_of_row[r]
            pos = starts[i]
            for j in range(3):
                a = starts[i] + spans[r, j + 1, 0]
                b = starts[i] + spans[r, j + 1, 1]
                dec = decs[j, 1] if inch[v] else decs[j, 0]
                o = _copy(out, o, buf, pos, a, write)
                o = _put_num(out, o, mags[v, j], negs[v, j], dec, pow10i, write)
                pos = b
            o = _copy(out, o, buf, pos, stops[i], write)
    if not write:
        out_off[starts.size] = o


_POW10I = np.array([10 ** k for k in range(19)], dtype=np.int64)


def render_lines(buf, starts, stops, mode, row_of_line, vert_of_row, spans, mags, negs, inch, decs, blob, blob_off):
    """The output bytes (uint8 array) and each source line's output offsets (n + 1,); see
    :func:`_render`. ``decs`` (3, 2): per axis column the decimals written on a mm line and on an
    inch line (a rotary column: its degrees' decimals twice); ``blob_off`` (n + 1,)
    indexes ``blob`` for the lines of mode 2."""
    n = starts.size
    out_off = np.empty(n + 1, np.int64)
    empty = np.zeros(0, np.uint8)
    decs = np.asarray(decs, np.int64)
    if decs.shape != (3, 2):
        raise ValueError(f"Expected decimals of shape (3, 2) (per axis column: mm line, inch line), got {decs.shape}")
    args = (buf, starts, stops, mode, row_of_line, vert_of_row, spans, mags, negs, inch, decs, blob, blob_off, _POW10I)
    _render(*args, empty, out_off, False)
    out = np.empty(int(out_off[n]), np.uint8)
    _render(*args, out, out_off, True)
    return out, out_off
