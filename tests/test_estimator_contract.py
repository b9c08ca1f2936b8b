"""One contract for every public estimator (scikit-learn's): ``fit`` returns self, the settings are the
same after it (``get_params`` before == after), learned attributes (ending in ``_``) are set, a refit on
the same data learns the same values, and use before ``fit`` raises a clear NotFittedError (one line).

Small simulated data, fixed seeds: a mill's sweeps and checks, the grinder file's sweeps (identified as its
chain), a UR5's poses, a tripod's poses, a short drift log."""
from __future__ import annotations

import copy
import functools

import numpy as np
import pytest

import errormap
from errormap import (ArmCalibration, ClosedLoop, DriftSelector, Identification, NotFittedError, PKMCalibration,
                      load_machine, simulate_checks, simulate_sweeps, simulate_truth)

REFIT_TOL = 0.0
"""A refit on the same data runs the same arithmetic in the same order: learned arrays equal bit for bit."""
MESSAGE_MAX_CHARS = 300
"""A refusal is one line under 300 characters (the project's rule for every message)."""


@functools.lru_cache(maxsize=None)
def _mill_sweeps():
    m = load_machine("mill-xyz")
    return m, simulate_truth(m, seed=1), simulate_sweeps(simulate_truth(m, seed=1), noise_um=1.0, seed=2, n_stations=6)


@functools.lru_cache(maxsize=None)
def _mill_identified():
    m, _, sweeps = _mill_sweeps()
    return Identification(m).fit(sweeps)


def _identification():
    m, _, sweeps = _mill_sweeps()
    return Identification(m), (sweeps,), (np.array([[100.0, 50.0, -100.0], [500.0, 350.0, -350.0]]),), \
        ("elements_", "covariance_")


def _identification_grinder():
    from errormap.chain_truth import make_chain_truth
    from errormap.chain_sweeps import simulated_sweeps
    from errormap.sweeps import sweeps_from_columns
    g = load_machine()
    sweeps = sweeps_from_columns(simulated_sweeps(make_chain_truth(g, seed=3), noise_um=1.0, seed=4))
    axes = np.array([[10.0, 20.0, 30.0], [40.0, 60.0, 200.0]])
    return Identification(g), (sweeps,), (axes,), ("elements_", "covariance_", "field_")


def _closed_loop():
    m, truth, _ = _mill_sweeps()
    ident = _mill_identified()
    checks = simulate_checks(truth, n=40, noise_um=1.0, seed=3)
    return ClosedLoop(m, effects=False), (checks, ident.elements_, ident.prior_covariance_), \
        (np.array([[100.0, 50.0, -100.0]]),), ("elements_", "summary_")


def _arm_calibration():
    from errormap.arm_simulate import draw_truth, measure, random_joints
    ur5 = load_machine("ur5")
    lo, hi = np.array([j.lo for j in ur5.joints]), np.array([j.hi for j in ur5.joints])
    q = random_joints(lo, hi, 60, seed=5)
    poses = measure(ur5, draw_truth(ur5, 6), q, 0.02, 7)
    return ArmCalibration(ur5), (poses,), (q[:3],), ("result_",)


def _pkm_calibration():
    from errormap.pkm.simulate import simulate_tripod_poses
    tripod = load_machine("tripod")
    sim = simulate_tripod_poses(tripod, 20, 5.0, seed=4)
    return PKMCalibration(tripod), (sim.data,), (sim.data.q[:3],), ("result_", "machine_", "frame_")


def _drift():
    from errormap.diagnosis.drift_models import OLSFamily, RidgeBankFamily
    from drift_fixtures import drift_log_of
    from errormap.diagnosis.drift_sim import simulate_lumped_log
    log = drift_log_of(simulate_lumped_log(seed=0, hours=8.0, dt_s=60.0, n_sensors=8, n_dropouts=0))
    return DriftSelector(families=(OLSFamily(), RidgeBankFamily())), (log,), (log,), ("model_", "chosen_")


CASES = {"identification": _identification, "identification-grinder-file": _identification_grinder,
         "closed-loop": _closed_loop, "arm-calibration": _arm_calibration, "pkm-calibration": _pkm_calibration,
         "drift": _drift}
COVERED = {Identification, ClosedLoop, ArmCalibration, PKMCalibration, DriftSelector}
"""The estimators the cases above construct (checked against every exported class with a ``fit``)."""


def test_every_exported_estimator_has_a_case():
    """Every class errormap or compensation exports with a ``fit`` is checked here (training exports a field and
    a ``fit_field`` function, no estimator class; resolving them loads torch)."""
    import compensation
    exported = {getattr(pkg, n) for pkg in (errormap, compensation) for n in pkg.__all__}
    estimators = {c for c in exported if isinstance(c, type) and callable(getattr(c, "fit", None))}
    assert estimators == COVERED, sorted(c.__name__ for c in estimators ^ COVERED)


def _learned(est) -> dict:
    return {k: v for k, v in vars(est).items() if k.endswith("_") and not k.startswith("_")}


def _same(a, b, where: str) -> None:
    """Equal learned values: arrays to REFIT_TOL, containers element by element, objects by their own fields."""
    if where.endswith("['fit_time_s']"):   # wall-clock time of the solve: measured, not learned
        return
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=0, atol=REFIT_TOL, err_msg=where)
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert (np.isnan(a) and np.isnan(b)) or a == b, where
    elif hasattr(a, "__dict__") and not callable(a) and type(a).__module__.startswith("errormap"):
        assert type(a) is type(b), where
        _same({k: v for k, v in vars(a).items() if k not in ("machine", "chain")},
              {k: v for k, v in vars(b).items() if k not in ("machine", "chain")}, where)
    elif isinstance(a, (str, int, bool, type(None), np.generic)):
        assert a == b, where
    else:   # nothing is left uncompared by accident
        assert callable(a) or (type(a).__module__ == "errormap.machine_tool"), f"{where}: {type(a)}"


SLOW_CASES = {"closed-loop", "identification", "pkm-calibration"}
"""Over 5 CPU s on 2 cores when first in the process (the chain kernels compile on first use, the loop's GCV; the
PKM calibrator loads torch for its autodiff Jacobians): measured 8–10 s, 7.4 s and 5.5 s (20 tripod poses); the
other cases 0.6–3.5 s."""


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW_CASES else c
                                  for c in sorted(CASES)])
def test_estimator_contract(case):
    est, data, use, expected = CASES[case]()
    before = est.get_params()
    shown = {k: repr(v) for k, v in before.items()}             # a setting changed in place shows in its repr
    assert type(est)(**before).get_params() == before          # the constructor stores settings as given
    with pytest.raises(NotFittedError, match="not fitted yet") as info:
        est.predict(*use)
    message = str(info.value)
    assert "\n" not in message and len(message) < MESSAGE_MAX_CHARS, message
    assert not _learned(est)
    assert est.fit(*data) is est
    after = est.get_params()
    assert after.keys() == before.keys() and all(after[k] is before[k] for k in before)
    assert {k: repr(v) for k, v in after.items()} == shown
    learned = copy.deepcopy(_learned(est))       # a fit that reused its containers would compare them with themselves
    assert set(expected) <= set(learned)
    first = est.predict(*use)
    est.fit(*data)
    _same(learned, _learned(est), case)
    _same(first, est.predict(*use), f"{case}.predict")


def test_set_params_refuses_unknown_names():
    m = load_machine("mill-xyz")
    est = Identification(m).set_params(max_iter=5)
    assert est.max_iter == 5
    with pytest.raises(ValueError, match="unknown setting"):
        est.set_params(max_iters=5)


def test_fit_reads_no_file():
    m = load_machine("mill-xyz")
    with pytest.raises(TypeError, match="read the file first"):
        Identification(m).fit("sweeps.csv")


def test_import_is_light():
    """The public names resolve lazily: a fresh ``import errormap, training, compensation`` loads no torch, Ray
    or MLflow."""
    import subprocess
    import sys
    code = ("import sys, errormap, training, compensation; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'ray', 'mlflow'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"
    assert set(errormap.__all__) <= set(dir(errormap))


def test_identification_defaults_are_the_commands():
    """``Identification()`` and ``volcomp identify`` share one set of defaults (the command reads the
    estimator's): station-mean gauge, smoothed; and the default fit IS the command's method on the same sweeps."""
    from compensation.app.cli import build_parser
    from errormap.identification import ChainIdentification, smooth_chain
    args = build_parser().parse_args(["identify", "sw.csv", "--out", "E.json"])
    d = Identification.defaults()
    assert (args.gauge, not args.raw) == (d["gauge"], d["smooth"]) == ("station-mean", True)
    m, _, sweeps = _mill_sweeps()
    est = _mill_identified()
    ref = smooth_chain(ChainIdentification(gauge="station-mean").fit(sweeps, m).result_, m)
    for s, v in ref.elements_.functions.items():
        np.testing.assert_array_equal(est.elements_.functions[s], v)
    np.testing.assert_array_equal(est.covariance_[2], ref.cov)
    raw = Identification(m, gauge="first-station", smooth=False).fit(sweeps)
    first = ChainIdentification().fit(sweeps, m).result_
    np.testing.assert_array_equal(raw.covariance_[2], first.cov)
    with pytest.raises(TypeError, match="smooth"):
        Identification(m, smooth="yes").fit(sweeps)


def test_identification_bootstrap_is_the_residual_bootstrap_before_smoothing():
    """``Identification(n_boot=N, seed=S)``: the covariance is the residual bootstrap's (the same draws as
    :func:`errormap.identification.bootstrap_covariance` with the same settings), then smoothed; ``raw_result_`` is
    the result before smoothing. Bit for bit: the same arithmetic in the same order."""
    from errormap.identification import ChainIdentification, bootstrap_covariance, smooth_chain
    m, _, sweeps = _mill_sweeps()
    est = Identification(m, n_boot=3, seed=1).fit(sweeps)
    raw = ChainIdentification(gauge="station-mean").fit(sweeps, m).result_
    raw = bootstrap_covariance(sweeps, m, raw, 3, 1, gauge="station-mean")
    ref = smooth_chain(raw, m)
    np.testing.assert_array_equal(est.raw_result_.cov, raw.cov)
    np.testing.assert_array_equal(est.covariance_[2], ref.cov)
    assert est.result_.covariance_info["method"] == "residual-bootstrap" and est.result_.covariance_info["seed"] == 1


POSE_CSV_REL = 1e-8
"""A pose file's columns are written to 9 significant digits (errormap.io.write_csv): a value read back is within
5e-9 of it, relatively; 1e-8 is far below a mis-read column (another column's values differ by percents)."""


def test_read_poses_follows_the_machine(tmp_path):
    """``errormap.read_poses`` reads a hexapod's or tripod's pose file for PKMCalibration (by the machine given)."""
    from errormap import read_poses
    from errormap.pkm.poses import PoseData
    from errormap.pkm.simulate import simulate_tripod_poses
    tripod = load_machine("tripod")
    sim = simulate_tripod_poses(tripod, 20, 5.0, seed=4)
    p = sim.write_csv(tmp_path / "poses.csv")
    got = read_poses(p, tripod)
    assert isinstance(got, PoseData) and got.rotation is None
    np.testing.assert_allclose(got.q, sim.data.q, rtol=POSE_CSV_REL, atol=0)
    np.testing.assert_allclose(got.tip_mm, sim.data.tip_mm, rtol=POSE_CSV_REL, atol=0)


def test_read_sweeps_is_the_commands_reader(tmp_path):
    """``errormap.read_sweeps`` (the reference's example with measured sweeps) reads a sweep file as ``volcomp
    identify`` does, for a machine tool and the grinder file; an arm is refused by name. It raised NameError before
    (found by mutating input files, 2026-12-04: no test called it)."""
    from errormap import read_sweeps
    from errormap.sweeps import read_sweeps as command_reader
    from compensation.app.cli import main
    for name in ("mill-xyz", None):
        p = tmp_path / f"sw-{name}.csv"
        assert main(["sweeps", "--seed", "1", "--out", str(p)] + (["--machine", name] if name else [])) == 0
        m = load_machine(name)
        got, ref = read_sweeps(p, m), command_reader(p, m)
        assert sorted(got.axes) == sorted(ref.axes) and got.axes
        for w in ref.axes:
            np.testing.assert_array_equal(got.axes[w].balls_mm, ref.axes[w].balls_mm)
            np.testing.assert_array_equal(got.axes[w].command, ref.axes[w].command)
    with pytest.raises(TypeError, match="read_sweeps"):
        read_sweeps(tmp_path / "sw-mill-xyz.csv", load_machine("ur5"))
