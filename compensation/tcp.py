"""5-axis programs in tool-centre-point (TCP) mode, and inverse-time feed (``G93``), on machine-tool chains.

In TCP mode a program's ``X Y Z`` are the tool tip in the workpiece frame and its rotary words the axes'
positions. The words read by controller (each only in its dialect), how a TCP point is compensated (placed by
the chain's nominal inverse, :func:`tcp_axes`; written back in TCP form, :func:`tip_words`), ``G93`` feeds of
split blocks (:func:`inverse_time_lines`) and what is refused: docs/reference/tool-paths.md, "Five-axis
programs in tool-centre-point mode".
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from errormap.io import InputError

from .gcode_state import _Refuse
from .gcode_words import AXIS_LETTERS, tokenize

TCP_G = {"G43.4": ("fanuc", "siemens-iso"), "G43.5": ("fanuc", "siemens-iso"), "G234": ("haas",)}
"""TCP-on G codes and the dialects that read them (off: ``G49`` or a plain ``G43``)."""
TCP_M = {128: ("heidenhain-iso", "on"), 129: ("heidenhain-iso", "off")}
"""Heidenhain's TCPM M codes (ISO programs)."""
SIEMENS_LINE = re.compile(r"[ \t]*(?:N\d+[ \t]*)?(TRAORI(?:[ \t]*\([ \t]*1?[ \t]*\))?|TRAFOOF)[ \t]*(?:;.*)?\r?",
                          re.IGNORECASE)
SIEMENS_VECTOR = re.compile(r"(?<![A-Za-z0-9_])([ABC][2-7]|LEAD|TILT|THETA|PHI|PSI)[ \t]*=", re.IGNORECASE)
"""Siemens orientation programming (A3= B3= C3= direction vectors, A2= angles, A4–A7 surface normals, LEAD/TILT):
refused by name under the TCP pre-pass."""
SIEMENS_ORI_LINE = re.compile(r"[ \t]*(?:N\d+[ \t]*)?((?:ORI[A-Z0-9]+[ \t]*)+)(?:;.*)?\r?", re.IGNORECASE)
"""A Siemens line of orientation-interpolation words (G groups 25, 50-51: ``ORIAXES``, ``ORIVECT``, ``ORIWKS`` ...)."""
ORI_DEFAULT = "ORIVECT"
"""The Siemens control's initial setting of G group 51 (its programming manual's G-code table): the tool
orientation interpolated on a large circle, whatever words gave the block's end orientation."""
ORI_WORDS = {"ORIAXES": "ORIAXES", "ORIVECT": "ORIVECT", "ORIPLANE": "ORIVECT", "ORIWKS": None, "ORIMKS": None}
"""The orientation words read: the interpolation they select (``ORIPLANE`` is ``ORIVECT``); ``ORIWKS`` / ``ORIMKS``
(the frame a vector interpolation turns in) change nothing where the axes are interpolated (``ORIAXES``)."""
SIEMENS_OTHER = re.compile(r"[ \t]*(?:N\d+[ \t]*)?TRAORI\b", re.IGNORECASE)
TRIGGER = rb"(?i)G[ \t]*0*(?:43[ \t]*\.[ \t]*[45]|234|93)(?![0-9.])|M[ \t]*0*12[89](?![0-9.])|TRA(?:ORI|FOOF)"
"""Bytes that may hold a word of this module; a program without any is read without the pre-pass."""
INVERSE_TIME_DECIMALS = 6
"""Decimals of a rewritten inverse-time F (1e-6 per minute: a block's time is kept to < 1e-6 relative)."""
INVERSE_TOL_MM = 1e-10
"""The nominal inverse's tip tolerance (it is affine in the linear axes on an XYZ + rotary chain)."""


@dataclass
class TcpProgram:
    """What the TCP pre-pass found in a program. ``on`` (L,) bool per source line: TCP active for a move
    there; ``inverse_time`` (L,) bool: G93 active; ``switch`` (L,) the (line, column, word) that switched
    TCP on for each line (None off); ``words`` the TCP words seen; ``tool_events`` the tool calls recorded
    for the reader (Heidenhain ``T``, Siemens ``D1``); ``lines`` the original lines (written back)."""

    on: np.ndarray
    inverse_time: np.ndarray
    switch: list
    words: list
    tool_events: list
    lines: list
    _machines: dict = field(default_factory=dict, repr=False)
    machine_tool_points: int = 0
    """TCP points placed at the machine file's own tool point (``G49`` under a ``[tcp]`` switch whose file says
    ``tool_length_under_g49 = "machine"``), recorded by :func:`tcp_axes` for the summary."""
    off_at_end: list = field(default_factory=list)
    """0-based lines whose TCP-off word acts at the end of the block (Heidenhain ``M129``): written on the last
    piece of a split move (:func:`render_tcp`)."""
    first_line: int | None = None
    """The 0-based line of the first word the pre-pass read (a refusal's line where no switch or G93 names one)."""

    def active(self, lines0) -> np.ndarray:
        return self.on[np.asarray(lines0, dtype=np.int64)]

    def machine_at(self, machine, length_mm):
        """The machine with its tool at ``length_mm`` (built once per length); None or NaN: the machine file's
        own tool (``machine`` itself)."""
        from .nc_state import machine_with_tool
        if length_mm is None or not np.isfinite(length_mm):
            return machine
        key = float(length_mm)
        if key not in self._machines:
            self._machines[key] = machine_with_tool(machine, key)
        return self._machines[key]

    def place(self, machine, program, frames, lines0, q_prog, count: bool = True) -> np.ndarray:
        """Machine axes (n, k) of program axes ``q_prog`` (n, k) on 0-based ``lines0`` (n,): TCP lines by
        :func:`tcp_axes`, the others by the work offset and tool length shift; ``count`` False: points the
        planner samples, not counted in :attr:`machine_tool_points`."""
        lines0 = np.asarray(lines0, dtype=np.int64)
        words = program.axis_words.words
        out = np.asarray(q_prog, dtype=float) + frames.shift(lines0, words)
        on = self.active(lines0)
        if on.any():
            off, tool = frames.at(lines0[on])
            out[on] = tcp_axes(self, machine, program, lines0[on], np.asarray(q_prog, float)[on], off, tool, count)
        return out

    def program_axes(self, machine, program, frames, lines0, axes, fallback) -> np.ndarray:
        """Program axes (n, k) to write for machine ``axes`` (n, k) on ``lines0``: TCP lines in TCP form
        (:func:`tip_words`), the others ``fallback`` (n, k)."""
        out = np.array(fallback, dtype=float)
        on = self.active(lines0)
        if on.any():
            off, tool = frames.at(np.asarray(lines0)[on])
            out[on] = tip_words(self, machine, axes[on], off, tool)
        return out


def _refuse(path, line0, col, msg):
    return InputError(f"{path}: line {line0 + 1}, column {col}: {msg}")


def _blank(body: str, start: int, end: int, keep: str = "") -> str:
    """``body`` with ``[start, end)`` replaced by ``keep`` padded with spaces (columns unchanged)."""
    return body[:start] + keep.ljust(end - start) + body[end:]


def _triggered(data: bytes, codes: str):
    """The first match of :data:`TRIGGER` (or of the machine's switch M ``codes``, a regex alternation) in
    ``data``, or None: matched case-sensitively in lower case (ASCII folding, as ``(?i)`` on bytes), which
    lets the regex engine skip to its literal prefixes (13 times faster on a 100 kB program)."""
    pattern = TRIGGER.removeprefix(b"(?i)").lower() + (rb"|" + codes.lower().encode() if codes else b"")
    return re.search(pattern, data.lower())


def tcp_prepass(path, data: bytes, dialect_name: str, machine):
    """Find TCP and G93 words in a program (module docstring): ``(bytes for the reader, TcpProgram)`` with
    each TCP / G93 word blanked in place (columns kept; the plain ``G43`` of a ``G43.4 Hn`` kept for the
    tool length), or ``(data, None)`` where the program has none. Refuses (InputError, file, line,
    column) what has no exact meaning."""
    from .gcode import split_lines
    if not prepass_applies(data, dialect_name, machine):
        return data, None  # the common case: no word of this module (the reader keeps its bulk speed)
    lines = split_lines(data.decode("latin-1"))
    rotary = [a for a in machine.axes if a.kind != "linear"]
    n = len(lines)
    on, g93, switch = np.zeros(n, bool), np.zeros(n, bool), [None] * n
    words, tool_events, out = [], [], []
    state = {"tcp": None, "g93": False, "tool": None, "t": None, "edge": False, "incremental": False,
             "ori": ORI_DEFAULT, "rot": {}}
    found, first = False, None
    for i, line in enumerate(lines):
        body = line.rstrip("\r\n")
        ending = line[len(body):]
        if dialect_name == "heidenhain-iso":
            framed = _heidenhain_block(body)
            found |= framed != body
            body = framed
        new, hit = _prepass_line(path, i, body, dialect_name, machine, rotary, state, words, tool_events)
        found |= hit
        first = i if hit and first is None else first
        out.append(line if new is None else new + ending)  # None: the reader refuses it with its own words
        on[i], g93[i], switch[i] = state["tcp"] is not None, state["g93"], state["tcp"]
        if state.pop("off_at_end", False):  # Heidenhain's M129 acts at the end of its block
            state["tcp"] = None
    if not found:
        return data, None
    return "".join(out).encode("latin-1"), TcpProgram(on, g93, switch, words, tool_events, lines,
                                                     off_at_end=state.get("off_lines", []), first_line=first)


def prepass_applies(data: bytes, dialect_name: str, machine) -> bool:
    """Whether ``data`` may hold a word of this module (:data:`TRIGGER`, the machine's TCP switch M codes, or a
    Heidenhain program): the pre-pass reads it line by line."""
    codes = "|".join(f"M0*{c}" for c in sorted(set((machine.tcp or {}).get("switch_on", ()))
                                                 | set((machine.tcp or {}).get("switch_off", ()))))
    return dialect_name == "heidenhain-iso" or _triggered(data, codes) is not None


def flat_prepass(path, data: bytes, dialect_name: str, machine, subprograms=None):
    """:func:`tcp_prepass` of a program that holds subprograms, macros or parameters: run on its flat program
    (:func:`compensation.nc_expand.expand_if_needed`, by the rules the reader would use), so a ``G93`` block
    written inside a call has its own line and F. Returns ``(expanded or None, bytes for the reader,
    TcpProgram or None)``; ``expanded`` None where the program is read as it is (then :func:`tcp_prepass` of
    ``data``). Refusals are named at the source line."""
    from . import nc_expand
    from .gcode_classify import ProgramState
    exp = None
    if dialect_name in nc_expand.DIALECTS and prepass_applies(data, dialect_name, machine) and \
            nc_expand.needs_expansion(data):
        try:
            exp = nc_expand.expand_if_needed(data, path, dialect_name, ProgramState, subprograms)
        except InputError:
            exp = None  # read as before: the reader's own expansion names the refusal
    if exp is None:
        return (None,) + tcp_prepass(path, data, dialect_name, machine)
    try:
        flat, pre = tcp_prepass(path, exp.text.encode("latin-1"), dialect_name, machine)
    except InputError as exc:
        raise exp.relocate(exc) from None
    if pre is None:
        return None, data, None  # nothing of this module once expanded: the program is read as usual
    if pre.on.any():
        i = int(np.flatnonzero(pre.on)[0])
        raise exp.relocate(_refuse(path, i, 1, "tool-centre-point control in a program whose subprograms, macros or "
                                               "parameters are expanded: not supported (post the 5-axis path flat)"))
    return exp, flat, pre


def _prepass_line(path, i, body, dialect_name, machine, rotary, state, words, tool_events):
    """One line of :func:`tcp_prepass`: ``(its text for the reader, None where it does not tokenise;
    whether it holds a word of this module)``, the state updated."""
    ori = SIEMENS_ORI_LINE.fullmatch(body)
    if ori is not None:
        return _orientation_words(path, i, body, ori, dialect_name, state), True
    m = SIEMENS_LINE.fullmatch(body)
    if m is None and SIEMENS_OTHER.match(body):
        raise _refuse(path, i, body.upper().index("TRAORI") + 1, "'TRAORI' with parameters (orientation "
                      "offsets, another transformation number): not interpretable exactly; write TRAORI or "
                      "TRAORI(1)")
    if m is not None:
        word = m.group(1).upper()
        _need_dialect(path, i, m.start(1) + 1, word, ("siemens-iso",), dialect_name)
        if word.startswith("TRAORI"):
            _switch_on(path, i, m.start(1) + 1, "TRAORI", rotary, machine, state, words)
            if state["t"] is None or not state["edge"]:
                raise _refuse(path, i, m.start(1) + 1, "'TRAORI' with no tool length: call the tool with T n "
                              "and its edge D1 before it (the length comes from --tool-table)")
        else:
            state["tcp"] = None
        return _blank(body, m.start(1), m.end(1)), True
    vec = SIEMENS_VECTOR.search(body.split(";")[0])
    if vec is not None:
        raise _refuse(path, i, vec.start(1) + 1, f"'{vec.group(1)}=' (Siemens tool orientation: a direction "
                      "vector or angle under TRAORI): the rotary positions are the controller's choice (two "
                      "solutions); post rotary words (A, C) instead")
    try:
        _, toks, _ = tokenize(body)
    except _Refuse:
        return None, False
    new, hit, codes = _line_words(path, i, body, toks, dialect_name, state, machine, rotary, words)
    new = _tool_calls(path, i, toks, new, dialect_name, state, tool_events)
    if state["g93"]:
        _check_inverse_time(path, i, toks, codes, state)
    if dialect_name == "siemens-iso":
        _check_orientation_interpolation(path, i, toks, codes, state, rotary)
    return new, hit


HEIDENHAIN_FRAME = re.compile(r"([ \t]*(?:N\d+[ \t]*)?)%[ \t]*\w+[ \t]+G7([01])[ \t]*\*[ \t]*\r?")
HEIDENHAIN_END = re.compile(r"\*[ \t]*\r?$")


def _heidenhain_block(body: str) -> str:
    """A Heidenhain DIN/ISO block as the reader reads it: the ``%NAME G71 *`` / ``%NAME G70 *`` framing lines
    as ``G21`` / ``G20`` (mm / inch), the ``*`` block end blanked (columns kept)."""
    m = HEIDENHAIN_FRAME.fullmatch(body)
    if m is not None:
        g = m.group(0).index("G7", len(m.group(1)))
        return " " * g + ("G21" if m.group(2) == "1" else "G20") + " " * (len(body) - g - 3)
    e = HEIDENHAIN_END.search(body.split(";")[0].split("(")[0])
    return body if e is None else _blank(body, e.start(), e.start() + 1)


def _line_words(path, i, body, toks, dialect_name, state, machine, rotary, words):
    """The TCP / G93 / tool-length words of one tokenised line: the state updated, the line returned with its
    TCP and G93 words blanked, whether it held one, and its G and M words by code (``(body, found, codes)``)."""
    found = False
    switch_on = set((machine.tcp or {}).get("switch_on", ()))
    switch_off = set((machine.tcp or {}).get("switch_off", ()))
    new = body
    codes = {w.code: w for w in toks if w.letter in "GM"}
    for code, w in codes.items():
        if code in ("G90", "G91"):
            state["incremental"] = code == "G91"
        if code in TCP_G:
            found = True
            _need_dialect(path, i, w.start + 1, code, TCP_G[code], dialect_name)
            h = next((t for t in toks if t.letter == "H"), None)
            if h is None and not (code == "G234" and state["tool"] is not None):
                raise _refuse(path, i, w.start + 1, f"'{code}' without H (the tool length): write '{code} Hn' "
                              "with the tool table's number n (--tool-table)")
            if code == "G43.5" and any(t.letter in "IJK" for t in toks):
                raise _refuse(path, i, w.start + 1, "'G43.5' with a tool-direction vector I J K: the rotary "
                              "positions are the controller's choice (two solutions); post rotary words (G43.4)")
            _switch_on(path, i, w.start + 1, code, rotary, machine, state, words)
            if h is not None:
                state["tool"] = int(h.value)
            new = _blank(new, w.start, w.num_end, "G43" if h is not None else "")
        elif code in ("G43", "G49"):
            h = next((t for t in toks if t.letter == "H"), None)
            state["tool"] = None if code == "G49" else int(h.value) if h is not None else state["tool"]
            if state["tcp"] is not None and state["tcp"][2] in TCP_G:
                state["tcp"] = None
        elif code in ("G93", "G94", "G95"):
            if code == "G93":
                found = True
                new = _blank(new, w.start, w.num_end)
            state["g93"] = code == "G93"
        elif w.letter == "M" and w.value == int(w.value):
            mv = int(w.value)
            if mv in switch_on or mv in switch_off:
                found = True
                if mv in switch_on:
                    _switch_on(path, i, w.start + 1, code, rotary, machine, state, words)
                else:
                    state["tcp"] = None
                new = _blank(new, w.start, w.num_end)
            elif mv in TCP_M:
                found = True
                _need_dialect(path, i, w.start + 1, code, (TCP_M[mv][0],), dialect_name)
                if TCP_M[mv][1] == "on":
                    if state["t"] is None:
                        raise _refuse(path, i, w.start + 1, "'M128' with no tool length: call the tool with "
                                      "T n before it (the length comes from --tool-table)")
                    _switch_on(path, i, w.start + 1, code, rotary, machine, state, words)
                    f = next((t for t in toks if t.letter == "F" and t.start > w.start), None)
                    if f is not None:  # the feed of M128's compensating movements, not the path's
                        new = _blank(new, f.start, f.num_end)
                elif state["tcp"] is not None:
                    state["off_at_end"] = True
                    state.setdefault("off_lines", []).append(i)
                new = _blank(new, w.start, w.num_end)
    return new, found, codes


def _orientation_words(path, i, body, match, dialect_name, state) -> str:
    """A line of Siemens orientation words: ``ORIAXES`` / ``ORIVECT`` recorded, the words blanked for the reader;
    the other interpolation types (cone, path-relative, second curve) refused by name."""
    col = match.start(1) + 1
    _need_dialect(path, i, col, match.group(1).split()[0].upper(), ("siemens-iso",), dialect_name)
    for w in re.finditer(r"ORI[A-Z0-9]+", match.group(1), re.IGNORECASE):
        word = w.group(0).upper()
        if word not in ORI_WORDS:
            raise _refuse(path, i, match.start(1) + w.start() + 1, f"'{word}' (Siemens orientation interpolation): "
                          "not interpretable exactly; write ORIAXES (the rotary axes interpolated linearly)")
        state["ori"] = ORI_WORDS[word] or state["ori"]
    return _blank(body, match.start(1), match.end(1))


def _check_orientation_interpolation(path, i, toks, codes, state, rotary):
    """Under TRAORI with large-circle interpolation (``ORIVECT``, the control's initial setting) a feed move that
    turns a rotary axis swings the tool on a large circle, not linearly in the axes as the compensated pieces
    are written: refused (file, line, column) naming ``ORIAXES``, which makes it exact."""
    motion = [c for c in codes if c in ("G0", "G1", "G2", "G3")]
    if motion:
        state["motion_ori"] = motion[-1]
    for t in toks:
        if t.letter not in {a.word for a in rotary}:
            continue
        prev = state["rot"].get(t.letter)
        turned = t.value != 0.0 if state["incremental"] else prev is None or t.value != prev
        state["rot"][t.letter] = None if state["incremental"] else t.value
        if (turned and state["tcp"] is not None and state["ori"] != "ORIAXES"
                and state.get("motion_ori") in ("G1", "G2", "G3")):
            raise _refuse(path, i, t.start + 1, f"'{t.letter}{t.text}' under TRAORI with {state['ori']} (the "
                          "control's default): the tool swings on a large circle, not linearly in the axes as "
                          "compensated pieces are written; write ORIAXES after TRAORI")


def _need_dialect(path, i, col, word, dialects, dialect_name):
    if dialect_name not in dialects:
        raise _refuse(path, i, col, f"'{word}' (tool-centre-point control) is a word of {', '.join(dialects)}; the "
                      f"program is read as {dialect_name}: name the controller with --dialect "
                      f"{dialects[0]}")


def _switch_on(path, i, col, word, rotary, machine, state, words):
    if not rotary:
        raise _refuse(path, i, col, f"'{word}': tool-centre-point control on the machine {machine.name!r}, which has "
                      "no rotary axis (TCP needs a rotary chain; use a 5-axis machine file)")
    state["tcp"] = (i, col, word)
    words.append(word)


def _tool_calls(path, i, toks, body, dialect_name, state, tool_events):
    """Heidenhain's ``T n`` call and Siemens' ``D1`` edge activate the tool's length: recorded as tool
    events (line, column, "tool", n, text) for the reader; Siemens' ``D`` word blanked (the reader takes D
    only with G41/G42)."""
    t = next((w for w in toks if w.letter == "T"), None)
    if dialect_name == "heidenhain-iso" and t is not None:
        if state["tcp"] is not None:
            raise _refuse(path, i, t.start + 1, f"'T{t.text}' tool call while M128 is active: reset M128 (M129) "
                          "before a tool call (Heidenhain)")
        state["t"] = int(t.value)
        tool_events.append((i, t.start + 1, "tool", int(t.value), f"T{int(t.value)}"))
    if dialect_name == "siemens-iso":
        if t is not None:
            state["t"], state["edge"] = int(t.value), False
        d = next((w for w in toks if w.letter == "D"), None)
        if d is not None and not any(w.letter == "G" and w.code in ("G41", "G42") for w in toks):
            if state["tcp"] is not None:
                raise _refuse(path, i, d.start + 1, f"'D{d.text}' while TRAORI is active: not supported")
            if d.value not in (0.0, 1.0):
                raise _refuse(path, i, d.start + 1, f"'D{d.text}': a cutting edge other than D1 (its length is not "
                              "in the tool table); write D1")
            if d.value == 1.0 and state["t"] is None:
                raise _refuse(path, i, d.start + 1, "'D1' before any T: the tool's length is not known")
            state["edge"] = d.value == 1.0
            value = state["t"] if state["edge"] else None
            tool_events.append((i, d.start + 1, "tool", value, f"T{value} D1" if value is not None else "D0"))
            body = _blank(body, d.start, d.num_end)
    if tool_events and tool_events[-1][0] == i and state["incremental"]:
        raise _refuse(path, i, tool_events[-1][1], f"'{tool_events[-1][4]}' tool call under G91: the tip's position "
                      "after a tool call is not determined by the program; program it with G90 (absolute)")
    return body


def _check_inverse_time(path, i, toks, codes, state):
    """Under G93 every feed move carries F (its time); a G0 needs none."""
    motion = [c for c in codes if c in ("G0", "G1", "G2", "G3")]
    if motion:
        state["motion"] = motion[-1]
    has_axes = any(t.letter in AXIS_LETTERS for t in toks)
    if has_axes and state.get("motion") in ("G1", "G2", "G3") and not any(t.letter == "F" for t in toks):
        first = next(t for t in toks if t.letter in AXIS_LETTERS)
        raise _refuse(path, i, first.start + 1, f"{state['motion']} under G93 (inverse time) without F: every feed "
                      "move needs its time (F = 1/minutes) on its line")


G93_RE = re.compile(r"G0*93(?![\d.])", re.IGNORECASE)


def _first_word(pre: TcpProgram) -> str:
    """``"line L, column C: 'WORD'"`` of the program's first TCP switch or ``G93`` (from the pre-pass); else
    ``"line L"`` of the first word it read (a TCP-off word alone, say)."""
    on = [k for k, sw in enumerate(pre.switch) if sw is not None]
    inv = np.flatnonzero(pre.inverse_time)
    if on and (not inv.size or on[0] <= inv[0]):
        i, col, word = pre.switch[on[0]]
        return f"line {i + 1}, column {col}: '{word}'"
    if inv.size:
        i = int(inv[0])
        m = G93_RE.search(pre.lines[i])
        return f"line {i + 1}" + (f", column {m.start() + 1}: '{m.group()}'" if m else "")
    return f"line {pre.first_line + 1}" if pre.first_line is not None else "the program"


def attach(prog, pre: TcpProgram, flat=None) -> None:
    """After the reader: the program's original lines back (its TCP / G93 words written as they were), the
    tool calls among its events, and the pre-pass kept on the program (``prog.tcp``). ``flat``: the expansion the
    pre-pass ran on (:func:`flat_prepass`; the program read is its flat text), recorded as the program's."""
    if prog.expanded is not None:
        raise InputError(f"{prog.path}: {_first_word(pre)}: tool-centre-point or G93 words in a program whose canned "
                         "cycles (or, with TCP, subprograms or macros) were expanded: not supported (post the 5-axis "
                         "path flat)")
    if flat is not None:
        prog.expanded = flat
        prog.g80_line = flat.named(flat.origin[prog.g80_line - 1][0]) if prog.g80_line else prog.g80_line
    try:
        check_mode_changes(prog, pre)
    except InputError as exc:  # on the flat lines: named at the source, as the reader's refusals
        raise (flat.relocate(exc) if flat is not None else exc) from None
    prog.lines = pre.lines
    prog.data = None
    if pre.tool_events:
        prog.events = tuple(sorted(tuple(prog.events) + tuple(pre.tool_events), key=lambda e: (e[0], e[1])))
    prog.tcp = pre


def check_mode_changes(prog, pre: TcpProgram) -> None:
    """The first move after TCP switched on or off starts where the other mode left the machine, which the
    program's coordinates do not say: it must give every axis absolutely and be a kept rapid (``G0`` under
    ``--rapids keep``: run as written); otherwise refused (file, line, column). So must the first move after a
    Heidenhain / Siemens tool call give Z absolutely (the tip's height changes with the tool's length); the call's
    line named as the source's (:func:`compensation.nc_expand.source_line`)."""
    from .nc_expand import source_line
    words = prog.axis_words.words
    prev = None
    for m in prog.moves:
        state = bool(pre.on[m.index])
        if prev is not None and state != prev:
            first = min((w for a, w in m.words.items() if a in words), key=lambda w: w.start)
            where = f"the first move after tool-centre-point control switched {'on' if state else 'off'}"
            missing = [a for a in words if a not in m.words]
            if missing or m.incremental:
                raise _refuse(prog.path, m.index, first.start + 1,
                              f"{where} gives {'no ' + ', '.join(missing) if missing else 'incremental words'}: "
                              "its position in the new mode is not the program's; give every axis absolutely")
            if m.compensate:
                raise _refuse(prog.path, m.index, first.start + 1,
                              f"{where} is compensated but starts where the other mode left the machine (its path "
                              "is not the program's): position with G0 first (kept under --rapids keep)")
        prev = state
    calls = sorted(e[0] for e in pre.tool_events)
    for line in calls:  # a tool call changes where the program's Z is: the next move gives Z absolutely
        m = next((m for m in prog.moves if m.index > line), None)
        if m is not None and ("Z" not in m.words or m.incremental) and "Z" in words:
            w = min((w for a, w in m.words.items() if a in words), key=lambda w: w.start)
            raise _refuse(prog.path, m.index, w.start + 1, "the first move after the tool call on line "
                          f"{source_line(prog, line + 1)} gives no absolute Z: the tip's height under the new tool "
                          "length is not the program's")


def tcp_axes(pre: TcpProgram, machine, program, lines0, q_prog, offset, tool_mm, count: bool = True) -> np.ndarray:
    """Machine axes (n, k) of TCP points: tip ``q_prog[:, linear] + offset`` (workpiece frame, mm), rotary
    axes as programmed, the linear axes by the chain's nominal inverse at the tool length ``tool_mm`` (n,).
    Refused (InputError naming the line and the switching word): no tool length, a rotary work offset, a
    tip the linear axes cannot reach."""
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    rot = [j for j, a in enumerate(machine.axes) if a.kind != "linear"]
    lines0 = np.asarray(lines0, dtype=np.int64)
    out = np.array(q_prog, dtype=float)

    def where(k):
        sw = pre.switch[int(lines0[k])]
        return f"{program.path}: line {int(lines0[k]) + 1}: under '{sw[2]}' (line {sw[0] + 1}, column {sw[1]})"

    unset = np.flatnonzero(~np.isfinite(tool_mm))
    bad = [k for k in unset if not machine_tool_under_g49(pre, machine, lines0[k])]
    if count:  # the largest set of points placed at once (the vertices), not the planner's samples
        pre.machine_tool_points = max(pre.machine_tool_points, len(unset) - len(bad))
    if bad:
        raise InputError(f"{where(bad[0])}: tool-centre-point control with no tool length active: give 'G43 Hn' "
                         "(or the dialect's tool call) and the tool in --tool-table")
    rbad = np.flatnonzero(np.any(np.abs(offset[:, rot]) > 0.0, axis=1)) if rot else np.zeros(0, int)
    if rbad.size:
        raise InputError(f"{where(rbad[0])}: a work offset on a rotary axis under tool-centre-point control (the "
                         "workpiece frame would turn by a controller-specific convention): give rotary offsets 0")
    out[:, lin] += offset[:, lin]
    words = tuple(machine.axes[j].word for j in lin)
    mid = 0.5 * (machine.stroke_lo + machine.stroke_hi)
    for length, idx in by_length(tool_mm):
        mt = pre.machine_at(machine, length)
        start = out[idx].copy()
        start[:, lin] = mid[lin]
        q, ok = mt.inverse(out[idx][:, lin], start, free=words, tol_mm=INVERSE_TOL_MM)
        if not ok.all():
            k = idx[np.argmin(ok)]
            raise InputError(f"{where(k)}: the tool tip is not reachable by the linear axes at these rotary positions")
        out[idx] = q
    return out


def machine_tool_under_g49(pre: TcpProgram, machine, line0) -> bool:
    """Whether a TCP line with no tool length offset active runs at the machine file's own tool point: its
    switch is one of the file's ``[tcp] switch_on`` codes and the file says ``tool_length_under_g49 =
    "machine"`` (LinuxCNC's switchable kinematics read a zero tool offset under ``G49``)."""
    sw = pre.switch[int(line0)]
    tcp = machine.tcp or {}
    return (sw is not None and tcp.get("tool_length_under_g49") == "machine" and sw[2][:1] == "M"
            and float(sw[2][1:]) in tcp.get("switch_on", ()))


def by_length(tool_mm):
    """``(length_mm or None, indices)`` per distinct tool length of ``tool_mm`` (n,); None: NaN (no tool length
    offset active: the machine file's own tool)."""
    t = np.asarray(tool_mm, dtype=float)
    for length in np.unique(t[np.isfinite(t)]):
        yield float(length), np.flatnonzero(t == length)
    nan = np.flatnonzero(~np.isfinite(t))
    if nan.size:
        yield None, nan


def tip_words(pre: TcpProgram, machine, axes, offset, tool_mm) -> np.ndarray:
    """The TCP-form program axes (n, k) of machine ``axes`` (n, k): the nominal tool tip at the tool length
    ``tool_mm`` (n,) minus the work offset, the rotary axes as they are."""
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    out = np.array(axes, dtype=float)
    for length, idx in by_length(tool_mm):
        out[np.ix_(idx, lin)] = pre.machine_at(machine, length).nominal(axes[idx]) - offset[np.ix_(idx, lin)]
    return out


# ---------------------------------------------------------------------------- inverse time


def inverse_time_lines(program, groups) -> list:
    """Output line groups with every split G93 feed move's F multiplied by its piece count (and written on
    every piece): ``groups[i]`` the output lines of source line ``i`` (:func:`compensation.gcode.render_program`)."""
    pre = program.tcp
    out = list(groups)
    for m in program.moves:
        if not (m.compensate and pre.inverse_time[m.index]) or m.kind == "rapid":
            continue
        g = out[m.index]
        if len(g) == 1:
            continue
        _, toks, _ = tokenize(program.lines[m.index].rstrip("\r\n"))
        f = next(t for t in toks if t.letter == "F")
        value = f"{f.value * len(g):.{INVERSE_TIME_DECIMALS}f}".rstrip("0").rstrip(".")
        first = g[0]  # its F found anew: the written axis words before it may be shorter than the source's
        hit = next(t for t in tokenize(first.rstrip("\r\n"))[1] if t.letter == "F")
        new = [first[:hit.num_start] + value + first[hit.num_end:]]
        for ln in g[1:]:
            body = ln.rstrip("\r\n")
            new.append(f"{body} F{value}{ln[len(body):]}")
        out[m.index] = new
    return out


END_OF_BLOCK_M = re.compile(r"[ \t]*M[ \t]*0*129(?![0-9.])", re.IGNORECASE)


def end_of_block_word_last(group: list) -> list:
    """The output lines of one split move with its end-of-block M word (``M129``: TCP off at the end of the
    block) moved from the first piece to the last, so TCP stays on over every piece."""
    if len(group) < 2:
        return group
    first = group[0]
    cut = min([k for k in (first.find("("), first.find(";")) if k >= 0] + [len(first)])
    m = END_OF_BLOCK_M.search(first[:cut])
    if m is None:
        return group
    last = group[-1].rstrip("\r\n")
    return ([first[:m.start()] + first[m.end():]] + list(group[1:-1])
            + [f"{last} {m.group(0).strip()}{group[-1][len(last):]}"])


def render_tcp(program, vertices, header=()) -> str:
    """:func:`compensation.gcode.render_program` of a program the pre-pass read: the G93 feeds of split moves
    rewritten (:func:`inverse_time_lines`); in a Heidenhain program every added block ends with ``*`` and the
    header lines are ``;`` comments after its ``%NAME G71 *`` line."""
    from .gcode import _comment_safe, _with_header, render_program
    _, groups = render_program(program, vertices)
    if program.tcp.inverse_time.any():
        groups = inverse_time_lines(program, groups)
    for i in program.tcp.off_at_end:
        groups[i] = end_of_block_word_last(groups[i])
    if program.dialect != "heidenhain-iso":
        return _with_header([ln for g in groups for ln in g], program.notes() + tuple(header))
    out = []
    for g in groups:
        out.append(g[0])
        for ln in g[1:]:
            body = ln.rstrip("\r\n")
            out.append(f"{body} *{ln[len(body):]}")
    head = [f"; {_comment_safe(h)}\n" for h in program.notes() + tuple(header)]
    return "".join(out[:1] + head + out[1:])


def report(pre: TcpProgram, points_on: np.ndarray, before_urad=None, after_urad=None, solved=None,
           partly=None) -> dict:
    """The summary's ``tcp`` entry (``pre`` None: a joint-mode program compensated with its orientation:
    ``points_on`` every point); ``solved`` / ``partly`` (n,) bool of ``--compensate-orientation``
    (:func:`compensation.tcp_orientation.solve_orientation`): the points whose tool axis was turned out, and those
    near a rotary singularity where it was turned out only in the other rotary axis's plane."""
    out = {"words": sorted(set(pre.words)) if pre else [], "points": int(points_on.sum()),
           "inverse_time_lines": int(pre.inverse_time.sum()) if pre else 0,
           "form": "TCP points written in TCP form: tool tip X Y Z in the workpiece frame (compensated), rotary "
                   "words as programmed (or as corrected with --compensate-orientation)"}
    if pre is not None and pre.machine_tool_points:
        out["tool"] = (f"{pre.machine_tool_points} TCP point(s) with no G43 active run at the machine file's own tool "
                       "point (its [tcp] tool_length_under_g49 = \"machine\": the control's kinematics use a zero "
                       "tool offset)")

    def st(v):
        return {"max_urad": float(v.max()), "rms_urad": float(np.sqrt(np.mean(v ** 2)))}
    if before_urad is not None:
        out["orientation"] = ("angle between the truth's tool axis and the programmed one (urad); without "
                              "--compensate-orientation the rotary axes are kept and leave it as it was")
        out["true_orientation"] = st(after_urad)
        out["true_orientation_uncompensated"] = st(before_urad)
    if solved is not None:
        partly = np.zeros_like(solved) if partly is None else partly
        out["orientation_solved_points"] = int(solved.sum())
        out["orientation_partly_points"] = int(partly.sum())
        out["orientation_kept_points"] = int((~solved & ~partly).sum())
        for name, mask in (("solved", solved), ("partly", partly)):
            if before_urad is not None and mask.any():
                out[f"true_orientation_{name}"] = st(after_urad[mask])
                out[f"true_orientation_{name}_uncompensated"] = st(before_urad[mask])
        if partly.any():
            out["orientation_partly"] = (
                "points near a rotary singularity (the tool axis along the last rotary axis: A = 0 on an A/C table): "
                "that axis turns the tool about itself, so the other rotary axis turns out the tilt in its own plane "
                "and that axis is held; the tilt toward the other axis's line is left (turning it out would need the "
                "held axis to swing by tens of degrees from point to point)")
    return out
