"""`volcomp calibrate` and `volcomp interpolate` fuzzed through ``main``: a mangled pose file,
waypoint file, calibration file or machine file gives exit 0, or exit 2 with one bounded line
naming the command — never a traceback, never a half-written output."""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compensation.app.cli import MAX_ERROR_CHARS
from errormap.machine import builtin_machine_path, load_machine
from errormap.pkm.simulate import simulate_hexapod_poses
from test_fuzz_inputs import mangled, mangled_toml, run_main

# Each example runs a whole calibration (~1 s on 2 cores) or interpolation: few examples, fixed order.
PKM_FUZZ = settings(max_examples=10, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])
N_POSES = 40        # enough poses for the calibration to run; few enough to keep each example short
NOISE_UM = 5.0
WAYPOINTS = "px_mm,py_mm,pz_mm\n0,0,600\n20,0,600\n20,20,610\n0,20,610\n0,0,600\n"


def _exit_0_or_one_line_2(argv, out_paths=()):
    rc, err = run_main(argv)
    assert rc in (0, 2), err
    if rc == 2:
        line = err.strip().split("\n")[-1]
        assert line.startswith(f"volcomp {argv[0]}: error: ") and len(line) <= MAX_ERROR_CHARS, line
        for p in out_paths:  # a refused run leaves nothing behind
            assert not Path(p).exists(), p
    return rc


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    d = tmp_path_factory.mktemp("cal")
    sim = simulate_hexapod_poses(load_machine(expect_kind="hexapod"), N_POSES, NOISE_UM, seed=5)
    sim.write_csv(d / "poses.csv")
    assert run_main(["calibrate", str(d / "poses.csv"), "--out", str(d / "cal"), "--noise-um", str(NOISE_UM)])[0] == 0
    return d


@pytest.mark.slow  # a full calibration per drawn file: 6.7 CPU s (tier rule: > 5 s)
@PKM_FUZZ
@given(data=st.data())
def test_fuzz_calibrate_poses(calibration, data):
    raw = data.draw(mangled((calibration / "poses.csv").read_text(encoding="utf-8")))
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "p.csv").write_bytes(raw)
        out = Path(d) / "o"
        rc = _exit_0_or_one_line_2(["calibrate", str(Path(d) / "p.csv"), "--out", str(out),
                                    "--noise-um", str(NOISE_UM)], [out])
        if rc == 0:
            assert (out / "model.json").is_file()


@PKM_FUZZ
@given(data=st.data())
def test_fuzz_interpolate_waypoints_and_machine(calibration, data):
    raw = data.draw(mangled(WAYPOINTS))
    machine = data.draw(mangled_toml(builtin_machine_path("hexapod").read_text(encoding="utf-8")))
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "w.csv").write_bytes(raw)
        (Path(d) / "m.toml").write_bytes(machine)
        out1, out2 = Path(d) / "prog1.csv", Path(d) / "prog2.csv"
        _exit_0_or_one_line_2(["interpolate", str(Path(d) / "w.csv"), "--out", str(out1)], [out1])
        _exit_0_or_one_line_2(["interpolate", "sphere", "--machine", str(Path(d) / "m.toml"), "--out", str(out2)], [out2])


@PKM_FUZZ
@given(data=st.data())
def test_fuzz_interpolate_calibration_file(calibration, data):
    doc = json.loads((calibration / "cal" / "model.json").read_text(encoding="utf-8"))
    text = json.dumps(doc, indent=0)
    raw = data.draw(mangled(text))
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "model.json").write_bytes(raw)
        out = Path(d) / "prog.csv"
        _exit_0_or_one_line_2(["interpolate", "sphere", "--calibration", str(Path(d) / "model.json"),
                               "--out", str(out)], [out])
