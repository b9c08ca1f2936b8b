"""Controller tables: hand-checkable cases, round trips through the files, refusal and bad input."""
import json

import numpy as np
import pytest

from compensation import export as ex
from compensation.app.cli import main
from compensation.toolpath import flute_path
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError, read_table
from errormap.chain_truth import ChainTruth, make_chain_truth

# the tolerance the tables are sized to in the round trips: the check must meet it
TOL_UM = 1.0
# a table that represents the model exactly (linear profiles, linear interpolation) leaves only
# float rounding of μm-sized values through the exact HTM chain and the Newton solve (xtol 1e-9 μm)
EXACT_UM = 1e-6
# the linear X profile (0.1 μm/mm) is sampled at 1 mm nodes; the exact correction x_c = x/(1+1e-4)
# is linear too, so the per-joint table holds it to the file's 9 decimals (5e-10 mm)
FILE_MM = 2e-9
# 8 μm backlash = ±4 μm; with the diagnosed reversal in the table, the truth's reversal is removed:
# what remains is the table's interpolation of a linear profile (sub-nm) and float noise
BACKLASH_UM = 8.0
REMOVED_UM = 1e-3


def linear_elements(machine, k_um_per_mm=0.1):
    """dx_x = k·(x − x0), everything else zero: a model every format represents exactly."""
    el = ChainElementSet.zeros(machine)
    x = el.stations["x_mm"]
    el.functions["dx_x"] = k_um_per_mm * (x - x[0])
    return ChainElementSet(machine, el.stations, el.functions, el.constants, machine.name, machine.sha256)


@pytest.fixture(scope="module")
def small_sets(grinder):
    return ex.check_sets(grinder, n_volume=200, seed=5, flute=flute_path(turns=1.0))


def test_linuxcnc_hand_value_of_a_pure_positioning_error(grinder, tmp_path):
    """EXX = +0.1 μm/mm · x: commanded to x, the carriage reaches x(1 + 1e-4); the exact correction
    solves x_c = x − 1e-4·x_c, so at nominal 100 mm the actual position written is
    100 − (100/1.0001 − 100) = 100.0099990001 mm (forward == reverse without a diagnosis)."""
    model = ex.ModelError(grinder, linear_elements(grinder))
    t = ex.joint_tables_from_model(model, grinder, n_points=201, samples=4, seed=0)
    ex.write_joint_tables(t, tmp_path)
    rows = np.loadtxt(tmp_path / "joint_x.comp")
    i = int(np.flatnonzero(np.isclose(rows[:, 0], 100.0))[0])
    assert rows[i, 1] == pytest.approx(100.0099990001, abs=FILE_MM)
    assert rows[i, 2] == rows[i, 1]
    np.testing.assert_allclose(np.loadtxt(tmp_path / "joint_z.comp")[:, 1:],
                               np.loadtxt(tmp_path / "joint_z.comp")[:, [0, 0]], atol=FILE_MM)


def test_iso_tables_exact_for_linear_profiles(grinder, small_sets):
    """Linear profiles are reproduced exactly by linear interpolation: the table field equals the
    model (sign, frame turn and reference point all survive the ISO conversion and back)."""
    el = linear_elements(grinder)
    z = el.stations["z_mm"]
    el.functions["dy_z"] = 0.2 * (z - z[0])      # mixed into EXZ/EYZ by θ1
    el.functions["ey_z"] = 1.5 * (z - z[0])
    el.constants.update({"dy_oa": 3.0, "ez_oa": -20.0, "s_xz": 40.0})
    model = ex.ModelError(grinder, el)
    t = ex.iso_tables_from_model(el, grinder, 5)
    axes = small_sets["volume"][1]
    np.testing.assert_allclose(t.field(grinder)(axes), model(axes), atol=EXACT_UM)


def test_grid_exact_for_a_field_linear_in_x_and_z(grinder):
    class Lin:
        def predict(self, q):
            return np.column_stack([0.3 * q[:, 0] - 2 * q[:, 1], q[:, 1] + 1.0, -0.05 * q[:, 0]])
    model = ex.ModelError(grinder, field=Lin())
    g = ex.grid_from_model(model, (3, 4, 5))
    q = np.random.default_rng(1).uniform([0, 0, -720], [200, 60, 720], (500, 3))
    np.testing.assert_allclose(g(q), Lin().predict(q), atol=1e-9)


@pytest.mark.parametrize("fmt", ["iso-tables", "grid"])
def test_round_trip_meets_the_stated_tolerance(grinder, small_sets, tmp_path, fmt):
    """export → files → read back → the re-simulated controller leaves at most the tolerance the
    table was sized for, and at least 100× less than no compensation, on flute and volume."""
    truth = make_chain_truth(grinder, 11)
    model = ex.ModelError(grinder, truth.elements)
    table, sizing = ex.build_table(fmt, model, grinder, TOL_UM, small_sets)
    assert sizing["interpolation_error_um"] <= TOL_UM
    ex.write_table(table, tmp_path, grinder, "test")
    back = ex.read_back(table, tmp_path, grinder)
    check = ex.check_export(back, model, grinder, small_sets, ex.truth_tool_points(truth, grinder))
    for name, r in check.items():
        assert r["model"]["max_um"] <= TOL_UM, name
        assert r["model"]["max_um"] * 100 < r["baseline_none"]["model"]["max_um"], name
        # truth == model here: the true residual is the model residual (no undeclared effects)
        assert r["true"]["max_um"] == pytest.approx(r["model"]["max_um"], rel=1e-6, abs=1e-9)


def test_linuxcnc_diagnosed_backlash_removes_the_reversal(grinder, small_sets, tmp_path):
    el = linear_elements(grinder)
    truth = ChainTruth(grinder, el, {"reversal": {"backlash_um": BACKLASH_UM}})
    diag = tmp_path / "diagnosis.json"
    diag.write_text(json.dumps({"effects": [
        {"kind": "reversal", "axis": "z", "element": "dz_z", "parameters": {"backlash_um": {"value": BACKLASH_UM}}},
        {"kind": "thermal", "axis": "x", "element": "dx_x", "parameters": {}}]}))
    back, left = ex.backlash_from_diagnosis(diag)
    assert back == {"z": BACKLASH_UM} and left == ["thermal(x) on dx_x"]
    plain = ex.ModelError(grinder, el)
    with_rev = ex.ModelError(grinder, el, reversal={j.upper(): b for j, b in back.items()})
    t0, _ = ex.build_table("linuxcnc", plain, grinder, TOL_UM, small_sets, n_points=201)
    t1, _ = ex.build_table("linuxcnc", with_rev, grinder, TOL_UM, small_sets, n_points=201)
    ex.write_table(t1, tmp_path / "lc", grinder, "test")
    rows = np.loadtxt(tmp_path / "lc" / "joint_z.comp")
    np.testing.assert_allclose(rows[:, 1] - rows[:, 2], BACKLASH_UM * 1e-3, atol=FILE_MM)
    t1 = ex.read_back(t1, tmp_path / "lc", grinder)
    tool = ex.truth_tool_points(truth, grinder)
    c0 = ex.check_export(t0, plain, grinder, small_sets, tool)
    c1 = ex.check_export(t1, with_rev, grinder, small_sets, tool)
    # random approach directions over the volume: without the reversal the truth's ±4 μm remains
    assert c0["volume"]["true"]["max_um"] == pytest.approx(BACKLASH_UM / 2, abs=REMOVED_UM)
    assert c1["volume"]["true"]["max_um"] < REMOVED_UM
    assert c1["volume"]["model"]["max_um"] < REMOVED_UM


def test_cli_refuses_then_forces(grinder, tmp_path, capsys):
    el_path = make_chain_truth(grinder, 2).elements.save(tmp_path / "el.json")
    out = tmp_path / "lc"
    args = ["export", str(el_path), "--format", "linuxcnc", "--out", str(out), "--tolerance-um", "1",
            "--check-points", "100", "--points", "64"]
    assert main(args) == 2
    assert not out.exists()
    assert "tolerance not met" in capsys.readouterr().err
    assert main(args + ["--force"]) == 0
    info = json.loads((out / "export.json").read_text())
    assert info["override"]["forced"] is True and info["tolerance_met"] is False
    assert sorted(info["files"]) == ["joint_a.comp", "joint_x.comp", "joint_z.comp"]
    assert info["read_back_difference_um"] <= 1e-5


def test_cli_grid_writes_and_records(grinder, tmp_path):
    el_path = make_chain_truth(grinder, 2).elements.save(tmp_path / "el.json")
    out = tmp_path / "g"
    assert main(["export", str(el_path), "--format", "grid", "--out", str(out), "--tolerance-um", "2",
                 "--check-points", "100"]) == 0
    info = json.loads((out / "export.json").read_text())
    assert info["tolerance_met"] and info["override"] is None
    assert info["worst_model_residual_um"] <= 2.0
    g = ex.read_grid(out / "grid.csv", grinder)
    assert list(g.values.shape[:3]) == info["sizing"]["counts"]


def test_bad_files_name_the_place(grinder, tmp_path):
    model = ex.ModelError(grinder, make_chain_truth(grinder, 2).elements)
    g = ex.grid_from_model(model, (3, 3, 5))
    p = ex.write_grid(g, tmp_path, grinder, "test")
    lines = p.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if not s.startswith("#")) + 3
    cells = lines[k].split(",")
    cells[1] = "7.5"
    lines[k] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=rf"row {k + 1}, column 'z_mm'"):
        ex.read_grid(p, grinder)
    t = ex.joint_tables_from_model(ex.ModelError(grinder, linear_elements(grinder)), grinder, 8, samples=2)
    ex.write_joint_tables(t, tmp_path)
    c = tmp_path / "joint_a.comp"
    c.write_text(c.read_text().replace("\n", " 1\n", 1))
    with pytest.raises(InputError, match="joint_a.comp: line 1: expected 3 numbers"):
        ex.read_joint_tables(tmp_path, t)
    c.write_text("\n".join(f"{i} {i} {i}" for i in range(257)) + "\n")
    with pytest.raises(InputError, match="expected 2 to 256 lines"):
        ex.read_joint_tables(tmp_path, t)
    d = tmp_path / "d.json"
    d.write_text(json.dumps({"effects": [{"kind": "reversal", "axis": "z", "element": "dx",
                                          "parameters": {"backlash_um": {"value": 3}}}]}))
    with pytest.raises(InputError, match=r"effects\[0\]\.element"):
        ex.backlash_from_diagnosis(d)


def test_iso_table_header_states_reference_and_sign(grinder, tmp_path):
    t = ex.iso_tables_from_model(make_chain_truth(grinder, 2).elements, grinder, 5)
    ex.write_iso_tables(t, tmp_path, grinder, "test")
    head = read_table(tmp_path / "iso_X.csv").comments   # its provenance sidecar
    assert any(h.startswith("reference point: the origin of the X body's frame") for h in head)
    assert any("the tool moves relative to the workpiece by minus this" in h for h in head)
    assert "x_mm,EXX_um,EYX_um,EZX_um,EAX_urad,EBX_urad,ECX_urad" in (tmp_path / "iso_X.csv").read_text()


def test_cli_refuses_a_model_of_another_machine(grinder, tmp_path, capsys):
    el = make_chain_truth(grinder, 2).elements
    el.machine_sha256 = "0" * 64
    p = el.save(tmp_path / "el.json")
    assert main(["export", str(p), "--format", "iso-tables", "--out", str(tmp_path / "o")]) == 2
    assert "key 'machine_sha256'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["mill-xyz", "five-axis-ac", "lathe-xzc"])
def test_iso_tables_rebuild_the_model_at_their_rows_on_every_machine_tool(name):
    """The turn into the machine frame and back is one transform per axis (the axis at its row, the others at
    the reference pose): at the rows' positions, where linear interpolation is exact, the controller's rebuilt
    error equals the model's, on a mill, on a five-axis machine whose C table rides on A, and on a lathe."""
    from errormap.machine import load_machine
    from errormap.chain_elements import ChainElementSet
    m = load_machine(name)
    el = ChainElementSet.random(m, 3)
    model = ex.ModelError(m, el)
    t = ex.iso_tables_from_model(el, m, 11)
    rng = np.random.default_rng(4)
    q = np.column_stack([rng.choice(t.positions[a.word], 200) if a.word in t.positions else rng.uniform(*a.stroke, 200)
                         for a in m.axes])
    np.testing.assert_allclose(t.field(m)(q), model(q), atol=EXACT_UM)


NET_GRID_TOL_UM = 5.0
"""The grid's tolerance in the network test: a coarse one keeps the grid small (the check is the same at any)."""


@pytest.mark.slow
def test_a_trained_chain_network_is_exported_like_an_element_set(tmp_path):
    """A chain network (a seeded random one: the export does not care how it was trained) on the lathe: the grid
    over X, Z and C (C periodic) meets the tolerance at the re-simulated controller and reads back; the per-joint
    tables are written for X, Z and C."""
    import torch
    from errormap.machine import load_machine
    from training.model import MLPField
    m = load_machine("lathe-xzc")
    f = MLPField.for_machine(m, hidden=(6, 5), activation="tanh")
    rng = np.random.default_rng(3)
    ax = rng.uniform(m.stroke_lo, m.stroke_hi, (200, len(m.axes)))
    f.fit_scalers(ax, rng.normal(0.0, 20.0, (200, 3)))
    f.theta_ = torch.randn(f.n_params, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    net = f.save(tmp_path / "net")
    common = ["--machine", "lathe-xzc", "--check-points", "100"]
    assert main(["export", str(net), "--format", "grid", "--tolerance-um", str(NET_GRID_TOL_UM), *common,
                 "--out", str(tmp_path / "g")]) == 0
    info = json.loads((tmp_path / "g" / "export.json").read_text())
    assert info["tolerance_met"] and info["worst_model_residual_um"] <= NET_GRID_TOL_UM
    assert info["read_back_difference_um"] <= 1e-5
    assert main(["export", str(net), "--format", "linuxcnc", "--points", "8", "--force", *common,
                 "--out", str(tmp_path / "l")]) == 0
    assert sorted(p.name for p in (tmp_path / "l").glob("*.comp")) == ["joint_c.comp", "joint_x.comp", "joint_z.comp"]
    assert main(["export", str(net), "--format", "iso-tables", *common, "--out", str(tmp_path / "i")]) == 2
