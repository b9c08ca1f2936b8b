"""Diagnosis of check measurements: each undeclared effect is found, noise is not, bad input fails cleanly."""
import json

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.app.workflows.diagnosis import augmented_feature_points, retrain_learned, run_checks
from errormap.diagnosis.checks import CheckData
from errormap.diagnosis.pipeline import diagnose
from errormap.featurepoints import make_feature_points
from errormap.htm import HTMField
from errormap.io import InputError, write_csv
from errormap.simulator import random_truth

NOISE_UM = 1.0
N_CHECKS = 400
RMS_RATIO_MAX = 1.25   # held-out RMS after / RMS of the same pipeline without the effect
SEED = 7

EXPECTED = {  # simulator effect -> (kind, axis, elements accepted)
    "thermal": ("thermal", "x", {"dx_x"}),
    "reversal": ("reversal", "z", {"dz_z"}),
    "pitch": ("periodic", "x", {"dx_x"}),
    "worm": ("harmonic", "a", {"ex_a"}),
    "interaction": ("interaction", "x*z", {"dx_x", "dx"}),
}


def run_pipeline(machine, seed, effects):
    truth = random_truth(machine, seed, effects=effects)
    checks = CheckData.from_columns(truth.check_measurements(N_CHECKS, NOISE_UM, seed + 1000))
    return diagnose(machine, HTMField(machine, truth.elements), checks)


@pytest.fixture(scope="module")
def baseline(grinder):
    return run_pipeline(grinder, SEED, [])


@pytest.mark.parametrize("effect", sorted(EXPECTED))
def test_each_undeclared_effect_is_found(grinder, baseline, effect):
    d = run_pipeline(grinder, SEED, [effect])
    s = d.summary
    assert s["effects"], f"{effect}: nothing found"
    kind, axis, elements = EXPECTED[effect]
    top = s["effects"][0]
    assert (top["kind"], top["axis"]) == (kind, axis)
    assert top["element"] in elements
    assert top["rms_reduction_um"] > 0
    assert s["rms_after_um"] <= RMS_RATIO_MAX * baseline.summary["rms_after_um"]
    assert s["rms_after_um"] < s["rms_before_um"]
    for p in top["parameters"].values():
        assert p["unit"] and np.isfinite(p["value"])


def test_parameters_match_the_simulated_magnitudes(grinder):
    d = run_pipeline(grinder, SEED, ["pitch"])
    p = d.summary["effects"][0]["parameters"]
    assert abs(p["period_mm"]["value"] - 10.0) < 5 * p["period_mm"]["se"] + 0.05
    assert abs(p["amplitude_um"]["value"] - 4.0) < 5 * p["amplitude_um"]["se"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_effect_is_reported_on_noise(grinder, seed):
    d = run_pipeline(grinder, seed, [])
    assert d.summary["effects"] == []
    assert d.summary["rms_after_um"] == d.summary["rms_before_um"]


def test_two_effects_at_once_are_both_found(grinder):
    d = run_pipeline(grinder, SEED, ["reversal", "worm"])
    found = {(e["kind"], e["axis"], e["element"]) for e in d.summary["effects"]}
    assert {("reversal", "z", "dz_z"), ("harmonic", "a", "ex_a")} <= found
    assert len(found) == 2


def test_corrected_field_needs_its_conditions(grinder):
    d = run_pipeline(grinder, SEED, ["reversal"])
    cf = d.corrected
    assert cf.needs == ("dir_z",)
    axes = d.checks.axes[:5]
    with pytest.raises(ValueError, match="dir_z"):
        cf.predict(axes)
    plus, minus = cf.predict(axes, dir_z=np.ones(5)), cf.predict(axes, dir_z=-np.ones(5))
    backlash = d.summary["effects"][0]["parameters"]["backlash_um"]["value"]
    np.testing.assert_allclose(np.linalg.norm(plus - minus, axis=1), abs(backlash), rtol=1e-3)


def test_learned_retrain_hook_gets_feature_points_plus_terms(grinder):
    d = run_pipeline(grinder, SEED, ["worm"])
    base = HTMField(grinder, random_truth(grinder, SEED).elements)
    fp = make_feature_points(grinder, base, n=5)
    seen = {}

    class Result:
        field, metrics, run_id = base, {"rms_um": 0.0}, "child"

    def fake_fit_field(featurepoints, **kw):
        seen.update(kw, fp=featurepoints)
        return Result()

    res = retrain_learned(fp, d.corrected, parent_run_id="parent123", fit_field=fake_fit_field, max_time_s=1.0)
    assert res.run_id == "child" and seen["parent_run_id"] == "parent123" and seen["trainer"] == "lm"
    np.testing.assert_allclose(seen["fp"].errors_um - fp.errors_um, d.corrected.terms_only(fp.axes), atol=1e-12)
    assert "harmonic" in seen["fp"].meta["diagnosis_terms"]
    # terms needing conditions cannot go into a field of the axes
    d2 = run_pipeline(grinder, SEED, ["reversal"])
    with pytest.raises(ValueError, match="dir_z"):
        augmented_feature_points(fp, d2.corrected)


def _write_checks(path, machine, seed=3, effects=("worm",), n=120):
    cols = random_truth(machine, seed, effects=list(effects)).check_measurements(n, NOISE_UM, seed)
    write_csv(path, cols)
    return cols


def test_cli_writes_report_and_json(grinder, tmp_path, capsys):
    truth = random_truth(grinder, 3, effects=["worm"])
    el = truth.elements.save(tmp_path / "el.json")
    write_csv(tmp_path / "checks.csv", truth.check_measurements(N_CHECKS, NOISE_UM, 3))
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "checks.csv"), "--model", str(el), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    for k in ("effects", "rms_before_um", "rms_after_um", "max_before_um", "max_after_um", "unexplained_after"):
        assert k in d
    assert d["effects"][0]["kind"] == "harmonic" and d["effects"][0]["element"] == "ex_a"
    assert d["effects"][0]["parameters"]["order"]["value"] == 40
    page = (out / "report.html").read_text()
    assert "data:image/png;base64," in page and "measured residual" in page
    assert "ex_a (EAA)" in page  # the element with its ISO 230-1 name beside it
    assert "src='http" not in page and 'src="http' not in page
    assert "harmonic" in capsys.readouterr().out


BAD = {
    "nan": (lambda c: c["dy_um"].__setitem__(4, np.nan), "row 6", "dy_um"),
    "metres": (lambda c: c["dz_um"].__setitem__(7, 0.05 * 1e6 * 1e3), "row 9", "dz_um"),
    "outside": (lambda c: c["x_mm"].__setitem__(2, 250.0), "row 4", "x_mm"),
    "duplicate": (lambda c: [c[k].__setitem__(9, c[k][8]) for k in c], "row 11", "row 10"),
    "dup_seq": (lambda c: c["seq"].__setitem__(9, c["seq"][8]), "row 11", "seq"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_names_row_and_column_and_writes_nothing(grinder, tmp_path, capsys, case):
    cols = {k: np.array(v, dtype=float) for k, v in
            random_truth(grinder, 3).check_measurements(60, NOISE_UM, 3).items()}
    change, row, col = BAD[case]
    change(cols)
    write_csv(tmp_path / "checks.csv", cols)
    el = random_truth(grinder, 3).elements.save(tmp_path / "el.json")
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "checks.csv"), "--model", str(el), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert row in err and col in err and "checks.csv" in err
    assert not out.exists() or not any(out.iterdir())


def test_missing_column_and_unit_mistake(grinder, tmp_path):
    truth = random_truth(grinder, 3)
    cols = truth.check_measurements(60, NOISE_UM, 3)
    cols.pop("dz_um")
    write_csv(tmp_path / "a.csv", cols)
    with pytest.raises(InputError, match="dz_um"):
        run_checks(tmp_path / "a.csv", grinder, "x", tmp_path / "out", field_=HTMField(grinder, truth.elements))
    cols = truth.check_measurements(60, NOISE_UM, 3)
    cols["dx_um"] = cols["dx_um"] * 1e-3  # written in mm, not μm
    write_csv(tmp_path / "b.csv", cols)
    with pytest.raises(InputError, match=r"row \d+, column 'dx_um': units do not fit"):
        run_checks(tmp_path / "b.csv", grinder, "x", tmp_path / "out", field_=HTMField(grinder, truth.elements))
    assert not (tmp_path / "out").exists()


def test_grid_aliasing_of_terms_is_detected(grinder):
    """A 40/rev worm harmonic on the 11-point A grid (every 36°) aliases to a constant: the
    learned retrain must not pretend feature points carry it; an x·z interaction survives."""
    from compensation.app.workflows.diagnosis import grid_aliasing
    base = HTMField(grinder, random_truth(grinder, SEED).elements)
    fp = make_feature_points(grinder, base, n=11)
    worm = grid_aliasing(fp, run_pipeline(grinder, SEED, ["worm"]).corrected)
    assert worm["aliased"] and worm["rms_missed_by_grid_um"] > 0.5 * worm["rms_in_volume_um"]
    inter = grid_aliasing(fp, run_pipeline(grinder, SEED, ["interaction"]).corrected)
    assert not inter["aliased"] and inter["rms_missed_by_grid_um"] < 0.05 * inter["rms_in_volume_um"]
