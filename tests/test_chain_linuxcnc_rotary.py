"""Issue 26, the lathe: ``volcomp export --format linuxcnc`` with a table for the rotary joint the exact solver
moves (``lathe-xzc``: X, Z and C; LinuxCNC compensation files are per joint in joint units, so C's is in
degrees). The rotary correction is averaged over seeded positions of the other axes weighted by r² (the
least-squares angle); checked before writing (MODEL, TRUE with --truth)."""
import json

import numpy as np
import pytest

from compensation import export as ex
from compensation.app.cli import main
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField

from test_chain_linuxcnc import check_and_write_tables, joint_tables

LATHE = "lathe-xzc"
ANGULAR_ONLY_TOL_UM = 0.01
"""A lathe whose only error is the spindle's angular positioning error EC(C) (≤ 80 μrad, one and two waves per
turn) is compensated exactly by C's table: the same angle at every X, so the average is exact; what is left is
linear interpolation between 256 lines over 360° (≈ 80e-6·(2π·2/255)²/8 rad ≈ 6e-9 rad, at 200 mm ≈ 1e-3 μm)
and the first-order reading of the table at the nominal C (80 μrad² · 200 mm ≈ 1e-3 μm); 0.01 μm leaves a margin."""
FILE_DIGITS = 1e-9
"""The .comp files hold 9 decimals (of mm, of degrees for C)."""
WEIGHTED_MEAN_TOL = 1e-12
"""Closed-form weighted means: round-off."""


def angular_only(machine, seed=0) -> ChainElementSet:
    el = ChainElementSet.zeros(machine)
    rng = np.random.default_rng(seed)
    c = np.radians(el.stations["c_deg"])
    el.functions["ez_c"] = rng.uniform(30, 50) * np.sin(c + rng.uniform(0, 6)) + rng.uniform(10, 30) * np.sin(2 * c)
    return el


def test_weighted_node_means():
    nom = np.array([0.0, 1.0, 2.0])
    c = np.array([[1.0, 3.0], [5.0, 5.0], [7.0, 9.0]])
    ok = np.array([[True, True], [False, False], [True, False]])
    w = np.array([[1.0, 3.0], [1.0, 1.0], [2.0, 5.0]])
    m = ex.weighted_node_means(nom, c, ok, w, "none")
    assert np.abs(m - np.array([2.5, 4.75, 7.0])).max() < WEIGHTED_MEAN_TOL  # node 1: its neighbours' interpolation
    with pytest.raises(ValueError, match="none"):
        ex.weighted_node_means(nom, c, np.zeros_like(ok), w, "none")


def test_c_table_compensates_a_spindle_with_angular_error_only(tmp_path):
    """Independent check of the rotary table's sign, unit and direction: the spindle's angular error alone is
    fully carried by C's table (degrees), the linear tables carry nothing."""
    m = load_machine(LATHE)
    el = angular_only(m)
    fld = ChainField(m, el)
    tables = joint_tables(fld, el, m, 256, samples=4, seed=0)
    assert sorted(tables.nominal) == ["c", "x", "z"] and tables.units == {"x": "mm", "z": "mm", "c": "deg"}
    assert tables.turns == {"c": 0.0} and tables.forward["c"][-1] - 360.0 == tables.forward["c"][0]
    corr_deg = tables.nominal["c"] - tables.forward["c"]
    ez_deg = np.degrees(1e-6 * el.functions["ez_c"])
    assert 0.5 < np.abs(corr_deg).max() / np.abs(ez_deg).max() < 2.0  # the size of the angular error, in degrees
    assert max(np.abs(tables.nominal[j] - tables.forward[j]).max() for j in "xz") < 1e-9  # nothing on X, Z
    pts = ex.volume_points(el, 500, 1)
    pts[:, 2] += np.random.default_rng(3).integers(-1, 2, len(pts)) * 360.0  # C on other turns: folded
    files, back = check_and_write_tables(tables, fld, m, pts, ANGULAR_ONLY_TOL_UM, tmp_path, "c")
    assert [p.name for p in files] == ["joint_x.comp", "joint_z.comp", "joint_c.comp"]
    assert back.shape == (256, 3) and back[0, 0] == 0.0 and back[-1, 0] == 360.0
    assert np.max(np.abs(back - np.column_stack([tables.nominal["c"], *tables.actual("c")]))) <= FILE_DIGITS


@pytest.mark.slow
def test_lathe_users_path_with_an_effect_on_c(tmp_path, capsys):
    """simulate (worm:C) → sweeps → identify → export --format linuxcnc --truth: three tables, C's in degrees,
    checked before writing; the tables leave less TRUE error than none; C's table helps (the same tables without
    it leave more)."""
    base = ["--machine", LATHE, "--seed", "0", "--effect", "worm:C"]
    d = tmp_path
    assert main(["simulate", *base, "--out", str(d / "sim")]) == 0
    assert main(["sweeps", *base, "--out", str(d / "sw.csv")]) == 0
    assert main(["identify", str(d / "sw.csv"), "--machine", LATHE, "--out", str(d / "E.json")]) == 0
    capsys.readouterr()
    out = d / "lx"
    assert main(["export", str(d / "E.json"), "--format", "linuxcnc", "--machine", LATHE, "--truth",
                 str(d / "sim" / "truth.json"), "--force", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "note: rotary joint C: table in degrees" in said
    assert sorted(p.name for p in out.iterdir()) == ["export.json", "joint_c.comp", "joint_x.comp", "joint_z.comp"]
    info = json.loads((out / "export.json").read_text())
    assert info["joint_units"] == {"x": "mm", "z": "mm", "c": "deg"} and info["left_out"] == []
    ck = info["check"]["volume"]
    assert ck["true"]["max_um"] < ck["baseline_none"]["true"]["max_um"]
    assert ck["true"]["mean_um"] < ck["baseline_none"]["true"]["mean_um"]
    # the same tables without C's: more MODEL error left (C's table carries the spindle's angular error)
    m = load_machine(LATHE)
    el = ChainElementSet.load(d / "E.json", m)
    fld = ChainField(m, el)
    from errormap.seeds import spawn_seeds
    model = ex.ModelError(m, el, field=fld)
    tables = ex.joint_tables_from_model(model, m, 256, seed=spawn_seeds(0, 1)[0])
    sets = {"volume": ex.check_sets(m, 2000, 0)["volume"]}
    with_c = ex.check_export(tables, model, m, sets)["volume"]
    assert abs(with_c["model"]["max_um"] - ck["model"]["max_um"]) < 1e-9  # the CLI's check, reproduced
    tables.joints.pop("c")
    without_c = ex.check_export(tables, model, m, sets)["volume"]
    assert with_c["model"]["mean_um"] < without_c["model"]["mean_um"]
