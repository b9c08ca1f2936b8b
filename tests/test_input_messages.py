"""Misleading messages and tracebacks on damaged or foreign inputs, each one line naming the file
and what to do (a truncated ``E.cov.npz`` was a BadZipFile traceback; a NaN element said "got shape
(21,)"; CR-only endings said "repeated 'X' word"; UTF-16 suggested Latin-1; a CSV given where a
program is expected said a G-code word error)."""
from __future__ import annotations

import json
import subprocess

import pytest

from test_output_safety import one_line, run_cli

PROGRAM = "G21 G90 G18\nG1 X100. Z0.3 A0 F100\nG1 X110. Z0.5 A30\n"


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """sweeps → identify: E.json with its covariance E.cov.npz."""
    d = tmp_path_factory.mktemp("ident")
    assert run_cli(["sweeps", "--seed", "1", "--out", d / "sw.csv"])[0] == 0
    rc, _, err = run_cli(["identify", d / "sw.csv", "--out", d / "E.json"])
    assert rc == 0, err
    return d


@pytest.fixture
def points(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("x_mm,z_mm,a_deg\n10,20,30\n")
    return p


def _damage(raw: bytes, how: str) -> bytes:
    if how == "flipped":
        b = bytearray(raw)
        b[200] ^= 0xFF  # inside the first member's compressed data: a bad CRC when it is read
        return bytes(b)
    return raw[: {"truncated": len(raw) // 2, "header_only": 100, "empty": 0}[how]]


@pytest.mark.parametrize("how", ["truncated", "header_only", "empty", "flipped"])
def test_predict_band_with_a_damaged_covariance(tmp_path, identified, points, how):
    el = tmp_path / "E.json"
    el.write_bytes((identified / "E.json").read_bytes())
    cov = tmp_path / "E.cov.npz"
    cov.write_bytes(_damage((identified / "E.cov.npz").read_bytes(), how))
    rc, _, err = run_cli(["predict", points, "--model", el, "--band", "95", "--out", tmp_path / "p.csv"])
    one_line(rc, err, str(cov), "not a readable covariance file", "identify")
    assert not (tmp_path / "p.csv").exists()


def test_sweeps_on_a_chain_machine_file_without_targets(tmp_path):
    from errormap.machine import builtin_machine_path
    src = builtin_machine_path("mill-xyz").read_text().split("\n")
    out, skip = [], False
    for line in src:
        if line.startswith("["):
            skip = line.strip() == "[targets]"
        if not skip:
            out.append(line)
    m = tmp_path / "no_targets.toml"
    m.write_text("\n".join(out))
    rc, _, err = run_cli(["sweeps", "--machine", m, "--seed", "1", "--out", tmp_path / "sw.csv"])
    one_line(rc, err, str(m), "no [targets] for axis X, Y, Z", "three target balls")


@pytest.mark.parametrize("bad", [float("nan"), None, float("inf")])
def test_nan_in_an_element_set_names_element_and_station(tmp_path, grinder, points, bad):
    from errormap.chain_truth import make_chain_truth
    el = make_chain_truth(grinder, 3).elements.save(tmp_path / "el.json")
    d = json.loads(el.read_text())
    d["functions"]["ex_x"][4] = bad
    el.write_text(json.dumps(d))
    stations = d["stations"]["x_mm"]
    rc, _, err = run_cli(["predict", points, "--model", el, "--out", tmp_path / "p.csv"])
    line = one_line(rc, err, str(el), "element 'ex_x': value 5 of 21", f"x_mm station {stations[4]:g}")
    assert "shape" not in line


def test_nan_in_a_chain_element_set(tmp_path):
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    el = make_chain_truth(load_machine("mill-xyz"), 3).elements.save(tmp_path / "el.json")
    d = json.loads(el.read_text())
    name = next(iter(d["functions"]))
    d["functions"][name][2] = None
    el.write_text(json.dumps(d))
    p = tmp_path / "p.csv"
    p.write_text("x_mm,y_mm,z_mm\n10,20,-30\n")
    rc, _, err = run_cli(["predict", p, "--machine", "mill-xyz", "--model", el, "--out", tmp_path / "o.csv"])
    one_line(rc, err, str(el), f"element '{name}': value 3 of", "NaN, null or infinity")


@pytest.fixture
def model(tmp_path, grinder):
    from errormap.chain_truth import make_chain_truth
    return make_chain_truth(grinder, 3).elements.save(tmp_path / "model.json")


def _compensate(tmp_path, model, src):
    return run_cli(["compensate", "--work-offsets", "machine",
                    src, "--model", model, "--method", "traditional", "--out", tmp_path / "o"])


def test_cr_only_line_endings(tmp_path, model):
    """CR-only ends throughout: read line by line and written back with CR (tests/test_gcode_unknown_position.py);
    CR-only at the start and LF further on (mixed): one line naming the file, not "repeated 'X' word"."""
    src = tmp_path / "mac.nc"
    src.write_bytes(PROGRAM.replace("\n", "\r").encode())
    rc, _, err = _compensate(tmp_path, model, src)
    assert rc == 0, err
    assert b"\n" not in (tmp_path / "o" / "mac.nc").read_bytes()
    src = tmp_path / "mixed" / "mac.nc"
    src.parent.mkdir()
    src.write_bytes(("G21 G90 G18\r" + "G1 X100. Z0.3 A0 F100\r" * 4000 + "G1 X110. Z0.5 A30\n").encode())
    rc, _, err = _compensate(src.parent, model, src)
    line = one_line(rc, err, str(src), "CR-only line endings", "convert")
    assert "repeated" not in line and "mixed" in line


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be"])
@pytest.mark.parametrize("kind", ["gcode", "csv", "machine"])
def test_utf16_detected_not_latin1(tmp_path, model, points, encoding, kind):
    if kind == "gcode":
        src = tmp_path / "p.nc"
        src.write_bytes(PROGRAM.encode(encoding))
        rc, _, err = _compensate(tmp_path, model, src)
    elif kind == "csv":
        src = tmp_path / "pts16.csv"
        src.write_bytes(points.read_text().encode(encoding))
        rc, _, err = run_cli(["predict", src, "--model", model, "--out", tmp_path / "p.csv"])
    else:
        from errormap.machine import builtin_machine_path
        src = tmp_path / "m.toml"
        src.write_bytes(builtin_machine_path("grinder").read_text().encode(encoding))
        rc, _, err = run_cli(["simulate", "--machine", src, "--out", tmp_path / "s"])
    line = one_line(rc, err, str(src), "UTF-16 text detected", "re-save it as UTF-8")
    assert "Latin-1" not in line


@pytest.mark.parametrize("text,header", [("X,Z,A\n100,0.3,0\n110,0.5,30\n", "X, Z, A"),
                                         ("# exported\nx,z,a\n100,0.3,0\n", "x, z, a"),
                                         ("pos x,pos z,angle\n1,2,3\n4,5,6\n", "pos x, pos z, angle")])
def test_a_csv_where_a_program_is_expected_is_named_a_csv(tmp_path, model, text, header):
    src = tmp_path / "path.nc"   # named like a program: recognised by content
    src.write_text(text)
    rc, _, err = _compensate(tmp_path, model, src)
    one_line(rc, err, str(src), f"is a CSV header ({header})", "x_mm, z_mm, a_deg", "px_mm, py_mm, pz_mm")


def test_gcode_with_commas_in_comments_is_still_gcode(tmp_path, model):
    src = tmp_path / "ok.nc"
    src.write_text("(part 7, op 2, flute)\n" + PROGRAM)
    rc, _, err = _compensate(tmp_path, model, src)
    assert rc == 0, err


def test_a_spindle_speed_no_spindle_reaches_is_refused_naming_row_and_column(tmp_path):
    """Found by the CLI fuzz (tests/test_fuzz_commands.py): a speed cell of 6.3e9 rpm was read, and drift-predict
    wrote a drift of -1e12 μm from it. A speed outside drift.SPEED_RANGE_RPM is now refused by the log's reader."""
    import numpy as np

    from errormap.diagnosis.drift import SPEED_RANGE_RPM, load_drift_log
    from errormap.diagnosis.drift_sim import simulate_lumped_log
    from errormap.io import InputError, write_csv
    cols = simulate_lumped_log(seed=0, hours=2.0)
    n = len(cols["time_s"])
    cols = {k: np.array(v, float) for k, v in cols.items() if np.ndim(v) == 1 and len(v) == n}
    write_csv(tmp_path / "ok.csv", cols)
    assert load_drift_log(tmp_path / "ok.csv", causal=True, require_displacement=False).speed_rpm is not None
    cols["speed_rpm"][3] = 6275724086.0
    write_csv(tmp_path / "log.csv", cols)
    with pytest.raises(InputError, match=r"row 5, column 'speed_rpm': 6\.27572e\+09 rpm is outside the plausible"):
        load_drift_log(tmp_path / "log.csv", causal=True, require_displacement=False)
    assert SPEED_RANGE_RPM[1] >= 12000.0    # the simulated spindle's top speed passes
