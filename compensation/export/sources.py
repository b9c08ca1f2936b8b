"""Reading what ``volcomp export`` tabulates: the model, the truth it is checked against, and the reversal
terms of a ``diagnosis.json``, for any machine tool. A ``kind = "grinder"`` file's model, truth and
diagnosis files keep their own formats (read here); a chain's are read by the chain's readers."""
from __future__ import annotations

import numpy as np

from errormap.effect_kinds import diagnosed_kind, effect_kind
from errormap.io import InputError, read_json_object, sha256_file
from errormap.grinder_file import is_grinder_chain
from errormap.machine import made_on

from .model import ModelError, nominal_mm, TABLE_TEMP_C

BACKLASH_EXPORT = "linuxcnc-backlash"
"""The registry's ``export`` of a kind a per-joint table carries (:mod:`errormap.effect_kinds`)."""
CHECKS_DIAGNOSIS_FORMAT = "volcomp-checks-diagnosis/1"
"""The ``format`` key of the grinder's older checks ``diagnosis.json`` (written by ``volcomp diagnose CHECKS``
before every machine tool took the one closed loop; still read; the drift diagnosis has its own content and no
``effects``)."""


def joint_elements(machine) -> dict:
    """``{axis word: the element that is its own positioning error}`` read from the machine's axes (a
    linear axis along x: ``dx_<w>``; a rotary one about x: ``ex_<w>``); the grinder's
    ``{x: dx_x, z: dz_z, a: ex_a}``."""
    return {a.word.lower(): ("d" if a.kind == "linear" else "e") + "xyz"[a.along] + "_" + a.word.lower()
            for a in machine.axes}


def load_model(spec, fmt: str, machine, tracking_uri=None) -> tuple:
    """``(ModelError, description, Model)`` of the model ``spec`` for ``--format fmt`` on ``machine``, read by
    :func:`compensation.model_file.read_model` (the one reader): an element set tabulates its elements (ISO
    tables need one and nothing more); a model with effect terms tabulates its field at the tables' conditions;
    a network its learned field (grid, linuxcnc). A kept learned residual is refused by name (a table would
    drop it silently otherwise). InputError / ValueError in one line otherwise."""
    from ..model_file import read_model
    model = read_model(spec, machine, tracking_uri)
    src = model.source
    if model.elements_only:
        el = load_elements(model.elements_path, machine)
        return (ModelError(machine, el, field=chain_field(machine, el)),
                f"{model.elements_path} (element set, sha256 {sha256_file(model.elements_path)})", model)
    if fmt == "iso-tables":
        raise ValueError(f"--format iso-tables needs an element set: ISO component tables are the elements' "
                         f"components, and {src.description} holds {', '.join(model.holds())}")
    if model.per_point:   # the grinder's older closed-loop model: its terms take their conditions point by point
        raise InputError(f"{src.path}: its effect terms take their conditions per point, which a table cannot; "
                         f"export its element set {model.elements_path} (with --diagnosis for the reversal terms)")
    if model.learned is not None:
        raise InputError(f"{src.path}: key 'learned_residual': the model's kept stage includes a learned residual, "
                         f"which --format {fmt} does not carry (predict and compensate do); it is not dropped silently")
    if model.elements is not None:   # elements + diagnosed terms
        return (ModelError(machine, model.elements, field=model.field),
                f"{spec} (diagnosed model, {', '.join(model.holds())}: {src.description})", model)
    return ModelError(machine, None, field=model.field), f"{spec} (learned field: {src.description})", model


def chain_field(machine, elements):
    """The chain's own field of an element set (exact, with its analytic Jacobian)."""
    from errormap.chain_field import ChainField
    return ChainField(machine, elements)


def load_elements(path, machine):
    """The element set ``path`` of ``machine`` (:class:`errormap.chain_elements.ChainElementSet`; on the grinder
    refused when made for another machine file than its own, :func:`errormap.machine.made_on`)."""
    from errormap.chain_elements import ChainElementSet
    el = ChainElementSet.load(path, machine)
    if is_grinder_chain(machine) and el.machine_sha256 and not made_on(machine, el.machine_sha256):
        raise InputError(f"{path}: key 'machine_sha256': the model was made for machine file sha256 "
                         f"{el.machine_sha256[:12]}…, but the machine given is {machine.sha256[:12]}… "
                         f"({machine.path}); pass the model's --machine")
    return el


def chain_truth_tool_points(truth, machine):
    """``tool(axes (n, k), dirs (n, k)) -> (n, 3)`` mm of a chain's truth (``simulate --machine``'s truth at the
    reference conditions with its simulated machine as ``truth.truth``, or any field): where it puts the tool at
    the tables' reference temperature and the given approach directions."""
    def tool(q, dirs):
        if hasattr(truth, "truth"):
            cond = {f"dir_{a.word.lower()}": dirs[:, j] for j, a in enumerate(machine.axes)}
            e = truth.truth.spatial_error(q, temp_c=np.full(len(q), TABLE_TEMP_C), **cond)
        else:
            e = truth.predict(q)
        return nominal_mm(machine, q) + 1e-3 * np.asarray(e)
    return tool


def truth_tool_points(truth, machine):
    """``tool(axes (n, k), dirs (n, k)) -> (n, 3)`` mm of a simulated truth machine with ``tool_point(axes,
    temp_c=, dir_<w>=)`` (:class:`errormap.chain_truth.ChainTruth`), at the tables' reference
    temperature and the given approach directions."""
    words = [a.word.lower() for a in machine.axes]

    def tool(q, dirs):
        cond = {"temp_c": np.full(len(q), TABLE_TEMP_C), **{f"dir_{w}": dirs[:, j] for j, w in enumerate(words)}}
        return truth.tool_point(q, **cond)
    return tool


def reversal_from_diagnosis(path, model: ModelError) -> tuple:
    """``(model with the diagnosis' reversal terms, [labels of the effects a per-joint table cannot carry])``
    from ``diagnosis.json`` ``path`` of ``model``'s machine, told by content: the closed loop's (``volcomp diagnose
    --machine``, every machine tool, with its ``machine`` key): the registry's exportable terms; the grinder's older
    checks diagnosis (effects with ``parameters``): reversal terms on a joint's own element."""
    machine = model.machine
    if model.elements is None or getattr(model.field, "elements", model.elements) is not model.elements:
        raise ValueError("--diagnosis needs an element-set model (the reversal is added to its elements)")
    doc = read_json_object(path, "a diagnosis")
    if is_grinder_chain(machine) and not (isinstance(doc, dict) and "machine" in doc):  # the grinder's older diagnosis
        back, left = backlash_from_diagnosis(path, doc, machine)
        return ModelError(machine, model.elements, reversal={j.upper(): b for j, b in back.items()}), left
    from errormap.diagnosis.loop_model import ChainModelField
    terms, left = reversal_terms_from_diagnosis(doc, path, machine)
    return ModelError(machine, model.elements, field=ChainModelField(machine, model.elements, terms)), left


def backlash_from_diagnosis(path, doc=None, machine=None) -> tuple[dict, list[str]]:
    """Joint backlash (in its element's unit, μm or μrad) from a grinder file's ``diagnosis.json`` reversal
    terms, and the effects NOT exported: ``({joint: backlash}, [labels])``. A reversal term on a joint's own
    positioning element (``dx_x``, ``dz_z``, ``ex_a``) is a joint backlash; one on any other element cannot be
    carried by a per-joint table and is refused. ``doc``: the file's parsed JSON where the caller has read it;
    ``machine``: the grinder file's chain (default the built-in grinder): it names each joint's own
    element."""
    from errormap.machine import load_machine
    own = joint_elements(machine if machine is not None else load_machine())
    d = read_json_object(path, "a diagnosis") if doc is None else doc
    fmt = d.get("format") if isinstance(d, dict) else None
    if fmt is not None and fmt != CHECKS_DIAGNOSIS_FORMAT:  # by content; files from before the key: by 'effects'
        raise InputError(f"{path}: key 'format': {str(fmt)!r}; expected {CHECKS_DIAGNOSIS_FORMAT!r} (the "
                         "diagnosis.json of `volcomp diagnose CHECKS`)")
    effects = d.get("effects") if isinstance(d, dict) else None
    if not isinstance(effects, list):
        raise InputError(f"{path}: key 'effects': expected a list of diagnosed effects")
    back, left = {}, []
    for i, e in enumerate(effects):
        if not isinstance(e, dict) or "kind" not in e:
            raise InputError(f"{path}: key 'effects[{i}]': expected an object with 'kind'")
        try:
            spec = diagnosed_kind(e["kind"])  # the registry: an unknown kind is refused, never skipped
        except ValueError as exc:
            raise InputError(f"{path}: key 'effects[{i}].kind': {exc}") from None
        if spec.export != BACKLASH_EXPORT:
            left.append(f"{e.get('kind')}({e.get('axis')}) on {e.get('element')}")
            continue
        j, el = e.get("axis"), e.get("element")
        if j not in own or el != own[j]:
            raise InputError(f"{path}: key 'effects[{i}].element': a per-joint table carries a reversal on the "
                             f"joint's own element ({own}), got reversal({j}) on {el!r}")
        p = (e.get("parameters") or {})
        key = next((k for k in p if k.startswith("backlash_")), None)
        try:
            b = float(p[key]["value"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: key 'effects[{i}].parameters': expected backlash_<unit>.value") from None
        if j in back:
            raise InputError(f"{path}: key 'effects[{i}]': a second reversal term on joint {j}")
        back[j] = b
    return back, left


def reversal_terms_from_diagnosis(d, path, machine) -> tuple[list, list]:
    """The terms of a chain loop's ``diagnosis.json`` (``volcomp diagnose --machine``: its ``effects``; ``d`` its
    parsed JSON, read from ``path``) that a per-joint table carries as its forward/reverse difference (the registry's
    ``export``), and labels of the other effects, left out. An InputError names the file and key for another
    machine's diagnosis."""
    from errormap.diagnosis.loop_model import read_terms
    if not isinstance(d, dict) or d.get("machine") != machine.name or (d.get("machine_sha256") is not None and not made_on(machine, d["machine_sha256"])):
        got = d.get("machine") if isinstance(d, dict) else None
        raise InputError(f"{path}: key 'machine': expected the diagnosis of `volcomp diagnose --machine {machine.name}`, "
                         f"got {got!r}")
    terms = read_terms(d.get("effects"), machine, path, "effects")
    keep = [t for t in terms if effect_kind(t.kind).export == BACKLASH_EXPORT]
    left = [f"{t.kind}({'*'.join(t.axes)}) on {t.element}" for t in terms
            if effect_kind(t.kind).export != BACKLASH_EXPORT]
    return keep, left
