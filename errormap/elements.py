"""The grinder's 23 geometric error elements and their element-set file.

Translations in μm, angles in μrad. The 18 axis-motion elements are functions of
their own axis position, stored as values at stations and interpolated by a cubic
B-spline (``scipy.interpolate.make_interp_spline``; periodic in A). The 5 A-line and
squareness elements are constants.

Gauge (what a laser-tracker identification can observe): every axis-motion element
is zero at its first station (the axes are referenced there); constant offsets of a
body at its reference position are carried by the A-line constants.

Element-set file (JSON, ``format = "volcomp-elements/1"``)::

    {"format": "volcomp-elements/1", "machine": "<name>", "machine_sha256": "...",
     "stations": {"x_mm": [...], "z_mm": [...], "a_deg": [...]},   # per axis, increasing
     "functions": {"dx_x": [...], ...},                              # 18 lists, μm or μrad at the stations
     "constants": {"dy_oa": 0.0, "dz_oa": 0.0, "ey_oa": 0.0, "ez_oa": 0.0, "s_xz": 0.0},
     "units": {"dx_x": "um", "ex_x": "urad", ...}}
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import make_interp_spline

from .io import InputError, atomic_write, read_document_text
from .machine_tool import MachineTool

X_ELEMENTS = ("dx_x", "dy_x", "dz_x", "ex_x", "ey_x", "ez_x")
Z_ELEMENTS = ("dx_z", "dy_z", "dz_z", "ex_z", "ey_z", "ez_z")
A_ELEMENTS = ("dx_a", "dy_a", "dz_a", "ex_a", "ey_a", "ez_a")
FUNCTION_ELEMENTS = X_ELEMENTS + Z_ELEMENTS + A_ELEMENTS
CONSTANT_ELEMENTS = ("dy_oa", "dz_oa", "ey_oa", "ez_oa", "s_xz")
ELEMENT_NAMES = FUNCTION_ELEMENTS + CONSTANT_ELEMENTS
"""The 23 elements, in the column order of :meth:`ElementSet.values` and the Jacobian."""

AXIS_OF = {**{k: "x_mm" for k in X_ELEMENTS}, **{k: "z_mm" for k in Z_ELEMENTS},
           **{k: "a_deg" for k in A_ELEMENTS}}
AXIS_COLUMN = {"x_mm": 0, "z_mm": 1, "a_deg": 2}
IDX = {k: i for i, k in enumerate(ELEMENT_NAMES)}
"""Column of each element in :data:`ELEMENT_NAMES` order (the grinder chain's slot order)."""
_AXIS_ELEMENTS = {"x_mm": X_ELEMENTS, "z_mm": Z_ELEMENTS, "a_deg": A_ELEMENTS}


def element_unit(name: str) -> str:
    """``"um"`` for translations (names starting with ``d``), ``"urad"`` for angles."""
    if name not in ELEMENT_NAMES:
        raise KeyError(f"Expected one of the 23 element names {ELEMENT_NAMES}, got {name!r}")
    return "um" if name.startswith("d") else "urad"


def default_stations(machine: MachineTool, n: int = 21) -> dict:
    """``n`` equally spaced stations over each stroke (the paper: every 1/20; A every 18°)."""
    return {k: np.linspace(*machine.strokes[k], n) for k in ("x_mm", "z_mm", "a_deg")}


# No element of a machine tool reaches a metre (μm) or a radian (μrad), nor a station a kilometre:
# beyond this a value is a unit or typing mistake (and 1e308 would overflow the HTM products)
MAX_ELEMENT_VALUE = 1e6


def check_profile(name: str, values, stations, column: str) -> np.ndarray:
    """Element ``name``'s values (one per station of axis ``column``, ``stations`` shape (m,)) as
    float64 (m,); a wrong count or a value that is not a finite number (NaN, null, inf) raises
    ValueError naming the element, the value's position and its station."""
    try:
        v = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"element {name!r}: expected {stations.size} numbers (one per {column} station), got "
                         f"{str(values)[:60]}") from None
    if v.shape != stations.shape:
        raise ValueError(f"element {name!r}: expected {stations.size} values (one per {column} station), got shape "
                         f"{v.shape}")
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"element {name!r}: value {i + 1} of {v.size} ({column} station {stations[i]:g}) is {v[i]} "
                         f"(a NaN, null or infinity in the file){f'; {bad.size} such values' if bad.size > 1 else ''};"
                         " expected finite numbers")
    return v


@dataclass
class ElementSet:
    """Values of the 23 error elements.

    ``stations[axis]`` shape (m,), ``functions[name]`` shape (m,) at those stations,
    ``constants[name]`` scalars. A profiles must close (value at 360° equals value at 0°).
    """

    stations: dict
    functions: dict
    constants: dict
    machine_name: str = ""
    machine_sha256: str = ""
    _splines: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        self.stations = {k: np.asarray(self.stations[k], dtype=float) for k in ("x_mm", "z_mm", "a_deg")}
        for k, s in self.stations.items():
            if s.ndim != 1 or s.size < 4 or not np.all(np.isfinite(s)) or np.any(np.diff(s) <= 0):
                raise ValueError(f"Expected at least 4 increasing finite stations for {k}, got {s}")
            if np.abs(s).max() > MAX_ELEMENT_VALUE:
                raise ValueError(f"Expected stations for {k} within ±{MAX_ELEMENT_VALUE:g}, got {np.abs(s).max():g}")
        if abs(self.stations["a_deg"][-1] - self.stations["a_deg"][0] - 360.0) > 1e-9:
            raise ValueError("Expected A stations spanning exactly one turn (360°), got "
                             f"{self.stations['a_deg'][0]}..{self.stations['a_deg'][-1]}")
        missing = [k for k in FUNCTION_ELEMENTS if k not in self.functions]
        missing += [k for k in CONSTANT_ELEMENTS if k not in self.constants]
        if missing:
            raise ValueError(f"Expected all 23 elements, missing {missing}")
        unknown = sorted(set(self.functions) - set(FUNCTION_ELEMENTS)) + sorted(set(self.constants) - set(CONSTANT_ELEMENTS))
        if unknown:
            raise ValueError(f"Expected only the 23 element names, got unknown {unknown}")
        fun = {}
        for k in FUNCTION_ELEMENTS:
            v = check_profile(k, self.functions[k], self.stations[AXIS_OF[k]], AXIS_OF[k])
            if np.abs(v).max() > MAX_ELEMENT_VALUE:
                raise ValueError(f"Expected {k} within ±{MAX_ELEMENT_VALUE:g} (μm or μrad), got {np.abs(v).max():g}")
            fun[k] = v
        self.functions = fun
        self.constants = {k: float(self.constants[k]) for k in CONSTANT_ELEMENTS}
        for k, v in self.constants.items():
            if not (abs(v) <= MAX_ELEMENT_VALUE):
                raise ValueError(f"Expected {k} finite and within ±{MAX_ELEMENT_VALUE:g} (μm or μrad), got {v:g}")
        for k in A_ELEMENTS:
            v = self.functions[k]
            if abs(v[-1] - v[0]) > 1e-9 * max(1.0, np.abs(v).max()):
                raise ValueError(f"Expected a closed A profile for {k} (value at 360° = value at 0°), got {v[0]} and {v[-1]}")
            v[-1] = v[0]

    # -- construction -------------------------------------------------------------------
    @classmethod
    def zeros(cls, machine: MachineTool, n_stations: int = 21) -> "ElementSet":
        st = default_stations(machine, n_stations)
        return cls(st, {k: np.zeros(n_stations) for k in FUNCTION_ELEMENTS},
                   {k: 0.0 for k in CONSTANT_ELEMENTS}, machine.name, machine.sha256)

    def copy(self) -> "ElementSet":
        return ElementSet({k: v.copy() for k, v in self.stations.items()},
                          {k: v.copy() for k, v in self.functions.items()},
                          dict(self.constants), self.machine_name, self.machine_sha256)

    def scaled(self, factor: float) -> "ElementSet":
        out = self.copy()
        out.functions = {k: v * factor for k, v in out.functions.items()}
        out.constants = {k: v * factor for k, v in out.constants.items()}
        return out

    # -- evaluation ---------------------------------------------------------------------
    def _spline(self, name):
        """The cubic interpolating B-spline of one function element (the per-element reference)."""
        if name not in self._splines:
            st = self.stations[AXIS_OF[name]]
            bc = "periodic" if name in A_ELEMENTS else None
            self._splines[name] = make_interp_spline(st, self.functions[name], k=3, bc_type=bc)
        return self._splines[name]

    def _axis_spline(self, axis):
        """One vector-valued cubic B-spline for the 6 elements of ``axis``: their values at the
        shared stations as the columns of ``y`` (m, 6), so one call finds each point's knot
        interval and basis once for all 6 (the same interpolation problem per column as
        :meth:`_spline`). Cached in ``_splines`` (which callers reset after editing functions)."""
        key = ("axis", axis)
        if key not in self._splines:
            names = _AXIS_ELEMENTS[axis]
            y = np.stack([self.functions[k] for k in names], axis=1)
            bc = "periodic" if axis == "a_deg" else None
            self._splines[key] = make_interp_spline(self.stations[axis], y, k=3, bc_type=bc)
        return self._splines[key]

    def wrap_a(self, a_deg) -> np.ndarray:
        """A positions folded into the stations' turn ``[a0, a0 + 360)`` (errors are periodic in A)."""
        a0 = self.stations["a_deg"][0]
        return a0 + np.mod(np.asarray(a_deg, dtype=float) - a0, 360.0)

    def values(self, axes) -> np.ndarray:
        """The 23 element values at axis points, shape (n, 3) -> (n, 23), in ELEMENT_NAMES order."""
        axes = np.asarray(axes, dtype=float)
        out = np.empty((axes.shape[0], len(ELEMENT_NAMES)))
        cols = {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": self.wrap_a(axes[:, 2])}
        for axis, names in _AXIS_ELEMENTS.items():
            j = FUNCTION_ELEMENTS.index(names[0])
            out[:, j:j + len(names)] = self._axis_spline(axis)(cols[axis])
        for j, k in enumerate(CONSTANT_ELEMENTS, start=len(FUNCTION_ELEMENTS)):
            out[:, j] = self.constants[k]
        return out

    # -- file ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "format": "volcomp-elements/1",
            "machine": self.machine_name,
            "machine_sha256": self.machine_sha256,
            "stations": {k: v.tolist() for k, v in self.stations.items()},
            "functions": {k: self.functions[k].tolist() for k in FUNCTION_ELEMENTS},
            "constants": {k: self.constants[k] for k in CONSTANT_ELEMENTS},
            "units": {k: element_unit(k) for k in ELEMENT_NAMES},
        }

    def save(self, path) -> Path:
        """Write the element-set file (JSON) atomically."""
        with atomic_write(path, "w", encoding="utf-8") as fh:
            json.dump(self.to_dict(), fh, indent=1)
            fh.write("\n")
        return Path(path)

    @classmethod
    def load(cls, path) -> "ElementSet":
        """Read an element-set file; errors name the file and the key."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such element-set file")
        try:
            d = json.loads(read_document_text(path, "an element set"))
        except (json.JSONDecodeError, RecursionError) as exc:
            raise InputError(f"{path}: not valid JSON: {exc}") from None
        if not isinstance(d, dict) or d.get("format") != "volcomp-elements/1":
            raise InputError(f"{path}: key 'format': expected 'volcomp-elements/1', got {d.get('format') if isinstance(d, dict) else d!r}")
        for key in ("stations", "functions", "constants"):
            if not isinstance(d.get(key), dict):
                raise InputError(f"{path}: missing or malformed key '{key}'")
        missing = [k for k in ("x_mm", "z_mm", "a_deg") if k not in d["stations"]]
        if missing:   # a machine-tool chain's element set (its own axes) given for the grinder
            raise InputError(f"{path}: key 'stations': no {missing[0]!r} (this element set's axes are "
                             f"{sorted(d['stations'])[:6]}, of machine {str(d.get('machine', '?'))[:60]!r}; the grinder's "
                             "are x_mm, z_mm, a_deg): give its own --machine")
        try:
            return cls(d["stations"], d["functions"], d["constants"], d.get("machine", ""), d.get("machine_sha256", ""))
        except (ValueError, TypeError, KeyError, OverflowError) as exc:
            raise InputError(f"{path}: {exc}") from None
