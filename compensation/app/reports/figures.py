"""Figures for the self-contained HTML reports: matplotlib on the Agg backend, PNG inlined as base64."""
from __future__ import annotations

import base64
import io


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def png_base64(fig, dpi: int = 100) -> str:
    """Render ``fig`` to PNG, close it, and return the base64 text for a ``data:image/png`` URI."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    pyplot().close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def img_tag(fig, alt: str = "", dpi: int = 100) -> str:
    """An ``<img>`` element with ``fig`` inlined."""
    return f"<img alt='{alt}' src='data:image/png;base64,{png_base64(fig, dpi)}'>"
