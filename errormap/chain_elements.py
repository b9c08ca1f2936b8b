"""Element sets of any machine-tool chain: per-axis stations, component-error functions, constants.

Component errors (μm / μrad) are functions of their own axis, stored at that axis' stations and interpolated
by one vector-valued cubic B-spline per axis (``scipy.interpolate.make_interp_spline``; periodic for a
full-turn rotary axis, whose stations span exactly 360°); location and squareness errors are constants.
File: ``format = "volcomp-elements/1"`` (``docs/reference/file-formats.md``). Shapes:
``values(axes (n, k)) -> (n, P)`` in the machine's slot order; ``slopes(axes) -> (n, P)`` d(slot)/d(own
axis), zero for constants."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import make_interp_spline

from .elements import check_profile
from .io import InputError, atomic_write, read_document_text
from .machine_tool import MachineTool
from .machine_tool_file import FULL_TURN_DEG

ELEMENTS_FORMAT = "volcomp-elements/1"
# No element of a machine tool reaches a metre (μm) or a radian (μrad), nor a station a kilometre:
# beyond this a value is a unit or typing mistake (and 1e308 would overflow the HTM products)
MAX_ELEMENT_VALUE = 1e6
MIN_STATIONS = 4         # a cubic spline needs 4 stations
TURN_TOL_DEG = 1e-9      # stations of a full-turn axis span 360° to this


@dataclass
class ChainElementSet:
    """Values of a machine tool's error slots. ``stations[column]`` (m_k,) increasing per moving
    axis with component errors; ``functions[slot]`` (m_k,) at its axis' stations; ``constants[slot]``."""

    machine: MachineTool
    stations: dict
    functions: dict
    constants: dict
    machine_name: str = ""
    machine_sha256: str = ""
    _splines: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        m = self.machine
        axes_with = [a for a in m.axes if m.slots_of(a.word)]
        st = {}
        for a in axes_with:
            if a.column not in self.stations:
                raise ValueError(f"Expected stations for {a.column}")
            s = np.asarray(self.stations[a.column], dtype=float)
            if s.ndim != 1 or s.size < MIN_STATIONS or not np.all(np.isfinite(s)) or np.any(np.diff(s) <= 0):
                raise ValueError(f"Expected at least {MIN_STATIONS} increasing finite stations for {a.column}, got {s}")
            if np.abs(s).max() > MAX_ELEMENT_VALUE:
                raise ValueError(f"Expected stations for {a.column} within ±{MAX_ELEMENT_VALUE:g}")
            if a.full_turn and abs(s[-1] - s[0] - FULL_TURN_DEG) > TURN_TOL_DEG:
                raise ValueError(f"Expected {a.column} stations spanning exactly one turn (360°), got {s[0]}..{s[-1]}")
            st[a.column] = s
        unknown = sorted(set(self.stations) - set(st))
        if unknown:
            raise ValueError(f"Expected stations only for the axes with component errors {sorted(st)}, got {unknown}")
        self.stations = st
        fn, cn = m.function_slots, m.constant_slots
        missing = [k for k in fn if k not in self.functions] + [k for k in cn if k not in self.constants]
        if missing:
            raise ValueError(f"Expected all {len(m.slots)} elements of {m.name!r}, missing {missing}")
        unknown = sorted(set(self.functions) - set(fn)) + sorted(set(self.constants) - set(cn))
        if unknown:
            raise ValueError(f"Expected only the element names of {m.name!r}, got unknown {unknown}")
        slot = {s.name: s for s in m.slots}
        col = {a.word: a for a in m.axes}
        fun = {}
        for k in fn:
            ax = col[slot[k].axis]
            v = check_profile(k, self.functions[k], self.stations[ax.column], ax.column)
            if np.abs(v).max() > MAX_ELEMENT_VALUE:
                raise ValueError(f"Expected {k} within ±{MAX_ELEMENT_VALUE:g} (μm or μrad), got {np.abs(v).max():g}")
            if ax.full_turn:
                if abs(v[-1] - v[0]) > 1e-9 * max(1.0, np.abs(v).max()):
                    raise ValueError(f"Expected a closed {ax.word} profile for {k} (value at 360° = value at 0°), "
                                     f"got {v[0]} and {v[-1]}")
                v = v.copy()
                v[-1] = v[0]
            fun[k] = v
        self.functions = fun
        self.constants = {k: float(self.constants[k]) for k in cn}
        for k, v in self.constants.items():
            if not abs(v) <= MAX_ELEMENT_VALUE:
                raise ValueError(f"Expected {k} finite and within ±{MAX_ELEMENT_VALUE:g} (μm or μrad), got {v:g}")

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def zeros(cls, machine: MachineTool, n_stations: int = 21) -> "ChainElementSet":
        """All elements zero at ``n_stations`` equally spaced stations over each stroke."""
        st = {a.column: np.linspace(*a.stroke, n_stations) for a in machine.axes if machine.slots_of(a.word)}
        return cls(machine, st, {k: np.zeros(n_stations) for k in machine.function_slots},
                   {k: 0.0 for k in machine.constant_slots}, machine.name, machine.sha256)

    @classmethod
    def random(cls, machine: MachineTool, seed: int, scale_um: float = 20.0,
               n_stations: int = 11) -> "ChainElementSet":
        """A seeded element set of independent normal values (σ ``scale_um`` μm or μrad) at
        ``n_stations`` stations per axis, full-turn axes closed: a test and benchmark fixture, not a
        truth family (those are :mod:`errormap.chain_truth`'s)."""
        rng = np.random.default_rng(seed)
        z = cls.zeros(machine, n_stations)
        fun = {}
        for s in machine.slots:
            if s.is_function:
                f = rng.normal(0.0, scale_um, n_stations)
                if next(a for a in machine.axes if a.word == s.axis).full_turn:
                    f[-1] = f[0]
                fun[s.name] = f
        return cls(machine, z.stations, fun, {k: rng.normal(0.0, scale_um) for k in machine.constant_slots})

    def copy(self) -> "ChainElementSet":
        return ChainElementSet(self.machine, {k: v.copy() for k, v in self.stations.items()},
                               {k: v.copy() for k, v in self.functions.items()}, dict(self.constants),
                               self.machine_name, self.machine_sha256)

    def scaled(self, factor: float) -> "ChainElementSet":
        """Every element times ``factor``."""
        out = self.copy()
        out.functions = {k: v * factor for k, v in out.functions.items()}
        out.constants = {k: v * factor for k, v in out.constants.items()}
        out._splines = {}
        return out

    # -- evaluation ---------------------------------------------------------------------------
    def axis_spline(self, word: str):
        """One vector-valued cubic B-spline of the component errors of axis ``word`` (columns in
        :meth:`MachineTool.slots_of` order), cached."""
        if word not in self._splines:
            ax = next(a for a in self.machine.axes if a.word == word)
            y = np.stack([self.functions[k] for k in self.machine.slots_of(word)], axis=1)
            self._splines[word] = make_interp_spline(self.stations[ax.column], y, k=3,
                                                     bc_type="periodic" if ax.full_turn else None)
        return self._splines[word]

    def wrap(self, column: str, values) -> np.ndarray:
        """Positions of a full-turn axis folded into its stations' turn ``[s0, s0 + 360)``."""
        s0 = self.stations[column][0]
        return s0 + np.mod(np.asarray(values, dtype=float) - s0, FULL_TURN_DEG)

    def _evaluate(self, axes, nu: int) -> np.ndarray:
        axes = np.atleast_2d(np.asarray(axes, dtype=float))
        m = self.machine
        if axes.shape[1] != len(m.axes):
            raise ValueError(f"expected axes of shape (n, {len(m.axes)}) ({', '.join(m.axis_columns)}), got {axes.shape}")
        out = np.zeros((axes.shape[0], len(m.slots)))
        idx = {n: j for j, n in enumerate(m.slot_names)}
        for j, a in enumerate(m.axes):
            names = m.slots_of(a.word)
            if not names:
                continue
            x = self.wrap(a.column, axes[:, j]) if a.full_turn else axes[:, j]
            out[:, [idx[k] for k in names]] = self.axis_spline(a.word)(x, nu)
        if nu == 0:
            for k, v in self.constants.items():
                out[:, idx[k]] = v
        return out

    def values(self, axes) -> np.ndarray:
        """Element values at axis points, shape (n, k) -> (n, P) μm / μrad, in slot order."""
        return self._evaluate(axes, 0)

    def slopes(self, axes) -> np.ndarray:
        """d(element)/d(own axis) at axis points, (n, k) -> (n, P), μm or μrad per mm or per deg."""
        return self._evaluate(axes, 1)

    # -- file ---------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        m = self.machine
        unit = {s.name: s.unit for s in m.slots}
        return {"format": ELEMENTS_FORMAT, "machine": self.machine_name or m.name,
                "machine_sha256": self.machine_sha256 or m.sha256,
                "stations": {k: v.tolist() for k, v in self.stations.items()},
                "functions": {k: self.functions[k].tolist() for k in m.function_slots},
                "constants": {k: self.constants[k] for k in m.constant_slots},
                "units": {k: unit[k] for k in m.slot_names}}

    def save(self, path) -> Path:
        """Write the element-set file (JSON) atomically."""
        with atomic_write(path, "w", encoding="utf-8") as fh:
            json.dump(self.to_dict(), fh, indent=1)
            fh.write("\n")
        return Path(path)

    @classmethod
    def load(cls, path, machine: MachineTool) -> "ChainElementSet":
        """Read an element-set file for ``machine``; errors name the file and the key."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such element-set file")
        try:
            d = json.loads(read_document_text(path, "a chain element set"))
        except (json.JSONDecodeError, RecursionError) as exc:
            raise InputError(f"{path}: not valid JSON: {exc}") from None
        if not isinstance(d, dict) or d.get("format") != ELEMENTS_FORMAT:
            got = d.get("format") if isinstance(d, dict) else d
            raise InputError(f"{path}: key 'format': expected {ELEMENTS_FORMAT!r}, got {got!r}")
        for key in ("stations", "functions", "constants"):
            if not isinstance(d.get(key), dict):
                raise InputError(f"{path}: missing or malformed key '{key}'")
        units = d.get("units", {})
        if isinstance(units, dict):
            want = {s.name: s.unit for s in machine.slots}
            bad = [k for k, u in units.items() if k in want and u != want[k]]
            if bad:
                raise InputError(f"{path}: key 'units.{bad[0]}': expected {want[bad[0]]!r}, got {units[bad[0]]!r}")
        need = [a.column for a in machine.axes if machine.slots_of(a.word)]
        missing = [c for c in need if c not in d["stations"]]
        if missing:   # another machine's element set (its own axes)
            raise InputError(f"{path}: key 'stations': no {missing[0]!r} (this element set's axes are "
                             f"{sorted(d['stations'])[:6]}, of machine {str(d.get('machine', '?'))[:60]!r}; this "
                             f"machine's are {', '.join(need)}): give its own --machine")
        try:
            return cls(machine, d["stations"], d["functions"], d["constants"], d.get("machine", ""),
                       d.get("machine_sha256", ""))
        except (ValueError, TypeError, KeyError, OverflowError) as exc:
            raise InputError(f"{path}: {exc}") from None
