"""Levenberg–Marquardt training of an :class:`~training.model.MLPField` (float64).

Damped Gauss–Newton on the flat parameter vector ``theta``: with residuals ``r`` (scaled
network outputs minus scaled targets, all samples and outputs, shape (3n,)) and their
Jacobian ``J`` (shape (3n, P), per-sample ``vmap(jacrev(...))`` from :mod:`torch.func`),
each step solves ``(JᵀJ + μ I) δ = -Jᵀ r`` by Cholesky. A step that lowers the loss is
taken and μ shrinks (× ``mu_dec``); otherwise μ grows (× ``mu_inc``) and the step is
re-solved with the same Jacobian. This is MATLAB's ``trainlm`` rule, the paper's trainer.

Stopping rules (settings, the paper's defaults): MSE goal on the scaled outputs
(``mse_goal = 2.5e-10``), ``max_iter = 100_000`` iterations, ``max_time_s`` wall clock,
``mu > mu_max``, gradient norm below ``min_grad``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import torch
from torch.func import jacrev, vmap


@dataclass
class LMSettings:
    """Stopping rules and damping schedule of the Levenberg–Marquardt trainer."""

    mse_goal: float = 2.5e-10
    max_iter: int = 100_000
    max_time_s: float = 600.0
    mu0: float = 1e-3
    mu_dec: float = 0.1
    mu_inc: float = 10.0
    mu_max: float = 1e10
    mu_min: float = 1e-20
    min_grad: float = 1e-14
    jacobian: str = "analytic"   # or "torch.func" (per-sample vmap(jacrev), same numbers, slower)


@dataclass
class TrainHistory:
    """Per-iteration loss (MSE on scaled outputs), elapsed seconds and why training stopped."""

    loss: list = field(default_factory=list)
    elapsed_s: list = field(default_factory=list)
    stop_reason: str = ""
    iterations: int = 0
    seconds: float = 0.0


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


def train_lm(model, theta0: torch.Tensor, u: torch.Tensor, y: torch.Tensor,
             settings: LMSettings | None = None, callback=None) -> tuple[torch.Tensor, TrainHistory]:
    """Levenberg–Marquardt from ``theta0`` on scaled features ``u`` (n, k) and targets ``y`` (n, 3).

    ``callback(iteration, mse, elapsed_s, mu)`` is called after every accepted step.
    Returns the best parameters and the history.
    """
    s = settings or LMSettings()
    res, jac = residual_fn(model, u, y, s.jacobian)
    theta = theta0.clone()
    m = y.numel()
    r = res(theta)
    sse = float(r @ r)
    mu = s.mu0
    h = TrainHistory()
    t0 = time.perf_counter()
    eye = torch.eye(theta.shape[0], dtype=theta.dtype)
    with torch.no_grad():
        while True:
            mse = sse / m
            if mse <= s.mse_goal:
                h.stop_reason = f"mse goal {s.mse_goal:g} reached"
                break
            if h.iterations >= s.max_iter:
                h.stop_reason = f"max iterations {s.max_iter}"
                break
            if time.perf_counter() - t0 >= s.max_time_s:
                h.stop_reason = f"time budget {s.max_time_s:g} s"
                break
            J = jac(theta)
            g = J.T @ r
            if float(g.norm()) < s.min_grad:
                h.stop_reason = f"gradient below {s.min_grad:g}"
                break
            H = J.T @ J
            accepted = False
            while mu <= s.mu_max:
                L, info = torch.linalg.cholesky_ex(H + mu * eye)
                if int(info) == 0:
                    step = torch.cholesky_solve(-g[:, None], L)[:, 0]
                    cand = theta + step
                    r_new = res(cand)
                    sse_new = float(r_new @ r_new)
                    if sse_new < sse:
                        theta, r, sse = cand, r_new, sse_new
                        mu = max(mu * s.mu_dec, s.mu_min)
                        accepted = True
                        break
                mu *= s.mu_inc
            if not accepted:
                h.stop_reason = f"mu above {s.mu_max:g}"
                break
            h.iterations += 1
            el = time.perf_counter() - t0
            h.loss.append(sse / m)
            h.elapsed_s.append(el)
            if callback is not None:
                callback(h.iterations, sse / m, el, mu)
    h.seconds = time.perf_counter() - t0
    return theta, h
