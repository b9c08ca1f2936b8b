"""Trainers for the error-field network and ``fit_field``, the one call that trains and tracks.

Three trainers share one contract, ``train(model, theta0, u, y, settings, callback) -> (theta,
TrainHistory)`` on scaled features ``u`` and scaled targets ``y``, and the stopping rules (MSE goal on the
scaled outputs, iteration cap, wall-clock budget): ``lm`` (Levenberg–Marquardt, :mod:`training.lm`, the
paper's and the default, from Nguyen–Widrow initial weights, :func:`nguyen_widrow_params`), ``adam`` and
``lbfgs`` (full batch, for comparison). ``fit_field`` scales the data, trains, measures the fit in μm on the
training and on validation points, and records everything as an MLflow run (:mod:`training.tracking`)."""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from errormap.io import OUTPUT_LOCK_NAME, InputError
from errormap.progress import Progress
from errormap.seeds import spawn_seeds
from errormap.stats import residual_stats
from errormap.threads import limit_threads

from . import DEFAULT_MAX_ITER
from .lm import LMSettings, TrainHistory, stop_reason, train_lm
from .model import (A_ENCODINGS, ACTIVATIONS, PAPER_HIDDEN, MLPField, PhysicsMLPField, periodic_columns,
                    uses_fused_network)
from .physics import MAX_STATIONS, MIN_STATIONS, PHYSICS

TRAINERS = ("lm", "adam", "lbfgs")
VALIDATION_STREAM, SELECTION_STREAM = 0, 1  # children of SeedSequence(seed): validation, selection points
AXES = ("dx", "dy", "dz")


def train_adam(model, theta0, u, y, settings: LMSettings | None = None, callback=None, lr: float = 3e-3):
    """Full-batch Adam with a learning rate halved on 500-iteration plateaus; same stopping rules as LM."""
    s = settings or LMSettings()
    theta = theta0.clone().requires_grad_(True)
    opt = torch.optim.Adam([theta], lr=lr)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=500, min_lr=1e-7)
    h = TrainHistory()
    t0 = time.perf_counter()
    best, best_theta = math.inf, theta0.clone()
    while True:
        opt.zero_grad(set_to_none=True)
        loss = torch.mean((model.forward(theta, u) - y) ** 2)
        mse = float(loss.detach())
        if mse < best:
            best, best_theta = mse, theta.detach().clone()
        reason = stop_reason(s, h, mse, t0)
        if reason:
            h.stop_reason = reason
            break
        loss.backward()
        opt.step()
        sched.step(mse)
        h.record(mse, t0, callback, opt.param_groups[0]["lr"])
    h.seconds = time.perf_counter() - t0
    return best_theta, h


def train_lbfgs(model, theta0, u, y, settings: LMSettings | None = None, callback=None):
    """Full-batch L-BFGS (strong-Wolfe line search, history 50); one iteration = one optimizer step."""
    s = settings or LMSettings()
    theta = theta0.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([theta], lr=1.0, max_iter=20, history_size=50, line_search_fn="strong_wolfe",
                            tolerance_grad=0.0, tolerance_change=0.0)

    def closure():
        opt.zero_grad(set_to_none=True)
        loss = torch.mean((model.forward(theta, u) - y) ** 2)
        loss.backward()
        return loss

    h = TrainHistory()
    t0 = time.perf_counter()
    with torch.no_grad():
        mse = float(torch.mean((model.forward(theta, u) - y) ** 2))
    while True:
        reason = stop_reason(s, h, mse, t0)
        if reason:
            h.stop_reason = reason
            break
        opt.step(closure)
        with torch.no_grad():
            new = float(torch.mean((model.forward(theta, u) - y) ** 2))
        h.record(new, t0, callback)
        if not math.isfinite(new) or new >= mse:
            mse = min(mse, new)
            h.stop_reason = "no further decrease"
            break
        mse = new
    h.seconds = time.perf_counter() - t0
    return theta.detach(), h


TRAIN_FUNCS = {"lm": train_lm, "adam": train_adam, "lbfgs": train_lbfgs}

INITS = ("nguyen-widrow", "uniform")
# active input range of each hidden activation: where its slope is not negligible (MATLAB's
# logsig/tansig 'active' ranges); softplus is given tanh's
_ACTIVE = {"sigmoid": 4.0, "tanh": 2.0, "softplus": 2.0}
# output range of each hidden activation, the next layer's input range
_OUT_RANGE = {"sigmoid": (0.0, 1.0), "tanh": (-1.0, 1.0), "softplus": (0.0, 1.0)}


def nguyen_widrow_params(model, seed: int = 0) -> torch.Tensor:
    """Nguyen–Widrow initial parameters (MATLAB ``initnw``), from a seeded generator, float64.

    Every hidden layer of ``s`` units with ``k`` inputs: weight rows of random direction and
    length ``0.7·s^(1/k)``, biases spread evenly over ``[-0.7·s^(1/k), 0.7·s^(1/k)]`` (sign of the
    first weight), so that the units' active regions tile the input range; then mapped to the
    activation's active range (±4 for the sigmoid) and to the layer's input range (the scaled
    inputs' [-1, 1] for the first layer, the previous activation's output range after).
    The linear output layer: uniform in ``±1/sqrt(fan_in)`` (PyTorch's default), biases 0.
    """
    g = torch.Generator().manual_seed(int(seed))
    sizes = model.layer_sizes
    act = model.activation
    parts = []
    for i in range(len(sizes) - 1):
        k, sz = sizes[i], sizes[i + 1]
        if i == len(sizes) - 2:
            bound = 1.0 / math.sqrt(k)
            W = (torch.rand(sz, k, generator=g, dtype=torch.float64) * 2 - 1) * bound
            parts += [W.reshape(-1), torch.zeros(sz, dtype=torch.float64)]
            continue
        mag = 0.7 * sz ** (1.0 / k)
        W = torch.rand(sz, k, generator=g, dtype=torch.float64) * 2 - 1
        W = mag * W / W.norm(dim=1, keepdim=True).clamp_min(1e-12)
        b = mag * torch.linspace(-1.0, 1.0, sz, dtype=torch.float64) * torch.sign(W[:, 0]) if sz > 1 \
            else torch.zeros(1, dtype=torch.float64)
        x = _ACTIVE[act]
        W, b = x * W, x * b
        lo, hi = (-1.0, 1.0) if i == 0 else _OUT_RANGE[act]
        sc = 2.0 / (hi - lo)
        off = 1.0 - hi * sc          # input v maps to sc*v + off in [-1, 1]
        b = W @ torch.full((k,), off, dtype=torch.float64) + b
        W = W * sc
        parts += [W.reshape(-1), b]
    return torch.cat(parts)


def initial_params(model, seed: int = 0, init: str = "nguyen-widrow") -> torch.Tensor:
    """Initial flat parameters: ``nguyen-widrow`` (:func:`nguyen_widrow_params`) or ``uniform``
    (:meth:`MLPField.init_params`, PyTorch's bounds ×4 for the sigmoid)."""
    if init == "nguyen-widrow":
        return nguyen_widrow_params(model, seed)
    if init == "uniform":
        return model.init_params(seed)
    raise ValueError(f"Expected init in {INITS}, got {init!r}")


# -- metrics and validation ---------------------------------------------------------------
def fit_metrics(prefix: str, predicted_um, reference_um) -> dict:
    """Max |error| and RMS in μm, over all components and per axis; also the max vector norm."""
    st = residual_stats(np.asarray(predicted_um) - np.asarray(reference_um), AXES)
    # over all components: the largest per-axis max |.|, and RMS = sqrt(mean of the per-axis RMS²)
    m = {f"{prefix}_max_um": max(st[a]["max_abs_um"] for a in AXES),
         f"{prefix}_rms_um": float(np.sqrt(np.mean([st[a]["rms_um"] ** 2 for a in AXES]))),
         f"{prefix}_max_norm_um": st["max_um"]}
    for a in AXES:
        m[f"{prefix}_max_{a}_um"] = st[a]["max_abs_um"]
        m[f"{prefix}_rms_{a}_um"] = st[a]["rms_um"]
    return m


def validation_points(machine, elements_or_field, n: int = 10_000, seed: int = 12345):
    """``n`` random points uniform over the whole working volume and their errors from the model.

    ``elements_or_field``: an :class:`~errormap.chain_elements.ChainElementSet` (evaluated with the exact
    HTM model) or any object with ``predict``. Returns ``(axes shape (n, 3), errors shape (n, 3) μm)``.
    Uniform random points lie off the feature-point grid with probability one.
    """
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    from errormap.chain_truth import random_axes
    f = ChainField(machine, elements_or_field) if isinstance(elements_or_field, ChainElementSet) else elements_or_field
    axes = random_axes(machine, int(n), np.random.default_rng(seed))
    return axes, f.predict(axes)


def chain_reference(machine, meta: dict):
    """(machine, its element set's field) named in the feature points' ``elements_file``, or None."""
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    el = meta.get("elements_file")
    if not el or not Path(el).is_file():
        return None
    return machine, ChainField(machine, ChainElementSet.load(el, machine))


def zero_network(model) -> None:
    """Make the network part of ``model`` output exactly zero μm (last layer and output mean zeroed):
    a :class:`PhysicsMLPField` is then its physical part alone."""
    (o, n_in), _ = model.shapes[-2], model.shapes[-1]
    theta = model.theta_.detach().clone()
    theta[-(o * n_in + o):] = 0.0
    model.theta_ = theta
    model.out_mean_ = np.zeros(3)


def keep_physics_alone(model, selector, sel_residual_um) -> bool:
    """A physics-first ``model`` whose network makes the selection points worse than its physical
    part alone (``sel_residual_um``: what the physical part leaves there, (k, 3) μm) has its network
    zeroed (:func:`zero_network`): never return worse than that plain baseline. True when zeroed."""
    if selector is None or selector.best_max_um <= float(np.abs(sel_residual_um).max()):
        return False
    zero_network(model)
    return True


def physics_metrics(model, axes, errors_um, val_axes, val_errors_um) -> dict:
    """The physical part of a physics-first ``model`` alone, on the training and validation points
    (``physics_train_*``, ``physics_val_*``, μm): what the network added beside it."""
    m = fit_metrics("physics_train", model.physics_predict(axes), errors_um)
    m.update(fit_metrics("physics_val", model.physics_predict(val_axes), val_errors_um))
    return m


def machine_from_meta(meta: dict):
    """The machine tool feature points without a given machine were made on: their ``machine_file``, else the
    built-in default machine (the grinder's columns, what a feature-point file without ``axis_columns`` holds)."""
    from errormap.machine import load_machine, made_on
    mf = meta.get("machine_file") or None
    if mf and not Path(mf).is_file() and (meta.get("machine_sha256") in (None, "")
                                          or made_on(load_machine(), meta.get("machine_sha256"))):
        mf = None
    return load_machine(mf, expect_kind="machine-tool" if mf else None)


def data_hash(axes, errors) -> str:
    """SHA-256 of the training data (float64 bytes of axes then errors)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(axes, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(errors, dtype=np.float64).tobytes())
    return h.hexdigest()


RUN_FOLDER_FILES = ("model", "metrics.json", "fit_error_xz.png", "fit_featurepoints.png")


def check_run_folder(out_dir) -> None:
    """Refuse an existing ``out_dir`` that holds anything a training run did not write: the run
    folder is replaced as a whole, so nothing else may live in it."""
    d = Path(out_dir)
    if d.exists() and not d.is_dir():
        raise InputError(f"{d}: expected a folder for the training run, got a file")
    if d.is_dir():
        foreign = sorted(p.name for p in d.iterdir() if p.name not in RUN_FOLDER_FILES + (OUTPUT_LOCK_NAME,))
        if foreign:
            raise InputError(f"{d}: the training run replaces this folder whole, and it holds files a run did not "
                             f"write ({', '.join(foreign[:5])}{', ...' if len(foreign) > 5 else ''}); give a new or "
                             "empty folder")


# -- fit_field ----------------------------------------------------------------------------
@dataclass
class FitResult:
    """What ``fit_field`` returns: the trained field, metrics (μm), MLflow run id, seconds."""

    field: MLPField
    metrics: dict
    run_id: str | None
    seconds: float
    history: TrainHistory = field(default_factory=TrainHistory)
    params: dict = field(default_factory=dict)


class _BestOnSelection:
    """LM monitor: remembers the iterate with the smallest max |error| (μm) on selection points;
    with ``patience`` > 0 it stops training once that error has not improved for ``patience``
    accepted steps (the iterate it keeps is then the one a longer run would keep, unless the
    error falls below the kept one again later)."""

    def __init__(self, model, axes, errors_um, every: int, patience: int = 0):
        self.model, self.every = model, max(int(every), 1)
        self.patience = max(int(patience), 0)
        self.u = torch.from_numpy(model.features(axes))
        self.errors_um = np.asarray(errors_um, float)
        self.best_max_um, self.best_iteration, self.best_theta = math.inf, 0, None

    def _max_um(self, theta) -> float:
        with torch.no_grad():
            pred = self.model.unscale_errors(self.model.forward(theta, self.u).numpy())
        return float(np.abs(pred - self.errors_um).max())

    def __call__(self, iteration, theta):
        if iteration % self.every == 0:
            e = self._max_um(theta)
            if e < self.best_max_um:
                self.best_max_um, self.best_iteration, self.best_theta = e, iteration, theta.detach().clone()
            elif self.patience and iteration - self.best_iteration >= self.patience:
                return (f"selection error not improved in {self.patience} iterations "
                        f"(best {self.best_max_um:.4g} μm at iteration {self.best_iteration})")
        return ""

    def finish(self, theta, hist):
        """The best iterate, the final one included."""
        e = self._max_um(theta)
        if e <= self.best_max_um:
            self.best_max_um, self.best_iteration, self.best_theta = e, hist.iterations, theta.detach().clone()
        return self.best_theta


class _Printer:
    """Trainer callback: a :class:`~errormap.progress.Progress` over the iterations, with the
    loss and the RMS in μm beside it (drawn on a terminal only)."""

    def __init__(self, scale_um: float, quiet: bool, label: str, max_iter: float):
        self.scale_um = scale_um
        self.bar = Progress(max_iter, label, enabled=not quiet)

    def __call__(self, it, mse, el, extra):
        self.bar.update(it - self.bar.done, extra=f"mse {mse:.3e} rms≈{math.sqrt(mse) * self.scale_um:.4f} μm")

    def close(self):
        self.bar.close()


@dataclass(frozen=True)
class TrainSettings:
    """Everything that decides the trained network, validated here once.

    Training stops on ``max_iter`` iterations or the goals (``mse_goal`` on the scaled outputs,
    ``max_err_goal_um`` on the largest training |error|, LM only; 0 = off) by default, so the
    same settings give the same model on any machine; ``max_time_s`` (default off) adds a
    wall-clock budget, and a run it stops records the iterations reached.
    ``lm_settings``: damping/scaling/acceleration of the LM trainer (default :class:`LMSettings`);
    its stopping rules are replaced by the ones here. ``select_best`` (LM only): keep the iterate
    with the smallest max |error| on ``n_select`` selection points, checked every
    ``select_every`` accepted steps (see :func:`fit_field`); ``select_patience`` (> 0, LM with
    selection only): stop once that error has not improved for this many accepted steps (early
    stopping; 0 = off, the default, so ``max_iter`` or the goals decide). ``threads``: torch threads.
    ``baseline_gate`` (default on): a network whose validation RMS is not below the plain OLS baseline's is
    refused; off, it is returned with ``beats_baseline`` false in its metrics (a study of the trainer itself).
    """

    trainer: str = "lm"
    max_iter: int = DEFAULT_MAX_ITER
    max_time_s: float = math.inf
    mse_goal: float = 2.5e-10
    max_err_goal_um: float = 0.0
    seed: int = 0
    hidden: tuple = PAPER_HIDDEN
    activation: str = "sigmoid"
    a_encoding: str = "raw"
    init: str = "nguyen-widrow"
    lm_settings: LMSettings | None = None
    n_validation: int = 10_000
    select_best: bool = True
    n_select: int = 5_000
    select_every: int = 5
    select_patience: int = 0
    threads: int | None = None
    physics: str = "none"
    physics_stations: int | None = None
    baseline_gate: bool = True

    def __post_init__(self):
        for name, allowed in (("physics", PHYSICS), ("trainer", TRAINERS), ("init", INITS),
                              ("activation", sorted(ACTIVATIONS)), ("a_encoding", A_ENCODINGS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"Expected {name} in {allowed}, got {getattr(self, name)!r}")
        if self.physics_stations is not None and not (
                int(self.physics_stations) == self.physics_stations and MIN_STATIONS <= self.physics_stations <= MAX_STATIONS):
            raise ValueError(f"Expected physics_stations in [{MIN_STATIONS}, {MAX_STATIONS}] (an integer) or None, "
                             f"got {self.physics_stations}")
        if self.physics_stations is not None and self.physics == "none":
            raise ValueError("Expected physics_stations only with physics 'first-order' (--physics first-order): "
                             "with physics 'none' there is no element set to place stations on")
        if not (self.max_time_s > 0):
            raise ValueError(f"Expected max_time_s > 0, got {self.max_time_s}")
        if not (int(self.max_iter) == self.max_iter and self.max_iter >= 1):
            raise ValueError(f"Expected max_iter >= 1 (an integer), got {self.max_iter}")
        hidden = tuple(self.hidden)
        if not hidden or any(int(h) != h or h < 1 for h in hidden):
            raise ValueError(f"Expected hidden layer widths >= 1, got {self.hidden!r}")
        object.__setattr__(self, "hidden", tuple(int(h) for h in hidden))
        for name in ("n_validation", "n_select", "select_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"Expected {name} >= 1, got {getattr(self, name)}")
        if not (int(self.select_patience) == self.select_patience and self.select_patience >= 0):
            raise ValueError(f"Expected select_patience >= 0 (an integer; 0 = off), got {self.select_patience}")

    def lm(self, out_scale_um: float) -> LMSettings:
        """The trainer's settings: ``lm_settings`` with this object's stopping rules (scaled outputs)."""
        return dataclasses.replace(self.lm_settings or LMSettings(), mse_goal=self.mse_goal, max_iter=self.max_iter,
                                   max_time_s=self.max_time_s,
                                   max_abs_goal=max(float(self.max_err_goal_um), 0.0) / out_scale_um)


@dataclass(frozen=True)
class TrackSettings:
    """Where and how a fit is recorded in MLflow (``track=False``: not at all)."""

    track: bool = True
    tracking_uri: str | None = None
    run_name: str | None = None
    parent_run_id: str | None = None
    tags: dict | None = None
    experiment: str = "volcomp-field"


_TRAIN_FIELDS = {f.name for f in dataclasses.fields(TrainSettings)}
_TRACK_FIELDS = {f.name for f in dataclasses.fields(TrackSettings)}


def _settings(settings, tracking, overrides) -> tuple[TrainSettings, TrackSettings]:
    unknown = set(overrides) - _TRAIN_FIELDS - _TRACK_FIELDS
    if unknown:
        raise TypeError(f"fit_field() got unexpected keyword arguments {sorted(unknown)}")
    s = dataclasses.replace(settings or TrainSettings(), **{k: v for k, v in overrides.items() if k in _TRAIN_FIELDS})
    t = dataclasses.replace(tracking or TrackSettings(), **{k: v for k, v in overrides.items() if k in _TRACK_FIELDS})
    return s, t


def fit_field(featurepoints, settings: TrainSettings | None = None, *, machine=None, validation=None,
              selection=None, tracking: TrackSettings | None = None, out_dir=None, quiet: bool = False,
              **overrides) -> FitResult:
    """Train the network over a machine tool's axes on its feature points (:func:`network_for`), hold it against
    the plain OLS baseline and record it as an MLflow run; the same path for every machine tool.

    ``featurepoints``: :class:`errormap.featurepoints.FeaturePoints` (axes (n, k), errors (n, 3) μm, meta).
    ``machine``: the machine tool they were made on (None: :func:`machine_from_meta`).
    ``settings``: :class:`TrainSettings`; ``tracking``: :class:`TrackSettings`. Keyword ``overrides`` name
    fields of either (``fit_field(fp, max_iter=60, track=False)``) and go through the same validation.
    ``validation``: ``(axes (m, k), errors (m, 3) μm)``; when None, ``n_validation`` random off-grid points of
    the element set named in the feature points' meta (``elements_file``), InputError if there is none.
    ``out_dir``: also save the model, the fit plots and ``metrics.json`` there (written as a set).
    ``selection`` (for ``select_best``): ``(axes (s, k), errors (s, 3) μm)``, never the validation data; by
    default random off-grid points of the same model from another stream of the seed. Selection keeps the
    iterate best over the volume, not on the grid (docs/reference/learned-stage.md); off without a reference
    and with ``select_best=False``. A network whose validation RMS is not below the OLS baseline's is refused
    (InputError, nothing written; ``baseline_gate=False``: returned, ``beats_baseline`` false)."""
    s, t = _settings(settings, tracking, overrides)
    if out_dir is not None:
        check_run_folder(out_dir)
    axes, errors = np.asarray(featurepoints.axes, float), np.asarray(featurepoints.errors_um, float)
    meta, source = dict(getattr(featurepoints, "meta", {}) or {}), getattr(featurepoints, "source", "")
    machine = machine if machine is not None else machine_from_meta(meta)
    if tuple(featurepoints.axis_columns) != tuple(machine.axis_columns):
        raise InputError(f"{source or 'feature points'}: axis columns "
                         f"{', '.join(featurepoints.axis_columns)}; the machine {machine.name!r} has "
                         f"{', '.join(machine.axis_columns)}")
    ref = chain_reference(machine, meta)
    # the initial weights use the seed itself; validation and selection points its children
    streams = spawn_seeds(s.seed, 2)
    (val_axes, val_errors), val_source = _validation_data(s, validation, ref, meta, streams[VALIDATION_STREAM],
                                                          source, machine)
    t0 = time.process_time()
    model, target = _model_and_target(machine, axes, errors, s)
    selector = sel_errors = None
    if s.select_best and s.trainer == "lm" and (selection is not None or ref is not None):
        sel_axes, sel_errors = (tuple(np.asarray(v, float) for v in selection) if selection is not None
                                else validation_points(*ref, n=s.n_select, seed=streams[SELECTION_STREAM]))
        if s.physics != "none":
            sel_errors = sel_errors - model.physics_predict(sel_axes)
        selector = _BestOnSelection(model, sel_axes, sel_errors, s.select_every, s.select_patience)
    hist = _train(model, axes, target, s, selector, quiet)
    physics_kept_alone = s.physics != "none" and keep_physics_alone(model, selector, sel_errors)
    metrics = fit_metrics("train", model.predict(axes), errors)
    metrics.update(fit_metrics("val", model.predict(val_axes), val_errors))
    if s.physics != "none":
        metrics.update(physics_metrics(model, axes, errors, val_axes, val_errors))
    # the plain baseline beside the network, on the same validation points
    base = fit_metrics("val", ols_baseline(periodic_axes(machine, s.a_encoding), axes, errors, val_axes), val_errors)
    metrics.update({"baseline_ols_val_max_um": base["val_max_um"], "baseline_ols_val_rms_um": base["val_rms_um"],
                    "beats_baseline": bool(metrics["val_rms_um"] < base["val_rms_um"]),
                    "train_cpu_seconds": time.process_time() - t0,
                    "final_mse_scaled": hist.loss[-1] if hist.loss else float("nan"),
                    "iterations": hist.iterations, "train_seconds": hist.seconds})
    if selector is not None:
        metrics.update({"selected_iteration": selector.best_iteration, "selection_max_um": selector.best_max_um})
    if s.physics != "none":
        metrics["physics_alone_kept"] = physics_kept_alone
    if s.baseline_gate and not metrics["beats_baseline"]:
        raise InputError(f"{source or 'feature points'}: the trained network's validation RMS "
                         f"{metrics['val_rms_um']:.4g} μm is not below the plain OLS baseline's "
                         f"{metrics['baseline_ols_val_rms_um']:.4g} μm ({val_source}); model not written "
                         "(more feature points, iterations or another network)")
    params = _fit_params(model, s, machine, meta, hist, axes, errors, len(val_axes), val_source, selector is not None)
    run_id = None
    if t.track or out_dir is not None:
        run_id = _write_run(model, axes, errors, ref, metrics, params, hist, s, t, machine, out_dir)
    return FitResult(model, metrics, run_id, hist.seconds, hist, params)


def periodic_axes(machine, a_encoding: str = "raw") -> list:
    """One flag per axis of ``machine``: fed to a network as (cos, sin) — a full-turn rotary axis (the
    fused network's: only with ``a_encoding="periodic"``), a rotary axis short of a turn with ``"periodic"``."""
    fused = uses_fused_network(machine)
    return [a.kind == "rotary" and ((a.full_turn and not fused) or a_encoding == "periodic") for a in machine.axes]


def a_encoding_applies(machine) -> bool:
    """Whether ``a_encoding`` changes the network of ``machine``: a rotary axis whose input is raw by default."""
    return uses_fused_network(machine) or any(a.kind == "rotary" and not a.full_turn for a in machine.axes)


def network_for(machine, s: TrainSettings):
    """The untrained network over ``machine``'s axes (settings ``s``, :meth:`MLPField.for_machine`); its
    physics-first form (:class:`PhysicsMLPField`) with ``s.physics``."""
    return (PhysicsMLPField if s.physics != "none" else MLPField).for_machine(
        machine, s.a_encoding, hidden=s.hidden, activation=s.activation)


def ols_baseline(periodic, train_axes, train_errors_um, eval_axes) -> np.ndarray:
    """The plain baseline an engineer tries first: ordinary least squares of each error component on
    the axis columns (affine; an axis flagged in ``periodic`` as cos/sin, as the network takes it), fitted on
    the training points and evaluated at ``eval_axes``; (m, k) -> (m, 3) μm."""
    def design(a):
        return np.column_stack([np.ones(len(a))] + periodic_columns(periodic, a, a))
    coef = np.linalg.lstsq(design(np.asarray(train_axes, float)), np.asarray(train_errors_um, float), rcond=None)[0]
    return design(np.asarray(eval_axes, float)) @ coef


def _model_and_target(machine, axes, errors_um, s: TrainSettings):
    """The untrained network (:func:`network_for`, scalers fitted) and what it learns: the feature points'
    errors (``physics="none"``), or what the element set fitted to the same points leaves (``"first-order"``,
    :mod:`training.physics`)."""
    model = network_for(machine, s)
    target = errors_um
    if s.physics != "none":
        from .physics import fit_physics_elements
        model.set_physics(machine, fit_physics_elements(machine, axes, errors_um, s.physics_stations))
        target = errors_um - model.physics_predict(axes)
    model.fit_scalers(axes, target)
    return model, target


def no_validation_message(source, meta: dict, columns) -> str:
    """The refusal of a fit without validation data: the feature-point file and the element set its header names."""
    el = meta.get("elements_file")
    why = f"the elements_file its header names, {Path(el).name}, is not beside it" if el else "its header names no elements_file"
    return (f"{source or 'feature points'}: no validation data ({why}); pass validation points (--validation FILE "
            f"with {', '.join(columns)}, dx_um, dy_um, dz_um)")


def _validation_data(s: TrainSettings, validation, ref, meta: dict, seed, source, machine):
    """``((axes, errors), source)``: the given validation points, or random ones of the reference model."""
    if validation is not None:
        return tuple(np.asarray(v, float) for v in validation), "given"
    if ref is None:
        raise InputError(no_validation_message(source, meta, machine.axis_columns))
    source = (f"element set {meta.get('elements_file')} "
              f"({s.n_validation} random points, SeedSequence({s.seed}) child {VALIDATION_STREAM})")
    return validation_points(ref[0], ref[1], n=s.n_validation, seed=seed), source


def _train(model, axes, errors, s: TrainSettings, selector, quiet: bool) -> TrainHistory:
    """Run the trainer on the scaled data; sets ``model.theta_`` (the selected iterate, if any)."""
    settings = s.lm(model.out_scale_)
    u = torch.from_numpy(model.features(axes))
    y = torch.from_numpy(model.scale_errors(errors))
    theta0 = initial_params(model, s.seed, s.init)
    printer = _Printer(model.out_scale_, quiet, f"train {s.trainer}", settings.max_iter)
    with limit_threads(s.threads):
        if selector is not None:
            theta, hist = train_lm(model, theta0, u, y, settings, printer, monitor=selector)
            theta = selector.finish(theta, hist)
        else:
            theta, hist = TRAIN_FUNCS[s.trainer](model, theta0, u, y, settings, printer)
    printer.close()
    model.theta_ = theta.detach()
    return hist


def _fit_params(model, s: TrainSettings, machine, meta: dict, hist, axes, errors, n_val: int, val_source: str,
                selected: bool) -> dict:
    """The run's parameters (MLflow params; what reproduces and identifies it)."""
    periodic = periodic_axes(machine, s.a_encoding)
    params = {
        "hidden": ",".join(map(str, model.hidden)), "activation": s.activation, "a_encoding": s.a_encoding,
        "inputs": ",".join(machine.axis_columns),
        "periodic": ",".join(c for c, p in zip(machine.axis_columns, periodic) if p),
        "n_params": model.n_params, "trainer": s.trainer, "mse_goal": s.mse_goal, "max_iter": s.max_iter,
        "max_time_s": s.max_time_s, "seed": s.seed, "n_train": len(axes), "n_val": n_val,
        "validation_source": val_source, "data_sha256": data_hash(axes, errors),
        "machine": machine.name, "machine_file": str(machine.path or ""),
        "machine_sha256": machine.sha256 or meta.get("machine_sha256") or "",
        "elements_sha256": meta.get("elements_sha256", ""), "stop_reason": hist.stop_reason,
        "output_scale_um": model.out_scale_, "init": s.init,
        "select_best": bool(selected), "physics": s.physics,
    }
    if s.physics != "none":
        params["physics_stations"] = model.physics_stations
    if selected and s.select_patience:
        params["select_patience"] = s.select_patience
    if s.trainer == "lm":
        lm = s.lm(model.out_scale_)
        params.update({"mu0": lm.mu0, "mu_dec": lm.mu_dec, "mu_inc": lm.mu_inc,
                       "mu_max": lm.mu_max, "damping": lm.damping, "scaling": lm.scaling,
                       "geodesic": lm.geodesic, "max_err_goal_um": s.max_err_goal_um})
    return params


def _write_run(model, axes, errors, ref, metrics, params, hist, s: TrainSettings, t: TrackSettings, machine,
               out_dir) -> str | None:
    """Write the run folder as a set (``model/``, the fit plots, ``metrics.json``) and, with ``t.track``, log it
    to MLflow (tags ``machine`` and ``t.tags``; ``model/`` as a pyfunc model with the machine file); the run id
    (also in ``metrics.json``, with the store)."""
    from errormap.io import atomic_dir, write_json

    from .plots import fit_plots
    run_id = None
    summary = {**metrics, "stop_reason": hist.stop_reason, "trainer": s.trainer, "seconds": hist.seconds,
               "params": params}
    if hist.stop_reason.startswith("time budget"):  # the machine's speed decided: say how to repeat it
        summary["reproduce_with_max_iter"] = hist.iterations
    with contextlib.ExitStack() as stack:
        # the run folder is written as a set: a temporary folder that replaces out_dir at the end
        d = stack.enter_context(atomic_dir(out_dir)) if out_dir is not None else \
            Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="volcomp-fit-")))
        model.save(d / "model")
        plots = fit_plots(model, axes, errors, d, machine.axis_columns, reference=ref[1] if ref else None)
        write_json(d / "metrics.json", summary)
        if t.track:
            from .tracking import default_tracking_uri, log_fit
            uri = t.tracking_uri or default_tracking_uri()
            mf = machine.path if machine.path and Path(machine.path).is_file() else None
            numbers = {k: float(v) for k, v in metrics.items() if isinstance(v, (int, float))}
            run_id = log_fit(params, numbers, hist, d / "model", plots + [d / "metrics.json"], tracking_uri=uri,
                             run_name=t.run_name, parent_run_id=t.parent_run_id,
                             tags={"machine": machine.name, **(t.tags or {})}, experiment=t.experiment,
                             machine_file=mf)
            if out_dir is not None:
                write_json(d / "metrics.json", {**summary, "run_id": run_id, "tracking_uri": uri})
    return run_id
