"""A deep ensemble of small multilayer perceptrons: a learned-residual family beside the GP.

:class:`MLPEnsemble` is the ``"ensemble"`` family of :class:`training.residual.ResidualRegressor` (the GP's
interface): :data:`N_MEMBERS` tanh networks ``d → H → H → 3``, each from its own ``SeedSequence.spawn``
child, trained by L-BFGS on the MSE plus a weight decay toward zero (:data:`WEIGHT_DECAY`); prediction the
members' mean, band their spread, noise the mean's training residual variance; closed-form Jacobian.
:class:`compensation.hybrid.LearnedResidual` tapers it to zero outside its data.
docs/reference/learned-stage.md."""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import minimize

from errormap.seeds import spawn_seeds

__all__ = ["MLPEnsemble", "N_MEMBERS", "HIDDEN", "WEIGHT_DECAY", "MAX_ITER"]

N_MEMBERS = 5
"""Members of the ensemble (the usual deep-ensemble size: the spread of 5 is a usable band after
the CV calibration; more members cost linearly)."""

HIDDEN = 16
"""Units per hidden layer: 2 × 16 tanh units (≈ 400 weights) are enough for the smooth, few-bump
fields a residual of a physical model leaves over 4 inputs, few enough for ~500 noisy checks."""

WEIGHT_DECAY = 1.0
"""L2 penalty: ``WEIGHT_DECAY`` × the mean squared weight, beside the mean squared error of outputs
scaled to unit RMS. Measured on a synthetic residual (a 2 μm Gaussian bump plus an X·cos A
coupling, 480 points, 1 μm noise, 2 × 16 units; ``tests/test_ensemble.py`` keeps the case): TRUE
RMS error of the ensemble mean 1.08 / 1.02 / 0.39 / 0.45 μm at 0.01 / 0.1 / 1 / 3 (GP: 0.32): a
smaller penalty lets the members interpolate the check noise."""

MAX_ITER = 400
"""L-BFGS iterations per member (the loss is flat by then at these sizes; a cap, also, on CPU)."""


def _shapes(d: int, h: int, k: int):
    return [(d, h), (h,), (h, h), (h,), (h, k), (k,)]


@lru_cache(maxsize=64)
def _slices(d: int, h: int, k: int):
    """Per weight array of :func:`_shapes`: (its slice of the flat weights, its shape). Cached: L-BFGS asks
    for the loss thousands of times per member."""
    out, i = [], 0
    for s in _shapes(d, h, k):
        n = s[0] * s[1] if len(s) == 2 else s[0]
        out.append((slice(i, i + n), s))
        i += n
    return tuple(out)


def _unpack(w, d, h, k):
    return [w[sl].reshape(s) for sl, s in _slices(d, h, k)]


def _init(rng, d, h, k):
    parts = []
    for s in _shapes(d, h, k):
        if len(s) == 2:
            parts.append(rng.normal(0.0, np.sqrt(2.0 / (s[0] + s[1])), s).ravel())   # Glorot normal
        else:
            parts.append(np.zeros(s))
    return np.concatenate(parts)


def _forward(w, X, d, h, k, parts=None):
    """``parts``: :func:`_unpack` of ``w`` where the caller has it already."""
    W1, b1, W2, b2, W3, b3 = _unpack(w, d, h, k) if parts is None else parts
    h1 = np.tanh(X @ W1 + b1)
    h2 = np.tanh(h1 @ W2 + b2)
    return h1, h2, h2 @ W3 + b3


def _loss_grad(w, X, Y, d, h, k, decay):
    """Mean squared error (over n × k) + decay · mean of squared weights (biases free), gradient."""
    parts = _unpack(w, d, h, k)
    W1, b1, W2, b2, W3, b3 = parts
    h1, h2, y = _forward(w, X, d, h, k, parts)
    n = X.shape[0]
    r = y - Y
    nw = W1.size + W2.size + W3.size
    loss = float(np.mean(r * r)) + decay * float((W1 * W1).sum() + (W2 * W2).sum() + (W3 * W3).sum()) / nw
    g_y = 2.0 * r / (n * Y.shape[1])
    gW3 = h2.T @ g_y + 2 * decay * W3 / nw
    gb3 = g_y.sum(0)
    g2 = (g_y @ W3.T) * (1 - h2 * h2)
    gW2 = h1.T @ g2 + 2 * decay * W2 / nw
    gb2 = g2.sum(0)
    g1 = (g2 @ W2.T) * (1 - h1 * h1)
    gW1 = X.T @ g1 + 2 * decay * W1 / nw
    gb1 = g1.sum(0)
    return loss, np.concatenate([gW1.ravel(), gb1, gW2.ravel(), gb2, gW3.ravel(), gb3])


class MLPEnsemble:
    """``n_members`` tanh MLPs on standardised inputs (module doc). ``seed``: an int or
    SeedSequence (each member gets a child of ``spawn``), or None only for :meth:`from_state`."""

    def __init__(self, seed=0, n_members: int = N_MEMBERS, hidden: int = HIDDEN, weight_decay: float = WEIGHT_DECAY,
                 max_iter: int = MAX_ITER):
        self.seed = seed
        self.n_members = int(n_members)
        self.hidden = int(hidden)
        self.weight_decay = float(weight_decay)
        self.max_iter = int(max_iter)

    def fit(self, Xs, Ys):
        """Xs (n, d) standardised, Ys (n, k) scaled → self (``weights_`` (M, p), ``noise_var_`` (k,))."""
        Xs, Ys = np.asarray(Xs, dtype=float), np.asarray(Ys, dtype=float)
        n, d = Xs.shape
        k = Ys.shape[1]
        self.d_, self.k_ = d, k
        ws = []
        for ss in spawn_seeds(self.seed, self.n_members):
            w0 = _init(np.random.default_rng(ss), d, self.hidden, k)
            r = minimize(_loss_grad, w0, args=(Xs, Ys, d, self.hidden, k, self.weight_decay), jac=True,
                         method="L-BFGS-B", options={"maxiter": self.max_iter})
            ws.append(r.x)
        self.weights_ = np.array(ws)
        mean = self.predict(Xs)
        self.noise_var_ = np.maximum(np.mean((Ys - mean) ** 2, axis=0), 1e-12)
        return self

    def noise_var(self):
        """(k,) residual variance of the ensemble mean on the training points (scaled units)."""
        return self.noise_var_

    def predict(self, Xs, return_std=False, jacobian=False):
        """Mean (m, k) [, members' std (m, k)] [, dmean/dXs (m, k, d)] in scaled units."""
        Xs = np.asarray(Xs, dtype=float)
        d, h, k = self.d_, self.hidden, self.k_
        outs, jacs = [], []
        for w in self.weights_:
            h1, h2, y = _forward(w, Xs, d, h, k)
            outs.append(y)
            if jacobian:
                W1, _, W2, _, W3, _ = _unpack(w, d, h, k)
                A = W1[None, :, :] * (1 - h1 * h1)[:, None, :]           # (m, d, h)
                B = (A @ W2) * (1 - h2 * h2)[:, None, :]                  # (m, d, h)
                jacs.append(np.transpose(B @ W3, (0, 2, 1)))             # (m, k, d)
        Y = np.array(outs)
        mean = Y.mean(0)
        out = (mean,)
        if return_std:
            out += (Y.std(0, ddof=1) if len(Y) > 1 else np.zeros_like(mean),)
        if jacobian:
            out += (np.mean(jacs, axis=0),)
        return out if len(out) > 1 else mean

    def state(self) -> dict:
        """JSON-able weights and settings (:meth:`from_state`)."""
        return {"n_members": self.n_members, "hidden": self.hidden, "weight_decay": self.weight_decay,
                "max_iter": self.max_iter, "d": int(self.d_), "k": int(self.k_),
                "weights": self.weights_.tolist(), "noise_var": self.noise_var_.tolist()}

    @classmethod
    def from_state(cls, st: dict) -> "MLPEnsemble":
        """The ensemble :meth:`state` describes; ValueError on inconsistent shapes."""
        self = cls(None, st["n_members"], st["hidden"], st["weight_decay"], st["max_iter"])
        self.d_, self.k_ = int(st["d"]), int(st["k"])
        self.weights_ = np.asarray(st["weights"], dtype=float)
        p = sum(int(np.prod(s)) for s in _shapes(self.d_, self.hidden, self.k_))
        if self.weights_.shape != (self.n_members, p):
            raise ValueError(f"expected ensemble weights of shape ({self.n_members}, {p}), got {self.weights_.shape}")
        self.noise_var_ = np.asarray(st["noise_var"], dtype=float)
        if self.noise_var_.shape != (self.k_,):
            raise ValueError(f"expected {self.k_} noise variances")
        return self
