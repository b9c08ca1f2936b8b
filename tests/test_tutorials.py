"""Every tutorial runs as written (docs/tutorials/*.md), and so does every how-to guide a fresh folder can run
(RUNNABLE_HOWTOS; the scale-out guide needs Ray and an MLflow server, which tests/test_cluster.py starts, and the
five-axis guide the five-axis tutorial's model): its files are saved from the blocks titled with their name, the
`volcomp` lines of its `bash` blocks run in order in one fresh folder (a block titled "refused" must be refused,
exit status 2; a `shell` block needs the user's own files and is not run here), and every figure it shows — a
block titled "output" (what the commands of the block before it print) or "NAME (excerpt)" (lines of a written
file) — is found in what the run printed or wrote, each number within REL_TOL · |number| + ABS_TOL.

The runs are seeded, so the figures repeat exactly on one machine; the tolerance covers what differs between
machines (BLAS, CPU kernels: the last printed digit of a fitted figure), not a change of result."""
from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = sorted(p for p in (ROOT / "docs" / "tutorials").glob("*.md") if p.name != "index.md")
RUNNABLE_HOWTOS = [ROOT / "docs" / "how-to" / name for name in
                   ("machine-file.md", "instrument-files.md", "export-to-controller.md")]
"""How-to guides whose commands run in a fresh folder; each shows what its commands print, checked as a tutorial's."""
REL_TOL = 0.02
"""Relative tolerance on each figure a tutorial shows (printed to 3-4 significant digits)."""
ABS_TOL = 0.01
"""Absolute tolerance, in the printed unit (μm, mm): a round-off-level figure such as a model residual of 1e-10 μm."""
NUMBER = re.compile(r"…|[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
"""A number, or "…" in a shown line: a value that depends on the computer (seconds), matched but not compared."""
BLOCK = re.compile(r"^```(\w+)(?:[ \t]+title=\"([^\"]+)\")?[ \t]*\n(.*?)^```[ \t]*$", re.M | re.S)


def blocks(page: Path) -> list:
    """(language, title or None, text) of every fenced block, in page order."""
    return [(m.group(1), m.group(2), m.group(3)) for m in BLOCK.finditer(page.read_text(encoding="utf-8"))]


def _skeleton(line: str) -> str:
    return NUMBER.sub("#", " ".join(line.split()))


def _numbers(line: str) -> list:
    return [None if x == "…" else float(x) for x in NUMBER.findall(line)]


def check_figures(expected: str, actual: str, where: str) -> None:
    """Each non-empty expected line has a line of the same words in ``actual`` whose numbers all agree."""
    lines = actual.splitlines()
    for want in filter(str.strip, expected.splitlines()):
        same = [got for got in lines if _skeleton(got) == _skeleton(want)]
        assert same, f"{where}: no line like {want!r}"
        ok = any(all(w is None or abs(g - w) <= REL_TOL * abs(w) + ABS_TOL
                     for g, w in zip(_numbers(got), _numbers(want)))
                 for got in same)
        assert ok, f"{where}: {want!r} shown, the run gave {same}"


def run_volcomp(line: str) -> tuple:
    from compensation.app.cli import main
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        status = main(shlex.split(line, comments=True)[1:])
    return status, out.getvalue()


@pytest.mark.slow  # each tutorial is a whole workflow: 10-30 CPU s
@pytest.mark.parametrize("page", TUTORIALS + RUNNABLE_HOWTOS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_tutorial_runs_as_written_and_shows_its_figures(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    printed, ran = "", 0
    for lang, title, text in blocks(page):
        if lang == "bash" and title == "refused":
            printed = ""
            for line in text.splitlines():
                if line.startswith("volcomp "):
                    status, out = run_volcomp(line)
                    assert status == 2 and "Traceback" not in out, f"{page.name}: {line}: exit {status}\n{out[-2000:]}"
                    printed += out
        elif title and title != "output" and not title.endswith("(excerpt)"):
            (tmp_path / title).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / title).write_text(text, encoding="utf-8")
        elif title == "output":
            check_figures(text, printed, f"{page.name}, output")
        elif title:
            name = title.removesuffix("(excerpt)").strip()
            check_figures(text, (tmp_path / name).read_text(encoding="utf-8"), f"{page.name}, {name}")
        elif lang == "bash":
            printed = ""
            for line in text.splitlines():
                if line.startswith("volcomp "):
                    status, out = run_volcomp(line)
                    assert status == 0, f"{page.name}: {line}: exit {status}\n{out[-2000:]}"
                    printed += out
                    ran += 1
    assert ran, f"{page.name} runs no volcomp command"


def test_every_tutorial_shows_figures_that_the_test_checks():
    """A tutorial without a checked figure would pass by running alone: each has an output block."""
    assert TUTORIALS
    for page in TUTORIALS + RUNNABLE_HOWTOS:
        titles = [t for _, t, _ in blocks(page)]
        assert "output" in titles, page.name


MACHINE_FILE_MISTAKES = (
    ("stroke = [0.0, 800.0]", "stroke = [800.0, 0.0]"),
    ('axis = "Y"', 'axis = "X"'),
    ('tz = "beam_height"', 'tz = "beam_heigth"'),
    ("stroke = [0.0, 1500.0]", 'stroke = [0.0, 1500.0]\nunits = "mm"'),
    ('tz = "table_height"', 'tz = "table_height"\nerrors = true'),
    ("Z = [[-80.0", "A = [[-80.0"),
)
"""One mistake per refusal line the machine-file how-to shows, made in the page's own my-gantry.toml."""


def test_machine_file_howto_shows_the_refusals_volcomp_prints(tmp_path, monkeypatch):
    """The refusal lines of docs/how-to/machine-file.md are what `volcomp simulate` prints for those mistakes."""
    page = ROOT / "docs" / "how-to" / "machine-file.md"
    good = next(text for _, title, text in blocks(page) if title == "my-gantry.toml")
    shown = [line for _, title, text in blocks(page) if title is None
             for line in text.splitlines() if line.startswith("volcomp simulate: error:")]
    monkeypatch.chdir(tmp_path)
    printed = []
    for old, new in MACHINE_FILE_MISTAKES:
        assert good.count(old) == 1, old
        (tmp_path / "my-gantry.toml").write_text(good.replace(old, new), encoding="utf-8")
        status, out = run_volcomp("volcomp simulate --machine my-gantry.toml --seed 0 --out sim")
        assert status == 2 and "Traceback" not in out, out
        printed += [line for line in out.splitlines() if "error:" in line]
    assert shown == printed


@pytest.mark.slow  # simulates, identifies and reads six files: ~10 CPU s
def test_instrument_files_howto_shows_the_refusals_volcomp_prints(tmp_path, monkeypatch):
    """The refusal lines of docs/how-to/instrument-files.md are what volcomp prints for those mistakes, made in
    the files the page's own commands write (the drift log: a simulated one, 16 h at 60 s)."""
    import pandas as pd

    from errormap.diagnosis.drift_sim import simulate_lumped_log

    page = ROOT / "docs" / "how-to" / "instrument-files.md"
    shown = [line for _, title, text in blocks(page) if title is None
             for line in text.splitlines() if line.startswith("volcomp ") and ": error: " in line]
    monkeypatch.chdir(tmp_path)
    for line in ("volcomp sweeps --machine mill-xyz --seed 3 --out example_sweeps.csv",
                 "volcomp simulate --machine mill-xyz --seed 3 --out example",
                 "volcomp identify example_sweeps.csv --machine mill-xyz --out E.json"):
        assert run_volcomp(line)[0] == 0, line
    checks, sweeps = pd.read_csv("example/checks.csv"), pd.read_csv("example_sweeps.csv")
    metres = checks.copy()
    metres[["x_mm", "y_mm", "z_mm"]] /= 1000
    metres.to_csv("checks_in_metres.csv", index=False)
    checks.drop(columns=["dz_um"]).to_csv("checks_no_dz.csv", index=False)
    sweeps.drop(columns=["target"]).to_csv("sweeps_no_target.csv", index=False)
    text = sweeps.astype({"x_mm": object})
    text.loc[5, "x_mm"] = "n/a"  # file row 7: the header is row 1
    text.to_csv("sweeps_text.csv", index=False)
    log = pd.DataFrame({k: v for k, v in simulate_lumped_log(0, hours=16, dt_s=60).items() if k != "_truth"})
    log.loc[10, "time_s"] = log.loc[9, "time_s"]
    log.to_csv("log_time.csv", index=False)
    printed = []
    for line in ("volcomp diagnose checks_in_metres.csv --model E.json --machine mill-xyz --noise-um 1 --out d1",
                 "volcomp diagnose checks_no_dz.csv --model E.json --machine mill-xyz --noise-um 1 --out d2",
                 "volcomp identify sweeps_no_target.csv --machine mill-xyz --out E1.json",
                 "volcomp identify sweeps_text.csv --machine mill-xyz --out E2.json",
                 "volcomp diagnose --drift log_time.csv --out d3"):
        status, out = run_volcomp(line)
        assert status == 2 and "Traceback" not in out, out
        printed += [ln for ln in out.splitlines() if ": error: " in ln]
    assert shown == printed


@pytest.mark.slow  # a drift model from a 16 h log and two exports: ~15 CPU s
def test_export_howto_drift_step_shows_what_volcomp_prints(tmp_path, monkeypatch):
    """Step 5 of docs/how-to/export-to-controller.md needs the user's own log, so the page's run leaves it out:
    here it runs on the simulated log the page describes (16 h sampled every 60 s), and its output block and
    its refusal line are what volcomp prints."""
    import pandas as pd

    from errormap.diagnosis.drift_sim import simulate_lumped_log

    page = ROOT / "docs" / "how-to" / "export-to-controller.md"
    found = blocks(page)
    commands = next(text for lang, _, text in found if lang == "shell" and "--drift" in text)
    shown = next(text for lang, title, text in found if title is None and "check (controller re-simulated" in text)
    refusal = next(line for _, title, text in found if title is None for line in text.splitlines()
                   if line.startswith("volcomp export: error: tolerance not met: at a sample period"))
    monkeypatch.chdir(tmp_path)
    log = pd.DataFrame({k: v for k, v in simulate_lumped_log(0, hours=16, dt_s=60).items() if k != "_truth"})
    log.to_csv("machine_log.csv", index=False)
    printed = ""
    for line in commands.splitlines():
        status, out = run_volcomp(line)
        assert status == 0, out[-2000:]
        printed += out
    check_figures(shown, printed, f"{page.name}, drift step")
    status, out = run_volcomp("volcomp export ddiag/drift_model.json --format drift --log machine_log.csv "
                              "--sample-period-s 300 --out out/drift300")
    assert status == 2
    check_figures(refusal, out, f"{page.name}, drift refusal")
