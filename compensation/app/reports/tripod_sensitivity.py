"""The tripod's error-sensitivity figure (``volcomp interpolate --sensitivity-plot``)."""
from __future__ import annotations

import io
from pathlib import Path

from errormap.pkm.machine_file import PKM

from ..families import family_of
from .figures import pyplot


def plot_tripod_sensitivity(machine: PKM, out_png, **study_kw) -> dict:
    """Write a PNG of the tripod's error sensitivity ``K = ||A^-1||_inf`` (tripod-3tpt paper) and return its data.

    Left: ``K`` against the size ratio ``lambda = l / c`` at the axis and at an offset. Right: ``K`` over a
    vertical section of the workspace, horizontal distance from the axis against the distance of the
    moving platform from the fixed platform (blank where a leg leaves its range). The data are
    :func:`errormap.pkm.tripod.sensitivity_study` (``study_kw`` go to it); the PNG is written atomically.
    """
    plt = pyplot()

    from errormap.io import atomic_write
    from errormap.pkm.tripod import sensitivity_study

    if not family_of(machine).facts.sensitivity_study:
        raise ValueError(f"{machine.path}: the sensitivity plot is for a tripod machine file, got kind {machine.kind!r}")
    st = sensitivity_study(machine, **study_kw)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for off, K in zip(st["offsets_xy_mm"], st["K_lambda"]):
        a1.plot(st["lambdas"], K, "-", label=f"platform at x, y = {off[0]:g}, {off[1]:g} mm")
    a1.set_xlabel("size ratio lambda = l / c")
    a1.set_ylabel("K = ||A^-1||_inf (position error per leg error)")
    a1.set_title(f"K grows with lambda (c = R - r = {st['c_mm']:g} mm)")
    a1.grid(True, alpha=0.3)
    a1.legend(fontsize=8)
    im = a2.pcolormesh(st["radial_mm"], st["heights_mm"], st["K_map"].T, shading="auto", cmap="viridis")
    fig.colorbar(im, ax=a2, label="K")
    a2.set_xlabel(f"horizontal distance from the axis (mm, azimuth {st['azimuth_deg']:g} deg)")
    a2.set_ylabel("distance from the fixed platform (mm)")
    a2.set_title("K over the workspace (blank: leg out of range)")
    fig.suptitle(f"{machine.name}: error sensitivity")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    with atomic_write(out_png, "wb") as fh:
        fh.write(buf.getvalue())
    return {**st, "path": Path(out_png)}
