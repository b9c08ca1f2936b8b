"""Kept lathe grooving cycles (``G74``/``G75``, :mod:`compensation.nc_groove`): each bottom held at the across
coordinate the control plunges at (:func:`hold_kept`) and the cycle line written with its compensated plunge word
(:func:`render_kept`)."""
from __future__ import annotations

import numpy as np

from .gcode_state import MM_PER_INCH
from .nc_expand import source_line
from .nc_groove import ACROSS, ACROSS_UM, _where


def hold_kept(res, tp, field, machine):
    """``res`` with each kept G74/G75's bottom (its one compensated point) at the across coordinate the control
    plunges at (the written end of the move before it: compensated, or as programmed where kept), its model
    residual and commands recomputed there; refused (InputError, naming ``--expand-cycles``) where that moves it
    more than :data:`ACROSS_UM` from its compensation or where the spindle does not turn. ``res.info["grooves"]``:
    per cycle line its error across (um)."""
    from errormap.io import InputError
    from .turning import nominal_by_tool, surface_residual_by_tool
    prog = tp.source.program
    events = [e for e in prog.events if e[2] == "lathe-groove"]
    if not events:
        return res
    comp = [m for m in prog.moves if m.compensate]
    row = dict(zip((m.index for m in comp), np.cumsum(tp.source.counts) - 1))
    moves = sorted(prog.moves, key=lambda m: m.index)
    out = []
    for idx, col, _, g, code in events:
        r = int(row[idx])
        ja = machine.axis_words.index(ACROSS[code])
        before = [m for m in moves if m.index < idx]
        at = res.axes[row[before[-1].index], ja] if before and before[-1].compensate else tp.axes[r, ja]
        across_um = float(abs(res.axes[r, ja] - at) * 1e3)
        where = _where(prog, tp.path, idx, col)
        if tp.turning is not None and not tp.turning[r]:
            raise InputError(f"{where}: '{code}' with the spindle stopped (C-axis mode): a grooving cycle is read "
                             "while the spindle turns")
        if across_um > ACROSS_UM:
            raise InputError(f"{where}: '{code}' kept: the control plunges at the {ACROSS[code]} it stands at, "
                             f"{across_um:.3g} um across from where compensation puts the bottom (more than "
                             f"{ACROSS_UM:g} um); use --expand-cycles (the cycle written as its moves, compensated "
                             "point by point)")
        res.axes[r, ja] = at
        txz = None if tp.tool_xz is None else np.asarray(tp.tool_xz)[[r]]
        mean, _ = surface_residual_by_tool(field, machine, res.axes[[r]], tp.axes[[r]], txz)
        res.residual_um[r] = [mean[0, 0], 0.0, mean[0, 1]]
        res.commands_mm[[r]] = nominal_by_tool(machine, res.axes[[r]], txz)
        out.append({"line": source_line(prog, idx + 1), "code": code, "across_um": across_um})
    res.info["grooves"] = out
    return res


def render_kept(program, vertices, header=(), held=None) -> str:
    """The program with its kept G74/G75 lines written with the compensated plunge word (G74's Z, G75's X) of their
    bottom's vertex, the across word (where given) at the across coordinate the control stands at; every other line
    as :func:`compensation.gcode.render_program` writes it."""
    from .gcode_words import DECIMALS
    from .gcode_write import _with_header, fmt, render_program
    from .nc_cycles import _substitute
    _, groups = render_program(program, vertices, held=held)
    comp = [m.index for m in program.moves if m.compensate]
    for idx, _, kind, g, code in program.events:
        if kind != "lathe-groove":
            continue
        q = np.asarray(vertices[comp.index(idx)], dtype=float).reshape(-1, len(program.axis_words.words))[-1]
        scale = MM_PER_INCH if g.inch else 1.0
        vals = {}
        for a in "XZ":
            if a in g.words:
                s = scale * (0.5 if a == "X" and g.diameter else 1.0)
                vals[a] = fmt(q[program.axis_words.words.index(a)] / s, DECIMALS["inch" if g.inch else "mm"])
        line = program.lines[idx]
        body = line.rstrip("\r\n")
        groups[idx] = [_substitute(body, vals) + line[len(body):]]
    return _with_header([ln for grp in groups for ln in grp], program.notes() + tuple(header))
