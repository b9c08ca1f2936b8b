"""Issue 13: independent truth family, smoothed identification with uncertainty, the model
update from checks, and the closed loop — each injected → simulated → estimated → scored
against the hidden truth (the estimators never see it)."""
import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.chain_elements import ChainElementSet
from errormap.machine import load_machine
from errormap.chain_field import ChainField
from errormap.chain_kernel import spatial_error
from errormap.chain_truth import EFFECT_DEFAULTS, TRUTH_STATIONS, make_chain_truth, random_axes
from errormap.chain_sweeps import simulated_sweeps
from errormap.chain_covariance import band_sd, covariance_path, read_chain_covariance, save_chain_covariance
from errormap.diagnosis.chain_effects import full_parameters
from errormap.diagnosis.chain_update import apply_parameters
from errormap.estimators import Identification
from errormap.sweeps import sweeps_from_columns
from errormap.uncertainty import noise_um, station_standard_errors

SEED = 0
TRACKER_NOISE_UM = 2.0
NOISE_REL_TOL = 0.15   # σ̂ from ~180 residual dof has a relative SE of ~5 %: 3 SE
SMOOTH_GAIN = 0.75     # smoothed / interpolating prediction RMS on this seed (measured 0.55; the benchmark has the spread)
LINEAR_REL_TOL = 1e-3  # first-order update vs exact HTM for a μm-sized change (second order ~ ε ≈ 1e-4)
HELD_OUT_TARGET_UM = 2.2  # issue 13: 1.25 × √3 × 1 μm check noise
N_CHECKS = 600


def _identified(cols, grinder):
    """``volcomp identify``'s identification (its defaults: smoothed, station-mean gauge) of sweep columns."""
    return Identification(grinder).fit(sweeps_from_columns(cols))


def _loop(grinder, sm, cols, tmp, **kw):
    """The machine tools' loop (``volcomp diagnose``'s) on the grinder's chain: the smoothed identification
    ``sm`` as the files ``volcomp identify`` writes (elements and covariance with its prior_extra), read as the
    command reads them; ``cols`` the check columns. → (summary with ``_models``, checks)."""
    from compensation.app.workflows.measurement import load_chain_model
    from errormap.diagnosis.chain_loop import ChainChecks, closed_loop_chain
    mt = grinder
    el_path = sm.elements_.save(tmp / "el.json")
    save_chain_covariance(sm.result_, covariance_path(el_path))
    el, cov, _ = load_chain_model(el_path, mt, prior=True)
    checks = ChainChecks.from_columns(mt, cols)
    return closed_loop_chain(mt, el, checks, cov=cov, **kw), checks


@pytest.fixture(scope="module")
def indep(grinder):
    truth = make_chain_truth(grinder, SEED, family="independent")
    sm = _identified(simulated_sweeps(truth, noise_um=TRACKER_NOISE_UM, seed=SEED + 50), grinder)
    return truth, sm


def test_independent_family_is_seeded_and_differs(grinder):
    a = make_chain_truth(grinder, 3, family="independent", effects=["pitch", "worm"])
    b = make_chain_truth(grinder, 3, family="independent", effects=["pitch", "worm"])
    d = make_chain_truth(grinder, 3)
    assert a.elements.stations["x_mm"].size == TRUTH_STATIONS
    np.testing.assert_array_equal(a.elements.functions["dx_x"], b.elements.functions["dx_x"])
    assert a.effects == b.effects
    assert a.parameters("pitch")["period_mm"] != EFFECT_DEFAULTS["periodic"]["period_mm"]
    pts = random_axes(grinder, 500, np.random.default_rng(0))
    ea, ed = ChainField(grinder, a.elements).predict(pts), ChainField(grinder, d.elements).predict(pts)
    assert np.abs(ea - ed).max() > 10.0  # a different machine, not a rescaled one
    c1 = a.check_measurements(100, 1.0, seed=5)
    c2 = b.check_measurements(100, 1.0, seed=5)
    np.testing.assert_array_equal(c1["dx_um"], c2["dx_um"])


def test_simulate_cli_family(tmp_path):
    assert main(["simulate", "--family", "independent", "--seed", "2", "--checks", "50", "--out", str(tmp_path)]) == 0
    info = json.loads((tmp_path / "truth.json").read_text())
    assert info["family"] == "independent"
    assert ChainElementSet.load(tmp_path / "truth_elements.json", load_machine()).stations["z_mm"].size == TRUTH_STATIONS


def test_noise_is_estimated_from_ball_residuals(indep):
    _, sm = indep
    assert abs(noise_um(sm.result_) - TRACKER_NOISE_UM) < NOISE_REL_TOL * TRACKER_NOISE_UM


def test_smoothing_beats_interpolation_on_the_truth(grinder, indep):
    truth, sm = indep
    pts = random_axes(grinder, 3000, np.random.default_rng(1))
    et = ChainField(grinder, truth.elements).predict(pts)
    rms = lambda el: np.sqrt(np.mean(np.sum((ChainField(grinder, el).predict(pts) - et) ** 2, axis=1)))  # noqa: E731
    assert rms(sm.elements_) < SMOOTH_GAIN * rms(sm.raw_result_.elements_)


def test_the_bands_parameter_matrix_is_the_first_order_change(grinder, indep):
    from errormap.diagnosis.chain_update import parameter_matrix
    _, sm = indep
    el = sm.elements_
    pts = random_axes(grinder, 200, np.random.default_rng(2))
    slots, stations = full_parameters(el)
    dtheta = np.random.default_rng(3).normal(0, 1.0, len(slots))  # ~1 μm / μrad
    new = apply_parameters(el, slots, stations, dtheta)
    exact = spatial_error(grinder, pts, new.values(pts)) - spatial_error(grinder, pts, el.values(pts))
    lin = np.einsum("nip,p->ni", parameter_matrix(grinder, el, pts, slots, stations), dtheta)
    assert np.abs(exact - lin).max() < LINEAR_REL_TOL * np.abs(exact).max()


def test_band_shape_and_station_se(grinder, indep):
    _, sm = indep
    sd = band_sd(grinder, sm.elements_, sm.covariance_, random_axes(grinder, 10, np.random.default_rng(4)))
    assert sd.shape == (10, 3) and np.all(sd > 0)
    se = station_standard_errors(sm.result_)
    assert se["dx_x"].shape == (21,) and se["ex_a"][0] == se["ex_a"][-1] and se["s_xz"] > 0


def test_update_brings_held_out_to_the_noise_floor_and_reports_no_effect(grinder, indep, tmp_path):
    truth, sm = indep
    s, _ = _loop(grinder, sm, truth.check_measurements(N_CHECKS, 1.0, seed=11), tmp_path)
    st = s["stages"]
    assert st["identified"]["held_out"]["rms_um"] > 2 * HELD_OUT_TARGET_UM
    assert s["held_out_rms_um"] < HELD_OUT_TARGET_UM and s["kept_stage"].startswith("updated")
    assert s["effects"] == []
    assert 0.8 < s["noise_sigma_um"] < 1.25  # the check noise is 1 μm per component


@pytest.mark.slow
def test_reversal_is_named_after_the_update(grinder, tmp_path):
    truth = make_chain_truth(grinder, 1, family="independent", effects=["reversal"])
    sm = _identified(simulated_sweeps(truth, noise_um=TRACKER_NOISE_UM, seed=51), grinder)
    s, _ = _loop(grinder, sm, truth.check_measurements(800, 1.0, seed=13), tmp_path)
    e = s["effects"]
    assert e and (e[0]["kind"], e[0]["axis"]) == ("reversal", "Z")
    assert s["held_out_rms_um"] < HELD_OUT_TARGET_UM


def test_predict_band_cli(tmp_path, capsys):
    sw = tmp_path / "sw.csv"
    assert main(["sweeps", "--seed", "2", "--family", "independent", "--out", str(sw)]) == 0
    el = tmp_path / "el.json"
    assert main(["identify", str(sw), "--out", str(el)]) == 0
    assert covariance_path(el).is_file()
    read_chain_covariance(covariance_path(el), ChainElementSet.load(el, load_machine()))
    pts = tmp_path / "p.csv"
    pts.write_text("x_mm,z_mm,a_deg\n10,5,30\n150,40,200\n")
    out = tmp_path / "pred.csv"
    assert main(["predict", str(pts), "--model", str(el), "--out", str(out), "--band", "95"]) == 0
    text = out.read_text()
    assert "dx_band95_um" in text
    covariance_path(el).unlink()
    capsys.readouterr()
    assert main(["predict", str(pts), "--model", str(el), "--out", str(tmp_path / "p2.csv"), "--band", "1sigma"]) == 2
    assert "el.cov.npz" in capsys.readouterr().err


COMP_TRUE_TOL_UM = 0.01  # model = truth exactly here; the exact solver's own residual is ~1e-10 μm


@pytest.mark.slow  # over the 5 CPU s tier limit since the closed loop gained its learned stage
def test_compensate_takes_the_diagnosed_model_and_its_conditions(grinder, tmp_path, capsys):
    from errormap.io import read_table
    from errormap.chain_kernel import forward
    truth = make_chain_truth(grinder, 3, effects=["reversal"])
    truth.elements.save(tmp_path / "updated_elements.json")
    b = truth.parameters("reversal")["backlash_um"]
    term = {"kind": "reversal", "axis": "z", "element": "dz_z", "coefficients": [b], "period_mm": None, "order": None,
            "needs": ["dir_z"], "reference": {"ref_temp_c": 20.0, "ref_time_s": 0.0}}
    (tmp_path / "model.json").write_text(json.dumps({"format": "volcomp-diagnosed-model/1",
                                                      "elements": "updated_elements.json", "terms": [term]}))
    u = np.linspace(0, 1, 30)
    axes = np.c_[20 + 150 * u, 5 + 40 * u, 300 * u]
    path = tmp_path / "path.csv"
    path.write_text("x_mm,z_mm,a_deg\n" + "\n".join(f"{x:.6f},{z:.6f},{a:.6f}" for x, z, a in axes) + "\n")
    capsys.readouterr()
    assert main(["compensate", str(path), "--model", str(tmp_path / "model.json"), "--method", "exact",
                 "--out", str(tmp_path / "c0")]) == 2
    assert "dir_z" in capsys.readouterr().err and not (tmp_path / "c0" / "path.csv").exists()
    assert main(["compensate", str(path), "--model", str(tmp_path / "model.json"), "--method", "exact",
                 "--out", str(tmp_path / "c1"), "--dir-z", "-1"]) == 0
    t = read_table(tmp_path / "c1" / "path.csv")
    cmd = np.stack([t.float(c) for c in ("x_mm", "z_mm", "a_deg")], axis=1)
    n = len(cmd)
    landed = truth.tool_point(cmd, dir_z=-np.ones(n))
    err_um = np.linalg.norm(landed - forward(grinder, axes), axis=1) * 1e3
    assert err_um.max() < COMP_TRUE_TOL_UM


def _diagnosed_model(tmp_path, truth, terms):
    truth.elements.save(tmp_path / "updated_elements.json")
    (tmp_path / "model.json").write_text(json.dumps({"format": "volcomp-diagnosed-model/1",
                                                      "elements": "updated_elements.json", "terms": terms}))
    return tmp_path / "model.json"


@pytest.mark.slow  # over 5 CPU s in the fresh-clone CI run of 2026-11-24 (tier rule)
def test_compensate_takes_per_point_conditions_from_the_path_columns(grinder, tmp_path, capsys):
    """A reversal term (dir_z) and a thermal term (temp_c), both per point from the CSV's columns:
    the commands land on the targets on the truth under each point's own conditions."""
    from errormap.io import read_table
    from errormap.chain_kernel import forward
    truth = make_chain_truth(grinder, 3, effects=["reversal", "thermal"])
    b = truth.parameters("reversal")["backlash_um"]
    k = truth.parameters("thermal")["k_um_per_mm_c"]
    ref = {"ref_temp_c": 20.0, "ref_time_s": 0.0}
    model = _diagnosed_model(tmp_path, truth, [
        {"kind": "reversal", "axis": "z", "element": "dz_z", "coefficients": [b], "reference": ref},
        {"kind": "thermal", "axis": "x", "element": "dx_x", "coefficients": [k], "reference": ref}])
    n = 40
    u = np.linspace(0, 1, n)
    axes = np.c_[20 + 150 * u, 5 + 40 * u, 300 * u]
    dir_z = np.where(np.arange(n) % 3 == 0, -1, 1)
    temp = 20 + 4 * u
    path = tmp_path / "path.csv"
    path.write_text("x_mm,z_mm,a_deg,temp_c,dir_z\n" + "\n".join(
        f"{x:.6f},{z:.6f},{a:.6f},{t:.4f},{d}" for (x, z, a), t, d in zip(axes, temp, dir_z)) + "\n")
    assert main(["compensate", str(path), "--model", str(model), "--method", "exact", "--out", str(tmp_path / "c"),
                 "--dir-z", "1"]) == 0  # the column wins over the option
    t = read_table(tmp_path / "c" / "path.csv")
    cmd = np.stack([t.float(c) for c in ("x_mm", "z_mm", "a_deg")], axis=1)
    landed = truth.tool_point(cmd, dir_z=dir_z.astype(float), temp_c=np.round(temp, 4))
    err_um = np.linalg.norm(landed - forward(grinder, axes), axis=1) * 1e3
    assert err_um.max() < COMP_TRUE_TOL_UM
    summ = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert summ["model_max_um"] < COMP_TRUE_TOL_UM
    # a bad cell: file, row and column; a needed column that is absent with no option: refused by name
    bad = tmp_path / "bad.csv"
    lines = path.read_text().splitlines()
    lines[5] = lines[5].rsplit(",", 1)[0] + ",0"
    bad.write_text("\n".join(lines) + "\n")
    capsys.readouterr()
    assert main(["compensate", str(bad), "--model", str(model), "--method", "exact", "--out", str(tmp_path / "c2")]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and "row 6" in err and "dir_z" in err
    nocol = tmp_path / "nocol.csv"
    nocol.write_text("x_mm,z_mm,a_deg,dir_z\n" + "\n".join(
        f"{x:.6f},{z:.6f},{a:.6f},{d}" for (x, z, a), d in zip(axes, dir_z)) + "\n")
    assert main(["compensate", str(nocol), "--model", str(model), "--method", "exact", "--out", str(tmp_path / "c3")]) == 2
    err = capsys.readouterr().err
    assert "nocol.csv" in err and "temp_c" in err and "--temp-c" in err
    assert not (tmp_path / "c3" / "nocol.csv").exists()


@pytest.mark.slow  # over the 5 CPU s tier limit since the closed loop gained its learned stage
def test_compensate_gcode_with_a_diagnosed_model_follows_the_replanned_vertices(grinder, tmp_path):
    """A G-code path (no condition columns) with a thermal term: the option's temperature holds at
    every vertex the replan adds to the long moves, and the model residual stays at solver level."""
    truth = make_chain_truth(grinder, 3, effects=["thermal"])
    k = truth.parameters("thermal")["k_um_per_mm_c"]
    model = _diagnosed_model(tmp_path, truth, [{"kind": "thermal", "axis": "x", "element": "dx_x", "coefficients": [k],
                                                "reference": {"ref_temp_c": 20.0, "ref_time_s": 0.0}}])
    src = tmp_path / "long.nc"
    src.write_text("G21 G90\nG1 X10 Z5 A0 F100\nG1 X150 Z40 A90\nG1 X30 Z10 A180\nM30\n")  # two moves of >100 mm
    base = ["compensate", str(src), "--model", str(model), "--method", "exact", "--temp-c", "23.5",
            "--work-offsets", "machine"]  # the program is written in machine coordinates
    assert main(base + ["--out", str(tmp_path / "c"), "--max-segment-mm", "10"]) == 0
    summ = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert summ["points"] > 3 * summ["moves_compensated"]  # the replan added vertices along the long moves
    assert summ["model_max_um"] < COMP_TRUE_TOL_UM


@pytest.mark.slow
def test_an_effect_the_update_would_imitate_is_named_and_kept(grinder, tmp_path):
    """Thermal growth (a dx_x slope at the mean temperature) is partly taken up by an update made alone; the loop
    names it, re-fits it jointly with the update, and keeps the model with it."""
    truth = make_chain_truth(grinder, 0, family="independent", effects=["thermal"])
    sm = _identified(simulated_sweeps(truth, noise_um=TRACKER_NOISE_UM, seed=500), grinder)
    s, _ = _loop(grinder, sm, truth.check_measurements(800, 1.0, seed=14), tmp_path)
    assert s["effects"] and (s["effects"][0]["kind"], s["effects"][0]["axis"]) == ("thermal", "X")
    assert s["kept_stage"] == "updated_plus_effects"
    assert s["held_out_rms_um"] < HELD_OUT_TARGET_UM


@pytest.mark.slow
def test_an_effect_the_element_slots_represent_is_named_as_absorbed(grinder, tmp_path):
    """An X·Z coupling on the grinder is angular elements times lever arms: the element slots represent it over
    the checks, so the update takes it up; the loop names it as absorbed (not a missed effect) and the updated
    model reaches the held-out target."""
    truth = make_chain_truth(grinder, 0, family="independent", effects=["interaction"])
    sm = _identified(simulated_sweeps(truth, noise_um=TRACKER_NOISE_UM, seed=500), grinder)
    s, _ = _loop(grinder, sm, truth.check_measurements(800, 1.0, seed=14), tmp_path)
    assert ("interaction", "X*Z") in {(e["kind"], e["axis"]) for e in s["effects_absorbed"]}
    assert s["held_out_rms_um"] < HELD_OUT_TARGET_UM


REFIT_TRUE_GAIN = 1.0
"""refit_on_all_checks: the kept stage re-estimated on all 600 checks (instead of its 360 fitting
checks) must not be further from the truth over the volume (more data, same estimator; the
benchmark's 10 seeds show the typical gain)."""


@pytest.mark.slow  # a closed loop and its refit: over the 5 CPU s tier limit
def test_refit_on_all_checks_uses_every_check_and_leaves_the_validated_figures(grinder, indep, tmp_path):
    from errormap.chain_field import ChainField
    truth, sm = indep
    s, checks = _loop(grinder, sm, truth.check_measurements(N_CHECKS, 1.0, seed=11), tmp_path)
    held = json.dumps(s["stages"], sort_keys=True, default=str)
    m = s["_models"]
    assert s["kept_stage"] != "identified" and m["refit"] is not None
    el_all, terms, r_all = m["refit"]([], np.zeros((N_CHECKS, 3)), np.arange(N_CHECKS))
    assert json.dumps(s["stages"], sort_keys=True, default=str) == held   # the validated figures stay
    assert el_all is not m["elements"] and terms == [] == m["terms"] and r_all.shape == (N_CHECKS, 3)
    P = random_axes(grinder, 2000, np.random.default_rng(3))
    e_true = truth.spatial_error(P, **truth.default_conditions(len(P)))
    rms = lambda el: float(np.sqrt(np.mean(np.sum((ChainField(el.machine, el).predict(P) - e_true) ** 2, 1))))  # noqa: E731
    assert rms(el_all) <= REFIT_TRUE_GAIN * rms(m["elements"])


REFIT_STAGE_REPRODUCE_UM = 1e-9
"""The loop's refit on its own fitting checks without an offset runs the loop's own estimator on the same rows
(the same update, the same smoothness weight): equal to the loop's kept model up to round-off of μm-sized
predictions (the same floating-point operations; 1e-9 μm leaves room only for summation order)."""


@pytest.mark.slow  # a closed loop and two refits: over the 5 CPU s tier limit
def test_refit_reproduces_the_loop_and_takes_an_offset_off_its_target(grinder, indep, tmp_path):
    from errormap.chain_field import ChainField
    truth, sm = indep
    s, checks = _loop(grinder, sm, truth.check_measurements(N_CHECKS, 1.0, seed=11), tmp_path)
    m = s["_models"]
    fit_idx = np.arange(int(round(0.6 * N_CHECKS)))
    el, _, _ = m["refit"]([], np.zeros((N_CHECKS, 3)), fit_idx)
    P = random_axes(grinder, 500, np.random.default_rng(4))
    kept = ChainField(el.machine, m["elements"]).predict(P)
    assert m["terms"] == []                                      # this seed keeps no term: a plain update
    assert np.max(np.abs(ChainField(el.machine, el).predict(P) - kept)) <= REFIT_STAGE_REPRODUCE_UM
    # an offset (what another model part explains) is taken off the residual the kept update is made on
    off = np.zeros((N_CHECKS, 3))
    off[:, 1] = 0.5 * np.sin(checks.axes[:, 0] / 20.0)          # μm
    el1, _, _ = m["refit"]([], off, fit_idx)
    assert np.max(np.abs(ChainField(el.machine, el1).predict(P) - kept)) > 0.01   # it moved the update


STATED_TOO_LOW_UM = 0.3
"""A stated σ far below the checks' real 1 μm: the update's estimate (≈ 1 μm) is > NOISE_EXCESS (2) × it."""


@pytest.mark.slow  # two closed loops: 9 CPU s
def test_given_noise_sets_the_floor_and_the_verdict_compares_the_estimate_with_it(grinder, indep, tmp_path):
    """``diagnose --noise-um`` on the grinder, as on every machine tool (one helper, ``noise_record``): the floor is
    √3·σ of the given σ, the held-out RMS is reported over it, and a stated σ far below the update's estimate fails
    the verdict."""
    from errormap.diagnosis.plausibility import NOISE_EXCESS, diagnosis_verdict
    truth, sm = indep
    cols = truth.check_measurements(N_CHECKS, 1.0, seed=11)
    s, _ = _loop(grinder, sm, cols, tmp_path, noise_um=1.0, effects=False)
    assert s["noise_sigma_source"] == "given" and s["noise_sigma_stated_um"] == 1.0
    assert s["noise_floor_um"] == pytest.approx(np.sqrt(3.0), rel=1e-12)
    assert s["held_out_over_floor"] == pytest.approx(s["held_out_rms_um"] / np.sqrt(3.0), rel=1e-12)
    assert abs(s["noise_sigma_estimated_um"] - 1.0) <= NOISE_REL_TOL
    assert diagnosis_verdict(s)["status"] == "passed"
    low, _ = _loop(grinder, sm, cols, tmp_path, noise_um=STATED_TOO_LOW_UM, effects=False)
    v = diagnosis_verdict(low)
    assert low["noise_sigma_estimated_um"] > NOISE_EXCESS * STATED_TOO_LOW_UM
    assert v["status"] == "failed" and "stated σ" in v["reasons"][0]
