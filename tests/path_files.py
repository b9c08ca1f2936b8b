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


def read_as_compensate(path, machine, **settings):
    """The tool path as ``compensate`` reads it (settings: :class:`CompensateSettings` fields)."""
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    return read_tool_path(path, machine, CompensateSettings("exact", "", Path("."), **settings))


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
