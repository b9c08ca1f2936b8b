"""Diagnosis of check measurements on the grinder (the machine tools' one loop on its chain, effects on the model
as it is: no covariance, no update): each undeclared effect is found, noise is not, a trained network's terms are
carried into its retrain when its grid can, bad input fails cleanly."""
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.app.workflows.network_diagnosis import (TermsOnBase, augmented_feature_points, grid_aliasing,
                                                          retrain_learned)
from errormap.chain_elements import ChainElementSet
from errormap.diagnosis.chain_loop import ChainChecks, closed_loop_chain
from errormap.featurepoints import make_feature_points
from errormap.chain_field import ChainField
from errormap.io import write_csv
from errormap.seeds import spawn_seeds
from errormap.chain_truth import make_chain_truth
from training import TrainSettings

NOISE_UM = 1.0
N_CHECKS = 400
RMS_RATIO_MAX = 1.25   # held-out RMS after / RMS of the same loop without the effect
SEED = 7
PERIOD_TOL_MM = 0.05
"""The pitch period found (grid 1.4 % apart, then refined in 0.025 % steps) against the simulated 10 mm: 0.5 %,
where a wrong period (another grid point) is off by 1.4 % or more."""
AMPLITUDE_TOL_UM = 0.5
"""The pitch amplitude found against the simulated 4 μm: 240 fitting checks at 1 μm noise give its coefficients
a standard error near 0.1 μm; 0.5 μm is 5 of them."""

EXPECTED = {  # simulator effect -> (kind, axis word, elements accepted)
    "thermal": ("thermal", "X", {"dx_x"}),
    "reversal": ("reversal", "Z", {"dz_z"}),
    "pitch": ("periodic", "X", {"dx_x"}),
    "worm": ("harmonic", "A", {"ex_a"}),
}


def chain_elements(elements, mt):
    """A grinder element set as its chain's (the same file read by the chain)."""
    return ChainElementSet.load(elements.save(Path(tempfile.mkdtemp()) / "el.json"), mt)


def run_loop(machine, seed, effects):
    """The loop on the truth's own elements (nothing to update) and 400 checks: → summary (with ``_models``)."""
    mt = machine
    truth = make_chain_truth(machine, seed, effects=effects)
    checks = ChainChecks.from_columns(mt, truth.check_measurements(N_CHECKS, NOISE_UM, spawn_seeds(seed, 1)[0]))
    return closed_loop_chain(mt, chain_elements(truth.elements, mt), checks, cov=None)


@pytest.fixture(scope="module")
def baseline(grinder):
    return run_loop(grinder, SEED, [])


@pytest.mark.slow   # one loop per effect
@pytest.mark.parametrize("effect", sorted(EXPECTED))
def test_each_undeclared_effect_is_found(grinder, baseline, effect):
    s = run_loop(grinder, SEED, [effect])
    assert s["effects"], f"{effect}: nothing found"
    kind, axis, elements = EXPECTED[effect]
    top = s["effects"][0]
    assert (top["kind"], top["axis"]) == (kind, axis)
    assert top["element"] in elements and top["held_out_gain_z"] > 0
    before = s["stages"]["identified"]["held_out"]["rms_um"]
    assert s["held_out_rms_um"] <= RMS_RATIO_MAX * baseline["held_out_rms_um"]
    assert s["held_out_rms_um"] < before
    assert np.all(np.isfinite(top["coefficients"]))


@pytest.mark.slow   # one loop on 400 checks
def test_an_interaction_the_element_slots_represent_is_named_as_absorbed(grinder):
    """On the grinder an X·Z coupling is angular elements times lever arms: the loop names it as a term the
    element slots represent (an update takes it up), not a missed effect."""
    s = run_loop(grinder, SEED, ["interaction"])
    assert ("interaction", "X*Z") in {(e["kind"], e["axis"]) for e in s["effects_absorbed"]}


@pytest.mark.slow
def test_parameters_match_the_simulated_magnitudes(grinder):
    top = run_loop(grinder, SEED, ["pitch"])["effects"][0]
    assert abs(top["shape"]["period_mm"] - 10.0) < PERIOD_TOL_MM
    assert abs(np.hypot(*top["coefficients"]) - 4.0) < AMPLITUDE_TOL_UM


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_effect_is_reported_on_noise(grinder, seed):
    s = run_loop(grinder, seed, [])
    assert s["effects"] == []
    assert s["held_out_rms_um"] == s["stages"]["identified"]["held_out"]["rms_um"]   # nothing changed


@pytest.mark.slow
def test_two_effects_at_once_are_both_found(grinder):
    s = run_loop(grinder, SEED, ["reversal", "worm"])
    found = {(e["kind"], e["axis"], e["element"]) for e in s["effects"]}
    assert {("reversal", "Z", "dz_z"), ("harmonic", "A", "ex_a")} <= found
    assert len(found) == 2


def _terms_on(grinder, effects, base):
    s = run_loop(grinder, SEED, effects)
    return TermsOnBase(grinder, base, s["_models"]["terms"])


@pytest.mark.slow
def test_terms_on_a_network_need_their_conditions(grinder):
    base = ChainField(grinder, make_chain_truth(grinder, SEED).elements)
    cf = _terms_on(grinder, ["reversal"], base)
    assert cf.needs == ("dir_z",)
    axes = np.array([[50.0, 20.0, 30.0], [120.0, 10.0, 200.0]])
    with pytest.raises(ValueError, match="dir_z"):
        cf.predict(axes)
    plus, minus = cf.predict(axes, dir_z=np.ones(2)), cf.predict(axes, dir_z=-np.ones(2))
    np.testing.assert_allclose(plus + minus, 2 * base.predict(axes), atol=1e-9)   # the term is odd in the direction
    assert np.linalg.norm(plus - minus, axis=1).min() > 0


@pytest.mark.slow
def test_learned_retrain_hook_gets_feature_points_plus_terms(grinder):
    base = ChainField(grinder, make_chain_truth(grinder, SEED).elements)
    corrected = _terms_on(grinder, ["worm"], base)
    fp = make_feature_points(grinder, base, n=5)
    seen = {}

    class Result:
        field, metrics, run_id = base, {"rms_um": 0.0}, "child"

    def fake_fit_field(featurepoints, settings, tracking):
        seen.update(fp=featurepoints, settings=settings, tracking=tracking)
        return Result()

    res = retrain_learned(fp, corrected, parent_run_id="parent123", fit_field=fake_fit_field,
                          settings=TrainSettings(max_iter=3))
    assert res.run_id == "child" and seen["tracking"].parent_run_id == "parent123"
    assert seen["settings"].trainer == "lm" and seen["settings"].max_iter == 3
    assert seen["settings"].max_time_s == float("inf")  # stops on iterations: the same retrain on any machine
    np.testing.assert_allclose(seen["fp"].errors_um - fp.errors_um, corrected.terms_only(fp.axes), atol=1e-12)
    assert "harmonic" in seen["fp"].meta["diagnosis_terms"]
    # terms needing conditions cannot go into a field of the axes
    with pytest.raises(ValueError, match="dir_z"):
        augmented_feature_points(fp, _terms_on(grinder, ["reversal"], base))


@pytest.mark.slow
def test_grid_aliasing_of_terms_is_detected(grinder):
    """A 40/rev worm harmonic on the 11-point A grid (every 36°) aliases to a constant: the learned retrain must
    not pretend feature points carry it; a 10 mm pitch on the 11-point X grid (20 mm apart) aliases too."""
    base = ChainField(grinder, make_chain_truth(grinder, SEED).elements)
    fp = make_feature_points(grinder, base, n=11)
    for effect in ("worm", "pitch"):
        a = grid_aliasing(fp, _terms_on(grinder, [effect], base))
        assert a["aliased"] and a["rms_missed_by_grid_um"] > 0.5 * a["rms_in_volume_um"], effect


def test_cli_writes_report_and_json(grinder, tmp_path, capsys):
    truth = make_chain_truth(grinder, 3, effects=["worm"])
    el = truth.elements.save(tmp_path / "el.json")
    write_csv(tmp_path / "checks.csv", truth.check_measurements(N_CHECKS, NOISE_UM, 3))
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "checks.csv"), "--model", str(el), "--out", str(out), "--no-learned"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    for k in ("effects", "stages", "held_out_rms_um", "kept_stage", "verdict", "baselines_vs_kept"):
        assert k in d
    assert d["effects"][0]["kind"] == "harmonic" and d["effects"][0]["element"] == "ex_a"
    assert d["effects"][0]["shape"]["order"] == 40
    page = (out / "report.html").read_text()
    assert "data:image/png;base64," in page and "MEASURED" in page
    assert "src='http" not in page and 'src="http' not in page
    assert "harmonic" in capsys.readouterr().out


BAD = {
    "nan": (lambda c: c["dy_um"].__setitem__(4, np.nan), "row 6", "dy_um"),
    "metres": (lambda c: c["dz_um"].__setitem__(7, 0.05 * 1e6 * 1e3), "row 9", "dz_um"),
    "outside": (lambda c: c["x_mm"].__setitem__(2, 250.0), "row 4", "x_mm"),
    "dup_seq": (lambda c: c["seq"].__setitem__(9, c["seq"][8]), "row 11", "seq"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_names_row_and_column_and_writes_nothing(grinder, tmp_path, capsys, case):
    cols = {k: np.array(v, dtype=float) for k, v in
            make_chain_truth(grinder, 3).check_measurements(60, NOISE_UM, 3).items()}
    change, row, col = BAD[case]
    change(cols)
    write_csv(tmp_path / "checks.csv", cols)
    el = make_chain_truth(grinder, 3).elements.save(tmp_path / "el.json")
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "checks.csv"), "--model", str(el), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert row in err and col in err and "checks.csv" in err
    assert not out.exists() or not any(out.iterdir())


def test_missing_column_and_unit_mistake(grinder, tmp_path, capsys):
    truth = make_chain_truth(grinder, 3)
    el = truth.elements.save(tmp_path / "el.json")
    cols = truth.check_measurements(60, NOISE_UM, 3)
    cols.pop("dz_um")
    write_csv(tmp_path / "a.csv", cols)
    assert main(["diagnose", str(tmp_path / "a.csv"), "--model", str(el), "--out", str(tmp_path / "out")]) == 2
    assert "dz_um" in capsys.readouterr().err
    cols = truth.check_measurements(60, NOISE_UM, 3)
    cols["dx_um"] = cols["dx_um"] * 1e-3  # written in mm, not μm
    write_csv(tmp_path / "b.csv", cols)
    assert main(["diagnose", str(tmp_path / "b.csv"), "--model", str(el), "--out", str(tmp_path / "out")]) == 2
    assert "dx_um" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_retrain_options_with_an_element_set_are_refused(grinder, tmp_path, capsys):
    """--featurepoints and the retrain's limits retrain a trained network; with an element set they are refused in
    one line, nothing written."""
    el = make_chain_truth(grinder, 3).elements.save(tmp_path / "el.json")
    write_csv(tmp_path / "c.csv", make_chain_truth(grinder, 3).check_measurements(60, NOISE_UM, 3))
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "c.csv"), "--model", str(el), "--out", str(out), "--seed", "3"]) == 2
    err = capsys.readouterr().err
    assert "--seed" in err and "element set" in err and not out.exists()


@pytest.mark.parametrize("opt, value, named", [("--retrain-iter", "0", "--retrain-iter"),
                                               ("--retrain-time-s", "-1", "--retrain-time-s")])
def test_retrain_limits_are_checked_before_any_work(tmp_path, capsys, opt, value, named):
    """The retrain stops on iterations by default; a bad limit is one line, exit 2, nothing written."""
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "none.csv"), "--model", "x", "--out", str(out), opt, value]) == 2
    assert named in capsys.readouterr().err and not out.exists()


@pytest.mark.slow   # a 20-iteration network is trained first
def test_cli_diagnoses_a_trained_network_and_refuses_track_with_it(grinder, tmp_path, capsys):
    """A trained network as the model (the grinder's, a folder): identified + effects on it, diagnosis.json only;
    --track (a kept learned residual) is refused in one line, nothing written."""
    truth = make_chain_truth(grinder, 3, effects=["worm"])
    el = truth.elements.save(tmp_path / "el.json")
    write_csv(tmp_path / "checks.csv", truth.check_measurements(N_CHECKS, NOISE_UM, 3))
    assert main(["featurepoints", "--elements", str(el), "--grid", "5", "--out", str(tmp_path / "fp.csv")]) == 0
    assert main(["train", str(tmp_path / "fp.csv"), "--out", str(tmp_path / "net"), "--max-iter", "20",
                 "--hidden", "6,6", "--no-select"]) == 0
    argv = ["diagnose", str(tmp_path / "checks.csv"), "--model", str(tmp_path / "net" / "model")]
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "t"), "--track"]) == 2
    assert "--track" in capsys.readouterr().err and not (tmp_path / "t").exists()
    assert main([*argv, "--out", str(tmp_path / "d")]) in (0, 1)   # 1: the verdict judges a poorly trained network
    s = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert s["update"] is False and s["model_source"]["kind"] == "network"
    assert s["stages"]["identified"]["held_out"]["rms_um"] > 0 and "verdict" in s
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == ["diagnosis.json"]
