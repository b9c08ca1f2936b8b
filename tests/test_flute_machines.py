"""One rule says where the flute path runs (compensation.toolpath.runs_flute): the demo, report --flute, the
benchmark's test part and the export check's flute set all ask it. A user's X, Y, A grinder (the wheel fed
radially by Y, not Z) runs the flute everywhere; the same machine with an A that does not turn fully runs it
nowhere."""
import numpy as np
import pytest

from compensation.app.cli import build_parser
from compensation.app.families import family_of
from compensation.app.validate import UsageError
from compensation.app.workflows.benchmark_common import quick_settings
from compensation.app.workflows.benchmark_paths import judging_path
from compensation.app.workflows.demo import PROGRAM_DECIMALS, PROGRAM_FEED, write_flute_program
from compensation.export import check_sets
from compensation.toolpath import check_in_strokes, flute_path, runs_flute
from errormap.chain_kernel import forward
from errormap.machine import load_machine

TOL_MM = 1e-9
"""The closed-form inverse's round trip (nominal tool points of the flute's axes against its targets)."""

XYA_TOML = """
[machine]
kind = "machine-tool"
schema = 1
name = "xya-flute-test"
description = "X-Y-A flute grinder: X carriage and A spindle carry the workpiece, the Y slide feeds the wheel"

[geometry]
wheel_x = 200.0
wheel_y = -30.0

[[work]]
joint = "linear"
axis = "X"
stroke = [0.0, 200.0]
[[work]]
joint = "rotary"
axis = "A"
stroke = [0.0, A_END]

[[tool]]
tx = "wheel_x"
[[tool]]
ty = "wheel_y"
[[tool]]
joint = "linear"
axis = "Y"
stroke = [0.0, 50.0]

[targets]
X = [[0.0, -60.0, 40.0], [80.0, 40.0, 40.0], [-40.0, 60.0, 90.0]]
Y = [[0.0, -50.0, 0.0], [60.0, 30.0, 20.0], [-50.0, 40.0, 60.0]]
A = [[10.0, 45.0, 0.0], [40.0, -25.0, 40.0], [70.0, -30.0, -35.0]]
"""


def _machine(tmp_path, a_end_deg):
    path = tmp_path / f"xya-{a_end_deg:g}.toml"
    path.write_text(XYA_TOML.replace("A_END", f"{a_end_deg:.1f}"), encoding="utf-8")
    return load_machine(str(path))


def _decisions(machine) -> dict:
    """Whether the demo, report --flute, the benchmark and the export check each take the flute."""
    family = family_of(machine)
    args = build_parser(["report"]).parse_args(["report", "--machine", str(machine.path), "--model", "E.json",
                                                "--flute", "--out", "o"])
    try:
        family.refuse_unsupported("report", args)
        report = True
    except UsageError as exc:
        assert "flute needs" in str(exc)
        report = False
    try:
        bench = judging_path(machine, quick_settings()).name.startswith("flute")
    except ValueError as exc:
        assert "the flute needs" in str(exc)
        bench = False
    return {"rule": runs_flute(machine), "demo": family.runs("demo"), "report --flute": report,
            "benchmark": bench, "export check": "flute" in check_sets(machine, n_volume=10)}


def test_built_in_machine_tools_run_the_flute_only_on_the_grinder():
    for name, runs in (("grinder", True), ("mill-xyz", False), ("lathe-xzc", False), ("five-axis-ac", False)):
        assert set(_decisions(load_machine(name)).values()) == {runs}, name


def test_an_x_y_a_grinder_runs_the_flute_in_every_command(tmp_path):
    m = _machine(tmp_path, 360.0)
    assert [a.word for a in m.axes] == ["X", "Y", "A"]
    assert set(_decisions(m).values()) == {True}
    fl = flute_path(turns=1, points_per_turn=20)
    ax = fl.axes(m)
    check_in_strokes(m, ax, "the flute path")
    assert np.abs(forward(m, ax) - fl.targets_mm).max() < TOL_MM
    lines = write_flute_program(tmp_path / "flute.nc", m, ax, fl).read_text().splitlines()
    assert lines[2] == "G21 G90 G17 G94"           # the plane of X and Y
    assert lines[4].startswith("G1 X") and " Y29.6" in lines[4] and " A" in lines[4] and "Z" not in lines[4]


def test_the_same_machine_with_a_half_turn_a_runs_it_nowhere(tmp_path):
    """The flute turns the workpiece several times: an A of half a turn cannot make it, in any command."""
    assert set(_decisions(_machine(tmp_path, 180.0)).values()) == {False}


def test_the_demo_program_of_the_grinder_keeps_its_words(tmp_path):
    g = load_machine(None)
    fl = flute_path(turns=1, points_per_turn=4)
    ax = fl.axes(g)
    lines = write_flute_program(tmp_path / "flute.nc", g, ax, fl).read_text().splitlines()
    d = PROGRAM_DECIMALS
    moves = [f"X{x:.{d}f} Z{z:.{d}f} A{a:.{d}f}" for x, z, a in ax]
    assert lines[2:] == ["G21 G90 G18 G94", f"G0 {moves[0]}", f"G1 {moves[1]} F{PROGRAM_FEED:g}", *moves[2:],
                         "M30", "%"]


def test_the_grinders_stroke_check_names_its_linear_axes():
    g = load_machine("grinder")
    with pytest.raises(ValueError, match="inside the X/Z strokes.*x_mm"):
        check_in_strokes(g, flute_path(px_start_mm=1.0, turns=1, points_per_turn=40).axes(g))
