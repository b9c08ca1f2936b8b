"""The block-wise reader's columns (:mod:`compensation.gcode`): the strict plain-line patterns, the moves as
columns (:class:`MoveTable`) and the lazy sequences over them."""
from __future__ import annotations

import functools
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .gcode_words import GMove, Word


# ---------------------------------------------------------------------------- block-wise
# Plain move and comment lines are recognised by two strict patterns and read in bulk; every other line, and
# any the bulk step would not read exactly as the per-line reader (compensation.gcode_classify) does, goes
# through the per-line classifier in order: the per-line reader's result (tests/test_gcode_blockwise.py).

_BULK_NUM = r"[+-]?(?:\d{1,300}(?:\.\d*)?|\.\d+)"
"""A plain RS274 number, no blanks inside; at most 300 digits before the point, so it is finite."""


@functools.lru_cache(maxsize=16)
def _bulk_move(words: tuple) -> re.Pattern:
    """A plain move line of a machine with the three axis words ``words`` (``("X", "Z", "A")``):
    optional N, optional G0/G1 (G00/G01), then the three axis words in this order (any of them),
    optional F, an optional trailing comment. Upper case, blanks only between words; a number
    followed by blanks and a digit (RS274 reads 'X1 0' as X10) does not match. Group 1 is the G
    word, groups 2-4 the three axis numbers."""
    axes = "".join(rf"(?:{w}({_BULK_NUM})[ \t]*)?" for w in words)
    return re.compile(r"[ \t]*(?:N\d{1,300}[ \t]*)?(?:(G0?[01])[ \t]*)?" + axes + rf"(?:F{_BULK_NUM}[ \t]*)?"
                      r"(?:\([^)]*\)[ \t]*)?(?:;.*)?")
_BULK_PASS = re.compile(r"[ \t]*(?:\([^)]*\)[ \t]*)*(?:;.*)?")


@dataclass
class MoveTable:
    """The moves of a program as columns, in order (n moves).

    ``line`` (n,) 0-based line; ``kind`` (n,) 0 rapid, 1 linear, 2 arc; ``start``/``end``
    (n, 3) absolute mm / deg (NaN: not known); ``inch``, ``incremental``, ``compensate`` (n,)
    bool; ``known`` (n, 3); ``obj`` (n,) index into ``objects`` (the :class:`GMove` of a move
    read line by line) or -1 for a move read in bulk, whose G word and three axis word
    spans in its line are ``spans`` (n, 4, 2) (-1 where absent).
    """

    line: np.ndarray
    kind: np.ndarray
    start: np.ndarray
    end: np.ndarray
    inch: np.ndarray
    incremental: np.ndarray
    compensate: np.ndarray
    known: np.ndarray
    obj: np.ndarray
    objects: list
    spans: np.ndarray

    def __len__(self) -> int:
        return self.line.shape[0]

    @classmethod
    def concat(cls, pieces: list, objects: list) -> "MoveTable":
        if not pieces:
            z3 = np.zeros((0, 3))
            return cls(np.zeros(0, np.int64), np.zeros(0, np.int8), z3, z3.copy(), *(np.zeros(0, bool),) * 3,
                       np.zeros((0, 3), bool), np.zeros(0, np.int64), objects, np.zeros((0, 4, 2), np.int32))
        cols = list(zip(*pieces))
        return cls(*(np.concatenate(c) for c in cols[:9]), objects, np.concatenate(cols[9]))


def _piece_from_move(m: GMove, k: int) -> tuple:
    """One table row (the columns of :class:`MoveTable`, ``objects`` aside) for a per-line move."""
    kind = {"rapid": 0, "linear": 1, "arc": 2, "spline": 2}[m.kind]
    return (np.array([m.index]), np.array([kind], np.int8), m.start[None, :].astype(float),
            m.end[None, :].astype(float), np.array([m.units == "inch"]), np.array([m.incremental]),
            np.array([m.compensate]), np.asarray(m.known, bool)[None, :], np.array([k]),
            np.full((1, 4, 2), -1, np.int32))


class _LazyMoves(Sequence):
    """``GProgram.moves`` of a block-wise read program: the :class:`GMove` of each move, built
    from the table when first asked for (a bulk move's words are re-read from its line)."""

    def __init__(self, table: MoveTable, lines: list, words: tuple):
        self._t, self._lines, self._words, self._cache = table, lines, words, {}

    def __len__(self) -> int:
        return len(self._t)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        k = range(len(self))[k]
        if k not in self._cache:
            self._cache[k] = self._build(k)
        return self._cache[k]

    def _build(self, k: int) -> GMove:
        t = self._t
        if t.obj[k] >= 0:
            return t.objects[t.obj[k]]
        i = int(t.line[k])
        body = self._lines[i].rstrip("\r\n")
        words = {}
        for j, a in enumerate(self._words):
            s, e = (int(v) for v in t.spans[k, j + 1])
            if s >= 0:
                words[a] = Word(a, float(body[s:e]), body[s:e], s - 1, s, e)
        gs, ge = (int(v) for v in t.spans[k, 0])
        motion = Word("G", float(body[gs + 1:ge]), body[gs + 1:ge], gs, gs + 1, ge) if gs >= 0 else None
        return GMove(i, "rapid" if t.kind[k] == 0 else "linear", t.start[k].copy(), t.end[k].copy(),
                     "inch" if t.inch[k] else "mm", bool(t.incremental[k]), words, motion,
                     bool(t.compensate[k]), known=t.known[k].copy())


def _forward_fill(values, given, initial):
    """Per column, the last given value up to each row (``initial`` before the first), (m, 3)."""
    m = values.shape[0]
    out = np.empty_like(values)
    rows = np.arange(m)
    for j in range(values.shape[1]):
        last = np.maximum.accumulate(np.where(given[:, j], rows, -1))
        out[:, j] = np.where(last >= 0, values[np.maximum(last, 0), j], initial[j])
    return out


class _Lines(Sequence):
    """``GProgram.lines`` of a block-wise read file: each line (its ending kept) cut from the
    file's text when asked for, as :func:`split_lines` cuts them."""

    def __init__(self, text: str, starts, stops):
        self._text, self._starts, self._stops = text, starts, stops

    def __len__(self) -> int:
        return self._starts.size

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = range(len(self))[i]
        return self._text[self._starts[i]:self._stops[i]]

    def __iter__(self):
        text = self._text
        for s, e in zip(self._starts.tolist(), self._stops.tolist()):
            yield text[s:e]
