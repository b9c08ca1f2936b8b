"""Effect-term conditions per point: the grinder file's old closed-loop model at given conditions, on paths.

The grinder's closed-loop model (``volcomp-diagnosed-model/1``) carries effect terms that may need
conditions; each is taken per point from the CSV path's column of that name, else from the constant option
for the whole path, else refused naming the file, column and option (docs/reference/file-formats.md,
"Conditions per point"). They are solved exactly by moving the terms into the targets
(:func:`solve_with_conditions`): with ``E(q) = B(q) + t(q, c)``, compensating ``p_d`` is compensating ``p_d
− t(q*, c)`` with the axes-only field ``B`` (``q*`` the solution; two or three fixed-point passes make ``t``
consistent), and the model residual is then computed with the terms at the final commands and the points'
own conditions."""
from __future__ import annotations

import numpy as np

from errormap.io import InputError
from errormap.units import UNITS_CHECK, check_units, temperature_mistake

CONDITIONS = ("temp_c", "time_s", "dir_x", "dir_z", "dir_a")
DIR_CONDITIONS = ("dir_x", "dir_z", "dir_a")
FIXED_POINT_TOL_UM = 1e-6      # the terms at the solution change by less than this between passes
FIXED_POINT_MAX_PASSES = 5


class ConditionedField:
    """A :class:`errormap.diagnosis.corrected.CorrectedField` at fixed conditions, an error field (:class:`errormap.field.ErrorField`):
    ``predict(axes) -> (n, 3)`` μm, calibrated where the corrected model is (its base's volume)."""

    kind = "diagnosed"
    capabilities = frozenset()

    def __init__(self, corrected, conditions: dict, check: bool = True):
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
    """Per-point conditions of tool path ``tp`` (a :class:`compensation.app.workflows.compensate_paths.ToolPath`)
    for the condition names ``needs``: {name: (n,) array}, from the CSV's columns when present, else the
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
