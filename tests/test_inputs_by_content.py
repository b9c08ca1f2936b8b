"""Issue 30, points 1, 2 and 8: files known by content, one unit check for every reader, and the
messages that misled. Each test is the reproduction of a defect, run through the CLI (``main``):
exit status 2 and one line naming the file, the row and the column and the likely mistake."""
import dataclasses
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.fields import resolve_model
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError, read_table, write_csv
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth
from errormap.chain_sweeps import simulated_sweeps
from errormap.sweeps import write_sweeps
from errormap.chain_covariance import covariance_path

ROOT = Path(__file__).resolve().parents[1]
SEED = 5
GAUGE_TOL = 0.01
"""μm / μrad: noise-free sweeps of a truth identify to it exactly up to the solver's 1e-9 tolerance
and the B-spline; what is left between the overlay and the identification must be below this."""
GAUGE_SHIFT_MIN = 10.0
"""μrad: the rigid frame change between the simulator's gauge and station-mean moves tens of μrad
(42 μrad in ez_x, ez_z for seed 5); the old overlay (squareness only) must show at least this."""


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def _one_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if ln.startswith("volcomp ")]
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


def _checks(machine, tmp_path, name="checks.csv", **change) -> Path:
    cols = make_chain_truth(machine, SEED).check_measurements(n=60, seed=1)
    cols = {k: np.asarray(v) for k, v in cols.items()}
    for k, f in change.items():
        cols[k] = f(cols[k])
    return write_csv(tmp_path / name, cols)


def _points(tmp_path, name, x, z, a) -> Path:
    return write_csv(tmp_path / name, {"x_mm": np.asarray(x, float), "z_mm": np.asarray(z, float),
                                       "a_deg": np.asarray(a, float)})


# -- point 1: files known by content ---------------------------------------------------------------
def test_models_are_recognised_by_their_format_key_whatever_the_name(machine, tmp_path):
    el = ChainElementSet.zeros(machine).save(tmp_path / "elements")          # no suffix
    assert resolve_model(el).kind == "elements"
    (tmp_path / "m").write_text(json.dumps({"format": "volcomp-diagnosed-model/1", "elements": "elements"}))
    assert resolve_model(tmp_path / "m").kind == "diagnosed"
    (tmp_path / "d.txt").write_text(json.dumps({"schema": "volcomp.drift_model", "schema_version": 1}))
    assert resolve_model(tmp_path / "d.txt").kind == "drift"
    assert resolve_model("0" * 32).kind == "mlflow"
    (tmp_path / "x.json").write_text("x_mm,z_mm\n1,2\n")
    with pytest.raises(InputError, match=r"x\.json: not a model file"):
        resolve_model(tmp_path / "x.json")
    (tmp_path / "y.json").write_text('{"format": "volcomp-sweeps/1"}')
    with pytest.raises(InputError, match=r"key 'format': 'volcomp-sweeps/1'; not a model file"):
        resolve_model(tmp_path / "y.json")
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match="not a trained model folder"):
        resolve_model(tmp_path / "folder")
    # the companion: a .json suffix replaced, any other name kept whole (no two sets share one)
    assert covariance_path(tmp_path / "E.json").name == "E.cov.npz"
    assert covariance_path(tmp_path / "elements").name == "elements.cov.npz"
    assert covariance_path(tmp_path / "E.v2").name == "E.v2.cov.npz"


def test_a_model_of_another_kind_is_named_not_misread(machine, tmp_path, capsys):
    """`export --format drift` on an element set said "key 'schema': missing"; `predict` on a drift
    model would have tried it as an element set."""
    el = ChainElementSet.zeros(machine).save(tmp_path / "el")
    assert main(["export", str(el), "--format", "drift", "--out", str(tmp_path / "out")]) == 2
    line = _one_line(capsys)
    assert "an element set (volcomp-elements/1), but --format drift exports one of: drift model" in line
    assert "'schema'" not in line
    (tmp_path / "drift").write_text(json.dumps({"schema": "volcomp.drift_model", "schema_version": 1}))
    pts = _points(tmp_path, "p.csv", [10, 20], [5, 6], [0, 45])
    assert main(["predict", "--model", str(tmp_path / "drift"), str(pts), "--out", str(tmp_path / "o.csv")]) == 2
    line = _one_line(capsys)
    assert "a drift model (volcomp.drift_model)" in line and "drift-predict" in line


@pytest.mark.slow
def test_identify_out_without_suffix_then_diagnose_runs_the_closed_loop(machine, tmp_path, capsys):
    """The reproduction: `identify --out elements` then `diagnose --model elements` skipped the model
    update without a word (a suffix test) and reported other effects and figures than with
    `elements.json`. Both names must give the same closed loop, and say so."""
    sw = tmp_path / "sweeps.csv"
    assert main(["sweeps", "--seed", str(SEED), "--out", str(sw), "--noise-um", "0.5"]) == 0
    el = tmp_path / "elements"
    assert main(["identify", str(sw), "--out", str(el), "--bootstrap", "10"]) == 0
    assert (tmp_path / "elements.cov.npz").is_file()
    shutil.copyfile(el, tmp_path / "elements.json")           # same companion: elements.cov.npz
    checks = _checks(machine, tmp_path)
    capsys.readouterr()
    summaries = []
    for model, out in ((el, tmp_path / "d1"), (tmp_path / "elements.json", tmp_path / "d2")):
        assert main(["diagnose", str(checks), "--model", str(model), "--out", str(out)]) == 0
        err = capsys.readouterr().err
        assert f"element set (volcomp-elements/1): {model}" in err and "closed loop" in err
        s = json.loads((out / "diagnosis.json").read_text())
        assert s["update"] is True and s["model_source"]["kind"] == "elements"
        assert (out / "model.json").is_file()
        summaries.append(s)
    a, b = summaries
    assert a["held_out_rms_um"] == b["held_out_rms_um"] and a["effects"] == b["effects"]


@pytest.mark.slow
def test_diagnose_without_covariance_says_it_skips_the_update(machine, tmp_path, capsys):
    el = make_chain_truth(machine, SEED).elements.save(tmp_path / "truth")
    checks = _checks(machine, tmp_path)
    assert main(["diagnose", str(checks), "--model", str(el), "--out", str(tmp_path / "d")]) == 0
    err = capsys.readouterr().err
    assert "no model update (no covariance" in err and "truth.cov.npz" in err
    s = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert s["update"] is False and s["model_source"]["path"] == str(el)


def test_tool_paths_are_told_csv_or_gcode_by_content(machine, tmp_path, capsys):
    el = ChainElementSet.zeros(machine).save(tmp_path / "zero.json")
    csv_nc = tmp_path / "in" / "axes.nc"                       # a CSV named like G-code
    csv_nc.parent.mkdir()
    csv_nc.write_text("x_mm,z_mm,a_deg,feed\n10,5,0,100\n20,6,45,100\n")
    gcode_csv = tmp_path / "in" / "prog.csv"                   # G-code named like a CSV
    gcode_csv.write_text("G21 G90\nG1 X10 Z5 A0 F100\nG1 X20 Z6 A45\nM30\n")
    assert main(["compensate", "--work-offsets", "machine",
                 str(csv_nc), str(gcode_csv), "--model", str(el), "--method", "exact",
                 "--out", str(tmp_path / "out")]) == 0
    s = json.loads((tmp_path / "out" / "compensate_summary.json").read_text())
    assert [f["format"] for f in s["files"]] == ["csv-axes", "gcode"]
    assert s["model_source"]["kind"] == "elements" and s["units"] == "check"
    assert (tmp_path / "out" / "axes.nc").read_text().splitlines()[-3] == "x_mm,z_mm,a_deg,feed"


# -- point 2: one unit check ---------------------------------------------------------------------------
def test_check_temperatures_in_fahrenheit_are_refused(machine, tmp_path, capsys):
    """°F (68 °F at 20 °C) passed the old −40…80 °C range; diagnose then found thermal effects."""
    el = ChainElementSet.zeros(machine).save(tmp_path / "zero.json")
    checks = _checks(machine, tmp_path, "f.csv", temp_c=lambda t: t * 1.8 + 32)
    assert main(["diagnose", str(checks), "--model", str(el), "--out", str(tmp_path / "d")]) == 2
    line = _one_line(capsys)
    assert re.search(r"f\.csv: row \d+, column 'temp_c': units do not fit: .*°F\? \(6\d\.\d+ °F = 2\d\.\d °C\)", line)
    assert not (tmp_path / "d").exists()
    k = _checks(machine, tmp_path, "k.csv", temp_c=lambda t: t + 273.15)
    assert main(["diagnose", str(k), "--model", str(el), "--out", str(tmp_path / "d")]) == 2
    assert "kelvin?" in _one_line(capsys)


def test_compensate_temp_c_option_in_fahrenheit_is_refused(machine, tmp_path, capsys):
    el = ChainElementSet.zeros(machine).save(tmp_path / "updated_elements.json")
    model = tmp_path / "model"  # a diagnosed model, no suffix, with a thermal term
    model.write_text(json.dumps({"format": "volcomp-diagnosed-model/1", "elements": el.name, "needs": ["temp_c"],
                                 "terms": [{"kind": "thermal", "axis": "x_mm", "element": "dx_x",
                                            "coefficients": [0.01], "needs": ["temp_c"],
                                            "reference": {"ref_temp_c": 20.0, "ref_time_s": 0.0}}]}))
    src = tmp_path / "p.nc"
    src.write_text("G21 G90\nG1 X10 Z5 A0 F100\nG1 X20 Z6 A45\nM30\n")
    assert main(["compensate", "--work-offsets", "machine",
                 str(src), "--model", str(model), "--method", "exact", "--temp-c", "68",
                 "--out", str(tmp_path / "o")]) == 2
    assert "--temp-c: units do not fit: 68 °C" in _one_line(capsys)


@pytest.mark.parametrize("case", ["metres", "radians"])
def test_predict_points_in_metres_or_radians_are_refused(machine, tmp_path, capsys, case):
    rng = np.random.default_rng(0)
    x, z, a = rng.uniform(0, 200, 20), rng.uniform(0, 60, 20), rng.uniform(0, 360, 20)
    pts = _points(tmp_path, "p.csv", x / 1000, z / 1000, a) if case == "metres" else \
        _points(tmp_path, "p.csv", x, z, np.radians(a))
    el = ChainElementSet.zeros(machine).save(tmp_path / "zero.json")
    out = tmp_path / "pred.csv"
    assert main(["predict", "--model", str(el), str(pts), "--out", str(out)]) == 2
    line = _one_line(capsys)
    col = "x_mm" if case == "metres" else "a_deg"
    assert re.search(rf"p\.csv: row \d+, column '{col}': units do not fit: .*{case} rather than", line)
    assert "(if not, --units as-written)" in line and not out.exists()
    assert main(["predict", "--model", str(el), str(pts), "--out", str(out), "--units", "as-written"]) == 0
    assert read_table(out).meta()["units"] == "as-written"


@pytest.mark.parametrize("case", ["axes-metres", "axes-radians", "targets-metres", "temp-fahrenheit"])
def test_tool_path_csv_unit_mistakes_are_refused(machine, tmp_path, capsys, case):
    from errormap.chain_kernel import forward
    a = np.linspace(0, 350, 30)
    axes = np.stack([np.linspace(50, 150, 30), np.linspace(10, 50, 30), a], axis=1)
    if case == "axes-metres":
        path = _points(tmp_path, "p.csv", axes[:, 0] / 1000, axes[:, 1] / 1000, a)
    elif case == "axes-radians":
        path = _points(tmp_path, "p.csv", axes[:, 0], axes[:, 1], np.radians(a))
    elif case == "targets-metres":
        t = forward(machine, axes[:3] * [1, 1, 0] + [0, 0, 10]) / 1000
        path = write_csv(tmp_path / "p.csv", {"px_mm": t[:, 0], "py_mm": t[:, 1], "pz_mm": t[:, 2]})
    else:
        path = write_csv(tmp_path / "p.csv", {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": a,
                                               "temp_c": np.full(30, 68.0)})
    el = ChainElementSet.zeros(machine).save(tmp_path / "zero.json")
    assert main(["compensate", "--work-offsets", "machine",
                 str(path), "--model", str(el), "--method", "exact", "--out", str(tmp_path / "o")]) == 2
    line = _one_line(capsys)
    col, why = {"axes-metres": ("x_mm", "metres"), "axes-radians": ("a_deg", "radians"),
                "targets-metres": ("p[xyz]_mm", "metres"), "temp-fahrenheit": ("temp_c", "°F")}[case]
    assert re.search(rf"p\.csv: row \d+, column '{col}': units do not fit: .*{why}", line), line
    assert not (tmp_path / "o").exists()


def test_a_path_in_mm_near_zero_passes_with_units_as_written(machine, tmp_path, capsys):
    """The override exists for a real path the plausibility test would take for metres; it is recorded."""
    path = _points(tmp_path, "p.csv", [0.05, 0.1, 0.15], [0.02, 0.03, 0.04], [0, 1, 2])
    el = ChainElementSet.zeros(machine).save(tmp_path / "zero.json")
    base = ["compensate", "--work-offsets", "machine",
            str(path), "--model", str(el), "--method", "exact", "--max-segment-mm", "none"]
    assert main(base + ["--out", str(tmp_path / "o1")]) == 2
    assert "metres rather than mm" in _one_line(capsys)
    assert main(base + ["--out", str(tmp_path / "o2"), "--units", "as-written"]) == 0
    assert json.loads((tmp_path / "o2" / "compensate_summary.json").read_text())["units"] == "as-written"


# -- point 8: messages that misled -------------------------------------------------------------------------
def test_sweeps_in_metres_name_the_unit_not_coinciding_targets(machine, tmp_path, capsys):
    cols = simulated_sweeps(make_chain_truth(machine, SEED), noise_um=0.0, seed=0)
    for k in ("x_mm", "y_mm", "z_mm"):
        cols[k] = np.asarray(cols[k]) / 1000
    sw = write_sweeps(tmp_path / "sw_m.csv", cols)
    assert main(["identify", str(sw), "--out", str(tmp_path / "e.json")]) == 2
    line = _one_line(capsys)
    assert "sw_m.csv: axis X, columns 'x_mm', 'y_mm', 'z_mm': units do not fit" in line
    assert "looks like metres (multiply by 1000" in line and "coincide" not in line


def test_sweep_axis_typo_is_quoted_as_written(machine, tmp_path, capsys):
    cols = simulated_sweeps(make_chain_truth(machine, SEED), noise_um=0.0, seed=0)
    cols["axis"] = np.where(np.asarray(cols["axis"]) == "Z", "Y", np.asarray(cols["axis"]))
    sw = write_sweeps(tmp_path / "sw.csv", cols)
    assert main(["identify", str(sw), "--out", str(tmp_path / "e.json")]) == 2
    line = _one_line(capsys)
    assert "column 'axis': expected one of ['X', 'Z', 'A'] (the axes of " in line and line.endswith("got 'Y'")
    assert "np.str_" not in line


@pytest.mark.parametrize("text,expect", [
    ("x_mm;z_mm;a_deg\n10,5;20,25;30\n", "row 1: cells separated by semicolons (['x_mm', 'z_mm', 'a_deg']) with "
                                         "decimal commas: a spreadsheet export"),
    ("x_mm\tz_mm\ta_deg\n10\t20\t30\n", "row 1: cells separated by tabs (['x_mm', 'z_mm', 'a_deg']): a spreadsheet"),
    ("x_mm,z_mm,a_deg\n10,5,20,25,30\n", "row 2: expected 3 cells (columns ['x_mm', 'z_mm', 'a_deg']), got 5; "
                                         "decimal commas?"),
])
def test_spreadsheet_csv_is_named(machine, tmp_path, capsys, text, expect):
    p = tmp_path / "excel.csv"
    p.write_text(text)
    el = ChainElementSet.zeros(machine).save(tmp_path / "zero.json")
    assert main(["predict", "--model", str(el), str(p), "--out", str(tmp_path / "o.csv")]) == 2
    line = _one_line(capsys)
    assert "excel.csv: row" in line and expect in line and "expected 1 cells" not in line


def test_identify_truth_overlay_is_in_the_identified_gauge(machine):
    """`identify --truth` drew the truth in its own frame (curves tens of μrad off the identified ones);
    the overlay must be the truth in the identified gauge, and the old one measurably was not."""
    from errormap.sweeps import sweeps_from_columns
    from errormap.identification import ChainIdentification
    from compensation.app.workflows.measurement import truth_in_gauge
    truth = make_chain_truth(machine, SEED).elements
    sweeps = sweeps_from_columns(simulated_sweeps(make_chain_truth(machine, SEED), noise_um=0.0, seed=3), "<sweeps>")
    # the interpolating identification (--raw): on noise-free sweeps it is the truth in its gauge exactly
    ident = ChainIdentification(noise_um=0.5, gauge="station-mean").fit(sweeps, machine).elements_
    pts = np.zeros((300, 3))
    pts[:, 0], pts[:, 1], pts[:, 2] = np.linspace(0, 200, 300), np.linspace(0, 60, 300), np.linspace(0, 360, 300)
    overlay = truth_in_gauge(machine, truth, "station-mean", ident.stations)
    assert np.abs(overlay.values(pts) - ident.values(pts)).max() < GAUGE_TOL
    assert np.abs(truth.values(pts) - ident.values(pts)).max() > GAUGE_SHIFT_MIN


def test_demo_help_states_the_ga_budget_the_demo_uses(capsys):
    from compensation.app.workflows.demo import DEMO_GA_BUDGET_S, DemoSettings
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    m = re.search(r"--ga-budget-s GA_BUDGET_S time budget .*?\(default ([\d.]+) s\)", text)
    default = {f.name: f.default for f in dataclasses.fields(DemoSettings)}["ga_budget_s"]
    assert m and float(m.group(1)) == DEMO_GA_BUDGET_S == default


def _schema_csv_blocks():
    """The plain fenced blocks (no language) of docs/reference/file-formats.md whose first non-comment line is a
    header of at least three comma-separated names."""
    blocks, cur, lang = [], None, None
    for line in (ROOT / "docs" / "reference" / "file-formats.md").read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            if cur is None:
                cur, lang = [], line[3:].strip()
            else:
                if not lang:
                    blocks.append("\n".join(cur) + "\n")
                cur = None
        elif cur is not None:
            cur.append(line)
    header = lambda b: next((ln for ln in b.splitlines() if ln and not ln.startswith("#")), "")  # noqa: E731
    return [b for b in blocks if re.fullmatch(r"\w+(,\w+){2,}", header(b))]


def test_every_csv_example_in_the_schemas_parses(machine, tmp_path, capsys):
    """Each CSV example reads as a table of numbers (the axis names of sweeps aside); each tool-path
    example compensates (exit 0) — the target example used to be refused by the stroke guard."""
    blocks = _schema_csv_blocks()
    assert len(blocks) >= 8
    el = ChainElementSet.zeros(machine).save(tmp_path / "zero.json")
    paths = 0
    for i, b in enumerate(blocks):
        p = tmp_path / f"ex{i}.csv"
        p.write_text(b, encoding="utf-8")
        t = read_table(p)
        assert len(t) >= 1
        for name in t.names:
            if name not in ("axis",):
                t.float(name)
        if {"x_mm", "z_mm", "a_deg"} <= set(t.names) and "dx_um" not in t.names or "px_mm" in t.names:
            if "temp_c" in t.names:
                continue  # the conditions example: only for a diagnosed model (tests/test_closed_loop.py)
            paths += 1
            assert main(["compensate", "--work-offsets", "machine", str(p), "--model", str(el), "--method", "exact",
                         "--out", str(tmp_path / f"out{i}")]) == 0, capsys.readouterr().err
    assert paths == 2


def test_pkm_calibration_file_is_known_by_its_format_key(tmp_path):
    from compensation.model_file import read_model
    from errormap.pkm.calibration_file import CALIBRATION_FORMAT
    m = load_machine(ROOT / "errormap" / "machines" / "hexapod.toml")
    im = {"base_joints_mm": m.base_joints_mm.tolist(), "platform_joints_mm": (m.platform_joints_mm * 1.001).tolist(),
          "leg_offset_mm": np.asarray(m.leg_offset_mm).tolist(), "leg_scale": np.asarray(m.leg_scale).tolist()}
    cal = tmp_path / "cal"                                             # no suffix
    cal.write_text(json.dumps({"format": CALIBRATION_FORMAT, "kind": m.kind, "identified_machine": im}))
    got = read_model(cal, m, family="parallel").calibration
    assert np.array_equal(got.platform_joints_mm, m.platform_joints_mm * 1.001)
    el = ChainElementSet.zeros(load_machine()).save(tmp_path / "calibration.json")  # the right name, the wrong content
    with pytest.raises(InputError, match=r"calibration.json: key 'family': a model of a machine tool, not of a "
                                         r"parallel machine"):
        read_model(el, m, family="parallel")


def test_a_stale_covariance_companion_is_refused(machine, tmp_path):
    """The companion is found by name; that an older grinder file (θ layout) belongs to the element set is
    checked by content."""
    from errormap.chain_covariance import read_chain_covariance
    from errormap.diagnosis.chain_effects import full_parameters
    from errormap.identification import parameter_vector
    el = make_chain_truth(machine, SEED).elements
    slots, stations = full_parameters(el)
    np.savez(tmp_path / "E.cov.npz", theta=parameter_vector(el, slots, stations), cov=np.eye(len(slots)),
             layout_element=np.array(slots), layout_station=stations)
    el.save(tmp_path / "E.json")
    read_chain_covariance(covariance_path(tmp_path / "E.json"),
                          ChainElementSet.load(tmp_path / "E.json", machine))
    other = el.copy()
    other.constants["s_xz"] += 1.0
    other.save(tmp_path / "E.json")                      # re-identified, the old companion left beside it
    with pytest.raises(InputError, match=r"E\.cov\.npz: not the covariance of this element set: .* at s_xz"):
        read_chain_covariance(covariance_path(tmp_path / "E.json"),
                              ChainElementSet.load(tmp_path / "E.json", machine))


def test_export_diagnosis_is_known_by_its_format_key(tmp_path):
    from compensation.export import CHECKS_DIAGNOSIS_FORMAT, backlash_from_diagnosis
    good = tmp_path / "diag"
    good.write_text(json.dumps({"format": CHECKS_DIAGNOSIS_FORMAT, "effects": [
        {"kind": "reversal", "axis": "z", "element": "dz_z", "parameters": {"backlash_um": {"value": 1.5}}}]}))
    assert backlash_from_diagnosis(good) == ({"z": 1.5}, [])
    bad = tmp_path / "diagnosis.json"
    bad.write_text(json.dumps({"format": "volcomp-elements/1", "effects": []}))
    with pytest.raises(InputError, match=r"key 'format': 'volcomp-elements/1'; expected 'volcomp-checks-diagnosis/1'"):
        backlash_from_diagnosis(bad)
