"""The names of the grinder's 23 geometric error elements (the slots of its chain file,
:func:`errormap.grinder_file.parse_grinder_file`) and the profile checks every element set shares.

Translations in μm, angles in μrad. The 18 axis-motion elements are functions of their own
axis position (X, Z, A); the 5 A-line and squareness elements are constants. Their values, the
element-set file and its interpolation are those of every machine tool:
:class:`errormap.chain_elements.ChainElementSet` (the grinder's element-set files load unchanged
against its chain).
"""
from __future__ import annotations

import numpy as np

X_ELEMENTS = ("dx_x", "dy_x", "dz_x", "ex_x", "ey_x", "ez_x")
Z_ELEMENTS = ("dx_z", "dy_z", "dz_z", "ex_z", "ey_z", "ez_z")
A_ELEMENTS = ("dx_a", "dy_a", "dz_a", "ex_a", "ey_a", "ez_a")
FUNCTION_ELEMENTS = X_ELEMENTS + Z_ELEMENTS + A_ELEMENTS
CONSTANT_ELEMENTS = ("dy_oa", "dz_oa", "ey_oa", "ez_oa", "s_xz")
ELEMENT_NAMES = FUNCTION_ELEMENTS + CONSTANT_ELEMENTS
"""The 23 elements, in the grinder chain's slot order (the columns of its element values and Jacobian)."""

AXIS_OF = {**{k: "x_mm" for k in X_ELEMENTS}, **{k: "z_mm" for k in Z_ELEMENTS},
           **{k: "a_deg" for k in A_ELEMENTS}}
IDX = {k: i for i, k in enumerate(ELEMENT_NAMES)}
"""Column of each element in :data:`ELEMENT_NAMES` order (the grinder chain's slot order)."""


def element_unit(name: str) -> str:
    """``"um"`` for translations (names starting with ``d``), ``"urad"`` for angles."""
    if name not in ELEMENT_NAMES:
        raise KeyError(f"Expected one of the 23 element names {ELEMENT_NAMES}, got {name!r}")
    return "um" if name.startswith("d") else "urad"


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
