"""Learned vs parametric, side by side, on the same machines and the same measurements.

``run_benchmark(machines, out_dir, settings)`` runs both compensation paths on each machine
under a set of measurement conditions, evaluates the TRUE residual (residual 2 of docs/explanation/kinematics.md: the
simulated truth machine driven with the compensated commands, minus the target) along the
test paths, records every run in MLflow under one parent run, and writes
``DIR/benchmark.json`` and ``DIR/report.html`` (:mod:`compensation.app.reports.benchmark`).

**Grinder** (one simulated truth machine, seed ``truth_seed``):

* measurements: laser-tracker sweeps (``errormap.sweeps.simulate_sweeps``) with ``stations``
  stations per axis and tracker noise ``noise_um``; ``n_measurements = stations × 3 balls × 3 axes``
  (ball-centre measurements); the closed loop adds ``n_checks`` check measurements;
* parametric: identified 23 elements → :class:`errormap.htm.HTMField` → ``exact`` solver;
* learned: the same identified elements → 11×11×11 feature points → the BP network
  (``training.fit_field``, LM, ``train_iter`` iterations) → ``batched-ga`` (the paper's GA,
  vectorised) on ``ga_points`` evenly spaced flute points and ``exact`` on the whole flute;
  the row's headline numbers are the ``exact`` ones (whole path), the GA subset is beside them;
* test path: the variable-helix flute (``compensation.toolpath.flute_path``), under the path
  condition :data:`PATH_CONDITIONS` (a warm machine at 24 °C, X and A approached from below as
  the path moves, Z from above because the wheel plunges to the flute-bottom radius);
* conditions: sweep density (stations), tracker noise, and each undeclared effect of the
  simulator in the truth, before and after the closed loop (check measurements → the effect search
  on the identified element set, :func:`errormap.diagnosis.chain_loop.closed_loop_chain` without its
  element update → the elements plus the found terms → compensate with it). The learned path has no
  element set: its row after the loop says so;
* out-of-catalogue conditions (``ooc_effects`` × ``ooc_checks``, and the same machine without an
  effect): after the loop the parametric path runs the user's path instead — the sweeps identified as
  ``volcomp identify`` does (smoothing, element covariance), then ``volcomp diagnose``'s closed loop on
  the checks (:func:`compensation.app.workflows.measurement.diagnose_chain`: element update, effects,
  the learned residual backfitted with the update, all re-estimated on all checks); its loop alone is
  the parametric row, its kept model (``model.json``) the hybrid row. Each row says which loop ran
  (``loop_method``: :data:`USER_LOOP` or :data:`EFFECTS_LOOP`).

**Hexapod** (and the tripod): simulated pose measurements (``simulate_poses``, known instrument
frame), ``n_poses`` poses with noise ``noise_um``;

* parametric: ``PKMCalibrator`` (Tikhonov + Morozov) → corrected inverse kinematics in the
  interpolation (``true_path_residual``);
* learned: :func:`training.pose_field.fit_pose_field` (commanded pose → pose error) →
  compensation by iterating the commanded pose (:func:`learned_pkm_commands`);
* test paths: the paper's sphere and hyperboloid passes (tripod: random workspace points).

**Machine-tool chain files** (``kind = "machine-tool"``: mill-xyz, five-axis-ac, a user's file):
per condition (no effect, each undeclared effect the chain has axes for) the user's path —
simulate a hidden truth → sweeps → identify → diagnose → exact compensation of the four body
diagonals with the identified set and with the loop's model — judged by the TRUE residual
(:mod:`compensation.app.workflows.chain_benchmark`).

Every figure is measured in this run; a part that cannot run is reported as not available
with the reason, never filled in.
"""
from __future__ import annotations

import math
import platform
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from errormap.io import write_json
from errormap.seeds import spawn_seeds
from errormap.stats import residual_stats

from ..families import family_of
from .benchmark_loop import at_conditions, chain_elements, loop_models

PATH_CONDITIONS = {"temp_c": 24.0, "time_s": 7200.0, "dir_x": 1.0, "dir_z": -1.0, "dir_a": 1.0}
"""Conditions of the flute test path: a warm machine (24 °C, 2 h after the start of the warm-up
the check log records), X and A approached in the path's direction of motion (+), Z from above
(the wheel plunges in to the flute-bottom radius)."""

TRUTH_CONDITIONS = ("temp_c", "dir_x", "dir_z", "dir_a")
"""The conditions the simulated truth grinder's effects depend on (``time_s`` is only for fitted drift terms)."""

EXPERIMENT = "volcomp-benchmark"
USER_LOOP = ("the user's path: volcomp identify (smoothing, covariance) → volcomp diagnose (element update + effects "
             "+ learned residual backfitted with the update, re-estimated on all checks)")
"""Which loop a row ran (key ``loop_method``): the out-of-catalogue conditions' parametric loop and hybrid."""
EFFECTS_LOOP = "effect search on the base's element set (the closed loop without its element update)"
"""Which loop a row ran (key ``loop_method``): every other condition's; the learned base (no elements) says it did not run."""
FEATURE_REUSE_TOL_UM = 1e-6


LEARNED_GRID = 11  # feature points per axis of the learned stage: the paper's network on the paper's 11³ grid (docs/reference/benchmark.md)


@dataclass
class BenchmarkSettings:
    """What the benchmark runs. Defaults: the full benchmark (about 23 CPU minutes; ~1 h wall on a loaded 2-core
    machine, docs/reference/benchmark.md "Run time")."""

    truth_seed: int = 0
    seed: int = 0
    stations: tuple = (6, 11, 21, 41)
    noises_um: tuple = (0.0, 1.0, 5.0, 20.0)
    base_stations: int = 21
    base_noise_um: float = 1.0
    effects: tuple = ("thermal", "reversal", "pitch", "worm", "interaction")
    # effects no catalogue kind represents (errormap.simulator.OUT_OF_CATALOGUE), each with the closed
    # loop and its learned-residual stage (the hybrid column); plus the same machine without an effect
    ooc_effects: tuple = ("bump", "a_tilt", "squareness", "a_lobe_x")
    # check counts of the out-of-catalogue conditions (each effect and none at every count: the learned
    # stage's estimation error against the number of checks; `volcomp benchmark --checks N`, repeatable)
    ooc_checks: tuple = (800, 150, 1600)
    # the out-of-catalogue conditions' loop runs the user's path: `volcomp identify` (smoothing, covariance
    # Gauss-Newton's, or from this many residual-bootstrap draws) → `volcomp diagnose` (workflows/measurement.py)
    identify_bootstrap: int | None = None
    n_checks: int = 400
    check_noise_um: float = 1.0
    train_iter: int = 150                  # LM iterations per learned grinder condition (~30 s on 2 cores)
    train_s: float | None = None           # optional wall-clock limit on top (off: results depend on the load)
    hidden: tuple = (10, 15, 25, 15, 10)   # the paper's network (LM + off-grid model selection)
    activation: str = "sigmoid"
    a_encoding: str = "raw"
    paper_network: bool = False            # extra row with the paper's network: it is the default now
    ga_points: int = 100
    ga_generations: int = 400
    flute_turns: float = 7.0
    flute_points_per_turn: int = 400
    volume_points: int = 300
    pkm_poses: tuple = (20, 50, 100, 200)
    pkm_noises_um: tuple = (0.0, 1.0, 5.0, 20.0)
    pkm_base_poses: int = 100
    pkm_base_noise_um: float = 5.0
    pkm_pose_error_mm: float = 1.0
    pkm_train_iter: int = 200              # pose-field LM iterations
    pkm_train_s: float | None = None       # optional wall-clock limit on top
    pkm_hidden: tuple = (16,)
    pkm_ridge: float = 1e-3
    pkm_path_step_mm: float = 0.5
    pkm_half_width_mm: tuple = (160.0, 160.0, 220.0)
    pkm_max_tilt_deg: float = 32.0
    chain_path_points: int = 100           # machine-tool chains: points per body diagonal (4 diagonals)
    # serial arms (--machine ur5 …; workflows/arm_benchmark.py): one seeded truth arm per condition (no effect,
    # then each arm effect), measured by a tracker at arm_noise_um, calibrated and compensated as the commands do
    arm_effects: tuple = ((), ("sag",), ("backlash",), ("sag", "backlash"))
    arm_poses: int = 300                   # fitting poses (the real UR5 grid has 1,000; the WAM's 216)
    arm_checks: int = 100                  # held-out poses (MEASURED residual beside the TRUE one)
    arm_noise_um: float = 20.0             # tracker σ per component (simulate_serial's default)
    arm_learned: bool = True               # run the learned residual stage (its CV decides whether it is kept)
    arm_k_folds: int = 5
    torch_threads: int = 1
    quick: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


def quick_settings() -> BenchmarkSettings:
    """The ``--quick`` variant (a test runs it): fewer conditions, tiny training, path subsets."""
    return BenchmarkSettings(stations=(21,), noises_um=(1.0,), effects=("thermal",), n_checks=200,
                             ooc_effects=("bump",), ooc_checks=(200,),
                             train_iter=60, hidden=(8, 8), activation="tanh", a_encoding="periodic", paper_network=False,
                             ga_points=20, ga_generations=100, flute_turns=1.0, flute_points_per_turn=200,
                             volume_points=50,
                             pkm_poses=(50,), pkm_noises_um=(5.0,), pkm_base_poses=50, pkm_train_iter=50,
                             pkm_path_step_mm=4.0, chain_path_points=25, arm_effects=(("sag",),),
                             arm_poses=200, arm_checks=50, arm_learned=False, quick=True)


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# sub-streams of the run's seed (errormap.seeds), one per consumer; the same child for every
# condition, so that the conditions see the same draws where their shapes agree
STREAMS = ("volume_points", "sweep_noise", "validation", "selection", "checks", "pkm_paths", "pkm_poses")


def _streams(seed: int) -> dict:
    """``{consumer: SeedSequence}``: the children of ``SeedSequence(seed)`` named by :data:`STREAMS`."""
    return dict(zip(STREAMS, spawn_seeds(seed, len(STREAMS))))


def _row(machine, kind, path, condition, **kw) -> dict:
    row = {"machine": machine, "machine_kind": kind, "path": path, "condition": condition,
           "available": True, "true_rms_um": None, "true_max_um": None, "fit_seconds": None,
           "compensate_seconds_per_point": None, "n_measurements": None}
    row.update(kw)
    return row


# ------------------------------------------------------------------------------- MLflow
class Tracker:
    """One parent MLflow run per benchmark; each result row and each training is a child run.

    ``tracking_uri=None`` uses :func:`training.tracking.default_tracking_uri`; ``enabled=False``
    records nothing (``parent_id`` is then None).
    """

    def __init__(self, tracking_uri: str | None, enabled: bool = True, run_name: str = "benchmark"):
        self.enabled = enabled
        self.parent_id = None
        self.client = None
        if not enabled:
            return
        from mlflow.tracking import MlflowClient

        from training.tracking import default_tracking_uri
        self.uri = tracking_uri or default_tracking_uri()
        if self.uri.startswith("sqlite:///"):
            Path(self.uri[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
        self.client = MlflowClient(tracking_uri=self.uri)
        exp = self.client.get_experiment_by_name(EXPERIMENT)
        if exp is None:
            art = None
            if self.uri.startswith("sqlite:///"):
                art = (Path(self.uri[len("sqlite:///"):]).parent / "artifacts").resolve().as_uri()
            try:
                self.exp_id = self.client.create_experiment(EXPERIMENT, artifact_location=art)
            except Exception:  # created concurrently
                self.exp_id = self.client.get_experiment_by_name(EXPERIMENT).experiment_id
        else:
            self.exp_id = exp.experiment_id
        self.parent_id = self.client.create_run(self.exp_id, run_name=run_name,
                                                tags={"volcomp.kind": "benchmark"}).info.run_id

    def log_params(self, params: dict, run_id: str | None = None) -> None:
        if not self.enabled:
            return
        from mlflow.entities import Param
        ps = [Param(k, str(v)[:6000]) for k, v in params.items()]
        for i in range(0, len(ps), 100):
            self.client.log_batch(run_id or self.parent_id, params=ps[i:i + 100])

    def child(self, name: str, params: dict, metrics: dict, tags: dict | None = None) -> str | None:
        """A finished child run with ``params`` and numeric ``metrics`` (None values skipped)."""
        if not self.enabled:
            return None
        from mlflow.entities import Metric
        t = {"mlflow.parentRunId": self.parent_id, **{k: str(v) for k, v in (tags or {}).items()}}
        rid = self.client.create_run(self.exp_id, run_name=name, tags=t).info.run_id
        self.log_params(params, rid)
        now = int(time.time() * 1000)
        ms = [Metric(k, float(v), now, 0) for k, v in metrics.items()
              if isinstance(v, (int, float)) and not isinstance(v, bool) and v is not None and np.isfinite(v)]
        if ms:
            self.client.log_batch(rid, metrics=ms)
        self.client.set_terminated(rid, "FINISHED")
        return rid

    def finish(self, metrics: dict, artifacts=(), status: str = "FINISHED") -> None:
        if not self.enabled:
            return
        from mlflow.entities import Metric
        now = int(time.time() * 1000)
        ms = [Metric(k, float(v), now, 0) for k, v in metrics.items() if v is not None]
        if ms:
            self.client.log_batch(self.parent_id, metrics=ms)
        for a in artifacts:
            self.client.log_artifact(self.parent_id, str(a))
        self.client.set_terminated(self.parent_id, status)


def log_row(tracker: Tracker, row: dict) -> None:
    """Record a result row as a child run (params: the condition; metrics: the numbers)."""
    params = {k: row.get(k) for k in ("machine", "path", "condition", "group", "stations", "noise_um", "effect",
                                      "closed_loop", "loop_method", "n_poses", "solver", "test_path")
              if row.get(k) is not None}
    metrics = {k: v for k, v in row.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    for s, d in (row.get("solvers") or {}).items():
        for k, v in d.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                metrics[f"{s}.{k}"] = v
    tags = {"training_run_id": row["training_run_id"]} if row.get("training_run_id") else None
    row["run_id"] = tracker.child(f"{row['machine_kind']}/{row['path']}/{row['condition']}", params, metrics, tags)


# ------------------------------------------------------------------------------- grinder
@dataclass
class GrinderCondition:
    name: str
    group: str
    stations: int
    noise_um: float
    effect: str | None = None
    n_checks: int | None = None   # check measurements of the closed loop (None: the settings' n_checks)
    loop: bool = False            # run the closed loop (and its hybrid stage) even without an effect


def grinder_conditions(s: BenchmarkSettings) -> list[GrinderCondition]:
    """Density sweep (at the base noise), noise sweep (at the base density), each effect (base)."""
    out = {}
    for st in s.stations:
        name = f"stations={st}, noise={s.base_noise_um:g}um"
        out.setdefault(name, GrinderCondition(name, "density", st, s.base_noise_um))
    for nz in s.noises_um:
        name = f"stations={s.base_stations}, noise={nz:g}um"
        out.setdefault(name, GrinderCondition(name, "noise", s.base_stations, nz))
    for eff in s.effects:
        name = f"effect={eff}"
        out[name] = GrinderCondition(name, "effect", s.base_stations, s.base_noise_um, eff)
    if s.ooc_effects:  # out of any catalogue, and the same machine without an effect, at each check count
        for eff in (*s.ooc_effects, "none"):
            for nc in dict.fromkeys(s.ooc_checks):
                name = f"effect={eff}" + (f", checks={nc}" if nc != s.n_checks else "")
                out[name] = GrinderCondition(name, "out-of-catalogue", s.base_stations, s.base_noise_um,
                                             None if eff == "none" else eff, nc, True)
    return list(out.values())


def _subset(n: int, m: int) -> np.ndarray:
    return np.unique(np.round(np.linspace(0, n - 1, min(n, m))).astype(int))


@dataclass
class GrinderTestPoints:
    """Where the grinder rows are evaluated, the same for every condition (truth-independent).

    targets_mm, nominal_axes : (n, 3)   the flute path's WCS targets and nominal axes
    ga_idx : (m,)                       the evenly spaced flute points the batched GA solves
    path_cond : {name: (n,)}            :data:`PATH_CONDITIONS` the truth needs, per point
    volume_axes, volume_targets_mm : (k, 3), volume_cond : {name: (k,)}   random volume points
    """

    targets_mm: np.ndarray
    nominal_axes: np.ndarray
    ga_idx: np.ndarray
    path_cond: dict
    volume_axes: np.ndarray
    volume_targets_mm: np.ndarray
    volume_cond: dict

    def select(self, idx=None, volume: bool = False):
        """(targets, nominal axes, conditions) of the path (or the volume points), at ``idx``."""
        tg, nom, cond = (self.volume_targets_mm, self.volume_axes, self.volume_cond) if volume else \
            (self.targets_mm, self.nominal_axes, self.path_cond)
        if idx is not None:
            tg, nom, cond = tg[idx], nom[idx], {k: v[idx] for k, v in cond.items()}
        return tg, nom, cond


def grinder_test_points(machine, s: BenchmarkSettings) -> GrinderTestPoints:
    """The flute (``s.flute_turns`` × ``s.flute_points_per_turn``) and ``s.volume_points`` volume
    points: uniform over the strokes, rho >= 5 mm (away from the A axis, where the WCS is
    singular), nominal axes -> targets."""
    from errormap.kinematics import forward
    from errormap.simulator import random_axes

    from ...toolpath import flute_path
    flute = flute_path(turns=s.flute_turns, points_per_turn=s.flute_points_per_turn)
    targets, nominal = flute.targets_mm, flute.axes(machine)
    rng = np.random.default_rng(_streams(s.seed)["volume_points"])
    ax = random_axes(machine, 4 * s.volume_points, rng)
    ax = ax[ax[:, 1] >= machine.strokes["z_mm"][0] + 5.0][: s.volume_points]

    def at(n):
        return {k: np.full(n, v) for k, v in PATH_CONDITIONS.items() if k in TRUTH_CONDITIONS}

    return GrinderTestPoints(targets, nominal, _subset(len(targets), s.ga_points), at(len(targets)),
                             ax, forward(machine, ax), at(len(ax)))


def grinder_truth(machine, s: BenchmarkSettings, effect=None):
    """The simulated truth grinder of ``s.truth_seed``, with the undeclared ``effect`` if given."""
    from errormap.simulator import random_truth
    return random_truth(machine, s.truth_seed, effects=(effect,) if effect else ())


def condition_sweeps(s: BenchmarkSettings, truth, c: GrinderCondition) -> dict:
    """Simulated tracker sweeps of ``truth`` under condition ``c`` (columns, as a sweep file holds them)."""
    from errormap.sweeps import simulate_sweeps
    return simulate_sweeps(truth, noise_um=c.noise_um, seed=_streams(s.seed)["sweep_noise"], n_stations=c.stations)


def identify_from_sweeps(machine, s: BenchmarkSettings, truth, c: GrinderCondition):
    """Simulated tracker sweeps of ``truth`` under condition ``c`` → the 23 identified elements.
    Returns ``(elements, identification seconds, number of ball-centre measurements)``."""
    from errormap.uncertainty import smooth_identify
    sw = condition_sweeps(s, truth, c)
    t0 = time.perf_counter()
    res = smooth_identify(sw, machine, smooth=False, gauge="first-station").raw
    return res.elements_, time.perf_counter() - t0, len(sw["axis"])


def identify_with_covariance(machine, s: BenchmarkSettings, truth, c: GrinderCondition):
    """The same sweeps identified as ``volcomp identify`` does with its defaults
    (:func:`compensation.app.workflows.identification.identify_elements` → :func:`errormap.uncertainty.smooth_identify`:
    penalised smoothing, station-mean gauge, tracker noise estimated from the ball residuals, the covariance
    Gauss-Newton's or ``s.identify_bootstrap`` residual-bootstrap draws of seed 0). Returns ``(ElementCovariance, seconds)``: the element
    set and its covariance, what ``volcomp diagnose`` finds beside the element-set file."""
    from errormap.uncertainty import smooth_identify
    sw = condition_sweeps(s, truth, c)
    t0 = time.perf_counter()
    sm = smooth_identify(sw, machine, n_boot=s.identify_bootstrap, seed=0)
    return sm.covariance_, time.perf_counter() - t0


def compensate_true(machine, s: BenchmarkSettings, points: GrinderTestPoints, truth, field_, method: str,
                    idx=None, volume: bool = False) -> dict:
    """Compensate with ``field_`` and ``method``; the TRUE residual on ``truth`` (RMS, max), the
    solver's time per point, its worst model residual and its failures."""
    from ...evaluate import true_residual_um
    from ...solvers import solve
    tg, nom, cond = points.select(idx, volume)
    opts = {"target_axes": nom, "progress": False}
    if method == "batched-ga":
        opts.update(seed=s.seed, generations=s.ga_generations)
    r = solve(method, field_, tg, machine, **opts)
    st = residual_stats(true_residual_um(truth, r.axes, tg, cond))
    return {"true_rms_um": st["rms_um"], "true_max_um": st["max_um"], "seconds_per_point": r.seconds / len(tg), "points": len(tg),
            "model_max_um": float(np.max(r.residual_norm_um)), "failures": int(np.count_nonzero(~r.success))}


def uncompensated_true(points: GrinderTestPoints, truth) -> tuple[float, float]:
    """(RMS, max) TRUE residual of the nominal flute commands."""
    from ...evaluate import true_residual_um
    st = residual_stats(true_residual_um(truth, points.nominal_axes, points.targets_mm, points.path_cond))
    return st["rms_um"], st["max_um"]


class NetworkTrainer:
    """Trains the learned field on identified elements, once per distinct feature-point set and
    network setting (a condition whose identified elements equal an earlier one's reuses it)."""

    def __init__(self, machine, tracker: Tracker, warm_up_axes):
        self.m, self.tracker, self.warm_up_axes = machine, tracker, warm_up_axes
        self.cache = []  # (network settings, feature-point errors, fit result, seconds, condition)

    def train(self, elements, cond_name: str, s: BenchmarkSettings):
        """``(fit result, seconds, name of the condition reused or None)``."""
        from errormap.featurepoints import make_feature_points
        from errormap.htm import HTMField
        from training import TrackSettings, TrainSettings, fit_field, validation_points
        fp = make_feature_points(self.m, HTMField(self.m, elements), n=LEARNED_GRID, meta={"benchmark_condition": cond_name})
        key = (tuple(s.hidden), s.activation, s.a_encoding, s.train_iter, s.train_s)
        for k, errs, res, secs, name in self.cache:
            if k == key and np.max(np.abs(errs - fp.errors_um)) < FEATURE_REUSE_TOL_UM:
                return res, secs, name
        streams = _streams(s.seed)
        val = validation_points(self.m, elements, n=2000, seed=streams["validation"])
        # model selection on other off-grid points of the same identified model (not the validation set)
        sel = validation_points(self.m, elements, n=2000, seed=streams["selection"])
        _log(f"grinder: training the network ({cond_name}, LM, {s.train_iter} iterations"
             + (f", ≤ {s.train_s:g} s)" if s.train_s is not None else ")"))
        t0 = time.perf_counter()
        tr = self.tracker
        settings = TrainSettings(trainer="lm", max_iter=s.train_iter, seed=s.seed,
                                 max_time_s=math.inf if s.train_s is None else s.train_s,
                                 hidden=s.hidden, activation=s.activation, a_encoding=s.a_encoding)
        tracking = TrackSettings(track=tr.enabled,
                                 tracking_uri=tr.uri if tr.enabled else None,
                                 parent_run_id=tr.parent_id, run_name=f"grinder/learned/train/{cond_name}",
                                 experiment=EXPERIMENT, tags={"benchmark_condition": cond_name})
        res = fit_field(fp, settings, validation=val, selection=sel, tracking=tracking, quiet=True)
        secs = time.perf_counter() - t0
        res.field.jacobian(self.warm_up_axes)  # torch.func warm-up, so that compensation timings exclude it
        self.cache.append((key, fp.errors_um.copy(), res, secs, cond_name))
        return res, secs, None


class RowLog:
    """The result rows in order: each is recorded in MLflow (:func:`log_row`) and logged."""

    def __init__(self, tracker: Tracker):
        self.tracker, self.rows = tracker, []

    def add(self, row: dict) -> None:
        log_row(self.tracker, row)
        self.rows.append(row)
        if row.get("available"):
            _log(f"  {row['path']:10s} {row['condition']}: true RMS {row['true_rms_um']:.3f} um, max "
                 f"{row['true_max_um']:.3f} um, fit {row['fit_seconds']:.1f} s")


def _with_volume(row: dict, vol) -> dict:
    if vol:
        row.update(volume_rms_um=vol["true_rms_um"], volume_max_um=vol["true_max_um"])
    return row


class GrinderBench:
    """The grinder rows: for each condition, parametric and learned, then the closed loop when
    the condition adds an undeclared effect. Measurement, identification, training and the TRUE
    residual are the functions and classes above; this class only puts the rows together."""

    def __init__(self, machine, s: BenchmarkSettings, tracker: Tracker):
        self.m, self.s = machine, s
        self.points = grinder_test_points(machine, s)
        self.trainer = NetworkTrainer(machine, tracker, self.points.nominal_axes[:2])
        self.log = RowLog(tracker)

    @property
    def rows(self) -> list:
        return self.log.rows

    def _compensate(self, truth, field_, method, idx=None, volume=False) -> dict:
        return compensate_true(self.m, self.s, self.points, truth, field_, method, idx=idx, volume=volume)

    def _volume(self, truth, field_):
        return self._compensate(truth, field_, "exact", volume=True) if self.s.volume_points else None

    def run_condition(self, c: GrinderCondition) -> None:
        truth = grinder_truth(self.m, self.s, c.effect)
        unc_rms, unc_max = uncompensated_true(self.points, truth)
        elements, id_s, n_meas = identify_from_sweeps(self.m, self.s, truth, c)
        common = {"group": c.group, "stations": c.stations, "noise_um": c.noise_um, "effect": c.effect,
                  "test_path": f"flute ({len(self.points.targets_mm)} points)", "n_measurements": n_meas,
                  "uncompensated_rms_um": unc_rms, "uncompensated_max_um": unc_max}
        loop = bool(c.effect or c.loop)
        label = c.name + (" (before closed loop)" if loop else "")
        par_field, par = self.parametric_row(truth, elements, id_s, label, common)
        # the network is trained once per identified element set (a condition with other checks reuses it)
        learned = self.learned_row(truth, elements, id_s, c.name, label, common)
        if loop and learned is not None:
            mlp, lrn = learned
            self.closed_loop(c, truth, ((par, par_field), (lrn, mlp)), common)

    def parametric_row(self, truth, elements, id_s, label, common):
        """The exact inverse of the identified HTM field; returns (field, row)."""
        from errormap.htm import HTMField
        field_ = HTMField(self.m, elements)
        _log(f"grinder: parametric, {label}")
        ex = self._compensate(truth, field_, "exact")
        row = _row(self.m.name, "grinder", "parametric", label, closed_loop=False, solver="exact",
                   fit_seconds=id_s, identify_seconds=id_s, compensate_seconds_per_point=ex["seconds_per_point"],
                   true_rms_um=ex["true_rms_um"], true_max_um=ex["true_max_um"], solvers={"exact": ex}, **common)
        self.log.add(_with_volume(row, self._volume(truth, field_)))
        return field_, row

    def learned_row(self, truth, elements, id_s, cond_name, label, common):
        """Feature points → network → batched GA (subset) + exact (whole path); returns (network,
        row), or None when training failed (the row then says why)."""
        try:
            fit, _, reused = self.trainer.train(elements, cond_name, self.s)
        except Exception as exc:  # training unavailable or failed: say so, never fake numbers
            self.log.add(_row(self.m.name, "grinder", "learned", label, available=False,
                              not_available=f"training failed: {type(exc).__name__}: {exc}", **common))
            return None
        mlp = fit.field
        _log(f"grinder: learned, {label}")
        ex = self._compensate(truth, mlp, "exact")
        ga = self._compensate(truth, mlp, "batched-ga", idx=self.points.ga_idx)
        vol = self._volume(truth, mlp)
        row = _row(self.m.name, "grinder", "learned", label, closed_loop=False, solver="exact",
                   fit_seconds=id_s + fit.seconds, identify_seconds=id_s, train_seconds=fit.seconds,
                   training_run_id=fit.run_id, reused_training_of=reused,
                   train_val_rms_um=fit.metrics.get("val_rms_um"), train_val_max_um=fit.metrics.get("val_max_um"),
                   train_iterations=fit.metrics.get("iterations"),
                   compensate_seconds_per_point=ex["seconds_per_point"], true_rms_um=ex["true_rms_um"],
                   true_max_um=ex["true_max_um"], solvers={"exact": ex, "batched-ga": ga}, **common)
        self.log.add(_with_volume(row, vol))
        return mlp, row

    def closed_loop(self, c, truth, bases, common) -> None:
        """Checks → the closed loop → compensate → true residual, for each ``(base row, base field)`` of
        ``bases``: on an out-of-catalogue condition the parametric base runs the user's path
        (:meth:`user_loop_rows`: the parametric loop and the hybrid), every other base the effect
        search on its field (:meth:`closed_loop_row`)."""
        from errormap.diagnosis.chain_loop import MTChecks
        from errormap.grinder_file import machine_tool_of
        s = self.s
        n_checks = c.n_checks or s.n_checks
        cols = truth.check_measurements(n=n_checks, noise_um=s.check_noise_um, seed=_streams(s.seed)["checks"])
        checks = MTChecks.from_columns(machine_tool_of(self.m), cols, path=f"<simulated checks, {c.name}>")
        label = f"{c.name} (after closed loop)"
        for base_row, base in bases:
            if base_row["path"] == "parametric" and c.group == "out-of-catalogue":
                self.user_loop_rows(c, truth, label, checks, common)
                continue
            _log(f"grinder: {base_row['path']}, {label}")
            try:
                self.closed_loop_row(truth, label, checks, base_row, base, common)
            except Exception as exc:  # never fake numbers: the row says why it is missing
                self.log.add(_row(self.m.name, "grinder", base_row["path"], label, available=False, closed_loop=True,
                                  loop_method=EFFECTS_LOOP,
                                  not_available=f"closed loop failed: {type(exc).__name__}: {exc}", **common))

    def user_loop_rows(self, c, truth, label, checks, common) -> None:
        """The user's path on the checks: ``volcomp identify`` (:func:`identify_with_covariance`) → ``volcomp
        diagnose`` with that element set (:func:`compensation.app.workflows.measurement.diagnose_chain`: the
        element update, the effects, the learned residual backfitted with the update and gated on the held-out
        checks, the kept stage re-estimated on all checks) → compensate, judged by the truth. Two rows: the
        parametric loop is the loop alone (``model.json`` without its learned part, its ``loop_alone`` when the
        base was backfitted), the hybrid the kept model (``model.json``); both at :data:`PATH_CONDITIONS`."""
        import tempfile
        from .measurement import diagnose_chain
        s = self.s
        _log(f"grinder: identify + diagnose (the user's path), {label}")
        done = []
        try:
            cov, id_s = identify_with_covariance(self.m, s, truth, c)
            with tempfile.TemporaryDirectory(prefix="volcomp-benchmark-") as td:
                from errormap.uncertainty import covariance_path
                el_path = cov.elements.save(Path(td) / "elements.json")
                cov.save(covariance_path(el_path))
                t0 = time.perf_counter()
                summary, _ = diagnose_chain(checks, self.m, el_path, Path(td) / "diagnosis")
                loop_s = time.perf_counter() - t0
                models = loop_models(self.m, Path(td) / "diagnosis" / "model.json", PATH_CONDITIONS)
            lr = summary.get("learned_residual") or {}
            kept_learned = summary["kept_stage"] == "learned_residual"
            learned = {"learned_kept": kept_learned, "learned_family": lr.get("family"),
                       "learned_why": lr.get("why"), "learned_gain_z": lr.get("held_out_gain_z"),
                       "learned_band95_cover": lr.get("held_out_band95_cover"), "learned_backfitted": "backfit" in lr}
            rms_after = {"parametric": summary.get("held_out_rms_base_um", summary["held_out_rms_um"]),
                         "hybrid": summary["held_out_rms_um"]}
            for path, (terms, stage, field_) in models.items():
                _log(f"grinder: {path}, {label}")
                sol = {"exact": self._compensate(truth, field_, "exact")}
                if path == "hybrid" and kept_learned:
                    sol["batched-ga"] = self._compensate(truth, field_, "batched-ga", idx=self.points.ga_idx)
                row = _row(self.m.name, "grinder", path, label, closed_loop=True, loop_method=USER_LOOP,
                           solver="exact", fit_seconds=id_s + loop_s, identify_seconds=id_s, diagnosis_seconds=loop_s,
                           compensate_seconds_per_point=sol["exact"]["seconds_per_point"],
                           true_rms_um=sol["exact"]["true_rms_um"], true_max_um=sol["exact"]["true_max_um"],
                           solvers=sol, effects_found=[f"{e['kind']}:{e['axis']}:{e['element']}" for e in terms],
                           stage=stage, n_checks=len(checks),
                           checks_rms_before_um=summary["stages"]["identified"]["held_out"]["rms_um"],
                           checks_rms_after_um=rms_after[path],
                           check_noise_um=s.check_noise_um, model_verdict=summary.get("verdict"),
                           **(learned if path == "hybrid" else {}),
                           **{**common, "n_measurements": common["n_measurements"] + len(checks)})
                self.log.add(_with_volume(row, self._volume(truth, field_)))
                done.append(path)
        except Exception as exc:  # never fake numbers: the rows say why they are missing
            for path in ("parametric", "hybrid"):
                if path not in done:
                    self.log.add(_row(self.m.name, "grinder", path, label, available=False, closed_loop=True,
                                      loop_method=USER_LOOP,
                                      not_available=f"closed loop failed: {type(exc).__name__}: {exc}", **common))

    def closed_loop_row(self, truth, label, checks, base_row, base, common):
        """The effect search on the base's element set (the closed loop without the element update); a base without
        elements (the learned field) is a row that says so."""
        from errormap.chain_elements import ChainElementSet
        from errormap.diagnosis.chain_loop import closed_loop_chain
        from errormap.diagnosis.loop_model import ChainModelField
        from errormap.grinder_file import machine_tool_of
        s = self.s
        if getattr(base, "elements", None) is None:
            raise ValueError("the closed loop searches effects on an element set; a trained network is not one")
        mt = machine_tool_of(self.m)
        el = base.elements if isinstance(base.elements, ChainElementSet) else chain_elements(base.elements, mt)
        t0 = time.perf_counter()
        d = closed_loop_chain(mt, el, checks, cov=None)
        diag_s = time.perf_counter() - t0
        terms = d["_models"]["terms"] if d["kept_stage"].endswith("plus_effects") else []
        found = [f"{t.kind}:{'*'.join(t.axes)}:{t.element}" for t in terms]
        corrected = at_conditions(ChainModelField(mt, el, terms), mt, PATH_CONDITIONS)
        sol = {"exact": self._compensate(truth, corrected, "exact")}
        vol = self._volume(truth, corrected)
        extra = {k: base_row.get(k) for k in ("identify_seconds", "train_seconds", "training_run_id",
                                               "reused_training_of") if base_row.get(k) is not None}
        row = _row(self.m.name, "grinder", base_row["path"], label, closed_loop=True, loop_method=EFFECTS_LOOP,
                   solver="exact", fit_seconds=base_row["fit_seconds"] + diag_s, diagnosis_seconds=diag_s,
                   compensate_seconds_per_point=sol["exact"]["seconds_per_point"],
                   true_rms_um=sol["exact"]["true_rms_um"], true_max_um=sol["exact"]["true_max_um"],
                   solvers=sol, effects_found=found, n_checks=len(checks),
                   checks_rms_before_um=d["stages"]["identified"]["held_out"]["rms_um"],
                   checks_rms_after_um=d["held_out_rms_um"],
                   **{**common, "n_measurements": common["n_measurements"] + len(checks)}, **extra)
        self.log.add(_with_volume(row, vol))
        return d, row

    def paper_network_row(self) -> None:
        """The learned path at the base condition with the paper's network (10-15-25-15-10, sigmoid, A raw)
        and the same LM budget: what the architecture choice costs."""
        from training.model import PAPER_HIDDEN
        s = self.s
        c = GrinderCondition(f"stations={s.base_stations}, noise={s.base_noise_um:g}um", "network", s.base_stations,
                             s.base_noise_um)
        truth = grinder_truth(self.m, s, None)
        elements, id_s, n_meas = identify_from_sweeps(self.m, s, truth, c)
        label = f"{c.name}, paper network {'-'.join(map(str, PAPER_HIDDEN))} sigmoid"
        paper = replace(s, hidden=PAPER_HIDDEN, activation="sigmoid", a_encoding="raw")
        fit, _, _ = self.trainer.train(elements, label, paper)
        ex = self._compensate(truth, fit.field, "exact")
        unc_rms, unc_max = uncompensated_true(self.points, truth)
        self.log.add(_row(self.m.name, "grinder", "learned", label, group="network", stations=c.stations,
                          noise_um=c.noise_um, effect=None, closed_loop=False, solver="exact",
                          test_path=f"flute ({len(self.points.targets_mm)} points)", n_measurements=n_meas,
                          uncompensated_rms_um=unc_rms, uncompensated_max_um=unc_max,
                          fit_seconds=id_s + fit.seconds, identify_seconds=id_s, train_seconds=fit.seconds,
                          training_run_id=fit.run_id, train_val_rms_um=fit.metrics.get("val_rms_um"),
                          train_val_max_um=fit.metrics.get("val_max_um"), train_iterations=fit.metrics.get("iterations"),
                          compensate_seconds_per_point=ex["seconds_per_point"], true_rms_um=ex["true_rms_um"],
                          true_max_um=ex["true_max_um"], solvers={"exact": ex}))


def run_grinder(machine, s: BenchmarkSettings, tracker: Tracker) -> list[dict]:
    """Both paths on every grinder condition; rows in condition order."""
    g = GrinderBench(machine, s, tracker)
    for c in grinder_conditions(s):
        try:
            g.run_condition(c)
        except Exception as exc:  # the other conditions still run; the failure is a row
            _log(f"grinder: {c.name} failed: {type(exc).__name__}: {exc}")
            done = {r["path"] for r in g.rows if r["condition"].startswith(c.name)}
            for path in ("parametric", "learned"):
                if path not in done:
                    g.log.add(_row(machine.name, "grinder", path, c.name, available=False, group=c.group,
                                   not_available=f"condition failed: {type(exc).__name__}: {exc}"))
    if s.paper_network:
        try:
            g.paper_network_row()
        except Exception as exc:
            g.log.add(_row(machine.name, "grinder", "learned", "paper network", available=False, group="network",
                           not_available=f"failed: {type(exc).__name__}: {exc}"))
    return g.rows


# ------------------------------------------------------------------------------- PKM
def _rotvec(R) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_rotvec()


def _from_rotvec(v) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(v).as_matrix()


def _oriented(machine) -> bool:
    """Whether a pose of ``machine`` (a parallel machine) has a platform orientation (a hexapod's)."""
    return family_of(machine).facts.platform_orientation


def _tool(machine, tool_length_mm):
    if tool_length_mm is None or not _oriented(machine):
        return machine
    return replace(machine, tool_in_platform_mm=np.array([0.0, 0.0, -tool_length_mm]))


def pose_inputs(oriented: bool, tip_mm, R) -> np.ndarray:
    """Network inputs of commanded poses: with a platform orientation (a hexapod) tip and rotation vector, else
    (a tripod) the tip; (n, 6|3)."""
    return np.hstack([tip_mm, _rotvec(R)]) if oriented else np.asarray(tip_mm, float)


def measured_pose_errors(machine, data):
    """(inputs, outputs) for the learned PKM field from pose measurements (instrument frame = machine).

    Commanded pose: nominal forward kinematics of the commanded drives; error: measured minus
    commanded tip (μm), and for the hexapod the rotation vector of ``R_meas·R_cmdᵀ`` (μrad).
    """
    from errormap.pkm.hexapod import forward_kinematics
    fk = forward_kinematics(machine, machine.drive_to_legs(data.q), check_limits=False)
    d_tip = (data.tip_mm - fk.x) * 1e3
    if _oriented(machine):
        d_ang = _rotvec(np.einsum("nij,nkj->nik", data.rotation, fk.platform2base)) * 1e6
        return pose_inputs(True, fk.x, fk.platform2base), np.hstack([d_tip, d_ang])
    return pose_inputs(False, fk.x, None), d_tip


def learned_pkm_commands(field_, machine, tip_mm, R, tool_length_mm=None, iterations: int = 6):
    """Compensated commanded poses for target poses by iterating the commanded pose.

    The field predicts the pose error at the measurement tool (the machine file's); a path with
    another tool length (``tool_length_mm``) is handled exactly: the platform pose is the same,
    the tip moves by ``R·(t_path - t_meas)``. Fixed point: ``R_cmd = exp(-δθ(cmd))·R_d``,
    ``tip_cmd ← tip_cmd - (reached tip - target tip)``. Returns (tip_cmd (n,3), R_cmd (n,3,3)).
    """
    hexa = _oriented(machine)
    t_meas = machine.tool_in_platform_mm
    t_path = _tool(machine, tool_length_mm).tool_in_platform_mm
    tip_d = np.asarray(tip_mm, float)
    R_d = np.asarray(R, float) if hexa else None
    tip_c, R_c = tip_d.copy(), (R_d.copy() if hexa else None)
    for _ in range(iterations):
        if hexa:
            tip_meas = tip_c + np.einsum("nij,j->ni", R_c, t_meas - t_path)
            e = field_.predict(pose_inputs(True, tip_meas, R_c))
            dtip, dth = e[:, :3] * 1e-3, e[:, 3:] * 1e-6
            R_reach = _from_rotvec(dth) @ R_c
            reach = tip_meas + dtip + np.einsum("nij,j->ni", R_reach, t_path - t_meas)
            R_c = _from_rotvec(-dth) @ R_d
        else:
            reach = tip_c + field_.predict(pose_inputs(False, tip_c, None)) * 1e-3
        tip_c = tip_c - (reach - tip_d)
    return tip_c, R_c


def pkm_true_residual(truth, machine, tip_cmd, R_cmd, tip_target, tool_length_mm=None) -> np.ndarray:
    """True residual (μm), shape (n, 3): tip the truth machine reaches with the nominal inverse
    kinematics of the commanded poses, minus the target tip."""
    from errormap.pkm.hexapod import forward_kinematics, inverse_kinematics
    nom = _tool(machine, tool_length_mm)
    legs = inverse_kinematics(nom, tip_cmd, R_cmd if _oriented(machine) else None)
    q = nom.legs_to_drive(legs)
    tt = _tool(truth.machine, tool_length_mm)
    fk = forward_kinematics(tt, tt.drive_to_legs(q), guess_tip_mm=tip_target, guess_platform2base=R_cmd,
                            check_limits=False)
    return (fk.x - tip_target) * 1e3


def _pkm_paths(machine, s: BenchmarkSettings):
    from ...pkm_interpolation import PosePath, builtin_path
    if family_of(machine).facts.paper_paths:
        return {n: builtin_path(n, s.pkm_path_step_mm) for n in ("sphere", "hyperboloid")}
    from errormap.pkm.hexapod import workspace_poses
    tips, _ = workspace_poses(machine, 200 if not s.quick else 50, seed=_streams(s.seed)["pkm_paths"])
    return {"workspace": PosePath(tips, np.broadcast_to(np.eye(3), (len(tips), 3, 3)).copy(),
                                  np.zeros(len(tips), int), None, "workspace")}


def _pkm_conditions(s: BenchmarkSettings) -> dict:
    """``{(n_poses, noise_um): group}``: the pose-count and the noise series."""
    conditions = {}
    for n in s.pkm_poses:
        conditions.setdefault((n, s.pkm_base_noise_um), "poses")
    for nz in s.pkm_noises_um:
        conditions.setdefault((s.pkm_base_poses, nz), "noise")
    return conditions


def _pkm_parametric_row(machine, s: BenchmarkSettings, sim, paths, cname, common, unc) -> dict:
    """Regularised kinematic calibration -> corrected inverse kinematics; its true residual row."""
    from errormap.pkm.calibration import PKMCalibrator

    from ...pkm_interpolation import leg_program, true_path_residual
    kind = machine.kind
    try:
        t0 = time.perf_counter()
        cal = PKMCalibrator(machine, estimate_scales=True, register=False,
                            noise_um=max(common["noise_um"], 0.1)).fit(sim.data)
        fit_s = time.perf_counter() - t0
        per_path, allpos, comp_s, npts = {}, [], 0.0, 0
        for k, p in paths.items():
            t0 = time.perf_counter()
            leg_program(machine, p, cal.machine, check_limits=False)
            comp_s += time.perf_counter() - t0
            npts += len(p)
            r = true_path_residual(sim.truth, cal, p)
            per_path[k] = {"true_rms_um": r["rms_um"], "true_max_um": r["max_um"]}
            allpos.append(r["position_um"])
        st = residual_stats(np.concatenate(allpos))
        return _row(machine.name, kind, "parametric", cname, solver="corrected inverse kinematics",
                    fit_seconds=fit_s, compensate_seconds_per_point=comp_s / npts,
                    true_rms_um=st["rms_um"], true_max_um=st["max_um"],
                    per_path=per_path, calibration_success=bool(cal.success), calibration_lambda=float(cal.lam),
                    **common, **unc)
    except Exception as exc:
        return _row(machine.name, kind, "parametric", cname, available=False,
                    not_available=f"calibration failed: {type(exc).__name__}: {exc}", **common, **unc)


def _pkm_learned_row(machine, s: BenchmarkSettings, tracker: Tracker, sim, paths, cname, common, unc) -> dict:
    """Pose-error MLP -> iterated commanded pose; its true residual row."""
    from training.pose_field import fit_pose_field
    kind = machine.kind
    try:
        x, y = measured_pose_errors(machine, sim.data)
        fit = fit_pose_field(x, y, hidden=s.pkm_hidden, ridge=s.pkm_ridge, max_iter=s.pkm_train_iter,
                             max_time_s=math.inf if s.pkm_train_s is None else s.pkm_train_s, seed=s.seed)
        per_path, allpos, comp_s, npts = {}, [], 0.0, 0
        for k, p in paths.items():
            t0 = time.perf_counter()
            tip_c, R_c = learned_pkm_commands(fit.field, machine, p.tip_mm, p.platform2base, p.tool_length_mm)
            comp_s += time.perf_counter() - t0
            npts += len(p)
            err = pkm_true_residual(sim.truth, machine, tip_c, R_c, p.tip_mm, p.tool_length_mm)
            st = residual_stats(err)
            per_path[k] = {"true_rms_um": st["rms_um"], "true_max_um": st["max_um"]}
            allpos.append(np.linalg.norm(err, axis=1))
        st = residual_stats(np.concatenate(allpos))
        tr_id = tracker.child(f"{kind}/learned/train/{cname}", fit.params, fit.metrics,
                              {"benchmark_condition": cname})
        return _row(machine.name, kind, "learned", cname, solver="iterated commanded pose (6 steps)",
                    fit_seconds=fit.seconds, train_seconds=fit.seconds, training_run_id=tr_id,
                    train_rms_pos_um=fit.metrics["train_rms_pos_um"], train_iterations=fit.metrics["iterations"],
                    compensate_seconds_per_point=comp_s / npts,
                    true_rms_um=st["rms_um"], true_max_um=st["max_um"], per_path=per_path, **common, **unc)
    except Exception as exc:
        return _row(machine.name, kind, "learned", cname, available=False,
                    not_available=f"learned PKM path failed: {type(exc).__name__}: {exc}", **common, **unc)


def run_pkm(machine, s: BenchmarkSettings, tracker: Tracker, conditions=None) -> list[dict]:
    """Both PKM paths on each (n_poses, noise) condition; true residual along the test paths."""
    from errormap.pkm.simulate import simulate_poses

    from ...pkm_interpolation import true_path_residual
    kind, oriented = machine.kind, _oriented(machine)
    paths = _pkm_paths(machine, s)
    conditions = _pkm_conditions(s) if conditions is None else conditions
    rows = []
    for (n_poses, noise), group in conditions.items():
        cname = f"poses={n_poses}, noise={noise:g}um"
        sim = simulate_poses(machine, n_poses, noise, seed=_streams(s.seed)["pkm_poses"],
                             pose_error_mm=s.pkm_pose_error_mm, frame="identity",
                             half_width_mm=s.pkm_half_width_mm if oriented else (150.0, 150.0, 100.0),
                             max_tilt_deg=s.pkm_max_tilt_deg if oriented else 0.0,
                             orientation="quat" if oriented else "none")
        common = {"group": group, "n_poses": n_poses, "noise_um": noise, "n_measurements": n_poses,
                  "test_path": " + ".join(f"{k} ({len(p)} points)" for k, p in paths.items())}
        before = {k: true_path_residual(sim.truth, None, p) for k, p in paths.items()}
        unc = {"uncompensated_rms_um": residual_stats(np.concatenate([b["position_um"] for b in before.values()]))["rms_um"],
               "uncompensated_max_um": float(max(b["max_um"] for b in before.values()))}
        _log(f"{kind}: parametric, {cname}")
        rows.append(_pkm_parametric_row(machine, s, sim, paths, cname, common, unc))
        log_row(tracker, rows[-1])
        _log(f"{kind}: learned, {cname}")
        rows.append(_pkm_learned_row(machine, s, tracker, sim, paths, cname, common, unc))
        log_row(tracker, rows[-1])
        for r in rows[-2:]:
            if r["available"]:
                _log(f"  {r['path']:10s} {cname}: true RMS {r['true_rms_um']:.3f} um, max {r['true_max_um']:.3f} um")
    return rows


# ------------------------------------------------------------------------------- driver
def _bench_grinder(m, s, tracker, out_dir):
    return run_grinder(m, s, tracker), []


def _bench_pkm(m, s, tracker, out_dir):
    conds = None
    if not family_of(m).facts.paper_paths:  # one condition: the tripod has no paper test path
        conds = {(s.pkm_base_poses, s.pkm_base_noise_um): "baseline"}
    return run_pkm(m, s, tracker, conds), []


def _bench_chain(m, s, tracker, out_dir):
    """A chain file: the user's path per condition (workflows/chain_benchmark.py)."""
    from .chain_benchmark import run_chain
    log = RowLog(tracker)
    skipped = run_chain(m, s, log, out_dir, _row, _streams(s.seed), _log)
    return log.rows, skipped


def _bench_arm(m, s, tracker, out_dir):
    """An arm: simulate → calibrate → compensate per condition (workflows/arm_benchmark.py)."""
    from .arm_benchmark import run_arm
    log = RowLog(tracker)
    run_arm(m, s, log, out_dir, _row, _log)
    return log.rows, []


BENCH_BY_TARGET = {"grinder": _bench_grinder, "parallel": _bench_pkm, "chain": _bench_chain, "arm": _bench_arm}
"""Each family's benchmark (its registry target, :mod:`compensation.app.families`):
``(machine, settings, tracker, out_dir) -> (rows, skipped)``."""


def run_benchmark(machines, out_dir, settings: BenchmarkSettings | None = None, tracking_uri: str | None = None,
                  track: bool = True) -> dict:
    """Run the benchmark on ``machines`` (loaded machine objects) and write the outputs.

    Returns the ``benchmark.json`` document (``rows``, ``settings``, ``environment``, ``paths``).
    """
    from ..reports.benchmark import render_html
    s = settings or BenchmarkSettings()
    for m in machines:  # a kind no family holds, or one that does not run it: refused before any work
        try:
            family_of(m).target("benchmark")
        except ValueError as exc:
            from ..validate import UsageError
            raise UsageError(f"benchmark: machine {m.name!r} ({getattr(m, 'path', '') or 'built in'}): {exc}") from None
    out = Path(out_dir)
    t_start = time.perf_counter()
    tracker = Tracker(tracking_uri, enabled=track, run_name="benchmark (quick)" if s.quick else "benchmark")
    tracker.log_params({f"settings.{k}": v for k, v in s.to_dict().items()})
    rows, skipped = [], []
    status = "FAILED"
    from errormap.threads import limit_threads
    try:
        with limit_threads(s.torch_threads):
            rows, skipped = _run_machines(machines, s, tracker, out)
        total_s = time.perf_counter() - t_start
        doc = {"format": "volcomp-benchmark/1", "rows": rows, "skipped": skipped, "settings": s.to_dict(),
               "path_conditions": PATH_CONDITIONS, "seconds": total_s, "parent_run_id": tracker.parent_id,
               "tracking_uri": getattr(tracker, "uri", None),
               "environment": {"python": platform.python_version(), "machine": platform.machine(),
                               "cpus": _cpus()},
               "residual": "true residual (simulated truth machine driven with the compensated commands, minus the "
                           "target), vector norm per point, um",
               "machines": [{"name": m.name, "kind": m.kind, "file": getattr(m, "path", ""),
                             "sha256": getattr(m, "sha256", "")} for m in machines]}
        out.mkdir(parents=True, exist_ok=True)
        json_path = write_json(out / "benchmark.json", doc)
        from errormap.io import atomic_write
        html_path = out / "report.html"
        page = render_html(doc)
        with atomic_write(html_path, "w", encoding="utf-8") as fh:
            fh.write(page)
        doc["paths"] = {"json": str(json_path), "html": str(html_path)}
        status = "FINISHED"
        avail = [r for r in rows if r["available"]]
        tracker.finish({"seconds": total_s, "rows": len(rows), "rows_available": len(avail)},
                       artifacts=(json_path, html_path), status=status)
        return doc
    finally:
        if status != "FINISHED":
            try:
                tracker.finish({}, status="FAILED")
            except Exception:  # pragma: no cover - keep the original error
                pass


def _run_machines(machines, s: BenchmarkSettings, tracker: Tracker, out_dir):
    rows, skipped = [], []
    for m in machines:
        t0 = time.perf_counter()
        r, k = BENCH_BY_TARGET[family_of(m).target("benchmark")](m, s, tracker, out_dir)
        rows += r
        skipped += k
        _log(f"{m.kind} done in {time.perf_counter() - t0:.0f} s")
    return rows, skipped


def _cpus() -> int:
    import os
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 0
