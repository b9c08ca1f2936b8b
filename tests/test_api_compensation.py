"""The compensation side of the public API: compensate_program is the ``compensate --machine`` command (the
same bytes, called with settings instead of a command line), compensate_points gives the commands the
program file gets, and save_model / load_model round-trip fitted estimators into the files commands read."""
from __future__ import annotations

import json

import numpy as np
import pytest

from compensation import CompensateSettings, compensate_points, compensate_program, load_model, save_model
from compensation.app.cli import main
from errormap import (ChainElementSet, ClosedLoop, Identification, load_machine, simulate_checks, simulate_sweeps,
                      simulate_truth)

CSV_DECIMALS_TOL_MM = 0.5e-6 + 1e-9
"""The axis CSV is written to 6 decimals (1 nm): the file's command differs from the solver's by at most half
a unit in the last place (plus the round-off of the comparison)."""
MESSAGE_MAX_CHARS = 300
"""A refusal is one line under 300 characters (the project's rule for every message)."""
ROUND_TRIP_TOL_UM = 0.0
"""Element sets are written with every float's shortest exact repr: the loaded model predicts the same bits."""


@pytest.fixture(scope="module")
def mill_program(tmp_path_factory):
    """A mill, a seeded element-set model file and a 5-point axis-CSV program inside the strokes."""
    d = tmp_path_factory.mktemp("api")
    m = load_machine("mill-xyz")
    model = ChainElementSet.random(m, 4, 20.0, 11).save(d / "E.json")
    axes = np.array([[50.0, 40, -60], [150, 120, -150], [300, 200, -200], [450, 300, -300], [550, 380, -380]])
    rows = "\n".join(",".join(f"{v:g}" for v in a) for a in axes)
    (d / "path.csv").write_text("x_mm,y_mm,z_mm\n" + rows + "\n", encoding="utf-8")
    return m, model, axes, d


def test_compensate_program_is_the_command(mill_program):
    m, model, axes, d = mill_program
    result = compensate_program(d / "path.csv", m, model, d / "api")
    summary = result.summary
    assert main(["compensate", str(d / "path.csv"), "--machine", "mill-xyz", "--method", "exact",
                 "--model", str(model), "--out", str(d / "cli")]) == 0
    assert (d / "api" / "path.csv").read_bytes() == (d / "cli" / "path.csv").read_bytes()
    cli = json.loads((d / "cli" / "compensate_summary.json").read_text(encoding="utf-8"))
    for k in ("method", "model", "units", "allow", "residual"):
        assert summary[k] == cli[k]
    (e,) = summary["files"]
    assert e["points"] == len(axes) and e["failures"] == 0 and not e.get("refused")
    assert result.accepted and not result.refused and result.overrides == ()
    assert result.commands == {d / "path.csv": d / "api" / "path.csv"}
    assert result.residual_um[d / "path.csv"]["model_max_um"] == e["model_max_um"]


def test_a_refused_guard_is_named_in_the_result(mill_program):
    """A point outside the strokes (and so the calibrated volume): compensate_points refuses it by the stroke
    and volume guards, each in one line naming its override; allowing one leaves the other refused, allowing
    both accepts, and the overrides are recorded."""
    m, model, axes, d = mill_program
    out = axes.copy()
    out[0, 0] = m.strokes["x_mm"][1] + 5.0    # 5 mm past the X stroke
    res = compensate_points(load_model(model, m), m, out)
    assert not res.accepted and "stroke" in res.refused and 0 in res.violations["stroke"]
    why = res.refused["stroke"]
    assert "\n" not in why and len(why) < MESSAGE_MAX_CHARS and "allow='stroke'" in why
    half = compensate_points(load_model(model, m), m, out, allow=("stroke",))
    assert set(half.refused) == {"volume"} and half.overrides == ("stroke",)
    ok = compensate_points(load_model(model, m), m, out, allow=("stroke", "volume"))
    assert ok.accepted and ok.overrides == ("stroke", "volume") and any(n.startswith("stroke") for n in ok.notes)


def test_compensate_points_gives_the_program_commands(mill_program):
    m, model, axes, d = mill_program
    if not (d / "api" / "path.csv").is_file():
        compensate_program(d / "path.csv", m, model, d / "api")
    res = compensate_points(load_model(model, m), m, axes)
    assert res.success.all() and res.accepted
    from errormap.io import read_table
    t = read_table(d / "api" / "path.csv")
    written = np.stack([t.float(c) for c in m.axis_columns], axis=1)
    np.testing.assert_allclose(written, res.commands, rtol=0, atol=CSV_DECIMALS_TOL_MM)


def test_compensate_program_refuses_settings_the_chain_cannot_take(mill_program):
    m, model, _, d = mill_program
    from compensation.app.validate import UsageError
    with pytest.raises(UsageError, match="--max-rotary-correction-deg"):
        compensate_program(d / "path.csv", m, model, d / "rot", rotary_limit_deg=10.0)
    with pytest.raises(TypeError):
        compensate_program(d / "path.csv", m, model, d / "bad", no_such_setting=1)
    assert CompensateSettings(method="exact", model=str(model), out_dir=d).seed == 0


def test_save_and_load_fitted_estimators(tmp_path):
    m = load_machine("mill-xyz")
    truth = simulate_truth(m, seed=1)
    ident = Identification(m).fit(simulate_sweeps(truth, noise_um=1.0, seed=2, n_stations=6))
    axes = np.array([[100.0, 50, -100], [500, 350, -350]])
    p = save_model(tmp_path / "ident.json", ident)   # model.json with its elements and covariance beside it
    from compensation.model_file import read_model
    got = read_model(p, m)
    assert got.format == "volcomp-model/1" and got.holds() == ["elements", "covariance"]
    assert got.elements_path == tmp_path / "ident.elements.json"
    assert got.covariance_path == tmp_path / "ident.elements.cov.npz"
    np.testing.assert_allclose(load_model(p, m).predict(axes), ident.predict(axes), rtol=0, atol=ROUND_TRIP_TOL_UM)
    loop = ClosedLoop(m, effects=False).fit(simulate_checks(truth, n=40, noise_um=1.0, seed=3), ident.elements_,
                                            ident.prior_covariance_)
    p = save_model(tmp_path / "model.json", loop)
    assert p.name == "model.json" and (tmp_path / "model.elements.json").is_file()
    np.testing.assert_allclose(load_model(p, m).predict(axes), loop.predict(axes), rtol=0, atol=ROUND_TRIP_TOL_UM)
    with pytest.raises(ValueError, match="not fitted yet"):
        save_model(tmp_path / "x.json", Identification(m))


def test_closed_loop_ships_what_diagnose_ships(tmp_path):
    """``ClosedLoop().fit`` and ``volcomp diagnose --no-learned`` run one loop and one all-checks re-estimate
    (:func:`errormap.diagnosis.chain_loop.ship_on_all_checks`) on the same numbers (the element set and its
    covariance through their files, written exactly): the shipped models predict the same bits."""
    from compensation.app.workflows.measurement import diagnose_chain
    m = load_machine("mill-xyz")
    truth = simulate_truth(m, seed=1)
    ident = Identification(m).fit(simulate_sweeps(truth, noise_um=1.0, seed=2, n_stations=6))
    checks = simulate_checks(truth, n=40, noise_um=1.0, seed=3)
    from compensation.model_file import read_model
    elements_path = read_model(save_model(tmp_path / "E.json", ident), m).elements_path   # as `diagnose` reads it
    summary, _ = diagnose_chain(checks, m, elements_path, tmp_path / "diag", learn=False)
    loop = ClosedLoop(m).fit(checks, ident.elements_, ident.prior_covariance_)
    assert loop.kept_stage_ == summary["kept_stage"] and loop.kept_stage_.startswith("updated")
    assert loop.summary_["refit_on_all_checks"] == summary["refit_on_all_checks"]
    assert loop.summary_["refit_on_all_checks"]["checks"] == len(checks.axes)
    axes = np.array([[100.0, 50, -100], [500, 350, -350]])
    shipped = load_model(tmp_path / "diag" / "model.json", m)
    np.testing.assert_allclose(shipped.predict(axes), loop.predict(axes), rtol=0, atol=ROUND_TRIP_TOL_UM)
    split = ClosedLoop(m, refit_all=False).fit(checks, ident.elements_, ident.prior_covariance_)
    assert "refit_on_all_checks" not in split.summary_
    assert split.held_out_rms_um_ == loop.held_out_rms_um_      # the validated figure is the split's either way
    assert np.abs(split.predict(axes) - loop.predict(axes)).max() > 0   # the re-estimate changed the model


ARM_TRUE_RMS_RATIO_MAX = 0.05
"""TRUE tool-point error RMS after / before compensate_joints on a simulated UR5 (link/base/tool errors of
0.2 mm / 0.3 mrad, 2 mm base, a joint sag the DH slot set cannot represent, 20 μm tracker noise, 60 fit
poses): the unrepresented sag and the noise leave 5–76 μm of 0.35–4.7 mm (measured ratio 0.013); 0.05 fails
a compensation that removed less than 95 %."""


def test_compensate_joints_moves_a_calibrated_arm_onto_its_targets():
    from compensation import compensate_joints
    from compensation.arm_compensation import NEWTON_TOL_MM
    from errormap import ArmCalibration
    from errormap.arm_simulate import draw_truth, measure, random_joints
    ur5 = load_machine("ur5")
    lo, hi = np.array([j.lo for j in ur5.joints]), np.array([j.hi for j in ur5.joints])
    truth = draw_truth(ur5, 6)
    cal = ArmCalibration(ur5).fit(measure(ur5, truth, random_joints(lo, hi, 60, seed=5), 0.02, 7))
    q = random_joints(0.8 * lo, 0.8 * hi, 10, seed=8)
    sol = compensate_joints(cal, q)
    assert sol.accepted and sol.success.all() and sol.residual_um.max() <= NEWTON_TOL_MM * 1e3
    target = ur5.tool_point(q)
    before = truth.tool_point(ur5, q) - target
    after = truth.tool_point(ur5, sol.commands) - target
    assert np.sqrt(np.mean(after ** 2) / np.mean(before ** 2)) <= ARM_TRUE_RMS_RATIO_MAX
    with pytest.raises(ValueError, match="not fitted yet"):
        compensate_joints(ArmCalibration(ur5), q)
