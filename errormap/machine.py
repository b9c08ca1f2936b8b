"""Machine files (TOML): loading and validation.

``[machine] kind`` selects the schema; :func:`machine_kinds` is the one registry of kinds (each kind's parser
and axes; schemas in ``docs/reference/file-formats.md``). The built-in machines are the files in
``errormap/machines/`` (:func:`builtin_machines`); the default grinder is a machine-tool chain there, and a
``kind = "grinder"`` file is read into the same chain (:mod:`errormap.grinder_file`). Every error names the
file and the key."""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from .io import InputError, check_not_wide, read_document_bytes, sha256_bytes
# MachineFileError is raised here and imported from here by callers (one class, defined with the checks)
from .machine_checks import MachineFileError, short_repr

BUILTIN_ALIASES = {"grinder-chain": "grinder"}
"""Other names of a built-in machine file (the grinder's chain file was once a file of its own)."""


def builtin_machine_path(kind: str = "grinder") -> Path:
    """Path of a built-in machine file (``grinder``, the default, a machine-tool chain also named
    ``grinder-chain``; ``mill-xyz``, ``mill-xyza``, ``hmc-xyzb``, ``five-axis-ac``, ``five-axis-bc``, ``lathe-xzc``; ``hexapod``, ``tripod``; ``ur5``,
    ``ur10``, ``wam``)."""
    p = Path(str(resources.files("errormap") / "machines" / f"{BUILTIN_ALIASES.get(kind, kind)}.toml"))
    if not p.is_file():
        raise MachineFileError(f"no built-in machine file for kind {kind!r} ({p})")
    return p


# -- the machine-kind registry --------------------------------------------------------------------
@dataclass(frozen=True)
class MachineAxis:
    """One commanded axis of a machine as its file states it: ``name`` (the axis word or joint/leg
    name), ``type`` (``linear`` or ``rotary``), ``unit`` (``mm`` or ``deg``) and its stroke or
    limits ``lo``, ``hi`` in that unit."""

    name: str
    type: str
    unit: str
    lo: float
    hi: float

    def to_dict(self) -> dict:
        return {"name": self.name, "type": self.type, "unit": self.unit, "lo": self.lo, "hi": self.hi}


@dataclass(frozen=True)
class MachineKind:
    """One ``[machine] kind``: its parser ``parse(doc, path, sha) -> machine`` (a frozen dataclass),
    ``axes(machine) -> [MachineAxis]`` (what ``volcomp machines`` lists) and the page documenting
    its schema."""

    kind: str
    parse: object
    axes: object
    schema_doc: str


def chain_axes(machine) -> list:
    """The joints of a serial chain with their limits (revolute: deg, prismatic: mm)."""
    return [MachineAxis(j.name, "rotary" if j.type == "revolute" else "linear",
                        "deg" if j.type == "revolute" else "mm", float(j.lo), float(j.hi)) for j in machine.joints]


def machine_tool_axes(machine) -> list:
    """The axes of a machine-tool chain with their strokes (linear: mm, rotary: deg)."""
    return [MachineAxis(a.word, a.kind, a.unit, float(a.stroke[0]), float(a.stroke[1])) for a in machine.axes]


def pkm_axes(machine) -> list:
    """The legs of a parallel kinematic machine with their length limits (mm)."""
    return [MachineAxis(f"leg{i + 1}", "linear", "mm", float(lo), float(hi))
            for i, (lo, hi) in enumerate(zip(machine.leg_min_mm, machine.leg_max_mm))]


def machine_kinds() -> dict:
    """The machine-kind registry: ``{kind: MachineKind}``. The PKM and serial-chain schemas live with
    their models (imported on first use: they need scipy, which a grinder-only run does not load).
    A new kind is one entry here (its parser and its axes)."""
    from .chain_file import parse_serial
    from .grinder_file import parse_grinder_file
    from .machine_tool import parse_machine_tool
    from .pkm.machine_file import parse_hexapod, parse_tripod
    return {k.kind: k for k in (
        MachineKind("grinder", parse_grinder_file, machine_tool_axes, "docs/reference/file-formats.md"),
        MachineKind("hexapod", parse_hexapod, pkm_axes, "docs/explanation/parallel-kinematics.md"),
        MachineKind("tripod", parse_tripod, pkm_axes, "docs/explanation/parallel-kinematics.md"),
        MachineKind("serial", parse_serial, chain_axes, "docs/explanation/serial-arms.md"),
        MachineKind("machine-tool", parse_machine_tool, machine_tool_axes, "docs/how-to/machine-file.md"),
    )}


def _parsers():
    """The parser of each ``[machine] kind``, from :func:`machine_kinds`."""
    return {k: v.parse for k, v in machine_kinds().items()}


def machine_kind(kind: str) -> MachineKind:
    """The registry entry of ``kind``; ``ValueError`` naming the known kinds otherwise."""
    kinds = machine_kinds()
    if kind not in kinds:
        raise ValueError(f"unknown machine kind {kind!r}; expected one of {sorted(kinds)}")
    return kinds[kind]


def machine_axes(machine) -> list:
    """The commanded axes of a loaded machine (:class:`MachineAxis` list), by its kind's entry."""
    return machine_kind(machine.kind).axes(machine)


def builtin_machines() -> dict:
    """``{name: path}`` of the built-in machine files, ``errormap/machines/<name>.toml``, sorted by
    name: a built-in machine is a file there, nothing else."""
    folder = Path(str(resources.files("errormap") / "machines"))
    return {p.stem: p for p in sorted(folder.glob("*.toml"))}


FORMER_SHA256 = {"grinder": ("79f2a794bd5774bc9bf7a052890bc36a5736f3deddd4c13eddc871b2ae73ba1a",
                             "4af8f4937f34b9a9780b1fce365864b3bde34c78846494a40419e63f51bec277")}
"""SHA-256 of earlier files of a built-in machine (the grinder's ``kind = "grinder"`` file before it became
its chain file, and its chain file before its ``[truth]`` table): a model or data file recorded with one of
them was made on that built-in machine."""


def made_on(machine, sha: str | None) -> bool:
    """True when a file's recorded machine ``sha`` names ``machine``'s file: its own sha256, or, for a built-in
    machine, an earlier file of it (:data:`FORMER_SHA256`)."""
    if sha == machine.sha256:
        return True
    name = next((k for k, p in builtin_machines().items() if str(p) == str(machine.path)), None)
    return sha in FORMER_SHA256.get(name, ())


def builtin_named(name: str):
    """The built-in machine file of ``name`` (a file's stem or an alias, :data:`BUILTIN_ALIASES`), or None."""
    return builtin_machines().get(BUILTIN_ALIASES.get(name, name))


def load_machine(path=None, expect_kind: str | None = None):
    """Load and validate a machine file; ``None`` gives the built-in default grinder (a machine-tool chain).

    Returns a :class:`errormap.machine_tool.MachineTool` for a machine tool (a ``kind = "grinder"`` file
    read as its chain, :func:`errormap.grinder_file.parse_grinder_file`), the PKM dataclass for
    ``hexapod``/``tripod`` files, a serial chain for arms. ``expect_kind = "grinder"``: a machine tool with
    the grinder's structure (:func:`errormap.grinder_file.is_grinder_chain`). Raises
    :class:`MachineFileError` naming the file and the offending key.
    """
    if expect_kind == "grinder":
        return _load_grinder(path)
    path = builtin_machine_path(expect_kind or "grinder") if path is None else Path(path)
    if not path.is_file() and path.suffix == "" and len(path.parts) == 1:  # a built-in machine by name (--machine ur5)
        path = builtin_named(path.name) or path
    if not Path(path).is_file():
        raise MachineFileError(f"{path}: no such machine file")
    try:
        raw = read_document_bytes(path, "a machine file")   # sized before it is read (MAX_DOCUMENT_BYTES)
    except InputError as exc:
        raise MachineFileError(str(exc)) from None
    from .urdf import is_urdf, load_urdf_machine
    if is_urdf(raw):   # recognised by content: XML (a URDF's <robot> root), never TOML
        check_machine_kind(path, "serial", expect_kind)
        return load_urdf_machine(raw, path, sha256_bytes(raw))
    try:
        check_not_wide(raw, path)
    except InputError as exc:
        raise MachineFileError(str(exc)) from None
    try:
        doc = tomllib.loads(raw.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        if isinstance(exc, UnicodeDecodeError):
            row = raw.count(b"\n", 0, exc.start) + 1
            raise MachineFileError(f"{path}: line {row}: byte 0x{raw[exc.start]:02x} is not UTF-8 (is the file in "
                                   "Latin-1 / Windows-1252?); save it as UTF-8") from None
        raise MachineFileError(f"{path}: not valid TOML: {exc}") from None
    m = doc.get("machine")
    if not isinstance(m, dict) or "kind" not in m:
        raise MachineFileError(f"{path}: missing key 'machine.kind' (one of {', '.join(machine_kinds())})")
    kind = m["kind"]
    parsers = _parsers()
    if not isinstance(kind, str) or kind not in parsers:
        raise MachineFileError(f"{path}: key 'machine.kind': expected one of {sorted(parsers)}, got {short_repr(kind)}")
    if kind in ("machine-tool", "grinder"):  # a chain file is checked whole first: a broken one names its key, whatever the command
        machine = parsers[kind](doc, path, sha256_bytes(raw))
        check_machine_kind(path, kind, expect_kind)
        return machine
    check_machine_kind(path, kind, expect_kind)
    return parsers[kind](doc, path, sha256_bytes(raw))


def _load_grinder(path):
    """A machine tool with the grinder's structure (the built-in grinder for None); refused otherwise."""
    from .grinder_file import is_grinder_chain
    machine = load_machine(path, expect_kind="machine-tool" if path is not None else None)
    if not is_grinder_chain(machine):
        raise MachineFileError(f"{machine.path}: expected the grinder's chain here (its 23 elements and axes X, Z, A), "
                               f"got {machine.name!r} with axes {', '.join(machine.axis_words)}")
    return machine


def check_machine_kind(path, kind: str, expect_kind: str | None) -> None:
    """Refuse a machine file of ``kind`` where ``expect_kind`` is needed (None: any kind)."""
    if kind == "grinder":   # read as its chain
        kind = "machine-tool"
    if expect_kind is not None and kind != expect_kind:
        hint = KIND_HINTS.get(kind, "")
        raise MachineFileError(f"{path}: key 'machine.kind': expected {expect_kind!r} here, got {kind!r}"
                               + (f" ({hint})" if hint else ""))


# what a machine of each kind is for, said when a command meant for another kind is given one
KIND_HINTS = {
    "serial": "a serial arm: use volcomp simulate, calibrate, compensate, predict or benchmark",
    "hexapod": "a parallel machine: use volcomp simulate, calibrate, predict, interpolate or benchmark",
    "tripod": "a parallel machine: use volcomp simulate, calibrate, predict, interpolate or benchmark",
}
