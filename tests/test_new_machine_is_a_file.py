"""A newcomer's machine is a file (issue 26): a gantry mill written here, in the test, from
docs/how-to/machine-file.md alone — not one of the built-in files — goes through the user's whole measurement
path with no code added: `volcomp machines`-style loading, simulate (truth hidden), tracker sweeps,
identify, diagnose, and compensate a 3-axis program with the loop's model."""
import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.machine import load_machine

GANTRY_TOML = """
[machine]
kind = "machine-tool"
schema = 1
name = "gantry-test"
description = "gantry mill: fixed table; X gantry, Y carriage on it, Z ram carry the tool"

[geometry]
table_height = 300.0
beam_height = 1400.0
ram_length = 500.0

[[work]]
tz = "table_height"

[[tool]]
joint = "linear"
axis = "X"
stroke = [0.0, 1500.0]
[[tool]]
joint = "linear"
axis = "Y"
stroke = [0.0, 800.0]
squareness = [{ name = "s_xy", toward = "x", iso = "EC0Y" }]
[[tool]]
tz = "beam_height"
[[tool]]
joint = "linear"
axis = "Z"
stroke = [-500.0, 0.0]
squareness = [{ name = "s_xz", toward = "x", iso = "EB0Z" }, { name = "s_yz", toward = "y", iso = "EA0Z" }]
[[tool]]
tz = "-ram_length"

[targets]
X = [[-300.0, -200.0, 200.0], [300.0, -200.0, 200.0], [0.0, 250.0, 260.0]]
Y = [[-200.0, -100.0, 150.0], [200.0, -100.0, 150.0], [0.0, 150.0, 200.0]]
Z = [[-80.0, 0.0, 60.0], [80.0, -60.0, 60.0], [0.0, 90.0, 150.0]]
"""

PROGRAM = """%
(gantry test: a pocket outline)
G21 G90 G17 G54
T1 M6
G0 X100. Y100. Z-100.
G1 Z-350. F500.
G1 X700. Y150.
G2 X900. Y350. I0. J200.
G1 Y600.
G3 X700. Y600. R100.
G1 X100. Y600.
G0 Z-100.
M30
%
"""

FLOOR_RATIO = 1.25
"""The issue's goal: held-out measured RMS within 1.25 × the noise floor √3·σ."""
TRUE_RMS_MAX_UM = np.sqrt(3.0)
"""Compensated with the loop's model, the TRUE residual of the program stays below the check noise
floor √3·1 μm (the model is fitted to checks of 1 μm noise; on the built-in mill it reaches 0.7 μm)."""


@pytest.mark.slow
def test_a_gantry_mill_written_in_a_file_goes_through_the_whole_path(tmp_path, capsys):
    mf = tmp_path / "gantry.toml"
    mf.write_text(GANTRY_TOML, encoding="utf-8")
    m = load_machine(str(mf))
    assert m.kind == "machine-tool" and tuple(m.axis_columns) == ("x_mm", "y_mm", "z_mm")
    assert len(m.slot_names) == 18 + 3  # six component errors per axis + the three squareness slots named in the file
    base = ["--machine", str(mf), "--seed", "4", "--family", "independent"]
    assert main(["sweeps", *base, "--out", str(tmp_path / "sw.csv")]) == 0
    assert main(["simulate", *base, "--checks", "800", "--out", str(tmp_path / "sim")]) == 0
    assert main(["identify", str(tmp_path / "sw.csv"), "--machine", str(mf), "--out", str(tmp_path / "E.json")]) == 0
    assert main(["diagnose", str(tmp_path / "sim" / "checks.csv"), "--machine", str(mf), "--model",
                 str(tmp_path / "E.json"), "--noise-um", "1", "--out", str(tmp_path / "d")]) == 0
    s = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert s["held_out_over_floor"] <= FLOOR_RATIO
    assert s["effects"] == []  # no effect was simulated: none reported
    prog = tmp_path / "pocket.nc"
    prog.write_text(PROGRAM, encoding="utf-8")
    capsys.readouterr()
    assert main(["compensate", str(prog), "--machine", str(mf), "--model", str(tmp_path / "d" / "model.json"),
                 "--method", "exact", "--truth", str(tmp_path / "sim" / "truth.json"), "--work-offsets", "machine",
                 "--out", str(tmp_path / "c")]) == 0
    f = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert f["failures"] == 0 and f["model_max_um"] <= 1e-6
    # TRUE: the hidden truth driven with the compensated commands (measured 0.65 μm RMS, 1.18 max,
    # against 71 μm RMS uncompensated)
    assert f["true"]["rms_um"] < TRUE_RMS_MAX_UM < f["true_uncompensated"]["rms_um"]
    out = next(p for p in (tmp_path / "c").iterdir() if p.suffix == ".nc").read_text()
    for line in PROGRAM.splitlines():  # every line without motion words passes through byte for byte
        if not any(w in line for w in ("X", "Y", "Z")) or line.startswith("("):
            assert line in out.splitlines()
