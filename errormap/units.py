"""One unit check for every reader of numbers with units (lengths, angles, temperatures).

Units are never guessed or converted: a file whose numbers fit another unit better than the one
its column names (metres for mm, radians for degrees, °F or kelvin for °C) is refused with one
line naming the file, the row, the column and the likely mistake (:class:`~errormap.io.InputError`,
exit status 2). Every reader calls :func:`check_units` (check measurements, predict points, tool-path
CSVs, the closed loop's per-point conditions) or one of the helpers below (sweeps: ball distances;
PKM poses: tip spread, both through :func:`length_unit_guess`).

``units``: :data:`UNITS_CHECK` (default) runs the plausibility tests; :data:`UNITS_AS_WRITTEN` (the
``--units as-written`` option) is the user's word that the columns are in their named units: the
likely-mistake tests are skipped and the choice is recorded in the command's output, while the hard
bounds stay (a temperature outside :data:`TEMP_HARD_RANGE_C`, a value beyond a reader's limit).
"""
from __future__ import annotations

import numpy as np

from .io import InputError

UNITS_CHECK = "check"
UNITS_AS_WRITTEN = "as-written"
UNITS_CHOICES = (UNITS_CHECK, UNITS_AS_WRITTEN)

TEMP_HARD_RANGE_C = (-40.0, 80.0)
"""A machine or room temperature outside this is refused even with ``--units as-written``."""
TEMP_PLAUSIBLE_C = (0.0, 45.0)
"""A precision machine tool and its hall are at 15–25 °C; structures near a spindle reach ~40 °C.
Above 45 °C a temperature column is far likelier °F (45 °F = 7.2 °C: every shop temperature above
7.2 °C written in °F lands above 45) or kelvin; below 0 °C no such machine works."""
FAHRENHEIT_RANGE = (45.0, 122.0)   # °F of 7 … 50 °C, named as the likely mistake
KELVIN_RANGE = (250.0, 330.0)      # K of −23 … 57 °C, named as the likely mistake

METRE_REACH = 1.5e-3
"""Path points all within this share of the stroke's larger end (|lo| or |hi|) of zero, while 1000× them
lie in the stroke: the X/Z columns are metres (a tool path in mm that never leaves the first 0.3 mm of a 200 mm
stroke is not a path)."""
MIN_TARGET_EXTENT_MM = 5e-3
"""A path of at least two distinct WCS targets spanning less than 5 μm in every coordinate is metres
(a real path moves further than a tracker's noise)."""
LENGTH_UNITS = (("metres", 1e-3), ("centimetres", 0.1), ("inches", 1 / 25.4), ("micrometres", 1e3))
"""(name, length in that unit of 1 mm): a measured/nominal ratio near the factor names the unit."""
LENGTH_RATIO_BAND = (0.8, 1.25)
UNIT_MIN_POINTS = 10      # below this a column's span says nothing about its unit
METRE_SPAN_FRACTION = 1 / 200  # an X/Z column spanning less than this share of its stroke ...
METRE_MATCH_FRACTION = 1 / 4   # ... while 1000x its span reaches this share is in metres
RADIAN_MIN_SPAN = 1.5 * np.pi  # an A column within ±2π spanning at least three quarters of a turn of radians
# (π, half a turn, also caught a check set measured in degrees over a small A range such as 0–6°)
DEGREE_GRID_DEG = 0.5          # A values that all lie on a 0.5° grid are degrees (a grid in radians does not)


def length_unit_guess(ratio: float) -> str:
    """The length unit a measured/nominal size ratio (1 for mm) points at, as a message tail, or ""."""
    for name, f in LENGTH_UNITS:
        if LENGTH_RATIO_BAND[0] < ratio / f < LENGTH_RATIO_BAND[1]:
            return f"; this looks like {name} (multiply by {1 / f:g} to get mm)"
    return ""


def temperature_mistake(temp_c, units: str = UNITS_CHECK) -> tuple[int, str] | None:
    """``(index, message)`` of the first temperature (°C, shape (n,)) whose unit does not fit, or None."""
    t = np.asarray(temp_c, dtype=float).reshape(-1)
    lo, hi = TEMP_PLAUSIBLE_C if units == UNITS_CHECK else TEMP_HARD_RANGE_C
    bad = np.flatnonzero((t < lo) | (t > hi))
    if not bad.size:
        return None
    k = int(bad[0])
    v = float(t[k])
    if KELVIN_RANGE[0] <= v <= KELVIN_RANGE[1]:
        hint = f"kelvin? ({v:g} K = {v - 273.15:.1f} °C)"
    elif FAHRENHEIT_RANGE[0] <= v <= FAHRENHEIT_RANGE[1]:
        hint = f"°F? ({v:g} °F = {(v - 32) / 1.8:.1f} °C)"
    else:
        hint = "kelvin, °F or a typing mistake?"
    return k, f"{v:g} °C is outside {lo:g} … {hi:g} °C: {hint}"


def chain_axes_mistake(axes, machine, coverage: str = "path") -> tuple[int, int, str] | None:
    """The likely unit mistake in the axis columns of a machine-tool chain (``axes`` (n, k) in
    ``machine.axis_columns`` order), or None: the grinder's tests, per axis of the chain.

    Linear axes (mm): ``coverage="path"`` every value within :data:`METRE_REACH` × the stroke's
    larger end of zero and 1000× them inside the stroke; ``"volume"`` the column's span about
    1/1000 of the stroke and every value within :data:`METRE_REACH` × its larger end. Rotary axes (deg) whose
    stroke spans at least 180°: values within ±2π spanning at least 3π/2 and off a 0.5° grid
    (radians). Needs at least two points (path) or :data:`UNIT_MIN_POINTS` (volume).
    """
    axes = np.asarray(axes, dtype=float)
    if len(axes) < (2 if coverage == "path" else UNIT_MIN_POINTS):
        return None
    for j, ax in enumerate(machine.axes):
        lo, hi = ax.stroke
        v = axes[:, j]
        if ax.kind == "linear":
            stroke = hi - lo
            reach = METRE_REACH * max(abs(lo), abs(hi))
            top = float(np.abs(v).max())
            if coverage == "path":
                hit = 0 < top <= reach and np.all(1000 * v >= lo - 1e-9) and np.all(1000 * v <= hi + 1e-9)
                msg = (f"all within {reach:.3g} mm of zero on a {stroke:g} mm stroke (1000× fits it): "
                       "metres rather than mm?")
            else:
                span = float(np.ptp(v))
                hit = (0 < span <= METRE_SPAN_FRACTION * stroke and span * 1000 >= METRE_MATCH_FRACTION * stroke
                       and top <= reach)
                msg = (f"values span only {span:.4g} mm of the {stroke:g} mm stroke; 1000× that fits it: "
                       "metres rather than mm?")
            if hit:
                return int(np.argmax(np.abs(v))), j, msg
        else:
            span = float(np.ptp(v))
            on_grid = np.allclose(v / DEGREE_GRID_DEG, np.round(v / DEGREE_GRID_DEG), rtol=0, atol=1e-9)
            if (hi - lo >= 180 and np.all(np.abs(v) <= 2 * np.pi + 1e-6) and span >= RADIAN_MIN_SPAN
                    and not on_grid):
                return int(np.argmax(np.abs(v))), j, f"values lie within ±2π and span {span:.4g}: radians rather than degrees?"
    return None


def wcs_box_mm(machine) -> tuple[np.ndarray, np.ndarray]:
    """The WCS bounding box (lo (3,), hi (3,)) mm of the nominal tool points over the machine's
    strokes (5 values per linear axis, 25 per rotary: its corners and the turn)."""
    g = [np.linspace(*a.stroke, 5 if a.kind == "linear" else 25) for a in machine.axes]
    p = machine.nominal(np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, len(g)))
    return p.min(axis=0), p.max(axis=0)


def targets_mistake(targets_mm, machine) -> tuple[int, int, str] | None:
    """``(row index, column index, message)`` when WCS targets (n, 3) mm are metres, or None: every
    coordinate within :data:`METRE_REACH` of the WCS box's far extent of zero and 1000× them inside
    the box (a real path does not stay within a few tenths of a mm of the WCS origin), or — without a
    machine to size it — a path of distinct targets spanning less than :data:`MIN_TARGET_EXTENT_MM`."""
    p = np.asarray(targets_mm, dtype=float)
    if len(p) < 2 or not np.abs(p).max() > 0:
        return None
    if machine is not None:
        lo, hi = wcs_box_mm(machine)
        reach = METRE_REACH * float(np.abs(np.concatenate([lo, hi])).max())
        slack = 0.05 * (hi - lo)
        if np.abs(p).max() <= reach and np.all(1000 * p >= lo - slack) and np.all(1000 * p <= hi + slack):
            k, j = np.unravel_index(int(np.argmax(np.abs(p))), p.shape)
            return int(k), int(j), (f"all within {reach:.3g} mm of the WCS origin while the machine reaches "
                                    f"{reach / METRE_REACH:.4g} mm (1000× fits it): metres rather than mm?")
        return None
    span = np.ptp(p, axis=0)
    if span.max() > 0 and span.max() < MIN_TARGET_EXTENT_MM:
        j = int(np.argmax(span))
        return int(np.argmax(np.abs(p[:, j]))), j, (f"the whole path spans only {span.max():.3g} mm: metres "
                                                    "rather than mm?")
    return None


def _fail(path, rows, k, column, msg, option):
    row = f"row {int(rows[k])}, " if rows is not None else ""
    tail = f" (if not, {option} {UNITS_AS_WRITTEN})" if option else ""
    return InputError(f"{path}: {row}column '{column}': units do not fit: {msg}{tail}")


def check_units(path, rows=None, *, machine=None, axes=None, axes_columns=("x_mm", "z_mm", "a_deg"),
                coverage: str = "path", targets=None, target_columns=("px_mm", "py_mm", "pz_mm"),
                temps=None, units: str = UNITS_CHECK, option: str | None = None) -> None:
    """The one unit check every reader calls; raises :class:`InputError` (file, row, column, the
    likely mistake) for the first column whose unit does not fit.

    ``rows`` (n,): the file row of each point (None: no rows to name). ``axes`` (n, 3) with
    ``machine`` (a machine-tool chain, the grinder among them: (n, k) in its ``axis_columns``,
    :func:`chain_axes_mistake`): ``coverage="volume"`` for data that covers the machine's volume (check
    measurements, feature points), ``"path"`` for a tool path or a set of points. ``targets`` (n, 3) mm WCS
    (:func:`targets_mistake`, sized by ``machine`` when given). ``temps``:
    ``{column: (n,) °C}``. ``units``: see the module doc; ``option``: the command's option that
    overrides (``"--units"``), named in the message (None: the command has none).
    """
    if units not in UNITS_CHOICES:
        raise ValueError(f"Expected units in {UNITS_CHOICES}, got {units!r}")
    for column, t in (temps or {}).items():
        m = temperature_mistake(t, units)
        if m is not None:
            raise _fail(path, rows, m[0], column, m[1], option)
    if units == UNITS_AS_WRITTEN:
        return
    if axes is not None:
        if coverage not in ("volume", "path"):
            raise ValueError(f"Expected coverage 'volume' or 'path', got {coverage!r}")
        m = chain_axes_mistake(axes, machine, coverage)
        if m is not None:
            cols = machine.axis_columns if tuple(axes_columns) == ("x_mm", "z_mm", "a_deg") else axes_columns
            raise _fail(path, rows, m[0], cols[m[1]], m[2], option)
    if targets is not None:
        m = targets_mistake(targets, machine)
        if m is not None:
            raise _fail(path, rows, m[0], target_columns[m[1]], m[2], option)
