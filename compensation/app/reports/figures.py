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


def png_bytes(fig, dpi: int = 100) -> bytes:
    """Render ``fig`` to PNG (tight bounding box), close it, and return the bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    pyplot().close(fig)
    return buf.getvalue()
