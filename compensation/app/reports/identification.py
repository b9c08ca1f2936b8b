"""What ``volcomp identify`` shows of an identified element set: one figure per axis and the
ISO 230-1 summary lines."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.elements import A_ELEMENTS, ElementSet, X_ELEMENTS, Z_ELEMENTS, element_unit
from errormap.io import atomic_write
from errormap.iso230 import label as iso_label

AXIS_GROUPS = {"X": (X_ELEMENTS, "x_mm", "x (mm)"), "Z": (Z_ELEMENTS, "z_mm", "z (mm)"),
               "A": (A_ELEMENTS, "a_deg", "a (deg)")}


def plot_elements(elements: ElementSet, prefix, truth: ElementSet | None = None) -> list[Path]:
    """One figure per axis (six elements each, the constants in the title), truth dashed when given.

    Written atomically as ``PREFIX_X.png``, ``PREFIX_Z.png``, ``PREFIX_A.png``; returns the paths.
    The caller passes the truth in the identified gauge and squareness split
    (:func:`compensation.app.workflows.identification.truth_in_gauge`), so like is compared with like.
    """
    from matplotlib.figure import Figure  # Agg canvas, no pyplot state
    c = elements.constants
    out = []
    for ax, (names, key, label) in AXIS_GROUPS.items():
        fig = Figure(figsize=(11, 6.5), layout="constrained")
        axs = fig.subplots(2, 3)
        st = elements.stations[key]
        grid = np.linspace(st[0], st[-1], 400)
        pts = np.zeros((grid.size, 3))
        pts[:, ["x_mm", "z_mm", "a_deg"].index(key)] = grid
        v = elements.values(pts)
        vt = truth.values(pts) if truth is not None else None
        from errormap.elements import ELEMENT_NAMES
        for a, name in zip(axs.ravel(), names):
            j = ELEMENT_NAMES.index(name)
            a.plot(grid, v[:, j], "C0-", label="identified")
            a.plot(st, elements.functions[name], "C0o", ms=3)
            if vt is not None:
                a.plot(grid, vt[:, j], "k--", lw=1, label="truth")
            a.set_title(f"{iso_label(name)} ({'μm' if element_unit(name) == 'um' else 'μrad'})")
            a.set_xlabel(label)
            a.grid(alpha=0.3)
        axs[0, 0].legend(fontsize=8)
        if ax == "A":
            extra = (f"dy_oa {c['dy_oa']:.3f} μm, dz_oa {c['dz_oa']:.3f} μm, "
                     f"ey_oa {c['ey_oa']:.3f} μrad, ez_oa {c['ez_oa']:.3f} μrad")
        else:
            extra = f"s_xz {c['s_xz']:.3f} μrad"
        fig.suptitle(f"identified {ax}-axis elements ({extra})")
        path = Path(f"{prefix}_{ax}.png")
        with atomic_write(path, "wb") as fh:
            fig.savefig(fh, format="png", dpi=110)
        out.append(path)
    return out


def iso_summary_lines(elements: ElementSet) -> list[str]:
    """The 23 elements with their ISO 230-1 names (docs/export.md) and their largest magnitude.

    The ISO names hold in the project's frames: Z's lateral pairs and A's radial/tilt pairs
    are turned (θ1, a) before they equal the ISO components (``errormap.iso230.to_iso``).
    """
    from errormap.elements import CONSTANT_ELEMENTS, FUNCTION_ELEMENTS
    lines = ["element (ISO 230-1)    max |value|"]
    for k in FUNCTION_ELEMENTS:
        lines.append(f"  {iso_label(k):<20} {np.abs(elements.functions[k]).max():9.3f} {element_unit(k)}")
    for k in CONSTANT_ELEMENTS:
        lines.append(f"  {iso_label(k):<20} {elements.constants[k]:9.3f} {element_unit(k)} (constant)")
    return lines
