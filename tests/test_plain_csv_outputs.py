"""Every CSV volcomp writes opens with a plain ``pandas.read_csv(path)``: the header is its first line, and its
provenance is in the sidecar ``NAME.meta.json`` beside it (errormap.io.write_csv / sidecar_path), which volcomp's own
reader (errormap.io.read_table) takes back; an older file with leading ``#`` lines is still read, its provenance
from those lines.

The command runs use small settings; each reads every CSV its commands wrote, whatever its name, so a new CSV
output of these commands is covered without a new line here."""
from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compensation.app.cli import main
from errormap.io import CSV_META_FORMAT, read_table, sidecar_path, write_csv

# cells are written with 9 significant digits by default ("%.9g"): pandas reads them back within this
TOL_REL = 1e-8


def _ok(*argv):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    assert rc == 0, (argv, err.getvalue()[-1500:])


def _check_every_csv(root: Path, expected: set) -> list:
    """Read every CSV under ``root`` with plain pandas: its header is its sidecar's columns, its rows the sidecar's
    count, the sidecar holds the provenance; ``expected`` names (relative paths) must be among them."""
    found = sorted(p for p in root.rglob("*.csv"))
    rel = {str(p.relative_to(root)) for p in found}
    assert expected <= rel, sorted(expected - rel)
    for p in found:
        if p.relative_to(root).parts[0] == "in":   # the test's own inputs
            continue
        df = pd.read_csv(p)
        side = sidecar_path(p)
        assert side.is_file(), f"{p}: no sidecar {side.name}"
        meta = json.loads(side.read_text(encoding="utf-8"))
        assert meta["format"] == CSV_META_FORMAT and meta["csv"] == p.name
        assert list(df.columns) == meta["columns"], p
        assert len(df) == meta["rows"] and len(df) > 0, p
        assert meta["written_by"].startswith("volcomp ") and isinstance(meta["provenance"], dict), p
        assert not any(str(c).startswith("#") for c in df.columns), p
        assert read_table(p).comments == meta["lines"], p      # volcomp's reader takes it back
    return found


def test_write_csv_is_plain_and_its_sidecar_holds_the_provenance(tmp_path):
    p = write_csv(tmp_path / "t.csv", {"x_mm": np.array([1.0, 2.5]), "n": np.array([3, 4])},
                  header_comments=["machine: grinder", "a free note"])
    assert p.read_text().splitlines()[0] == "x_mm,n"
    df = pd.read_csv(p)
    assert list(df.columns) == ["x_mm", "n"] and df["x_mm"].tolist() == [1.0, 2.5]
    meta = json.loads((tmp_path / "t.meta.json").read_text())
    assert meta["provenance"] == {"machine": "grinder"} and meta["lines"] == ["machine: grinder", "a free note"]
    t = read_table(p)
    assert t.meta() == {"machine": "grinder"} and t.comments == ["machine: grinder", "a free note"]


def test_an_older_file_with_comment_lines_is_still_read_with_its_provenance(tmp_path):
    p = tmp_path / "old.csv"
    p.write_text("# machine: grinder\n# grid: 3x3x3\nx_mm,z_mm\n1,2\n")
    t = read_table(p)
    assert t.meta() == {"machine": "grinder", "grid": "3x3x3"} and t.float("z_mm").tolist() == [2.0]


def test_a_sidecar_of_other_columns_is_not_taken(tmp_path):
    """A CSV rewritten by another tool (other columns) keeps only its own provenance: the stale sidecar is ignored."""
    p = write_csv(tmp_path / "t.csv", {"x_mm": np.array([1.0])}, header_comments=["machine: grinder"])
    p.write_text("y_mm\n1\n")
    assert read_table(p).meta() == {}


def test_the_sidecar_of_another_name(tmp_path):
    assert sidecar_path(tmp_path / "a.csv") == tmp_path / "a.meta.json"
    assert sidecar_path(tmp_path / "a.CSV") == tmp_path / "a.meta.json"
    assert sidecar_path(tmp_path / "a.txt") == tmp_path / "a.txt.meta.json"


@pytest.mark.slow  # a grinder's whole file path: simulate, featurepoints, predict, sweeps, compensate, report, export
def test_every_csv_of_the_grinder_commands_opens_in_pandas(tmp_path):
    from path_files import write_targets_csv
    from compensation.toolpath import flute_path
    el = tmp_path / "sim" / "truth_elements.json"
    _ok("simulate", "--seed", "0", "--out", tmp_path / "sim", "--checks", "20")
    _ok("featurepoints", "--elements", el, "--grid", "3", "--out", tmp_path / "fp.csv")
    (tmp_path / "in").mkdir()
    pts = tmp_path / "in" / "pts.csv"
    grid = pd.read_csv(tmp_path / "fp.csv")[["x_mm", "z_mm", "a_deg"]].iloc[:5]   # points inside the volume
    pts.write_text("# an older file: a comment line above the header\n" + grid.to_csv(index=False))
    _ok("predict", "--model", el, pts, "--out", tmp_path / "p.csv")
    assert read_table(tmp_path / "p.csv").meta()["model_kind"]      # provenance through the sidecar
    _ok("sweeps", "--seed", "0", "--out", tmp_path / "sw.csv")
    flute = write_targets_csv(tmp_path / "in" / "flute.csv", flute_path(turns=1, points_per_turn=12).targets_mm)
    _ok("compensate", flute, "--model", el, "--method", "exact", "--work-offsets", "machine", "--out", tmp_path / "c")
    _ok("report", "--model", el, "--path", pts, "--methods", "exact", "--out", tmp_path / "r")
    _ok("export", el, "--format", "grid", "--out", tmp_path / "eg")
    _ok("export", el, "--format", "iso-tables", "--out", tmp_path / "ei")
    found = _check_every_csv(tmp_path, {"sim/featurepoints.csv", "sim/checks.csv", "fp.csv", "p.csv", "sw.csv",
                                        "c/flute.csv", "r/residuals.csv", "eg/grid.csv", "ei/iso_location.csv"})
    got = pd.read_csv(tmp_path / "p.csv")
    want = read_table(tmp_path / "p.csv")
    np.testing.assert_allclose(got["dx_um"], want.float("dx_um"), rtol=TOL_REL)
    assert len(found) >= 10


@pytest.mark.slow  # drift: diagnose --drift on a short simulated log, export --format drift, drift-predict
def test_every_csv_of_the_drift_commands_opens_in_pandas(tmp_path):
    from errormap.diagnosis.drift_sim import simulate_lumped_log
    cols = simulate_lumped_log(0, hours=16.0, dt_s=120.0, n_dropouts=0, n_sensors=8)
    cols.pop("_truth")
    (tmp_path / "in").mkdir()
    write_csv(tmp_path / "in" / "log.csv", cols)
    _ok("diagnose", "--drift", tmp_path / "in" / "log.csv", "--out", tmp_path / "d")
    _ok("drift-predict", tmp_path / "d" / "drift_model.json", tmp_path / "in" / "log.csv", "--out", tmp_path / "dp.csv")
    _ok("export", tmp_path / "d" / "drift_model.json", "--format", "drift", "--log", tmp_path / "in" / "log.csv",
        "--out", tmp_path / "ed")
    _check_every_csv(tmp_path, {"d/drift_compensation.csv", "dp.csv", "ed/drift_coefficients.csv"})


@pytest.mark.slow  # a serial arm and a hexapod: simulate, calibrate, predict, register, interpolate; a chain's files
def test_every_csv_of_the_arm_parallel_and_chain_commands_opens_in_pandas(tmp_path):
    _ok("simulate", "--machine", "ur5", "--seed", "0", "--out", tmp_path / "arm")
    _ok("calibrate", tmp_path / "arm" / "poses.csv", "--check", tmp_path / "arm" / "checks.csv", "--machine", "ur5",
        "--no-learned", "--out", tmp_path / "cal")
    _ok("predict", "--machine", "ur5", "--model", tmp_path / "cal" / "model.json", tmp_path / "arm" / "program.csv",
        "--out", tmp_path / "ap.csv")
    _ok("register", tmp_path / "arm" / "checks.csv", "--machine", "ur5", "--model", tmp_path / "cal" / "model.json",
        "--out", tmp_path / "reg")
    _ok("compensate", tmp_path / "arm" / "program.csv", "--machine", "ur5", "--model",
        tmp_path / "cal" / "model.json", "--out", tmp_path / "ac")
    _ok("simulate", "--machine", "hexapod", "--seed", "0", "--poses", "60", "--checks", "40", "--out", tmp_path / "hex")
    _ok("calibrate", tmp_path / "hex" / "poses.csv", "--check", tmp_path / "hex" / "checks.csv", "--machine", "hexapod",
        "--out", tmp_path / "hcal")
    (tmp_path / "in").mkdir()
    checks = pd.read_csv(tmp_path / "hex" / "checks.csv")
    checks[[c for c in checks.columns if c in ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")]].iloc[:5].to_csv(
        tmp_path / "in" / "hex_pts.csv", index=False)
    _ok("predict", "--machine", "hexapod", "--model", tmp_path / "hcal" / "model.json",
        tmp_path / "in" / "hex_pts.csv", "--out", tmp_path / "hp.csv")
    _ok("interpolate", "sphere", "--out", tmp_path / "i.csv")
    _ok("simulate", "--machine", "mill-xyz", "--seed", "2", "--checks", "20", "--out", tmp_path / "mill")
    _ok("sweeps", "--machine", "mill-xyz", "--seed", "2", "--out", tmp_path / "mill_sw.csv")
    (tmp_path / "in" / "mill_path.csv").write_text("x_mm,y_mm,z_mm\n100,100,-100\n300,200,-200\n500,300,-300\n")
    _ok("compensate", tmp_path / "in" / "mill_path.csv", "--machine", "mill-xyz", "--model",
        tmp_path / "mill" / "truth_elements.json", "--method", "exact", "--work-offsets", "machine", "--out", tmp_path / "mc")
    _check_every_csv(tmp_path, {"arm/poses.csv", "arm/checks.csv", "arm/program.csv", "ap.csv", "hex/poses.csv",
                                "hex/checks.csv", "hp.csv", "i.csv", "mill/checks.csv", "mill_sw.csv",
                                "mc/mill_path.csv"})
    assert {p.suffix for p in (tmp_path / "ac").iterdir()} & {".csv"}   # the arm's compensated program


@pytest.mark.slow  # the shared tiny demo run and the shared quick benchmark of a chain (tests/shared_runs.py)
def test_every_csv_of_demo_and_benchmark_opens_in_pandas(tiny_demo, mill_quick_benchmark):
    _check_every_csv(tiny_demo.root / "demo", {"residuals.csv", "sim/featurepoints.csv", "sim/checks.csv"})
    assert len(_check_every_csv(mill_quick_benchmark.root / "b", set())) >= 1


def test_ctrl_c_removes_the_new_csv_and_its_sidecar_and_keeps_an_old_pair(tmp_path):
    """A one-file output owned by a run (compensation/app/outputs.py owned_file): on Ctrl-C the CSV and its sidecar
    that were not there before are removed; a pair that was there before stays."""
    from compensation.app.outputs import owned_file
    out = tmp_path / "p.csv"
    with pytest.raises(KeyboardInterrupt), owned_file(out, "predict"):
        write_csv(out, {"x_mm": np.array([1.0])}, header_comments=["machine: grinder"])
        raise KeyboardInterrupt
    assert not out.exists() and not sidecar_path(out).exists()
    write_csv(out, {"x_mm": np.array([1.0])}, header_comments=["machine: grinder"])
    with pytest.raises(KeyboardInterrupt), owned_file(out, "predict"):
        raise KeyboardInterrupt
    assert out.exists() and read_table(out).meta() == {"machine": "grinder"}
