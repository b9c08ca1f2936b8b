"""The diagnosed model (``DIR/model.json`` of ``volcomp diagnose``) as an error field for paths.

``model.json`` (``format: volcomp-diagnosed-model/1``) names the updated element set (relative
to the file) and the accepted effect terms (kind, axis, element, coefficients, period/order,
references). A term may need conditions (``temp_c``, ``time_s``, ``dir_x``, ``dir_z``,
``dir_a``). For compensating a path, each needed condition is taken per point from the CSV
path file's column of that name when it has one (the check-measurement columns' names and
rules: a finite number, ``dir_*`` ±1, ``temp_c`` within 0…45 °C, °F and kelvin named), else from the constant
option (``--temp-c`` …) for the whole path; a needed condition found in neither is refused,
naming the file, the column and the option (a column's bad cell: file, row and column).

Per-point conditions are solved exactly by moving the terms into the targets
(:func:`solve_with_conditions`): with the model ``E(q) = B(q) + t(q, c)``, compensating
``p_d`` is compensating ``p_d − t(q*, c)`` with the axes-only field ``B``, where ``q*`` is the
solution; two or three fixed-point passes make ``t`` consistent (its change over a
correction of ≤ 250 μm is far below the solver tolerance), and the model residual is then
computed with the terms at the final commands and the points' own conditions.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from errormap.diagnosis.corrected import CorrectedField
from errormap.diagnosis.effects import Candidate, EffectTerm
from errormap.effect_kinds import diagnosed_kind
from errormap.elements import ElementSet
from errormap.htm import HTMField
from errormap.io import InputError, read_document_text
from errormap.units import UNITS_CHECK, check_units, temperature_mistake

from .fields import DIAGNOSED_FORMAT as FORMAT
from .fields import resolve_model  # the format's one name, recognised by content there

CONDITIONS = ("temp_c", "time_s", "dir_x", "dir_z", "dir_a")
DIR_CONDITIONS = ("dir_x", "dir_z", "dir_a")
FIXED_POINT_TOL_UM = 1e-6      # the terms at the solution change by less than this between passes
FIXED_POINT_MAX_PASSES = 5


def is_diagnosed_model(spec) -> bool:
    """Whether ``spec`` is a diagnosed model, by its content (``format``), whatever its name."""
    try:
        return resolve_model(spec).kind == "diagnosed"
    except InputError:
        return False


def load_diagnosed_model(path, machine) -> CorrectedField:
    """The updated elements plus the accepted terms, as a :class:`CorrectedField`."""
    path = Path(path)
    d = json.loads(read_document_text(path, "a diagnosed model"))
    return diagnosed_field(d, machine, lambda name: ElementSet.load(path.parent / name), path)


def diagnosed_field(doc: dict, machine, load_elements, where) -> CorrectedField:
    """``model.json``'s content ``doc`` as a :class:`CorrectedField` (what :func:`load_diagnosed_model`
    builds from the file); ``load_elements(name) -> ElementSet``: the element set ``doc`` names by
    file name (key ``elements``); ``where``: the file (or a label) an error names."""
    if not isinstance(doc.get("elements"), str):
        raise InputError(f"{where}: key 'elements': expected the updated element set's file name, got "
                         f"{doc.get('elements')!r}")
    base = HTMField(machine, load_elements(doc["elements"]))
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


LEARNED_KEYS = ("learned_residual", "base_stage", "base_terms_replaced", "loop_alone", "learned_family",
                "mlflow_run_id")
"""The keys of ``model.json`` that only a kept learned residual writes."""


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


class ConditionedField:
    """A :class:`CorrectedField` at fixed conditions, an error field (:class:`errormap.field.ErrorField`):
    ``predict(axes) -> (n, 3)`` μm, calibrated where the corrected model is (its base's volume)."""

    kind = "diagnosed"
    capabilities = frozenset()

    def __init__(self, corrected: CorrectedField, conditions: dict, check: bool = True):
        self.corrected = corrected
        self.machine = corrected.machine
        self.conditions = {k: v for k, v in conditions.items() if v is not None}
        missing = [c for c in corrected.needs if c not in self.conditions]
        if missing and check:
            opts = ", ".join("--" + c.replace("_", "-") for c in missing)
            raise InputError(f"the diagnosed model's terms {[t.cand.label for t in corrected.terms]} need the "
                             f"condition(s) {missing}; give them ({opts})")

    @property
    def needs(self) -> tuple[str, ...]:
        return self.corrected.needs

    @property
    def calibrated_volume(self):
        return self.corrected.calibrated_volume

    def predict(self, axes) -> np.ndarray:
        axes = np.asarray(axes, dtype=float)
        missing = [c for c in self.corrected.needs if c not in self.conditions]
        if missing:  # only per point (solve_with_conditions) can this model be evaluated
            raise InputError(f"the diagnosed model's terms need the condition(s) {missing} at every point")
        return self.corrected.predict(axes, **{k: np.full(axes.shape[0], float(v)) for k, v in self.conditions.items()})

    __call__ = predict


def path_conditions(tp, needs, constants: dict, units: str = UNITS_CHECK, units_option: str | None = None) -> dict:
    """Per-point conditions of tool path ``tp`` (a :class:`compensation.pathio.ToolPath`) for the
    condition names ``needs``: {name: (n,) array}, from the CSV's columns when present, else the
    constant in ``constants`` (None: not given). Refuses (InputError) a needed condition in
    neither, and a bad cell (file, row, column); temperatures go through the shared unit check
    (:func:`errormap.units.check_units`, ``units`` / ``units_option`` as there)."""
    table = tp.source if tp.kind in ("csv-axes", "csv-targets") else None
    n = len(tp)
    out = {}
    for c in needs:
        if table is not None and c in table:
            if c in DIR_CONDITIONS:
                v = table.int(c, allowed=(-1, 1)).astype(float)
            else:
                v = table.float(c)
                if c == "temp_c":  # °F or kelvin: the shared unit check
                    check_units(tp.path, tp.lines, temps={"temp_c": v}, units=units, option=units_option)
            if v.shape != (n,):  # pragma: no cover - the table and the path have one row per point
                raise InputError(f"{tp.path}: column '{c}' has {v.size} values for {n} points")
            out[c] = v
        elif constants.get(c) is not None:
            if c == "temp_c":
                m = temperature_mistake([float(constants[c])], units)
                if m is not None:
                    raise InputError(f"--temp-c: units do not fit: {m[1]}")
            out[c] = np.full(n, float(constants[c]))
        else:
            where = "a column" if table is not None else "columns (a G-code path has none)"
            raise InputError(f"{tp.path}: the diagnosed model needs the condition '{c}' at every point: give it as "
                             f"{where} '{c}' or for the whole path with --{c.replace('_', '-')}")
    return out


def replanned_conditions(conditions, toolpath):
    """``conditions`` ({name: (n,)} from :func:`path_conditions`, or None) for ``toolpath`` after
    :func:`compensation.pathio.replan`: a CSV path comes back unchanged (its rows and their
    conditions too); a G-code path's vertices may be placed again, and its conditions are the
    options' constants (a G-code file has no condition columns), so each is the same value at
    every new vertex."""
    if conditions is None:
        return None
    n = len(toolpath)
    out = {}
    for name, v in conditions.items():
        if len(v) == n:
            out[name] = v
            continue
        if toolpath.kind != "gcode" or v.size == 0 or np.any(v != v[0]):  # pragma: no cover - replan keeps CSV rows
            raise AssertionError(f"{toolpath.path}: condition '{name}' cannot follow the replanned vertices")
        out[name] = np.full(n, v[0])
    return out


def solve_with_conditions(method, field, targets_mm, machine, conditions: dict, **kw):
    """Compensate ``targets_mm`` (n, 3) with a diagnosed model whose terms take per-point
    ``conditions`` {name: (n,)} (see module doc); ``field``: :class:`ConditionedField`.
    Returns the solver's :class:`SolveResult` with the model residual of the full model."""
    from .solvers import solve
    corrected = field.corrected
    targets = np.asarray(targets_mm, dtype=float)
    shift_um = np.zeros_like(targets)
    for _ in range(FIXED_POINT_MAX_PASSES):
        res = solve(method, corrected.base, targets - 1e-3 * shift_um, machine, **kw)
        t_um = corrected.terms_only(res.axes, **conditions)
        change = float(np.max(np.abs(t_um - shift_um))) if t_um.size else 0.0
        used, shift_um = shift_um, t_um
        if change <= FIXED_POINT_TOL_UM:
            break
    # p_r + B + t − p_d = (p_r + B − (p_d − shift)) + (t − shift), with the shift the solve used
    res.residual_um = res.residual_um + (t_um - used)
    res.targets_mm = targets
    res.correction_um = np.linalg.norm(res.commands_mm - targets, axis=1) * 1e3
    res.info = dict(res.info or {}, conditions="per point", fixed_point_change_um=change)
    return res


def load_path_field(spec, machine, tracking_uri, conditions=None):
    """``load_field`` for compensation, with ``model.json`` of ``volcomp diagnose`` understood;
    ``conditions``: ``{name: value or None}`` for :data:`CONDITIONS` (a diagnosed model's terms;
    missing ones are checked per path, from its columns or these constants)."""
    src = resolve_model(spec)
    if src.kind == "diagnosed":
        return ConditionedField(load_diagnosed_model(src.path, machine), dict(conditions or {}), check=False)
    from . import fields  # looked up at call time (tests stand a field in for fields.load_field)
    return fields.load_field(spec, machine, tracking_uri)
