"""The error-field network over a machine-tool chain's own axes, and its training.

:class:`ChainMLPField` is :class:`training.model.MLPField` (layers, activations, trainers, output scaling,
file set) with one input per axis column of the chain, each scaled from its training range to ``[-1, 1]``, a
full-turn rotary axis as ``(cos q, sin q)`` (exactly periodic). Output: the tool point's error (μm) in the
workpiece frame, with the input Jacobian (n, 3, k) by forward-mode tangents. Its files record the format
``volcomp-chain-mlpfield/1``, the axis columns and the machine (:func:`check_machine` refuses another);
:func:`training.trainers.fit_field` trains it (given the machine). docs/reference/learned-stage.md
("The network over a chain")."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from errormap.field import JACOBIAN, PREDICT_AND_JACOBIAN, CalibratedVolume
from errormap.io import InputError, read_document_text

from .model import A_ENCODINGS, PAPER_HIDDEN, MLPField, check_model_files
from .physics import PHYSICS_FILES, PhysicsPart

CHAIN_FORMAT = "volcomp-chain-mlpfield/1"


class ChainMLPField(MLPField):
    """An MLP error field over a machine-tool chain's axes (module docstring).

    Settings: ``axis_columns`` (the machine's, in order), ``periodic`` (one bool per axis: a
    full-turn rotary axis, fed as cos/sin), ``machine`` (its name), ``machine_sha256``,
    ``hidden``, ``activation``, ``chunk``. Learned: ``theta_``, ``in_lo_``/``in_hi_`` (k,),
    ``out_mean_`` (3,) μm, ``out_scale_`` μm.
    """

    kind = "chain-mlp"
    capabilities = frozenset({JACOBIAN, PREDICT_AND_JACOBIAN})

    def __init__(self, axis_columns, periodic=None, machine: str = "", machine_sha256: str = "",
                 hidden=PAPER_HIDDEN, activation: str = "sigmoid", chunk: int = 65_536):
        super().__init__(hidden, activation, "periodic", chunk)
        self.axis_columns = tuple(str(c) for c in axis_columns)
        self.periodic = tuple(bool(p) for p in (periodic if periodic is not None else [False] * len(self.axis_columns)))
        self.machine = str(machine)
        self.machine_sha256 = str(machine_sha256)
        if not self.axis_columns or len(self.periodic) != len(self.axis_columns):
            raise ValueError(f"Expected one periodic flag per axis column {self.axis_columns}, got {self.periodic}")
        if any(p and not c.endswith("_deg") for c, p in zip(self.axis_columns, self.periodic)):
            raise ValueError(f"Expected periodic axes in degrees, got {self.axis_columns} / {self.periodic}")

    @classmethod
    def for_machine(cls, machine, a_encoding: str = "raw", **settings) -> "ChainMLPField":
        """The untrained field over ``machine``'s axes (a :class:`errormap.machine_tool.MachineTool`):
        a full-turn rotary axis as (cos, sin) always; a rotary axis short of a full turn as one
        scaled input (``a_encoding="raw"``) or as (cos, sin) too (``"periodic"``)."""
        if a_encoding not in A_ENCODINGS:
            raise ValueError(f"Expected a_encoding in {A_ENCODINGS}, got {a_encoding!r}")
        return cls(machine.axis_columns,
                   [a.kind == "rotary" and (a.full_turn or a_encoding == "periodic") for a in machine.axes],
                   machine.name, machine.sha256 or "", **settings)

    @property
    def n_axes(self) -> int:
        return len(self.axis_columns)

    @property
    def n_inputs(self) -> int:
        return self.n_axes + sum(self.periodic)

    def _check(self, axes) -> np.ndarray:
        a = np.atleast_2d(np.asarray(axes, dtype=float))
        if a.ndim != 2 or a.shape[1] != self.n_axes:
            raise ValueError(f"expected axes of shape (n, {self.n_axes}) ({', '.join(self.axis_columns)}), "
                             f"got {np.shape(axes)}")
        if not np.all(np.isfinite(a)):
            raise ValueError("axes contain NaN or infinite values")
        return a

    def fit_scalers(self, axes, errors_um) -> "ChainMLPField":
        axes = self._check(axes)
        e = np.asarray(errors_um, dtype=float)
        lo, hi = axes.min(axis=0), axes.max(axis=0)
        self.in_lo_, self.in_hi_ = lo, np.where(hi > lo, hi, lo + 1.0)
        self.out_mean_ = 0.5 * (e.max(axis=0) + e.min(axis=0))
        self.out_scale_ = float(max(0.5 * (e.max(axis=0) - e.min(axis=0)).max(), 1e-12))
        return self

    def _features_and_tangents(self, axes, jac: bool):
        """Scaled inputs (n, n_inputs) and d(inputs)/d(axes) (n_inputs, k) per point or None."""
        n = axes.shape[0]
        s = 2.0 / (self.in_hi_ - self.in_lo_)
        cols, tang = [], []
        for j, per in enumerate(self.periodic):
            if per:
                r = np.deg2rad(axes[:, j])
                c, sn = np.cos(r), np.sin(r)
                cols += [c, sn]
                if jac:
                    k = math.pi / 180.0
                    tang += [(j, -sn * k), (j, c * k)]
            else:
                cols.append((axes[:, j] - self.in_lo_[j]) * s[j] - 1.0)
                if jac:
                    tang.append((j, np.full(n, s[j])))
        u = np.column_stack(cols)
        if not jac:
            return u, None
        T = np.zeros((n, self.n_inputs, self.n_axes))
        for i, (j, v) in enumerate(tang):
            T[:, i, j] = v
        return u, T

    def features(self, axes) -> np.ndarray:
        """Scaled network inputs, shape (n, n_inputs)."""
        return self._features_and_tangents(self._check(axes), False)[0]

    @property
    def calibrated_volume(self) -> CalibratedVolume | None:
        if "in_lo_" not in self.__dict__:
            return None
        return CalibratedVolume(self.in_lo_, self.in_hi_, self.axis_columns)

    def predict(self, axes, dtype=np.float64) -> np.ndarray:
        """Spatial error (dx_um, dy_um, dz_um), (n, k) -> (n, 3) μm, float64."""
        return self._infer_rows(self._check(axes), jac=False)[0]

    __call__ = predict

    def predict_and_jacobian(self, axes, dtype=np.float64):
        """``(E (n, 3) μm, dE/d(axes) (n, 3, k) μm per mm / per deg)``; float64 only."""
        if np.dtype(dtype) != np.float64:
            raise ValueError(f"Expected dtype float64 (ChainMLPField declares no float32), got {np.dtype(dtype)}")
        return self._infer_rows(self._check(axes), jac=True)

    def jacobian(self, axes) -> np.ndarray:
        return self.predict_and_jacobian(axes)[1]

    def _infer_rows(self, axes, jac: bool):
        layers = self.layers(self._theta().detach())
        n = axes.shape[0]
        E = np.empty((n, 3))
        J = np.empty((n, 3, self.n_axes)) if jac else None
        blk = max(1, self.chunk)
        with torch.inference_mode():
            for s0 in range(0, n, blk):
                u, T = self._features_and_tangents(axes[s0:s0 + blk], jac)
                h = torch.from_numpy(u)
                Tt = torch.from_numpy(T) if jac else None      # (m, units, k)
                for i, (W, b) in enumerate(layers):
                    z = h @ W.T + b
                    if jac:
                        Tt = torch.matmul(W, Tt)
                    if i == len(layers) - 1:
                        h = z
                        break
                    h, d = self.act_and_slope(z)
                    if jac:
                        Tt = Tt * d.unsqueeze(2)
                E[s0:s0 + blk] = h.numpy() * self.out_scale_ + self.out_mean_
                if jac:
                    J[s0:s0 + blk] = Tt.numpy() * self.out_scale_
        return E, J

    def predict_columns(self, xa):  # pragma: no cover - not declared (capabilities)
        raise NotImplementedError("ChainMLPField declares no predict_columns")

    def offset_fitness(self, machine, targets_mm):  # pragma: no cover - not declared (capabilities)
        raise NotImplementedError("ChainMLPField declares no offset_fitness")

    # -- files --------------------------------------------------------------------------
    def config(self) -> dict:
        return {"format": CHAIN_FORMAT, "hidden": list(self.hidden), "activation": self.activation,
                "n_params": self.n_params, "inputs": list(self.axis_columns), "periodic": list(self.periodic),
                "machine": self.machine, "machine_sha256": self.machine_sha256,
                "outputs": ["dx_um", "dy_um", "dz_um"]}

    def scalers(self) -> dict:
        return {"in_lo": self.in_lo_, "in_hi": self.in_hi_, "out_mean_um": self.out_mean_,
                "out_scale_um": self.out_scale_}

    @classmethod
    def load(cls, directory) -> "ChainMLPField":
        """Load a folder written by :meth:`save` (InputError naming file and key otherwise)."""
        d, cfg = cls._config(directory, CHAIN_FORMAT, "chain network")
        if cfg.get("physics") and cls is ChainMLPField:  # a network on what a fitted physical part leaves
            return ChainPhysicsMLPField.load(d)
        check_model_files(cls, d, cfg)
        try:
            sc = json.loads(read_document_text(d / "scalers.json", "a trained model's scalers"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{d / 'scalers.json'}: not valid JSON: {exc}") from None
        try:
            m = cls(cfg["inputs"], cfg["periodic"], cfg.get("machine", ""), cfg.get("machine_sha256", ""),
                    cfg["hidden"], cfg["activation"])
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


class ChainPhysicsMLPField(PhysicsPart, ChainMLPField):
    """A chain network on the residual of the chain's own fitted element set:
    ``E = ChainField(machine, elements)(axes) + network(axes)`` (:class:`training.physics.PhysicsPart`;
    the element set by :func:`training.physics.fit_physics_elements` on the same feature
    points). Same capabilities, inputs and files as :class:`ChainMLPField`, plus
    ``physics_elements.json`` and ``physics_machine.toml`` (the machine file's bytes; refused on load
    when its SHA-256 is not the one the network records)."""

    kind = "chain-mlp+physics"

    def _physics_field(self, machine, elements):
        from errormap.chain_field import ChainField
        return ChainField(machine, elements)

    def _physics_axes(self, axes) -> np.ndarray:
        return self._check(axes)

    def _read_physics(self, folder: Path):
        from errormap.machine import load_machine
        from errormap.chain_elements import ChainElementSet
        machine = load_machine(folder / PHYSICS_FILES[1])
        if getattr(machine, "kind", None) != "machine-tool" or tuple(machine.axis_columns) != self.axis_columns:
            raise InputError(f"{folder / PHYSICS_FILES[1]}: not the machine-tool chain over "
                             f"{', '.join(self.axis_columns)} the network takes")
        if self.machine_sha256 and machine.sha256 != self.machine_sha256:
            raise InputError(f"{folder / PHYSICS_FILES[1]}: SHA-256 differs from the machine_sha256 config.json "
                             "records; the folder holds a partial or mixed set")
        return machine, ChainElementSet.load(folder / PHYSICS_FILES[0], machine)


def check_machine(model: ChainMLPField, machine, where) -> ChainMLPField:
    """Refuse (InputError naming ``where``) a chain network trained on another machine: other axis
    columns, or another machine name."""
    if tuple(machine.axis_columns) != model.axis_columns:
        raise InputError(f"{where}: key 'inputs': the network takes {', '.join(model.axis_columns)}, the machine "
                         f"{machine.name!r} has {', '.join(machine.axis_columns)}")
    if model.machine and model.machine != machine.name:
        raise InputError(f"{where}: key 'machine': the network was trained on {model.machine!r}, not on "
                         f"{machine.name!r}")
    return model


def load_network(folder):
    """The trained network saved in ``folder``, as its ``config.json``'s ``format`` names it: a
    :class:`ChainMLPField` (or its physics-first form) or an :class:`~training.model.MLPField` (or its)."""
    d = Path(folder)
    try:
        doc = json.loads(read_document_text(d / "config.json", "a trained model's config"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{d / 'config.json'}: not valid JSON: {exc}") from None
    return (ChainMLPField if isinstance(doc, dict) and doc.get("format") == CHAIN_FORMAT else MLPField).load(d)
