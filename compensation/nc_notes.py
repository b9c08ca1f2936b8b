"""The summary's notes that name a program's lines, all by one convention: :func:`compensation.nc_expand.source_line`
(an int for a program read as it is or written line for line; for one whose lines shift when it is expanded, the text
``'12 (expanded line 40, called from line 3)'``, ``'k of FILE'`` for a ``--subprograms`` file): the controller
state's (:func:`event_notes`: G53/G92/G52/probe lines, M codes, G43.1, G41.1/G42.1, moves before the position is
known) and the lathe cycles' (:class:`LineNote`, :func:`cycle_notes`: G70-G73, G74/G75, G76, G92 passes, the rapid
before a thread), written when the summary is, at the lines of the program written
(docs/reference/tool-paths.md, "Line numbers in the summary")."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .nc_expand import source_line, source_lines


def event_notes(program, events, dynamic, offsets_mm_deg: dict) -> dict:
    """The summary's notes from a program's ``events`` (in line order), every line named by
    :func:`compensation.nc_expand.source_line`: ``dynamic_tool_lengths_mm`` (G43.1; ``dynamic`` its
    ``(1-based line, text)``) and ``dynamic_cutter_radii_mm`` (G41.1/G42.1: D/2) where any, ``offsets_mm_deg`` (given:
    the work systems' offsets), ``g53_lines``, ``g92_lines`` (G92-G92.3), ``g52_lines``, ``probe_lines``
    (G38.2-G38.5, written as programmed), ``dialect_modes``, ``machine_m_codes`` and ``moves_before_position_known``
    (written as programmed: a first ``G0 Z5``)."""
    def named(kind):
        return source_lines(program, [e[0] + 1 for e in events if kind(e[2])])
    notes = {"dynamic_tool_lengths_mm": [f"line {source_line(program, k)}: {text}" for k, text in dynamic],
             "dynamic_cutter_radii_mm": [f"line {source_line(program, e[0] + 1)}: {e[3]:g}" for e in events
                                         if e[2] == "cutter-dynamic"]}
    notes = {k: v for k, v in notes.items() if v}
    notes["offsets_mm_deg"] = offsets_mm_deg
    notes.update({"g53_lines": named(lambda k: k == "g53"), "g92_lines": named(lambda k: k.startswith("g92")),
                  "g52_lines": named(lambda k: k == "g52"), "probe_lines": named(lambda k: k == "probe"),
                  "dialect_modes": sorted({e[3] for e in events if e[2] == "mode"}),
                  "machine_m_codes": [f"line {source_line(program, e[0] + 1)}: {e[4]}" for e in events
                                      if e[2] == "machine-m"]})
    t = getattr(program, "table", None)
    unknown = (t.line[~t.compensate & ~t.known.all(axis=1)] + 1 if t is not None else
               [m.index + 1 for m in program.moves if not m.compensate and not np.all(m.known)])
    notes["moves_before_position_known"] = source_lines(program, unknown)
    return notes


@dataclass(frozen=True)
class LineNote:
    """A lathe cycle's summary note (the text of its ``"lathe-cycle"`` event), its lines named when the summary is
    written (:meth:`text`): ``parts`` text (str) and lines of the program that holds the event, each a 1-based line
    (int) or a range ``(first, last)``; a step that writes cycles as moves carries it to the lines it writes
    (:meth:`moved`)."""

    parts: tuple

    def moved(self, to) -> LineNote:
        """The note with every line ``k`` as ``to(k)``, its line in the program written from this one."""
        return LineNote(tuple(p if isinstance(p, str) else (to(p[0]), to(p[1])) if isinstance(p, tuple) else to(p)
                              for p in self.parts))

    def text(self, program) -> str:
        """The note with its lines as :func:`compensation.nc_expand.source_line` names those of ``program``; a range
        ``'12-15'`` (both ints), else ``'A to B'``."""
        return "".join(p if isinstance(p, str) else line_span(*source_lines(program, p)) if isinstance(p, tuple) else
                       str(source_line(program, int(p))) for p in self.parts)


def note(*parts) -> LineNote:
    """A :class:`LineNote` of ``parts`` (text, 1-based lines, ``(first, last)`` ranges)."""
    return LineNote(tuple(parts))


def line_span(a, b) -> str:
    """Lines ``a`` to ``b`` as named (:func:`compensation.nc_expand.source_line`): ``'12-15'`` (ints), else
    ``'A to B'``."""
    return f"{a}-{b}" if isinstance(a, int) and isinstance(b, int) else f"{a} to {b}"


def cycle_notes(program) -> list:
    """The summary's line per lathe cycle of ``program`` (its ``"lathe-cycle"`` events' :class:`LineNote`, in line
    order: roughing, the controller's passes from the compensated contour; finishing, exactly the compensated
    contour; cycles written as moves; the rapid before a thread made compensated)."""
    return [e[4].text(program) for e in program.events if e[2] == "lathe-cycle"]
