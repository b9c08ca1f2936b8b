"""``volcomp export --format linuxcnc`` on machine-tool chains: one pitch table per linear joint, checked
before writing (the one export of every machine tool)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField

PITCH_ONLY_TOL_UM = 0.01
"""A machine whose only errors are the linear joints' own positioning errors is compensated exactly by
their pitch tables up to linear interpolation between 256 lines of a smooth ≤ 25 μm profile (< 1e-3 μm)
and the exact solver's round-off; 0.01 μm leaves a margin."""
FILE_DIGITS_MM = 1e-9
"""The .comp files hold 9 decimals of mm."""
BACKLASH_TOL_UM = 0.5
"""The loop's reversal estimate on Z from 400 checks at 1 μm noise (seed 0: 8.23 μm for a simulated 8.0 μm
backlash); the table's forward − reverse must carry it to within 0.5 μm."""


def positioning_only(machine, seed=0) -> ChainElementSet:
    """Elements with only each linear joint's positioning error along its own axis (smooth, ≤ 25 μm)."""
    el = ChainElementSet.zeros(machine)
    rng = np.random.default_rng(seed)
    for a in machine.axes:
        if a.kind != "linear":
            continue
        s = el.stations[a.column]
        u = (s - s[0]) / (s[-1] - s[0])
        el.functions[f"d{'xyz'[a.along]}_{a.word.lower()}"] = (rng.uniform(5, 15) * np.sin(2 * np.pi * u)
                                                                + rng.uniform(-10, 10) * u)
    return el


def joint_check(tables, fld, machine, pts, dirs) -> dict:
    """The export's check of per-joint ``tables`` against the field ``fld`` at axes ``pts`` approached in ``dirs``."""
    from compensation import export as ex
    model = ex.ModelError(machine, field=fld)
    return ex.check_export(tables, model, machine, {"p": ex.point_set(machine, pts, dirs)})["p"]


def joint_tables(fld, el, machine, n, **kw):
    """The export's per-joint tables of the element set ``el`` with its field ``fld``."""
    from compensation import export as ex
    return ex.joint_tables_from_model(ex.ModelError(machine, el, field=fld), machine, n, **kw)


def check_and_write_tables(tables, fld, machine, pts, tol_um, out_dir, joint):
    """Joint tables judged before writing, as ``export`` does: at the check points ``pts`` (n, k) with seeded
    random approach directions the tables leave at most ``tol_um`` μm of the MODEL (the field ``fld``) and no
    compensation more than 100 × that; then written to ``out_dir``. Returns (written paths, the table of
    ``joint`` read back (lines, 3))."""
    from compensation import export as ex
    dirs = np.random.default_rng(2).choice([-1.0, 1.0], pts.shape)
    check = joint_check(tables, fld, machine, pts, dirs)
    assert check["model"]["max_um"] <= tol_um
    assert check["baseline_none"]["model"]["max_um"] > 100 * tol_um
    files = ex.write_joint_tables(tables, out_dir)
    return files, np.loadtxt(out_dir / f"joint_{joint}.comp")


def test_pitch_tables_compensate_a_machine_with_positioning_errors_only(tmp_path):
    """Independent check of sign and joint direction: positioning errors alone are fully carried by the tables."""
    from compensation import export as ex
    m = load_machine("mill-xyz")
    el = positioning_only(m)
    fld = ChainField(m, el)
    tables = joint_tables(fld, el, m, 256, samples=4, seed=0)
    assert sorted(tables.nominal) == ["x", "y", "z"]
    assert all(np.array_equal(tables.forward[j], tables.reverse[j]) for j in tables.nominal)  # no reversal term
    pts = ex.volume_points(el, 500, 1)
    files, back = check_and_write_tables(tables, fld, m, pts, PITCH_ONLY_TOL_UM, tmp_path, "y")
    assert [p.name for p in files] == ["joint_x.comp", "joint_y.comp", "joint_z.comp"]
    assert back.shape == (256, 3)
    assert np.max(np.abs(back - np.column_stack([tables.nominal["y"], *tables.actual("y")]))) <= FILE_DIGITS_MM


def test_cli_five_axis_writes_the_linear_joints_and_says_what_it_does_with_the_rotary_ones(tmp_path, capsys):
    m = load_machine("five-axis-ac")
    model = positioning_only(m).save(tmp_path / "E.json")
    out = tmp_path / "lx"
    assert main(["export", str(model), "--format", "linuxcnc", "--machine", "five-axis-ac", "--points", "128",
                 "--check-points", "300", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["export.json", "joint_x.comp", "joint_y.comp", "joint_z.comp"]
    notes = [ln for ln in text.splitlines() if ln.startswith("note: rotary joint")]
    assert [n.split()[3] for n in notes] == ["A:", "C:"]
    info = json.loads((out / "export.json").read_text())
    assert info["tolerance_met"] and info["worst_model_residual_um"] <= PITCH_ONLY_TOL_UM
    assert info["joints"] == {"x": "x_mm", "y": "y_mm", "z": "z_mm"} and len(info["left_out"]) == 2


@pytest.mark.parametrize("argv, word", [
    (["--machine", "mill-xyz", "--diagnosis", "d.json"], "d.json"),                  # no such file
    (["--machine", "mill-xyz", "--region", "0:1,0:1"], "--region"),                  # two ranges on three axes
    (["--machine", "mill-xyz", "--region", "0:1,0:1,-50:1"], "--region"),            # leaves Z's stroke
    (["--machine", "mill-xyz", "--points", "300"], "--points"),
])
def test_cli_refusals_are_one_line(argv, word, tmp_path, capsys):
    m = load_machine("mill-xyz")
    model = positioning_only(m).save(tmp_path / "E.json")
    assert main(["export", str(model), "--format", "linuxcnc", "--out", str(tmp_path / "o"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and word in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_reversal_of_the_loops_model_becomes_forward_minus_reverse(tmp_path, capsys):
    """User's path: simulate (reversal:Z, 8 μm backlash) → sweeps → identify → diagnose → export the loop's
    model.json: joint Z's forward − reverse carries the backlash, the others none; TRUE with --truth."""
    base = ["--machine", "mill-xyz", "--seed", "0", "--effect", "reversal:Z"]
    d = tmp_path
    assert main(["simulate", *base, "--checks", "400", "--out", str(d / "sim")]) == 0
    assert main(["sweeps", *base, "--out", str(d / "sw.csv")]) == 0
    assert main(["identify", str(d / "sw.csv"), "--machine", "mill-xyz", "--out", str(d / "E.json")]) == 0
    # --no-learned: the loop's model.json is exported (the learned stage after the loop is most of the CPU)
    assert main(["diagnose", str(d / "sim" / "checks.csv"), "--machine", "mill-xyz", "--model", str(d / "E.json"),
                 "--noise-um", "1", "--no-learned", "--out", str(d / "diag")]) == 0
    truth_b = json.loads((d / "sim" / "truth.json").read_text())["effects"]["reversal:Z"]["backlash_um"]
    capsys.readouterr()
    assert main(["export", str(d / "diag" / "model.json"), "--format", "linuxcnc", "--machine", "mill-xyz",
                 "--truth", str(d / "sim" / "truth.json"), "--force", "--out", str(d / "lx")]) == 0
    info = json.loads((d / "lx" / "export.json").read_text())
    rev = info["max_forward_minus_reverse_um"]
    assert abs(rev["z"] - truth_b) <= BACKLASH_TOL_UM and rev["x"] == rev["y"] == 0.0
    c = info["check"]["volume"]
    assert c["true"]["max_um"] < c["baseline_none"]["true"]["max_um"]
    assert c["model"]["mean_um"] < c["baseline_none"]["model"]["mean_um"]
    z = np.loadtxt(d / "lx" / "joint_z.comp")
    assert abs(np.median(z[:, 1] - z[:, 2]) * 1e3 - truth_b) <= BACKLASH_TOL_UM


REGION_GAIN = 0.5
"""Averaging each joint's correction over a small working region instead of the whole volume must at least halve
the worst MODEL residual the tables leave inside that region, on a seeded truth whose angular errors couple the
axes (a region 2 % of each stroke wide; seed 0: measured 18.1 -> 3.6 um, factor 0.20); 0.5 leaves a margin."""
SOLVER_TOL_UM = 1e-6
"""The exact chain solver's convergence (its tolerance is far below 1e-6 um)."""


def coupled_elements(machine):
    """A seeded truth's element set (angular errors: a joint's correction depends on the other axes)."""
    from compensation.app.workflows.measurement import make_truth
    return make_truth(machine, 0).elements


def test_region_averages_over_the_working_region(tmp_path):
    """``--region`` on a chain (as on the grinder): the other axes sampled in the region; inside it the tables
    leave less than the whole-volume tables."""
    from compensation import export as ex
    m = load_machine("mill-xyz")
    el = coupled_elements(m)
    fld = ChainField(m, el)
    lo, hi = m.stroke_lo, m.stroke_hi
    box = {c: (a + 0.4 * (b - a), a + 0.42 * (b - a)) for c, a, b in zip(m.axis_columns, lo, hi)}
    whole = joint_tables(fld, el, m, 64, samples=16, seed=0)
    local = joint_tables(fld, el, m, 64, samples=16, seed=0, region=box)
    same = joint_tables(fld, el, m, 64, samples=16, seed=0, region=None)
    assert all(np.array_equal(whole.forward[j], same.forward[j]) for j in whole.nominal)   # no region: as before
    pts = np.random.default_rng(3).uniform([b[0] for b in box.values()], [b[1] for b in box.values()], (300, 3))
    dirs = np.ones_like(pts)
    r_whole = joint_check(whole, fld, m, pts, dirs)["model"]["max_um"]
    r_local = joint_check(local, fld, m, pts, dirs)["model"]["max_um"]
    assert r_local <= REGION_GAIN * r_whole
    with pytest.raises(ValueError, match="calibrated range"):
        joint_tables(fld, el, m, 8, samples=2, region={"x_mm": (lo[0] - 1.0, hi[0])})
    out = tmp_path / "lx"
    region = ",".join(f"{a:g}:{b:g}" for a, b in box.values())
    assert main(["export", str(el.save(tmp_path / "E.json")), "--format", "linuxcnc", "--machine", "mill-xyz",
                 "--points", "32", "--check-points", "200", "--region", region, "--force", "--out", str(out)]) == 0
    info = json.loads((out / "export.json").read_text())
    assert info["region"] == {c: list(v) for c, v in box.items()}


def test_diagnosis_reversal_is_the_models_term(tmp_path, capsys):
    """``--diagnosis`` on a chain (as on the grinder): the chain loop's diagnosis.json reversal terms on the element
    set give the same tables, byte for byte, as the loop's model.json with those terms; other effects are listed
    as left out; the Z table's forward - reverse is the backlash."""
    from errormap.diagnosis.chain_loop import EffectTerm
    from errormap.diagnosis.loop_model import save_chain_model
    from errormap.io import write_json
    m = load_machine("mill-xyz")
    el_path = positioning_only(m).save(tmp_path / "E.json")
    b_um = 6.0
    rev = EffectTerm("reversal", ("Z",), "dz_z", {}, np.array([b_um]))
    inter = EffectTerm("interaction", ("X", "Y"), "dx_x", {}, np.array([3.0]))
    write_json(tmp_path / "diagnosis.json", {"machine": m.name, "machine_sha256": m.sha256,
                                             "effects": [rev.to_dict(), inter.to_dict()]})
    model = save_chain_model(tmp_path / "model.json", m, el_path, [rev], "updated_plus_effects")
    common = ["--format", "linuxcnc", "--machine", "mill-xyz", "--points", "32", "--check-points", "200"]
    assert main(["export", str(el_path), *common, "--diagnosis", str(tmp_path / "diagnosis.json"),
                 "--out", str(tmp_path / "a")]) == 0
    assert "note: effect interaction(X*Y) on dx_x" in capsys.readouterr().out
    assert main(["export", str(model), *common, "--out", str(tmp_path / "b")]) == 0
    for j in "xyz":
        assert (tmp_path / "a" / f"joint_{j}.comp").read_bytes() == (tmp_path / "b" / f"joint_{j}.comp").read_bytes()
    info = json.loads((tmp_path / "a" / "export.json").read_text())
    fr = info["max_forward_minus_reverse_um"]
    # the correction c solves c + e(z + c) + b/2·dir = 0 on Z's positioning error e: forward − reverse is
    # b / (1 + e'), within b·max|e'| of b (e' in μm/μm), plus the solver's convergence
    el = positioning_only(m)
    z = el.stations["z_mm"]
    slope = np.max(np.abs(np.gradient(el.functions["dz_z"], z))) * 1e-3
    assert abs(fr["z"] - b_um) <= b_um * slope / (1 - slope) + SOLVER_TOL_UM and fr["x"] == fr["y"] == 0.0
    assert info["diagnosis"] == str(tmp_path / "diagnosis.json")
    # another machine's diagnosis, and a model.json beside --diagnosis (its terms twice), are refused in one line
    write_json(tmp_path / "other.json", {"machine": "five-axis-ac", "effects": []})
    for bad in ([str(el_path), "--diagnosis", str(tmp_path / "other.json")],
                [str(model), "--diagnosis", str(tmp_path / "diagnosis.json")]):
        assert main(["export", bad[0], *common, *bad[1:], "--out", str(tmp_path / "c")]) == 2
        err = [ln for ln in capsys.readouterr().err.strip().splitlines() if "error" in ln]
        assert len(err) == 1 and len(err[0]) < 300
        assert not (tmp_path / "c").exists()


def test_the_grinders_diagnosis_of_today_is_read_as_every_chains(tmp_path):
    """The grinder's ``volcomp diagnose`` runs the one closed loop and writes its ``diagnosis.json`` (the machine
    key, the terms with coefficients): ``export --diagnosis`` reads its reversal as every chain's; the grinder's
    older checks diagnosis (effects with ``parameters``) still gives a per-joint backlash."""
    from compensation import export as ex
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.chain_loop import EffectTerm
    from errormap.io import write_json
    g = load_machine()
    el = ChainElementSet.zeros(g)
    rev = EffectTerm("reversal", ("Z",), "dz_z", {}, np.array([4.0]))
    therm = EffectTerm("thermal", ("Z",), "dz_z", {}, np.array([1.0]))
    write_json(tmp_path / "today.json", {"machine": g.name, "machine_sha256": g.sha256,
                                         "effects": [rev.to_dict(), therm.to_dict()]})
    model, left = ex.reversal_from_diagnosis(tmp_path / "today.json", ex.ModelError(g, el))
    assert [t.kind for t in model.field.terms] == ["reversal"] and left == ["thermal(Z) on dz_z"]
    write_json(tmp_path / "older.json", {"effects": [
        {"kind": "reversal", "axis": "z", "element": "dz_z", "parameters": {"backlash_um": {"value": 4.0}}}]})
    model, left = ex.reversal_from_diagnosis(tmp_path / "older.json", ex.ModelError(g, el))
    assert model.reversal == {"Z": 4.0} and left == []
