"""Levenberg–Marquardt training of an :class:`~training.model.MLPField` (float64).

Damped Gauss–Newton on the flat parameter vector ``theta``: with residuals ``r`` (scaled network outputs
minus scaled targets, shape (3n,)) and their Jacobian ``J`` (3n, P), by explicit backpropagation or
``vmap(jacrev(...))`` from :mod:`torch.func`, each step solves ``(JᵀJ + μ D) δ = -Jᵀ r`` by a Cholesky
factorisation (``JᵀJ`` and ``Jᵀr`` formed once per Jacobian; a rejected step only re-factors).

Settings (:class:`LMSettings`): ``scaling`` ``"identity"`` (``D = I``, MATLAB ``trainlm``'s, the default) or
``"marquardt"`` (``D`` the running maximum of ``diag(JᵀJ)``); ``damping`` ``"nielsen"`` (the default: gain
ratio ``ρ``; taken when ``ρ > 0``, then ``μ ← μ·max(1/3, 1−(2ρ−1)³)``, ``ν ← 2``; a rejection ``μ ← μ·ν``,
``ν ← 2ν``) or ``"trainlm"`` (MATLAB's ``mu_dec`` / ``mu_inc``); ``geodesic`` (default on: Transtrum's
geodesic acceleration, step ``v + a/2`` kept when ``2|a|/|v| ≤ geo_alpha``). Only steps that lower the loss
are taken. Stopping: MSE goal on the scaled outputs, optional ``max_abs_goal``, ``max_iter``,
``max_time_s``, ``mu_max``, ``min_grad``. The measurements behind the defaults:
docs/decisions/020-benchmark-notebook.md."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import torch
from torch.func import jacrev, vmap

DAMPINGS = ("nielsen", "trainlm")
SCALINGS = ("marquardt", "identity")


@dataclass
class LMSettings:
    """Stopping rules, damping rule and scaling of the Levenberg–Marquardt trainer."""

    mse_goal: float = 2.5e-10
    max_iter: int = 100_000
    max_time_s: float = 600.0
    max_abs_goal: float = 0.0    # stop when max |scaled residual| <= this (0: off)
    damping: str = "nielsen"     # or "trainlm" (MATLAB: x mu_inc / x mu_dec)
    scaling: str = "identity"    # D = I (as MATLAB trainlm), or "marquardt" (D = running max diag(JᵀJ))
    geodesic: bool = True
    geo_alpha: float = 0.75      # acceleration kept when 2|a|/|v| <= geo_alpha
    geo_h: float = 0.1           # finite-difference step for the second directional derivative
    mu0: float = 1e-3
    mu_dec: float = 0.1
    mu_inc: float = 10.0
    mu_max: float = 1e10
    mu_min: float = 1e-20
    min_grad: float = 1e-14
    jacobian: str = "analytic"   # or "torch.func" (per-sample vmap(jacrev), same numbers, slower)

    def __post_init__(self):
        if self.damping not in DAMPINGS:
            raise ValueError(f"Expected damping in {DAMPINGS}, got {self.damping!r}")
        if self.scaling not in SCALINGS:
            raise ValueError(f"Expected scaling in {SCALINGS}, got {self.scaling!r}")
        if self.jacobian not in ("analytic", "torch.func"):
            raise ValueError(f"Expected jacobian 'analytic' or 'torch.func', got {self.jacobian!r}")


@dataclass
class TrainHistory:
    """Per-iteration loss (MSE on scaled outputs), elapsed seconds and why training stopped."""

    loss: list = field(default_factory=list)
    elapsed_s: list = field(default_factory=list)
    stop_reason: str = ""
    iterations: int = 0
    seconds: float = 0.0
    max_abs: list = field(default_factory=list)   # max |scaled residual| after each iteration

    def record(self, mse: float, t0: float, callback=None, rate: float = 0.0) -> None:
        """One iteration done: its loss and elapsed seconds (since ``t0``), then
        ``callback(iteration, mse, elapsed_s, rate)`` (``rate``: LM's μ, Adam's learning rate)."""
        self.iterations += 1
        el = time.perf_counter() - t0
        self.loss.append(mse)
        self.elapsed_s.append(el)
        if callback is not None:
            callback(self.iterations, mse, el, rate)


def residual_fn(model, u: torch.Tensor, y: torch.Tensor, jacobian: str = "analytic"):
    """``theta -> r`` (shape (3n,)) and ``theta -> J`` (shape (3n, P)) for a model and scaled data."""
    def res(theta):
        return (model.forward(theta, u) - y).reshape(-1)

    def one(theta, ui):
        return model.forward(theta, ui)

    per_sample = vmap(jacrev(one), in_dims=(None, 0))

    def jac(theta):
        if jacobian == "analytic":
            return model.param_jacobian(theta, u).reshape(-1, theta.shape[0])
        return per_sample(theta, u).reshape(-1, theta.shape[0])

    if jacobian not in ("analytic", "torch.func"):
        raise ValueError(f"Expected jacobian 'analytic' or 'torch.func', got {jacobian!r}")

    return res, jac


def stop_reason(s: LMSettings, h: TrainHistory, mse: float, t0: float, r: torch.Tensor | None = None) -> str:
    """Why training stops before the next iteration ("" to go on): goals (the max |residual| goal where ``r``,
    the scaled residuals, is given), iteration cap, budget."""
    if mse <= s.mse_goal:
        return f"mse goal {s.mse_goal:g} reached"
    if r is not None and s.max_abs_goal > 0 and float(r.abs().max()) <= s.max_abs_goal:
        return f"max |residual| goal {s.max_abs_goal:g} reached"
    if h.iterations >= s.max_iter:
        return f"max iterations {s.max_iter}"
    if time.perf_counter() - t0 >= s.max_time_s:
        return f"time budget {s.max_time_s:g} s"
    return ""


@dataclass
class _Damping:
    """The damping state ``μ`` (and Nielsen's ``ν``) and its update rules (module doc)."""

    mu: float
    nu: float = 2.0

    def reject(self, s: LMSettings) -> None:
        if s.damping == "trainlm":
            self.mu *= s.mu_inc
        else:
            self.mu *= self.nu
            self.nu *= 2.0

    def accept(self, s: LMSettings, rho: float) -> None:
        if s.damping == "trainlm":
            self.mu = max(self.mu * s.mu_dec, s.mu_min)
        else:
            self.mu = max(self.mu * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), s.mu_min)
            self.nu = 2.0


def _geodesic_step(s: LMSettings, res, theta, r, J, v, L) -> torch.Tensor:
    """``v + a/2`` with Transtrum's geodesic acceleration ``a``, or ``v`` when ``a`` is too large."""
    Jv = J @ v
    rv = res(theta + s.geo_h * v)
    rvv = (2.0 / s.geo_h) * ((rv - r) / s.geo_h - Jv)
    a = torch.cholesky_solve(-(J.T @ rvv)[:, None], L)[:, 0]
    return v + 0.5 * a if 2.0 * float(a.norm()) <= s.geo_alpha * float(v.norm()) else v


def _damped_step(s: LMSettings, res, theta, r, sse: float, J, g, H, Hd, Dk, damping: _Damping):
    """Raise ``μ`` until a step lowers the sum of squares: ``(theta, r, sse)`` after it, or None
    when ``μ`` passes ``mu_max``. ``H`` (JᵀJ) is overwritten on its diagonal."""
    idx = torch.arange(theta.shape[0])
    while damping.mu <= s.mu_max:
        H[idx, idx] = Hd + damping.mu * Dk
        L, info = torch.linalg.cholesky_ex(H)
        if int(info) != 0:
            damping.reject(s)
            continue
        v = torch.cholesky_solve(-g[:, None], L)[:, 0]
        step = _geodesic_step(s, res, theta, r, J, v, L) if s.geodesic else v
        cand = theta + step
        r_new = res(cand)
        sse_new = float(r_new @ r_new)
        rho = 0.0
        if s.damping == "trainlm":
            ok = sse_new < sse
        else:
            # predicted decrease of the sum of squares for the linearised step v
            pred = float(v @ (damping.mu * Dk * v - g))
            rho = (sse - sse_new) / pred if pred > 0 else -1.0
            ok = rho > 0 and sse_new < sse
        if ok:
            damping.accept(s, rho)
            return cand, r_new, sse_new
        damping.reject(s)
    return None


def train_lm(model, theta0: torch.Tensor, u: torch.Tensor, y: torch.Tensor,
             settings: LMSettings | None = None, callback=None, monitor=None) -> tuple[torch.Tensor, TrainHistory]:
    """Levenberg–Marquardt from ``theta0`` on scaled features ``u`` (n, k) and targets ``y`` (n, 3).

    ``callback(iteration, mse, elapsed_s, mu)`` is called after every accepted step;
    ``monitor(iteration, theta)`` too (model selection, see :func:`training.fit_field`): a
    non-empty string it returns stops training with that reason (early stopping).
    Returns the best parameters (the last accepted) and the history.
    """
    s = settings or LMSettings()
    res, jac = residual_fn(model, u, y, s.jacobian)
    theta = theta0.clone()
    m = y.numel()
    P = theta.shape[0]
    r = res(theta)
    sse = float(r @ r)
    damping = _Damping(s.mu0)
    h = TrainHistory()
    t0 = time.perf_counter()
    D = torch.zeros(P, dtype=theta.dtype)
    with torch.no_grad():
        while True:
            h.stop_reason = stop_reason(s, h, sse / m, t0, r)
            if h.stop_reason:
                break
            J = jac(theta)
            g = J.T @ r
            if float(g.norm()) < s.min_grad:
                h.stop_reason = f"gradient below {s.min_grad:g}"
                break
            H = J.T @ J
            Hd = H.diagonal().clone()
            if s.scaling == "marquardt":
                D = torch.maximum(D, Hd)
                Dk = torch.clamp(D, min=1e-30)
            else:
                Dk = torch.ones(P, dtype=theta.dtype)
            stepped = _damped_step(s, res, theta, r, sse, J, g, H, Hd, Dk, damping)
            if stepped is None:
                h.stop_reason = f"mu above {s.mu_max:g}"
                break
            theta, r, sse = stepped
            h.max_abs.append(float(r.abs().max()))
            h.record(sse / m, t0, callback, damping.mu)
            if monitor is not None:
                stop = monitor(h.iterations, theta)
                if stop:
                    h.stop_reason = str(stop)
                    break
    h.seconds = time.perf_counter() - t0
    return theta, h
