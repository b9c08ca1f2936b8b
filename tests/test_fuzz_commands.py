"""The commands tests/test_fuzz_inputs.py does not reach, fuzzed through ``main`` the same way: ``identify`` (a
grinder's and a chain's sweeps), ``simulate`` (a machine file), ``register`` (an arm's session poses),
``diagnose`` (a chain's checks) and ``drift-predict`` (a thermal log). Each example draws one hostile input
(tests/test_fuzz_inputs.hostile_bytes: a cell mangled, bytes inserted, UTF-16, CR-only endings, NUL bytes, a
foreign CSV, an empty file, the file cut short).
Outcomes: exit 0 whose output is checked against the library computed on the same input (a mismatch is counted
"silent wrong" and fails), or exit 2 with ONE line naming the input (``diagnose``: also exit 1 when the written
verdict failed); a traceback or any other status fails. The counts go to test_fuzz_inputs.TALLY (printed at the
end of the module; ``VOLCOMP_FUZZ_TALLY=FILE`` writes them as JSON). ``VOLCOMP_FUZZ_EXAMPLES=N`` runs N examples
per test instead of the CI's few (docs/decisions/020-benchmark-notebook.md "Fuzzing every command" is such a run)."""
from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compensation.app.cli import main
from errormap.io import read_table
from errormap.machine import builtin_machine_path, load_machine
from test_fuzz_inputs import (TALLY, TOL_PREDICT_ABS_UM, TOL_PREDICT_REL, _check_output, _head, _tally_outcome,
                              hostile_bytes, mangled_toml, report_tally, run_main)
from compensation.calibration_models import calibration_section

EXAMPLES = int(os.environ.get("VOLCOMP_FUZZ_EXAMPLES", "0")) or None


def fuzz(ci_examples: int):
    return settings(max_examples=EXAMPLES or ci_examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


TOL_CHECKS_UM = 1e-4
"""A noiseless check file against its truth's field: its axes are written to 9 significant digits (1e-6 mm at
200 mm), which moves an error of a few μm per 100 mm by ~1e-7 μm; 1.7e-6 μm was measured on the unmangled
grinder, so 1e-4 μm is far below any real mismatch (a mis-read machine file moves the errors by μm)."""
AXES_PROBE = np.array([[50.0, 20.0, 0.0], [150.0, 60.0, 90.0], [250.0, 100.0, 270.0]])
"""Grinder axes (x_mm, z_mm, a_deg) where two element sets are compared through their fields."""


@pytest.fixture(scope="module", autouse=True)
def tally():
    yield TALLY
    report_tally()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Valid inputs to mangle: a grinder's and a mill's sweeps (the first rows of each), a mill's element set and
    checks, a UR5 calibration and a session's poses."""
    from compensation.fields import ARM_FORMAT as MODEL_FORMAT
    from errormap.arm_calibration import fit_plain_lsq
    from errormap.arm_poses import write_arm_poses
    from errormap.arm_simulate import draw_truth, measure, random_joints
    d = tmp_path_factory.mktemp("fuzzcmd")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["sweeps", "--seed", "3", "--out", str(d / "g_sweeps.csv")]) == 0
        assert main(["sweeps", "--machine", "mill-xyz", "--seed", "3", "--out", str(d / "m_sweeps.csv")]) == 0
        assert main(["simulate", "--machine", "mill-xyz", "--seed", "3", "--checks", "60", "--noise-um", "1",
                     "--out", str(d / "m")]) == 0
    ur5 = load_machine("ur5")
    lo, hi = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0]), np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
    t = draw_truth(ur5, 7)
    geo = fit_plain_lsq(ur5, measure(ur5, t, random_joints(lo, hi, 40, [7, 0]), 0.02, [7, 1]))
    (d / "arm.json").write_text(json.dumps({"format": MODEL_FORMAT, "machine": {"name": ur5.name,
                                                                                "joints": ur5.joint_columns},
                                            "kept_stage": "plain geometric LSQ", "geometric": geo.to_dict(),
                                            "plain_geometric": geo.to_dict(),
                                            "learned": None}))
    write_arm_poses(d / "session.csv", ur5, measure(ur5, t, random_joints(lo, hi, 10, [7, 2]), 0.02, [7, 3]))
    return d


@pytest.mark.slow   # an identification per example (grinder, 2 bootstrap draws): about 0.5 CPU s each
@fuzz(8)
@given(data=st.data())
def test_fuzz_identify_grinder(files, data):
    """exit 0 writes the element set the library identifies from the same file (compared through the field)."""
    from compensation.app.workflows.identification import identify_chain_files
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.sweeps import read_sweeps
    machine = load_machine(None)
    raw = data.draw(hostile_bytes((files / "g_sweeps.csv").read_text(), table=True))
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "sw.csv"
        p.write_bytes(raw)
        argv = ["identify", str(p), "--bootstrap", "2", "--out", str(Path(d) / "E.json")]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p)]):
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                lib = identify_chain_files(machine, [str(p)], Path(d) / "L.json", n_boot=2, seed=0,
                                           sweeps=read_sweeps([str(p)], machine))[0]
            got = ChainField(machine, ChainElementSet.load(Path(d) / "E.json", machine)).predict(AXES_PROBE)
            want = ChainField(machine, lib.elements_).predict(AXES_PROBE)
            _check_output("identify", np.allclose(got, want, rtol=TOL_PREDICT_REL, atol=TOL_PREDICT_ABS_UM), argv)


@pytest.mark.slow   # a Gauss-Newton identification per example: about 0.5 CPU s each
@fuzz(8)
@given(data=st.data())
def test_fuzz_identify_chain(files, data):
    """identify --machine mill-xyz: exit 0 writes the element set the library identifies from the same file (the
    command's defaults: station-mean gauge, smoothed)."""
    from errormap.chain_elements import ChainElementSet
    from errormap.identification import ChainIdentification, smooth_chain
    from errormap.sweeps import read_sweeps
    mill = load_machine("mill-xyz")
    raw = data.draw(hostile_bytes((files / "m_sweeps.csv").read_text(), table=True))
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "sw.csv"
        p.write_bytes(raw)
        argv = ["identify", str(p), "--machine", "mill-xyz", "--out", str(Path(d) / "E.json")]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p)]):
            res = ChainIdentification(gauge="station-mean").fit(read_sweeps(p, mill), mill).result_
            want = smooth_chain(res, mill).elements_
            got = ChainElementSet.load(Path(d) / "E.json", mill)
            pairs = [(got.constants.get(k), v) for k, v in want.constants.items()] + [
                (got.functions.get(k), v) for k, v in want.functions.items()]
            same = all(g is not None and np.allclose(g, w, rtol=TOL_PREDICT_REL, atol=TOL_PREDICT_ABS_UM)
                       for g, w in pairs)
            _check_output("identify", same, argv)


@fuzz(10)
@given(data=st.data(), kind=st.sampled_from(["grinder", "mill-xyz"]))
def test_fuzz_simulate_machine_file(data, kind):
    """simulate --machine on a mangled machine file (no noise): exit 0 writes a truth whose field gives exactly the
    check errors written beside it (read back through the machine file as written), or one line naming the file."""
    raw = data.draw(mangled_toml(builtin_machine_path(kind).read_text(encoding="utf-8")))
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "m.toml"
        src.write_bytes(raw)
        argv = ["simulate", "--machine", str(src), "--seed", "1", "--checks", "12", "--noise-um", "0",
                "--out", str(Path(d) / "s")]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(src)]):
            from compensation.model_file import read_model
            from errormap.field import machine_axes
            machine = load_machine(src)
            t = read_table(Path(d) / "s" / "checks.csv")
            axes = np.stack([t.float(c) for c in machine_axes(machine)], axis=1)
            got = np.stack([t.float(c) for c in ("dx_um", "dy_um", "dz_um")], axis=1)
            want = read_model(str(Path(d) / "s" / "truth_elements.json"), machine).field.predict(axes)
            _check_output("simulate", np.allclose(got, want, rtol=TOL_PREDICT_REL, atol=TOL_CHECKS_UM), argv)


@fuzz(10)
@given(data=st.data())
def test_fuzz_register_poses(files, data):
    """register on a mangled session: exit 0 registers on every pose the library reads from the same file and
    writes the calibration's link parameters unchanged, or one line naming the file."""
    from errormap.arm_poses import read_arm_poses
    ur5 = load_machine("ur5")
    raw = data.draw(hostile_bytes((files / "session.csv").read_text(), table=True))
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.csv"
        p.write_bytes(raw)
        argv = ["register", str(p), "--machine", "ur5", "--model", str(files / "arm.json"), "--out", str(Path(d) / "r")]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p)]):
            doc = calibration_section(Path(d) / "r" / "model.json", "arm")[0]
            old = {q["name"]: q["value"] for q in json.loads((files / "arm.json").read_text())["geometric"]["parameters"]}
            new = {q["name"]: q["value"] for q in doc["geometric"]["parameters"]}
            links = [k for k in old if not k.startswith(("base.", "tool."))]
            _check_output("register", doc["registration"]["n_fit_poses"] == len(read_arm_poses(p, ur5)) and links
                          and all(new[k] == old[k] for k in links), argv)


@pytest.mark.slow   # a closed loop per example (no learned stage): about 1.5 CPU s each
@fuzz(6)
@given(data=st.data())
def test_fuzz_diagnose_chain_checks(files, data):
    """diagnose --machine mill-xyz on mangled checks: exit 0 with a passed verdict, exit 1 with a failed one
    (written in diagnosis.json), each with the check count the library reads from the same file; or one line."""
    from errormap.diagnosis.chain_loop import load_chain_checks
    mill = load_machine("mill-xyz")
    raw = data.draw(hostile_bytes(_head(files / "m" / "checks.csv", 60), table=True))
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "c.csv"
        p.write_bytes(raw)
        argv = ["diagnose", str(p), "--machine", "mill-xyz", "--model", str(files / "m" / "truth_elements.json"),
                "--no-learned", "--out", str(Path(d) / "o")]
        rc, err = run_main(argv)
        if rc == 1 and "Traceback" not in err and (Path(d) / "o" / "diagnosis.json").is_file():
            rc = 0      # a failed verdict, written: checked below like an exit 0
            failed = True
        else:
            failed = False
        if _tally_outcome(argv, rc, err, [str(p)]):
            doc = json.loads((Path(d) / "o" / "diagnosis.json").read_text())
            n = len(load_chain_checks(p, mill).axes)
            _check_output("diagnose", doc["verdict"]["status"] == ("failed" if failed else "passed")
                          and doc["n_fit"] + doc["n_held_out"] == n, argv)


@pytest.fixture(scope="module")
def drift_model(tmp_path_factory):
    """A drift model (diagnose --drift on a simulated 2-hour lumped log, seed 0) and that log."""
    from errormap.diagnosis.drift_sim import simulate_lumped_log
    from errormap.io import write_csv
    d = tmp_path_factory.mktemp("drift")
    cols = simulate_lumped_log(seed=0, hours=2.0)
    n = len(cols["time_s"])
    log = write_csv(d / "log.csv", {k: v for k, v in cols.items() if np.ndim(v) == 1 and len(v) == n})
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["diagnose", "--drift", str(log), "--out", str(d / "dr")]) in (0, 1)
    return d / "dr" / "drift_model.json", log


@pytest.mark.slow   # the drift model's fit: about 7 CPU s once
@fuzz(10)
@given(data=st.data())
def test_fuzz_drift_predict_log(drift_model, data):
    """drift-predict on a mangled log: exit 0 writes the model's compensation columns the library computes from the
    same file (read as the command reads it), or one line naming the file."""
    from compensation.app.workflows.drift import compensation_columns
    from errormap.diagnosis.drift import load_drift_log
    from errormap.diagnosis.drift_models import DriftModel
    model_path, log = drift_model
    raw = data.draw(hostile_bytes(log.read_text(), table=True))
    with tempfile.TemporaryDirectory() as d:
        p, o = Path(d) / "log.csv", Path(d) / "o.csv"
        p.write_bytes(raw)
        argv = ["drift-predict", str(model_path), str(p), "--allow", "failed-verdict", "--out", str(o)]
        rc, err = run_main(argv)
        if _tally_outcome(argv, rc, err, [str(p)]):
            want = compensation_columns(load_drift_log(p, causal=True, require_displacement=False),
                                        DriftModel.load(model_path))
            t = read_table(o)
            _check_output("drift-predict", all(np.allclose(t.float(k, allow_nan=True), v, rtol=TOL_PREDICT_REL,
                                                           atol=TOL_PREDICT_ABS_UM, equal_nan=True)
                                               for k, v in want.items() if k in t)
                          and any(k in t for k in want), argv)
