"""The statements of :mod:`compensation.nc_expand` that branch, call and compute: LinuxCNC O-codes,
Fanuc/Haas calls (``M98``, ``M97``, ``G65``, ``M99``), expression values and parameter settings.

Every function takes the running interpreter (``nc_expand._Machine``) ``m``, the 0-based source line
``pc`` and the current frame ``fr``; a statement returns the next line to run.
"""
from __future__ import annotations

import math
import operator
import re

from errormap.io import InputError

MAX_CALL_DEPTH = 32
"""Nested calls (subprograms, macros, subroutines): more is refused as runaway recursion
(Fanuc allows 10 levels of M98 and 4 of G65 (5 with G66), LinuxCNC tens)."""
EQ_TOLERANCE_LINUXCNC = 1e-4
"""LinuxCNC's ``EQ``/``NE`` compare within this (its interpreter's TOLERANCE_EQUAL); Fanuc compares exactly."""
G65_ARGS = {"A": 1, "B": 2, "C": 3, "I": 4, "J": 5, "K": 6, "D": 7, "E": 8, "F": 9, "H": 11, "M": 13, "Q": 17,
            "R": 18, "S": 19, "T": 20, "U": 21, "V": 22, "W": 23, "X": 24, "Y": 25, "Z": 26}
"""Fanuc G65 argument specification I: address -> local variable."""
CONTROLLER_PARAMETERS = (
    (5061, 5069, "probe result (G38/G31 skip position)"), (5161, 5169, "G28 reference position"),
    (5181, 5189, "G30 reference position"), (5201, 5399, "work offset / coordinate system"),
    (5400, 5409, "current tool and its offsets"), (5420, 5428, "current position"),
    (5001, 5060, "current position"), (5070, 5160, "position / servo data"),
    (4001, 4400, "modal information (#4120: current tool)"), (3000, 3999, "controller clock, alarm or parts count"),
    (2000, 2999, "tool offset memory"), (1000, 1999, "interface signals"), (7000, 99999, "extended offsets"),
)
"""Numbered parameters that hold controller state (ranges of the Fanuc and LinuxCNC tables), named in refusals."""


class _Frame:
    """One level of a running program: its unit, its local parameters (a subprogram shares its caller's)."""

    def __init__(self, unit, named=None, local=None):
        self.unit = unit
        self.local = {} if local is None else local
        self.named = {} if named is None else named
        self.repeats = {}


class _Return(Exception):
    """A subprogram returns (M99, endsub, return)."""


LOCAL_LAST = {"linuxcnc": 30, "fanuc": 33, None: 30}
"""Highest local numbered parameter (LinuxCNC #1-#30 per subroutine call, Fanuc #1-#33 per macro call)."""
GLOBAL_SETTABLE = {"linuxcnc": ((31, 4999),), "fanuc": ((100, 199), (500, 999)), None: ((31, 999),)}
"""Numbered parameters a program may set (LinuxCNC 31-4999 user parameters; Fanuc common variables
#100-#199 and #500-#999). Others hold controller state and are refused when set."""
PREDEFINED_NAMES = {"_x", "_y", "_z", "_a", "_b", "_c", "_u", "_v", "_w", "_current_tool", "_current_pocket",
                    "_selected_tool", "_selected_pocket", "_line", "_motion_mode", "_plane", "_feed", "_rpm",
                    "_metric", "_imperial", "_absolute", "_incremental", "_coord_system", "_tool_offset",
                    "_spindle_on", "_spindle_cw", "_mist", "_flood", "_speed_override", "_feed_override",
                    "_adaptive_feed", "_feed_hold", "_inverse_time", "_units_per_minute", "_units_per_rev",
                    "_ccomp_off", "_ccomp_left", "_ccomp_right", "_retract_r_plane", "_retract_old_z",
                    "_task", "_call_level", "_remap_level", "_lathe_diameter_mode"}
"""LinuxCNC's predefined named parameters: run-time state of the controller, never the program's."""


TRACKED_NAMES = {"_x": "X", "_y": "Y", "_z": "Z", "_a": "A", "_b": "B", "_c": "C", "_u": "U", "_v": "V", "_w": "W",
                 "_metric": None, "_imperial": None, "_absolute": None, "_incremental": None,
                 "_lathe_diameter_mode": None}
"""Predefined parameters the program itself determines (LinuxCNC G-code reference, "Predefined Named Parameters":
``#<_x>`` … the current position in the current coordinate system, in the current units; ``#<_metric>`` …
the modes, 1 or 0): read from the lines written before, in the order they run (:class:`ProgramState`)."""
PREDEFINED_READ = re.compile(r"#\s*<\s*_(?:[xyzabcuvw]|metric|imperial|absolute|incremental|lathe_diameter_mode)\s*>",
                             re.IGNORECASE)


# ---------------------------------------------------------------------------- parameters
def _controller_state(idx: int) -> str:
    for lo, hi, what in CONTROLLER_PARAMETERS:
        if lo <= idx <= hi:
            return f" ({what})"
    return ""


def read_numbered(m, idx: int, pc, fr, col) -> float:
    if idx <= LOCAL_LAST.get(m.dialect, 30) and idx >= 1:
        if idx in fr.local:
            return fr.local[idx]
        how = "not passed to this call" if m.calls else "not set by the program before this line"
        raise m._err(pc, col, f"#{idx} is {how}: its value would be whatever the controller holds")
    if idx in m.glob:
        return m.glob[idx]
    if idx == 0:
        raise m._err(pc, col, "#0 is the controller's null (vacant) value: arithmetic with it is not read")
    raise m._err(pc, col, f"#{idx}{_controller_state(idx)} is controller state, not set by the program: its "
                          "value is known only at run time (set it in the program to use it)")


def read_named(m, name: str, pc, fr, col) -> float:
    table = m.gnamed if name.startswith("_") else fr.named
    if name in table:
        return table[name]
    if name in TRACKED_NAMES and getattr(m, "state", None) is not None:
        return m.state.value(m, name, pc, col)
    if name in PREDEFINED_NAMES:
        raise m._err(pc, col, f"#<{name}> is the controller's run-time state (a predefined parameter): its value "
                              "is known only at run time")
    raise m._err(pc, col, f"#<{name}> is not set by the program before this line"
                          + (" (a global: its value would be whatever the controller holds)" if name.startswith("_")
                             else ""))


def assign(m, target, v: float, pc, fr, col):
    if target[0] == "name":
        name = target[1]
        if name in PREDEFINED_NAMES:
            raise m._err(pc, col, f"#<{name}> is a predefined (read-only) parameter of the controller")
        (m.gnamed if name.startswith("_") else fr.named)[name] = v
        return
    idx = _index(m, target[1], pc, fr, target[2])
    if 1 <= idx <= LOCAL_LAST.get(m.dialect, 30):
        fr.local[idx] = v
    elif any(lo <= idx <= hi for lo, hi in GLOBAL_SETTABLE.get(m.dialect, GLOBAL_SETTABLE[None])):
        m.glob[idx] = v
    elif idx == 3000 or idx == 3006:
        raise m._err(pc, col, f"#{idx} = ...: the program raises an alarm / stop message here")
    else:
        raise m._err(pc, col, f"#{idx} = ...: #{idx}{_controller_state(idx)} is controller state (setting it "
                              "changes offsets or controller data the reader does not follow)")


def _index(m, node, pc, fr, col) -> int:
    v = evaluate(m, node, pc, fr)
    if v != round(v) or v < 0:
        raise m._err(pc, col, f"parameter number {v:g} is not a whole number ≥ 0")
    return int(round(v))


# ---------------------------------------------------------------------------- expressions
def evaluate(m, node, pc, fr, in_word=False) -> float:
    kind = node[0]
    if kind == "num":
        return node[1]
    if kind == "neg":
        return -evaluate(m, node[1], pc, fr, in_word)
    if kind == "par":
        return read_numbered(m, _index(m, node[1], pc, fr, node[2]), pc, fr, node[2])
    if kind == "name":
        return read_named(m, node[1], pc, fr, node[2])
    if kind == "exists":
        return 1.0 if node[1] in (m.gnamed if node[1].startswith("_") else fr.named) else 0.0
    if kind == "atan":
        y, x = evaluate(m, node[1], pc, fr), evaluate(m, node[2], pc, fr)
        a = math.degrees(math.atan2(y, x))
        return a % 360.0 if m.dialect == "fanuc" else a
    if kind == "fn":
        return _function(m, node[1], evaluate(m, node[2], pc, fr), pc, node[3], in_word)
    return _binary(m, node[1], evaluate(m, node[2], pc, fr, in_word), evaluate(m, node[3], pc, fr, in_word),
                   pc, node[4])


def _round_half_away(v: float) -> float:
    return math.copysign(math.floor(abs(v) + 0.5), v)


def _function(m, name, v, pc, col, in_word) -> float:
    bad = None
    if name in ("FIX", "FUP") and v < 0 and v != int(v):
        if m.dialect is None:
            raise m._err(pc, col, f"{name} of a negative number rounds one way on LinuxCNC and the other on "
                                  "Fanuc, and the program's content does not tell its controller")
        if m.dialect == "fanuc":
            return float(math.trunc(v)) if name == "FIX" else -float(math.ceil(-v))
    if name == "ROUND" and in_word and m.dialect != "linuxcnc":
        raise m._err(pc, col, "ROUND inside an address rounds to the control's least input increment (a setting "
                              "the reader does not know): round in a parameter setting instead")
    if name in ("ASIN", "ACOS") and not -1.0 <= v <= 1.0:
        bad = f"{name}[{v:g}] is outside [-1, 1]"
    elif name == "SQRT" and v < 0:
        bad = f"SQRT of a negative number ({v:g})"
    elif name == "LN" and v <= 0:
        bad = f"LN of {v:g} (not > 0)"
    if bad:
        raise m._err(pc, col, bad)
    rad = math.radians
    f = {"ABS": abs, "ACOS": lambda x: math.degrees(math.acos(x)), "ASIN": lambda x: math.degrees(math.asin(x)),
         "COS": lambda x: math.cos(rad(x)), "SIN": lambda x: math.sin(rad(x)), "TAN": lambda x: math.tan(rad(x)),
         "EXP": math.exp, "LN": math.log, "SQRT": math.sqrt, "FIX": math.floor, "FUP": math.ceil,
         "ROUND": _round_half_away}[name]
    try:
        return float(f(v))
    except OverflowError:
        raise m._err(pc, col, f"{name}[{v:g}] overflows") from None


_PLAIN_OPS = {"+": operator.add, "-": operator.sub, "*": operator.mul,
              "GT": lambda a, b: float(a > b), "GE": lambda a, b: float(a >= b),
              "LT": lambda a, b: float(a < b), "LE": lambda a, b: float(a <= b)}
"""The operators both controllers compute alike."""


def _binary(m, op, a, b, pc, col) -> float:
    d = m.dialect
    if op in _PLAIN_OPS:
        return _PLAIN_OPS[op](a, b)
    if op in ("/", "MOD") and b == 0:
        raise m._err(pc, col, f"{op} by zero")
    if op == "/":
        return a / b
    if op == "**":
        if a < 0 and b != int(b):
            raise m._err(pc, col, f"{a:g} ** {b:g}: a negative number to a fractional power")
        if a == 0 and b < 0:
            raise m._err(pc, col, f"{a:g} ** {b:g}: zero to a negative power (a division by zero)")
        try:
            return float(a ** b)
        except OverflowError:
            raise m._err(pc, col, f"{a:g} ** {b:g} overflows") from None
    if op == "MOD":
        if d == "linuxcnc":
            r = math.fmod(a, b)
            return r if r >= 0 else r + abs(b)
        if a >= 0 and b > 0 and (d is None or (a == int(a) and b == int(b))):
            return math.fmod(a, b)
        if d == "fanuc" and a == int(a) and b == int(b):
            return math.fmod(a, b)
        raise m._err(pc, col, f"{a:g} MOD {b:g}: the controllers differ on this (LinuxCNC: a non-negative "
                              "remainder; Fanuc: whole numbers only)")
    if op in ("EQ", "NE"):
        diff = abs(a - b)
        if d == "linuxcnc":
            eq = diff < EQ_TOLERANCE_LINUXCNC
        elif d is None and 0 < diff < EQ_TOLERANCE_LINUXCNC:
            raise m._err(pc, col, f"{a!r} {op} {b!r}: LinuxCNC takes these as equal, Fanuc not, and the program's "
                                  "content does not tell its controller")
        else:
            eq = diff == 0
        return float(eq if op == "EQ" else not eq)
    # AND OR XOR
    if d != "linuxcnc" and not (a in (0.0, 1.0) and b in (0.0, 1.0)):
        if a != int(a) or b != int(b):
            raise m._err(pc, col, f"{a:g} {op} {b:g}: bitwise on a fraction")
        ia, ib = int(a), int(b)
        if d is None:
            raise m._err(pc, col, f"{a:g} {op} {b:g}: LinuxCNC takes it as logic, Fanuc bitwise, and the "
                                  "program's content does not tell its controller")
        return float({"AND": ia & ib, "OR": ia | ib, "XOR": ia ^ ib}[op])
    ta, tb = a != 0, b != 0
    return float({"AND": ta and tb, "OR": ta or tb, "XOR": ta != tb}[op])


# ---------------------------------------------------------------------------- calls
def _enter(m, pc, span, frame, times=1):
    if len(m.calls) >= MAX_CALL_DEPTH:
        raise m._err(pc, None, f"calls nested more than {MAX_CALL_DEPTH} deep (MAX_CALL_DEPTH): runaway recursion")
    m.calls = m.calls + (pc,)
    try:
        for _ in range(times):
            try:
                m._unit(span, frame)
            except _Return:
                pass
            if m.modal is not None:
                m.modal.leave(m, pc)  # an M73 state restored on return (compensation.nc_modal)
    finally:
        m.calls = m.calls[:-1]


def _word_value(w, vals) -> float:
    return w[4] if w[3] is None else vals[id(w)]


def _whole(m, pc, w, vals, what: str) -> int:
    """A call word's value as a whole number ≥ 0; refused (``what`` names it) otherwise."""
    v = _word_value(w, vals)
    if v != int(v) or v < 0:
        raise m._err(pc, w[1] + 1, what.format(v))
    return int(v)


def call_statement(m, pc, call, words, vals, fr):
    kind, by = call
    if kind == "M99":
        if not m.calls:
            raise m._err(pc, by["M"][1] + 1, "M99 in the main program restarts it endlessly: end it with M30")
        raise _Return
    if m.given == "grbl" or (kind == "M97" and m.given not in (None, "haas", "rs274")):
        w = by.get("M") or by.get("G") or by["P"]
        why = ("grbl has no subprogram calls" if m.given == "grbl" else
               f"M97 is Haas's local subprogram call, not a call on {m.given} (name --dialect haas)")
        raise m._err(pc, w[1] + 1, f"{kind}: {why}")
    times = 1 if "L" not in by else _whole(m, pc, by["L"], vals,
                                           kind + " repeat count L{:g} is not a whole number ≥ 0")
    if "P" not in by:
        raise m._err(pc, None, f"{kind} without P (the program to call)")
    p = _whole(m, pc, by["P"], vals, kind + " P{:g} is not a program number")
    col = by["P"][1] + 1
    if kind == "M97":
        lo, hi = fr.unit_span
        hits = [j for j in m.labels.get(p, []) if lo <= j < hi]
        if len(hits) != 1:
            raise m._err(pc, col, f"M97 P{p}: {'no' if not hits else 'more than one'} block N{p} in this program")
        _enter(m, pc, (hits[0], len(m.stmts)), _Frame("M97", named=fr.named, local=fr.local), times)
        return pc + 1
    if kind == "M98" and "L" not in by and p > 9999:
        if m.given == "fanuc":
            times, p = p // 10000, p % 10000
        elif m.given != "haas":
            raise m._err(pc, col, f"M98 P{p}: on Fanuc the digits before the last four are a repeat count, on Haas "
                                  "P is the program number; write it as M98 P<program> L<count>")
    if p not in m.progs:
        _load_program(m, pc, col, kind, p)
    if kind == "M98":
        frame = _Frame(f"O{p}", named=fr.named, local=fr.local)  # a subprogram shares its caller's locals
    else:  # G65: a new level of locals from the arguments
        local = {G65_ARGS[w[0]]: _word_value(w, vals) for w in words if w[0] in G65_ARGS}
        frame = _Frame(f"O{p}", named={}, local=local)
    _enter(m, pc, m.progs[p], frame, times)
    return pc + 1


def _load_program(m, pc, col, kind, p):
    """Program O``p`` read from the subprogram folders (:mod:`compensation.nc_subfiles`); refused without them."""
    if m.sub_files is None:
        raise m._err(pc, col, f"{kind} P{p}: program O{p} is not in this file (a subprogram stored in the "
                              "controller's memory): give its folder with --subprograms DIR")
    try:
        path = m.sub_files.fanuc(p)
    except InputError as exc:
        raise m._err(pc, col, f"{kind} P{p}: {exc}") from None
    if path is None:
        raise m._err(pc, col, f"{kind} P{p}: program O{p} is neither in this file nor in --subprograms "
                              f"{m.sub_files.named()} (no file there has the program-number line O{p} or :{p})")
    m.load(path)


def _load_sub(m, pc, col, name):
    """LinuxCNC's ``o<name> call`` of a subroutine not in the program: ``DIR/name.ngc`` (SUBROUTINE_PATH's rule)."""
    plain = name[1:-1] if name.startswith("<") and name.endswith(">") else None
    if m.sub_files is None or plain is None:
        how = ("<name>.ngc in its SUBROUTINE_PATH): give that folder with --subprograms DIR" if plain is not None
               else "a named one in its SUBROUTINE_PATH): define it in the file")
        raise m._err(pc, col, f"o{name} call: the subroutine is not defined in this file (LinuxCNC looks for {how}")
    path = m.sub_files.linuxcnc(plain)
    if path is None:
        raise m._err(pc, col, f"o{name} call: not defined in this file and no {plain}.ngc in --subprograms "
                              f"{m.sub_files.named()}")
    lo = m.load(path)
    if name not in m.subs or m.subs[name][0] <= lo:
        raise m._err(pc, col, f"o{name} call: {path} does not define o{name} sub ... o{name} endsub (a subroutine "
                              "file holds its own subroutine)")


# ---------------------------------------------------------------------------- LinuxCNC G70-G72 contours
G7X = (70, 71, 71.1, 71.2, 72, 72.1, 72.2)
"""LinuxCNC's lathe cycles whose contour is a subroutine (:mod:`compensation.nc_g7x`)."""


def g7x_contour(m, pc, words, vals):
    """On a LinuxCNC ``G70``-``G72`` line with Q (``m`` the running ``nc_expand._Machine``): the lines of the
    subroutine o<Q> recorded (:attr:`compensation.nc_expand.Expanded.contours`) for the line about to be written,
    each a motion line with its values evaluated in a fresh call's parameters, up to the first ``endsub``. The cycle
    reads them as ``interp_g7x.cc`` does (``Interp::read``, which parses a line, never ``execute``): an O-word line
    (``repeat``, ``if``, ``while``, ``call`` …) is read and not run, so it is recorded as ``(line, None)``, a line
    without motion (a loop's body is read once, every branch of an if in turn; the summary names them). Refused: a
    subroutine line that sets a parameter, a Fanuc-style call or a program end (not read here)."""
    value = lambda w: w[4] if w[3] is None else vals[id(w)]  # noqa: E731
    if m.dialect != "linuxcnc" or not any(w[0] == "G" and round(value(w), 1) in G7X for w in words):
        return
    q = next((w for w in words if w[0] == "Q"), None)
    name = None if q is None else str(int(math.floor(value(q) + 0.5)))  # the interpreter's lround (Q > 0)
    span = m.subs.get(name)
    if span is None or span[0] > pc:  # LinuxCNC knows a subroutine once it has read its definition
        return  # the reader refuses the cycle: no contour
    lines, fr = [], _Frame(f"o{name}")
    for j in range(span[0], span[1] - 1):
        s = m.stmts[j]
        if s[0] == "o" and s[3] == "endsub":  # the reading ends at the first endsub, whichever
            break
        if s[0] == "o":  # read, not run: no motion (a loop's body is read once, both branches of an if)
            lines.append((m.named(j), None))
        elif s[0] == "plain" and not s[1]:
            lines.append((m.named(j), m.lines[j].rstrip("\r")))
        elif s[0] == "words" and not s[3] and s[4] is None and not s[5] and all(w[0] not in "@^" for w in s[2]):
            got = {id(w): evaluate(m, w[3], j, fr, True) for w in s[2] if w[3] is not None}
            lines.append((m.named(j), _spliced(m.lines[j].rstrip("\r"), m._cuts(j, s[2], (), got))))
        else:
            col = s[3][0][2] + 1 if s[0] == "words" and s[3] else s[5] if s[0] == "o" else None
            raise m._err(j, col, f"in o{name}, the contour of the G7x cycle on line {m.named(pc)}: the cycle reads its "
                                 "subroutine's lines without running them (LinuxCNC never sets the parameter); only "
                                 "motion and O-word lines are read there, not a parameter setting, a call or a "
                                 "program end")
    m.contours.append((len(m.out), tuple(lines)))


def _spliced(body: str, cuts: list) -> str:
    """``body`` with each span ``(start, end)`` of ``cuts`` replaced by its text."""
    out, at = [], 0
    for a, b, rep in sorted(cuts):
        out.append(body[at:a])
        out.append(rep)
        at = b
    return "".join(out) + body[at:]


# ---------------------------------------------------------------------------- LinuxCNC O-codes
def o_statement(m, pc, s, fr):
    _, label, name, kw, args, col = s
    if kw == "sub":
        if m.subs.get(name, (None,))[0] != pc + 1:
            raise m._err(pc, col, f"o{name} sub defined twice")
        return m.subs[name][1]
    if kw in ("endsub", "return"):
        if not m.calls:
            raise m._err(pc, col, f"o{name} {kw} outside a call")
        if args:
            m.gnamed["_value"] = evaluate(m, args[0], pc, fr)
        m.gnamed["_value_returned"] = 1.0 if args else 0.0
        raise _Return
    if kw == "call":
        if isinstance(name, tuple):  # o[expression] call: the subroutine numbered by its value
            v = evaluate(m, name[1], pc, fr)
            if v != int(v) or v < 0:
                raise m._err(pc, col, f"o[...] call: the O-number {v:g} is not a whole number ≥ 0")
            name = str(int(v))
        if name not in m.subs:
            _load_sub(m, pc, col, name)
        values = [evaluate(m, a, pc, fr) for a in args]
        if len(values) > 30:
            raise m._err(pc, col, f"o{name} call with {len(values)} arguments (at most 30)")
        _enter(m, pc, m.subs[name], _Frame(f"o{name}", local={k + 1: v for k, v in enumerate(values)}))
        return pc + 1
    if kw == "if":
        return pc + 1 if evaluate(m, args[0], pc, fr) != 0 else _next_branch(m, pc, name, col, fr)
    if kw in ("elseif", "else"):
        return _need(m, pc, name, ("endif",), col, kw) + 1
    if kw in ("endif", "do"):
        return pc + 1
    if kw == "while":
        prev = _prev(m, pc, name)
        if prev is not None and m.stmts[prev][3] == "do":
            return prev + 1 if evaluate(m, args[0], pc, fr) != 0 else pc + 1
        return pc + 1 if evaluate(m, args[0], pc, fr) != 0 else _need(m, pc, name, ("endwhile",), col, kw) + 1
    if kw == "endwhile":
        return _back(m, pc, name, "while", col)
    if kw == "repeat":
        v = evaluate(m, args[0], pc, fr)
        if v != int(v):
            raise m._err(pc, col, f"o{name} repeat [{v:g}]: not a whole count")
        end = _need(m, pc, name, ("endrepeat",), col, kw)
        if v <= 0:
            return end + 1
        fr.repeats[pc] = int(v)
        return pc + 1
    if kw == "endrepeat":
        r = _back(m, pc, name, "repeat", col)
        fr.repeats[r] = fr.repeats.get(r, 1) - 1
        if fr.repeats[r] > 0:
            return r + 1
        fr.repeats.pop(r, None)
        return pc + 1
    # break / continue
    end = _need(m, pc, name, ("endwhile", "endrepeat", "while"), col, kw)
    end_kw = m.stmts[end][3]
    if kw == "break":
        if end_kw == "endrepeat":
            fr.repeats.pop(_back(m, end, name, "repeat", col), None)
        return end + 1
    return end if end_kw in ("endrepeat", "while") else _back(m, end, name, "while", col)


def _next_branch(m, pc, name, col, fr):
    j = _need(m, pc, name, ("elseif", "else", "endif"), col, "if")
    s = m.stmts[j]
    if s[3] == "elseif":
        m._tick(j)
        return j + 1 if evaluate(m, s[4][0], j, fr) != 0 else _next_branch(m, j, name, s[5], fr)
    return j + 1


def _need(m, pc, name, keys, col, kw):
    j = m._find(pc, name, keys)
    if j is None:
        raise m._err(pc, col, f"o{name} {kw} without its o{name} {' / '.join(keys)}")
    return j


def _prev(m, pc, name):
    for j in range(pc - 1, -1, -1):
        s = m.stmts[j]
        if s[0] == "o" and s[2] == name and s[3] not in ("break", "continue"):
            return j
    return None


def _back(m, pc, name, kw, col):
    for j in range(pc - 1, -1, -1):
        s = m.stmts[j]
        if s[0] == "o" and s[2] == name and s[3] == kw:
            return j
    raise m._err(pc, col, f"o{name} end{kw} without its o{name} {kw}")
