"""The error field: the one interface every layer shares.

``predict(axes (n, k)) -> (n, 3)`` μm (dx, dy, dz in the workpiece frame, float64), plus two plain attributes:
``calibrated_volume`` (a :class:`CalibratedVolume` where the field is valid, or ``None``; the guards refuse
commands outside it) and ``capabilities`` (a frozenset from :data:`CAPABILITIES` of the optional methods the
field offers: ``jacobian``, ``predict_and_jacobian``, ``float32``, ``predict_columns``, ``offset_fitness``;
:func:`check_field` checks that each is backed by its method). The capabilities' signatures, the fields that
implement them and which solver uses which: ``docs/explanation/solvers.md``."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

GRINDER_AXES = ("x_mm", "z_mm", "a_deg")
"""Axis names (and order) of a grinder field's input columns."""


def machine_axes(machine) -> tuple:
    """The axis columns a field of ``machine`` takes, in order: a machine-tool chain's own
    (``machine.axis_columns``: ``x_mm, y_mm, z_mm, a_deg, c_deg``...), else the grinder's
    :data:`GRINDER_AXES`."""
    cols = getattr(machine, "axis_columns", None)
    return tuple(cols) if cols is not None else GRINDER_AXES


def is_rotary_column(column: str) -> bool:
    """An axis column in degrees (``*_deg``: the project's unit-in-the-name rule) is a rotary axis;
    every other (``*_mm``) a linear one."""
    return str(column).endswith("_deg")


JACOBIAN = "jacobian"
PREDICT_AND_JACOBIAN = "predict_and_jacobian"
FLOAT32 = "float32"
PREDICT_COLUMNS = "predict_columns"
OFFSET_FITNESS = "offset_fitness"
CAPABILITIES = frozenset({JACOBIAN, PREDICT_AND_JACOBIAN, FLOAT32, PREDICT_COLUMNS, OFFSET_FITNESS})
"""Every optional capability a field may declare (module docstring)."""


@dataclass(frozen=True)
class CalibratedVolume:
    """The box a field is valid in: ``lo[k] ≤ axis k ≤ hi[k]`` for each axis named in ``names``.

    ``lo``, ``hi``: tuples of floats, one per axis (units in the names, e.g. mm and deg);
    ``names`` default to the grinder's :data:`GRINDER_AXES`. A range of at least 360° in a
    ``*_deg`` rotary axis means the whole turn (errors are periodic in A).
    """

    lo: tuple
    hi: tuple
    names: tuple = GRINDER_AXES

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        lo = np.asarray(self.lo, dtype=float).reshape(-1)
        hi = np.asarray(self.hi, dtype=float).reshape(-1)
        if lo.shape != (len(names),) or hi.shape != (len(names),):
            raise ValueError(f"Expected lo and hi of {len(names)} values ({', '.join(names)}), "
                             f"got {lo.size} and {hi.size}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise ValueError(f"Expected a finite calibrated box with lo ≤ hi, got lo={lo}, hi={hi}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "lo", tuple(float(v) for v in lo))
        object.__setattr__(self, "hi", tuple(float(v) for v in hi))

    @property
    def lo_array(self) -> np.ndarray:
        """``lo`` as a float array, shape (k,)."""
        return np.array(self.lo)

    @property
    def hi_array(self) -> np.ndarray:
        """``hi`` as a float array, shape (k,)."""
        return np.array(self.hi)


@runtime_checkable
class ErrorField(Protocol):
    """``predict(axes (n, 3)) -> (n, 3)`` μm, plus ``calibrated_volume`` and ``capabilities``."""

    calibrated_volume: CalibratedVolume | None
    capabilities: frozenset

    def predict(self, axes) -> np.ndarray:
        """Spatial error (dx_um, dy_um, dz_um), shape (n, 3), at axes (x_mm, z_mm, a_deg), shape (n, 3)."""


@runtime_checkable
class _Jacobian(Protocol):
    def jacobian(self, axes) -> np.ndarray:
        """dE/d(axes), shape (n, 3, 3): μm per (mm, mm, deg)."""


@runtime_checkable
class _PredictAndJacobian(Protocol):
    def predict_and_jacobian(self, axes, dtype=np.float64) -> tuple:
        """``(E (n, 3) μm, dE/d(axes) (n, 3, 3))`` in one pass."""


@runtime_checkable
class _PredictColumns(Protocol):
    def predict_columns(self, cols):
        """Errors μm at axis columns (3, m) -> (3, m), no validation, A folded into the field's turn."""


class OffsetFitness(Protocol):
    """The batched GA's fitness kernel for a fixed set of n targets ``p_d`` (WCS mm).

    ``fitness(points, offsets_um)``: ``points`` shape (k,) int64, indices into the targets;
    ``offsets_um`` shape (3, k) float32, offsets ``d`` as columns (μm); returns shape (k,)
    float32, ``-|d + E(IK(p_d + 1e-3·d))|²`` μm² (NaN mapped to -inf), IK the nominal grinder
    inverse kinematics. ``threads``: the threads one call uses by itself (the solver's default
    number of parallel workers; the solver runs them inside :func:`errormap.threads.limit_threads`
    ``(1)``). Calls for disjoint targets may run in several threads at once.
    """

    threads: int

    def __call__(self, points: np.ndarray, offsets_um: np.ndarray) -> np.ndarray: ...


@runtime_checkable
class _OffsetFitness(Protocol):
    def offset_fitness(self, machine, targets_mm) -> OffsetFitness:
        """The batched GA's fitness kernel for ``targets_mm`` (n, 3) (:class:`OffsetFitness`)."""


_BACKED_BY = {JACOBIAN: _Jacobian, PREDICT_AND_JACOBIAN: _PredictAndJacobian, PREDICT_COLUMNS: _PredictColumns,
              OFFSET_FITNESS: _OffsetFitness}
"""The method each capability promises (``float32`` is a ``dtype`` argument of ``predict``)."""


def check_field(field, names=GRINDER_AXES) -> ErrorField:
    """Return ``field`` if it is an :class:`ErrorField` for axes ``names``; raise TypeError otherwise.

    Checked once per call of a solver or guard: ``predict``, ``calibrated_volume`` (None or a
    :class:`CalibratedVolume` over ``names``) and ``capabilities`` (a frozenset drawn from
    :data:`CAPABILITIES`, each backed by its method).
    """
    if not isinstance(field, ErrorField):
        raise TypeError(f"Expected an error field (predict(axes) -> (n, 3) μm, calibrated_volume, capabilities; "
                        f"see errormap.field), got {type(field).__name__}")
    caps = field.capabilities
    if not isinstance(caps, frozenset) or not caps <= CAPABILITIES:
        raise TypeError(f"Expected {type(field).__name__}.capabilities to be a frozenset of {sorted(CAPABILITIES)}, "
                        f"got {caps!r}")
    missing = [c for c in sorted(caps) if c in _BACKED_BY and not isinstance(field, _BACKED_BY[c])]
    if missing:
        raise TypeError(f"{type(field).__name__} declares {missing} without the method(s)")
    vol = field.calibrated_volume
    if vol is not None and not isinstance(vol, CalibratedVolume):
        raise TypeError(f"Expected {type(field).__name__}.calibrated_volume to be a CalibratedVolume or None, "
                        f"got {type(vol).__name__}")
    if vol is not None and vol.names != tuple(names):
        raise TypeError(f"Expected a field over the axes {list(names)}, got {type(field).__name__} calibrated over "
                        f"{list(vol.names)}")
    return field
