"""`volcomp sweeps` and `volcomp identify` from the command line."""
import json

import numpy as np

from chain_fixtures import OLD_GRINDER_FILE

from compensation.app.cli import main
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes

SPATIAL_TOL_UM = 0.01


def test_sweeps_then_identify(tmp_path, capsys):
    sw = tmp_path / "sweeps.csv"
    assert main(["sweeps", "--seed", "5", "--out", str(sw), "--noise-um", "0"]) == 0
    out = tmp_path / "el.json"
    truth_path = make_chain_truth(load_machine(), 5).elements.save(tmp_path / "truth.json")
    assert main(["identify", str(sw), "--out", str(out), "--plot", str(tmp_path / "fig"),
                 "--truth", str(truth_path)]) == 0
    text = capsys.readouterr().out
    assert "Gauss-Newton:" in text and f"wrote elements: {out}" in text
    for ax in "XZA":
        assert (tmp_path / f"fig_{ax}.png").stat().st_size > 10_000
    report = json.loads((tmp_path / "el.report.json").read_text())
    assert len(report["residual_rms_um"]["A"]) == 21 and report["gauge"] == "station-mean"
    m = load_machine()
    pts = random_axes(m, 2000, np.random.default_rng(1))
    d = (ChainField(m, ChainElementSet.load(out, m)).predict(pts)
         - ChainField(m, ChainElementSet.load(truth_path, m)).predict(pts))
    assert np.abs(d).max() < SPATIAL_TOL_UM


def test_degenerate_layout_is_one_clean_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    text = OLD_GRINDER_FILE.read_text()   # a kind = "grinder" file, read as its chain
    bad.write_text(text.replace("X = [[0.0, -60.0, 40.0], [80.0, 40.0, 40.0], [-40.0, 60.0, 90.0]]",
                                "X = [[0.0, 0.0, 40.0], [50.0, 0.0, 40.0], [100.0, 0.0, 40.0]]"))
    sw = tmp_path / "s.csv"
    assert main(["sweeps", "--machine", str(bad), "--seed", "1", "--out", str(sw)]) == 0
    capsys.readouterr()
    assert main(["identify", str(sw), "--machine", str(bad), "--out", str(tmp_path / "e.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and 'kind = "grinder" read as its machine-tool chain' in err[0]
    assert "targets.X" in err[-1] and "collinear" in err[-1]
    assert not (tmp_path / "e.json").exists()


def test_identify_reports_the_uncertainty_and_iso_names_of_any_machine_tool(tmp_path, capsys):
    """One identification for every machine tool: a mill's report carries the ``uncertainty`` block (a standard error
    per slot and station: the covariance file's diagonal, the same floats) and the ISO 230-1 names of its own file's
    slots, and the command prints them."""
    from errormap.chain_covariance import read_chain_covariance
    from errormap.chain_elements import ChainElementSet
    sw = tmp_path / "sw.csv"
    assert main(["sweeps", "--machine", "mill-xyz", "--seed", "2", "--out", str(sw)]) == 0
    capsys.readouterr()
    assert main(["identify", str(sw), "--machine", "mill-xyz", "--out", str(tmp_path / "E.json")]) == 0
    text = capsys.readouterr().out
    m = load_machine("mill-xyz")
    report = json.loads((tmp_path / "E.report.json").read_text())
    assert report["iso230_names"] == dict(zip(m.slot_names, m.iso_names))
    se = report["uncertainty"]["standard_errors"]
    assert list(se) == list(m.slot_names)
    slots, stations, C = read_chain_covariance(tmp_path / "E.cov.npz", ChainElementSet.load(tmp_path / "E.json", m))
    sd = np.sqrt(np.diag(C))
    assert [se[s] if i < 0 else se[s][i] for s, i in zip(slots, stations)] == sd.tolist()   # no full-turn axis
    assert all(f"{s} ({iso})" in text for s, iso in zip(m.slot_names, m.iso_names))
    assert "largest station standard error:" in text
