"""The foundation's commands from the command line: simulate, featurepoints, predict."""
import json

import numpy as np
import pytest

from compensation.cli import main
from errormap.elements import ElementSet
from errormap.featurepoints import FeaturePoints
from errormap.io import read_table

TOL_UM = 1e-6


def test_simulate_featurepoints_predict(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["simulate", "--seed", "4", "--out", str(out), "--effect", "worm", "--checks", "50"]) == 0
    printed = capsys.readouterr().out
    assert "truth_elements.json" in printed and "checks.csv" in printed
    info = json.loads((out / "truth.json").read_text())
    assert 150 <= info["max_spatial_error_um"] <= 230 and "worm" in info["effects"]
    fp = FeaturePoints.load(out / "featurepoints.csv")
    assert fp.axes.shape == (1331, 3) and fp.meta["grid"] == "11x11x11"
    assert fp.meta["elements_sha256"] and fp.meta["machine_sha256"]
    # featurepoints command from the saved element set reproduces the simulate output
    assert main(["featurepoints", "--elements", str(out / "truth_elements.json"), "--out", str(tmp_path / "fp.csv")]) == 0
    np.testing.assert_allclose(FeaturePoints.load(tmp_path / "fp.csv").errors_um, fp.errors_um, atol=TOL_UM)
    # predict at the feature points gives the feature-point errors, extra columns kept
    pts = tmp_path / "pts.csv"
    pts.write_text("x_mm,z_mm,a_deg,label\n" + "\n".join(f"{x},{z},{a},p{i}" for i, (x, z, a) in enumerate(fp.axes[:20])))
    assert main(["predict", "--model", str(out / "truth_elements.json"), str(pts), "--out", str(tmp_path / "pred.csv")]) == 0
    t = read_table(tmp_path / "pred.csv")
    assert t.raw("label")[3] == "p3"
    np.testing.assert_allclose(np.c_[t.float("dx_um"), t.float("dy_um"), t.float("dz_um")], fp.errors_um[:20], atol=TOL_UM)


def test_bad_inputs_exit_cleanly(tmp_path, capsys):
    bad = tmp_path / "m.toml"
    bad.write_text('[machine]\nkind = "grinder"\n')
    assert main(["simulate", "--machine", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "geometry" in capsys.readouterr().err
    pts = tmp_path / "pts.csv"
    pts.write_text("x_mm,z_mm,a_deg\n1,2,3\n4,oops,6\n")
    el = tmp_path / "el.json"
    from errormap.machine import load_machine
    ElementSet.zeros(load_machine()).save(el)
    assert main(["predict", "--model", str(el), str(pts), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert "row 3" in err and "z_mm" in err
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("effect", ["thermal", "reversal"])
def test_simulate_effects_that_need_conditions(tmp_path, effect):
    assert main(["simulate", "--seed", "1", "--out", str(tmp_path), "--effect", effect, "--checks", "20"]) == 0
    info = json.loads((tmp_path / "truth.json").read_text())
    assert effect in info["effects"] and info["max_spatial_error_um"] > 150
