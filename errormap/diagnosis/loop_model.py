"""The model file (``model.json``, ``format: volcomp-model/1``; the older ``volcomp-chain-model/1`` read too):
its writer, and its elements and effect terms as an error field of a machine-tool chain.
Schema: ``docs/reference/file-formats.md``; ``compensation.model_file.read_model`` is the one reader.

:class:`ChainModelField` is ``E(q, c) = B(q) + t(q, c)``: ``B`` the :class:`errormap.chain_field.ChainField`
of the elements, ``t`` the terms' spatial contribution, exactly the columns the loop fitted
(:func:`errormap.diagnosis.chain_loop.effect_columns`). Value (n, 3) μm and axis Jacobian (n, 3, k): ``B``'s
compiled Jacobian plus the terms' by central differences (:data:`TERM_STEP`). A thermal term needs
``temp_c``, a reversal term ``dir_<w>`` (±1), given as constants or per-point arrays; a missing one is an
:class:`InputError` naming it."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..field import JACOBIAN, PREDICT_AND_JACOBIAN
from ..io import InputError, read_document_text, write_json
from ..machine_tool import MachineTool
from ..chain_elements import ChainElementSet
from ..chain_field import ChainField
from ..chain_truth import EFFECT_KINDS
from .chain_loop import EffectTerm, effect_columns

MODEL_FORMAT = "volcomp-model/1"
CHAIN_MODEL_FORMAT = "volcomp-chain-model/1"
"""The chain loop's model.json before :data:`MODEL_FORMAT` (read, never written)."""
READ_FORMATS = (MODEL_FORMAT, CHAIN_MODEL_FORMAT)
TERM_STEP = {"linear": 1e-3, "rotary": 1e-3}
"""Central-difference step (mm / deg) of the terms' axis Jacobian. The shortest shape the search fits is a
2 mm period (a harmonic of order 120 is 3° per cycle): truncation error h²/6·|t'''| ≤ 1e-6·(2π/2)³·10 μm
/ 6 ≈ 5e-7 μm/mm at 10 μm amplitude, round-off ~1e-16·10/1e-3 = 1e-12: far below what Newton needs."""
KINDS = EFFECT_KINDS
"""The kinds a chain model's terms may have: the chain's kinds from the registry (one vocabulary)."""


def term_needs(machine: MachineTool, term: EffectTerm) -> tuple:
    """Condition names a term needs (``temp_c``, ``dir_<w>``)."""
    if term.kind == "thermal":
        return ("temp_c",)
    if term.kind == "reversal":
        return (f"dir_{term.axes[0].lower()}",)
    return ()


def save_chain_model(path, machine: MachineTool, elements_file, terms=(), kept_stage: str = "elements", extra=None,
                     covariance_file=None, network=None, provenance=None) -> Path:
    """Write ``model.json`` (module doc; format :data:`MODEL_FORMAT`), whole. ``elements_file``: the element
    set's path (stored relative; None: no element set, a network alone); ``covariance_file``: its covariance
    (stored relative; None: none); ``network``: ``{"folder": path}`` (stored relative) or ``{"mlflow": uri}``;
    ``provenance``: ``{"written_by": ..., inputs ...}``. ``extra``: further keys (the learned-residual
    stage's ``learned_residual``, ``base_stage``, ``learned_family``, ``base_terms_replaced``, the verdict;
    written by the compensation layer, which owns the learned part; :data:`LEARNED_KEY`)."""
    path = Path(path)
    rel = (lambda f: None if f is None else _relative(f, path.parent))
    d = {"format": MODEL_FORMAT, "machine": machine.name, "machine_sha256": machine.sha256,
         "elements": rel(elements_file), "covariance": rel(covariance_file), "kept_stage": kept_stage,
         "terms": [t.to_dict() for t in terms],
         "network": ({"folder": rel(network["folder"])} if network and "folder" in network else
                     {"mlflow": str(network["mlflow"])} if network else None),
         "provenance": dict(provenance or {}),
         "note": "E(q, c) = ChainField(elements)(q) + sum of the terms' columns (error-Jacobian column of the "
                 "element at the nominal chain times the effect's shape) times their coefficients"}
    if extra:
        if LEARNED_KEY in extra:
            d["note"] += ("; + the learned residual (learned_residual: a regressor of the axes, tapered to zero "
                          "outside the checks' box; read by compensation.model_file)")
        d.update(extra)
    return write_json(path, d)


def _relative(f, folder: Path) -> str:
    """``f`` relative to ``folder`` when inside it (a file beside the model: its name), else as given."""
    f = Path(f)
    try:
        return f.resolve().relative_to(folder.resolve()).as_posix()
    except ValueError:
        return str(f)


LEARNED_KEY = "learned_residual"
"""The key of a kept learned-residual stage in ``model.json`` (:mod:`compensation.hybrid`'s saved form). The
learned part lives in the compensation layer: :func:`load_chain_model_file` reads the elements and terms
only and REFUSES a file that has it unless told to ignore it (``learned="ignore"``: a caller that needs the
elements alone, the report page), so no reader silently drops the kept stage's learned part;
``compensation.model_file.read_model`` reads the whole model."""
LEARNED_MODES = ("refuse", "ignore")


class ChainModelField:
    """Elements plus effect terms of a machine-tool chain, an error field (module doc).

    ``conditions``: {name: scalar or (n,)} for the terms that need them (per-point arrays must match the
    number of points evaluated)."""

    kind = "chain-model"

    def __init__(self, machine: MachineTool, elements: ChainElementSet, terms=(), conditions=None):
        self.machine = machine
        self.base = ChainField(machine, elements)
        self.elements = elements
        self.terms = list(terms)
        self.conditions = dict(conditions or {})

    @property
    def capabilities(self) -> frozenset:
        return frozenset({JACOBIAN, PREDICT_AND_JACOBIAN})

    @property
    def calibrated_volume(self):
        return self.base.calibrated_volume

    @property
    def needs(self) -> tuple:
        out = []
        for t in self.terms:
            out += [c for c in term_needs(self.machine, t) if c not in out]
        return tuple(out)

    def with_conditions(self, conditions: dict) -> "ChainModelField":
        return ChainModelField(self.machine, self.elements, self.terms, {**self.conditions, **conditions})

    def _cond(self, n: int) -> dict:
        missing = [c for c in self.needs if c not in self.conditions]
        if missing:
            raise InputError(f"the model's effect terms {[t.kind + ':' + '*'.join(t.axes) for t in self.terms]} "
                             f"need the condition(s) {missing}")
        out = {}
        for c in self.needs:
            v = np.asarray(self.conditions[c], float)
            out[c] = np.full(n, float(v)) if v.ndim == 0 else v
            if out[c].shape != (n,):
                raise ValueError(f"condition {c!r}: {out[c].shape} values for {n} points")
        return out

    def terms_only(self, axes) -> np.ndarray:
        """The terms' spatial contribution (μm), (n, k) -> (n, 3)."""
        axes = np.atleast_2d(np.asarray(axes, float))
        out = np.zeros((axes.shape[0], 3))
        if not self.terms:
            return out
        cond = self._cond(axes.shape[0])
        Je = self.machine.error_jacobian(axes)
        for t in self.terms:
            C, _ = effect_columns(self.machine, t.kind, t.axes, axes, cond, t.shape or None, Je)
            out += np.einsum("nic,c->ni", C, np.asarray(t.coefficients, float))
        return out

    def predict(self, axes) -> np.ndarray:
        """Spatial error (μm), (n, k) -> (n, 3)."""
        axes = np.atleast_2d(np.asarray(axes, float))
        return self.base.predict(axes) + self.terms_only(axes)

    __call__ = predict

    def predict_and_jacobian(self, axes, dtype=np.float64):
        """``(E (n, 3) μm, dE/d(axes) (n, 3, k))``: the elements' compiled Jacobian plus the terms' by
        central differences."""
        axes = np.atleast_2d(np.asarray(axes, float))
        E, J = self.base.predict_and_jacobian(axes, dtype=dtype)
        if not self.terms:
            return E, J
        E = E + self.terms_only(axes)
        J = J.copy()
        for j, a in enumerate(self.machine.axes):
            h = TERM_STEP[a.kind]
            qp, qm = axes.copy(), axes.copy()
            qp[:, j] += h
            qm[:, j] -= h
            J[:, :, j] += (self.terms_only(qp) - self.terms_only(qm)) / (2 * h)
        return E, J

    def jacobian(self, axes) -> np.ndarray:
        return self.predict_and_jacobian(axes)[1]


def check_made_on(doc: dict, machine: MachineTool, path) -> None:
    """Refuse (InputError naming ``path`` and the key) a model whose recorded ``machine_sha256`` names another
    machine file than ``machine``'s: its own, or an earlier file of the same built-in machine
    (:func:`errormap.machine.made_on`), or none recorded, is accepted."""
    from ..machine import made_on
    sha = doc.get("machine_sha256")
    if sha not in (None, "") and not made_on(machine, sha):
        raise InputError(f"{path}: key 'machine_sha256': the model was made for machine {doc.get('machine')!r} "
                         f"({str(sha)[:12]}…), not for {machine.name!r} ({machine.sha256[:12]}…)")


def load_chain_model_file(path, machine: MachineTool, learned: str = "refuse") -> ChainModelField:
    """Read ``model.json`` (module doc) for ``machine`` (a chain, or a ``kind = "grinder"`` file: its chain,
    :mod:`errormap.grinder_file`); errors name the file and the key (InputError).
    ``learned``: what to do with a kept learned residual (:data:`LEARNED_KEY`): ``"refuse"`` (an
    InputError naming the key: this reader would drop it) or ``"ignore"`` (the elements and terms alone,
    for a caller that needs only them)."""
    if learned not in LEARNED_MODES:
        raise ValueError(f"Expected learned one of {LEARNED_MODES}, got {learned!r}")
    path = Path(path)
    try:
        d = json.loads(read_document_text(path, "a diagnosed chain model"))
    except (OSError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a chain model file ({exc})") from None
    if not isinstance(d, dict) or d.get("format") not in READ_FORMATS:
        raise InputError(f"{path}: key 'format': expected {MODEL_FORMAT!r} (or the older {CHAIN_MODEL_FORMAT!r})")
    if d.get(LEARNED_KEY) is not None and learned == "refuse":
        raise InputError(f"{path}: key '{LEARNED_KEY}': the model's kept stage includes a learned residual, which "
                         "this command does not carry (predict and compensate --machine do); it is not dropped silently")
    check_made_on(d, machine, path)
    if not isinstance(d.get("elements"), str):
        raise InputError(f"{path}: key 'elements': expected the element set's file name, got {d.get('elements')!r}")
    el = ChainElementSet.load(path.parent / d["elements"], machine)
    return ChainModelField(machine, el, read_terms(d.get("terms", []), machine, path, "terms"))


def read_terms(items, machine: MachineTool, path, key: str) -> list:
    """The :class:`EffectTerm` of each dict in ``items`` (``EffectTerm.to_dict``'s form: ``model.json``'s
    ``terms``, ``diagnosis.json``'s ``effects`` of the chain loop); an InputError names ``path`` and
    ``key[i]`` for anything that is not one of this machine's terms."""
    words = {a.word for a in machine.axes}
    if not isinstance(items, list):
        raise InputError(f"{path}: key '{key}': expected a list of effect terms")
    terms = []
    for i, t in enumerate(items):
        try:
            kind, axes = t["kind"], tuple(str(t["axis"]).split("*"))
            if kind not in KINDS:
                raise ValueError(f"unknown effect kind {kind!r} (known: {', '.join(KINDS)})")
            if not set(axes) <= words or len(axes) != (2 if kind == "interaction" else 1):
                raise ValueError(f"axis {t['axis']!r} does not fit the kind on machine {machine.name!r}")
            if str(t["element"]) not in machine.slot_names:
                raise ValueError(f"element {t['element']!r} is not one of machine {machine.name!r}'s")
            coef = np.asarray(t["coefficients"], float)
            if coef.ndim != 1 or not np.all(np.isfinite(coef)):
                raise ValueError("coefficients must be a list of finite numbers")
            terms.append(EffectTerm(kind, axes, str(t["element"]), dict(t.get("shape") or {}), coef,
                                    float(t.get("held_out_gain_z", 0.0))))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: key '{key}[{i}]': {exc}") from None
    return terms
