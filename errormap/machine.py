"""Machine files (TOML): loading and validation.

One file per machine; ``[machine] kind`` selects the schema (``grinder``, ``hexapod``,
``tripod``). The built-in default grinder ships as ``errormap/machines/grinder.toml``.
Every error names the file and the key.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from .io import sha256_bytes

GRINDER_GEOMETRY_KEYS = ("l1", "l2", "l3", "l4", "R", "l5", "l6", "l7", "l8", "theta1_deg")
GRINDER_STROKE_KEYS = ("x_mm", "z_mm", "a_deg")
GRINDER_TARGET_KEYS = ("X", "Z", "A")


class MachineFileError(ValueError):
    """A machine file is malformed; the message names the file and the key."""


def builtin_machine_path(kind: str = "grinder") -> Path:
    """Path of a built-in machine file (``grinder``, ``hexapod`` or ``tripod``)."""
    p = Path(str(resources.files("errormap") / "machines" / f"{kind}.toml"))
    if not p.is_file():
        raise MachineFileError(f"no built-in machine file for kind {kind!r} ({p})")
    return p


@dataclass(frozen=True)
class Grinder:
    """The micro-drill flute grinder's nominal description (lengths mm, angles deg).

    ``strokes`` maps ``x_mm``/``z_mm``/``a_deg`` to ``(lo, hi)``; ``targets`` maps
    ``X``/``Z``/``A`` to the nominal target-ball centres, shape (3, 3), in the body frame.
    """

    name: str
    l1: float
    l2: float
    l3: float
    l4: float
    R: float
    l5: float
    l6: float
    l7: float
    l8: float
    theta1_deg: float
    strokes: dict
    targets: dict
    path: str = ""
    sha256: str = ""
    kind: str = field(default="grinder")

    @property
    def rho0_mm(self) -> float:
        """Radius of the tool point about the A axis at z = 0: ``l1 + l4 - R - l6 - l8``."""
        return self.l1 + self.l4 - self.R - self.l6 - self.l8

    @property
    def stroke_lo(self) -> np.ndarray:
        """Lower stroke limits (x_mm, z_mm, a_deg), shape (3,)."""
        return np.array([self.strokes[k][0] for k in GRINDER_STROKE_KEYS])

    @property
    def stroke_hi(self) -> np.ndarray:
        """Upper stroke limits (x_mm, z_mm, a_deg), shape (3,)."""
        return np.array([self.strokes[k][1] for k in GRINDER_STROKE_KEYS])


def _expect_number(doc: dict, key: str, where: str, path) -> float:
    if key not in doc:
        raise MachineFileError(f"{path}: missing key '{where}.{key}'")
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MachineFileError(f"{path}: key '{where}.{key}': expected a number, got {v!r}")
    if not np.isfinite(v):
        raise MachineFileError(f"{path}: key '{where}.{key}': expected a finite number, got {v!r}")
    return float(v)


def _expect_table(doc: dict, key: str, path) -> dict:
    if key not in doc:
        raise MachineFileError(f"{path}: missing section '[{key}]'")
    if not isinstance(doc[key], dict):
        raise MachineFileError(f"{path}: '{key}': expected a table, got {type(doc[key]).__name__}")
    return doc[key]


def _no_unknown(section: dict, allowed, where: str, path) -> None:
    unknown = sorted(set(section) - set(allowed))
    if unknown:
        raise MachineFileError(f"{path}: unknown key(s) {['%s.%s' % (where, k) for k in unknown]}; allowed: {list(allowed)}")


def expect_array(value, shape: tuple, where: str, path) -> np.ndarray:
    """Convert a TOML value to a float array of ``shape`` (``-1`` = any), naming the key on error."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise MachineFileError(f"{path}: key '{where}': expected numbers of shape {shape}, got {value!r}") from None
    if arr.ndim != len(shape) or any(s not in (-1, a) for s, a in zip(shape, arr.shape)):
        raise MachineFileError(f"{path}: key '{where}': expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise MachineFileError(f"{path}: key '{where}': expected finite numbers, got {value!r}")
    return arr


def parse_grinder(doc: dict, path, sha: str = "") -> Grinder:
    """Validate a parsed grinder machine file; see DESIGN.md for the schema."""
    _no_unknown(doc, ("machine", "geometry", "strokes", "targets"), "", path)
    m = _expect_table(doc, "machine", path)
    _no_unknown(m, ("kind", "name"), "machine", path)
    name = m.get("name", "grinder")
    if not isinstance(name, str):
        raise MachineFileError(f"{path}: key 'machine.name': expected a string, got {name!r}")
    g = _expect_table(doc, "geometry", path)
    _no_unknown(g, GRINDER_GEOMETRY_KEYS, "geometry", path)
    geom = {k: _expect_number(g, k, "geometry", path) for k in GRINDER_GEOMETRY_KEYS}
    if geom["R"] <= 0:
        raise MachineFileError(f"{path}: key 'geometry.R': expected a positive wheel radius, got {geom['R']}")
    s = _expect_table(doc, "strokes", path)
    _no_unknown(s, GRINDER_STROKE_KEYS, "strokes", path)
    strokes = {}
    for k in GRINDER_STROKE_KEYS:
        if k not in s:
            raise MachineFileError(f"{path}: missing key 'strokes.{k}'")
        arr = expect_array(s[k], (2,), f"strokes.{k}", path)
        if not arr[1] > arr[0]:
            raise MachineFileError(f"{path}: key 'strokes.{k}': expected [lo, hi] with hi > lo, got {s[k]!r}")
        strokes[k] = (float(arr[0]), float(arr[1]))
    t = _expect_table(doc, "targets", path)
    _no_unknown(t, GRINDER_TARGET_KEYS, "targets", path)
    targets = {}
    for k in GRINDER_TARGET_KEYS:
        if k not in t:
            raise MachineFileError(f"{path}: missing key 'targets.{k}'")
        targets[k] = expect_array(t[k], (3, 3), f"targets.{k}", path)
    return Grinder(name=name, strokes=strokes, targets=targets, path=str(path), sha256=sha, **geom)


def _parsers():
    parsers = {"grinder": parse_grinder}
    try:  # the PKM schemas live with the PKM models
        from .pkm.machine_file import parse_hexapod, parse_tripod
        parsers["hexapod"] = parse_hexapod
        parsers["tripod"] = parse_tripod
    except ImportError:  # pragma: no cover - during bootstrapping only
        pass
    return parsers


def load_machine(path=None, expect_kind: str | None = None):
    """Load and validate a machine file; ``None`` gives the built-in default grinder.

    Returns a :class:`Grinder` (or the PKM dataclass for ``hexapod``/``tripod`` files).
    Raises :class:`MachineFileError` naming the file and the offending key.
    """
    path = builtin_machine_path(expect_kind or "grinder") if path is None else Path(path)
    if not Path(path).is_file():
        raise MachineFileError(f"{path}: no such machine file")
    raw = Path(path).read_bytes()
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise MachineFileError(f"{path}: not valid TOML: {exc}") from None
    m = doc.get("machine")
    if not isinstance(m, dict) or "kind" not in m:
        raise MachineFileError(f"{path}: missing key 'machine.kind' (one of grinder, hexapod, tripod)")
    kind = m["kind"]
    parsers = _parsers()
    if kind not in parsers:
        raise MachineFileError(f"{path}: key 'machine.kind': expected one of {sorted(parsers)}, got {kind!r}")
    if expect_kind is not None and kind != expect_kind:
        raise MachineFileError(f"{path}: key 'machine.kind': expected {expect_kind!r} here, got {kind!r}")
    return parsers[kind](doc, path, sha256_bytes(raw))
