"""Loading an error field from what the user names on the command line.

``--model`` accepts an element-set file (JSON, the HTM field), or an MLflow run id /
``runs:/<id>/...`` / ``models:/...`` URI of a trained network (the learned field).
"""
from __future__ import annotations

from pathlib import Path

from errormap.elements import ElementSet
from errormap.htm import HTMField
from errormap.io import InputError


def load_field(spec: str, machine, tracking_uri: str | None = None):
    """Return an object with ``predict(axes) -> (n, 3) μm`` for ``spec``."""
    p = Path(spec)
    if p.suffix.lower() == ".json" or p.is_file():
        if not p.is_file():
            raise InputError(f"{spec}: no such element-set file")
        return HTMField(machine, ElementSet.load(p))
    try:
        from training.tracking import load_field as load_learned
    except ImportError as exc:  # pragma: no cover
        raise InputError(f"{spec}: not an element-set file, and the learned-field loader is unavailable ({exc})") from None
    return load_learned(spec, tracking_uri=tracking_uri)
