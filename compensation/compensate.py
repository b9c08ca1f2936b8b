"""Compensation for the public API: points in memory, program files on disk, models saved and loaded.

* :func:`compensate_points` — the axis commands that put the tool point where the nominal machine puts it
  at ``axes`` (the ``compensate`` command's solver and guards, on arrays);
* :func:`compensate_joints` — the same for a calibrated serial arm's joint commands;
* :func:`compensate_program` — the ``compensate`` command on a machine-tool chain, called with settings
  (:class:`compensation.app.workflows.compensate.CompensateSettings`) instead of a command line;
* :func:`save_model` / :func:`load_model` — an identified or closed-loop model to files that every command
  reads, and any model file (or MLflow reference) back as an error field.

Shapes: ``axes`` (n, k) in the machine's axis columns (``machine.axis_columns``: mm, deg); errors and
residuals μm.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


def _require_chain(machine, what: str) -> None:
    from errormap.mt_chain import MachineTool
    if not isinstance(machine, MachineTool):
        raise TypeError(f"{what}: expected a machine-tool chain (load_machine('mill-xyz'), 'grinder-chain', a "
                        f"kind = \"machine-tool\" file), got {type(machine).__name__}")


@dataclass
class PointCompensation:
    """The result of :func:`compensate_points`: ``axes`` (n, k) compensated commands, ``correction_um`` (n,)
    the tool-point move, ``residual_um`` (n, 3) the MODEL residual (the field's predicted position error left
    at the compensated commands), ``success`` (n,) converged inside the ball, ``violations`` {guard: indices
    of the points that violate it}, ``allowed`` (the guards overridden), ``solve`` (the solver's own
    :class:`compensation.solvers.base.SolveResult`)."""

    axes: np.ndarray
    correction_um: np.ndarray
    residual_um: np.ndarray
    success: np.ndarray
    violations: dict
    allowed: frozenset
    solve: object

    @property
    def accepted(self) -> bool:
        """No guard violated that was not overridden (what ``compensate`` writes)."""
        return not any(len(v) for g, v in self.violations.items() if g not in self.allowed)


def compensate_points(field, machine, axes, method: str = "exact", seed: int = 0, allow=(),
                      rotary_limit_deg: float | None = None) -> PointCompensation:
    """Compensate the points a program commands at ``axes`` (n, k) on a machine-tool chain with the error
    ``field`` (``Identification.field_``, ``load_model``): targets are the nominal tool points there, the
    solver ``method`` (:data:`compensation.solvers.CHAIN_METHODS`; ``seed`` for the seeded ones) finds the
    commands, and every guard runs (``allow``: guard names overridden, as ``--allow``)."""
    from . import guards
    from .solvers import CHAIN_METHODS, solve, solver_spec
    from .solvers.chain_exact import check_rotary_limit, nominal_and_jacobian
    _require_chain(machine, "compensate_points")
    if method not in CHAIN_METHODS:
        raise ValueError(f"Expected method in {list(CHAIN_METHODS)}, got {method!r}")
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
    return PointCompensation(res.axes, res.correction_um, res.residual_um, res.success,
                             {g: np.asarray(v) for g, v in report.violations.items()}, frozenset(report.allowed), res)


def compensate_joints(calibration, q, targets_mm=None):
    """Joint commands (n, nq) that put a calibrated arm's tool point on ``targets_mm`` (n, 3) (None: the
    nominal arm's tool points at the programmed joints ``q`` (n, nq), the program's intent), by Newton on the
    calibrated chain from ``q`` keeping the tool's orientation (``volcomp compensate --machine ur5``'s solver,
    without a learned stage). ``calibration``: a fitted :class:`errormap.ArmCalibration`. Returns the
    :class:`compensation.arm_compensation.ArmSolution` (``q``, ``residual_mm`` the MODEL residual,
    ``converged``)."""
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
    return solve_joints(geo.chain, geo.params, None, target, q)


def compensate_program(files, machine, model, out_dir, work_offsets=None, tool_table=None, executor=None,
                       **settings) -> dict:
    """Compensate tool-path ``files`` (G-code or axis CSV, by content) of a machine-tool chain with ``model``
    (a model file, folder or MLflow reference: :func:`save_model` writes one) into ``out_dir``, as
    ``volcomp compensate --machine`` does. ``work_offsets``: the controller's work offsets, as
    ``--work-offsets`` (a ``.var`` / CSV file, ``"machine"`` for a program written in machine
    coordinates, or a :class:`compensation.nc_state.WorkOffsets`); None (default): a G-code program is
    refused like the CLI refuses it (a controller never runs it at an assumed machine zero).
    ``tool_table``: as ``--tool-table`` (a file or a :class:`compensation.nc_state.ToolTable`).
    ``settings``: the other fields of :class:`compensation.app.workflows.compensate.CompensateSettings`
    (``method="exact"``, ``allow``, ``force``, ``truth``, ``chunk_points``, ``max_segment_mm`` …).
    ``executor``: where the chunks are solved (:class:`compensation.batch.LocalExecutor` (default), or
    :class:`compensation.app.workflows.cluster.RayExecutor` entered as a context manager). Returns the written
    ``compensate_summary.json`` as a dict (``files``: per input its residuals, guard counts, output or
    ``refused``)."""
    import json

    from .app.workflows.compensate import SUMMARY_NAME, CompensateSettings, compensate_files
    from .nc_state import ToolTable, WorkOffsets, read_tool_table, read_work_offsets
    _require_chain(machine, "compensate_program")
    files = [files] if isinstance(files, (str, Path)) else list(files)
    if work_offsets is not None and not isinstance(work_offsets, WorkOffsets):
        work_offsets = read_work_offsets(work_offsets)
    if tool_table is not None and not isinstance(tool_table, ToolTable):
        tool_table = read_tool_table(tool_table)
    s = CompensateSettings(**{"method": "exact", **settings, "model": str(model), "out_dir": Path(out_dir),
                         "work_offsets": work_offsets, "tool_table": tool_table})
    compensate_files(files, machine, s, executor=executor)
    return json.loads((Path(out_dir) / SUMMARY_NAME).read_text(encoding="utf-8"))


def save_model(path, model) -> Path:
    """Write ``model`` where every command reads it; returns the file to name as ``--model``:

    * an element set, or a fitted ``Identification``: the element set at ``path`` (with a chain's
      covariance beside it, ``NAME.cov.npz``, as ``volcomp identify`` writes);
    * a fitted ``ClosedLoop``: its kept elements at ``NAME.elements.json`` and ``path`` the chain model
      (``model.json`` format: elements + effect terms, as ``volcomp diagnose`` writes without a learned
      residual)."""
    from errormap.estimators import ClosedLoop, Identification
    from errormap.io import companion_path
    path = Path(path)
    if isinstance(model, ClosedLoop):
        from errormap.diagnosis.mt_model import save_chain_model
        model._check_fitted("field_")
        el = model.elements_.save(companion_path(path, ".elements.json"))
        return save_chain_model(path, model.machine, el, model.terms_, model.kept_stage_)
    if isinstance(model, Identification):
        model._check_fitted("elements_")
        if model.covariance_ is not None:
            model.result_.save_covariance(companion_path(path, ".cov.npz"))
        model = model.elements_
    if not hasattr(model, "save"):
        raise TypeError(f"save_model: expected an element set or a fitted Identification / ClosedLoop, got "
                        f"{type(model).__name__}")
    return model.save(path)


def load_model(spec, machine, tracking_uri: str | None = None):
    """An error field (``predict(axes) -> (n, 3)`` μm) from a model file, folder or MLflow reference for
    ``machine`` (:func:`compensation.fields.load_field`: recognised by content, refused naming the file)."""
    from .fields import load_field
    return load_field(spec, machine, tracking_uri)


__all__ = ["PointCompensation", "compensate_joints", "compensate_points", "compensate_program", "load_model", "save_model"]
