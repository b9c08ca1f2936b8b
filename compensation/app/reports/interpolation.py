"""The PKM leg-command program page (``interpolate.html``), for ``volcomp interpolate --report FILE``.

Shows the program, not a residual: the setting, per leg the range used against the machine file's
limits and the largest step, the correction a calibration adds to the nominal commands, and figures
of the path, the leg lengths and the increments (plus the tripod's sensitivity plot when written).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .figures import pyplot
from .toolkit import Figure, Table, figure, kv_table, num, render_page, write_page

FIG_DPI = 100


def _figures(prog, nominal_legs_mm) -> list[Figure]:
    plt = pyplot()
    tip = prog.path.tip_mm
    out = []
    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    for ax, (i, j, a, b) in zip(axs, ((0, 1, "x", "y"), (0, 2, "x", "z"))):
        ax.plot(tip[:, i], tip[:, j], "-", lw=0.8)
        ax.plot(tip[:1, i], tip[:1, j], "o", ms=5, color="tab:green", label="start")
        ax.set_xlabel(f"{a} (mm)")
        ax.set_ylabel(f"{b} (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    axs[0].legend(fontsize=8)
    out.append(figure(fig, "tool path", "Tool tip of every interpolation step, projected on x–y and x–z.", FIG_DPI,
                      tight_layout=True))
    k = prog.legs_mm.shape[1]
    fig, axs = plt.subplots(1, 2, figsize=(10, 3.6))
    steps = np.arange(len(prog.q))
    for i in range(k):
        axs[0].plot(steps, prog.legs_mm[:, i] - prog.legs_mm[0, i], lw=0.8, label=f"leg {i + 1}")
        axs[1].plot(steps, 1e3 * prog.increments_mm[:, i], lw=0.6, label=f"leg {i + 1}")
    axs[0].set_ylabel("leg length − first step (mm)")
    axs[1].set_ylabel("increment per step (μm)")
    for ax in axs:
        ax.set_xlabel("interpolation step")
        ax.grid(True, alpha=0.3)
    axs[1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    out.append(figure(fig, "leg commands", "Leg lengths (relative to the first step) and the leg increments of "
                      "each interpolation period.", FIG_DPI, tight_layout=True))
    if nominal_legs_mm is not None:
        fig, ax = plt.subplots(figsize=(10, 3.4))
        for i in range(k):
            ax.plot(steps, 1e3 * (prog.legs_mm[:, i] - nominal_legs_mm[:, i]), lw=0.8, label=f"leg {i + 1}")
        ax.set_xlabel("interpolation step")
        ax.set_ylabel("correction (μm)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
        out.append(figure(fig, "corrections", "Compensated minus nominal leg length per step.", FIG_DPI))
    return out


def interpolation_page(prog, machine, setting: dict, nominal_legs_mm=None, sensitivity_png=None) -> str:
    """The page of a :class:`~compensation.pkm_interpolation.LegProgram` on ``machine``.

    ``setting``: what the command was given (shown as it is); ``nominal_legs_mm`` (n, k): the
    uncompensated legs of the same path, when the program is compensated; ``sensitivity_png``: a
    tripod sensitivity PNG to embed.
    """
    legs = prog.legs_mm
    k = legs.shape[1]
    lo, hi = np.broadcast_to(machine.leg_min_mm, (k,)), np.broadcast_to(machine.leg_max_mm, (k,))
    header = ["leg", "min (mm)", "max (mm)", "limits (mm)", "smallest margin (mm)", "largest step (μm)"]
    rows = []
    for i in range(k):
        margin = min(legs[:, i].min() - lo[i], hi[i] - legs[:, i].max())
        row = [f"leg {i + 1}", legs[:, i].min(), legs[:, i].max(), f"{num(lo[i], 5)} … {num(hi[i], 5)}", margin,
               1e3 * np.abs(prog.increments_mm[:, i]).max()]
        if nominal_legs_mm is not None:
            corr = 1e3 * (legs[:, i] - nominal_legs_mm[:, i])
            row += [np.abs(corr).max(), float(np.sqrt(np.mean(corr ** 2)))]
        rows.append(row)
    if nominal_legs_mm is not None:
        header += ["max |correction| (μm)", "RMS correction (μm)"]
    figures = _figures(prog, nominal_legs_mm)
    if sensitivity_png is not None:
        figures.append(Figure.from_png(sensitivity_png, "tripod error sensitivity",
                                       "Error sensitivity K = ‖A⁻¹‖∞ against the size ratio and over the workspace."))
    return render_page("interpolate.html", title=f"PKM leg-command program: {machine.name}",
                       path_name=prog.path.name or "(waypoints)", compensated=prog.compensated,
                       setting=kv_table(setting), legs=Table(header, rows, formats={1: 6, 2: 6, 4: 4}),
                       figures=figures)


def write_interpolation_report(path, prog, machine, setting: dict, nominal_legs_mm=None, sensitivity_png=None) -> Path:
    """Write :func:`interpolation_page` to ``path`` (atomically)."""
    return write_page(path, interpolation_page(prog, machine, setting, nominal_legs_mm, sensitivity_png))
