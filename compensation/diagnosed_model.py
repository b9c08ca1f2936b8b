"""The diagnosed model (``DIR/model.json`` of ``volcomp diagnose``) as an error field for paths.

``model.json`` (``format: volcomp-diagnosed-model/1``) names the updated element set (relative
to the file) and the accepted effect terms (kind, axis, element, coefficients, period/order,
references). A term may need conditions (``temp_c``, ``time_s``, ``dir_x``, ``dir_z``,
``dir_a``); for compensating a path they are given as constants (options of ``volcomp
compensate``); a needed condition that is missing is refused, naming it.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from errormap.diagnosis.corrected import CorrectedField
from errormap.diagnosis.effects import Candidate, EffectTerm
from errormap.elements import ElementSet
from errormap.htm import HTMField
from errormap.io import InputError

FORMAT = "volcomp-diagnosed-model/1"
CONDITIONS = ("temp_c", "time_s", "dir_x", "dir_z", "dir_a")


def is_diagnosed_model(spec) -> bool:
    p = Path(str(spec))
    if p.suffix.lower() != ".json" or not p.is_file():
        return False
    try:
        return json.loads(p.read_text(encoding="utf-8")).get("format") == FORMAT
    except (json.JSONDecodeError, AttributeError):
        return False


def load_diagnosed_model(path, machine) -> CorrectedField:
    """The updated elements plus the accepted terms, as a :class:`CorrectedField`."""
    path = Path(path)
    d = json.loads(path.read_text(encoding="utf-8"))
    el_path = path.parent / d["elements"]
    base = HTMField(machine, ElementSet.load(el_path))
    terms = []
    for i, t in enumerate(d.get("terms", [])):
        try:
            ref = {"strokes": {k: tuple(machine.strokes[k]) for k in ("x_mm", "z_mm", "a_deg")},
                   "ref_temp_c": float(t["reference"]["ref_temp_c"]), "ref_time_s": float(t["reference"]["ref_time_s"])}
            terms.append(EffectTerm(Candidate(t["kind"], t["axis"], t["element"]), np.asarray(t["coefficients"], float),
                                    ref, t.get("period_mm"), t.get("order")))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: key 'terms[{i}]': malformed term ({exc})") from None
    return CorrectedField(machine, base, terms)


class ConditionedField:
    """A :class:`CorrectedField` at fixed conditions, an error field (:class:`errormap.field.ErrorField`):
    ``predict(axes) -> (n, 3)`` μm, calibrated where the corrected model is (its base's volume)."""

    kind = "diagnosed"
    capabilities = frozenset()

    def __init__(self, corrected: CorrectedField, conditions: dict):
        self.corrected = corrected
        self.machine = corrected.machine
        self.conditions = {k: v for k, v in conditions.items() if v is not None}
        missing = [c for c in corrected.needs if c not in self.conditions]
        if missing:
            opts = ", ".join("--" + c.replace("_", "-") for c in missing)
            raise InputError(f"the diagnosed model's terms {[t.cand.label for t in corrected.terms]} need the "
                             f"condition(s) {missing}; give them ({opts})")

    @property
    def calibrated_volume(self):
        return self.corrected.calibrated_volume

    def predict(self, axes) -> np.ndarray:
        axes = np.asarray(axes, dtype=float)
        return self.corrected.predict(axes, **{k: np.full(axes.shape[0], float(v)) for k, v in self.conditions.items()})

    __call__ = predict


def add_condition_options(p) -> None:
    """The constant-condition options of ``volcomp compensate`` (for a diagnosed model)."""
    p.add_argument("--temp-c", type=float, default=None, help="temperature for a diagnosed model's thermal term (°C)")
    p.add_argument("--time-s", type=float, default=None, help="time for a diagnosed model's drift term (s)")
    for ax in ("x", "z", "a"):
        p.add_argument(f"--dir-{ax}", type=int, choices=(-1, 1), default=None,
                       help=f"approach direction of {ax.upper()} for a diagnosed model's reversal term")


def load_path_field(spec, machine, tracking_uri, args):
    """``load_field`` for compensation, with ``model.json`` of ``volcomp diagnose`` understood."""
    from .fields import load_field
    if is_diagnosed_model(spec):
        return ConditionedField(load_diagnosed_model(spec, machine),
                                {c: getattr(args, c, None) for c in CONDITIONS})
    return load_field(spec, machine, tracking_uri)
