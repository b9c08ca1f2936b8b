"""A learned pose-error field for parallel kinematic machines: commanded pose -> pose error.

The learned PKM path of the benchmark: a small multilayer perceptron maps the
commanded platform pose to the pose error the machine makes there, trained on measured
poses. It reuses the grinder network's functional MLP (:meth:`training.model.MLPField.forward`,
flat parameter vector ``theta``) and the Levenberg–Marquardt trainer's residual and Jacobian
(:func:`training.lm.residual_fn`), with a ridge (Tikhonov) term on the weights, because a PKM
calibration campaign gives tens to hundreds of poses, not thousands of grid points.

Inputs (``k`` columns, shape (n, k)): hexapod ``(x_mm, y_mm, z_mm, rx_rad, ry_rad, rz_rad)``
(tool tip at the measurement tool, orientation as a rotation vector), tripod ``(x_mm, y_mm,
z_mm)``. Outputs (``m`` columns, shape (n, m)): hexapod ``(dx_um, dy_um, dz_um, ex_urad,
ey_urad, ez_urad)`` (tip error and the rotation vector of ``R_reached · R_cmdᵀ``), tripod
``(dx_um, dy_um, dz_um)``. Inputs are scaled to ``[-1, 1]`` over the training range, each
output is standardised (mean removed, divided by its own standard deviation).

The training objective is ``Σ r² + λ Σ θ²`` on the scaled outputs: each LM step solves
``(JᵀJ + (λ + μ) I) δ = -(Jᵀ r + λ θ)``. Stopping: iteration cap, wall-clock budget,
relative decrease below ``1e-10`` over 20 steps.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from errormap.field import CalibratedVolume
from errormap.stats import residual_stats

from .lm import TrainHistory, residual_fn
from .model import ACTIVATIONS, DTYPE, MLPField

DEFAULT_HIDDEN = (16,)
DEFAULT_RIDGE = 1e-3
POSE_INPUTS = {6: ("x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad"), 3: ("x_mm", "y_mm", "z_mm")}
"""Input names of the hexapod and tripod pose fields (module docstring)."""
MIN_SPAN = 1e-6
"""Inputs whose training range is below this are treated as constant (unit span)."""


class PoseMLP(MLPField):
    """An MLP with ``n_in`` inputs and ``n_out`` outputs and per-output standardisation.

    Shares the grinder field's functional network (``forward``, ``init_params``); the A-axis
    wrapping of :class:`MLPField` does not apply (no periodic input here).
    """

    kind = "pose-mlp"
    capabilities = frozenset()
    """None of the grinder field's optional methods (:mod:`errormap.field`): no A turn, no columns."""

    def __init__(self, n_in: int, n_out: int, hidden=DEFAULT_HIDDEN, activation: str = "tanh"):
        super().__init__(hidden, activation, "raw")
        self.n_in, self.n_out = int(n_in), int(n_out)

    @property
    def input_names(self) -> tuple:
        """The pose inputs' names: hexapod (6) or tripod (3) poses, else ``u0``, ``u1``, …"""
        return POSE_INPUTS.get(self.n_in, tuple(f"u{i}" for i in range(self.n_in)))

    @property
    def calibrated_volume(self) -> CalibratedVolume | None:
        """The training poses' range per input (``in_lo_``..``in_hi_``, named by :attr:`input_names`);
        None before training."""
        if "in_lo_" not in self.__dict__:
            return None
        return CalibratedVolume(self.in_lo_, self.in_hi_, self.input_names)

    @property
    def n_inputs(self) -> int:
        return self.n_in

    @property
    def layer_sizes(self) -> tuple:
        return (self.n_in, *self.hidden, self.n_out)

    def fit_scalers(self, inputs, outputs) -> "PoseMLP":
        x = np.asarray(inputs, dtype=float)
        y = np.asarray(outputs, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.n_in or y.shape != (x.shape[0], self.n_out):
            raise ValueError(f"Expected inputs (n, {self.n_in}) and outputs (n, {self.n_out}), got {x.shape} and {y.shape}")
        lo, hi = x.min(axis=0), x.max(axis=0)
        # an input that does not vary in the measurements (e.g. the platform spin, zero by the paper's
        # gamma = -alpha convention) gets a unit span, so that small changes of it stay small features
        self.in_lo_, self.in_hi_ = lo, np.where(hi - lo > MIN_SPAN, hi, lo + 1.0)
        self.out_mean_ = y.mean(axis=0)
        self.out_std_ = np.maximum(y.std(axis=0), 1e-12)
        return self

    def features(self, inputs) -> np.ndarray:
        x = np.asarray(inputs, dtype=float)
        return 2.0 * (x - self.in_lo_) / (self.in_hi_ - self.in_lo_) - 1.0

    def scale_errors(self, outputs) -> np.ndarray:
        return (np.asarray(outputs, dtype=float) - self.out_mean_) / self.out_std_

    def unscale_errors(self, y) -> np.ndarray:
        return np.asarray(y) * self.out_std_ + self.out_mean_

    def predict(self, inputs) -> np.ndarray:
        """Pose errors, shape (n, n_out), at inputs shape (n, n_in)."""
        x = np.asarray(inputs, dtype=float)
        if x.ndim != 2 or x.shape[1] != self.n_in:
            raise ValueError(f"Expected inputs of shape (n, {self.n_in}), got {x.shape}")
        with torch.no_grad():
            out = self.forward(self._theta(), torch.from_numpy(self.features(x))).numpy()
        return self.unscale_errors(out)

    __call__ = predict


@dataclass
class PoseFitResult:
    """What :func:`fit_pose_field` returns: the field, metrics (output units), seconds, history."""

    field: PoseMLP
    metrics: dict
    seconds: float
    history: TrainHistory = field(default_factory=TrainHistory)
    params: dict = field(default_factory=dict)


def train_ridge_lm(model: PoseMLP, theta0: torch.Tensor, u: torch.Tensor, y: torch.Tensor, ridge: float,
                   max_iter: int = 500, max_time_s: float = 30.0, mu0: float = 1e-3) -> tuple[torch.Tensor, TrainHistory]:
    """Levenberg–Marquardt on ``|r|² + ridge·|θ|²`` (scaled data); returns the best θ and the history."""
    res, jac = residual_fn(model, u, y, "torch.func")
    theta = theta0.clone()
    P = theta.shape[0]
    eye = torch.eye(P, dtype=DTYPE)

    def objective(th, r):
        return float(r @ r) + ridge * float(th @ th)

    r = res(theta)
    f = objective(theta, r)
    mu = mu0
    h = TrainHistory()
    t0 = time.perf_counter()
    with torch.no_grad():
        while True:
            if h.iterations >= max_iter:
                h.stop_reason = f"max iterations {max_iter}"
                break
            if time.perf_counter() - t0 >= max_time_s:
                h.stop_reason = f"time budget {max_time_s:g} s"
                break
            if len(h.loss) > 20 and h.loss[-21] - h.loss[-1] <= 1e-10 * max(h.loss[-21], 1e-300):
                h.stop_reason = "converged (relative decrease below 1e-10 over 20 steps)"
                break
            J = jac(theta)
            g = J.T @ r + ridge * theta
            H = J.T @ J
            accepted = False
            while mu <= 1e10:
                L, info = torch.linalg.cholesky_ex(H + (ridge + mu) * eye)
                if int(info) == 0:
                    cand = theta + torch.cholesky_solve(-g[:, None], L)[:, 0]
                    r_new = res(cand)
                    f_new = objective(cand, r_new)
                    if f_new < f:
                        theta, r, f = cand, r_new, f_new
                        mu = max(mu * 0.1, 1e-20)
                        accepted = True
                        break
                mu *= 10.0
            if not accepted:
                h.stop_reason = "mu above 1e10"
                break
            h.record(f / y.numel(), t0)
    h.seconds = time.perf_counter() - t0
    return theta, h


def fit_pose_field(inputs, outputs, *, hidden=DEFAULT_HIDDEN, activation: str = "tanh", ridge: float = DEFAULT_RIDGE,
                   max_time_s: float = math.inf, max_iter: int = 200, seed: int = 0) -> PoseFitResult:
    """Train a :class:`PoseMLP` on measured poses: ``inputs`` (n, k), ``outputs`` (n, m).

    Training stops after ``max_iter`` iterations (or earlier on its own criteria), so the same
    data and seed give the same field on any machine; ``max_time_s`` (default off) adds a
    wall-clock budget, and the iterations it allowed are in ``metrics["iterations"]``.

    Metrics: ``train_rms`` and ``train_max`` of the fit per output block (``pos_um`` for the
    first three outputs as a vector norm, ``ang_urad`` for the rest), ``iterations``, ``stop_reason``.
    """
    if activation not in ACTIVATIONS:
        raise ValueError(f"Expected activation in {sorted(ACTIVATIONS)}, got {activation!r}")
    x = np.asarray(inputs, dtype=float)
    yv = np.asarray(outputs, dtype=float)
    model = PoseMLP(x.shape[1], yv.shape[1], hidden, activation).fit_scalers(x, yv)
    u = torch.from_numpy(model.features(x))
    y = torch.from_numpy(model.scale_errors(yv))
    theta0 = model.init_params(seed)
    theta, hist = train_ridge_lm(model, theta0, u, y, ridge, max_iter=max_iter, max_time_s=max_time_s)
    model.theta_ = theta.detach()
    d = model.predict(x) - yv
    pos = residual_stats(d[:, :3])
    metrics = {"train_rms_pos_um": pos["rms_um"], "train_max_pos_um": pos["max_um"],
               "iterations": hist.iterations, "train_seconds": hist.seconds}
    if yv.shape[1] > 3:
        ang = residual_stats(d[:, 3:])  # the same statistics of the angle vector (values in μrad)
        metrics.update({"train_rms_ang_urad": ang["rms_um"], "train_max_ang_urad": ang["max_um"]})
    params = {"hidden": ",".join(map(str, model.hidden)), "activation": activation, "ridge": ridge,
              "n_params": model.n_params, "n_train": int(x.shape[0]), "max_time_s": max_time_s, "max_iter": max_iter,
              "seed": seed, "stop_reason": hist.stop_reason}
    if not math.isfinite(metrics["train_rms_pos_um"]):
        raise FloatingPointError("pose-field training diverged (non-finite fit)")
    return PoseFitResult(model, metrics, hist.seconds, hist, params)
