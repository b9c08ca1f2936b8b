"""Tracker sweep simulator and sweep file: same chains as the HTM model, round trip, clear errors."""
import numpy as np
import pytest


from errormap.io import InputError
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes
from errormap.chain_sweeps import simulated_sweeps
from errormap.sweeps import read_sweeps, sweeps_from_columns, write_sweeps
from errormap.transforms import apply

CHAIN_TOL_MM = 1e-9        # same chains: agreement to float rounding at ~1 m
ROUNDTRIP_TOL_MM = 1e-8    # 12 significant digits at up to ~3.5 m
RIGID_TOL_MM = 1e-9


@pytest.fixture(scope="module")
def machine():
    return load_machine()


@pytest.fixture(scope="module")
def truth(machine):
    return make_chain_truth(machine, 11)


def test_body_frames_reproduce_the_htm_tool_point(machine, truth):
    """Tool point from the simulated Z-carriage and A-body frames == errormap.htm's exact chain."""
    axes = random_axes(machine, 200, np.random.default_rng(0))
    v = truth.element_values(axes)
    tool_R, tool_t = machine.body_frames("Z", axes, v)
    tool_mcs = tool_t + apply(tool_R, np.array([machine.geometry["l3"], 0.0, machine.geometry["l4"] - machine.geometry["R"]]))
    body_R, body_t = machine.body_frames("A", axes, v)
    wcs = apply(np.swapaxes(body_R, -1, -2), tool_mcs - body_t)  # the A body's frame inverted
    assert np.abs(wcs - machine.tool_point(axes, v)).max() < CHAIN_TOL_MM


def test_noise_free_sweeps_keep_the_ball_triangle(machine, truth):
    cols = simulated_sweeps(truth, noise_um=0.0, seed=4)
    sw = sweeps_from_columns(cols)
    for ax in "XZA":
        b = sw[ax].balls_mm
        mounts = machine.targets[ax]
        assert b.shape == (21, 3, 3)
        for i, j in ((0, 1), (0, 2), (1, 2)):
            d = np.linalg.norm(b[:, i] - b[:, j], axis=1)
            assert np.abs(d - np.linalg.norm(mounts[i] - mounts[j])).max() < RIGID_TOL_MM
    assert sw["A"].command[-1] - sw["A"].command[0] == pytest.approx(360.0)


def test_sweep_file_round_trip_and_bidirectional(tmp_path, truth):
    cols = simulated_sweeps(truth, noise_um=2.0, seed=5, bidirectional=True)
    assert set(np.unique(cols["direction"])) == {-1, 1}
    assert len(cols["axis"]) == 3 * 2 * 21 * 3
    path = write_sweeps(tmp_path / "s.csv", cols, comments=["setup: a"])
    sw = read_sweeps(path, truth.machine)
    ref = sweeps_from_columns(cols)
    for ax in "XZA":
        assert np.abs(sw[ax].balls_mm - ref[ax].balls_mm).max() < ROUNDTRIP_TOL_MM
        assert set(sw[ax].by_direction) == {1, -1}
    assert sw.setup == "a"


def test_seeded_and_tracker_pose_given(truth):
    a = simulated_sweeps(truth, noise_um=2.0, seed=7)
    b = simulated_sweeps(truth, noise_um=2.0, seed=7)
    assert np.array_equal(a["x_mm"], b["x_mm"])
    pose = (np.eye(3), np.zeros(3))
    c = simulated_sweeps(truth, noise_um=0.0, seed=7, tracker_pose=pose)
    R, t = truth.machine.body_frames("X", np.array([truth.machine.stroke_lo]),
                                     truth.element_values(np.array([truth.machine.stroke_lo])))
    first = (c["axis"] == "X") & (c["station"] == 0) & (c["target"] == 1)
    want = apply(R, truth.machine.targets["X"][0]) + t
    assert np.abs(np.array([c["x_mm"][first], c["y_mm"][first], c["z_mm"][first]]).ravel() - want[0]).max() < RIGID_TOL_MM


def _write(tmp_path, text, name="s.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


HEADER = "axis,station,command,target,x_mm,y_mm,z_mm\n"


def test_reader_names_row_and_column(tmp_path, machine):
    p = _write(tmp_path, HEADER + "X,0,0,1,1,2,3\nY,0,0,2,1,2,3\n")
    with pytest.raises(InputError, match=r"s\.csv: row 3, column 'axis'"):
        read_sweeps(p, machine)
    p = _write(tmp_path, HEADER + "X,0,0,4,1,2,3\n")
    with pytest.raises(InputError, match=r"row 2, column 'target'"):
        read_sweeps(p, machine)


def test_reader_refuses_other_length_units(tmp_path, machine):
    p = _write(tmp_path, "axis,station,command,target,x_in,y_in,z_in\nX,0,0,1,1,2,3\n")
    with pytest.raises(InputError, match="x_in.*mm"):
        read_sweeps(p, machine)


def test_reader_refuses_mixed_command_units(tmp_path, machine, truth):
    cols = simulated_sweeps(truth, noise_um=0.0, seed=1)
    cols["command_unit"] = np.where(cols["axis"] == "A", "deg", "mm")
    cols["command_unit"][(cols["axis"] == "A") & (cols["station"] == 5)] = "rad"
    p = write_sweeps(tmp_path / "s.csv", cols)
    with pytest.raises(InputError, match="axis A, station 5.*mixed units"):
        read_sweeps(p, machine)


def test_missing_station_and_target_name_axis_and_station(truth):
    cols = simulated_sweeps(truth, noise_um=0.0, seed=1)
    keep = ~((cols["axis"] == "Z") & (cols["station"] == 7))
    with pytest.raises(InputError, match=r"axis Z: station\(s\) \[7\] missing"):
        sweeps_from_columns({k: v[keep] for k, v in cols.items()})
    keep = ~((cols["axis"] == "X") & (cols["station"] == 3) & (cols["target"] == 2))
    with pytest.raises(InputError, match="axis X, station 3: target 2 missing"):
        sweeps_from_columns({k: v[keep] for k, v in cols.items()})
    dup = {k: np.concatenate([v, v[:1]]) for k, v in cols.items()}
    with pytest.raises(InputError, match="measured twice"):
        sweeps_from_columns(dup)


def test_several_files_must_share_a_setup(tmp_path, truth):
    cols = simulated_sweeps(truth, noise_um=0.0, seed=1)
    parts = {ax: {k: v[cols["axis"] == ax] for k, v in cols.items()} for ax in "XZA"}
    a = write_sweeps(tmp_path / "x.csv", parts["X"], comments=["setup: s1"])
    b = write_sweeps(tmp_path / "z.csv", parts["Z"], comments=["setup: s2"])
    with pytest.raises(InputError, match="same tracker set-up"):
        read_sweeps([a, b], truth.machine)
    b = write_sweeps(tmp_path / "z.csv", parts["Z"], comments=["setup: s1"])
    c = write_sweeps(tmp_path / "a.csv", parts["A"], comments=["setup: s1"])
    sw = read_sweeps([a, b, c], truth.machine)
    assert set(sw.axes) == {"X", "Z", "A"}


def test_a_chain_set_up_over_several_files_reads_as_one(tmp_path):
    """One reader for every machine tool: a mill's set-up split over files that name the same set-up reads as
    the one file would (its axis words from the machine)."""
    from errormap.chain_sweeps import simulated_sweeps
    from errormap.chain_truth import make_chain_truth
    mill = load_machine("mill-xyz")
    cols = simulated_sweeps(make_chain_truth(mill, 2), noise_um=1.0, seed=3)
    whole = read_sweeps(write_sweeps(tmp_path / "all.csv", cols, comments=["setup: s1"]), mill)
    parts = [write_sweeps(tmp_path / f"{w}.csv", {k: v[cols["axis"] == w] for k, v in cols.items()},
                          comments=["setup: s1"]) for w in ("X", "Y", "Z")]
    split = read_sweeps(parts, mill)
    assert set(split.axes) == set(whole.axes) == {"X", "Y", "Z"}
    for w in whole.axes:
        assert np.array_equal(split[w].balls_mm, whole[w].balls_mm)
