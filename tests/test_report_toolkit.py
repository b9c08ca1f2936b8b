"""The report toolkit (compensation.app.reports.toolkit): escaping, numbers with units, tables, figures, layout."""
from __future__ import annotations

import base64
import re

import pytest

from compensation.app.reports import toolkit as rt

HOSTILE = '<script>alert("x")</script> & "M1"'


@pytest.mark.parametrize("value, digits, text", [
    (1.2345, 3, "1.23"), (12.345, 3, "12.3"), (123.45, 3, "123"), (1234.56, 3, "1235"),
    (0.012345, 3, "0.0123"), (0.00012345, 3, "0.000123"), (3.2e-9, 3, "3.20e-09"), (2.5e7, 3, "2.50e+07"),
    (9.996, 3, "10.0"),            # rounding carries into a new digit: still three significant digits
    (0.0, 3, "0"), (-0.5, 2, "-0.50"), (1.2345, 5, "1.2345"), (7, 3, "7"), (True, 3, "yes"),
    (None, 3, "—"), (float("nan"), 3, "—"), (float("inf"), 3, "∞"),
])
def test_num_significant_digits(value, digits, text):
    assert rt.num(value, digits) == text


def test_numpy_scalars_format_like_python_ones():
    np = pytest.importorskip("numpy")
    assert rt.num(np.float32(0.125)) == "0.125" and rt.num(np.int64(12)) == "12" and rt.num(np.bool_(False)) == "no"


def test_quantities_carry_the_micro_sign_never_um():
    assert rt.um(0.5) == "0.500 μm" and rt.qty(2.0, "μrad") == "2.00 μrad" and rt.pct(0.1234) == "12.3 %"
    assert rt.um(None) == "—"     # no unit after a missing value
    # units as files and JSON spell them, shown with the micro sign; other units untouched
    assert rt.qty(3.0, "um") == "3.00 μm" and rt.unit_text("um/(mm·°C)") == "μm/(mm·°C)"
    assert rt.unit_text("urad") == "μrad" and rt.unit_text("mm") == "mm" and rt.unit_text("per revolution") == "per revolution"
    assert rt.unit_text("drum") == "drum"


def test_everything_printed_is_escaped():
    table = rt.Table(["machine", "RMS (μm)"], [[HOSTILE, 1.23456]])
    probe = rt.environment().from_string('{% extends "base.html" %}{% block content %}<h2 id="m">{{ name }}</h2>'
                                         "{{ table }}{% endblock %}")
    text = rt.render_page(probe, title=HOSTILE, name=HOSTILE, table=table)
    # <title>, <h1>, the heading and the table cell: all escaped (one section: no nav)
    assert "<script>" not in text and text.count("&lt;script&gt;") == 4
    assert "<td>1.23</td>" in text


def test_render_page_builds_the_nav_from_the_sections(tmp_path):
    probe = rt.environment().from_string('{% extends "base.html" %}{% block content %}<h2 id="a">First <b>one</b></h2>'
                                         '<h2 id="b">Second</h2>{% endblock %}')
    page = rt.render_page(probe, title="probe")
    nav = re.search(r"<nav>.*?</nav>", page, re.S).group(0)
    assert '<a href="#a">First one</a>' in nav and '<a href="#b">Second</a>' in nav
    assert rt.NAV_MARK not in page
    assert rt.stylesheet().strip()[:40] in page          # the one stylesheet, inlined
    assert not re.search(r"""(src|href)=["'](?!data:|#)""", page)   # nothing outside the page
    path = rt.write_page(tmp_path / "p.html", page)
    assert path.read_text(encoding="utf-8") == page


def test_figure_embeds_png_and_escapes_its_alt(tmp_path):
    from compensation.app.reports.figures import pyplot
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(2, 1))
    ax.plot([0, 1], [0, 1])
    f = rt.figure(fig, alt=HOSTILE, caption="residual (μm)")
    html = str(rt.Markup(f.__html__()))
    assert "<script>" not in html and "&lt;script&gt;" in html and "<figcaption>residual (μm)</figcaption>" in html
    b64 = re.search(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html).group(1)
    assert base64.b64decode(b64)[:8] == b"\x89PNG\r\n\x1a\n"
    saved = f.save(tmp_path / "f.png")
    assert rt.Figure.from_png(saved, "again").png == f.png
    with pytest.raises(ValueError, match="Expected PNG"):
        rt.Figure.from_png(b"GIF89a..", "not a png")


def test_table_cells_formats_and_classes():
    t = rt.Table(["name", "a", "b", "list"], [["x", 0.123456, 2.0, ["p", "q"]], ["y", None, 3.14159, []]],
                 formats={2: lambda v: rt.qty(v, "s", 2)}, row_classes=["learned", "parametric"])
    html = t.__html__()
    assert '<tr class="learned"><td class="label">x</td><td>0.123</td><td>2.0 s</td><td>p, q</td></tr>' in html
    assert "<td>—</td><td>3.1 s</td><td>none</td>" in html
    kv = rt.kv_table({"model": "<b>", "points": 40})
    assert "<thead>" not in kv.__html__() and "&lt;b&gt;" in kv.__html__()


def test_templates_and_stylesheet_ship_as_package_data():
    """pyproject's package-data must name what the toolkit loads (a non-editable install has only those)."""
    import tomllib
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    data = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    patterns = data["compensation.app.reports"]
    files = sorted(p.name for p in (root / "compensation/app/reports/templates").iterdir())
    assert files and all(any(Path("templates", f).match(p) for p in patterns) for f in files)
    assert "jinja2" in " ".join((root / "pyproject.toml").read_text().split("dependencies", 1)[1].split("]", 1)[0].split())
