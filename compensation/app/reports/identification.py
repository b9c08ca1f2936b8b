"""What ``volcomp identify`` shows of an identified element set: one figure per axis and the
ISO 230-1 summary lines."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.chain_elements import ChainElementSet
from errormap.elements import A_ELEMENTS, X_ELEMENTS, Z_ELEMENTS, element_unit
from errormap.io import atomic_write
from errormap.iso230 import label as iso_label

AXIS_GROUPS = {"X": (X_ELEMENTS, "x_mm", "x (mm)"), "Z": (Z_ELEMENTS, "z_mm", "z (mm)"),
               "A": (A_ELEMENTS, "a_deg", "a (deg)")}


def axis_figure(path, title: str, xlabel: str, grid, curves) -> Path:
    """One figure of an axis' elements, written atomically to ``path`` (PNG): ``curves`` is a list of
    ``(title, values on grid (g,), (stations, station values), truth on grid (g,) or None)``, one panel each
    (three columns), truth dashed. The grinder's and a chain's plots are both this figure."""
    from matplotlib.figure import Figure  # Agg canvas, no pyplot state
    rows = int(np.ceil(len(curves) / 3))
    fig = Figure(figsize=(11, 3.25 * rows), layout="constrained")
    axs = np.atleast_1d(fig.subplots(rows, 3)).ravel()
    for a, (name, v, (st, sv), vt) in zip(axs, curves):
        a.plot(grid, v, "C0-", label="identified")
        a.plot(st, sv, "C0o", ms=3)
        if vt is not None:
            a.plot(grid, vt, "k--", lw=1, label="truth")
        a.set_title(name)
        a.set_xlabel(xlabel)
        a.grid(alpha=0.3)
    for a in axs[len(curves):]:
        a.set_visible(False)
    axs[0].legend(fontsize=8)
    fig.suptitle(title)
    path = Path(path)
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    return path


def _unit_label(unit: str) -> str:
    return "μm" if unit == "um" else "μrad"


def plot_elements(elements: ChainElementSet, prefix, truth: ChainElementSet | None = None) -> list[Path]:
    """One figure per axis (six elements each, the constants in the title), truth dashed when given.

    Written atomically as ``PREFIX_X.png``, ``PREFIX_Z.png``, ``PREFIX_A.png``; returns the paths.
    The caller passes the truth in the identified gauge and squareness split
    (:func:`compensation.app.workflows.measurement.truth_in_gauge`), so like is compared with like.
    """
    from errormap.elements import ELEMENT_NAMES
    c = elements.constants
    out = []
    for ax, (names, key, label) in AXIS_GROUPS.items():
        st = elements.stations[key]
        grid = np.linspace(st[0], st[-1], 400)
        pts = np.zeros((grid.size, 3))
        pts[:, ["x_mm", "z_mm", "a_deg"].index(key)] = grid
        v = elements.values(pts)
        vt = truth.values(pts) if truth is not None else None
        curves = [(f"{iso_label(n)} ({_unit_label(element_unit(n))})", v[:, ELEMENT_NAMES.index(n)],
                   (st, elements.functions[n]), None if vt is None else vt[:, ELEMENT_NAMES.index(n)]) for n in names]
        if ax == "A":
            extra = (f"dy_oa {c['dy_oa']:.3f} μm, dz_oa {c['dz_oa']:.3f} μm, "
                     f"ey_oa {c['ey_oa']:.3f} μrad, ez_oa {c['ez_oa']:.3f} μrad")
        else:
            extra = f"s_xz {c['s_xz']:.3f} μrad"
        out.append(axis_figure(f"{prefix}_{ax}.png", f"identified {ax}-axis elements ({extra})", label, grid, curves))
    return out


def plot_chain_elements(elements, prefix, truth=None) -> list[Path]:
    """A machine-tool chain's :func:`plot_elements`: one figure per swept axis ``w`` (``PREFIX_<W>.png``), a panel
    per component error of that axis (ISO 230 name), the constants in the title; ``truth`` (a
    :class:`errormap.chain_elements.ChainElementSet` in the identified gauge) dashed. Returns the paths."""
    from errormap.chain_sweeps import swept_words
    m = elements.machine
    iso = dict(zip(m.slot_names, m.iso_names))
    unit = {s.name: s.unit for s in m.slots}
    owner = {s.name: s.axis for s in m.slots}
    idx = {n: k for k, n in enumerate(m.slot_names)}
    out = []
    for w in swept_words(m):
        consts = ", ".join(f"{n} {v:.3f} {_unit_label(unit[n])}" for n, v in elements.constants.items()
                           if owner.get(n) == w)
        k = next(j for j, a in enumerate(m.axes) if a.word == w)
        col = m.axes[k].column
        st = elements.stations[col]
        grid = np.linspace(st[0], st[-1], 400)
        pts = np.tile(m.stroke_lo, (grid.size, 1))
        pts[:, k] = grid
        v = elements.values(pts)
        vt = truth.values(pts) if truth is not None else None
        curves = [(f"{iso[n]} ({_unit_label(unit[n])})", v[:, idx[n]], (st, elements.functions[n]),
                   None if vt is None else vt[:, idx[n]]) for n in m.slots_of(w)]
        label = f"{w.lower()} ({m.axes[k].unit})"
        out.append(axis_figure(f"{prefix}_{w}.png", f"identified {w}-axis elements of {m.name}"
                               + (f" ({consts})" if consts else ""), label, grid, curves))
    return out


def iso_summary_lines(elements: ChainElementSet) -> list[str]:
    """The 23 elements with their ISO 230-1 names (docs/how-to/export-to-controller.md) and their largest magnitude.

    The ISO names hold in the project's frames: Z's lateral pairs and A's radial/tilt pairs
    are turned (θ1, a) before they equal the ISO components (``errormap.iso230.axis_to_mcs``).
    """
    from errormap.elements import CONSTANT_ELEMENTS, FUNCTION_ELEMENTS
    lines = ["element (ISO 230-1)    max |value|"]
    for k in FUNCTION_ELEMENTS:
        lines.append(f"  {iso_label(k):<20} {np.abs(elements.functions[k]).max():9.3f} {element_unit(k)}")
    for k in CONSTANT_ELEMENTS:
        lines.append(f"  {iso_label(k):<20} {elements.constants[k]:9.3f} {element_unit(k)} (constant)")
    return lines
