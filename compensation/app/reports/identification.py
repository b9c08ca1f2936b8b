"""What ``volcomp identify`` shows of an identified element set: one figure per axis and the
ISO 230-1 summary lines."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.chain_elements import ChainElementSet
from errormap.io import atomic_write


def axis_figure(path, title: str, xlabel: str, grid, curves) -> Path:
    """One figure of an axis' elements, written atomically to ``path`` (PNG): ``curves`` is a list of
    ``(title, values on grid (g,), (stations, station values), truth on grid (g,) or None)``, one panel each
    (three columns), truth dashed."""
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


def plot_chain_elements(elements, prefix, truth=None) -> list[Path]:
    """One figure per swept axis ``w`` of a machine tool (``PREFIX_<W>.png``; the grinder: ``PREFIX_X.png``,
    ``PREFIX_Z.png``, ``PREFIX_A.png``), a panel per component error of that axis (ISO 230 name), the constants in
    the title; ``truth`` (a :class:`errormap.chain_elements.ChainElementSet` in the identified gauge and squareness
    split, :func:`compensation.app.workflows.measurement.truth_in_gauge`) dashed. Returns the paths."""
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
    """Every slot of the element set's machine with its ISO 230-1 name (the machine file's ``iso`` of each slot) and
    its largest magnitude over its stations (a constant: its value): the functions first, then the constants.

    The ISO names hold in the chain's frames: an axis' components are turned by its body's nominal rotation
    before they equal the ISO components in the MCS (``errormap.iso230.axis_to_mcs``,
    docs/how-to/export-to-controller.md).
    """
    m = elements.machine
    iso = dict(zip(m.slot_names, m.iso_names))
    lines = ["element (ISO 230-1)    max |value|"]
    for s in (s for s in m.slots if s.is_function):
        lines.append(f"  {f'{s.name} ({iso[s.name]})':<20} {np.abs(elements.functions[s.name]).max():9.3f} {s.unit}")
    for s in (s for s in m.slots if not s.is_function):
        lines.append(f"  {f'{s.name} ({iso[s.name]})':<20} {elements.constants[s.name]:9.3f} {s.unit} (constant)")
    return lines
