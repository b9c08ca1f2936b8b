"""Figures of the HTML reports: matplotlib on the Agg backend, rendered to PNG bytes.

The report toolkit (:mod:`.toolkit`) embeds them in the pages (:func:`.toolkit.figure`).
"""
from __future__ import annotations

import io


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def png_bytes(fig, dpi: int = 100, tight_layout: bool = False) -> bytes:
    """Render ``fig`` to PNG, close it, and return the bytes: trimmed to its tight bounding box, or with
    ``tight_layout`` laid out by ``fig.tight_layout()`` (which keeps every label inside the figure: the trim would draw
    the figure once more to find its box, a third of a many-panel figure's rendering time)."""
    buf = io.BytesIO()
    if tight_layout:
        fig.tight_layout()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches=None if tight_layout else "tight")
    pyplot().close(fig)
    return buf.getvalue()
