"""The paper's BP network as an error field over a machine tool's axes -> (dx_um, dy_um, dz_um).

One class for every machine tool (:meth:`MLPField.for_machine`): one input per axis column, each scaled
from its training range to ``[-1, 1]``, a periodic axis as ``(cos q, sin q)``. A float64 multilayer
perceptron (default hidden layers 10, 15, 25, 15, 10, sigmoid: the grinder paper's), in functional form
``forward(theta, features)`` with all weights in one flat vector ``theta`` so the trainers
(Levenberg–Marquardt) take per-sample Jacobians. Outputs minus their per-axis mean, divided by ONE
common scale (the largest per-axis half-range).

On the grinder's columns ``x_mm, z_mm, a_deg`` with A a full turn, A is folded into the training turn
``[a0, a0 + 360]`` (``a_encoding="raw"``: one scaled input; ``"periodic"``: ``(cos a, sin a)``); with the
raw input ``predict``/``jacobian`` close the seam: over the last ``SEAM_WINDOW_DEG`` (30°) they add
``(N(x, z, a0) − N(x, z, a0 + 360))·t²(3 − 2t)``, ``t`` the ramp's fraction (docs/explanation/solvers.md,
"Known limits"; ``forward``, ``param_jacobian`` and the training metrics use the raw network); saved as
``volcomp-mlpfield/1``. On any other machine tool every full-turn rotary axis is periodic, and the files
(``volcomp-chain-mlpfield/1``) record the axis columns and the machine. Fast inference (cached weights,
points as columns, a float32 path, ``predict_columns`` for the solvers' inner loop):
docs/explanation/solvers.md ("Speed")."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from errormap.field import (FLOAT32, JACOBIAN, OFFSET_FITNESS, PREDICT_AND_JACOBIAN, PREDICT_COLUMNS, CalibratedVolume)
from errormap.io import OUTPUT_LOCK_NAME, InputError, read_document_text, atomic_dir, atomic_write, load_array, sha256_file, write_json
from errormap.threads import limit_threads
from errormap.transforms import check_points

from .physics import PHYSICS_FILES, PhysicsPart

FORMAT = "volcomp-mlpfield/1"
CHAIN_FORMAT = "volcomp-chain-mlpfield/1"
"""The saved format of a network over other axis columns than :data:`INPUTS` (it records them and the machine)."""
MODEL_FILES = ("scalers.json", "weights.npy")  # config.json records their SHA-256
PAPER_HIDDEN = (10, 15, 25, 15, 10)
INPUTS = ("x_mm", "z_mm", "a_deg")
"""The axis columns the network takes: two linear axes and a full-turn rotary axis (the grinder's)."""
ACTIVATIONS = {"sigmoid": torch.sigmoid, "tanh": torch.tanh, "softplus": torch.nn.functional.softplus}
A_ENCODINGS = ("raw", "periodic")
DTYPE = torch.float64


def wrap_a(a_deg: np.ndarray, a0_deg: float) -> np.ndarray:
    """Fold A (deg) into the training turn ``[a0, a0 + 360]``; values already inside pass unchanged."""
    a = np.asarray(a_deg, dtype=float)
    inside = (a >= a0_deg) & (a <= a0_deg + 360.0)
    return np.where(inside, a, a0_deg + np.mod(a - a0_deg, 360.0))


def uses_fused_network(machine) -> bool:
    """True where the machine's axis columns are :data:`INPUTS` with A a full turn: the network folds A into its
    training turn (raw A with the seam closed, or periodic), saves the grinder's format and offers the batched
    GA's fused fitness (:mod:`training.ga_fitness`)."""
    return tuple(machine.axis_columns) == INPUTS and bool(machine.axes[2].full_turn)


def check_model_format(d: Path, cfg, fmts: tuple) -> None:
    """``config.json`` of the saved model folder ``d`` is a dict whose ``format`` is one of ``fmts`` (InputError otherwise)."""
    if not isinstance(cfg, dict) or cfg.get("format") not in fmts:
        got = cfg.get("format") if isinstance(cfg, dict) else cfg
        raise InputError(f"{d / 'config.json'}: key 'format': expected {' or '.join(map(repr, fmts))}, got {got!r}")


def check_model_files(cls, d: Path, cfg: dict) -> None:
    """The saved model folder ``d`` holds ``cls``'s extra files, and every file ``config.json`` records has the
    SHA-256 recorded there (InputError otherwise). Folders saved before the set was recorded carry no
    ``files_sha256`` (MLflow runs kept from then)."""
    extra = cls._extra_file_names()
    for name in extra:
        if not (d / name).is_file():
            raise InputError(f"{d}: not a saved {cls.__name__} (missing {name})")
    for name, sha in (cfg.get("files_sha256") or {}).items():
        if name in MODEL_FILES + extra and sha256_file(d / name) != sha:
            raise InputError(f"{d / name}: does not belong to this model (SHA-256 differs from the one "
                             f"config.json records); the folder holds a partial or mixed set")


def periodic_columns(periodic, axes_deg, values) -> list:
    """The input columns of axes flagged ``periodic`` as the network takes them: per axis ``j``, ``cos`` and ``sin``
    of ``axes_deg[:, j]`` (degrees) where periodic, else ``values[:, j]``; ``axes_deg``, ``values`` (n, k) -> list of
    (n,) columns (the network's scaled inputs, or the OLS baseline's raw ones)."""
    cols = []
    for j, per in enumerate(periodic):
        if per:
            r = np.deg2rad(axes_deg[:, j])
            cols += [np.cos(r), np.sin(r)]
        else:
            cols.append(values[:, j])
    return cols


class MLPField:
    """A multilayer perceptron error field with built-in scaling, over a machine tool's axes.

    Settings (constructor only stores them): ``hidden`` layer widths, ``activation``
    (``sigmoid``, ``tanh``, ``softplus``), ``a_encoding`` (``raw``: A as one scaled input, the
    paper's; ``periodic``: A as ``(cos a, sin a)``), ``chunk`` (points per batch in
    ``predict``/``jacobian``, bounding memory); ``axis_columns`` (None: :data:`INPUTS` with A
    folded into the training turn, ``turn_axis`` 2) with ``periodic`` (one flag per axis, fed as
    cos/sin), ``machine`` and ``machine_sha256`` (recorded in the chain format).

    Learned state: ``theta_`` (flat float64 parameters), ``in_lo_``/``in_hi_`` (input ranges,
    shape (k,)), ``a0_deg_`` (the turn's start, with a ``turn_axis``), ``out_mean_`` (shape (3,),
    μm), ``out_scale_`` (μm).
    """

    kind = "mlp"

    def __init__(self, hidden=PAPER_HIDDEN, activation: str = "sigmoid", a_encoding: str = "raw",
                 chunk: int = 65_536, axis_columns=None, periodic=None, machine: str = "", machine_sha256: str = ""):
        self.hidden = tuple(int(h) for h in hidden)
        self.activation = activation
        self.a_encoding = a_encoding
        self.chunk = int(chunk)
        self.turn_axis = 2 if axis_columns is None else None
        self.axis_columns = INPUTS if axis_columns is None else tuple(str(c) for c in axis_columns)
        if periodic is None:
            periodic = [self.turn_axis == j and a_encoding == "periodic" for j in range(len(self.axis_columns))]
        self.periodic = tuple(bool(p) for p in periodic)
        self.machine = str(machine)
        self.machine_sha256 = str(machine_sha256)
        if not self.axis_columns or len(self.periodic) != len(self.axis_columns):
            raise ValueError(f"Expected one periodic flag per axis column {self.axis_columns}, got {self.periodic}")
        if any(p and not c.endswith("_deg") for c, p in zip(self.axis_columns, self.periodic)):
            raise ValueError(f"Expected periodic axes in degrees, got {self.axis_columns} / {self.periodic}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"Expected activation in {sorted(ACTIVATIONS)}, got {activation!r}")
        if a_encoding not in A_ENCODINGS:
            raise ValueError(f"Expected a_encoding in {A_ENCODINGS}, got {a_encoding!r}")
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"Expected at least one hidden layer of width >= 1, got {hidden!r}")

    @classmethod
    def for_machine(cls, machine, a_encoding: str = "raw", **settings) -> "MLPField":
        """The untrained field over ``machine``'s axes (a :class:`errormap.machine_tool.MachineTool`): where
        :func:`uses_fused_network`, A folded into its turn (raw with the seam closed, or ``"periodic"``); else
        a full-turn rotary axis as (cos, sin) always, a rotary axis short of a turn as one scaled input
        (``a_encoding="raw"``) or as (cos, sin) too (``"periodic"``)."""
        if a_encoding not in A_ENCODINGS:
            raise ValueError(f"Expected a_encoding in {A_ENCODINGS}, got {a_encoding!r}")
        if uses_fused_network(machine):
            return cls(a_encoding=a_encoding, **settings)
        return cls(a_encoding=a_encoding, axis_columns=machine.axis_columns,
                   periodic=[a.kind == "rotary" and (a.full_turn or a_encoding == "periodic") for a in machine.axes],
                   machine=machine.name, machine_sha256=machine.sha256 or "", **settings)

    # -- structure ----------------------------------------------------------------------
    @property
    def capabilities(self) -> frozenset:
        """The optional error-field methods it offers (:mod:`errormap.field`): all of them; ``offset_fitness``
        (the batched GA's fused kernel) only over the grinder's columns with A folded into its turn."""
        caps = {JACOBIAN, PREDICT_AND_JACOBIAN, FLOAT32, PREDICT_COLUMNS}
        return frozenset(caps | {OFFSET_FITNESS} if self.turn_axis is not None else caps)

    @property
    def n_axes(self) -> int:
        return len(self.axis_columns)

    @property
    def n_inputs(self) -> int:
        return self.n_axes + sum(self.periodic)

    @property
    def format(self) -> str:
        """The saved format: :data:`FORMAT` with A folded into its turn, else :data:`CHAIN_FORMAT`."""
        return FORMAT if self.turn_axis is not None else CHAIN_FORMAT

    def _check(self, axes) -> np.ndarray:
        return check_points(axes, f"axes ({', '.join(self.axis_columns)})", self.n_axes)

    @property
    def layer_sizes(self) -> tuple:
        return (self.n_inputs, *self.hidden, 3)

    @property
    def shapes(self) -> list:
        """(out, in) weight shape and (out,) bias shape per layer, in ``theta`` order."""
        s = self.layer_sizes
        out = []
        for i in range(len(s) - 1):
            out += [(s[i + 1], s[i]), (s[i + 1],)]
        return out

    @property
    def n_params(self) -> int:
        return sum(math.prod(s) for s in self.shapes)

    def init_params(self, seed: int = 0) -> torch.Tensor:
        """Nguyen–Widrow-like uniform init (PyTorch's Linear default bounds), from a seeded generator."""
        g = torch.Generator().manual_seed(int(seed))
        parts = []
        for i, shp in enumerate(self.shapes):
            fan_in = self.shapes[i - (i % 2)][1]
            bound = 1.0 / math.sqrt(fan_in)
            if self.activation == "sigmoid" and i % 2 == 0 and i < len(self.shapes) - 2:
                bound *= 4.0  # sigmoid is 4x flatter than tanh at 0 (Glorot's rule)
            parts.append((torch.rand(math.prod(shp), generator=g, dtype=DTYPE) * 2 - 1) * bound)
        return torch.cat(parts)

    def layers(self, theta: torch.Tensor) -> list:
        """``[(W (out, in), b (out,))]`` per layer: views of the flat parameter vector ``theta``."""
        out, k = [], 0
        for (o, n_in), _ in zip(self.shapes[0::2], self.shapes[1::2]):
            out.append((theta[k:k + o * n_in].view(o, n_in), theta[k + o * n_in:k + o * n_in + o]))
            k += o * n_in + o
        return out

    def act_and_slope(self, z: torch.Tensor):
        """The activation at the pre-activations ``z`` and its derivative there."""
        if self.activation == "sigmoid":
            h = torch.sigmoid(z)
            return h, h * (1 - h)
        if self.activation == "tanh":
            h = torch.tanh(z)
            return h, 1 - h * h
        return torch.nn.functional.softplus(z), torch.sigmoid(z)

    def forward(self, theta: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Scaled outputs from scaled features; ``u`` shape (n, n_inputs) or (n_inputs,)."""
        act = ACTIVATIONS[self.activation]
        layers = self.layers(theta)
        h = u
        for i, (W, b) in enumerate(layers):
            h = h @ W.T + b
            if i < len(layers) - 1:
                h = act(h)
        return h

    def param_jacobian(self, theta: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """∂(scaled outputs)/∂theta per sample, shape (n, 3, P), by explicit backpropagation.

        Equal to ``vmap(jacrev(forward))`` from :mod:`torch.func` (tested) and about ten
        times faster, because all samples and the three outputs go through one batched
        backward pass of plain matrix products.
        """
        layers = self.layers(theta)
        n_layers = len(layers)
        acts, dacts = [u], []
        h = u
        for W, b in layers[:-1]:
            h, d = self.act_and_slope(h @ W.T + b)
            dacts.append(d)
            acts.append(h)
        n = u.shape[0]
        blocks = [None] * (2 * n_layers)
        delta = torch.eye(3, dtype=u.dtype).expand(n, 3, 3)  # (n, out k, units of last layer)
        for i in range(n_layers - 1, -1, -1):
            a_prev = acts[i]  # (n, in)
            blocks[2 * i] = (delta[:, :, :, None] * a_prev[:, None, None, :]).reshape(n, 3, -1)
            blocks[2 * i + 1] = delta
            if i > 0:
                delta = (delta @ layers[i][0]) * dacts[i - 1][:, None, :]
        return torch.cat(blocks, dim=2)

    # -- scaling ------------------------------------------------------------------------
    def fit_scalers(self, axes, errors_um) -> "MLPField":
        """Set the input ranges and output scaling from training data; returns self."""
        axes = self._check(axes)
        e = np.asarray(errors_um, dtype=float)
        lo, hi = axes.min(axis=0), axes.max(axis=0)
        hi = np.where(hi > lo, hi, lo + 1.0)
        self.in_lo_, self.in_hi_ = lo, hi
        if self.turn_axis is not None:
            self.a0_deg_ = float(lo[self.turn_axis])
        self.out_mean_ = 0.5 * (e.max(axis=0) + e.min(axis=0))
        self.out_scale_ = float(max(0.5 * (e.max(axis=0) - e.min(axis=0)).max(), 1e-12))
        return self

    def features(self, axes) -> np.ndarray:
        """Scaled network inputs from raw axes, shape (n, n_inputs). The turn axis is wrapped first."""
        x = self._wrapped(self._check(axes))
        lo, hi = self.in_lo_, self.in_hi_
        return self._encode(x, 2.0 * (x - lo) / (hi - lo) - 1.0)

    def _wrapped(self, axes) -> np.ndarray:
        """Axes (n, k) with the turn axis (if any) folded into the training turn (:func:`wrap_a`)."""
        t = self.turn_axis
        if t is None:
            return axes
        return np.column_stack([axes[:, :t], wrap_a(axes[:, t], self.a0_deg_), axes[:, t + 1:]])

    def _encode(self, x, u) -> np.ndarray:
        """Network inputs (n, n_inputs): the scaled columns ``u`` (n, k), a periodic axis of ``x`` as cos/sin."""
        if not any(self.periodic):
            return u
        return np.column_stack(periodic_columns(self.periodic, x, u))

    def scale_errors(self, errors_um) -> np.ndarray:
        return (np.asarray(errors_um, dtype=float) - self.out_mean_) / self.out_scale_

    def unscale_errors(self, y) -> np.ndarray:
        return np.asarray(y) * self.out_scale_ + self.out_mean_

    # -- the error-field interface (errormap.field.ErrorField) ----------------------------
    @property
    def calibrated_volume(self) -> CalibratedVolume | None:
        """The training inputs' range ``in_lo_``..``in_hi_`` (its axis columns); None before training."""
        if "in_lo_" not in self.__dict__:
            return None
        return CalibratedVolume(self.in_lo_, self.in_hi_, self.axis_columns)

    def offset_fitness(self, machine, targets_mm):
        """The batched GA's fitness around WCS targets (n, 3) mm as one float32 torch pipeline
        (:class:`training.ga_fitness.FusedOffsetFitness`; the ``offset_fitness`` capability)."""
        from .ga_fitness import FusedOffsetFitness
        return FusedOffsetFitness(self, machine, targets_mm)

    def _theta(self) -> torch.Tensor:
        if not hasattr(self, "theta_"):
            raise RuntimeError("MLPField is not trained: call a trainer or MLPField.load first")
        return self.theta_

    def predict(self, axes, dtype=np.float64) -> np.ndarray:
        """Spatial error (dx_um, dy_um, dz_um) at raw axes shape (n, k) -> shape (n, 3) μm, float64.

        ``dtype=np.float32`` runs the network in float32 (features are computed in float64
        first): about 2x faster, values within a few nm of float64 (≤ 1e-3 μm tested on a
        ~50 μm field, ``tests/test_model_inference.py``; 0.004 μm measured on the demo's
        trained field). Meant for GA fitness and Newton starts; every residual stays float64.
        """
        axes = self._check(axes)
        self._theta()
        return self._infer(axes, jac=False, dtype=dtype)[0]

    __call__ = predict

    def jacobian(self, axes) -> np.ndarray:
        """∂(error μm)/∂(axes) at raw axes, shape (n, 3, k).

        Row i is the error component (dx, dy, dz); columns are μm/mm or μm/deg per axis.
        Forward mode by hand, alongside the forward pass (:meth:`predict_and_jacobian`);
        the seam correction of the raw A input is included.
        """
        return self.predict_and_jacobian(axes)[1]

    def predict_and_jacobian(self, axes, dtype=np.float64):
        """Both at once (one pass): (errors shape (n, 3) μm, jacobian shape (n, 3, k)).

        Forward-mode differentiation written out: with ``z = W h + b`` and ``h' = σ(z)`` the
        three input tangents (one per axis) go through each layer as ``dh' = σ'(z) ⊙ (W dh)``,
        as one matrix product over all points and the three tangents; equal to ``torch.func.jvp``
        to float64 rounding (tested).
        ``dtype=np.float32`` runs the network in float32 (a Newton start, where only the
        step direction matters); the arrays returned are float64 either way.
        """
        axes = self._check(axes)
        self._theta()
        return self._infer(axes, jac=True, dtype=dtype)

    # -- fast inference -----------------------------------------------------------------
    SEAM_WINDOW_DEG = 30.0
    """Width (deg) of the seam correction's ramp at the end of the training turn (raw A only)."""
    SMALL_BATCH = 2048
    """Calls with fewer points run torch on one thread (thread start-up dominates below this)."""
    BLOCK = 4096
    """Points per block inside a call (each layer's activations stay in cache)."""

    def _seam_window(self) -> float:
        """The seam ramp width (deg), 0 when no correction applies (no turn axis, or a periodic one)."""
        t = self.turn_axis
        if t is None or self.periodic[t] or not self.SEAM_WINDOW_DEG > 0:
            return 0.0  # SEAM_WINDOW_DEG = 0 switches the correction off (the bare network)
        return float(min(self.SEAM_WINDOW_DEG, 360.0))

    def _input_col(self) -> list:
        """The first network input column of each axis (a periodic axis takes two)."""
        out, c = [], 0
        for per in self.periodic:
            out.append(c)
            c += 2 if per else 1
        return out

    def _net(self, dtype):
        """Cached per-dtype weights ``W`` (out, in) and biases (out, 1), and the input scalers.

        The cache is keyed on the parameter tensor (identity and in-place version) and the
        scalers, so retraining or reloading invalidates it.
        """
        theta = self._theta()
        key = (id(theta), theta._version, id(self.in_lo_), id(self.in_hi_), self.out_scale_,
               self.__dict__.get("a0_deg_"), self.activation, self.periodic, self.hidden)
        cache = self.__dict__.get("_net_cache")
        if cache is None or cache[0] != key:
            cache = (key, {})
            self.__dict__["_net_cache"] = cache
        nets = cache[1]
        if dtype not in nets:
            tdt = torch.float32 if dtype == np.float32 else torch.float64
            k = self.n_axes
            with torch.no_grad():
                layers = [(W.contiguous().to(tdt), b.reshape(-1, 1).to(tdt))
                          for W, b in self.layers(theta.detach())]
                s = 2.0 / (self.in_hi_ - self.in_lo_)
                W1 = layers[0][0]  # (h1, n_inputs)
                # first layer's pre-activation tangent per axis, (h1, k axes, 1); a periodic
                # axis's tangent depends on the point and is built in _net_cols
                tan0 = torch.zeros((W1.shape[0], k, 1), dtype=tdt)
                for j, c in enumerate(self._input_col()):
                    if not self.periodic[j]:
                        tan0[:, j, 0] = W1[:, c] * float(s[j])
            lo = np.asarray(self.in_lo_, dtype=float)
            net = {"layers": layers, "s": s, "lo": lo, "tan0": tan0, "tdt": tdt,
                   "lo_col": torch.as_tensor(lo, dtype=tdt).reshape(k, 1),
                   "s_col": torch.as_tensor(s, dtype=tdt).reshape(k, 1),
                   "out_mean_col": torch.as_tensor(self.out_mean_, dtype=tdt).reshape(3, 1)}
            if not any(self.periodic):
                net["raw_um_layers"] = self._raw_um_layers(layers, s, lo, tdt)
            nets[dtype] = net
        return nets[dtype]

    def _raw_um_layers(self, layers, s, lo, tdt) -> list:
        """The same network on raw axes in, μm out (:meth:`predict_columns`): the input scaling folded
        into the first layer, the output scaling into the last (from float64)."""
        with torch.no_grad():
            L = [(w.to(torch.float64), b.to(torch.float64)) for w, b in layers]
            s64 = torch.as_tensor(s, dtype=torch.float64)
            lo64 = torch.as_tensor(lo, dtype=torch.float64)
            W1, b1 = L[0]
            first = (W1 * s64, b1 - W1 @ (lo64 * s64 + 1.0).reshape(-1, 1))
            Wn, bn = L[-1]
            mean = torch.as_tensor(self.out_mean_, dtype=torch.float64).reshape(3, 1)
            last = (Wn * self.out_scale_, bn * self.out_scale_ + mean)
            raw = [first, *L[1:-1], last] if len(L) > 1 else [(first[0] * self.out_scale_,
                                                                first[1] * self.out_scale_ + mean)]
            return [(w.to(tdt).contiguous(), b.to(tdt).contiguous()) for w, b in raw]

    def _features_wrapped(self, x, net) -> np.ndarray:
        """Scaled network inputs of axes whose turn axis is already in the training turn, (n, n_inputs)."""
        return self._encode(x, (x - net["lo"]) * net["s"] - 1.0)

    def _first_tangent(self, W, u, net):
        """d(first layer's pre-activations)/d(axes), (h1, k, 1) or (h1, k, m) with a periodic axis
        (d(cos r, sin r)/dq = (-sin r, cos r)·π/180, from the feature columns ``u`` (n_inputs, m))."""
        if not any(self.periodic):
            return net["tan0"]  # (h1, k, 1), broadcast over the points
        k = math.pi / 180.0
        T = net["tan0"].expand(W.shape[0], self.n_axes, u.shape[1]).clone()
        for j, c in enumerate(self._input_col()):
            if self.periodic[j]:
                T[:, j] = torch.outer(W[:, c], -u[c + 1] * k) + torch.outer(W[:, c + 1], u[c] * k)
        return T

    def _net_cols(self, u, net, jac: bool):
        """The network on feature columns ``u`` (n_inputs, m) (torch, the net's dtype).

        Returns (scaled outputs (3, m), tangents d(outputs)/d(axes) (3 outputs, k axes, m) or
        None). Points are columns: each layer is one ``addmm(b, W, h)`` with W (out, in), which
        runs faster on these narrow layers than the row layout; the k tangents of a layer
        are one (units, k·m) matrix, so they too take one matrix product.
        """
        layers = net["layers"]
        last = len(layers) - 1
        act = self.activation
        m, k = u.shape[1], self.n_axes
        h, T = u, None
        for i, (W, b) in enumerate(layers):
            z = torch.addmm(b, W, h)
            if jac:
                if i == 0:
                    T = self._first_tangent(W, u, net)
                else:
                    T = torch.mm(W, T.view(T.shape[0], k * m)).view(W.shape[0], k, m)
            if i == last:
                return z, T
            if act == "sigmoid":
                h = torch.sigmoid_(z)
                if jac:
                    d = h * (1.0 - h)
            elif act == "tanh":
                h = torch.tanh_(z)
                if jac:
                    d = 1.0 - h * h
            else:
                if jac:
                    d = torch.sigmoid(z)
                h = torch.nn.functional.softplus(z)
            if jac:
                d = d.unsqueeze(1)
                T = T * d if i == 0 else T.mul_(d)
        raise AssertionError("unreachable")  # pragma: no cover

    def _run_net(self, x, net, jac: bool, out_e, out_j):
        """The network on wrapped axes x (n, k) float64, in blocks; scaled outputs into out_e (n, 3)
        and, with ``jac``, d(scaled)/d(axes) into out_j (n, 3, k) (torch float64 views)."""
        tdt = net["tdt"]
        blk = max(1, min(self.chunk, self.BLOCK))
        for s0 in range(0, x.shape[0], blk):
            xs = x[s0:s0 + blk]
            m = xs.shape[0]
            u = torch.from_numpy(np.ascontiguousarray(self._features_wrapped(xs, net).T)).to(tdt)
            y, T = self._net_cols(u, net, jac)
            out_e[s0:s0 + m] = y.T
            if jac:
                out_j[s0:s0 + m] = T.permute(2, 0, 1)  # (3 outputs, k axes, m) -> (m, outputs, axes)

    COLUMNS_BLOCK = {torch.float32: 16_384, torch.float64: 8_192}
    """Columns per network call in :meth:`predict_columns` (activations stay in cache)."""

    def predict_columns(self, xa):
        """Errors μm at axis columns ``xa`` (k, m) -> (3, m) (the grinder: [x_mm; z_mm; a_deg]).

        The solvers' inner loop (the ``predict_columns`` capability): a numpy array in, a numpy
        array out (sharing memory with the tensor computed), or a torch tensor in, the same dtype
        (float32 or float64) out, no validation and no copies. A turn axis is folded into the training
        turn ``[a0, a0 + 360)`` (E is periodic, so the turn's end maps onto its start) and the seam
        correction is applied as in :meth:`predict`; equal to :meth:`predict` to float
        rounding (tested). Without a periodic input the input and output scalings are folded into
        the first and last layers.
        """
        if isinstance(xa, np.ndarray):
            return self.predict_columns(torch.from_numpy(xa)).numpy()
        net = self._net(np.float32 if xa.dtype == torch.float32 else np.float64)
        m, t = xa.shape[1], self.turn_axis
        with torch.inference_mode():
            if t is not None:
                a = torch.remainder(xa[t] - self.a0_deg_, 360.0) + self.a0_deg_
                xa = torch.cat([xa[:t], a.unsqueeze(0), xa[t + 1:]])
            blk = self.COLUMNS_BLOCK.get(xa.dtype, 8_192)
            if m <= blk:
                return self._columns(xa, net)
            out = torch.empty((3, m), dtype=xa.dtype)
            for s0 in range(0, m, blk):
                out[:, s0:s0 + blk] = self._columns(xa[:, s0:s0 + blk], net)
            return out

    def _columns(self, xa, net):
        """:meth:`predict_columns` on one block whose turn axis lies in the training turn."""
        if any(self.periodic):
            u = (xa - net["lo_col"]) * net["s_col"] - 1.0
            cols = []
            for j, per in enumerate(self.periodic):
                if per:
                    r = torch.deg2rad(xa[j])
                    cols += [torch.cos(r), torch.sin(r)]
                else:
                    cols.append(u[j])
            return self._net_cols(torch.stack(cols), net, False)[0] * self.out_scale_ + net["out_mean_col"]
        raw = {"layers": net["raw_um_layers"]}
        w, t = self._seam_window(), self.turn_axis
        sel = torch.nonzero(xa[t] > self.a0_deg_ + 360.0 - w).squeeze(1) if w else None
        if sel is None or sel.numel() == 0:
            return self._net_cols(xa, raw, False)[0]
        # the seam points again at both ends of the turn, in the same network call
        m, k = xa.shape[1], sel.numel()
        x = torch.empty((xa.shape[0], m + 2 * k), dtype=xa.dtype)
        x[:, :m] = xa
        xs = xa[:, sel]
        x[:, m:m + k] = xs
        x[:, m + k:] = xs
        x[t, m:m + k] = self.a0_deg_
        x[t, m + k:] = self.a0_deg_ + 360.0
        y_all = self._net_cols(x, raw, False)[0]
        y = y_all[:, :m]
        tk = (xs[t] - (self.a0_deg_ + 360.0 - w)) / w
        y[:, sel] += (y_all[:, m:m + k] - y_all[:, m + k:]) * (tk * tk * (3.0 - 2.0 * tk))
        return y

    def _infer(self, axes, jac: bool, dtype=np.float64):
        """Errors μm (n, 3) [and Jacobian (n, 3, k)] at raw axes, with the seam correction."""
        dtype = np.float32 if np.dtype(dtype) == np.float32 else np.float64
        n, t = axes.shape[0], self.turn_axis
        x = self._wrapped(axes)
        w = self._seam_window()
        if w:
            tt = (x[:, t] - (self.a0_deg_ + 360.0 - w)) / w
            sel = np.flatnonzero(tt > 0)
        else:
            sel = np.empty(0, dtype=np.intp)
        k = sel.size
        if k:  # the seam points again at both ends of the turn
            start, end = x[sel], x[sel]
            start[:, t], end[:, t] = self.a0_deg_, self.a0_deg_ + 360.0
            x = np.concatenate([x, start, end])
        net = self._net(dtype)
        y = np.empty((x.shape[0], 3))
        J = np.empty((x.shape[0], 3, self.n_axes)) if jac else None
        with torch.inference_mode(), limit_threads(1 if x.shape[0] < self.SMALL_BATCH else None):
            self._run_net(x, net, jac, torch.from_numpy(y), torch.from_numpy(J) if jac else None)
        e = y[:n]
        e *= self.out_scale_
        e += self.out_mean_
        if jac:
            Jn = J[:n]
            Jn *= self.out_scale_
        if k:
            tk = tt[sel]
            c = (y[n:n + k] - y[n + k:]) * self.out_scale_  # N(a0) - N(a0 + 360), μm
            ramp = tk * tk * (3.0 - 2.0 * tk)
            e[sel] += c * ramp[:, None]
            if jac:
                for j in (j for j in range(self.n_axes) if j != t):
                    Jn[sel, :, j] += ramp[:, None] * ((J[n:n + k, :, j] - J[n + k:, :, j]) * self.out_scale_)
                Jn[sel, :, t] += c * (6.0 * tk * (1.0 - tk) / w)[:, None]
        e = np.ascontiguousarray(e)
        return (e, np.ascontiguousarray(Jn)) if jac else (e, None)

    # -- files --------------------------------------------------------------------------
    def config(self) -> dict:
        if self.format == FORMAT:
            return {"format": FORMAT, "hidden": list(self.hidden), "activation": self.activation,
                    "a_encoding": self.a_encoding, "n_params": self.n_params,
                    "inputs": list(INPUTS), "outputs": ["dx_um", "dy_um", "dz_um"]}
        return {"format": CHAIN_FORMAT, "hidden": list(self.hidden), "activation": self.activation,
                "n_params": self.n_params, "inputs": list(self.axis_columns), "periodic": list(self.periodic),
                "machine": self.machine, "machine_sha256": self.machine_sha256,
                "outputs": ["dx_um", "dy_um", "dz_um"]}

    def scalers(self) -> dict:
        turn = {"a0_deg": self.a0_deg_} if self.turn_axis is not None else {}
        return {"in_lo": self.in_lo_, "in_hi": self.in_hi_, **turn,
                "out_mean_um": self.out_mean_, "out_scale_um": self.out_scale_}

    def save(self, directory) -> Path:
        """Write ``config.json``, ``scalers.json`` and ``weights.npy`` (float64) as one set.

        The three files are written into a temporary folder beside ``directory`` which then
        replaces ``directory`` whole (:func:`errormap.io.atomic_dir`): a crash leaves the old
        model or none, never new scalers beside old weights. ``config.json`` (written last)
        records the SHA-256 of the other two files, and :meth:`load` refuses a set whose files
        do not match it. ``directory`` must be a model folder of its own (it is replaced).
        """
        d = Path(directory)
        extra = self._extra_file_names()
        if d.is_dir():
            foreign = sorted(p.name for p in d.iterdir() if p.name not in ("config.json", OUTPUT_LOCK_NAME) + MODEL_FILES + extra)
            if foreign:
                raise InputError(f"{d}: a saved model replaces this folder whole, and it holds other files "
                                 f"({', '.join(foreign[:5])}); give a folder of its own")
        with atomic_dir(d) as tmp:
            # repr() round-trips float64 exactly through JSON
            write_json(tmp / "scalers.json", {k: (np.asarray(v).tolist()) for k, v in self.scalers().items()})
            with atomic_write(tmp / "weights.npy", "wb") as fh:
                np.save(fh, self._theta().detach().numpy())
            self._write_extra_files(tmp)
            files = {n: sha256_file(tmp / n) for n in MODEL_FILES + extra}
            write_json(tmp / "config.json", {**self.config(), "files_sha256": files})
        return d

    @classmethod
    def load(cls, directory) -> "MLPField":
        """Load a folder written by :meth:`save`; raises :class:`InputError` for a missing file,
        another format or a file whose SHA-256 differs from the one ``config.json`` records."""
        d, cfg = cls._config(directory, (FORMAT, CHAIN_FORMAT), "MLPField")
        if cfg.get("physics") and cls is MLPField:  # a network on what a fitted physical part leaves
            return PhysicsMLPField.load(d)
        check_model_files(cls, d, cfg)
        try:
            sc = json.loads(read_document_text(d / "scalers.json", "a trained model's scalers"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{d / 'scalers.json'}: not valid JSON: {exc}") from None
        try:
            if cfg["format"] == FORMAT:
                m = cls(cfg["hidden"], cfg["activation"], cfg["a_encoding"])
                m.a0_deg_ = float(sc["a0_deg"])
            else:
                m = cls(cfg["hidden"], cfg["activation"], axis_columns=cfg["inputs"], periodic=cfg["periodic"],
                        machine=cfg.get("machine", ""), machine_sha256=cfg.get("machine_sha256", ""))
            m.in_lo_ = np.asarray(sc["in_lo"], dtype=float)
            m.in_hi_ = np.asarray(sc["in_hi"], dtype=float)
            m.out_mean_ = np.asarray(sc["out_mean_um"], dtype=float)
            m.out_scale_ = float(sc["out_scale_um"])
        except KeyError as exc:
            raise InputError(f"{d}: config.json/scalers.json: missing key {exc}") from None
        except (ValueError, TypeError) as exc:
            raise InputError(f"{d / 'config.json'}: {exc}") from None
        if m.in_lo_.shape != (m.n_axes,) or m.in_hi_.shape != (m.n_axes,) or m.out_mean_.shape != (3,):
            raise InputError(f"{d / 'scalers.json'}: keys 'in_lo'/'in_hi': expected {m.n_axes} values "
                             f"({', '.join(m.axis_columns)}) and 'out_mean_um' 3")
        return m._read_weights(d)

    @staticmethod
    def _config(directory, fmts: tuple, what: str) -> tuple:
        """``(folder, its config.json)`` of a folder written by :meth:`save` in one of ``fmts``; InputError
        naming the file for a missing file (``what``: the model's name), bad JSON or another format."""
        d = Path(directory)
        for name in ("config.json",) + MODEL_FILES:
            if not (d / name).is_file():
                raise InputError(f"{d}: not a saved {what} (missing {name})")
        try:
            cfg = json.loads(read_document_text(d / "config.json", "a trained model's config"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{d / 'config.json'}: not valid JSON: {exc}") from None
        check_model_format(d, cfg, fmts)
        return d, cfg

    def _read_weights(self, d: Path):
        """The weights (``weights.npy``, ``n_params`` values) and extra files of a saved folder ``d``; returns self."""
        theta = load_array(d / "weights.npy", "weights file")
        if theta.shape != (self.n_params,):
            raise InputError(f"{d / 'weights.npy'}: expected {self.n_params} parameters, got shape {theta.shape}")
        self.theta_ = torch.from_numpy(theta.astype(np.float64))
        self._read_extra_files(d)
        return self

    @staticmethod
    def _extra_file_names() -> tuple:
        """Files a subclass saves beside the network's (their SHA-256 recorded in config.json)."""
        return ()

    def _write_extra_files(self, folder: Path) -> None:
        pass

    def _read_extra_files(self, folder: Path) -> None:
        pass


class PhysicsMLPField(PhysicsPart, MLPField):
    """The network on the residual of a fitted physical part: ``E = HTM(elements)(axes) + network(axes)``.

    ``physics_`` is an :class:`~errormap.chain_elements.ChainElementSet` fitted to the same feature points
    the network is trained on (:func:`training.physics.fit_physics_elements`), evaluated with the
    exact HTM model of ``physics_machine_`` (:class:`training.physics.PhysicsPart`); the network
    (every setting of :class:`MLPField`) learns the feature points minus that part. Capabilities:
    ``jacobian`` and ``predict_and_jacobian`` only (the float32 and fused GA paths are the
    network's alone; solvers use the float64 value and Jacobian here). Saved as the network's files
    plus ``physics_elements.json`` and ``physics_machine.toml`` (the machine file's bytes; refused on
    load when its axis columns are not the network's, or its SHA-256 not the one the network records).
    """

    kind = "mlp+physics"
    capabilities = frozenset({JACOBIAN, PREDICT_AND_JACOBIAN})

    def _physics_field(self, machine, elements):
        from errormap.chain_field import ChainField
        return ChainField(machine, elements)

    def _physics_axes(self, axes) -> np.ndarray:
        return self._check(axes)

    def _read_physics(self, folder: Path):
        from errormap.chain_elements import ChainElementSet
        from errormap.machine import load_machine
        machine = load_machine(folder / PHYSICS_FILES[1])
        if getattr(machine, "kind", None) != "machine-tool" or tuple(machine.axis_columns) != self.axis_columns:
            raise InputError(f"{folder / PHYSICS_FILES[1]}: not the machine-tool chain over "
                             f"{', '.join(self.axis_columns)} the network takes")
        if self.machine_sha256 and machine.sha256 != self.machine_sha256:
            raise InputError(f"{folder / PHYSICS_FILES[1]}: SHA-256 differs from the machine_sha256 config.json "
                             "records; the folder holds a partial or mixed set")
        return machine, ChainElementSet.load(folder / PHYSICS_FILES[0], machine)

    def predict_columns(self, xa):
        """Columns (k, m) in, (3, m) out, float64 (not a declared capability: the sum is not fused)."""
        x = xa.numpy() if isinstance(xa, torch.Tensor) else np.asarray(xa)
        out = self.predict(np.ascontiguousarray(np.asarray(x, dtype=np.float64).T)).T
        return torch.from_numpy(np.ascontiguousarray(out)).to(xa.dtype) if isinstance(xa, torch.Tensor) else out

    def offset_fitness(self, machine, targets_mm):
        raise TypeError("PhysicsMLPField declares no offset_fitness (the fused GA pipeline is the network's alone)")


def check_machine(model: MLPField, machine, where) -> MLPField:
    """Refuse (InputError naming ``where``) a network trained on another machine: other axis columns, or
    another machine name (recorded in the chain format)."""
    if tuple(machine.axis_columns) != model.axis_columns:
        raise InputError(f"{where}: key 'inputs': the network takes {', '.join(model.axis_columns)}, the machine "
                         f"{machine.name!r} has {', '.join(machine.axis_columns)}")
    if model.machine and model.machine != machine.name:
        raise InputError(f"{where}: key 'machine': the network was trained on {model.machine!r}, not on "
                         f"{machine.name!r}")
    return model
