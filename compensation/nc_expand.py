"""Subprograms, macros and parameters expanded into the flat program the G-code reader reads.

:func:`expand_program` runs a program's control language (Fanuc / Haas Custom Macro B, LinuxCNC O-codes) the
way the controller does and writes out every line it executes, in order, so each call's moves are compensated
where they are cut. What is read, how the dialects differ, what is refused and how the flat program is
written: docs/reference/tool-paths.md, "Subprograms, macros and parameters". Execution is bounded
(:data:`MAX_EXECUTED_LINES`, :data:`MAX_CALL_DEPTH`); :attr:`Expanded.origin` maps every output line back to
its source line and call sites, so every refusal names the source. The reader
(:func:`compensation.gcode.parse_program`) expands only a program its allow-list refuses and that holds a mark
of these constructs (:func:`needs_expansion`).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from errormap.io import InputError

from .nc_modal import ModalTracker
from .nc_polar import has_polar, polar_cuts
from .nc_flow import PREDEFINED_READ
from .nc_flow import (MAX_CALL_DEPTH,  # noqa: F401  (re-exported: the documented call-depth bound)
                      _Frame, _Return, _spliced, assign, call_statement, evaluate, g7x_contour, o_statement)

MAX_EXECUTED_LINES = 2_000_000
"""Executed source lines (every pass of a loop counts): more is refused as an endless loop."""
DIALECTS = ("fanuc", "haas", "linuxcnc", "mach3", "siemens-iso", "grbl")
SLASH_COMMENT = ("'//' is not a comment in G-code (a C-style comment line of some controllers' programs): write the "
                 "comment in ( ) or after ';'")

_MARK_BYTES = (b"#", b"[", b"<", b"@", b"^")
_MARK_WORDS = (b"m98", b"m97", b"m99", b"g65", b"goto", b"while", b"if", b"sub", b"call", b"repeat")
"""A program holding none of these (any case) has nothing to expand (the words of every construct
contain one: ``o100 do`` closes with ``while``, ``END1`` pairs with ``WHILE``, ``endsub`` holds ``sub``)."""
_LINE_MARKS = re.compile(r"#|\[|@|\^|o\s*<|m\s*0*9\s*[789](?![\d.])|g\s*0*65(?![\d.])"
                         r"|(?<![a-z])(?:goto|while|if|then|end\s*\d|do\s*\d)(?![a-z])"
                         r"|^\s*/?\s*(?:n\s*\d+\s*)?o\s*\d+\s*[a-z]", re.I)
_M7X_BYTES = re.compile(rb"m[ \t]*0*7[0-3](?![\d.])")
_END_CODES = re.compile(r"(?<![a-z])m\s*0*(?:2|30)(?![\d.])", re.I)
_O_STMT = re.compile(r"\s*o\s*(<[^>]*>|\d+|\[(?:[^\[\]]|\[[^\[\]]*\])*\])\s*([a-z]+)?", re.I)
_PROG = re.compile(r"\s*(?:[oO]|:)\s*(\d+)\s*$")
_N_LABEL = re.compile(r"\s*[nN]\s*(\d+)")
_COMMENT = re.compile(r"\([^)]*\)|;.*", re.S)
_NUM = re.compile(r"[ \t]*((?:\d[\d \t]*)?\.?[\d \t]*)")
_LCNC_KEY_ORDER = ("sub", "endsub", "call", "do", "while", "repeat", "if", "elseif", "else", "endif", "break",
                   "continue", "endwhile", "endrepeat", "return")
"""LinuxCNC reads an O-word's keyword from the line with its spaces and tabs removed (``close_and_downcase``),
taking the first of these, in this order, that the text starts with (``interp_read.cc`` ``read_o``): so
``else if`` is ``elseif`` and ``end sub`` is ``endsub``; letters left after the keyword stop the controller
("Unexpected character after O-word": only ``[arguments]`` and comments may follow)."""
_G7X_MARK = re.compile(r"[gG]\s*0*7\s*[012]")
"""A plain line that may hold LinuxCNC's G70-G72 (its contour recorded: :func:`compensation.nc_flow.g7x_contour`)."""
FUNCS = ("ABS", "ACOS", "ASIN", "ATAN", "COS", "EXP", "FIX", "FUP", "ROUND", "LN", "SIN", "SQRT", "TAN", "EXISTS")
_PREC = {"**": 4, "*": 3, "/": 3, "MOD": 3, "+": 2, "-": 2, "EQ": 1, "NE": 1, "GT": 1, "GE": 1, "LT": 1, "LE": 1,
         "AND": 0, "OR": 0, "XOR": 0}


class _Refuse(Exception):
    def __init__(self, col: int, msg: str):
        self.col, self.msg = col, msg


class _Stop(Exception):
    """The program ended (M2 / M30 / the closing '%')."""


@dataclass(frozen=True)
class Expanded:
    """A program with its subprograms and macros expanded.

    ``text``: the flat program (the executed lines, endings kept). ``origin[i]``: for output line
    ``i`` a tuple ``(source_line, verbatim, calls)``: the 1-based source line, whether the output
    line is that line byte for byte, and the 1-based lines of the call sites it was reached
    through (outermost first). ``dialect``: the dialect whose rules were used."""

    text: str
    origin: tuple
    dialect: str
    path: str
    files: tuple = ()
    """``(first line, path, sha256)`` of each subprogram file read (:mod:`compensation.nc_subfiles`): source lines from
    ``first line`` (1-based, in the numbering of ``origin``) on are that file's, from its line 1."""
    contours: tuple = ()
    """``(output line (0-based), ((source line, text), ...))`` for each LinuxCNC ``G70``-``G72`` line written: the
    lines of the o-subroutine its Q names (each named as reports name a source line: :meth:`named`), values
    evaluated, an O-word line's text None (:func:`compensation.nc_flow.g7x_contour`), which the cycle reads without
    running them (:mod:`compensation.nc_g7x`)."""

    def at(self, src: int) -> tuple:
        """``(path, line)`` of a source line in the numbering of ``origin``."""
        return file_line(self.files, self.path, src)

    def named(self, src: int):
        """A source line in the numbering of ``origin`` as a report names it (:func:`named_line`)."""
        return named_line(self.files, self.path, src)

    @cached_property
    def line_for_line(self) -> bool:
        """Whether every output line is the main file's line of its number, outside any call: the program's lines
        are then named as those of a program read as it is."""
        return all(src == i and not calls for i, (src, _, calls) in enumerate(self.origin, 1))

    def name(self, line: int):
        """1-based output ``line`` as a report names it (:func:`source_line`)."""
        if self.line_for_line or not 1 <= line <= len(self.origin):
            return line
        src, _, calls = self.origin[line - 1]
        return (f"{self.named(src)} (expanded line {line}"
                + "".join(f", called from line {self.named(c)}" for c in reversed(calls)) + ")")

    def where(self, out_line: int, col: int | None = None) -> str:
        """``'prog.nc: line 12, column 3 (called from line 4)'`` for 1-based output line ``out_line``."""
        src, verbatim, calls = self.origin[out_line - 1]
        path, line = self.at(src)
        at = f"{path}: line {line}"
        if col is not None:
            at += f", column {col}" if verbatim else f" (expanded as {self.line(out_line)!r}), column {col} of that"
        return at + "".join(f" (called from line {self.named(c)})" for c in reversed(calls))

    def note(self) -> str:
        """The header line of a written program: it is the flat (expanded) one."""
        calls = sum(1 for o in self.origin if o[2])
        files = "".join(f"; subprogram file {Path(p).name} sha256 {h[:16]}" for _, p, h in self.files)
        return (f"volcomp: subprograms, macros and parameters expanded by {self.dialect} rules; this is the flat "
                f"program of {len(self.origin)} executed lines, {calls} of them inside calls{files}")

    def line(self, out_line: int) -> str:
        return self.text.split("\n")[out_line - 1].rstrip("\r")

    def relocate(self, exc: InputError) -> InputError:
        """A reader's refusal ``'PATH: line N[, column C]: ...'`` on the flat text, re-addressed to the source."""
        msg = str(exc)
        m = re.match(re.escape(self.path) + r": line (\d+)(?:, column (\d+))?: ", msg)
        if m is None or not 1 <= int(m.group(1)) <= len(self.origin):
            return exc
        col = int(m.group(2)) if m.group(2) else None
        return InputError(f"{self.where(int(m.group(1)), col)}: {msg[m.end():]}")


def file_line(files, path: str, src: int) -> tuple:
    """``(path, line)`` of source line ``src`` in the numbering of the lines run: the main file's (``path``) lines,
    then each subprogram file's of ``files`` ``(first line, path, sha256)`` from its ``first line`` on."""
    for first, sub, _ in reversed(files):
        if src >= first:
            return sub, src - first + 1
    return path, src


def named_line(files, path: str, src: int):
    """Source line ``src`` (:func:`file_line`) as reports and refusals name it: its line ``k`` (int) in the main file
    ``path``, ``'k of FILE'`` in a subprogram file."""
    sub, k = file_line(files, path, src)
    return k if sub == path else f"{k} of {sub}"


def source_line(program, line: int):
    """A reader's 1-based ``line`` as every note of a summary or report names it: the line itself (int) for a
    program read as it is, or written line for line as the source (:attr:`Expanded.line_for_line`; canned cycles
    kept, :meth:`compensation.nc_cycles.CycleExpansion.name`); for one written as its flat program
    (``program.expanded``: subprograms, macros, loops, cycles written as moves), text: its source line
    (:meth:`Expanded.named`), the flat program's line and the call sites, outermost last:
    ``'12 (expanded line 40, called from line 3)'``."""
    exp = getattr(program, "expanded", None)
    return line if exp is None else exp.name(line)


def source_lines(program, lines) -> list:
    """:func:`source_line` of each 1-based line of ``lines`` (ints for a program read as it is)."""
    return [source_line(program, int(k)) for k in lines]


def needs_expansion(data: bytes) -> bool:
    """Whether a program's bytes hold any mark of parameters, subprograms or control flow (or LinuxCNC's modal
    state save / restore ``M70``–``M73``, :mod:`compensation.nc_modal`)."""
    if any(b in data for b in _MARK_BYTES):
        return True
    low = data.lower()
    return any(w in low for w in _MARK_WORDS) or _M7X_BYTES.search(low) is not None


def expand_if_needed(data: bytes, path, dialect: str | None = None, state=None, files=None) -> Expanded | None:
    """:func:`expand_program` of a program's bytes where they hold any mark (:func:`needs_expansion`)
    and the expansion changes the text; None otherwise (the program is read as it is)."""
    if not needs_expansion(data):
        return None
    text = data.decode("latin-1")
    exp = expand_program(text, path, dialect, state, files)
    return None if exp.text == text else exp


def expand_program(text: str, path, dialect: str | None = None, state=None, files=None) -> Expanded:
    """Expand ``text`` (a whole program, Latin-1 decoded) read from ``path`` (named in refusals).

    ``dialect``: one of :data:`DIALECTS` or None (told from content: LinuxCNC O-codes or named
    parameters make it ``linuxcnc``, Fanuc calls or macro statements ``fanuc``). ``state``: a class
    ``(dialect, text)`` that follows the lines written and answers ``#<_x>``, ``#<_metric>`` …
    (:class:`compensation.gcode_classify.ProgramState`; None: those are refused as run-time state). ``files``: the
    :class:`compensation.nc_subfiles.SubprogramFiles` a call of a subprogram not in ``text`` reads (None: refused)."""
    if dialect is not None and dialect not in DIALECTS:
        raise ValueError(f"Expected dialect in {list(DIALECTS)} or None, got {dialect!r}")
    return _Machine(text, str(path), dialect, state, files).run()


# ---------------------------------------------------------------------------- parsing one line
def program_number(body: str) -> int | None:
    """The number of a program-number line (``O9100``, ``:9100``, comments aside), else None: the one rule of
    what starts a program, in the file (:func:`_parse_line`) and in a folder of subprograms
    (:mod:`compensation.nc_subfiles`)."""
    m = _PROG.match(_COMMENT.sub(lambda c: " " * len(c.group()), body))
    return int(m.group(1)) if m else None


def _code_of(body: str) -> str:
    """``body`` with comments blanked (same length, so columns stay); a '(' left is an unclosed comment."""
    code = _COMMENT.sub(lambda m: " " * len(m.group()), body)
    if "(" in code:
        raise _Refuse(code.index("(") + 1, "unclosed '(' comment")
    return code


class _Parser:
    """Recursive-descent reader of the values and expressions of one line (``s`` without comments)."""

    def __init__(self, s: str):
        self.s, self.n = s, len(s)

    def ws(self, i: int) -> int:
        while i < self.n and self.s[i] in " \t\r":
            i += 1
        return i

    def alpha(self, i: int):
        j = i
        while j < self.n and self.s[j].isascii() and self.s[j].isalpha():
            j += 1
        return self.s[i:j].upper(), j

    def number(self, i: int):
        m = _NUM.match(self.s, i)
        text = m.group(1).replace(" ", "").replace("\t", "")
        if not any(c.isdigit() for c in text):
            return None, i
        end = m.end(1)
        while end > i and self.s[end - 1] in " \t":
            end -= 1
        return float(text), end

    def value(self, i: int):
        """One value: number, parameter, ``[expression]``, signed value or function. ``(node, end)``."""
        i = self.ws(i)
        if i >= self.n:
            raise _Refuse(i + 1, "a value is missing")
        c = self.s[i]
        if c == "[":
            node, j = self.binary(i + 1)
            j = self.ws(j)
            if j >= self.n or self.s[j] != "]":
                raise _Refuse(i + 1, "'[' without its ']'")
            return node, j + 1
        if c == "#":
            return self.param(i)
        if c in "+-":
            node, j = self.value(i + 1)
            return (("neg", node) if c == "-" else node), j
        if c.isdigit() or c == ".":
            v, j = self.number(i)
            if v is None:
                raise _Refuse(i + 1, f"unexpected {c!r}")
            if j < self.n and self.s[j] in "eE":
                raise _Refuse(i + 1, "exponent notation is not RS274")
            return ("num", v), j
        if c.isascii() and c.isalpha():
            name, j = self.alpha(i)
            if name not in FUNCS:
                raise _Refuse(*_not_a_function(self.s, i, name))
            j = self.ws(j)
            if j >= self.n or self.s[j] != "[":
                raise _Refuse(i + 1, f"{name} needs its argument in '[ ]' ('(' opens a comment; LinuxCNC stops "
                                     f"here too: \"Left bracket missing after unary operation name\"); write "
                                     f"{name}[...]")
            if name == "EXISTS":
                arg, k = self.value(j)
                if arg[0] != "name":
                    raise _Refuse(i + 1, "EXISTS takes a named parameter #<...>")
                return ("exists", arg[1]), k
            arg, k = self.value(j)
            if name == "ATAN":
                k = self.ws(k)
                if k >= self.n or self.s[k] != "/":
                    raise _Refuse(i + 1, "ATAN is written ATAN[y]/[x]")
                k2 = self.ws(k + 1)
                if k2 >= self.n or self.s[k2] != "[":
                    raise _Refuse(k + 2, "ATAN is written ATAN[y]/[x]")
                arg2, k = self.value(k2)
                return ("atan", arg, arg2, i + 1), k
            return ("fn", name, arg, i + 1), k
        raise _Refuse(i + 1, f"unexpected character {c!r} in a value")

    def param(self, i: int):
        """``#n``, ``##n``, ``#[expr]``, ``#<name>`` at ``i`` (the '#')."""
        j = self.ws(i + 1)
        if j < self.n and self.s[j] == "<":
            k = self.s.find(">", j)
            if k < 0:
                raise _Refuse(i + 1, "'#<' without its '>'")
            name = re.sub(r"\s+", "", self.s[j + 1:k]).lower()
            if not name:
                raise _Refuse(i + 1, "empty parameter name '#<>'")
            return ("name", name, i + 1), k + 1
        if j < self.n and (self.s[j].isdigit() or self.s[j] == "."):
            v, k = self.number(j)
            return ("par", ("num", v), i + 1), k
        if j < self.n and self.s[j] == "$":
            name = re.match(r"\$(\w*)\$?", self.s[j:]).group(1)
            raise _Refuse(i + 1, f"'#${name}$': LinuxCNC reads a named parameter only as #<name> ('$' after '#' is a "
                                 f"bad number to its interpreter, read_parameter); write #<{name}>")
        inner, k = self.value(j)
        return ("par", inner, i + 1), k

    def operator(self, i: int):
        i = self.ws(i)
        if i >= self.n:
            return None, i
        if self.s.startswith("**", i):
            return "**", i + 2
        if self.s[i] in "*/+-":
            return self.s[i], i + 1
        name, j = self.alpha(i)
        return (name, j) if name in _PREC else (None, i)

    def binary(self, i: int, level: int = 0):
        """Expression of operators of precedence ≥ ``level`` (left-associative)."""
        left, i = self.value(i)
        while True:
            at = self.ws(i)
            op, j = self.operator(i)
            if op is None or _PREC[op] < level:
                return left, i
            right, i = self.binary(j, _PREC[op] + 1)
            left = ("bin", op, left, right, at + 1)


MACRO_WORDS = ("WHILE", "GOTO", "END", "THEN", "IF", "DO")
# Two-letter forms (WH, GO, TH, SI, RO ...) stay refused: no FANUC operator's manual text at hand lists which words
# a control reads abbreviated (second-hand notes name functions only, all but POW; none names the macro words).


def _not_a_function(s: str, i: int, name: str) -> tuple:
    """``(column, refusal)`` of a name at ``s[i]`` that is no function: a macro word's first letters (``WH[`` for
    ``WHILE``, the ``W`` read as a word letter before it) named as such, from its first letter."""
    joined = i > 0 and s[i - 1].isascii() and s[i - 1].isalpha()
    word = (s[i - 1] + name).upper() if joined else name
    full = next((w for w in MACRO_WORDS + FUNCS if len(word) >= 2 and w != word and w.startswith(word)), None)
    if full is not None:
        return (i if joined else i + 1), (f"'{word}' is not a macro word: macro words and functions are read written "
                                          f"in full (the two-letter forms some Fanuc editors take are not read); "
                                          f"write {full}")
    return i + 1, f"{name!r} is not a function of the expression language ({' '.join(FUNCS)})"


def _parse_line(body: str):
    """One source line into a statement tuple (its first item the kind); see :class:`_Machine`."""
    code = _code_of(body)
    m = _PROG.match(code)
    if m:
        return ("prog", int(m.group(1)))
    if not _LINE_MARKS.search(code):
        return ("plain", bool(_END_CODES.search(code)))
    p = _Parser(code)
    i = p.ws(0)
    if code.startswith("//", i):
        raise _Refuse(i + 1, SLASH_COMMENT)
    if i < p.n and code[i] == "/":
        raise _Refuse(i + 1, "block delete ('/') on a line with parameters or control flow: whether it "
                             "runs depends on the controller's switch")
    n = _N_LABEL.match(code, i)
    label = int(n.group(1)) if n else None
    i = n.end() if n else i
    o = _O_STMT.match(code, i)
    key = _o_keyword(p, o) if o and o.group(2) else None
    if key is not None:
        return _parse_o(p, o, label, *key)
    if o and o.group(2) and (len(o.group(2)) > 1 or o.group(1)[0] in "<["):
        raise _Refuse(o.start(2) + 1, f"'o{o.group(1)} {o.group(2)}': '{o.group(2)}' is not an O-word keyword "
                                      f"({', '.join(sorted(_LCNC_KEY_ORDER))})")
    key, j = p.alpha(p.ws(i))
    if key == "IF":
        cond, k = p.value(j)
        then, k2 = p.alpha(p.ws(k))
        if then == "GOTO":
            target, k3 = p.value(k2)
            _rest_empty(p, k3)
            return ("ifgoto", label, cond, target, i + 1)
        if then == "THEN":
            if p.ws(k2) >= p.n:
                raise _Refuse(k + 1, "IF [..] THEN with no statement after it: the block form (THEN, ELSE, ENDIF on "
                                     "lines of their own) is not read; write IF [..] GOTO n or IF [..] THEN #i = ...")
            return ("then", label, cond, _assignments(p, k2))
        raise _Refuse(k + 1, "IF [..] is followed by GOTO n or THEN #i = ...")
    if key == "GOTO":
        target, k = p.value(j)
        _rest_empty(p, k)
        return ("goto", label, target, i + 1)
    if key == "WHILE":
        cond, k = p.value(j)
        do, k2 = p.alpha(p.ws(k))
        if do != "DO":
            raise _Refuse(k + 1, "WHILE [..] is followed by DOm")
        ident, k3 = _loop_id(p, k2, do)
        _rest_empty(p, k3)
        return ("while", label, cond, ident, i + 1)
    if key == "END":
        ident, k = _loop_id(p, j, key)
        _rest_empty(p, k)
        return ("endm", label, ident)
    return _parse_words(p, body, code, i, label)


def _loop_id(p: _Parser, j: int, word: str):
    j = p.ws(j)
    v, k = p.number(j)
    if v is None or v != int(v) or not 1 <= v <= 3:
        raise _Refuse(j + 1, f"{word} needs a loop number 1, 2 or 3")
    return int(v), k


def _rest_empty(p: _Parser, k: int, rule: str = ""):
    k = p.ws(k)
    if k < p.n:
        raise _Refuse(k + 1, f"unexpected {p.s[k:k + 12].strip()!r} after the statement{rule}")


def _assignments(p: _Parser, i: int) -> list:
    out = []
    i = p.ws(i)
    while i < p.n:
        if p.s[i] != "#":
            raise _Refuse(i + 1, "expected a parameter setting '#i = ...'")
        target, j = p.param(i)
        j = p.ws(j)
        if j >= p.n or p.s[j] != "=":
            raise _Refuse(i + 1, "a parameter on its own is not a statement ('#i = ...')")
        rhs, k = p.binary(j + 1)
        out.append((target, rhs, i, k))
        i = p.ws(k)
    return out


def _o_keyword(p: _Parser, o):
    """``(keyword, end)`` of an O-word read by LinuxCNC's rule (:data:`_LCNC_KEY_ORDER`: the letters after the
    O-number with blanks removed), or None where they start with no keyword; letters left over are refused."""
    letters, ends, k = [], [], o.start(2)
    while k < p.n and (p.s[k] in " \t" or (p.s[k].isascii() and p.s[k].isalpha())):
        if p.s[k] not in " \t":
            letters.append(p.s[k].lower())
            ends.append(k + 1)
        k += 1
    word = "".join(letters)
    kw = next((w for w in _LCNC_KEY_ORDER if word.startswith(w)), None)
    if kw is None:
        return None
    if len(word) > len(kw):
        left = ends[len(kw)] - 1
        raise _Refuse(left + 1, f"'o{o.group(1)} {p.s[o.start(2):ends[-1]]}': LinuxCNC reads the keyword "
                                f"'{kw}' and stops at '{word[len(kw):]}' (\"Unexpected character after O-word\": only "
                                f"[arguments] and comments may follow); write 'o{o.group(1)} {kw}'")
    return kw, ends[-1]


def _parse_o(p: _Parser, o, label, kw: str, k: int):
    name = re.sub(r"\s+", "", o.group(1)).lower()
    if name.startswith("["):  # an indirect O-number (LinuxCNC: o[#101+2] call), evaluated when called
        if kw != "call":
            raise _Refuse(o.start(1) + 1, f"'o{o.group(1)} {kw}': a computed O-number is read only with call")
        name = ("indirect", p.value(o.start(1))[0])
    args = []
    if kw == "call":
        k = p.ws(k)
        while k < p.n and p.s[k] == "[":
            a, k = p.value(k)
            args.append(a)
            k = p.ws(k)
    elif kw in ("if", "elseif", "while", "repeat") or (kw in ("return", "endsub") and p.ws(k) < p.n):
        a, k = p.value(k)
        args.append(a)
    _rest_empty(p, k, " (LinuxCNC: \"Unexpected character after O-word\"; put it on a line of its own)")
    return ("o", label, name, kw, tuple(args), o.start() + 1)


def _parse_words(p: _Parser, body: str, code: str, i: int, label):
    """Words and parameter settings: ``("words", label, items, assigns, call, ends)``."""
    words, assigns = [], []
    while True:
        i = p.ws(i)
        if i >= p.n:
            break
        c = code[i]
        if c == "#":
            target, j = p.param(i)
            j = p.ws(j)
            if j >= p.n or code[j] != "=":
                raise _Refuse(i + 1, "a parameter outside a word ('#i' alone); write it as a word's value or set it")
            rhs, k = p.binary(j + 1)
            assigns.append((target, rhs, i, k))
            i = k
        elif (c.isascii() and c.isalpha()) or c in "@^":  # @ ^: LinuxCNC's polar words (compensation.nc_polar)
            letter = c.upper()
            j = p.ws(i + 1)
            plain, k = p.number(j) if j < p.n and (code[j].isdigit() or code[j] in ".+-") else (None, j)
            if j < p.n and code[j] in "+-" and plain is None:
                sign = code[j]
                v, k = p.number(p.ws(j + 1))
                plain = None if v is None else (v if sign == "+" else -v)
            if plain is not None and not (k < p.n and code[k] in "eE#[") :
                words.append((letter, i, k, None, float(plain)))
            else:
                node, k = p.value(j)
                words.append((letter, i, k, node, None))
            i = k
        elif c == ":":
            raise _Refuse(i + 1, "unexpected character ':' (in ISO code ':' is the program-number address, read only "
                                 "at the start of a line as ':1234'): remove it or end the block with ';'")
        else:
            raise _Refuse(i + 1, f"unexpected character {c!r}")
    return ("words", label, tuple(words), tuple(assigns), _call_of(words, p), bool(_END_CODES.search(code)))


def _call_of(words: list, p: _Parser):
    """``(kind, {letter: word})`` for a line with M98 / M97 / M99 / G65, else None."""
    kinds = [f"M{w[4]:g}" for w in words if w[0] == "M" and w[4] in (97, 98, 99)]
    kinds += ["G65" for w in words if w[0] == "G" and w[4] == 65]
    kinds += [f"{w[0]}#" for w in words if w[0] in "GM" and w[3] is not None]
    if not kinds:
        return None
    k = kinds[0]
    if k.endswith("#"):
        raise _Refuse(next(w for w in words if w[3] is not None)[1] + 1,
                      f"a {k[0]} code from a parameter: which code runs is decided at run time")
    if len(kinds) > 1:
        raise _Refuse(words[0][1] + 1, f"{' and '.join(kinds)} on one line")
    by = {}
    for w in words:
        if w[0] in by and w[0] not in "N":
            raise _Refuse(w[1] + 1, f"'{w[0]}' twice on a {k} line")
        by[w[0]] = w
    allowed = {"M98": "NMPL", "M97": "NMPL", "M99": "NM"}.get(k)
    if allowed is not None:
        extra = [w for w in words if w[0] not in allowed]
        if extra:
            raise _Refuse(extra[0][1] + 1, f"'{extra[0][0]}' on the {k} line: the reader expands the call "
                                           "on a line of its own (put the other words on their own line)")
    elif any(w[0] in "GMNO" and w is not by.get("G") for w in words if w[0] != "N"):
        w = next(w for w in words if w[0] in "GMO" and w is not by.get("G"))
        raise _Refuse(w[1] + 1, f"'{w[0]}' on the G65 line (its letters are the macro's arguments)")
    return k, by


# ---------------------------------------------------------------------------- running
def _detect(stmts) -> str | None:
    for s in stmts:
        if s[0] == "o" or (s[0] == "words" and any(t[0][0] == "name" for t in s[3])):
            return "linuxcnc"
    for s in stmts:
        if s[0] in ("ifgoto", "then", "goto", "while", "endm", "prog") or (s[0] == "words" and s[4] is not None):
            return "fanuc"
    return None


class _Machine:
    """The controller's interpreter of the control language (module docstring), run once."""

    def __init__(self, text: str, path: str, dialect, state=None, files=None):
        self.path, self.text, self.sub_files, self.files = path, text, files, []
        self.lines = text.split("\n")
        self.endings = ["\n"] * (len(self.lines) - 1) + [""]
        if self.lines and self.lines[-1] == "":
            self.lines.pop()
            self.endings.pop()
        self.stmts, self.n_main = [], len(self.lines)
        for i, ln in enumerate(self.lines):
            try:
                self.stmts.append(_parse_line(ln.rstrip("\r")))
            except _Refuse as r:
                raise InputError(f"{path}: line {i + 1}, column {r.col}: {r.msg}") from None
        self.given = dialect  # as named; the rules below are Fanuc's or LinuxCNC's
        dialect = {"haas": "fanuc", "siemens-iso": "fanuc", "mach3": "linuxcnc"}.get(dialect, dialect)
        polar = has_polar(text)
        self.dialect = dialect or _detect(self.stmts) or ("linuxcnc" if polar else None)
        self.glob, self.gnamed = {}, {}
        self.out, self.origin, self.contours = [], [], []
        self.executed, self.calls = 0, ()
        self.modal = ModalTracker() if _M7X_BYTES.search(text.lower().encode("latin-1")) else None
        follow = state is not None and (PREDEFINED_READ.search(text) or polar)
        self.state = state(self.given, text) if follow else None
        self._index()

    # -- structure
    def _index(self):
        self.subs, self.progs, self.labels = {}, {}, {}
        first_code = next((i for i, ln in enumerate(self.lines) if ln.strip() and ln.strip() != "%"), 0)
        prog_lines = [i for i, s in enumerate(self.stmts) if s[0] == "prog"]
        for i, end in zip(prog_lines, prog_lines[1:] + [len(self.lines)]):
            self.progs.setdefault(self.stmts[i][1], (i + 1, end))
        skip = 1 if prog_lines and prog_lines[0] == first_code else 0  # the main program's own number
        self.main = (0, (prog_lines[skip:] + [len(self.lines)])[0])
        for i, s in enumerate(self.stmts):
            if s[0] == "o" and s[3] == "sub":
                end = self._find(i, s[2], ("endsub",))
                if end is None:
                    raise self._err(i, s[5], f"o{s[2]} sub without its o{s[2]} endsub")
                self.subs[s[2]] = (i + 1, end + 1)
        for i, s in enumerate(self.stmts):
            lab = s[1] if s[0] not in ("plain", "prog") else self._plain_label(i)
            if lab is not None:
                self.labels.setdefault(lab, []).append(i)

    def _plain_label(self, i):
        m = _N_LABEL.match(self.lines[i])
        return int(m.group(1)) if m else None

    def _find(self, i, name, keys):
        for j in range(i + 1, len(self.stmts)):
            s = self.stmts[j]
            if s[0] == "o" and s[2] == name and s[3] in keys:
                return j
        return None

    def named(self, i: int):
        """0-based line ``i`` of the lines run as a refusal names it (:func:`named_line`)."""
        return named_line(self.files, self.path, i + 1)

    def _err(self, i, col, msg) -> InputError:
        """A refusal at 0-based line ``i`` (its file and line; column ``col``), the call sites as
        :meth:`Expanded.where` names them."""
        at = "{}: line {}".format(*file_line(self.files, self.path, i + 1)) + (f", column {col}" if col else "")
        return InputError(at + "".join(f" (called from line {self.named(c)})" for c in reversed(self.calls))
                          + f": {msg}")

    def load(self, path) -> int:
        """Append the subprogram file ``path`` to the lines run (its programs and subroutines indexed); the index of
        its first line."""
        lo = len(self.lines)
        text = self.sub_files.read(path)
        lines = text.split("\n")
        if lines and lines[-1] == "":
            lines.pop()
        ends = ["\n"] * len(lines)  # its last line too: the caller's next line follows it in the flat program
        for k, ln in enumerate(lines):
            try:
                self.stmts.append(_parse_line(ln.rstrip("\r")))
            except _Refuse as r:
                raise InputError(f"{path}: line {k + 1}, column {r.col}: {r.msg}") from None
        self.lines += lines
        self.endings += ends
        self.files.append((lo + 1, str(path), self.sub_files.used[str(path)]))
        prog_lines = [i for i in range(lo, len(self.lines)) if self.stmts[i][0] == "prog"]
        for i, end in zip(prog_lines, prog_lines[1:] + [len(self.lines)]):
            self.progs.setdefault(self.stmts[i][1], (i + 1, end))
        for i in range(lo, len(self.lines)):
            s = self.stmts[i]
            if s[0] == "o" and s[3] == "sub" and s[2] not in self.subs:
                end = self._find(i, s[2], ("endsub",))
                if end is None:
                    raise self._err(i, s[5], f"o{s[2]} sub without its o{s[2]} endsub")
                self.subs[s[2]] = (i + 1, end + 1)
            lab = s[1] if s[0] not in ("plain", "prog") else self._plain_label(i)
            if lab is not None:
                self.labels.setdefault(lab, []).append(i)
        return lo

    # -- output
    def _emit(self, i, text=None):
        if self.modal is not None:  # M70-M73 acted on and blanked (compensation.nc_modal)
            line = self.lines[i] if text is None else text
            new = self.modal.line(self, i, line)
            if new != line:
                text = new
        if self.state is not None:
            self.state.line(i, self.lines[i] if text is None else text)
        verbatim = text is None
        self.out.append(self.lines[i] + self.endings[i] if verbatim else
                        text + ("\r" if self.lines[i].endswith("\r") else "") + self.endings[i])
        self.origin.append((i + 1, verbatim, tuple(c + 1 for c in self.calls)))

    def run(self) -> Expanded:
        try:
            self._unit(self.main, _Frame("main"), main=True)
        except (_Stop, _Return):
            pass
        last = max((i for i, ln in enumerate(self.lines[:self.n_main]) if ln.strip()), default=None)
        if last is not None and self.lines[last].strip() == "%" and (not self.origin or self.origin[-1][0] != last + 1):
            self._emit(last)
        return Expanded("".join(self.out), tuple(self.origin), self.dialect or "unknown", self.path, tuple(self.files),
                        tuple(self.contours))

    def _tick(self, i):
        self.executed += 1
        if self.executed > MAX_EXECUTED_LINES:
            raise self._err(i, None, f"more than {MAX_EXECUTED_LINES:,} lines executed (MAX_EXECUTED_LINES): an "
                                     "endless loop or one the reader does not expand")

    def _unit(self, span, fr: _Frame, main=False):
        pc, end = span
        fr.unit_span = span
        seen_percent = False
        while pc < end:
            self._tick(pc)
            s = self.stmts[pc]
            if s[0] == "plain":
                if main and self.lines[pc].strip() == "%":
                    if seen_percent or self.origin:
                        self._emit(pc)
                        raise _Stop
                    seen_percent = True
                if self.dialect == "linuxcnc" and _G7X_MARK.search(self.lines[pc]):
                    try:
                        code = _code_of(self.lines[pc].rstrip("\r"))
                        words = _parse_words(_Parser(code), code, code, 0, None)[2]
                    except _Refuse:
                        words = ()  # the reader names what the line holds
                    g7x_contour(self, pc, words, {})
                self._emit(pc)
                if s[1]:
                    raise _Stop
                pc += 1
            else:
                pc = getattr(self, "_do_" + s[0])(pc, s, fr)  # the statement's kind names its method

    # -- statements
    def _do_prog(self, pc, s, fr):
        self._emit(pc)
        return pc + 1

    def _do_words(self, pc, s, fr):
        _, label, words, assigns, call, ends = s
        vals = {id(w): evaluate(self, w[3], pc, fr, True) for w in words if w[3] is not None}
        self._assign_all(assigns, pc, fr)
        if call is not None:
            return call_statement(self, pc, call, words, vals, fr)
        if words:
            body = self.lines[pc].rstrip("\r")
            cuts = self._cuts(pc, words, assigns, vals)
            polar, more = polar_cuts(self, pc, body, words, lambda w: vals[id(w)] if w[3] is not None else w[4],
                                     lambda v, col: _fmt(v, pc, col, self))
            cuts += polar
            g7x_contour(self, pc, words, vals)
            if cuts:
                self._emit(pc, _spliced(body, cuts))
            else:
                self._emit(pc)
            for text in more:  # a G91 polar canned cycle's further holes (compensation.nc_polar)
                self._emit(pc, text)
        if ends:
            raise _Stop
        return pc + 1

    def _cuts(self, pc, words, assigns, vals) -> list:
        """``[(start, end, text)]``: the spans of a line's parameter settings (removed) and its words' expressions
        (their values written)."""
        cuts = [(a, b, "") for _, _, a, b in assigns]
        return cuts + [(w[1] + 1, w[2], _fmt(vals[id(w)], pc, w[1] + 1, self)) for w in words
                       if w[3] is not None and w[0] not in "@^"]

    def _do_then(self, pc, s, fr):
        if self._truth(s[2], pc, fr):
            self._assign_all(s[3], pc, fr)
        return pc + 1

    def _assign_all(self, assigns, pc, fr):
        """A line's parameter settings: every value computed first, then set."""
        new = [(t, evaluate(self, rhs, pc, fr), a) for t, rhs, a, _ in assigns]
        for t, v, a in new:
            assign(self, t, v, pc, fr, a + 1)

    def _do_goto(self, pc, s, fr, target=None):
        n = self._int(s[2] if target is None else target, pc, fr, "GOTO's block number")
        lo, hi = fr.unit_span
        hits = [j for j in self.labels.get(n, []) if lo <= j < hi]
        if not hits:
            raise self._err(pc, s[-1], f"GOTO {n}: no block N{n} in this program")
        if len(hits) > 1:
            raise self._err(pc, s[-1], f"GOTO {n}: N{n} appears {len(hits)} times in this program (ambiguous)")
        return hits[0]

    def _do_ifgoto(self, pc, s, fr):
        if self._truth(s[2], pc, fr):
            return self._do_goto(pc, s, fr, target=s[3])
        return pc + 1

    def _do_while(self, pc, s, fr):
        end = self._match_end(pc, s[3])
        if self._truth(s[2], pc, fr):
            return pc + 1
        return end + 1

    def _match_end(self, pc, ident):
        depth = 0
        for j in range(pc + 1, len(self.stmts)):
            t = self.stmts[j]
            if t[0] == "while" and t[3] == ident:
                depth += 1
            elif t[0] == "endm" and t[2] == ident:
                if depth == 0:
                    return j
                depth -= 1
        raise self._err(pc, self.stmts[pc][-1], f"WHILE .. DO{ident} without its END{ident}")

    def _do_endm(self, pc, s, fr):
        for j in range(pc - 1, -1, -1):
            t = self.stmts[j]
            if t[0] == "while" and t[3] == s[2] and self._match_end(j, s[2]) == pc:
                return j
        raise self._err(pc, None, f"END{s[2]} without its WHILE .. DO{s[2]}")

    _do_o = o_statement  # LinuxCNC O-words (compensation.nc_flow)

    # -- values
    def _truth(self, node, pc, fr) -> bool:
        return evaluate(self, node, pc, fr) != 0.0

    def _int(self, node, pc, fr, what) -> int:
        v = evaluate(self, node, pc, fr)
        if v != round(v):
            raise self._err(pc, None, f"{what} {v:g} is not a whole number")
        return int(round(v))


def _fmt(v: float, pc: int, col: int, m: _Machine) -> str:
    """A value written as an RS274 number (fixed point, 10 decimals at most, no exponent)."""
    if not math.isfinite(v) or abs(v) >= 1e9:
        raise m._err(pc, col, f"the value {v!r} cannot be written as a G-code number")
    t = f"{v:.10f}".rstrip("0").rstrip(".")
    return "0" if t in ("", "-0") else t
