"""Tool-path files for tests: a WCS-target CSV written from an array, and a compensated output written the way
``volcomp compensate`` writes it (its reader, renderer and set writer)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from compensation.pathio import TARGET_COLUMNS, compensated_sidecar
from errormap.io import write_csv


def write_targets_csv(path, targets_mm, comments=()) -> Path:
    """Write WCS targets (n, 3) mm as a ``px_mm, py_mm, pz_mm`` CSV, atomically."""
    t = np.asarray(targets_mm, dtype=float)
    return write_csv(path, dict(zip(TARGET_COLUMNS, t.T)), header_comments=comments, float_fmt="%.9f")


def read_as_compensate(path, machine, field_=None, **settings):
    """The tool path as ``compensate`` reads it (settings: :class:`CompensateSettings` fields; ``field_``: the
    error field that splits G-code moves with ``max_segment_mm="auto"``, the default; without one no move is
    split)."""
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    return read_tool_path(path, machine, CompensateSettings("exact", "", Path("."), **settings), field_)


def render_gcode(tp, axes, header=(), machine=None) -> tuple:
    """``(text, groups)`` of a G-code tool path with its vertices at ``axes`` (n, k) machine axes: the text
    ``compensate`` writes (the program's axes: minus its work offset and tool length; ``machine`` for a program
    in TCP mode), and ``groups[i]`` the output lines of source line i (:func:`compensation.gcode.render_program`,
    which writes the same text)."""
    from compensation.app.workflows.compensate_paths import program_axes
    from compensation.chain_gcode import render_chain_axes
    from compensation.gcode import render_program
    job = tp.source
    axes = program_axes(tp, np.array(axes, dtype=float), machine)[:, list(tp.columns)]
    text = render_chain_axes(job.program, axes, job.counts, header=header)
    groups = render_program(job.program, np.split(axes, np.cumsum(job.counts)[:-1]), header=header)[1]
    return text, groups


def outcome(tp, dst, machine, axes, commands_mm=None, comments=()):
    """One file's accepted outcome as ``compensate`` renders it: ``axes`` (n, k) the compensated machine axes,
    ``commands_mm`` (n, 3) a WCS-target CSV's compensated commands."""
    from compensation.app.workflows.compensate import FileOutcome
    from compensation.app.workflows.compensate_paths import render
    meta = None if tp.kind == "gcode" else compensated_sidecar(tp.source, dst, comments)
    return FileOutcome(tp.path, Path(dst), tp, {}, render(tp, np.asarray(axes, float), commands_mm, machine,
                                                          comments), meta)


def write_compensated(tp, dst, machine, axes, commands_mm=None, comments=()) -> Path:
    """Write one compensated file through ``compensate``'s set writer; its path."""
    from compensation.app.workflows.compensate import write_outputs
    write_outputs([outcome(tp, dst, machine, axes, commands_mm, comments)])
    return Path(dst)
