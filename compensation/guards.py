"""Guards on compensated commands: the search ball, the axis strokes, the calibrated volume and convergence
(docs/reference/tool-paths.md, "Guards"). A job whose commands fail a guard is refused, every offending point
listed with its reasons (:attr:`GuardReport.blocking`, :meth:`GuardReport.point_reasons`), unless the user
overrides that guard explicitly (``allow``; the CLI's ``--allow``). Every method passes through :func:`check`: the guards look at the
result, never at how it was obtained.

Guard names (the keys of ``allow`` and of :attr:`GuardReport.violations`): ``ball`` (``|p_r - p_d| >
ball_um``, or an unsolved point whose correction reached the ball's surface), ``stroke`` (an axis command,
or the nominal axes of its target, outside the machine file's strokes; a rotary axis whose stroke spans a
full turn passes, a narrower one is checked as commanded), ``volume`` (the same outside the field's
calibrated volume, a :class:`errormap.field.CalibratedVolume` over the machine's axis columns: a full-turn
rotary range accepts every angle, a narrower one is checked folded modulo 360° into ``[lo, lo + 360)``; a
field without one cannot be checked: TypeError), ``convergence`` (``SolveResult.success`` False inside the
ball; not a lathe's point nearer the spindle axis than the tool tip passes it, which no X and Z reach).
``volume_tol`` (default 1e-9 mm/deg) absorbs rounding."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from errormap.field import GRINDER_AXES, check_field, is_rotary_column, machine_axes

from .solvers.base import BALL_RADIUS_UM

GUARDS = ("ball", "stroke", "volume", "convergence")
AXIS_NAMES = GRINDER_AXES


@dataclass
class GuardReport:
    """Offending point indices per guard, with a short reason per offending point.

    ``violations[guard]`` is a sorted int array; ``reasons[guard]`` an array of strings of
    the same length. ``allowed`` names the guards the user overrode.
    """

    n_points: int
    violations: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    allowed: frozenset = frozenset()

    @property
    def ok(self) -> bool:
        """True when no guard found anything (allowed or not)."""
        return not any(len(v) for v in self.violations.values())

    @property
    def blocking(self) -> dict:
        """Violations of guards that were not allowed: guard -> indices."""
        return {g: v for g, v in self.violations.items() if len(v) and g not in self.allowed}

    @property
    def indices(self) -> np.ndarray:
        """All offending point indices (any guard), sorted."""
        parts = [v for v in self.violations.values() if len(v)]
        return np.unique(np.concatenate(parts)) if parts else np.zeros(0, dtype=np.intp)

    def point_reasons(self, index: int) -> list[str]:
        """Reasons for one point, ``"guard: detail"``."""
        out = []
        for g in GUARDS:
            v = self.violations.get(g, np.zeros(0, dtype=np.intp))
            k = np.searchsorted(v, index)
            if k < len(v) and v[k] == index:
                out.append(f"{g}: {self.reasons[g][k]}")
        return out


ON_BALL_REL = 1e-6
"""A correction within this fraction of the ball radius counts as on its surface."""


def ball_violations(correction_um, radius_um: float = BALL_RADIUS_UM, tol_um: float = 1e-9, success=None):
    """Points whose correction ``|p_r - p_d|`` (shape (n,) μm) exceeds the ball, or (with
    ``success``, shape (n,) bool) unsolved points stopped on its surface; (indices, reasons)."""
    c = np.asarray(correction_um, dtype=float)
    over = ~(c <= radius_um + tol_um)
    on = np.zeros_like(over)
    if success is not None:
        on = ~np.asarray(success, dtype=bool) & (c >= radius_um * (1.0 - ON_BALL_REL)) & ~over
    bad = np.flatnonzero(over | on)
    reasons = [f"|correction| {c[i]:.3f} μm > {radius_um:g} μm" if over[i] else
               f"needs a correction beyond the {radius_um:g} μm ball (solver stopped on its surface)" for i in bad]
    return bad, np.array(reasons, dtype=object)


def _box_violations(axes, lo, hi, free, tol: float, what: str, names=AXIS_NAMES):
    """Axes (n, k) outside the box ``lo``/``hi`` (k,); ``free`` (k,) bool marks the full-turn axes, which pass
    whatever their value; ``names`` (k,) the axis columns. Returns (indices, reasons)."""
    vals = np.asarray(axes, dtype=float)
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    chk = np.flatnonzero(~np.asarray(free, dtype=bool))  # the columns checked (a full-turn axis passes)
    cols = vals[:, chk]
    # one pass for the common case (nothing out): NaN fails both comparisons, so it is caught
    inside = (cols >= lo[chk] - tol) & (cols <= hi[chk] + tol)
    if inside.all():
        return np.zeros(0, np.intp), np.array([], dtype=object)
    out = np.zeros(vals.shape, bool)
    out[:, chk] = ~inside
    bad = np.flatnonzero(out.any(axis=1))
    reasons = []
    for i in bad:  # formatting the offenders only (a message, not a computation)
        parts = [f"{names[k]} = {vals[i, k]:.6g} outside {what} [{lo[k]:g}, {hi[k]:g}]"
                 for k in range(vals.shape[1]) if out[i, k]]
        reasons.append(", ".join(parts))
    return bad, np.array(reasons, dtype=object)


def stroke_violations(axes, machine, tol: float = 1e-9):
    """Axis commands (n, k) outside the machine's strokes: every full-turn rotary axis passes, the others
    are checked as commanded."""
    free = np.array([a.full_turn for a in machine.axes])
    lo, hi = machine.stroke_lo, machine.stroke_hi
    return _box_violations(axes, lo, hi, free, tol, "stroke", machine.axis_columns)


def calibrated_volume(field, names=AXIS_NAMES) -> tuple[np.ndarray, np.ndarray]:
    """The field's calibrated box ``(lo, hi)``, each shape (k,) over ``names`` (default the
    grinder's x_mm, z_mm, a_deg; a machine-tool chain's field: its axis columns).

    The field's ``calibrated_volume`` (module docstring); raises TypeError when the field is
    not an :class:`errormap.field.ErrorField`, its volume is None or over other axes.
    """
    vol = check_field(field, names).calibrated_volume
    if vol is None:
        raise TypeError(f"{type(field).__name__} does not say where it is calibrated (calibrated_volume is None; "
                        "see errormap.field)")
    return vol.lo_array, vol.hi_array


def volume_violations(axes, field, tol: float = 1e-9, names=AXIS_NAMES):
    """Axis commands (n, k) outside the field's calibrated volume over ``names``: a rotary (``*_deg``) range
    of a full turn accepts every angle, a narrower one is checked folded into its turn."""
    names = tuple(names)
    lo, hi = calibrated_volume(field, names)
    axes = np.asarray(axes, dtype=float)
    rot = np.array([is_rotary_column(n) for n in names])
    free = rot & (hi - lo >= 360.0 - 1e-9)
    fold = np.flatnonzero(rot & ~free)
    if fold.size:
        axes = axes.copy()
        axes[:, fold] = lo[fold] + np.mod(axes[:, fold] - lo[fold], 360.0)
    return _box_violations(axes, lo, hi, free, tol, "calibrated volume", names)


def solver_failures(result) -> np.ndarray:
    """(n,) bool: the points a solver reported as not successful, but a lathe's turning point nearer the spindle axis
    than the tool tip passes it (``info["spindle_axis"]``, :func:`compensation.turning.unreachable_radius`): its least
    radius is solved exactly, what is left is the centre-height error, which no X and Z remove (reported apart: the
    summary's ``spindle_axis_points``)."""
    failed = ~np.asarray(result.success, dtype=bool)
    failed[np.fromiter(result.info.get("spindle_axis", {}), dtype=np.intp)] = False
    return failed


def convergence_violations(result):
    """The :func:`solver_failures` strictly inside the ball; (indices, reasons)."""
    ball = float(result.info.get("ball_um", BALL_RADIUS_UM))
    bad = np.flatnonzero(solver_failures(result) & (result.correction_um < ball * (1.0 - ON_BALL_REL)))
    r = np.linalg.norm(np.asarray(result.residual_um)[bad], axis=1)
    tol = result.info.get("tol_um")
    retry = result.info.get("retry")
    how = (f" > tolerance {tol:.3g} μm" if tol is not None else "") + (
        " after the GA's retries and Newton polish" if retry and (retry.get("retry_rounds") or retry.get("polished"))
        else "")
    return bad, np.array([f"{result.method} did not converge (|residual| {v:.3g} μm{how})" for v in r], dtype=object)


def _merge(first, second):
    """Union of two (indices, reasons) pairs; reasons of a point in both are joined."""
    joined = {}
    for ix, rs in (first, second):
        for j, r in zip(ix.tolist(), rs):
            joined[j] = f"{joined[j]}; {r}" if j in joined else r
    idx = np.array(sorted(joined), dtype=np.intp)
    return idx, np.array([joined[i] for i in idx.tolist()], dtype=object)


def _targets(found):
    idx, reasons = found
    return idx, np.array([f"target {r}" for r in reasons], dtype=object)


def check(result, machine, field, allow=(), volume_tol: float = 1e-9, stroke_tol: float = 1e-9,
          target_axes=None) -> GuardReport:
    """Run every guard on a :class:`~compensation.solvers.base.SolveResult`; never raises on violations.

    ``allow``: guard names overridden by the user (or ``"all"``); they are still reported.
    ``target_axes`` (n, 3): nominal axes of the targets; when given, ``stroke`` and
    ``volume`` check them too (reasons start with ``target``).
    """
    allowed = frozenset(GUARDS) if allow == "all" or (not isinstance(allow, str) and "all" in allow) else \
        frozenset([allow] if isinstance(allow, str) else allow)
    allowed -= {"failed-verdict"}   # the model's verdict, checked before the solve (compensation.fields.check_verdict)
    unknown = sorted(allowed - set(GUARDS))
    if unknown:
        raise ValueError(f"Expected guard names from {list(GUARDS)} (or 'all'), got {unknown}")
    ball = float(result.info.get("ball_um", BALL_RADIUS_UM))
    names = machine_axes(machine)
    found = {
        "ball": ball_violations(result.correction_um, ball, success=result.success),
        "stroke": stroke_violations(result.axes, machine, stroke_tol),
        "volume": volume_violations(result.axes, field, volume_tol, names),
        "convergence": convergence_violations(result),
    }
    if target_axes is not None:
        target_axes = np.asarray(target_axes, dtype=float)
        if target_axes.shape != np.shape(result.axes):
            raise ValueError(f"Expected target_axes of shape {np.shape(result.axes)}, got {target_axes.shape}")
        found["stroke"] = _merge(found["stroke"], _targets(stroke_violations(target_axes, machine, stroke_tol)))
        found["volume"] = _merge(found["volume"], _targets(volume_violations(target_axes, field, volume_tol, names)))
    return GuardReport(n_points=len(result.axes), violations={g: v[0] for g, v in found.items()},
                       reasons={g: v[1] for g, v in found.items()}, allowed=allowed)


def violations(result, machine, field=None, **tolerances) -> list[tuple[int, str]]:
    """Every violation as ``(point index, "guard: detail")``, sorted by index.

    Convenience for callers that list offenders themselves. Without ``field`` the volume
    guard is skipped (pass the field: a command must not leave the calibrated volume).
    """
    if field is None:
        report = GuardReport(n_points=len(result.axes))
        found = {"ball": ball_violations(result.correction_um, float(result.info.get("ball_um", BALL_RADIUS_UM)),
                                         success=result.success),
                 "stroke": stroke_violations(result.axes, machine, tolerances.get("stroke_tol", 1e-9)),
                 "convergence": convergence_violations(result)}
        report.violations = {g: v[0] for g, v in found.items()}
        report.reasons = {g: v[1] for g, v in found.items()}
    else:
        report = check(result, machine, field, **tolerances)
    out = []
    for g in GUARDS:
        for i, r in zip(report.violations.get(g, []), report.reasons.get(g, [])):
            out.append((int(i), f"{g}: {r}"))
    return sorted(out, key=lambda t: t[0])
