"""A ``kind = "grinder"`` machine file read as its machine-tool chain.

The micro-drill flute grinder's file (``docs/reference/file-formats.md``: ``[geometry]`` l1…l8, R, theta1_deg;
``[strokes]`` x_mm, z_mm, a_deg; ``[targets]`` X, Z, A) names a fixed structure: two chains from
the machine base, written here once as a chain document whose fixed transforms are the file's
geometry names (no numbers)::

    work: Trans(l5,0,l6)·Trans(x,0,0)·E_x(x)·Trans(l7,0,l8)·E_oa·RotX(a)·E_a(a)
    tool: RotZ(θ1)·Trans(l2,0,l1)·RotZ(-θ1)·[Z along z, tilted towards +x by s_xz]·RotZ(θ1)·E_z(z)
          ·Trans(l3,0,l4)·Trans(0,0,-R)

:func:`grinder_to_chain` fills it with one grinder file's geometry, strokes and targets and compiles
it (:func:`errormap.machine_tool.parse_machine_tool`); the result keeps the grinder's 23 element names
(:data:`ELEMENT_SLOTS`, checked whole: an element or slot outside the table is refused) and its
axis columns x_mm, z_mm, a_deg, so element-set files and CSV files of the grinder read unchanged.
:func:`adapter_line` is the one line a command prints when it reads such a file.
"""
from __future__ import annotations

import numpy as np

from .machine import (GRINDER_GEOMETRY_KEYS, GRINDER_STROKE_KEYS, GRINDER_TARGET_KEYS, Grinder, MachineFileError,
                      parse_grinder)
from .machine_tool import MachineTool, parse_machine_tool

ELEMENT_SLOTS = (
    # grinder element, chain slot, ISO 230-1 name of the slot
    ("dx_x", "dx_x", "EXX"), ("dy_x", "dy_x", "EYX"), ("dz_x", "dz_x", "EZX"),
    ("ex_x", "ex_x", "EAX"), ("ey_x", "ey_x", "EBX"), ("ez_x", "ez_x", "ECX"),
    ("dx_z", "dx_z", "EXZ"), ("dy_z", "dy_z", "EYZ"), ("dz_z", "dz_z", "EZZ"),
    ("ex_z", "ex_z", "EAZ"), ("ey_z", "ey_z", "EBZ"), ("ez_z", "ez_z", "ECZ"),
    ("dx_a", "dx_a", "EXA"), ("dy_a", "dy_a", "EYA"), ("dz_a", "dz_a", "EZA"),
    ("ex_a", "ex_a", "EAA"), ("ey_a", "ey_a", "EBA"), ("ez_a", "ez_a", "ECA"),
    ("dy_oa", "dy_oa", "EY0A"), ("dz_oa", "dz_oa", "EZ0A"), ("ey_oa", "ey_oa", "EB0A"), ("ez_oa", "ez_oa", "EC0A"),
    ("s_xz", "s_xz", "EB0Z"),
)
"""The grinder's 23 elements (:data:`errormap.elements.ELEMENT_NAMES` order) and the chain slot each
one is, with the slot's ISO name: the whole mapping, both ways."""
SLOT_OF = {g: s for g, s, _ in ELEMENT_SLOTS}
ELEMENT_OF = {s: g for g, s, _ in ELEMENT_SLOTS}
COLUMN_OF = {"x_mm": "x_mm", "z_mm": "z_mm", "a_deg": "a_deg"}
"""Grinder axis column (CSV, element-set stations) -> the chain's axis column."""
AXIS_OF_COLUMN = {"x_mm": "X", "z_mm": "Z", "a_deg": "A"}


def _joint(axis: str, kind: str, stroke, **extra) -> dict:
    return {"joint": kind, "axis": axis, "stroke": [float(stroke[0]), float(stroke[1])], **extra}


def grinder_chain_document(machine: Grinder) -> dict:
    """The machine-tool chain document (the parsed TOML of a ``kind = "machine-tool"`` file) of a
    grinder file: the grinder's structure with that file's geometry, strokes and targets."""
    st = machine.strokes
    work = [{"tx": "l5"}, {"tz": "l6"}, _joint("X", "linear", st["x_mm"]),
            {"tx": "l7"}, {"tz": "l8"}, _joint("A", "rotary", st["a_deg"])]
    squareness = [{"name": "s_xz", "toward": "x", "iso": "EB0Z"}]
    tool = [{"rz": "theta1_deg"}, {"tx": "l2"}, {"tz": "l1"}, {"rz": "-theta1_deg"},
            _joint("Z", "linear", st["z_mm"], squareness=squareness), {"rz": "theta1_deg"}, {"errors_of": "Z"},
            {"tx": "l3"}, {"tz": "l4"}, {"tz": "-R"}]
    return {"machine": {"kind": "machine-tool", "schema": 1, "name": machine.name,
                        "description": 'read from a kind = "grinder" file'},
            "geometry": {k: float(getattr(machine, k)) for k in GRINDER_GEOMETRY_KEYS},
            "work": work, "tool": tool,
            "targets": {k: [[float(c) for c in row] for row in machine.targets[k]] for k in GRINDER_TARGET_KEYS}}


def grinder_to_chain(source, path="<grinder machine file>", sha: str = "") -> MachineTool:
    """The machine-tool chain of a grinder file: ``source`` a :class:`errormap.machine.Grinder` or a
    parsed ``kind = "grinder"`` TOML document (validated by :func:`errormap.machine.parse_grinder`,
    errors naming ``path`` and the key). Name, path and sha256 are the grinder file's; the element
    names and axis columns are checked against :data:`ELEMENT_SLOTS` / :data:`COLUMN_OF`."""
    if isinstance(source, dict):
        kind = source.get("machine", {}).get("kind") if isinstance(source.get("machine"), dict) else None
        if kind != "grinder":
            raise MachineFileError(f"{path}: key 'machine.kind': expected 'grinder' here, got {kind!r}")
        source = parse_grinder(source, path, sha)
    if not isinstance(source, Grinder):
        raise TypeError(f"expected a Grinder or a parsed grinder file, got {type(source).__name__}")
    where = source.path or path
    mt = parse_machine_tool(grinder_chain_document(source), where, source.sha256)
    check_grinder_chain(mt, where)
    return mt


def check_grinder_chain(mt: MachineTool, path) -> None:
    """Refuse a chain whose slots or axis columns are not exactly the grinder's (the mapping is total)."""
    want = tuple((s, iso) for _, s, iso in ELEMENT_SLOTS)
    got = tuple(zip(mt.slot_names, mt.iso_names))
    if got != want:
        extra = sorted(set(got) - set(want)) or sorted(set(want) - set(got)) or "(order)"
        raise MachineFileError(f"{path}: the chain's error slots are not the grinder's 23 elements: {extra}")
    if mt.axis_columns != tuple(COLUMN_OF[c] for c in GRINDER_STROKE_KEYS):
        raise MachineFileError(f"{path}: the chain's axis columns {mt.axis_columns} are not the grinder's "
                               f"{GRINDER_STROKE_KEYS}")


def rename(values: dict, mapping: dict, what: str) -> dict:
    """``values`` with every key renamed through ``mapping``; a key outside it is refused."""
    unmapped = sorted(set(values) - set(mapping))
    if unmapped:
        raise ValueError(f"{what}: no mapping for {unmapped} (the grinder's 23 elements and x_mm, z_mm, a_deg only)")
    return {mapping[k]: v for k, v in values.items()}


def adapter_line(machine: Grinder) -> str:
    """The one line a command says when it reads a grinder file as its chain."""
    return (f'{machine.path or "the built-in grinder"}: kind = "grinder" read as its machine-tool chain '
            "(axes X, Z, A; the same 23 element names and columns x_mm, z_mm, a_deg)")


def _grinder_key(machine) -> tuple:
    """Everything of a grinder file that its chain depends on, as a hashable key."""
    geo = tuple(float(getattr(machine, k)) for k in ("l1", "l2", "l3", "l4", "R", "l5", "l6", "l7", "l8", "theta1_deg"))
    strokes = tuple(sorted((k, tuple(map(float, v))) for k, v in machine.strokes.items()))
    targets = tuple(sorted((k, np.asarray(v, dtype=float).tobytes()) for k, v in machine.targets.items()))
    return (machine.name, machine.path, machine.sha256, geo, strokes, targets)


_GRINDER_CHAINS: dict = {}
GRINDER_CHAIN_CACHE = 32  # distinct grinder files kept compiled (a process uses one or two)


def machine_tool_of(machine) -> MachineTool:
    """``machine`` as a machine-tool chain: a :class:`MachineTool` itself, a grinder file's machine its
    chain (:func:`grinder_chain`)."""
    return machine if isinstance(machine, MachineTool) else grinder_chain(machine)


def grinder_chain(machine) -> MachineTool:
    """:func:`grinder_to_chain`, compiled once per grinder file's content
    (cached by its name, path, sha256, geometry, strokes and targets): the one source of the
    grinder's kinematics that :mod:`errormap.kinematics`, :mod:`errormap.htm` and
    :mod:`errormap.sweeps` evaluate."""
    key = _grinder_key(machine)
    mt = _GRINDER_CHAINS.get(key)
    if mt is None:
        if len(_GRINDER_CHAINS) >= GRINDER_CHAIN_CACHE:
            _GRINDER_CHAINS.pop(next(iter(_GRINDER_CHAINS)))
        mt = _GRINDER_CHAINS[key] = grinder_to_chain(machine)
    return mt
