"""The commands that read a user file and tests/test_fuzz_inputs.py / test_fuzz_commands.py do not reach, fuzzed
through ``main`` the same way: ``train`` (feature points), ``export`` (an element set), ``report --path`` (a tool
path), ``calibrate`` and ``predict`` on a serial arm (poses, a joint program), ``compensate`` on a targets CSV and
with a ``--work-offsets`` table, ``diagnose --drift`` (a thermal log) and ``benchmark --machine`` (a machine file).
Each example draws one hostile input (test_fuzz_inputs.hostile_bytes: a cell mangled, bytes inserted, UTF-16,
CR-only endings, NUL bytes, a foreign CSV, an empty file, the file cut short) and, where the command has them,
one of its bounded options in or out of range.
Outcomes: exit 0 whose output is checked against the library computed on the same input (a mismatch is counted
"silent wrong" and fails), or exit 2 with ONE line naming the input or the option (``diagnose --drift`` and
``calibrate``: also exit 1 with a written failed verdict); a traceback or any other status fails. Counts go to
test_fuzz_inputs.TALLY (``VOLCOMP_FUZZ_TALLY=FILE`` writes them; ``VOLCOMP_FUZZ_EXAMPLES=N`` runs N per test)."""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from compensation.app.cli import main
from errormap.io import read_table
from errormap.machine import builtin_machine_path, load_machine
from test_fuzz_commands import fuzz
from test_fuzz_inputs import (TALLY, TOL_LANDING_MM, TOL_PREDICT_ABS_UM, TOL_PREDICT_REL, _check_output, _head,
                              _tally_outcome, hostile_bytes, mangled_toml, report_tally, run_main)
from compensation.calibration_models import calibration_section

TOL_TRAIN_RMS_REL = 1e-5
"""train's metrics.json RMS against the written network re-evaluated on the same rows: the network runs in float64
and the metric is computed from the same predictions, so only the summation order differs (~1e-12 relative); the
model files round-trip the weights exactly. 1e-5 relative is far below a different row set (one row of 60 moves the
RMS by percents)."""
TOL_ARM_MM = 1e-6
"""predict on an arm writes 10 significant digits of values up to ~1000 mm: 1e-7 mm of rounding; 1e-6 mm is far
below any real mismatch (a wrong joint read moves the point by mm)."""


def _quiet(argv):
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main(argv)


@pytest.fixture(scope="module", autouse=True)
def tally():
    yield TALLY
    report_tally()


@pytest.fixture(scope="module")
def grinder(tmp_path_factory):
    """A simulated grinder (seed 3): its truth element set and feature points (the first 60 rows)."""
    d = tmp_path_factory.mktemp("fuzzfile")
    assert _quiet(["simulate", "--seed", "3", "--checks", "30", "--out", str(d / "sim")]) == 0
    return d


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    """A simulated UR5 session (seed 5): its poses, and a calibration on the first 60 (no learned stage, 2 folds)."""
    d = tmp_path_factory.mktemp("fuzzarm")
    assert _quiet(["simulate", "--machine", "ur5", "--seed", "5", "--out", str(d / "sim")]) == 0
    (d / "p60.csv").write_text(_head(d / "sim" / "poses.csv", 60))
    assert _quiet(["calibrate", str(d / "p60.csv"), "--machine", "ur5", "--no-learned", "--folds", "2",
                   "--out", str(d / "cal")]) in (0, 1)
    return d


# -- train --------------------------------------------------------------------------------------------------------
@pytest.mark.slow   # one short LM fit (3 iterations) with its MLflow record and plots per example: about 30 CPU s
@fuzz(2)           # each under load (the record dominates), so two examples
@given(data=st.data())
def test_fuzz_train_featurepoints(grinder, data, tmp_path_factory):
    """train on hostile feature points: exit 0 writes a network whose RMS on the rows the library reads from the
    same file is the one metrics.json records (so it was fitted on exactly those rows), or one line naming the file."""
    from compensation.model_file import read_model
    from errormap.featurepoints import FeaturePoints
    from training.trainers import fit_metrics
    store = tmp_path_factory.getbasetemp() / "mlflow.db"
    raw = data.draw(hostile_bytes(_head(grinder / "sim" / "featurepoints.csv", 60), table=True))
    with tempfile.TemporaryDirectory() as d:
        p, out = Path(d) / "fp.csv", Path(d) / "t"
        p.write_bytes(raw)
        (Path(d) / "truth_elements.json").write_bytes((grinder / "sim" / "truth_elements.json").read_bytes())
        argv = ["train", str(p), "--out", str(out), "--max-iter", "3", "--no-select", "--seed", "1",
                "--tracking-uri", f"sqlite:///{store}"]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p)]):
            fp = FeaturePoints.load(p)
            field = read_model(str(out / "model"), load_machine(None)).field
            want = fit_metrics("train", field.predict(fp.axes), fp.errors_um)["train_rms_um"]
            got = json.loads((out / "metrics.json").read_text())["train_rms_um"]
            _check_output("train", np.isclose(got, want, rtol=TOL_TRAIN_RMS_REL, atol=0), (argv, got, want))


# -- export -------------------------------------------------------------------------------------------------------
@pytest.mark.slow   # an export re-simulates the controller on the flute and 2,000 volume points: about 5 CPU s each
@fuzz(4)
@given(data=st.data(), tol=st.sampled_from(["1", "5", "0", "-1", "nan", "1e9"]))
def test_fuzz_export_element_set(grinder, data, tol):
    """export --format iso-tables on a hostile element set and tolerance: exit 0 writes the tables the library builds
    from the element set read from the same file (same rows), names that file's sha256 and met the tolerance; or
    one line naming the file or --tolerance-um."""
    from compensation.export.iso_tables import iso_tables_from_model, read_iso_tables
    from errormap.chain_elements import ChainElementSet
    machine = load_machine(None)
    raw = data.draw(hostile_bytes((grinder / "sim" / "truth_elements.json").read_text(), table=True))
    with tempfile.TemporaryDirectory() as d:
        src, out = Path(d) / "E.json", Path(d) / "x"
        src.write_bytes(raw)
        argv = ["export", str(src), "--format", "iso-tables", "--tolerance-um", tol, "--out", str(out)]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(src), "--tolerance-um"]):
            doc = json.loads((out / "export.json").read_text())
            want = iso_tables_from_model(ChainElementSet.load(src, machine), machine, doc["sizing"]["rows_per_axis"])
            got = read_iso_tables(out, machine)
            same = all(np.allclose(got.values[k], want.values[k], rtol=TOL_PREDICT_REL, atol=TOL_PREDICT_ABS_UM)
                       for k in want.values) and set(got.values) == set(want.values)
            _check_output("export", same and doc["tolerance_met"] and hashlib.sha256(raw).hexdigest() in doc["model"],
                          argv)


# -- report --path ------------------------------------------------------------------------------------------------
AXES_10 = np.array([[10.0 + 5 * i, 5.0 + i, 15.0 * i] for i in range(10)])
"""Ten grinder axis points (x_mm, z_mm, a_deg) inside the strokes."""
AXES_PATH = "x_mm,z_mm,a_deg,feed\n" + "\n".join(f"{x:g},{z:g},{a:g},100" for x, z, a in AXES_10) + "\n"


def _targets_csv() -> str:
    """The tool points the nominal grinder reaches at AXES_10, as a targets CSV."""
    from errormap.chain_kernel import forward
    p = forward(load_machine(None), AXES_10)
    return "px_mm,py_mm,pz_mm\n" + "\n".join(",".join(f"{v:.6f}" for v in row) for row in p) + "\n"


TARGETS = _targets_csv()


@pytest.mark.slow   # a comparison with its page (figures) per example: about 2.5 CPU s each
@fuzz(6)
@given(data=st.data(), text=st.sampled_from([TARGETS, AXES_PATH]),
       methods=st.sampled_from(["traditional", "exact", "traditional,exact", "bogus", ""]))
def test_fuzz_report_path(grinder, data, text, methods):
    """report --path on a hostile tool-path CSV: exit 0 compares the methods on exactly the points the library reads
    from the same file (metrics.json's count, the exact method's model residual under its solver's tolerance), or
    one line naming the file or --methods."""
    from path_files import read_as_compensate
    machine = load_machine(None)
    raw = data.draw(hostile_bytes(text, table=True))
    with tempfile.TemporaryDirectory() as d:
        p, out = Path(d) / "path.csv", Path(d) / "r"
        p.write_bytes(raw)
        argv = ["report", "--path", str(p), "--model", str(grinder / "sim" / "truth_elements.json"),
                "--methods", methods, "--out", str(out)]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p), "--methods"]):
            doc = json.loads((out / "metrics.json").read_text())
            n = len(read_as_compensate(p, machine))
            ok = doc["points"] == n and all(m["points"] == n for m in doc["methods"].values())
            if "exact" in doc["methods"]:   # the exact solve lands on every target under the model
                ok = ok and doc["methods"]["exact"]["model_max_um"] < 1e3 * TOL_LANDING_MM
            _check_output("report", ok, (argv, doc["points"], n))


# -- serial arm: calibrate and predict ----------------------------------------------------------------------------
@pytest.mark.slow   # a plain + geometric calibration per example (60 poses, 2 folds): about 8 CPU s each
@fuzz(4)
@given(data=st.data(), holdout=st.sampled_from(["0.2", "0.5", "0", "1", "nan"]))
def test_fuzz_calibrate_arm_poses(arm, data, holdout):
    """calibrate --machine ur5 on hostile poses: exit 0 (or 1 with a written failed verdict) fits on the poses the
    library reads from the same file (fit + held-out count), or one line naming the file or --holdout."""
    from errormap.arm_poses import read_arm_poses
    ur5 = load_machine("ur5")
    raw = data.draw(hostile_bytes((arm / "p60.csv").read_text(), table=True))
    with tempfile.TemporaryDirectory() as d:
        p, out = Path(d) / "poses.csv", Path(d) / "c"
        p.write_bytes(raw)
        argv = ["calibrate", str(p), "--machine", "ur5", "--no-learned", "--folds", "2", "--holdout", holdout,
                "--out", str(out)]
        rc, err = run_main(argv)
        if rc == 1 and "Traceback" not in err and (out / "model.json").is_file():
            rc = 0   # a failed verdict, written: its counts are checked like an exit 0's
        if _tally_outcome(argv, rc, err, [str(p), "--holdout"]):
            doc = calibration_section(out / "model.json", "arm")[0]
            n = len(read_arm_poses(p, ur5).q)
            _check_output("calibrate", doc["n_fit_poses"] + doc["n_check_poses"] == n, (argv, n))


@pytest.mark.slow   # the calibration once (fixture), then a prediction per example: about 2 CPU s each
@fuzz(6)
@given(data=st.data())
def test_fuzz_predict_arm_program(arm, data):
    """predict --machine ur5 on a hostile joint program: exit 0 writes the calibrated tool point of every joint row the
    library reads from the same file, or one line naming the file."""
    from compensation.model_file import read_model
    from compensation.app.workflows.arm_predict import read_points
    from compensation.arm_compensation import model_point
    from errormap.arm_frames import to_base_frame
    ur5 = load_machine("ur5")
    cal = arm / "cal" / "model.json"
    cols = ur5.joint_columns
    rows = [",".join(f"{(-1) ** j * (5 + 3 * i + 7 * j)}" for j in range(len(cols))) for i in range(8)]
    raw = data.draw(hostile_bytes(",".join(cols) + "\n" + "\n".join(rows) + "\n", table=True))
    with tempfile.TemporaryDirectory() as d:
        p, o = Path(d) / "q.csv", Path(d) / "o.csv"
        p.write_bytes(raw)
        argv = ["predict", str(p), "--machine", "ur5", "--model", str(cal), "--allow", "failed-verdict",
                "--out", str(o)]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p)]):
            geo, learner = read_model(str(cal), ur5, family="arm").calibration.require_base_frame(cal).stages
            q = read_points(p, ur5)[0]
            want = to_base_frame(ur5, geo.params, model_point(geo.chain, geo.params, learner, q))
            t = read_table(o)
            got = np.stack([t.float(c) for c in ("x_mm", "y_mm", "z_mm")], axis=1)
            _check_output("predict", got.shape == want.shape and np.allclose(got, want, rtol=0, atol=TOL_ARM_MM), argv)


# -- compensate: a targets CSV, a work-offset table -----------------------------------------------------------------
@fuzz(12)
@given(data=st.data(), seg=st.sampled_from(["none", "auto", "0.5", "1e-6", "-1"]))
def test_fuzz_compensate_targets_csv(grinder, data, seg):
    """compensate --method exact on a hostile targets CSV: exit 0 writes axes that land on every target the library
    reads from the same file under the model, or one line naming the file or --max-segment-mm."""
    from path_files import read_as_compensate
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.chain_kernel import forward
    machine = load_machine(None)
    el = grinder / "sim" / "truth_elements.json"
    raw = data.draw(hostile_bytes(TARGETS, table=True))
    with tempfile.TemporaryDirectory() as d:
        p, out = Path(d) / "t.csv", Path(d) / "c"
        p.write_bytes(raw)
        argv = ["compensate", str(p), "--model", str(el), "--method", "exact", "--max-segment-mm", seg,
                "--out", str(out)]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p), "--max-segment-mm"]):
            field = ChainField(machine, ChainElementSet.load(el, machine))
            src = read_as_compensate(p, machine)
            res = read_as_compensate(out / p.name, machine)
            lands = forward(machine, res.axes) + 1e-3 * field.predict(res.axes)
            miss = np.linalg.norm(src.targets_mm[:, None, :] - lands[None], axis=2).min(axis=1)
            _check_output("compensate", len(res) >= len(src) and miss.max() < TOL_LANDING_MM, (argv, miss.max()))


OFFSETS = "system,x_mm,y_mm,z_mm,a_deg\nG54,100,0,0.3,0\nG55,10,0,1,0\n"
PROGRAM_G54 = "%\nG21 G90 G18\nG54\nG0 X0 Z0 A0\nG1 X5. Z1. A10. F100\nG1 X12.5 Z7.7 A20.\nM30\n%\n"


@fuzz(12)
@given(data=st.data())
def test_fuzz_compensate_work_offsets(grinder, data):
    """compensate a G54 program with a hostile --work-offsets table: exit 0 writes a program that lands on every
    programmed block end the library reads with that table, or one line naming the table (or the program)."""
    import dataclasses
    from compensation.app.cli import build_parser
    from compensation.app.commands.compensate import settings_of
    from compensation.app.workflows.compensate_paths import read_tool_path
    from compensation.solvers.chain_exact import nominal_and_jacobian
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.chain_kernel import forward
    machine = load_machine(None)
    el = grinder / "sim" / "truth_elements.json"
    raw = data.draw(hostile_bytes(OFFSETS, table=True))
    with tempfile.TemporaryDirectory() as d:
        prog, wo, out = Path(d) / "part.nc", Path(d) / "wo.csv", Path(d) / "c"
        prog.write_text(PROGRAM_G54)
        wo.write_bytes(raw)
        argv = ["compensate", str(prog), "--model", str(el), "--method", "exact", "--work-offsets", str(wo),
                "--out", str(out)]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(wo), str(prog)]):
            field = ChainField(machine, ChainElementSet.load(el, machine))
            s = settings_of(build_parser(["compensate"]).parse_args(argv))   # the table read as the command reads it
            mt = machine   # the command reads every machine tool's program by its chain
            src = read_tool_path(prog, mt, s, field)   # nominal machine axes, the table's offsets applied
            res = read_tool_path(out / prog.name, mt, dataclasses.replace(s, max_segment_mm=None))
            src.targets_mm = nominal_and_jacobian(mt, src.axes)[0]
            lands = nominal_and_jacobian(mt, res.axes)[0] + 1e-3 * field.predict(res.axes)
            last = np.r_[src.lines[1:] != src.lines[:-1], True]
            ends = np.linalg.norm(src.targets_mm[last][:, None, :] - lands[None], axis=2).min(axis=1)
            _check_output("compensate", ends.max() < TOL_LANDING_MM, (argv, ends.max()))


# -- diagnose --drift, benchmark --machine ----------------------------------------------------------------------------
@pytest.mark.slow   # a drift identification per example on a 2-hour log: about 7 CPU s each (a refusal: < 1 s)
@fuzz(5)
@given(data=st.data())
def test_fuzz_diagnose_drift_log(data, tmp_path_factory):
    """diagnose --drift on a hostile log (a simulated 2-hour one mangled): exit 0 (or 1 with a written failed verdict)
    fits on that file's samples (drift_model.json names it, fits on part of the rows the library reads from it) and
    writes the compensation of every one of them; or one line naming the file."""
    from errormap.diagnosis.drift import load_drift_log
    from errormap.diagnosis.drift_sim import simulate_lumped_log
    from errormap.io import write_csv
    base = tmp_path_factory.getbasetemp() / "drift_log.csv"
    if not base.is_file():
        cols = simulate_lumped_log(seed=0, hours=2.0)
        n = len(cols["time_s"])
        write_csv(base, {k: v for k, v in cols.items() if np.ndim(v) == 1 and len(v) == n})
    raw = data.draw(hostile_bytes(base.read_text(), table=True))
    with tempfile.TemporaryDirectory() as d:
        p, out = Path(d) / "log.csv", Path(d) / "dr"
        p.write_bytes(raw)
        argv = ["diagnose", "--drift", str(p), "--out", str(out)]
        rc, err = run_main(argv)
        if rc == 1 and "Traceback" not in err and (out / "drift_model.json").is_file():
            rc = 0
        if _tally_outcome(argv, rc, err, [str(p)]):
            n = len(load_drift_log(p).time_s)
            fitted = json.loads((out / "drift_model.json").read_text())["fitted_on"]
            comp = read_table(out / "drift_compensation.csv")
            _check_output("diagnose", fitted["log"] == str(p) and 0 < fitted["fit_rows"] <= n and len(comp) == n,
                          (argv, n, fitted["fit_rows"], len(comp)))


@fuzz(12)
@given(data=st.data(), kind=st.sampled_from(["grinder", "mill-xyz", "hexapod"]))
def test_fuzz_benchmark_machine_file(data, kind):
    """benchmark --machine on a hostile machine file the library refuses: exit 2 in one line naming the file, before
    any simulation (the accepted files run the benchmark itself: tests/test_benchmark.py)."""
    from errormap.machine import MachineFileError
    raw = data.draw(mangled_toml(builtin_machine_path(kind).read_text(encoding="utf-8")))
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "m.toml"
        src.write_bytes(raw)
        try:
            load_machine(src)
            return   # accepted: the benchmark's own tests run accepted machines (minutes each)
        except MachineFileError:
            pass
        argv = ["benchmark", "--machine", str(src), "--quick", "--no-track", "--out", str(Path(d) / "b")]
        rc, err = run_main(argv)
        assert rc == 2, (argv, rc, err)
        _tally_outcome(argv, rc, err, [str(src)])
        assert not (Path(d) / "b").exists()
