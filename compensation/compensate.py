"""Compensation for the public API: points in memory, program files on disk, models saved and loaded.

* :func:`compensate_points` — the axis commands that put the tool point where the nominal machine puts it
  at ``axes`` (the ``compensate`` command's solver and guards, on arrays);
* :func:`compensate_joints` — the same for a calibrated serial arm's joint commands;
* :func:`compensate_program` — the ``compensate`` command on a machine-tool chain, called with settings
  (:class:`compensation.app.workflows.compensate.CompensateSettings`) instead of a command line;
* :func:`save_model` / :func:`load_model` — an identified or closed-loop model to files that every command
  reads, and any model file (or MLflow reference) back as an error field;
* :class:`Compensation` — the one result object of the three compensating calls.

Shapes: ``axes`` (n, k) in the machine's axis columns (``machine.axis_columns``: mm, deg); errors and
residuals μm.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


def _chain(machine, what: str):
    """A machine-tool chain, or the grinder file as its chain (the same axis columns and element names)."""
    from errormap.estimators import machine_tool
    return machine_tool(machine, what)


@dataclass
class Compensation:
    """The one result of :func:`compensate_points`, :func:`compensate_program` and :func:`compensate_joints`
    (scipy.optimize's one result object).

    * ``commands`` — points: the compensated axis commands (n, k) in ``machine.axis_columns`` (mm, deg);
      an arm: joint commands (n, nq); a program: ``{input file: written output file}`` (refused files are
      not written and not listed);
    * ``residual_um`` — points: the MODEL residual (n, 3) μm (the field's predicted position error left at
      the commands); an arm: its norm (n,) μm; a program: ``{input file: {"model_max_um",
      "model_mean_um"[, "true_…"]}}`` as the summary states them (TRUE figures only with a ``truth`` setting);
    * ``notes`` — one line each: the solver's notes, overridden guards, a lathe's points on the spindle axis
      (written where the tool tip passes nearest it), what the run read;
    * ``refused`` — ``{guard or input file: one-line reason}``; empty when every output is accepted;
    * ``overrides`` — the guard names overridden (``allow``), sorted;
    * ``correction_um`` (n,) the tool-point move, ``success`` (n,) converged inside the ball, ``violations``
      {guard: point indices}, ``solve`` (the solver's own result) — points and arms;
    * ``summary`` — a program: the written ``compensate_summary.json`` as a dict.
    """

    commands: object
    residual_um: object
    notes: list = field(default_factory=list)
    refused: dict = field(default_factory=dict)
    overrides: tuple = ()
    correction_um: np.ndarray | None = None
    success: np.ndarray | None = None
    violations: dict = field(default_factory=dict)
    solve: object = None
    summary: dict | None = None

    @property
    def accepted(self) -> bool:
        """Nothing refused: every guard passed or was overridden (what ``compensate`` writes)."""
        return not self.refused


REASON_CHARS = 160
"""A guard's reason is clipped to this in a refusal line, which stays one line under 300 characters."""


def _clip(text: str) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= REASON_CHARS else text[:REASON_CHARS - 1] + "…"


def compensate_points(field, machine, axes, method: str = "exact", seed: int = 0, allow=(),
                      rotary_limit_deg: float | None = None) -> Compensation:
    """Compensate the points a program commands at ``axes`` (n, k) on a machine-tool chain (or the grinder
    file, as its chain) with the error ``field`` (``Identification.field_``, ``load_model``): targets are the
    nominal tool points there, the solver ``method`` (:data:`compensation.solvers.METHODS`; ``seed``
    for the seeded ones) finds the commands, and every guard runs (``allow``: guard names overridden, as
    ``--allow``). Returns a :class:`Compensation`."""
    from . import guards
    from .solvers import METHODS, solve, solver_spec
    from .solvers.chain_exact import check_rotary_limit, nominal_and_jacobian
    machine = _chain(machine, "compensate_points(machine=...)")
    if method not in METHODS:
        raise ValueError(f"Expected method in {list(METHODS)}, got {method!r}")
    axes = np.atleast_2d(np.asarray(axes, dtype=float))
    if axes.ndim != 2 or axes.shape[1] != len(machine.axes):
        raise ValueError(f"Expected axes of shape (n, {len(machine.axes)}) in columns {list(machine.axis_columns)}, "
                         f"got {axes.shape}")
    check_rotary_limit(rotary_limit_deg)
    targets, _ = nominal_and_jacobian(machine, axes)
    options = {"seed": seed} if solver_spec(method).seeded else {}
    if rotary_limit_deg is not None:
        options["rotary_limit_deg"] = rotary_limit_deg
    res = solve(method, field, targets, machine, target_axes=axes, progress=False, **options)
    report = guards.check(res, machine, field, allow=allow, target_axes=axes)
    violations = {g: np.asarray(v) for g, v in report.violations.items()}
    refused = {g: f"{len(v)} of {len(axes)} point(s) violate the {g} guard (first: {_clip(report.reasons[g][0])}); "
                  f"allow={g!r} overrides it" for g, v in violations.items() if len(v) and g not in report.allowed}
    notes = [f"{g}: {len(v)} point(s) overridden (allow)" for g, v in violations.items()
             if len(v) and g in report.allowed] + ([res.info["note"]] if res.info.get("note") else [])
    return Compensation(res.axes, res.residual_um, notes, refused, tuple(sorted(report.allowed)), res.correction_um,
                        res.success, violations, res)


def compensate_joints(calibration, q, targets_mm=None):
    """Joint commands (n, nq) that put a calibrated arm's tool point on ``targets_mm`` (n, 3) (None: the
    nominal arm's tool points at the programmed joints ``q`` (n, nq), the program's intent), by Newton on the
    calibrated chain from ``q`` keeping the tool's orientation (``volcomp compensate --machine ur5``'s solver,
    without a learned stage). ``calibration``: a fitted :class:`errormap.ArmCalibration`. Returns a
    :class:`Compensation`: ``commands`` (n, nq) joints, ``residual_um`` (n,) the MODEL residual
    |target − calibrated tool point|, ``success`` (n,) converged, ``refused`` {"convergence": …} when a point
    did not converge, ``solve`` the :class:`compensation.arm_compensation.ArmSolution`."""
    from errormap.estimators import ArmCalibration
    from .arm_compensation import solve_joints
    if not isinstance(calibration, ArmCalibration):
        raise TypeError(f"compensate_joints: expected a fitted ArmCalibration, got {type(calibration).__name__}")
    calibration._check_fitted("result_")
    q = np.atleast_2d(np.asarray(q, dtype=float))
    chain = calibration.chain
    if q.shape[1] != chain.n_joints:
        raise ValueError(f"Expected q of shape (n, {chain.n_joints}) in columns {list(chain.joint_columns)}, "
                         f"got {q.shape}")
    target = chain.tool_point(q) if targets_mm is None else np.atleast_2d(np.asarray(targets_mm, dtype=float))
    if target.shape != (q.shape[0], 3):
        raise ValueError(f"Expected targets_mm of shape ({q.shape[0]}, 3), got {target.shape}")
    geo = calibration.result_
    sol = solve_joints(geo.chain, geo.params, None, target, q)
    bad = np.flatnonzero(~sol.converged)
    refused = {"convergence": f"{len(bad)} of {len(q)} point(s) did not converge (first: row {bad[0]}, MODEL "
                              f"residual {sol.residual_mm[bad[0]]:.3g} mm); targets out of the arm's reach?"} \
        if len(bad) else {}
    notes = ["tool orientation kept"] if sol.orientation_kept else []
    return Compensation(sol.q, sol.residual_mm * 1e3, notes, refused, (), success=sol.converged, solve=sol)


def compensate_program(files, machine, model, out_dir, work_offsets=None, tool_table=None, executor=None,
                       **settings) -> Compensation:
    """Compensate tool-path ``files`` (G-code or axis CSV, by content) of a machine-tool chain (or the grinder
    file, as its chain) with ``model`` (a model file, folder or MLflow reference: :func:`save_model` writes
    one) into ``out_dir``, as ``volcomp compensate --machine`` does. ``work_offsets``: the controller's work
    offsets, as ``--work-offsets`` (a ``.var`` / CSV file, ``"machine"`` for a program written in machine
    coordinates, or a :class:`compensation.nc_state.WorkOffsets`); None (default): a G-code program is
    refused like the CLI refuses it (a controller never runs it at an assumed machine zero).
    ``tool_table``: as ``--tool-table`` (a file or a :class:`compensation.nc_state.ToolTable`).
    ``settings``: the other fields of :class:`compensation.app.workflows.compensate.CompensateSettings`
    (``method="exact"``, ``allow``, ``force``, ``truth``, ``chunk_points``, ``max_segment_mm`` …).
    ``executor``: where the chunks are solved (:class:`compensation.batch.LocalExecutor` (default), or
    :class:`compensation.app.workflows.cluster.RayExecutor` entered as a context manager). Returns a
    :class:`Compensation` (``commands`` {input: output file}, per-file residual figures, refused files
    with their guards; ``summary`` the written ``compensate_summary.json``)."""
    import json

    from .app.workflows.compensate import SUMMARY_NAME, CompensateSettings, compensate_files
    from .nc_state import ToolTable, WorkOffsets, read_tool_table, read_work_offsets
    machine = _chain(machine, "compensate_program(machine=...)")
    files = [files] if isinstance(files, (str, Path)) else list(files)
    if work_offsets is not None and not isinstance(work_offsets, WorkOffsets):
        work_offsets = read_work_offsets(work_offsets)
    if tool_table is not None and not isinstance(tool_table, ToolTable):
        tool_table = read_tool_table(tool_table)
    s = CompensateSettings(**{"method": "exact", **settings, "model": str(model), "out_dir": Path(out_dir),
                         "work_offsets": work_offsets, "tool_table": tool_table})
    compensate_files(files, machine, s, executor=executor)
    return _program_result(json.loads((Path(out_dir) / SUMMARY_NAME).read_text(encoding="utf-8")))


def _program_result(summary: dict) -> Compensation:
    """The :class:`Compensation` of a written ``compensate_summary.json``."""
    entries = summary["files"]
    commands = {Path(e["input"]): Path(e["output"]) for e in entries if not e.get("refused")}
    residual = {Path(e["input"]): {k: v for k, v in e.items() if k.startswith(("model_", "true_"))} for e in entries}
    refused = {Path(e["input"]): f"{e['input']}: refused by guard(s) {', '.join(e.get('refused_guards', []))} "
                                 "(not written); allow=(GUARD, ...) overrides" for e in entries if e.get("refused")}
    notes = [f"{e['input']}: {e['note']}" for e in entries if e.get("note")]
    notes += [f"{e['input']}: overridden " + ", ".join(f"{g} {n}" for g, n in e["overridden"].items())
              for e in entries if e.get("overridden")]
    notes += [f"{e['input']}: {e['spindle_axis_points']['count']} point(s) on the spindle axis written where the tool "
              f"tip passes nearest it: {e['spindle_axis_points']['why']}" for e in entries if e.get("spindle_axis_points")]
    return Compensation(commands, residual, notes, refused, tuple(sorted(summary.get("allow", ()))), summary=summary)


def save_model(path, model) -> Path:
    """Write ``model`` where every command reads it; returns the file to name as ``--model``:

    * a fitted ``Identification``: ``model.json`` at ``path`` (format ``volcomp-model/1``) with its element set
      beside it (``NAME.elements.json``) and that set's covariance (``NAME.elements.cov.npz``);
    * a fitted ``ClosedLoop``: ``model.json`` at ``path`` with its kept elements beside it
      (``NAME.elements.json``) and its effect terms (as ``volcomp diagnose`` writes without a learned residual);
    * an element set: the element set at ``path``;
    * a fitted ``DriftSelector`` or a ``DriftModel``: the drift model (``drift_model.json`` format; read it
      back with ``DriftModel.load``)."""
    from errormap.diagnosis.drift_models import DriftSelector
    from errormap.diagnosis.loop_model import save_chain_model
    from errormap.estimators import ClosedLoop, Identification, machine_tool
    from errormap.io import companion_path
    path = Path(path)
    if isinstance(model, (ClosedLoop, Identification)):
        model._check_fitted("elements_")
        el = model.elements_.save(companion_path(path, ".elements.json"))
        mt = machine_tool(model.machine, "save_model")
        written = {"written_by": f"compensation.save_model({type(model).__name__})"}
        if isinstance(model, ClosedLoop):
            return save_chain_model(path, mt, el, model.terms_, model.kept_stage_, provenance=written)
        from errormap.chain_covariance import save_chain_covariance
        cov = save_chain_covariance(model.result_, companion_path(el, ".cov.npz"))
        return save_chain_model(path, mt, el, covariance_file=cov, provenance=written)
    if isinstance(model, DriftSelector):
        model._check_fitted("model_")
        model = model.model_
    if not hasattr(model, "save"):
        raise TypeError(f"save_model: expected an element set, a drift model or a fitted Identification / "
                        f"ClosedLoop / DriftSelector, got {type(model).__name__}")
    return model.save(path)


def load_model(spec, machine, tracking_uri: str | None = None):
    """An error field (``predict(axes) -> (n, 3)`` μm) from a model file, folder or MLflow reference for
    ``machine``: the ``field`` of :func:`compensation.model_file.read_model` (the one reader; recognised by
    content, refused naming the file and key). Element sets and model files are read on a machine's chain (a
    grinder file's too, as the estimators fit it); the grinder's trained network of x, z, a as trained."""
    from .model_file import read_model
    return read_model(spec, machine, tracking_uri).field


__all__ = ["Compensation", "compensate_joints", "compensate_points", "compensate_program", "load_model", "save_model"]
