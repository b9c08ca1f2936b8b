"""What every row set of ``volcomp benchmark`` shares: the settings, the seeded streams, the MLflow tracker (one
parent run, a child run per row), the row record and its log (:mod:`compensation.app.workflows.benchmark`)."""
from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from errormap.seeds import spawn_seeds

PATH_CONDITIONS = {"temp_c": 24.0, "time_s": 7200.0, "dir_x": 1.0, "dir_z": -1.0, "dir_a": 1.0}
"""Conditions of the flute test path: a warm machine (24 °C, 2 h after the start of the warm-up
the check log records), X and A approached in the path's direction of motion (+), Z from above
(the wheel plunges in to the flute-bottom radius)."""

EXPERIMENT = "volcomp-benchmark"
USER_LOOP = ("the user's path: volcomp identify (smoothing, covariance) → volcomp diagnose (element update + effects; "
             "on an out-of-catalogue condition + learned residual backfitted with the update, re-estimated on all checks)")
"""Which loop a row ran (key ``loop_method``): every machine tool's closed loop."""
FEATURE_REUSE_TOL_UM = 1e-6



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
    # effects no catalogue kind represents (errormap.effect_kinds.TRUTH_ONLY), each with the closed
    # loop and its learned-residual stage (the hybrid column); plus the same machine without an effect
    ooc_effects: tuple = ("bump", "a_tilt", "squareness", "a_lobe_x")
    # check counts of the out-of-catalogue conditions (each effect and none at every count: the learned
    # stage's estimation error against the number of checks; `volcomp benchmark --checks N`, repeatable)
    ooc_checks: tuple = (800, 150, 1600)
    # every closed loop runs the user's path: `volcomp identify` (smoothing, covariance Gauss-Newton's, or from
    # this many residual-bootstrap draws) → `volcomp diagnose` (workflows/measurement.py)
    identify_bootstrap: int | None = None
    n_checks: int = 400
    check_noise_um: float = 1.0
    train_iter: int = 150                  # LM iterations per learned machine-tool condition (~30 s on 2 cores)
    train_s: float | None = None           # optional wall-clock limit on top (off: results depend on the load)
    hidden: tuple = (10, 15, 25, 15, 10)   # the paper's network (LM + off-grid model selection)
    activation: str = "sigmoid"
    a_encoding: str = "raw"
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
    chain_path_points: int = 100           # machine tools: points per body diagonal (4) or turning line (2)
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
                             train_iter=60, hidden=(8, 8), activation="tanh", a_encoding="periodic",
                             ga_points=20, ga_generations=100, flute_turns=1.0, flute_points_per_turn=200,
                             volume_points=50,
                             pkm_poses=(50,), pkm_noises_um=(5.0,), pkm_base_poses=50, pkm_train_iter=50,
                             pkm_path_step_mm=4.0, chain_path_points=25, arm_effects=(("sag",),),
                             arm_poses=200, arm_checks=50, arm_learned=False, quick=True)


def say(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# sub-streams of the run's seed (errormap.seeds), one per consumer; the same child for every
# condition, so that the conditions see the same draws where their shapes agree
STREAMS = ("volume_points", "sweep_noise", "validation", "selection", "checks", "pkm_paths", "pkm_poses")


def rng_streams(seed: int) -> dict:
    """``{consumer: SeedSequence}``: the children of ``SeedSequence(seed)`` named by :data:`STREAMS`."""
    return dict(zip(STREAMS, spawn_seeds(seed, len(STREAMS))))


def bench_row(machine, kind, path, condition, **kw) -> dict:
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


class RowLog:
    """The result rows in order: each is recorded in MLflow (:func:`log_row`) and logged."""

    def __init__(self, tracker: Tracker):
        self.tracker, self.rows = tracker, []

    def add(self, row: dict) -> None:
        log_row(self.tracker, row)
        self.rows.append(row)
        if row.get("available"):
            say(f"  {row['path']:10s} {row['condition']}: true RMS {row['true_rms_um']:.3f} um, max "
                 f"{row['true_max_um']:.3f} um, fit {row['fit_seconds']:.1f} s")


def scored(sol: dict) -> dict:
    """A row's head figures from one solver's TRUE-residual result: RMS, max and seconds per point."""
    return {"true_rms_um": sol["true_rms_um"], "true_max_um": sol["true_max_um"],
            "compensate_seconds_per_point": sol["seconds_per_point"]}


def with_volume(row: dict, vol) -> dict:
    if vol:
        row.update(volume_rms_um=vol["true_rms_um"], volume_max_um=vol["true_max_um"])
    return row
