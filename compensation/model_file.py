"""The one reader of model files: :func:`read_model` -> :class:`Model` (the error field and what it holds).

``--model`` (and :func:`compensation.load_model`) names a ``model.json`` (``format: volcomp-model/1``,
written by ``volcomp diagnose`` and :func:`compensation.save_model`), or any older model file volcomp wrote,
recognised by content (:func:`compensation.fields.resolve_model`): an element set, an older closed-loop
``model.json``, a trained network folder or an MLflow reference, an arm's or parallel machine's calibration
(:mod:`compensation.calibration_models`); every format in docs/reference/file-formats.md. Every command that
evaluates a model (``predict``, ``compensate``, ``export``, ``report``) calls :func:`read_model` and asks
the :class:`Model` what it holds: no command branches on the file's format. A drift model is not an error
field of the axes and is refused here, naming the commands that take it."""
from __future__ import annotations

import json
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path

from errormap.io import InputError, companion_path, read_document_text

from .calibration_models import read_arm_model, read_pkm_model
from .fields import (CHAIN_MODEL_FORMAT, DIAGNOSED_FORMAT, MODEL_FORMAT, ModelSource, require_kind,
                     resolve_model)

FIELD_KINDS = ("model", "chain-model", "diagnosed", "elements", "chain-network", "network", "mlflow", "arm-model",
               "arm-calibration", "pkm-model", "pkm-calibration")
"""What :func:`resolve_model` recognises that :func:`read_model` reads."""
KIND_FAMILY = {"arm-model": "arm", "arm-calibration": "arm", "pkm-model": "parallel", "pkm-calibration": "parallel"}
"""The family of each kind of model file that is not a machine tool's."""
_A_FAMILY = {"machine tool": "a machine tool", "arm": "a serial arm", "parallel": "a parallel machine"}
LEARNED_KEYS = ("learned_residual", "base_stage", "base_terms_replaced", "loop_alone", "learned_family",
                "mlflow_run_id")
"""The keys of ``model.json`` that only a kept learned residual writes."""


@dataclass(frozen=True)
class Model:
    """A model file read (:func:`read_model`).

    * ``field`` — the error field, ``predict(axes (n, k)) -> (n, 3)`` μm in the machine's axis columns; with
      effect terms that need conditions, ``field.needs`` names them and ``field.with_conditions`` takes them
      (``per_point``: the grinder's old closed-loop model, its conditions taken per point by the compensating
      solver, :mod:`compensation.conditions`);
    * ``source`` — what ``--model`` named (:class:`compensation.fields.ModelSource`), ``format`` the format read;
    * ``elements`` / ``elements_path`` — the element set (None for a network);
    * ``covariance_path`` — its covariance file (None: none beside it);
    * ``terms`` — the accepted effect terms; ``learned`` — the kept learned residual
      (:class:`compensation.hybrid.LearnedResidual`) or None; ``network`` — the surrogate network's folder or
      MLflow reference (None: none); ``stage`` — the kept stage; ``provenance`` — what wrote it;
    * ``doc`` — the model.json's content (None for an element set or a network; an arm's or parallel machine's:
      its calibration section, with the file's verdict);
    * ``family`` — ``machine tool``, ``arm`` or ``parallel``; ``calibration`` — an arm's
      :class:`compensation.calibration_models.ArmCalibration` or a parallel machine's identified machine (``field``
      is then None: the family's own workflows evaluate it).
    """

    field: object
    source: ModelSource
    format: str
    elements: object = None
    elements_path: Path | None = None
    covariance_path: Path | None = None
    terms: tuple = ()
    learned: object = None
    network: str | None = None
    stage: str | None = None
    per_point: bool = False
    provenance: dict = dc_field(default_factory=dict)
    doc: dict | None = None
    family: str = "machine tool"
    calibration: object = None

    @property
    def needs(self) -> tuple:
        """The conditions the model's effect terms need (``temp_c``, ``dir_<w>`` …)."""
        return tuple(getattr(self.field, "needs", ()))

    @property
    def description(self) -> str:
        return self.source.description

    @property
    def elements_only(self) -> bool:
        """An element set and nothing else (no effect terms, learned residual or network): what a table of the
        elements' components (ISO tables) carries whole."""
        return self.elements is not None and not self.terms and self.learned is None and self.network is None

    def holds(self) -> list:
        """What the model holds, one word each (written into outputs beside the source)."""
        return [w for w, v in (("elements", self.elements is not None), ("covariance", self.covariance_path),
                               ("effect terms", self.terms), ("learned residual", self.learned is not None),
                               ("network", self.network)) if v]


def read_model(spec, machine, tracking_uri: str | None = None, source: ModelSource | None = None,
               family: str | None = None) -> Model:
    """The :class:`Model` of ``spec`` (a model file, trained-network folder or MLflow reference, recognised by
    content) for ``machine``: a machine tool (a chain, or a ``kind = "grinder"`` file: its chain; on the grinder
    also its older closed-loop model and the network of x, z, a that ``train`` fits there), a serial arm or a
    parallel machine.
    ``family``: the family the caller evaluates (None: any). InputError naming the file and key for anything else
    (a foreign or garbled file, another machine's or family's model, a drift model)."""
    src = source or resolve_model(spec)
    require_kind(src, FIELD_KINDS, "this command evaluates")
    got = KIND_FAMILY.get(src.kind, "machine tool")
    if family is not None and got != family:
        raise InputError(f"{src.path or src.spec}: key 'family': a model of {_A_FAMILY[got]}, not of "
                         f"{_A_FAMILY.get(family, family)} (--machine {getattr(machine, 'name', machine)})")
    return _READERS[src.kind](src, machine, tracking_uri)


def _read_model_json(src: ModelSource, machine, tracking_uri) -> Model:
    """``model.json`` (``volcomp-model/1``, or the chain loop's earlier ``volcomp-chain-model/1``)."""
    from errormap.diagnosis.loop_model import LEARNED_KEY, check_made_on, load_chain_model_file
    path = Path(src.path)
    doc = _doc(path)
    check_made_on(doc, machine, path)
    elements = el_path = None
    network = _network_ref(doc, path)
    if doc.get("elements") is None and network is not None:
        if doc.get("terms"):
            raise InputError(f"{path}: key 'terms': effect terms need the element set they act on (key 'elements')")
        net_src = require_kind(resolve_model(network), ("network", "chain-network", "mlflow"),
                               f"{path}: key 'network' names")
        base = _read_network(net_src, machine, tracking_uri).field
    else:
        base = load_chain_model_file(path, machine, learned="ignore")
        elements, el_path = base.elements, path.parent / doc["elements"]
    learned = None
    if doc.get(LEARNED_KEY) is not None:
        from .chain_hybrid import ChainHybridField
        from .hybrid import LearnedResidual
        try:
            learned = LearnedResidual.from_dict(doc[LEARNED_KEY])
            base = ChainHybridField(base, learned)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: key '{LEARNED_KEY}': {exc}") from None
    return Model(base, src, str(doc["format"]), elements, el_path, _covariance(doc, path, el_path),
                 tuple(getattr(base, "terms", ())), learned, network, doc.get("kept_stage"), False,
                 dict(doc.get("provenance") or {}), doc)


def _doc(path: Path) -> dict:
    try:
        doc = json.loads(read_document_text(path, "a model file"))
    except (OSError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a model file ({exc})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: not a model file (JSON {type(doc).__name__}, no key 'format')")
    for key, types in (("terms", list), ("provenance", dict), ("network", dict)):
        if doc.get(key) is not None and not isinstance(doc[key], types):
            raise InputError(f"{path}: key '{key}': expected {'a list' if types is list else 'an object'}, got "
                             f"{type(doc[key]).__name__}")
    for key in ("elements", "covariance", "kept_stage"):
        if doc.get(key) is not None and not isinstance(doc[key], str):
            raise InputError(f"{path}: key '{key}': expected a file name or null, got {doc[key]!r}")
    return doc


def _network_ref(doc: dict, path: Path) -> str | None:
    """The surrogate network ``doc`` names (key ``network``): a folder (relative to the file) or an MLflow
    reference; None: none."""
    net = doc.get("network")
    if net is None:
        return None
    if set(net) == {"folder"} and isinstance(net["folder"], str):
        return str(path.parent / net["folder"])
    if set(net) == {"mlflow"} and isinstance(net["mlflow"], str):
        return net["mlflow"]
    raise InputError(f"{path}: key 'network': expected {{\"folder\": NAME}} or {{\"mlflow\": RUN}}, got {net!r}")


def _covariance(doc: dict, path: Path, el_path) -> Path | None:
    """The element set's covariance: the file ``doc`` names (key ``covariance``; refused when missing), else
    (an older file without the key) ``NAME.cov.npz`` beside the element set when there."""
    if doc.get("covariance") is not None:
        cp = path.parent / doc["covariance"]
        if not cp.is_file():
            raise InputError(f"{path}: key 'covariance': {cp} not found")
        return cp
    if "covariance" in doc or el_path is None:
        return None
    cp = companion_path(el_path, ".cov.npz")
    return cp if cp.is_file() else None


def _read_elements(src: ModelSource, machine, tracking_uri) -> Model:
    """An element set (its chain's :class:`errormap.chain_field.ChainField`), covariance beside it when there."""
    from errormap.chain_elements import ChainElementSet
    from errormap.chain_field import ChainField
    el = ChainElementSet.load(src.path, machine)
    cp = companion_path(src.path, ".cov.npz")
    return Model(ChainField(machine, el), src, "volcomp-elements/1", el, Path(src.path), cp if cp.is_file() else None,
                 stage="elements")


def _read_network(src: ModelSource, machine, tracking_uri) -> Model:
    """A trained network: a folder (its ``config.json`` says which network) or an MLflow reference."""
    if src.kind == "chain-network":
        fld = _network(src.path, machine)
    else:
        try:
            from training.tracking import load_field as load_learned
        except ImportError as exc:  # pragma: no cover
            raise InputError(f"{src.spec}: a trained model, and the learned-field loader is unavailable ({exc})") from None
        fld = load_learned(str(src.path) if src.path is not None else src.spec, tracking_uri=tracking_uri,
                           loader=lambda folder: _network(folder, machine))
    ref = str(src.path) if src.path is not None else src.spec
    return Model(fld, src, src.to_dict()["kind_name"], network=ref, stage="network")


def _network(folder, machine):
    """The trained network in ``folder`` (:meth:`training.model.MLPField.load`), refused unless it takes
    ``machine``'s axis columns and (where its file names one) was trained on ``machine``."""
    from training.model import MLPField, check_machine
    return check_machine(MLPField.load(Path(folder)), machine, Path(folder) / "config.json")


def save_model_file(path, machine, elements=None, covariance=None, network_folder=None, kept_stage: str = "elements",
                    provenance=None) -> Path:
    """Write ``model.json`` (``volcomp-model/1``) at ``path`` naming the files a command wrote beside it: the element
    set ``elements`` and its ``covariance`` (``volcomp identify``), or the trained ``network_folder`` (``volcomp
    train``); ``provenance``: what wrote it, from which inputs. Returns the path."""
    from errormap.diagnosis.loop_model import save_chain_model
    network = {"folder": network_folder} if network_folder is not None else None
    return save_chain_model(path, machine, elements, (), kept_stage, covariance_file=covariance,
                            network=network, provenance=provenance)


# --- the grinder file's old closed-loop model (volcomp-diagnosed-model/1) ---------------------------------------
def _read_diagnosed(src: ModelSource, machine, tracking_uri) -> Model:
    """The grinder's closed-loop ``model.json``: its elements plus the grinder's effect terms (and learned residual),
    an error field whose conditions are given per point (:class:`compensation.conditions.ConditionedField`)."""
    from errormap.grinder_file import is_grinder_chain
    from .conditions import ConditionedField
    from .hybrid import HybridField
    if not is_grinder_chain(machine):
        raise InputError(f"{src.path}: key 'format': {DIAGNOSED_FORMAT!r} is the grinder file's closed-loop model; "
                         f"read it with the grinder's machine file, not {machine.name!r} (--machine)")
    path = Path(src.path)
    doc = _doc(path)
    corrected = load_diagnosed_model(path, machine, doc)
    base = corrected.base
    el_path = path.parent / doc["elements"]
    cp = companion_path(el_path, ".cov.npz")
    learned = base.learned if isinstance(base, HybridField) else None
    elements = base.base.elements if learned is not None else base.elements
    return Model(ConditionedField(corrected, {}, check=False), src, DIAGNOSED_FORMAT, elements, el_path,
                 cp if cp.is_file() else None, tuple(corrected.terms), learned, None, doc.get("stage"), True, {}, doc)


def load_diagnosed_model(path, machine, doc: dict | None = None):
    """The grinder's closed-loop ``model.json`` ``path`` (``volcomp-diagnosed-model/1``) as a
    :class:`errormap.diagnosis.corrected.CorrectedField` (its elements, learned residual when kept, and terms)."""
    from errormap.chain_elements import ChainElementSet
    path = Path(path)
    doc = _doc(path) if doc is None else doc
    return diagnosed_field(doc, machine, lambda name: ChainElementSet.load(path.parent / name, machine), path)


def diagnosed_field(doc: dict, machine, load_elements, where):
    """``model.json``'s content ``doc`` (``volcomp-diagnosed-model/1``) as a
    :class:`errormap.diagnosis.corrected.CorrectedField`; ``load_elements(name) -> ChainElementSet``: the element set
    ``doc`` names (key ``elements``); ``where``: the file (or a label) an error names."""
    import numpy as np
    from errormap.diagnosis.corrected import CorrectedField
    from errormap.diagnosis.effects import Candidate, EffectTerm
    from errormap.effect_kinds import diagnosed_kind
    from errormap.chain_field import ChainField
    if not isinstance(doc.get("elements"), str):
        raise InputError(f"{where}: key 'elements': expected the updated element set's file name, got "
                         f"{doc.get('elements')!r}")
    base = ChainField(machine, load_elements(doc["elements"]))
    if doc.get("learned_residual") is not None:  # the closed loop's learned stage (compensation.hybrid)
        from .hybrid import HybridField, LearnedResidual
        try:
            base = HybridField(base, LearnedResidual.from_dict(doc["learned_residual"]))
        except ValueError as exc:
            raise InputError(f"{where}: key 'learned_residual': {exc}") from None
    terms = []
    for i, t in enumerate(doc.get("terms", [])):
        try:
            diagnosed_kind(t.get("kind") if isinstance(t, dict) else None)
        except ValueError as exc:
            raise InputError(f"{where}: key 'terms[{i}].kind': {exc}") from None
        try:
            ref = {"strokes": {k: tuple(machine.strokes[k]) for k in ("x_mm", "z_mm", "a_deg")},
                   "ref_temp_c": float(t["reference"]["ref_temp_c"]), "ref_time_s": float(t["reference"]["ref_time_s"])}
            terms.append(EffectTerm(Candidate(t["kind"], t["axis"], t["element"]), np.asarray(t["coefficients"], float),
                                    ref, t.get("period_mm"), t.get("order")))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: key 'terms[{i}]': malformed term ({exc})") from None
    return CorrectedField(machine, base, terms)


def loop_alone_model(doc: dict) -> dict:
    """The loop alone of ``model.json``'s content ``doc``: what the closed loop ships without its learned
    part (a copy of ``doc`` when none was kept). Its elements and terms are ``loop_alone``'s where
    the learned part was backfitted with the element update (the shipped base is then not the loop's), the
    condition terms the learned part replaced (``base_terms_replaced``) are added back, and the keys of the
    learned part (:data:`LEARNED_KEYS`) are left out; its stage is ``base_stage``."""
    if doc.get("learned_residual") is None:
        return dict(doc)
    own = doc.get("loop_alone") or {}
    out = {k: v for k, v in doc.items() if k not in LEARNED_KEYS}
    out["stage"] = doc["base_stage"] if "base_stage" in doc else doc.get("stage")
    out["elements"] = own.get("elements", doc["elements"])
    out["terms"] = list(own.get("terms", doc["terms"])) + list(doc.get("base_terms_replaced", []))
    out["needs"] = sorted({c for e in out["terms"] for c in e.get("needs", [])})
    return out


def _read_calibration(src: ModelSource, machine, tracking_uri) -> Model:
    """A serial arm's or parallel machine's ``model.json`` or older ``calibration.json``
    (:mod:`compensation.calibration_models`): what was calibrated, and the calibration section."""
    family = KIND_FAMILY[src.kind]
    calibration, doc = {"arm": read_arm_model, "parallel": read_pkm_model}[family](src, machine)
    return Model(None, src, str(doc.get("format")), stage=doc.get("kept_stage"), doc=doc, family=family,
                 calibration=calibration)


_READERS = {"model": _read_model_json, "chain-model": _read_model_json, "diagnosed": _read_diagnosed,
            "elements": _read_elements, "chain-network": _read_network, "network": _read_network,
            "mlflow": _read_network, "arm-model": _read_calibration,
            "arm-calibration": _read_calibration, "pkm-model": _read_calibration, "pkm-calibration": _read_calibration}
"""The reader of each recognised format: the one place a model file's format decides anything."""

__all__ = ["Model", "read_model", "save_model_file", "LEARNED_KEYS", "loop_alone_model", "CHAIN_MODEL_FORMAT", "MODEL_FORMAT"]
