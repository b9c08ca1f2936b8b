"""The tool's orientation on 5-axis machine-tool chains (``volcomp compensate --compensate-orientation``): the
tool axis in the workpiece frame (:func:`tool_axis`), its TRUE residual (:func:`orientation_residual_urad`), and
the tool tip AND tool axis compensated with every axis (:func:`compensate_orientation`).

Near a rotary singularity (the tool axis along the last rotary axis: ``A = 0`` on an A/C table) that axis turns
the tool about itself. There the other rotary axis turns out the tilt in its own plane, the singular axis is held
as programmed (:func:`solve_orientation`, "partly" in the summary), and the tilt toward the other axis's line is
left: seen from the table, a turn of C only turns the machine's tilt against the table's own (its axis line's
and C's angular errors), so turning it out would need C to swing by tens of degrees, to wherever those cancel,
and differently from point to point: the part would turn under the tool mid-cut and the error would change
along every move between the points.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .tcp import by_length


def tool_axis(machine, axes, values=None) -> np.ndarray:
    """The tool axis (unit, spindle direction) in the workpiece frame, (n, 3), of ``machine`` at ``axes``
    (n, k) with slot ``values`` (n, P) μm/μrad (None: nominal)."""
    Rw, _ = machine.side_frames("work", axes, values)
    Rt, _ = machine.side_frames("tool", axes, values)
    return np.einsum("nji,nj->ni", Rw, Rt[:, :, 2])


def orientation_residual_urad(truth, machine, axes, nominal_axes, tool_mm) -> np.ndarray | None:
    """TRUE orientation residual (n,) μrad: the angle between the truth machine's tool axis at ``axes`` and the
    nominal tool axis at ``nominal_axes`` (the programmed orientation), at each point's tool length. None
    where the truth is not an element set nor a simulated truth without effects (its orientation is not known)."""
    elements = getattr(truth, "elements", None)
    sim = getattr(truth, "truth", None)  # simulate --machine's truth.json at the reference conditions
    if elements is None and sim is not None and not getattr(sim, "effects", None):
        elements = sim.elements
    if elements is None:
        return None
    from .nc_state import machine_with_tool
    out = np.empty(len(axes))
    for length, idx in by_length(tool_mm):
        mt = machine if length is None else machine_with_tool(machine, length)
        a = tool_axis(mt, axes[idx], elements.values(axes[idx]))
        b = tool_axis(mt, nominal_axes[idx])
        out[idx] = np.arcsin(np.clip(np.linalg.norm(np.cross(a, b), axis=1), 0.0, 1.0)) * 1e6
    return out


ORIENT_ROTARY_LIMIT_DEG = 0.05
"""Largest rotary correction the orientation solve makes by default (deg): the rotary axes' own errors are tens
of μrad (0.002°); a larger correction means the orientation error lies along a direction the rotary axes cannot
turn the tool (near ``A = 0`` the C axis turns the tool about itself) and the point keeps its programmed
rotary axes, or, near a singularity, has the other rotary axis turn out what it can (counted in the summary)."""
ORIENT_TOL_URAD = 0.01
"""The orientation solve's convergence on the MODEL's tool axis (μrad)."""
ORIENT_POS_TOL_UM = 1e-4
"""... and on the MODEL's tool tip (μm)."""
ORIENT_STEPS = {"linear": 1e-3, "rotary": 1e-4}
"""Central-difference steps of the orientation solve's Jacobian (mm, deg): the model varies over tens of mm /
degrees, so their h² error is far below the tolerances."""
ORIENT_MAX_ITER = 8
TIP_WEIGHT = 1e3
"""Weight of the tip's rows (μm) against the tool axis's (μrad) in the solve: where the tool axis cannot be
reached the least squares would otherwise give up tip for axis (the linear axes' angular errors vary by about
0.01 μrad per mm: unweighted, some 1e-4 μm of tip; weighted, 1e-10 μm)."""


def _pose_residual(field_, machine, q, targets, directions) -> np.ndarray:
    """MODEL tool tip minus target (μm) and MODEL tool axis minus the programmed one (μrad), (n, 6)."""
    p = machine.nominal(q) + 1e-3 * field_.predict(q)
    n = tool_axis(machine, q, field_.elements.values(q))
    return np.concatenate([(p - targets) * 1e3, (n - directions) * 1e6], axis=1)


def _gauss_newton(field_, machine, q, targets, directions, iterations, free=None) -> tuple:
    """``iterations`` Gauss-Newton steps of the axes ``free`` (column indices; None: every axis) on
    :func:`_pose_residual` from ``q`` (n, k) (columns scaled, central differences of :data:`ORIENT_STEPS`; the tip
    rows weighted by :data:`TIP_WEIGHT`, so that where the tool axis cannot be reached the tip still is):
    ``(q (n, k), tip reached (n,) bool, tool axis residual (n,) μrad)``."""
    rot = np.array([a.kind != "linear" for a in machine.axes])
    h = np.where(rot, ORIENT_STEPS["rotary"], ORIENT_STEPS["linear"])
    q = np.array(q, dtype=float)
    cols = list(range(q.shape[1])) if free is None else list(free)
    w = np.array([TIP_WEIGHT] * 3 + [1.0] * 3)
    for _ in range(iterations):
        r = _pose_residual(field_, machine, q, targets, directions) * w
        J = np.empty(r.shape + (len(cols),))
        for c, j in enumerate(cols):
            d = np.zeros(q.shape[1])
            d[j] = h[j]
            J[:, :, c] = (_pose_residual(field_, machine, q + d, targets, directions)
                          - _pose_residual(field_, machine, q - d, targets, directions)) * w / (2 * h[j])
        JtJ = np.einsum("nij,nik->njk", J, J)
        g = np.einsum("nij,ni->nj", J, r)
        scale = np.sqrt(np.einsum("njj->nj", JtJ)) + 1e-300
        A = JtJ / scale[:, :, None] / scale[:, None, :] + 1e-12 * np.eye(len(cols))
        dq = -np.linalg.solve(A, (g / scale)[:, :, None])[:, :, 0] / scale
        q[:, cols] += dq
        if np.abs(dq).max() < 1e-12:
            break
    r = _pose_residual(field_, machine, q, targets, directions)
    return q, np.linalg.norm(r[:, :3], axis=1) <= ORIENT_POS_TOL_UM, np.linalg.norm(r[:, 3:], axis=1)


def solve_orientation(field_, machine, axes0, targets, directions) -> tuple:
    """Tool tip AND tool axis compensated with all five axes (Gauss-Newton over the MODEL, an element set at
    the tool's length: ``field_`` a :class:`errormap.chain_field.ChainField` on ``machine``), from the
    position-only solution ``axes0`` (n, k); ``targets`` (n, 3) mm the programmed tips, ``directions`` (n, 3)
    the programmed tool axes (nominal, at the programmed axes). A point that does not converge within
    :data:`ORIENT_ROTARY_LIMIT_DEG` of its rotary axes is solved again with its singular rotary axis
    (:func:`_singular_axis`) held: the tip reached, the tool axis's residual least squares over the other axes
    (kept only where it is smaller than at ``axes0`` and the rotary correction within the limit). Returns
    ``(axes (n, k), solved (n,) bool, partly (n,) bool)``: solved, the tool axis reached; partly, the tool axis
    brought nearer; neither, ``axes0`` kept."""
    rot = np.array([a.kind != "linear" for a in machine.axes])
    axes0 = np.asarray(axes0, dtype=float)
    q, tip, axis_urad = _gauss_newton(field_, machine, axes0, targets, directions, ORIENT_MAX_ITER)
    ok = tip & (axis_urad <= ORIENT_TOL_URAD) & _within_limit(q, axes0, rot)
    q[~ok] = axes0[~ok]
    partly = np.zeros(len(q), bool)
    todo = np.flatnonzero(~ok)
    if not todo.size or rot.sum() < 2:
        return q, ok, partly
    before = np.linalg.norm(_pose_residual(field_, machine, axes0[todo], targets[todo], directions[todo])[:, 3:],
                            axis=1)
    sing = _singular_axis(machine, axes0[todo], list(np.flatnonzero(rot)))
    for j in np.unique(sing):
        i = todo[sing == j]
        qp, tip, axis_urad = _gauss_newton(field_, machine, axes0[i], targets[i], directions[i], ORIENT_MAX_ITER,
                                           [c for c in range(q.shape[1]) if c != j])
        good = tip & (axis_urad < before[sing == j]) & _within_limit(qp, axes0[i], rot)
        q[i[good]], partly[i[good]] = qp[good], True
    return q, ok, partly


def _within_limit(q, axes0, rot) -> np.ndarray:
    """(n,) bool: every rotary axis (mask ``rot``) of ``q`` within :data:`ORIENT_ROTARY_LIMIT_DEG` of ``axes0``."""
    return np.abs(q[:, rot] - axes0[:, rot]).max(axis=1) <= ORIENT_ROTARY_LIMIT_DEG


def _singular_axis(machine, q, rot_idx) -> np.ndarray:
    """Per point of ``q`` (m, k): the column of the rotary axis (of ``rot_idx``) whose turn moves the nominal tool
    axis least (the one turning the tool about itself near a singularity), (m,) int."""
    h = ORIENT_STEPS["rotary"]
    norms = []
    for j in rot_idx:
        d = np.zeros(q.shape[1])
        d[j] = h
        norms.append(np.linalg.norm(tool_axis(machine, q + d) - tool_axis(machine, q - d), axis=1))
    return np.asarray(rot_idx)[np.argmin(np.column_stack(norms), axis=1)]


def compensate_orientation(field_, machine, tp_axes, tool_mm, res, targets):
    """:func:`solve_orientation` over every point of a solved file at its tool length (NaN: the machine file's
    tool): ``(SolveResult with the new axes, commands and MODEL position residual, solved (n,) bool)``; the
    result's ``info`` holds ``orientation_solved`` and ``orientation_partly`` (n,) bool. ``field_`` must be an
    element set (``TypeError`` otherwise: only an element set gives the tool's orientation)."""
    from errormap.chain_field import ChainField

    from .nc_state import field_with_tool, machine_with_tool
    if not isinstance(field_, ChainField):
        raise TypeError(f"the model is a {type(field_).__name__}: the tool's orientation error needs an element set")
    axes = np.array(res.axes, dtype=float)
    solved, partly = np.zeros(len(axes), bool), np.zeros(len(axes), bool)
    commands = np.array(res.commands_mm, dtype=float)
    resid = np.array(res.residual_um, dtype=float)
    for length, idx in by_length(tool_mm):
        mt = machine if length is None else machine_with_tool(machine, length)
        f = field_ if length is None else field_with_tool(field_, mt)
        q, ok, part = solve_orientation(f, mt, axes[idx], targets[idx], tool_axis(mt, tp_axes[idx]))
        axes[idx], solved[idx], partly[idx] = q, ok, part
        commands[idx] = mt.nominal(q)
        resid[idx] = (commands[idx] - targets[idx]) * 1e3 + f.predict(q)
    kept = int((~solved & ~partly).sum())
    info = {**res.info, "orientation_solved": solved, "orientation_partly": partly,
            "compensated_axes": list(machine.axis_columns), "kept_axes": [],
            "note": (f"tool tip and tool orientation compensated with every axis ({', '.join(machine.axis_columns)}); "
                     f"{int(partly.sum())} point(s) near a rotary singularity (the tool along the last rotary axis) "
                     f"have their tool axis turned out only in the other rotary axis's plane"
                     + (f"; {kept} keep the programmed rotary axes (position only)" if kept else ""))}
    out = dataclasses.replace(res, axes=axes, commands_mm=commands, residual_um=resid,
                              correction_um=np.linalg.norm((commands - targets) * 1e3, axis=1), info=info)
    return out, solved
