"""The grinder benchmark's closed-loop models (:mod:`compensation.app.workflows.benchmark`): a diagnose run's
``model.json`` read back as the loop alone and the kept model, each at the flute's conditions."""
from __future__ import annotations

from pathlib import Path


def at_conditions(field_, mt, conditions: dict):
    """``field_`` with ``conditions`` (``{name: value}``) for the conditions its terms need."""
    from .compensate import field_conditions
    return field_conditions(field_, {c: conditions[c] for c in getattr(field_, "needs", ())}, mt)


def loop_models(machine, model_path, conditions: dict) -> dict:
    """``{"parametric": (terms, stage, field), "hybrid": ...}`` of a diagnose run's ``model.json``: the loop alone
    (without the learned part; its ``loop_alone`` elements and terms when the base was backfitted) and the kept
    model, each at ``conditions`` (the benchmark's flute conditions)."""
    import json
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.loop_model import ChainModelField, load_chain_model_file, read_terms
    from ...model_file import read_model
    doc = json.loads(Path(model_path).read_text(encoding="utf-8"))
    alone = doc.get("loop_alone")
    if alone is not None:
        base = ChainModelField(machine, ChainElementSet.load(Path(model_path).parent / alone["elements"], machine),
                               read_terms(alone["terms"], machine, model_path, "loop_alone"))
        alone_terms = alone["terms"]
    else:
        base = load_chain_model_file(model_path, machine, learned="ignore")
        alone_terms = doc["terms"] + doc.get("base_terms_replaced", [])
        if doc.get("base_terms_replaced"):   # the loop alone had the terms the learned part replaced
            base = ChainModelField(machine, base.elements, read_terms(alone_terms, machine, model_path, "terms"))
    return {"parametric": (alone_terms, doc.get("base_stage", doc["kept_stage"]), at_conditions(base, machine, conditions)),
            "hybrid": (doc["terms"], doc["kept_stage"], at_conditions(read_model(model_path, machine).field, machine, conditions))}
