"""No traceback reachable from the command line (issue 30, points 3 and 4).

Each reproduction of the issue is a test here: out-of-range options (``--seed -1`` in
``simulate`` and ``compensate --method batched-ga``, ``identify --noise-um -1``,
``featurepoints --grid -3``), sizes over their stated limits (``featurepoints --grid 1000``),
``--out`` naming a file where a folder belongs or the reverse, an output folder that cannot be
written, and Ctrl-C at several moments (also while the libraries are still being imported).
A hypothesis test then drives every checked option of every command with invalid values.

Every option here is refused by :func:`compensation.app.validate.check_args` BEFORE the
command's work: the tests check that by giving each command inputs that do not exist, so a
value the check wrongly accepted would surface as a different one-line error (not silently as
work), and by the time budget of the hypothesis test.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compensation.app import validate
from compensation.app.cli import COMMAND_MODULES, MAX_ERROR_CHARS, build_parser, main

REPO = Path(__file__).resolve().parents[1]

# exit status of a command stopped by Ctrl-C: 128 + SIGINT, what shells report
EXIT_INTERRUPTED = 130
# a command must answer Ctrl-C within this long; numpy loops and the CSV writer do not look at
# signals, the longest one seen here (featurepoints --grid 150, writing 3.4e6 rows) took 5 s
# on the loaded 2-core machine: 60 s leaves room for a busy machine and still fails a hang
INTERRUPT_ANSWER_S = 60.0
# the hypothesis test's examples (each an in-process main() call that must fail before work)
FUZZ_EXAMPLES = 150
FUZZ = settings(max_examples=FUZZ_EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

# options that name an output (checked for kind and writability) besides --out
OUTPUT_DESTS = {"out", "report", "plot", "sensitivity_plot"}


def run_cli(argv) -> tuple[int, str, str]:
    """``main(argv)`` in this process: (exit status, stdout, stderr); argparse's SystemExit included."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([str(a) for a in argv])
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 2
    return rc, out.getvalue(), err.getvalue()


def assert_one_line_refusal(rc, err, *needles) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (rc, err)
    assert "Traceback" not in err, err
    assert len(lines) == 1, err
    assert len(lines[0]) <= MAX_ERROR_CHARS + 40, lines[0]  # argparse adds the "(see ... --help)" hint
    for n in needles:
        assert n in lines[0], (n, lines[0])


def subparsers():
    """``{command: its sub-parser}`` with every command registered in full."""
    parser = build_parser()
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    raise AssertionError("no sub-commands")


def checked_actions(p):
    """The options of sub-parser ``p`` that need a rule: typed int/float (not a closed choice) or an output."""
    for a in p._actions:
        if not a.option_strings or a.dest == "help":
            continue
        if (a.type in (int, float) and not a.choices) or a.dest in OUTPUT_DESTS:
            yield a


# --- every option has a rule ---------------------------------------------------------------------
def test_every_numeric_and_output_option_of_every_command_has_a_rule():
    subs = subparsers()
    assert set(subs) == set(COMMAND_MODULES)
    missing = [f"{name} {a.option_strings[-1]}" for name, p in subs.items() for a in checked_actions(p)
               if validate.rule_for(name, a.dest) is None]
    assert not missing, f"options without a range or path rule in compensation/app/validate.py: {missing}"
    # and no rule names an option its command does not have (a renamed option would lose its check)
    stale = [f"{c} {d}" for c, rules in validate.RULES.items() for d in rules
             if d not in {a.dest for a in subs[c]._actions}]
    assert not stale, stale


# --- the reproductions -------------------------------------------------------------------
@pytest.fixture
def missing(tmp_path):
    """Paths of inputs that do not exist: a command that got past the checks fails on them at once."""
    return {k: tmp_path / f"missing.{k}" for k in ("toml", "json", "csv", "ngc")}


def test_seed_minus_one_simulate(tmp_path):
    rc, _, err = run_cli(["simulate", "--seed", "-1", "--out", tmp_path / "sim"])
    assert_one_line_refusal(rc, err, "--seed must be >= 0, got -1")
    assert not (tmp_path / "sim").exists()


def test_seed_minus_one_compensate_batched_ga(tmp_path, missing):
    rc, _, err = run_cli(["compensate", missing["ngc"], "--model", missing["json"], "--method", "batched-ga",
                          "--seed", "-1", "--out", tmp_path / "out"])
    assert_one_line_refusal(rc, err, "--seed", "-1")


def test_identify_noise_minus_one(tmp_path, missing):
    rc, _, err = run_cli(["identify", missing["csv"], "--noise-um", "-1", "--out", tmp_path / "e.json"])
    assert_one_line_refusal(rc, err, "--noise-um", "-1")


@pytest.mark.parametrize("grid, needle", [("-3", ">= 2"), ("0", ">= 2"), ("1000", "limit of 5e+06")])
def test_featurepoints_grid(tmp_path, missing, grid, needle):
    rc, _, err = run_cli(["featurepoints", "--elements", missing["json"], "--grid", grid, "--out",
                          tmp_path / "fp.csv"])
    assert_one_line_refusal(rc, err, "--grid", needle)
    if grid == "1000":  # the limit and the largest grid that fits are in the message
        n_max = int(err.split("--grid <= ")[1].split(")")[0])
        assert n_max ** 3 <= validate.MAX_GRID_POINTS < (n_max + 1) ** 3


def test_flute_points_bounded(tmp_path, missing):
    rc, _, err = run_cli(["report", "--flute", "--turns", "1e6", "--model", missing["json"],
                          "--out", tmp_path / "r"])
    assert_one_line_refusal(rc, err, "exceeds the limit", "points per path")


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "-0.5", "0"])
def test_non_finite_and_non_positive_floats_refused(tmp_path, missing, value):
    rc, _, err = run_cli(["export", missing["json"], "--format", "grid", "--tolerance-um", value,
                          "--out", tmp_path / "x"])
    assert_one_line_refusal(rc, err, "--tolerance-um")


# commands whose --out is a folder / a file: (argv before --out)
DIR_OUT = {
    "simulate": ["simulate"],
    "train": ["train", "{csv}"],
    "compensate": ["compensate", "{ngc}", "--model", "{json}", "--method", "exact"],
    "report": ["report", "--flute", "--model", "{json}"],
    "demo": ["demo"],
    "diagnose": ["diagnose", "{csv}", "--model", "{json}"],
    "calibrate": ["calibrate", "{csv}"],
    "benchmark": ["benchmark"],
    "fleet": ["fleet", "{toml}"],
    "export": ["export", "{json}", "--format", "grid"],
    "register": ["register", "{csv}", "--model", "{json}", "--machine", "{toml}"],
}
FILE_OUT = {
    "featurepoints": ["featurepoints", "--elements", "{json}"],
    "predict": ["predict", "{csv}", "--model", "{json}"],
    "identify": ["identify", "{csv}"],
    "sweeps": ["sweeps", "--seed", "0"],
    "interpolate": ["interpolate", "sphere"],
    "drift-predict": ["drift-predict", "{json}", "{csv}"],
}


def _fill(argv, missing):
    return [a.format(**missing) for a in argv]


@pytest.mark.parametrize("command", sorted(DIR_OUT))
def test_out_naming_a_file_where_a_folder_belongs(tmp_path, missing, command):
    f = tmp_path / "a_file.txt"
    f.write_text("mine\n")
    rc, _, err = run_cli(_fill(DIR_OUT[command], missing) + ["--out", f])
    assert_one_line_refusal(rc, err, "--out", "is a file; expected a folder")
    assert f.read_text() == "mine\n"


@pytest.mark.parametrize("command", sorted(FILE_OUT))
def test_out_naming_a_folder_where_a_file_belongs(tmp_path, missing, command):
    d = tmp_path / "a_folder"
    d.mkdir()
    rc, _, err = run_cli(_fill(FILE_OUT[command], missing) + ["--out", d])
    assert_one_line_refusal(rc, err, "--out", "is a folder; expected a file")
    assert list(d.iterdir()) == []


@pytest.mark.parametrize("command", ["simulate", "featurepoints"])
def test_out_below_a_file(tmp_path, missing, command):
    f = tmp_path / "a_file.txt"
    f.write_text("mine\n")
    argv = (_fill(DIR_OUT[command], missing) if command in DIR_OUT else _fill(FILE_OUT[command], missing))
    rc, _, err = run_cli(argv + ["--out", f / "sub" / "x.csv"])
    assert_one_line_refusal(rc, err, "--out", "is a file, not a folder")


@pytest.mark.parametrize("command", ["simulate", "compensate", "featurepoints", "identify", "export"])
def test_output_folder_that_cannot_be_written(tmp_path, missing, command):
    """A read-only place: /proc accepts no new file even from root; a chmod 555 folder otherwise."""
    if os.geteuid() != 0:
        ro = tmp_path / "read_only"
        ro.mkdir()
        ro.chmod(0o555)
    elif Path("/proc/self").is_dir():
        ro = Path("/proc")
    else:  # pragma: no cover
        pytest.skip("running as root without /proc: no folder here refuses a new file")
    argv = (_fill(DIR_OUT[command], missing) if command in DIR_OUT else _fill(FILE_OUT[command], missing))
    out = ro / ("volcomp_out" if command in DIR_OUT else "volcomp_out.json")
    try:
        rc, _, err = run_cli(argv + ["--out", out])
    finally:
        if os.geteuid() != 0:
            ro.chmod(0o755)
    assert_one_line_refusal(rc, err, "--out", "cannot write in")


def test_demo_trainer_checked_before_the_simulation(tmp_path):
    rc, _, err = run_cli(["demo", "--trainer", "sgd", "--out", tmp_path / "demo"])
    assert_one_line_refusal(rc, err, "--trainer", "'sgd'")
    assert not (tmp_path / "demo").exists()


def test_argparse_errors_are_one_line(tmp_path):
    rc, _, err = run_cli(["simulate", "--seed", "abc", "--out", tmp_path])
    assert_one_line_refusal(rc, err, "--seed", "invalid int value")
    rc, _, err = run_cli(["simulate"])  # --out missing
    assert_one_line_refusal(rc, err, "--out")


def test_lm_memory_bounded(tmp_path):
    """Training LM on a feature-point set whose Jacobian would not fit is refused before training."""
    from compensation.app.validate import MAX_LM_BYTES, check_lm_size, network_params
    from compensation.app.validate import UsageError
    p = network_params((10, 15, 25, 15, 10))
    n_fit = (MAX_LM_BYTES // 8 - p * p) // (3 * p)
    check_lm_size(n_fit, p)  # at the limit: accepted
    with pytest.raises(UsageError, match="over the limit of 4 GiB"):
        check_lm_size(n_fit + 1, p)


@pytest.mark.slow  # over 5 CPU s in the fresh-clone CI run of 2026-11-24 (tier rule)
def test_predict_batched_equals_whole(grinder):
    """Batches of PREDICT_BATCH give the same predictions as one call (an HTM field, per point)."""
    import numpy as np

    from errormap.chain_field import ChainField
    from errormap.chain_truth import make_chain_truth
    rng = np.random.default_rng(7)
    field = ChainField(grinder, make_chain_truth(grinder, 3).elements)
    lo = np.array([grinder.strokes[k][0] for k in ("x_mm", "z_mm", "a_deg")])
    hi = np.array([grinder.strokes[k][1] for k in ("x_mm", "z_mm", "a_deg")])
    axes = lo + (hi - lo) * rng.random((validate.PREDICT_BATCH + 1000, 3))
    np.testing.assert_array_equal(validate.predict_batched(field, axes), field.predict(axes))


# --- Ctrl-C ------------------------------------------------------------------------------------
# the child runs what the installed `volcomp` script runs; it says "started" once the interpreter
# is up (before the command's module is imported), and the delays count from there: a Ctrl-C while
# Python itself still starts (its `site` import, the first ~50 ms) is the interpreter's own
# "Fatal Python error", out of reach of any program it runs
CHILD = ("import sys; sys.stderr.write('started\\n'); sys.stderr.flush(); "
         "from compensation.app.cli import main; sys.exit(main())")


def _start(argv, cwd, **extra_env):
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "MPLBACKEND": "Agg", **extra_env}
    proc = subprocess.Popen([sys.executable, "-c", CHILD, *argv], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stderr.readline() == "started\n"
    return proc


def _interrupt(proc, after_s: float, wait_for: str | None = None) -> tuple[int, str]:
    """SIGINT ``proc`` ``after_s`` seconds after it started (or after a stderr line containing
    ``wait_for``); its exit status and whole stderr (after the "started" line)."""
    lines = []
    if wait_for is not None:
        for line in proc.stderr:
            lines.append(line)
            if wait_for in line:
                break
    time.sleep(after_s)
    proc.send_signal(signal.SIGINT)
    try:
        _, rest = proc.communicate(timeout=INTERRUPT_ANSWER_S)
    except subprocess.TimeoutExpired:  # pragma: no cover - the failure this test exists for
        proc.kill()
        proc.communicate()
        pytest.fail(f"no answer to Ctrl-C within {INTERRUPT_ANSWER_S} s")
    return proc.returncode, "".join(lines) + rest


def _assert_interrupted(rc, err, out_root: Path):
    assert rc == EXIT_INTERRUPTED, (rc, err)
    assert "Traceback" not in err and "Error" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and lines[-1].endswith("interrupted; nothing half-written"), err
    assert sum("interrupted" in ln for ln in lines) == 1, err
    leftovers = [p for p in out_root.rglob("*") if p.name.endswith((".tmp", ".old")) or ".tmp" in p.name]
    assert not leftovers, leftovers


@pytest.mark.parametrize("after_s", [0.2, 1.0])
def test_ctrl_c_early_exits_130(tmp_path, after_s):
    """In the first second the command is still importing numpy/scipy: the same one line."""
    proc = _start(["simulate", "--out", "sim", "--checks", "20"], tmp_path)
    rc, err = _interrupt(proc, after_s)
    _assert_interrupted(rc, err, tmp_path)


@pytest.mark.slow
def test_ctrl_c_mid_work_leaves_no_partial_output(tmp_path):
    """featurepoints on a 150³ grid (3.4e6 points, about 10 s of work): Ctrl-C a moment after the
    work started leaves no feature-point file and no temporary file."""
    sim = tmp_path / "sim"
    assert main(["simulate", "--out", str(sim), "--checks", "20"]) == 0
    proc = _start(["featurepoints", "--elements", str(sim / "truth_elements.json"), "--grid", "150",
                   "--out", "fp.csv"], tmp_path)
    rc, err = _interrupt(proc, 4.0)
    _assert_interrupted(rc, err, tmp_path)
    assert not (tmp_path / "fp.csv").exists()


@pytest.mark.slow
def test_ctrl_c_after_progress_line(tmp_path):
    """simulate, interrupted after it said it is simulating (mid-work): 130, no partial file."""
    proc = _start(["simulate", "--out", "sim", "--checks", "200000"], tmp_path)
    rc, err = _interrupt(proc, 0.3, wait_for="simulating truth ")
    _assert_interrupted(rc, err, tmp_path)


# a Ctrl-C while numba compiles (a cold cache: simulate compiles the HTM kernels for a few seconds
# after its progress line) lands inside the compiler's C callbacks, which swallow it ("Exception
# ignored ...") and can leave numba broken ("no compiled object yet"); before the fix 3 of 10 such
# delays ended in rc 1 or 0. Delays spread over the compile window of a 2-core machine.
COMPILE_WINDOW_DELAYS_S = (0.6, 1.0, 1.4, 1.8, 2.2)


@pytest.mark.slow
def test_ctrl_c_while_numba_compiles_exits_130(tmp_path):
    for k, after_s in enumerate(COMPILE_WINDOW_DELAYS_S):
        cwd = tmp_path / f"run{k}"
        cwd.mkdir()
        proc = _start(["simulate", "--out", "sim", "--checks", "200000"], cwd,
                      NUMBA_CACHE_DIR=str(cwd / "numba-cache"))
        rc, err = _interrupt(proc, after_s, wait_for="simulating truth ")
        _assert_interrupted(rc, err, cwd)
        assert "Exception ignored" not in err, (after_s, err)


# --- hypothesis: every checked option, invalid values -----------------------------------------------
BASE = {**DIR_OUT, **FILE_OUT}
NUMERIC_JUNK = ["-1", "0", "-0", "nan", "NaN", "inf", "-inf", "1e308", "1e999", "-1e308", "99999999999999999999",
                "abc", "", " ", "0x10", "1.5", "-2.5", "1e-320", "1_000", "１２", "None", "[]"]
numeric_value = st.one_of(st.sampled_from(NUMERIC_JUNK),
                          st.integers(min_value=-10**24, max_value=0).map(str),
                          st.integers(min_value=10**9, max_value=10**24).map(str),
                          st.floats(allow_nan=True, allow_infinity=True).filter(lambda x: not x > 0).map(repr))
PATH_KINDS = ["wrong_kind", "below_file", "empty", "unwritable"]  # /proc takes no new file, even from root


def _cases():
    subs = subparsers()
    out = []
    for name, p in sorted(subs.items()):
        for a in checked_actions(p):
            out.append((name, a.option_strings[-1], a.dest in OUTPUT_DESTS))
    return out


CASES = _cases()


@FUZZ
@given(case=st.sampled_from(CASES), value=numeric_value, path_kind=st.sampled_from(PATH_KINDS))
def test_every_option_invalid_values_one_line_never_a_traceback(tmp_path_factory, case, value, path_kind):
    command, flag, is_path = case
    tmp = tmp_path_factory.mktemp("fuzz")
    missing = {k: tmp / f"missing.{k}" for k in ("toml", "json", "csv", "ngc")}
    argv = _fill(BASE[command], missing) + ["--machine", missing["toml"]]
    if command in ("drift-predict", "fleet"):
        argv = argv[:-2]  # no --machine option
    argv += ["--out", tmp / ("o" if command in DIR_OUT else "o.csv")]  # a later --out wins
    if is_path:
        f = tmp / "file.txt"
        f.write_text("x\n")
        (tmp / "dir").mkdir()
        wants_dir = command in DIR_OUT and flag == "--out"
        value = {"wrong_kind": f if wants_dir else tmp / "dir", "below_file": f / "sub" / "x", "empty": "",
                 "unwritable": "/proc/volcomp_x"}[path_kind]
    rc, out, err = run_cli(argv + [flag, value])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err, err
    assert rc in (0, 2), (argv, flag, value, rc, err)
    assert rc == 2, (argv, flag, value, err)  # every base command lacks its inputs: never work
    assert len(lines) == 1, (argv, flag, value, err)
    assert len(lines[0]) <= MAX_ERROR_CHARS + 40


# an input path naming a folder (the readers' own messages; an OSError that escaped one, such as
# drift-predict's IsADirectoryError, is one line from main too)
INPUT_IS_FOLDER = {
    "predict": ["predict", "{dir}", "--model", "{json}", "--out", "{out}.csv"],
    "featurepoints": ["featurepoints", "--elements", "{dir}", "--out", "{out}.csv"],
    "identify": ["identify", "{dir}", "--out", "{out}.json"],
    "train": ["train", "{dir}", "--out", "{out}"],
    "compensate": ["compensate", "{dir}", "--model", "{json}", "--method", "exact", "--out", "{out}"],
    "calibrate": ["calibrate", "{dir}", "--out", "{out}"],
    "drift-predict": ["drift-predict", "{dir}", "{dir}", "--out", "{out}.csv"],
    "fleet": ["fleet", "{dir}", "--out", "{out}"],
    "export": ["export", "{dir}", "--format", "grid", "--out", "{out}"],
    "simulate": ["simulate", "--machine", "{dir}", "--out", "{out}"],
    "interpolate": ["interpolate", "{dir}", "--out", "{out}.csv"],
    "report": ["report", "--path", "{dir}", "--model", "{json}", "--out", "{out}"],
}


@pytest.mark.parametrize("command", sorted(INPUT_IS_FOLDER))
def test_input_path_naming_a_folder(tmp_path, missing, command):
    d = tmp_path / "a_folder"
    d.mkdir()
    argv = [a.format(dir=d, out=tmp_path / "out", **missing) for a in INPUT_IS_FOLDER[command]]
    rc, _, err = run_cli(argv)
    assert_one_line_refusal(rc, err, str(d))
