"""Validators for machine files (TOML), shared by every machine schema.

The grinder parser (:mod:`errormap.machine`) and the PKM parsers
(:mod:`errormap.pkm.machine_file`) check their sections with these functions. Each takes the
parsed TOML value, the key's dotted name (``where``) and the file ``path``, and raises
:class:`MachineFileError` with one line naming the file and the key, in the form
``"<file>: key '<where>': expected …, got …"`` (pytransform3d's ``check_*`` style).
"""
from __future__ import annotations

import numpy as np

# Largest magnitude of any number in a machine file (mm, deg, leg scale): a kilometre-sized
# machine or a million-degree stroke is a unit or typing mistake, and 1e308 would overflow.
MAX_MACHINE_VALUE = 1e6


class MachineFileError(ValueError):
    """A machine file is malformed; the message names the file and the key."""


def short_repr(v, n: int = 60) -> str:
    """``repr(v)`` cut to ``n`` characters (with the full length named) for error messages."""
    r = repr(v)
    return r if len(r) <= n else r[:n] + f"... ({len(r)} characters)"


def _flat(v):
    if isinstance(v, (list, tuple)):
        for x in v:
            yield from _flat(x)
    else:
        yield v


def check_number(doc: dict, key: str, where: str, path) -> float:
    """``doc[key]`` as a finite float of magnitude ≤ :data:`MAX_MACHINE_VALUE` (booleans refused);
    ``where`` is the section's dotted name (the key is reported as ``where.key``)."""
    if key not in doc:
        raise MachineFileError(f"{path}: missing key '{where}.{key}'")
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MachineFileError(f"{path}: key '{where}.{key}': expected a number, got {short_repr(v)}")
    try:
        f = float(v)
    except OverflowError:  # a TOML integer beyond float range
        f = float("inf")
    if not np.isfinite(f):
        raise MachineFileError(f"{path}: key '{where}.{key}': expected a finite number, got {short_repr(v)}")
    if abs(f) > MAX_MACHINE_VALUE:
        raise MachineFileError(f"{path}: key '{where}.{key}': {f:g} is beyond the plausible magnitude "
                               f"{MAX_MACHINE_VALUE:g} (mm or deg); wrong unit or a typing mistake?")
    return f


def check_table(doc: dict, key: str, path) -> dict:
    """The section ``[key]`` of ``doc``, which must exist and be a table."""
    if key not in doc:
        raise MachineFileError(f"{path}: missing section '[{key}]'")
    if not isinstance(doc[key], dict):
        raise MachineFileError(f"{path}: '{key}': expected a table, got {type(doc[key]).__name__}")
    return doc[key]


def optional_table(doc: dict, key: str, path, default=None):
    """The optional section ``[key]`` of ``doc`` (``default`` when absent), refused when it is not a table."""
    t = doc.get(key, default)
    if t is not None and not isinstance(t, dict):
        raise MachineFileError(f"{path}: '{key}': expected a table")
    return t


def check_known_keys(section: dict, allowed, where: str, path) -> None:
    """Refuse keys of ``section`` outside ``allowed``, naming them as ``where.key``."""
    unknown = sorted(set(section) - set(allowed))
    if unknown:
        raise MachineFileError(f"{path}: unknown key(s) {['%s.%s' % (where, k) for k in unknown]}; allowed: {list(allowed)}")


def check_range(value, where: str, path, angular: bool, what: str) -> tuple[float, float]:
    """A ``[lo, hi]`` range (mm or deg) with hi > lo; an ``angular`` one within ±2π spanning ≥ 1 is refused
    as radians (``what``, e.g. ``"rotary strokes"``, names the range in that message)."""
    lim = check_array(value, (2,), where, path)
    if not lim[1] > lim[0]:
        raise MachineFileError(f"{path}: key '{where}': expected [lo, hi] with hi > lo (a zero or inverted "
                               f"stroke), got {value!r}")
    if angular and np.all(np.abs(lim) <= 2 * np.pi + 1e-9) and lim[1] - lim[0] >= 1.0:
        raise MachineFileError(f"{path}: key '{where}': {value!r} lie within ±2π: radians rather than "
                               f"degrees? ({what} are in deg)")
    return float(lim[0]), float(lim[1])


def check_array(value, shape: tuple, where: str, path) -> np.ndarray:
    """Convert a TOML value to a float array of ``shape`` (``-1`` = any), naming the key on error.

    Every element must be a number (not a boolean) of magnitude at most :data:`MAX_MACHINE_VALUE`.
    """
    want = f"numbers of shape {shape}"
    if not isinstance(value, (list, tuple)) or any(isinstance(x, bool) or not isinstance(x, (int, float))
                                                   for x in _flat(value)):
        raise MachineFileError(f"{path}: key '{where}': expected {want}, got {short_repr(value)}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):  # ragged rows, integers beyond float range
        raise MachineFileError(f"{path}: key '{where}': expected {want}, got {short_repr(value)}") from None
    if arr.ndim != len(shape) or any(s not in (-1, a) for s, a in zip(shape, arr.shape)):
        raise MachineFileError(f"{path}: key '{where}': expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise MachineFileError(f"{path}: key '{where}': expected finite numbers, got {short_repr(value)}")
    if np.any(np.abs(arr) > MAX_MACHINE_VALUE):
        raise MachineFileError(f"{path}: key '{where}': {np.abs(arr).max():g} is beyond the plausible magnitude "
                               f"{MAX_MACHINE_VALUE:g} (mm or deg); wrong unit or a typing mistake?")
    return arr
