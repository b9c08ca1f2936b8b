"""The physical part of the residual-on-physics surrogate: an element set fitted to feature points.

``volcomp train --physics first-order`` trains the network on what a cheap physical model leaves: the
machine's element set fitted by ONE minimum-norm linear least-squares solve to the same feature points,
``E(axes) ≈ J(axes)·v(axes)`` (first-order error transfer), each axis-motion element a cubic interpolating
B-spline through ``n_stations`` stations of its axis, and evaluated with the EXACT chain
(:class:`errormap.chain_field.ChainField`). :func:`solve_station_values` is the solve,
:func:`fit_physics_elements` a machine tool's slots, :class:`PhysicsPart` the physical part of the networks.
docs/reference/learned-stage.md ("Physics first")."""
from __future__ import annotations

import numpy as np
from scipy.interpolate import make_interp_spline


PHYSICS = ("none", "first-order")
"""``--physics`` choices: no physical part (the paper's network alone), or the fitted element set."""
MIN_STATIONS, MAX_STATIONS = 4, 61
RCOND = 1e-10  # relative singular-value cut of the minimum-norm solve: drops the grid's gauge directions only


def grid_stations(axes) -> int:
    """Stations per axis for a feature-point grid: the fewest distinct values over the axis columns
    (three on the grinder, the machine's own on a chain), clipped to [MIN_STATIONS, MAX_STATIONS]
    (a regular n×…×n grid gives n)."""
    a = np.asarray(axes, float)
    n = min(np.unique(np.round(a[:, k], 9)).size for k in range(a.shape[1]))
    return int(np.clip(n, MIN_STATIONS, MAX_STATIONS))


def _n_stations(axes, n_stations) -> int:
    m = grid_stations(axes) if n_stations is None else int(n_stations)
    if not MIN_STATIONS <= m <= MAX_STATIONS:
        raise ValueError(f"Expected n_stations in [{MIN_STATIONS}, {MAX_STATIONS}], got {m}")
    return m


def _basis(stations, x, periodic: bool) -> np.ndarray:
    """Values at ``x`` (m,) of the cubic interpolating spline of each free station, shape (m, k):
    station 0 is the reference (zero); on a full turn the last station repeats the first."""
    s = stations.size
    free = range(1, s - 1) if periodic else range(1, s)
    eye = np.zeros((s, len(free)))
    for c, j in enumerate(free):
        eye[j, c] = 1.0
    return make_interp_spline(stations, eye, k=3, bc_type="periodic" if periodic else None)(x)


def solve_station_values(J, errors_um, function_bases, constant_slots):
    """The one linear least-squares solve of the physical part, for any kinematic chain.

    ``J`` (n, 3, P): first-order error transfer, μm per element unit; ``errors_um`` (n, 3);
    ``function_bases``: ``[(slot index, basis (n, f))]`` for the component errors (their free
    stations' spline values at the points, :func:`_basis`); ``constant_slots``: slot indices of the
    constants. Minimum norm in the elements' own units (μm, μrad): the gauge combinations the grid
    cannot see stay near zero, so they add nothing through the exact model's second-order terms
    (scaling the columns to unit norm first moved them and raised the grinder's exact misfit
    0.027 → 0.16 μm). Returns ``(free station values per function (f,), constant values)``.
    """
    J = np.asarray(J, float)
    cols = [J[:, :, i, None] * B[:, None, :] for i, B in function_bases] + [J[:, :, i, None] for i in constant_slots]
    A = np.concatenate(cols, axis=2).reshape(3 * J.shape[0], -1)
    p = np.linalg.lstsq(A, np.asarray(errors_um, float).reshape(-1), rcond=RCOND)[0]
    sizes = [B.shape[1] for _, B in function_bases]
    nf = int(sum(sizes))
    return np.split(p[:nf], np.cumsum(sizes)[:-1]), [float(v) for v in p[nf:]]


def _profile(free, n: int, periodic: bool) -> np.ndarray:
    """A component error's values at its ``n`` stations: zero at the reference, closed on a full turn."""
    v = np.zeros(n)
    v[1:1 + free.size] = free
    if periodic:
        v[-1] = v[0]
    return v


def fit_physics_elements(machine, axes, errors_um, n_stations: int | None = None):
    """The element set whose first-order field best fits ``errors_um``: a machine tool's own slots (the grinder's
    23 elements on its chain), ``n_stations`` equally spaced stations over
    each stroke with component errors, periodic on a full turn, fitted to ``errors_um`` (n, 3) at
    ``axes`` (n, k) by :func:`solve_station_values` with the chain's error-transfer matrix
    (:func:`errormap.chain_kernel.error_jacobian`); returns a :class:`ChainElementSet`, evaluated
    exactly by :class:`errormap.chain_field.ChainField`."""
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_kernel import error_jacobian as chain_error_jacobian
    axes = np.asarray(axes, float)
    if axes.ndim != 2 or axes.shape[1] != len(machine.axes):
        raise ValueError(f"expected axes of shape (n, {len(machine.axes)}) ({', '.join(machine.axis_columns)}), "
                         f"got {axes.shape}")
    st = ChainElementSet.zeros(machine, _n_stations(axes, n_stations)).stations
    bases = {}
    for j, a in enumerate(machine.axes):
        if a.column in st:
            s0 = st[a.column][0]
            x = s0 + np.mod(axes[:, j] - s0, 360.0) if a.full_turn else axes[:, j]
            bases[a.word] = (_basis(st[a.column], x, a.full_turn), a)
    J = chain_error_jacobian(machine, axes)                             # (n, 3, P)
    fun = [(i, s) for i, s in enumerate(machine.slots) if s.is_function]
    free, const = solve_station_values(J, errors_um, [(i, bases[s.axis][0]) for i, s in fun],
                                       [i for i, s in enumerate(machine.slots) if not s.is_function])
    functions = {s.name: _profile(f, st[bases[s.axis][1].column].size, bases[s.axis][1].full_turn)
                 for (_, s), f in zip(fun, free)}
    constants = dict(zip([s.name for s in machine.slots if not s.is_function], const))
    return ChainElementSet(machine, st, functions, constants, machine.name, machine.sha256 or "")


PHYSICS_FILES = ("physics_elements.json", "physics_machine.toml")
"""Files a physics-first model saves beside its network's (their SHA-256 recorded in config.json)."""


class PhysicsPart:
    """The physical part of a physics-first field, mixed in before a network class (the grinder's
    :class:`training.model.MLPField`):
    ``E = physical field(elements)(axes) + network(axes)``.

    ``physics_`` is the element set fitted to the feature points the network is trained on
    (:func:`fit_physics_elements`), ``physics_machine_`` the machine it belongs to; the subclass
    says how that pair becomes an exact field (``_physics_field``), how it checks axes
    (``_physics_axes``) and how it reads the saved pair back (``_read_physics``). Value and
    Jacobian are the sums of the two parts' closed forms. Saved as the network's files plus
    :data:`PHYSICS_FILES` (the element set and the machine file's bytes).
    """

    def _physics_field(self, machine, elements):  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def _physics_axes(self, axes) -> np.ndarray:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def _read_physics(self, folder):  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def set_physics(self, machine, elements):
        """Attach the physical part (a machine and its element set); returns self."""
        self.physics_machine_ = machine
        self.physics_ = elements
        self._physics_field_ = self._physics_field(machine, elements)
        return self

    def _physics(self):
        if "_physics_field_" not in self.__dict__:
            raise RuntimeError(f"{type(self).__name__} has no physical part: call set_physics or load")
        return self._physics_field_

    def physics_predict(self, axes) -> np.ndarray:
        """The physical part alone (μm), shape (n, 3)."""
        return self._physics().predict(self._physics_axes(axes))

    def network_predict(self, axes, dtype=np.float64) -> np.ndarray:
        """The network alone (μm), shape (n, 3): what it learned on top of the physical part."""
        return super().predict(axes, dtype)

    def predict(self, axes, dtype=np.float64) -> np.ndarray:
        axes = self._physics_axes(axes)
        return super().predict(axes, dtype) + self._physics().predict(axes)

    __call__ = predict

    def predict_and_jacobian(self, axes, dtype=np.float64):
        axes = self._physics_axes(axes)
        e, J = super().predict_and_jacobian(axes, dtype)
        pe, pJ = self._physics().predict_and_jacobian(axes)
        return e + pe, J + pJ

    @property
    def physics_stations(self) -> int | None:
        """Stations per axis of the fitted element set (None before ``set_physics``)."""
        if "physics_" not in self.__dict__:
            return None
        return int(next(iter(self.physics_.stations.values())).size)

    def config(self) -> dict:
        return {**super().config(), "physics": "first-order", "physics_stations": self.physics_stations}

    @staticmethod
    def _extra_file_names() -> tuple:
        return PHYSICS_FILES

    def _write_extra_files(self, folder) -> None:
        from pathlib import Path

        from errormap.io import atomic_write
        self._physics()
        self.physics_.save(folder / PHYSICS_FILES[0])
        with atomic_write(folder / PHYSICS_FILES[1], "wb") as fh:
            fh.write(Path(self.physics_machine_.path).read_bytes())

    def _read_extra_files(self, folder) -> None:
        self.set_physics(*self._read_physics(folder))
