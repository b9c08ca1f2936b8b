"""LinuxCNC's modal-state save and restore (``M70``–``M73``) for the expander (:mod:`compensation.nc_expand`).

From LinuxCNC's G-code manual ("M70 Save Modal State" … "M73 Save and Autorestore Modal State"):

* ``M70`` saves the modal state at the current call level; ``M71`` invalidates it; ``M72`` restores it;
* ``M73`` saves it and restores it automatically when the subroutine returns (``endsub`` or ``return``).

The state saved (the manual's list): units ``G20/G21``, plane ``G17``–``G19.1``, cutter compensation
``G40``–``G42.1``, distance mode ``G90/G91``, arc distance mode ``G90.1/G91.1``, feed mode ``G93/G94/G95``, the
coordinate system ``G54``–``G59.3``, tool length compensation ``G43/G43.1/G49``, retract mode ``G98/G99``,
spindle mode ``G96/G97``, lathe diameter / radius mode ``G7/G8``, path control ``G61/G61.1/G64``, the feed ``F``
and speed ``S``, the spindle ``M3/M4/M5``, mist ``M7`` and flood ``M8`` (``M9`` off), and the override switches
``M48``–``M53``. The motion mode is not part of it.

The expander tracks these from the lines it writes; an ``M70``/``M73`` word is blanked (columns kept) and the
state recorded; a restore writes the words of every group whose value differs from the saved one, as lines
of ordinary G-code at the restoring line (units first, so that a restored ``F`` is read in its units): the
flat program then does what the controller does, and the reader reads it like any other line.

Refused (naming line and column): an ``M70``–``M73`` sharing its line with other words (the order the
controller applies them in decides the result), ``M72`` with nothing saved at its call level, a restore of a
group the program had not set before the save (the controller's start-up value, which the program does not
say), a restore that would change cutter compensation or a dynamic tool length (``G43.1``/``G43.2``:
their entry moves and values are not modal words), and a restore across a tool change while a tool length
offset is active.
"""
from __future__ import annotations

import re

_G_GROUPS = {
    "units": ("G20", "G21"), "plane": ("G17", "G18", "G19", "G17.1", "G18.1", "G19.1"),
    "cutter": ("G40", "G41", "G42", "G41.1", "G42.1"), "distance": ("G90", "G91"), "arc_distance": ("G90.1", "G91.1"),
    "feed_mode": ("G93", "G94", "G95"),
    "coordinate_system": ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"),
    "tool_length": ("G43", "G43.1", "G43.2", "G49"), "retract": ("G98", "G99"), "spindle_mode": ("G96", "G97"),
    "lathe_mode": ("G7", "G8"), "path_control": ("G61", "G61.1", "G64"),
}
"""Modal G groups M70 saves (LinuxCNC manual) and the codes of each."""
_WITH_WORDS = {"G43": "H", "G41": "D", "G42": "D", "G41.1": "DL", "G42.1": "DL", "G96": "D", "G64": "PQ", "M50": "P",
               "M51": "P", "M52": "P", "M53": "P"}
"""Codes whose value includes words of the same line (G43 H, G64 P Q, ...)."""
_M_GROUPS = {3: "spindle", 4: "spindle", 5: "spindle", 48: "overrides", 49: "overrides", 50: "feed_override",
             51: "speed_override", 52: "adaptive_feed", 53: "feed_hold"}
ORDER = ("units", "plane", "distance", "arc_distance", "feed_mode", "coordinate_system", "tool_length", "retract",
         "spindle_mode", "lathe_mode", "path_control", "cutter", "F", "S", "spindle", "mist", "flood", "overrides",
         "feed_override", "speed_override", "adaptive_feed", "feed_hold")
"""The order a restore writes the groups in (units before F)."""
_CODE_OF = {c: g for g, cs in _G_GROUPS.items() for c in cs}
_WORD = re.compile(r"([A-Za-z])[ \t]*([+-]?[ \t]*(?:\d[\d \t]*(?:\.[\d \t]*)?|\.[\d \t]*\d[\d \t]*))")
_M7X = re.compile(r"[mM][ \t]*0*(7[0-3])(?![\d.])")


def _blank_comments(body: str) -> str:
    out, depth = [], 0
    for ch in body:
        if ch == ";" and depth == 0:
            break
        if ch == "(":
            depth += 1
        out.append(" " if depth else ch)
        if ch == ")" and depth:
            depth -= 1
    return "".join(out).ljust(len(body))


def _words(code: str):
    """``[(letter, value text, value, start)]`` of a comment-blanked line."""
    out = []
    for m in _WORD.finditer(code):
        txt = re.sub(r"[ \t]", "", m.group(2))
        out.append((m.group(1).upper(), txt, float(txt), m.start()))
    return out


def _g_code(v: float) -> str:
    return f"G{v:.1f}".replace(".0", "") if round(v, 1) != round(v) else f"G{int(round(v))}"


class ModalTracker:
    """The modal state of the lines the expander writes, and the states M70/M73 saved per call level."""

    def __init__(self):
        self.now: dict = {}
        self.saved: dict = {}        # call level -> (state dict, autorestore)

    def line(self, m, i: int, text: str) -> str:
        """The line ``text`` (source line ``i``, 0-based) as the expander writes it: its M70–M73 words acted on
        and blanked; the modal words it sets recorded."""
        code = _blank_comments(text)
        hits = list(_M7X.finditer(code)) if m.given in ("linuxcnc", None) and m.dialect == "linuxcnc" else []
        if hits:
            h = hits[0]
            others = [w for w in _words(code) if w[3] != h.start() and w[0] != "N"]
            if others or len(hits) > 1:
                raise m._err(i, h.start() + 1, f"'M{h.group(1)}' (modal state save/restore) with other words on its "
                                               "line: the order the controller applies them in decides the result; "
                                               "write it on a line of its own")
            self._act(m, i, int(h.group(1)), h.start() + 1)
            return text[:h.start()] + " " * (h.end() - h.start()) + text[h.end():]
        self._observe(_words(code))
        return text

    def _observe(self, words) -> None:
        by = {w[0]: w for w in words}
        for letter, txt, v, _ in words:
            if letter == "G":
                code = _g_code(v)
                g = _CODE_OF.get(code)
                if g is not None:
                    extra = "".join(f" {c}{by[c][1]}" for c in _WITH_WORDS.get(code, "") if c in by)
                    self.now[g] = code + extra
            elif letter in "FS":
                self.now[letter] = f"{letter}{txt}"
            elif letter == "T":
                self.now["_selected"] = txt
            elif letter == "M" and v == int(v):
                n = int(v)
                if n in _M_GROUPS:
                    extra = "".join(f" {c}{by[c][1]}" for c in _WITH_WORDS.get(f"M{n}", "") if c in by)
                    self.now[_M_GROUPS[n]] = f"M{n}{extra}"
                elif n == 6:
                    self.now["_loaded"] = self.now.get("_selected")
                elif n in (7, 8):
                    self.now["mist" if n == 7 else "flood"] = f"M{n}"
                elif n == 9:
                    self.now["mist"] = self.now["flood"] = "M9"

    def _act(self, m, i, n, col) -> None:
        level = len(m.calls)
        if n in (70, 73):
            self.saved[level] = (dict(self.now), n == 73)
        elif n == 71:
            self.saved.pop(level, None)
        else:
            if level not in self.saved:
                raise m._err(i, col, "'M72' with no state saved by M70 at this call level (nothing to restore)")
            self.restore(m, i, self.saved[level][0], col)

    def leave(self, m, i: int) -> None:
        """A call made on source line ``i`` returns (``m.calls`` still holds it): an M73 state saved in it is
        restored at the call site, in the caller; a state M70 saved in it is dropped (it belongs to that level)."""
        state = self.saved.pop(len(m.calls), None)
        if state is not None and state[1]:
            calls, m.calls = m.calls, m.calls[:-1]
            try:
                self.restore(m, i, state[0], None)
            finally:
                m.calls = calls

    def restore(self, m, i: int, saved: dict, col) -> None:
        """Write the lines that put every differing group back to ``saved`` (module docstring)."""
        lines = []
        g43 = any((v or "").startswith("G43") for v in (saved.get("tool_length"), self.now.get("tool_length")))
        if g43 and saved.get("_loaded") != self.now.get("_loaded"):
            raise m._err(i, col, "restoring the modal state (M72/M73) after a tool change with a tool length offset "
                                 "active: which length the controller restores is not the program's to say; not "
                                 "expanded")
        for g in ORDER:
            was, now = saved.get(g), self.now.get(g)
            if was == now:
                continue
            name = g.replace("_", " ")
            if was is None:
                raise m._err(i, col, f"restoring the modal state (M72/M73) would set the {name} back to the controller's "
                                     f"start-up value, which the program did not set before saving: set it (now "
                                     f"'{now}') before M70/M73")
            if g == "cutter" or was.startswith(("G43.1", "G43.2")) or (now or "").startswith(("G43.1", "G43.2")):
                raise m._err(i, col, f"restoring the modal state (M72/M73) would change the {name} from '{now}' to "
                                     f"'{was}': not a modal word alone (an entry move or dynamic values); not expanded")
            if g in ("mist", "flood"):
                continue
            lines.append(was)
        if saved.get("mist") != self.now.get("mist") or saved.get("flood") != self.now.get("flood"):
            lines.append("M9")
            lines += [saved[g] for g in ("mist", "flood") if saved.get(g) in ("M7", "M8")]
        for text in lines:
            m._emit(i, text)  # observed as it is written (ModalTracker.line)
