"""Every report page kind rendered in headless Chromium: no console errors, every image loads.

One page of each kind — demo, report, diagnose, drift, calibrate (a hexapod's and an arm's), interpolate,
benchmark — is written
by the code that writes it for the user, from small simulated inputs, then loaded from disk in one
headless Chromium (DevTools protocol over a pipe, tests/chromium_cdp.py). Asserted per page: no
console/log error, at least one ``<img>`` and every one decoded (complete, naturalWidth > 0), the one
stylesheet applied, nothing requested outside the page (only its own file and data: URIs), and the
toolkit's layout (title, navigation). The checker itself is tested on a deliberately broken copy.
"""
from __future__ import annotations

import json
import re

import pytest

from chromium_cdp import CHROMIUM, Browser
from compensation.app.cli import main
from errormap.io import write_csv
from shared_runs import private_copy
from compensation.calibration_models import calibration_section

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="headless Chromium not installed (apt-get install chromium)")

KINDS = ("demo", "report", "diagnose", "drift", "calibrate", "calibrate-arm", "interpolate", "benchmark",
         "diagnose-chain")
PAGE_KIND = {"calibrate-arm": "calibrate", "diagnose-chain": "diagnose"}   # the page's own kind (brand line) where it differs from the writer's key
POSE_NOISE_UM = 5.0        # as tests/test_pkm_cli.py
CHECK_NOISE_UM = 1.0       # as tests/test_diagnosis.py
N_CHECKS = 160             # enough for the worm harmonic to be found (a figure per effect), small enough to be fast
N_POSES = 60
N_ARM_POSES = 80           # a simulated UR5: enough for the 27 identifiable slots and a 2-fold learned stage
ARM_NOISE_MM = 0.02        # tracker noise, as tests/test_arm_calibration.py
ARM_LO_DEG = (-60.0, -120.0, 30.0, -120.0, 40.0, -30.0)   # the real UR5 grid's joint ranges
ARM_HI_DEG = (60.0, -30.0, 140.0, 30.0, 150.0, 30.0)


def _comparison(grinder):
    from compensation.app.workflows.compare import compare_methods
    from compensation.toolpath import flute_path
    from errormap.chain_field import ChainField
    from errormap.chain_truth import make_chain_truth
    truth = make_chain_truth(grinder, 11)
    flute = flute_path(turns=1, points_per_turn=40)
    return compare_methods(ChainField(grinder, truth.elements), flute.targets_mm, grinder,
                           methods=("traditional", "exact"), truth=truth)


def _report(root, grinder):
    from compensation.app.reports.methods import write_report
    return write_report(_comparison(grinder), root / "report", context={"model": "truth elements <seed 11>"})["html"]


def _diagnose(root, grinder):
    from errormap.chain_truth import make_chain_truth
    truth = make_chain_truth(grinder, 3, effects=["worm"])
    el = truth.elements.save(root / "el.json")
    write_csv(root / "checks.csv", truth.check_measurements(N_CHECKS, CHECK_NOISE_UM, 3))
    assert main(["diagnose", str(root / "checks.csv"), "--model", str(el), "--out", str(root / "diag")]) == 0
    return root / "diag" / "report.html"


def _drift(root, grinder):
    from drift_fixtures import simulate_drift_log
    cols = simulate_drift_log(0, noise_um=0.5)
    cols.pop("_truth")
    write_csv(root / "log.csv", cols)
    assert main(["diagnose", "--drift", str(root / "log.csv"), "--out", str(root / "drift")]) == 0
    return root / "drift" / "report.html"


def _interpolate(root, grinder, calibration=None):
    page = root / f"interpolate{'-compensated' if calibration else ''}.html"
    assert main(["interpolate", "hyperboloid", "--out", str(root / "prog.csv"), "--report", str(page),
                 "--feed-mm-min", "6000", "--period-ms", "10"]
                + (["--calibration", str(calibration)] if calibration else [])) == 0
    return page


def _benchmark(root, grinder):
    from compensation.app.reports.benchmark import render_html
    from compensation.app.reports.toolkit import write_page
    from test_benchmark import _doc
    return write_page(root / "benchmark.html", render_html(_doc()))


def _calibrate(root, grinder):
    from errormap.machine import load_machine
    from errormap.pkm.simulate import simulate_hexapod_poses
    simulate_hexapod_poses(load_machine(expect_kind="hexapod"), N_POSES, POSE_NOISE_UM, seed=21).write_csv(
        root / "poses.csv")
    assert main(["calibrate", str(root / "poses.csv"), "--out", str(root / "cal"), "--noise-um", str(POSE_NOISE_UM),
                 "--no-loop"]) == 0
    return root / "cal" / "report.html"


def _calibrate_arm(root, grinder):
    """A serial arm (built-in ur5, simulated link errors + sag + noise) with the learned stage: every section."""
    from errormap.arm_poses import write_arm_poses
    from errormap.arm_simulate import draw_truth, measure, random_joints
    from errormap.machine import load_machine
    ur5 = load_machine("ur5")
    truth = draw_truth(ur5, 21)
    q = random_joints(ARM_LO_DEG, ARM_HI_DEG, N_ARM_POSES, [21, 0])
    write_arm_poses(root / "arm.csv", ur5, measure(ur5, truth, q, ARM_NOISE_MM, [21, 1]))
    assert main(["calibrate", str(root / "arm.csv"), "--machine", "ur5", "--out", str(root / "arm-cal"),
                 "--folds", "2"]) == 0
    return root / "arm-cal" / "report.html"


def _demo(root, grinder, request):
    """The real demo, tiny: the run tests/test_demo.py asserts on (tests/shared_runs.py)."""
    return request.getfixturevalue("tiny_demo").root / "demo" / "report.html"


def _diagnose_chain(root, grinder, request):
    """A machine-tool chain's diagnose run (mill-xyz, reversal:Z, against the truth's elements; the run
    tests/test_chain_report.py asserts on, tests/shared_runs.py) → volcomp report RUN on a copy of it."""
    run = private_copy(request.getfixturevalue("mill_reversal").root / "diag", root / "mt-diag")
    assert main(["report", str(run)]) == 0
    return run / "report.html"


FAST = {"report": _report, "drift": _drift, "interpolate": _interpolate, "benchmark": _benchmark}
"""Page kinds written in the default run (small inputs; ~40 s on a 2-core machine under load)."""
SLOW = {"calibrate": _calibrate, "calibrate-arm": _calibrate_arm, "demo": _demo, "diagnose-chain": _diagnose_chain,
        "diagnose": _diagnose}
"""Page kinds whose writers are end-to-end runs (calibration, training, the closed loop: over the fast tier's 5 CPU s):
marked slow, still run in CI."""
SHARED = {"demo", "diagnose-chain"}
"""Page kinds written from a run other test files assert on too (a session fixture, tests/shared_runs.py)."""


@pytest.fixture(scope="module")
def pages(tmp_path_factory, grinder, request):
    """kind -> path of one page of that kind, written lazily by the code that writes it for the user."""
    root = tmp_path_factory.mktemp("pages")
    written = {}

    def get(kind):
        if kind not in written:
            write = {**FAST, **SLOW}[kind]
            written[kind] = write(root, grinder, request) if kind in SHARED else write(root, grinder)
        return written[kind]
    return get


@pytest.fixture(scope="module")
def browser():
    with Browser() as b:
        yield b


def _assert_renders(page, kind, browser):
    seen = browser.check(page)
    assert seen.errors == [], seen.errors
    assert seen.images, "a report page without a figure"
    assert seen.broken_images == [], seen.broken_images
    assert seen.styled                                   # the one stylesheet is applied
    assert all(u == seen.url or u.startswith("data:") for u in seen.requests), seen.requests   # works offline
    assert seen.title and seen.h1 == seen.title
    text = page.read_text(encoding="utf-8")
    assert f"volcomp · {PAGE_KIND.get(kind, kind)}</p>" in text and "<nav>" in text     # the one layout: brand, title, navigation
    assert not re.search(r"\(um\)|\bum\b", re.sub(r"<[^>]+>", " ", text))   # μm, never "um"
    return seen


def test_every_page_kind_is_covered():
    assert set(FAST) | set(SLOW) == set(KINDS) and not set(FAST) & set(SLOW)


@pytest.mark.parametrize("kind", FAST)
def test_page_renders_without_errors_and_every_image_loads(kind, pages, browser):
    _assert_renders(pages(kind), kind, browser)


@pytest.mark.slow
@pytest.mark.parametrize("kind", SLOW)
def test_slow_page_renders_without_errors_and_every_image_loads(kind, pages, browser):
    _assert_renders(pages(kind), kind, browser)


@pytest.mark.slow
def test_compensated_interpolation_page_shows_the_corrections(pages, browser, tmp_path):
    page = _interpolate(tmp_path, None, calibration=pages("calibrate").parent)
    seen = _assert_renders(page, "interpolate", browser)
    assert "corrections" in {i["alt"] for i in seen.images}
    assert "RMS correction (μm)" in page.read_text(encoding="utf-8")


def test_the_checker_catches_a_broken_image_and_a_missing_file(pages, browser, tmp_path):
    """The same page with one image corrupted and one pointing at a missing file must fail the checks."""
    text = pages("report").read_text(encoding="utf-8")
    srcs = re.findall(r'src="(data:image/png;base64,[^"]+)"', text)
    broken = text.replace(srcs[0], "data:image/png;base64,AAAA", 1).replace(srcs[1], "missing.png", 1)
    page = tmp_path / "broken.html"
    page.write_text(broken, encoding="utf-8")
    seen = browser.check(page)
    assert len(seen.broken_images) == 2 and len(seen.images) == len(srcs)
    assert any("missing.png" in e for e in seen.errors)
    assert any(u.endswith("missing.png") for u in seen.requests)


def test_the_checker_catches_a_script_error(browser, tmp_path):
    page = tmp_path / "script.html"
    page.write_text("<!DOCTYPE html><html><head><title>t</title></head><body><h1>t</h1>"
                    "<script>console.error('boom'); undefined_name();</script></body></html>", encoding="utf-8")
    seen = browser.check(page)
    assert any("boom" in e for e in seen.errors) and any(e.startswith("exception") for e in seen.errors)


def test_the_report_page_escapes_its_setting(pages):
    report = pages("report").read_text(encoding="utf-8")
    assert "truth elements &lt;seed 11&gt;" in report and "<seed 11>" not in report


@pytest.mark.slow
def test_the_calibration_page_escapes_names(pages):
    """Names from the user's files are printed escaped (the calibration page printed them raw)."""
    from compensation.app.reports.calibration import render_html
    doc = calibration_section(pages("calibrate").parent / "model.json", "parallel")[0]
    hostile = '<script>alert("x")</script>'
    doc["machine"]["name"] = hostile
    doc["parameters"] = {hostile: next(iter(doc["parameters"].values()))}
    doc["notes"] = [hostile]
    page = render_html(doc, figures=[])
    assert "<script>" not in page and page.count("&lt;script&gt;") == 4   # <title>, <h1>, a note, a parameter


@pytest.mark.slow
def test_the_arm_calibration_page_escapes_names_and_shows_every_section(pages):
    """The arm page prints names from the user's machine file (machine, slots) and the rule's words escaped,
    and has every section of a run with the learned stage."""
    from compensation.app.reports.arm_calibration import render_html
    page = pages("calibrate-arm").read_text(encoding="utf-8")
    for section in ("stages", "identifiability", "band-calibration", "learned", "figures", "parameters"):
        assert f'<h2 id="{section}">' in page
    doc = calibration_section(pages("calibrate-arm").parent / "model.json", "arm")[0]
    assert f'{doc["band_calibration"]["factor"]:.3f}' in page   # the factor predict --band applies, on the page
    hostile = '<script>alert("x")</script>'
    doc["machine"]["name"] = hostile
    doc["notes"] = [hostile]
    doc["kept_why"] = hostile
    doc["geometric"]["parameters"][0].update(name=hostile, identified=True)
    page = render_html(doc, figures=[])
    assert "<script>" not in page and page.count("&lt;script&gt;") == 5   # <title>, <h1>, banner, a note, a slot
