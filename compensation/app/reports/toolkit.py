"""One toolkit for every HTML page volcomp writes (compare/demo, diagnose, drift, calibrate, interpolate, benchmark).

A page is a jinja2 template in ``templates/`` that extends ``base.html`` (title, banner naming the
residual the page shows, the section navigation, one stylesheet). Everything a template prints is
HTML-escaped (autoescape is on for every template); only the toolkit's own objects —
:class:`Table`, :class:`Figure` and :class:`markupsafe.Markup` built with ``Markup(...).format`` —
carry markup through.

Decisions, the same on every page:

* **Self-contained.** The stylesheet ``templates/style.css`` is inlined in a ``<style>`` element and
  figures are PNG embedded as ``data:image/png;base64`` URIs: a page opened from disk, mailed, or
  logged to MLflow as one artifact shows everything, offline. (A page may also save its PNGs beside
  it, e.g. ``volcomp calibrate``; the page itself never depends on them.)
* **Numbers** through :func:`num` (significant digits, no ``1.23e+03`` for ordinary magnitudes, "—"
  for a missing value) and :func:`qty` / :func:`um` with their unit (``1.23 μm``; never "um").
  Table headers carry the unit once: ``"RMS (μm)"``.
* **Navigation** is built from the page's own ``<h2 id="...">`` headings (in-page anchors only).

Usage (``reports/interpolation.py`` is the smallest complete page)::

    from .toolkit import Table, figure, kv_table, render_page, write_page
    page = render_page("interpolate.html", title=f"PKM leg-command program: {machine.name}",
                       setting=kv_table({"steps": n}), legs=Table(["leg", "max (mm)"], rows),
                       figures=[figure(fig, "leg commands", "caption")], ...)
    write_page(out / "report.html", page)

Adding a page: copy ``templates/interpolate.html`` (extends ``base.html``: blocks ``kind``,
``banner`` — say which residual the page shows —, ``content`` with ``<h2 id=...>`` sections) and
``reports/interpolation.py`` (figures with :func:`figure`, tables with :class:`Table`, numbers
raw — the templates format them with the ``num``/``um``/``qty`` filters — then :func:`render_page`
and :func:`write_page`); the workflow or command calls it; add the kind to
``tests/test_report_pages.py``.
"""
from __future__ import annotations

import base64
import functools
import math
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Iterable, Sequence

import jinja2
from markupsafe import Markup

MISSING = "—"
"""Shown for a value that is absent (None, NaN)."""
DEFAULT_DIGITS = 3
"""Significant digits of a number on a page unless the caller asks for more."""
DEFAULT_DPI = 100
"""Resolution of embedded figures: about 1000 px for a 10-inch figure, sharp on screen, small files."""
NAV_MARK = "<!--volcomp:nav-->"
_PACKAGE = __name__.rpartition(".")[0]          # compensation.app.reports
_HEADING = re.compile(r'<h2 id="([A-Za-z][\w-]*)"[^>]*>(.*?)</h2>', re.S)

__all__ = ["Figure", "Markup", "Table", "environment", "figure", "kv_table", "num", "pct", "qty", "render_page",
           "stylesheet", "um", "unit_text", "write_page"]


# -- numbers -------------------------------------------------------------------------------------
def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def num(v, digits: int = DEFAULT_DIGITS) -> str:
    """A number for a page: ``digits`` significant digits, fixed notation for 1e-4 ≤ |v| < 1e6.

    ``None``/NaN → "—", booleans → "yes"/"no", integers exactly, infinities as "∞"; other values
    (strings) as they are. ``num(1234.5) == "1235"``, ``num(0.012345) == "0.0123"``,
    ``num(3.2e-9) == "3.20e-09"``.
    """
    if _missing(v):
        return MISSING
    kind = getattr(getattr(v, "dtype", None), "kind", "")
    if isinstance(v, bool) or kind == "b":
        return "yes" if v else "no"
    if isinstance(v, int) or kind in ("i", "u"):
        return str(int(v))
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    if math.isnan(x):
        return MISSING
    if math.isinf(x):
        return "∞" if x > 0 else "−∞"
    if x == 0:
        return "0"
    e = math.floor(math.log10(abs(x)))
    if -4 <= e < 6:
        decimals = max(0, digits - 1 - e)
        s = f"{x:.{decimals}f}"
        # rounding may carry into a new digit (9.996 → "10.00"): drop the extra decimal
        if decimals and len(s.lstrip("-").replace(".", "").lstrip("0")) > digits:
            s = f"{x:.{decimals - 1}f}"
        return s
    return f"{x:.{max(digits - 1, 0)}e}"


def qty(v, unit: str, digits: int = DEFAULT_DIGITS) -> str:
    """A number with its unit, ``qty(1.234, "μm") == "1.23 μm"``; "—" (no unit) when missing."""
    s = num(v, digits)
    return s if s == MISSING or not unit else f"{s} {unit_text(unit)}"


def um(v, digits: int = DEFAULT_DIGITS) -> str:
    """A length in micrometres: ``um(0.5) == "0.500 μm"``."""
    return qty(v, "μm", digits)


_ASCII_MICRO = re.compile(r"(?<![A-Za-z])u(m|rad|s)(?![A-Za-z])")


def unit_text(unit: str) -> str:
    """A unit as a page shows it: the file/JSON spelling ``um``, ``urad``, ``um/(mm·°C)`` with the micro
    sign (``μm``, ``μrad``, ``μm/(mm·°C)``); other units unchanged."""
    return _ASCII_MICRO.sub(r"μ\1", unit)


def pct(v, digits: int = DEFAULT_DIGITS) -> str:
    """A fraction as a percentage: ``pct(0.1234) == "12.3 %"``."""
    return MISSING if _missing(v) else qty(100.0 * float(v), "%", digits)


# -- tables --------------------------------------------------------------------------------------
@dataclass
class Table:
    """A table of values: header (k,) and rows (n, k) of cells.

    A cell is formatted by ``formats[column]`` when given (a callable, or an int = significant
    digits), else by :func:`num` with ``digits`` for numbers; strings are escaped, :class:`Markup`
    kept, lists joined with ", ". ``row_classes`` (n,) gives each row a CSS class (e.g. the path
    of a benchmark row); ``left`` is how many leading columns hold labels (left-aligned).
    """

    header: Sequence[str]
    rows: Sequence[Sequence]
    digits: int = DEFAULT_DIGITS
    formats: dict | None = None
    row_classes: Sequence[str] | None = None
    left: int = 1
    caption: str | None = None
    css_class: str = ""

    def cell(self, j: int, v) -> str:
        f = (self.formats or {}).get(j)
        if isinstance(v, Markup):
            return v
        if callable(f):
            return f(v)
        if isinstance(v, (list, tuple)):
            return ", ".join(str(x) for x in v) or "none"
        if isinstance(v, str):
            return v
        return num(v, f if isinstance(f, int) else self.digits)

    def __len__(self) -> int:
        """The number of rows (a table without rows is false: ``{% if table %}``)."""
        return len(self.rows)

    def body(self) -> list[tuple[str, list]]:
        classes = list(self.row_classes) if self.row_classes is not None else [""] * len(self.rows)
        return [(c, [self.cell(j, v) for j, v in enumerate(r)]) for c, r in zip(classes, self.rows)]

    def __html__(self) -> str:
        return environment().get_template("_table.html").render(t=self)


def kv_table(items: dict | Iterable[tuple], digits: int = DEFAULT_DIGITS) -> Table:
    """A two-column table of settings: key, value."""
    pairs = list(items.items()) if isinstance(items, dict) else list(items)
    return Table(["", ""], [[str(k), v] for k, v in pairs], digits=digits, css_class="kv")


# -- figures -------------------------------------------------------------------------------------
@dataclass
class Figure:
    """A PNG figure embedded in the page as a data URI, with its alt text and optional caption."""

    png: bytes
    alt: str
    caption: str | None = None

    @property
    def data_uri(self) -> str:
        return "data:image/png;base64," + base64.b64encode(self.png).decode("ascii")

    @classmethod
    def from_png(cls, png: bytes | str | Path, alt: str, caption: str | None = None) -> "Figure":
        """From PNG bytes or a PNG file."""
        data = png if isinstance(png, bytes) else Path(png).read_bytes()
        if data[:8] != b"\x89PNG\r\n\x1a\n":
            raise ValueError(f"Expected PNG data for figure {alt!r}, got {data[:8]!r}")
        return cls(data, alt, caption)

    def save(self, path) -> Path:
        """Write the PNG beside the page too (atomically)."""
        from errormap.io import atomic_write
        with atomic_write(path, "wb") as fh:
            fh.write(self.png)
        return Path(path)

    def __html__(self) -> str:
        return environment().get_template("_figure.html").render(f=self)


def figure(fig, alt: str, caption: str | None = None, dpi: int = DEFAULT_DPI, tight_layout: bool = False) -> Figure:
    """A matplotlib figure as an embedded :class:`Figure` (the matplotlib figure is closed); ``tight_layout``: laid
    out by ``fig.tight_layout()`` instead of trimmed (:func:`.figures.png_bytes`)."""
    from .figures import png_bytes
    return Figure(png_bytes(fig, dpi, tight_layout), alt, caption)


# -- pages ---------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def stylesheet() -> str:
    """The one stylesheet of every page (``templates/style.css``)."""
    return resources.files(_PACKAGE).joinpath("templates", "style.css").read_text(encoding="utf-8")


@functools.lru_cache(maxsize=1)
def environment() -> jinja2.Environment:
    """The jinja2 environment of the report templates: autoescape on, undefined names are errors."""
    env = jinja2.Environment(loader=jinja2.PackageLoader(_PACKAGE, "templates"), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
                             keep_trailing_newline=True)
    env.filters.update(num=num, qty=qty, um=um, pct=pct, unit=unit_text)
    return env


def render_page(template: str | jinja2.Template, *, title: str, **context) -> str:
    """Render ``templates/<template>`` (which extends ``base.html``) to one self-contained page.

    ``template`` is a file name in ``templates/`` (or a template of :func:`environment`);
    ``context`` goes to it as it is; ``title`` names the page. The navigation lists the page's
    ``<h2 id=...>`` sections.
    """
    from errormap import __version__
    env = environment()
    tmpl = env.get_template(template) if isinstance(template, str) else template
    text = tmpl.render(title=title, css=Markup(stylesheet()), version=__version__, **context)
    nav = [(m.group(1), Markup(m.group(2)).striptags()) for m in _HEADING.finditer(text)]
    return text.replace(NAV_MARK, env.get_template("_nav.html").render(items=nav) if len(nav) > 1 else "", 1)


def write_page(path, text: str) -> Path:
    """Write a page atomically (temporary file beside it, then rename); returns the path."""
    from errormap.io import atomic_write
    path = Path(path)
    with atomic_write(path, "w", encoding="utf-8") as fh:
        fh.write(text)
    return path

