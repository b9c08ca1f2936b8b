"""A ``kind = "grinder"`` machine file read as its machine-tool chain: the one adapter.

The built-in grinder is a chain file (``errormap/machines/grinder.toml``). A user's older ``kind = "grinder"``
file (``[geometry]`` l1…l8, R, theta1_deg; ``[strokes]``; ``[targets]``; ``docs/reference/file-formats.md``)
names the same two chains (``docs/explanation/kinematics.md``). :func:`parse_grinder_file` validates it, fills
the chain document with its geometry, strokes and targets and compiles it
(:func:`errormap.machine_tool.parse_machine_tool`), keeping the 23 element names (:data:`ELEMENT_SLOTS`) and
the axis columns x_mm, z_mm, a_deg, so the grinder's files read unchanged; ``read_as`` carries
:func:`adapter_line`, the one line a command says when it reads such a file."""
from __future__ import annotations

import dataclasses

import numpy as np

from .machine_checks import MachineFileError, check_array, check_known_keys, check_number, check_table, short_repr
from .machine_tool import MachineTool, parse_machine_tool

GRINDER_GEOMETRY_KEYS = ("l1", "l2", "l3", "l4", "R", "l5", "l6", "l7", "l8", "theta1_deg")
GRINDER_STROKE_KEYS = ("x_mm", "z_mm", "a_deg")
GRINDER_TARGET_KEYS = ("X", "Z", "A")
A_TURN_TOL_DEG = 1e-9  # strokes.a_deg must span one turn to this

ELEMENT_SLOTS = (
    # the grinder's element (= the chain's slot) and its ISO 230-1 name
    ("dx_x", "EXX"), ("dy_x", "EYX"), ("dz_x", "EZX"), ("ex_x", "EAX"), ("ey_x", "EBX"), ("ez_x", "ECX"),
    ("dx_z", "EXZ"), ("dy_z", "EYZ"), ("dz_z", "EZZ"), ("ex_z", "EAZ"), ("ey_z", "EBZ"), ("ez_z", "ECZ"),
    ("dx_a", "EXA"), ("dy_a", "EYA"), ("dz_a", "EZA"), ("ex_a", "EAA"), ("ey_a", "EBA"), ("ez_a", "ECA"),
    ("dy_oa", "EY0A"), ("dz_oa", "EZ0A"), ("ey_oa", "EB0A"), ("ez_oa", "EC0A"), ("s_xz", "EB0Z"),
)
"""The grinder's 23 elements (:data:`errormap.elements.ELEMENT_NAMES` order), each the chain slot of the
same name, with the slot's ISO name: the whole mapping."""


def _joint(axis: str, kind: str, stroke, **extra) -> dict:
    return {"joint": kind, "axis": axis, "stroke": [float(stroke[0]), float(stroke[1])], **extra}


def read_grinder(doc: dict, path) -> dict:
    """Validate a parsed ``kind = "grinder"`` file (schema in ``docs/reference/file-formats.md``):
    ``{"name", "geometry" {key: float}, "strokes" {column: (lo, hi)}, "targets" {word: (3, 3)}}``;
    errors name the file and the key."""
    check_known_keys(doc, ("machine", "geometry", "strokes", "targets"), "", path)
    m = check_table(doc, "machine", path)
    check_known_keys(m, ("kind", "name"), "machine", path)
    name = m.get("name", "grinder")
    if not isinstance(name, str):
        raise MachineFileError(f"{path}: key 'machine.name': expected a string, got {short_repr(name)}")
    g = check_table(doc, "geometry", path)
    check_known_keys(g, GRINDER_GEOMETRY_KEYS, "geometry", path)
    geom = {k: check_number(g, k, "geometry", path) for k in GRINDER_GEOMETRY_KEYS}
    if geom["R"] <= 0:
        raise MachineFileError(f"{path}: key 'geometry.R': expected a positive wheel radius, got {geom['R']}")
    s = check_table(doc, "strokes", path)
    check_known_keys(s, GRINDER_STROKE_KEYS, "strokes", path)
    strokes = {}
    for k in GRINDER_STROKE_KEYS:
        if k not in s:
            raise MachineFileError(f"{path}: missing key 'strokes.{k}'")
        arr = check_array(s[k], (2,), f"strokes.{k}", path)
        if not arr[1] > arr[0]:
            raise MachineFileError(f"{path}: key 'strokes.{k}': expected [lo, hi] with hi > lo, got {s[k]!r}")
        strokes[k] = (float(arr[0]), float(arr[1]))
    lo, hi = strokes["a_deg"]
    if abs((hi - lo) - 360.0) > A_TURN_TOL_DEG:
        hint = " (that is one turn in radians; the file is in degrees)" if abs((hi - lo) - 2 * np.pi) < 0.01 else ""
        raise MachineFileError(f"{path}: key 'strokes.a_deg': expected one turn, [lo, lo + 360] deg (the A-axis "
                               f"errors are periodic over a turn; commands may run past it), got {s['a_deg']!r}{hint}")
    t = check_table(doc, "targets", path)
    check_known_keys(t, GRINDER_TARGET_KEYS, "targets", path)
    targets = {}
    for k in GRINDER_TARGET_KEYS:
        if k not in t:
            raise MachineFileError(f"{path}: missing key 'targets.{k}'")
        targets[k] = check_array(t[k], (3, 3), f"targets.{k}", path)
    return {"name": name, "geometry": geom, "strokes": strokes, "targets": targets}


def grinder_chain_document(grinder: dict) -> dict:
    """The machine-tool chain document (the parsed TOML of a ``kind = "machine-tool"`` file) of a grinder
    file read by :func:`read_grinder`: the grinder's structure with that file's geometry, strokes, targets."""
    st = grinder["strokes"]
    work = [{"tx": "l5"}, {"tz": "l6"}, _joint("X", "linear", st["x_mm"]),
            {"tx": "l7"}, {"tz": "l8"}, _joint("A", "rotary", st["a_deg"])]
    squareness = [{"name": "s_xz", "toward": "x", "iso": "EB0Z"}]
    tool = [{"rz": "theta1_deg"}, {"tx": "l2"}, {"tz": "l1"}, {"rz": "-theta1_deg"},
            _joint("Z", "linear", st["z_mm"], squareness=squareness), {"rz": "theta1_deg"}, {"errors_of": "Z"},
            {"tx": "l3"}, {"tz": "l4"}, {"tz": "-R"}]
    return {"machine": {"kind": "machine-tool", "schema": 1, "name": grinder["name"],
                        "description": 'read from a kind = "grinder" file'},
            "geometry": {k: float(v) for k, v in grinder["geometry"].items()},
            "work": work, "tool": tool,
            "targets": {k: [[float(c) for c in row] for row in v] for k, v in grinder["targets"].items()},
            "truth": builtin_truth()}


def builtin_truth() -> dict:
    """The built-in grinder's ``[truth]`` table: a grinder file's seeded truths are drawn as the
    built-in's."""
    import tomllib
    from pathlib import Path
    with open(Path(__file__).parent / "machines" / "grinder.toml", "rb") as fh:
        return tomllib.load(fh).get("truth", {})


def parse_grinder_file(doc: dict, path, sha: str = "") -> MachineTool:
    """The machine-tool chain of a parsed ``kind = "grinder"`` file (the registry's parser of that kind):
    name, path and sha256 are the grinder file's, ``read_as`` its :func:`adapter_line`; the element names
    and axis columns are checked against :data:`ELEMENT_SLOTS` / :data:`GRINDER_STROKE_KEYS`."""
    kind = doc.get("machine", {}).get("kind") if isinstance(doc.get("machine"), dict) else None
    if kind != "grinder":
        raise MachineFileError(f"{path}: key 'machine.kind': expected 'grinder' here, got {short_repr(kind)}")
    mt = parse_machine_tool(grinder_chain_document(read_grinder(doc, path)), path, sha)
    check_grinder_chain(mt, path)
    return dataclasses.replace(mt, read_as=adapter_line(path))


def is_grinder_chain(mt) -> bool:
    """True for a machine-tool chain whose slots (with their ISO names) and axis columns are exactly the
    grinder's (:data:`ELEMENT_SLOTS`; x_mm, z_mm, a_deg): the built-in grinder, a grinder file read by
    :func:`parse_grinder_file`, or a chain file written with the same structure."""
    return (isinstance(mt, MachineTool) and tuple(zip(mt.slot_names, mt.iso_names)) == ELEMENT_SLOTS
            and mt.axis_columns == GRINDER_STROKE_KEYS)


def rho0_mm(mt) -> float | None:
    """The grinder's tool-point radius about its A axis at z = 0, ``l1 + l4 - R - l6 - l8`` mm, from the
    chain's geometry; None for a machine that is not the grinder's chain."""
    if not is_grinder_chain(mt):
        return None
    g = mt.geometry
    return g["l1"] + g["l4"] - g["R"] - g["l6"] - g["l8"]


def check_grinder_chain(mt: MachineTool, path) -> None:
    """Refuse a chain whose slots or axis columns are not exactly the grinder's (the mapping is total)."""
    got = tuple(zip(mt.slot_names, mt.iso_names))
    if got != ELEMENT_SLOTS:
        extra = sorted(set(got) - set(ELEMENT_SLOTS)) or sorted(set(ELEMENT_SLOTS) - set(got)) or "(order)"
        raise MachineFileError(f"{path}: the chain's error slots are not the grinder's 23 elements: {extra}")
    if mt.axis_columns != GRINDER_STROKE_KEYS:
        raise MachineFileError(f"{path}: the chain's axis columns {mt.axis_columns} are not the grinder's "
                               f"{GRINDER_STROKE_KEYS}")


def adapter_line(path) -> str:
    """The one line a command says when it reads a grinder file as its chain."""
    return (f'{path}: kind = "grinder" read as its machine-tool chain '
            "(axes X, Z, A; the same 23 element names and columns x_mm, z_mm, a_deg)")
