"""Every reader, fuzzed: a mangled input file either reads or raises the project's own error.

Each test starts from a valid file and applies one random mutation (a cell replaced by random
text or an absurd number, raw bytes inserted, a UTF-8 BOM, Latin-1 text, a line dropped or
doubled, the file cut short). The readers are the CSV ones (sweeps, checks, tool paths, feature
points), the element-set JSON and the machine TOML of every kind; and ``compensation.app.cli.main``
on the fast commands: nothing but exit 0 or 2 with one bounded line may come out of it.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from chain_fixtures import OLD_GRINDER_FILE
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compensation.app.cli import MAX_ERROR_CHARS, UsageError, main
from errormap.io import InputError
from errormap.machine import MachineFileError, builtin_machine_path, load_machine

PROJECT_ERRORS = (InputError, MachineFileError, UsageError)
FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

ABSURD = ["", " ", "nan", "inf", "-inf", "1e308", "1e400", "-1e300", "10000000000", "1e6", "6.283",
          "0x10", "1_000", "１２", "true", "[1]", '"', '""', "a,b", "\x00", "ü", "\ufeff1", "1e-320", "-0"]
cell = st.one_of(st.sampled_from(ABSURD), st.text(max_size=12),
                 st.floats(allow_nan=True, allow_infinity=True).map(repr),
                 st.integers(min_value=-10**30, max_value=10**30).map(str))


@st.composite
def mangled(draw, text: str) -> bytes:
    """``text`` (a valid file) with one random mutation, as bytes."""
    lines = text.split("\n")
    kind = draw(st.sampled_from(["cell", "cell", "cell", "bytes", "bom", "latin1", "drop", "double", "cut"]))
    if kind == "cell":
        k = draw(st.integers(0, len(lines) - 1))
        cells = lines[k].split(",")
        j = draw(st.integers(0, len(cells) - 1))
        cells[j] = draw(cell)
        lines[k] = ",".join(cells)
    elif kind in ("drop", "double"):
        k = draw(st.integers(0, len(lines) - 1))
        lines[k:k + 1] = [] if kind == "drop" else [lines[k], lines[k]]
    raw = "\n".join(lines).encode("utf-8")
    if kind == "bytes":
        k = draw(st.integers(0, len(raw)))
        raw = raw[:k] + draw(st.binary(min_size=1, max_size=4)) + raw[k:]
    elif kind == "bom":
        raw = b"\xef\xbb\xbf" + raw
    elif kind == "latin1":
        raw = ("# M\u00fcller\n" + "\n".join(lines)).encode("latin-1", errors="replace")
    elif kind == "cut":
        raw = raw[:draw(st.integers(0, len(raw)))]
    return raw


def reads_or_refuses(reader, raw: bytes, suffix: str):
    """Write ``raw``, call ``reader(path)``: it returns, or raises one of the project's errors."""
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"input{suffix}"
        p.write_bytes(raw)
        try:
            reader(p)
        except PROJECT_ERRORS as exc:
            assert str(p) in str(exc) or "no sweep" in str(exc)


@pytest.fixture(scope="module")
def machine():
    return load_machine(None)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["simulate", "--seed", "3", "--out", str(out / "sim"), "--checks", "30"]) == 0
        assert main(["sweeps", "--seed", "3", "--out", str(out / "sweeps.csv")]) == 0
        assert main(["identify", str(out / "sweeps.csv"), "--out", str(out / "ident" / "E.json")]) == 0
    return out


def _head(path: Path, n_data: int) -> str:
    """The comment lines, the header and the first ``n_data`` rows of a CSV."""
    lines = path.read_text(encoding="utf-8").split("\n")
    h = next(i for i, l in enumerate(lines) if l and not l.startswith("#"))
    return "\n".join(lines[: h + 1 + n_data]) + "\n"


@FUZZ
@given(data=st.data())
def test_fuzz_checks_reader(sim, machine, data):
    from errormap.diagnosis.chain_checks import load_chain_checks
    raw = data.draw(mangled(_head(sim / "sim" / "checks.csv", 30)))
    reads_or_refuses(lambda p: load_chain_checks(p, machine), raw, ".csv")


@FUZZ
@given(data=st.data())
def test_fuzz_featurepoints_reader(sim, machine, data):
    from errormap.featurepoints import FeaturePoints
    raw = data.draw(mangled(_head(sim / "sim" / "featurepoints.csv", 40)))
    reads_or_refuses(lambda p: FeaturePoints.load(p).check_units(machine), raw, ".csv")


@FUZZ
@given(data=st.data())
def test_fuzz_sweeps_reader(sim, machine, data):
    from errormap.sweeps import read_sweeps
    text = (sim / "sweeps.csv").read_text(encoding="utf-8")
    raw = data.draw(mangled(text))
    reads_or_refuses(lambda p: read_sweeps([p], machine), raw, ".csv")


@FUZZ
@given(data=st.data(), targets=st.booleans())
def test_fuzz_toolpath_csv_reader(machine, data, targets):
    from path_files import read_as_compensate
    text = ("px_mm,py_mm,pz_mm\n-250,10,200\n-260,20,205\n-270,0,210\n" if targets else
            "x_mm,z_mm,a_deg,feed\n10,5,0,100\n20,6,45,100\n30,7,90,100\n")
    raw = data.draw(mangled(text))
    reads_or_refuses(lambda p: read_as_compensate(p, machine), raw, ".csv")


@FUZZ
@given(data=st.data())
def test_fuzz_element_set_reader(sim, machine, data):
    from errormap.chain_elements import ChainElementSet
    d = json.loads((sim / "sim" / "truth_elements.json").read_text())
    # one value anywhere in the document replaced by an absurd JSON value, or the bytes mangled
    paths = []

    def walk(o, at):
        if isinstance(o, dict):
            for k, v in o.items():
                walk(v, at + [k])
        elif isinstance(o, list):
            for i, v in enumerate(o[:3]):
                walk(v, at + [i])
        paths.append(at)
    walk(d, [])
    at = data.draw(st.sampled_from(paths[:-1]))
    value = data.draw(st.one_of(st.sampled_from([None, True, "x", [], {}, [[1, 2], 3], 1e308, -1e308, 10**400]),
                                st.floats(allow_nan=True, allow_infinity=True)))
    o = d
    for k in at[:-1]:
        o = o[k]
    o[at[-1]] = value
    text = json.dumps(d, allow_nan=True)
    raw = data.draw(st.one_of(st.just(text.encode()), mangled(text)))
    reads_or_refuses(lambda p: ChainElementSet.load(p, machine), raw, ".json")


TOML_VALUES = st.one_of(
    st.sampled_from(['["grinder"]', '"grinder"', '"hexapod"', '"tripod"', "1e308", "-1e308", "nan", "inf",
                     "true", '"x"', "[]", "[[0, 0], 1]", "[1, 2]", "[0, 6.283]", "[[1,2,3],[4,5,6]]",
                     "{a = 1}", "1979-05-27", "99999999999999999999999999", "0", "-1", "[true, 1, 2]",
                     '[1, "a", 2]', "[[1,2,3],[4,5,6],[7,8]]"]),
    st.floats(allow_nan=False, allow_infinity=False, width=64).map(repr))


@st.composite
def mangled_toml(draw, text: str) -> bytes:
    lines = text.split("\n")
    keyed = [i for i, l in enumerate(lines) if "=" in l and not l.lstrip().startswith("#")]
    kind = draw(st.sampled_from(["value", "value", "value", "drop", "extra", "bytes"]))
    if kind == "value":
        k = draw(st.sampled_from(keyed))
        lines[k] = lines[k].split("=", 1)[0] + "= " + draw(TOML_VALUES)
    elif kind == "drop":
        del lines[draw(st.sampled_from(keyed))]
    elif kind == "extra":
        lines.insert(draw(st.integers(0, len(lines))), "zz = 1")
    raw = "\n".join(lines).encode("utf-8")
    if kind == "bytes":
        k = draw(st.integers(0, len(raw)))
        raw = raw[:k] + draw(st.binary(min_size=1, max_size=3)) + raw[k:]
    return raw


@pytest.mark.parametrize("kind", ["grinder", "hexapod", "tripod"])
@FUZZ
@given(data=st.data())
def test_fuzz_machine_files(kind, data):
    raw = data.draw(mangled_toml(builtin_machine_path(kind).read_text(encoding="utf-8")))
    reads_or_refuses(load_machine, raw, ".toml")


# -- through the command line ----------------------------------------------------------------
def run_main(argv):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, err.getvalue()


@settings(max_examples=25, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_fuzz_main_predict_and_featurepoints(sim, data):
    """``main`` on mangled points and machine files: exit 0, or exit 2 with one line of bounded length."""
    el = str(sim / "sim" / "truth_elements.json")
    points = data.draw(mangled("x_mm,z_mm,a_deg\n" + "\n".join(f"{10 * i},{3 * i},{20 * i}" for i in range(12)) + "\n"))
    machine = data.draw(mangled_toml(builtin_machine_path("grinder").read_text(encoding="utf-8")))
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "p.csv").write_bytes(points)
        (Path(d) / "m.toml").write_bytes(machine)
        for argv in (["predict", "--model", el, str(Path(d) / "p.csv"), "--out", str(Path(d) / "o.csv")],
                     ["featurepoints", "--machine", str(Path(d) / "m.toml"), "--elements", el, "--grid", "2",
                      "--out", str(Path(d) / "fp.csv")]):
            rc, err = run_main(argv)
            assert rc in (0, 2), err
            if rc == 2:
                line = err.strip().split("\n")[-1]
                assert line.startswith(f"volcomp {argv[0]}: error: ") and len(line) <= MAX_ERROR_CHARS


ISSUE_CASES = {
    # the inputs the issue found giving tracebacks: each must be one line, exit 2
    "latin1": (b"# M\xfcller\nx_mm,z_mm,a_deg\n1,2,3\n", "row 1, character 4"),
    "station": (None, "column 'station'"),
    "pz": (b"px_mm,py_mm,pz_mm\n-250,10,1e300\n", "row 2, column 'pz_mm'"),
}


def test_issue_cases_are_one_line_exit_2(sim, tmp_path):
    el = str(sim / "sim" / "truth_elements.json")
    p = tmp_path / "latin.csv"
    p.write_bytes(ISSUE_CASES["latin1"][0])
    rc, err = run_main(["predict", "--model", el, str(p), "--out", str(tmp_path / "o.csv")])
    assert rc == 2 and ISSUE_CASES["latin1"][1] in err and err.count("\n") == 1
    # a BOM (Excel's "CSV UTF-8") is accepted
    p.write_bytes(b"\xef\xbb\xbfx_mm,z_mm,a_deg\n1,2,3\n")
    assert run_main(["predict", "--model", el, str(p), "--out", str(tmp_path / "o.csv")])[0] == 0
    # a sweep station of 1e10 is refused by its row and column (and does not allocate 74 GiB)
    lines = (sim / "sweeps.csv").read_text().split("\n")
    h = next(i for i, l in enumerate(lines) if l and not l.startswith("#"))
    j = lines[h].split(",").index("station")
    for big in ("10000000000", "1000000"):
        row = lines[h + 1].split(",")
        row[j] = big
        (tmp_path / "sw.csv").write_text("\n".join(lines[: h + 1] + [",".join(row)] + lines[h + 2:]))
        rc, err = run_main(["identify", str(tmp_path / "sw.csv"), "--out", str(tmp_path / "id")])
        assert rc == 2 and f"row {h + 2}, column 'station'" in err and len(err) <= MAX_ERROR_CHARS + 1
    p = tmp_path / "t.csv"
    p.write_bytes(ISSUE_CASES["pz"][0])
    rc, err = run_main(["compensate", str(p), "--model", el, "--method", "exact", "--out", str(tmp_path / "c")])
    assert rc == 2 and ISSUE_CASES["pz"][1] in err
    grinder = OLD_GRINDER_FILE.read_text()   # a kind = "grinder" file: its schema's keys are refused by name
    for old, new, key in (('kind = "grinder"', 'kind = ["grinder"]', "machine.kind"),
                          ("l1 = 420.0", "l1 = 1e308", "geometry.l1"),
                          ("a_deg = [0.0, 360.0]", "a_deg = [0, 6.283]", "strokes.a_deg")):
        (tmp_path / "m.toml").write_text(grinder.replace(old, new))
        rc, err = run_main(["simulate", "--machine", str(tmp_path / "m.toml"), "--out", str(tmp_path / "s")])
        assert rc == 2 and key in err and err.count("\n") == 1, err
    hexapod = builtin_machine_path("hexapod").read_text()
    import re
    (tmp_path / "h.toml").write_text(re.sub(r"tool_tip_mm = .*", "tool_tip_mm = [[0, 0], 1]", hexapod))
    with pytest.raises(MachineFileError, match="home.tool_tip_mm"):
        load_machine(tmp_path / "h.toml")


# --- every command's file kinds and bounded options, through main: right output or one line -------
# Each example draws one input file of the command's kind (a valid file with one mutation, among
# them the hostile kinds: UTF-16, CR-only endings, a CSV given as a program, NaN, huge numbers) and
# the command's bounded options (in and out of range). Outcomes: exit 0 whose output is checked
# against the library computed on the same input ("silent wrong" otherwise), or exit 2 with ONE
# line naming the input file or the option; anything else (a traceback, exit 1) fails.
TALLY: dict = {}
"""Per command: inputs tried, exits 0 with the output checked, exits 2 with one line, tracebacks, silent wrong."""


def _count(command: str, what: str) -> None:
    c = TALLY.setdefault(command, dict.fromkeys(("inputs", "exit_0_checked", "exit_2_one_line", "tracebacks",
                                                 "silent_wrong"), 0))
    c[what] += 1
# an exact compensation lands on its target under the model within the solver's tolerance plus the
# 6-decimal rounding of the written program (as tests/test_compensate_cli.py)
TOL_LANDING_MM = 1e-6 + 2e-6
# predict writes 9 significant digits: relative 1e-8 with an absolute floor for values near zero
TOL_PREDICT_REL, TOL_PREDICT_ABS_UM = 1e-8, 1e-9
CLI_FUZZ = settings(max_examples=int(os.environ.get("VOLCOMP_FUZZ_EXAMPLES", "0")) or 40, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
PROGRAM = ("%\n(flute, op 1)\nG21 G90 G18\nG0 X100. Z0.3 A0\nG1 X105. Z1.3 A10. F100\n"
           "G2 X110. Z6.3 A10. I0 K5.\nG1 X112.5 Z8.0 A20.\nM30\n%\n")
PROGRAM_WORD_JUNK = ["", "(note, 2)", "F200", "G21", "G90", "X", "X-", "X1e5", "X110000", "Z.", "A1..2", "G91", "G17", "G20", "G4 P1", "M98 P100",
                     "N10 G1 X1 X2", "(unclosed", "G1 X100. Z0.3 A0 I5", "#1=5", "G1 X[1+2]", "\x00", "ü", ";"]


@st.composite
def hostile_bytes(draw, text: str, table: bool) -> bytes:
    """``text`` with one mutation: a table's (:func:`mangled`) or a program's, or one of the kinds a
    careless save makes of any file (UTF-16, CR-only endings, NUL bytes, a foreign CSV)."""
    kind = draw(st.sampled_from(["own", "none", "own", "own", "utf16", "cr", "nul", "csv", "empty"]))
    if kind == "none":
        return text.encode()
    if kind == "own" and table:
        return draw(mangled(text))
    if kind == "own":
        lines = text.split("\n")
        k = draw(st.integers(0, len(lines) - 1))
        junk = draw(st.one_of(st.sampled_from(PROGRAM_WORD_JUNK), st.text(max_size=16)))
        how = draw(st.sampled_from(["replace", "insert", "append"]))
        lines[k:k + 1] = {"replace": [junk], "insert": [junk, lines[k]], "append": [lines[k] + " " + junk]}[how]
        return "\n".join(lines).encode("latin-1", errors="replace")
    if kind == "utf16":
        return text.encode(draw(st.sampled_from(["utf-16", "utf-16-le", "utf-16-be"])))
    if kind == "cr":
        return text.replace("\n", "\r").encode()
    if kind == "nul":
        raw = text.encode()
        k = draw(st.integers(0, len(raw)))
        return raw[:k] + b"\x00" * draw(st.integers(1, 8)) + raw[k:]
    if kind == "csv":
        return b"X,Z,A\n100,0.3,0\n110,0.5,30\n"
    return b""


def _tally_outcome(argv, rc, err, names) -> bool:
    """Count one run; True when it exited 0 (the caller then checks the output)."""
    _count(argv[0], "inputs")
    if "Traceback" in err or rc not in (0, 2):
        _count(argv[0], "tracebacks")
        raise AssertionError((argv, rc, err))
    if rc == 0:
        return True
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(lines) == 1 and len(lines[0]) <= MAX_ERROR_CHARS + 40, (argv, err)
    assert any(n in lines[0] for n in names), (argv, names, lines[0])
    _count(argv[0], "exit_2_one_line")
    return False


def _check_output(command: str, ok: bool, what) -> None:
    """An exit 0's output, checked: counted, and a wrong one fails."""
    _count(command, "exit_0_checked" if ok else "silent_wrong")
    assert ok, what


def report_tally():
    """The module's fuzz tally printed (``VOLCOMP_FUZZ_TALLY=FILE``: also written there as JSON)."""
    print(f"\nCLI fuzz tally: {TALLY}")
    if os.environ.get("VOLCOMP_FUZZ_TALLY"):
        Path(os.environ["VOLCOMP_FUZZ_TALLY"]).write_text(json.dumps(TALLY, indent=1))


@pytest.fixture(scope="module")
def tally():
    yield TALLY
    report_tally()


@CLI_FUZZ
@given(data=st.data())
def test_fuzz_main_predict_checks_its_output(sim, machine, tally, data):
    """predict on hostile point files: exit 0 writes exactly the element set's prediction of the
    rows it read (compared with the library on the same file), or one line naming the file."""
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.io import read_table
    el = sim / "sim" / "truth_elements.json"
    raw = data.draw(hostile_bytes("x_mm,z_mm,a_deg\n" + "\n".join(f"{10 * i},{3 * i},{20 * i}" for i in range(12)) + "\n",
                                  table=True))
    with tempfile.TemporaryDirectory() as d:
        p, o = Path(d) / "p.csv", Path(d) / "o.csv"
        p.write_bytes(raw)
        argv = ["predict", "--model", str(el), str(p), "--out", str(o)]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p)]):
            t_in, t_out = read_table(p), read_table(o)
            axes = np.stack([t_in.float(c) for c in ("x_mm", "z_mm", "a_deg")], axis=1)
            want = ChainField(machine, ChainElementSet.load(el, machine)).predict(axes)
            got = np.stack([t_out.float(c) for c in ("dx_um", "dy_um", "dz_um")], axis=1)
            _check_output("predict", got.shape == want.shape and np.allclose(got, want, rtol=TOL_PREDICT_REL,
                                                                  atol=TOL_PREDICT_ABS_UM), (argv, got, want))


@pytest.mark.slow  # 40 compensations with their read-back: about 8 CPU s
@CLI_FUZZ
@given(data=st.data(), arc=st.sampled_from(["0.5", "5", "0.001", "0.5", "1e9", "5.01", "nan"]),
       seg=st.sampled_from(["none", "auto", "0.5", "100", "none", "1e-6", "fast"]))
def test_fuzz_main_compensate_checks_its_output(sim, machine, tally, data, arc, seg):
    """compensate on hostile programs and its bounded options: exit 0 writes a program that lands
    on the input's targets under the model (read back and checked), or one line naming the file or
    the option."""
    from compensation.nc_state import MACHINE, read_work_offsets
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.chain_kernel import forward
    from path_files import read_as_compensate
    el = sim / "sim" / "truth_elements.json"
    raw = data.draw(hostile_bytes(PROGRAM, table=False))
    with tempfile.TemporaryDirectory() as d:
        p, out = Path(d) / "part.nc", Path(d) / "out"
        p.write_bytes(raw)
        argv = ["compensate", str(p), "--model", str(el), "--method", "exact", "--out", str(out),
                "--arc-tolerance-um", arc, "--max-segment-mm", seg, "--work-offsets", "machine"]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p), "--arc-tolerance-um", "--max-segment-mm"]):
            field = ChainField(machine, ChainElementSet.load(el, machine))
            seg_mm = {"auto": "auto", "none": None}.get(seg) if seg in ("auto", "none") else float(seg)
            mcs = read_work_offsets(MACHINE)  # PROGRAM is in machine coordinates
            src = read_as_compensate(p, machine, field, arc_tolerance_um=float(arc), max_segment_mm=seg_mm,
                                     work_offsets=mcs)
            res = read_as_compensate(out / p.name, machine, max_segment_mm=None, work_offsets=mcs)
            lands = forward(machine, res.axes) + 1e-3 * field.predict(res.axes)
            # the end of every programmed block (the last point of each source line) is landed by a written point
            last = np.r_[src.lines[1:] != src.lines[:-1], True]
            ends = np.linalg.norm(forward(machine, src.axes[last])[:, None, :] - lands[None], axis=2).min(axis=1)
            _check_output("compensate", ends.max() < TOL_LANDING_MM, (argv, len(res), len(src), ends.max()))


@pytest.mark.slow  # 6.5 CPU s measured
@CLI_FUZZ
@given(data=st.data())
def test_fuzz_main_other_file_kinds(sim, machine, tally, data):
    """The other file kinds through their commands: an element set (featurepoints), a covariance
    companion (predict --band), a chain machine file (sweeps --machine) — exit 0 with the output
    checked, or one line naming the file."""
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.io import read_table
    kind = data.draw(st.sampled_from(["elements", "covariance", "chain_machine"]))
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        if kind == "elements":
            src = d / "el.json"
            src.write_bytes(data.draw(hostile_bytes((sim / "sim" / "truth_elements.json").read_text(), table=True)))
            argv = ["featurepoints", "--elements", str(src), "--grid", "2", "--out", str(d / "fp.csv")]
            rc, err = run_main(argv)
            if _tally_outcome(argv, rc, err, [str(src)]):
                t = read_table(d / "fp.csv")
                axes = np.stack([t.float(c) for c in ("x_mm", "z_mm", "a_deg")], axis=1)
                got = np.stack([t.float(c) for c in ("dx_um", "dy_um", "dz_um")], axis=1)
                want = ChainField(machine, ChainElementSet.load(src, machine)).predict(axes)
                _check_output("featurepoints", len(t) == 8 and np.allclose(got, want, rtol=TOL_PREDICT_REL,
                                                                           atol=TOL_PREDICT_ABS_UM), argv)
        elif kind == "covariance":
            for name in ("E.json", "E.cov.npz"):
                (d / name).write_bytes((sim / "ident" / name).read_bytes())
            cov = d / "E.cov.npz"
            raw = cov.read_bytes()
            cut = data.draw(st.integers(0, len(raw)))
            how = data.draw(st.sampled_from(["cut", "flip", "keep"]))
            if how == "cut":
                raw = raw[:cut]
            elif how == "flip" and raw:
                b = bytearray(raw)
                b[min(cut, len(b) - 1)] ^= 0xFF
                raw = bytes(b)
            cov.write_bytes(raw)
            (d / "p.csv").write_text("x_mm,z_mm,a_deg\n10,20,30\n50,30,200\n")
            argv = ["predict", str(d / "p.csv"), "--model", str(d / "E.json"), "--band", "95", "--out", str(d / "o.csv")]
            rc, err = run_main(argv)
            if _tally_outcome(argv, rc, err, [str(cov), str(d / "E.json")]):
                t = read_table(d / "o.csv")
                bands = [c for c in t.names if "band" in c]
                _check_output("predict", len(t) == 2 and len(bands) == 3 and all(
                    np.all(np.isfinite(t.float(c)) & (t.float(c) >= 0)) for c in bands), (argv, t.names))
        else:
            src = d / "mill.toml"
            src.write_bytes(data.draw(hostile_bytes(builtin_machine_path("mill-xyz").read_text(), table=False)))
            argv = ["sweeps", "--machine", str(src), "--seed", "1", "--out", str(d / "sw.csv")]
            rc, err = run_main(argv)
            if _tally_outcome(argv, rc, err, [str(src)]):
                from errormap.sweeps import read_sweeps
                sw = read_sweeps(d / "sw.csv", load_machine(src))
                _check_output("sweeps", len(read_table(d / "sw.csv")) > 0 and sw is not None, argv)
