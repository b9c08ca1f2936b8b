"""What ``volcomp compensate`` reports beside the model residual of a compensated machine-tool program.

The TRUE residual with a truth element set (``--truth``: given by a tester or a benchmark, never to the
solver) at the vertices (:func:`true_residual_um`) and along the moves as the controller interpolates
them (:func:`true_path_residual_um`); the error cutter radius compensation leaves
(:func:`cutter_radius_bound_um`); the tool-orientation pass (``--compensate-orientation``,
:func:`orientation_pass`) and its summary entry (:func:`tcp_entry`); canned cycles' tilt
(:func:`cycle_report`); the rotary continuity refusals of the exact solver (:func:`rotary_refusals`).
Shapes: axes (n, k) in ``machine.axis_columns`` order, residuals (n, 3) μm.
"""
from __future__ import annotations

import numpy as np

from compensation.app.validate import UsageError

from ...evaluate import gradient_norm
from ...nc_state import field_with_tool, machine_with_tool
from ...solvers.chain_exact import nominal_and_jacobian

def true_residual_um(truth_field, machine, axes, targets_mm) -> np.ndarray:
    """TRUE residual (μm), (n, 3): the truth machine's tool point at ``axes`` (nominal + its error)
    minus the targets."""
    p, _ = nominal_and_jacobian(machine, axes)
    return (p - targets_mm) * 1e3 + truth_field.predict(axes)


PATH_SAMPLES = 8
"""Points per straight segment at which the TRUE residual along the moves is taken (fractions 1/8 … 8/8)."""
JOIN_MM = 1e-9
"""A move starts at the previous vertex when its start is within this of it (the same point)."""


def straight_segments(tp: ToolPath) -> np.ndarray:
    """(n,) bool: point i is reached from point i-1 by a straight G1 segment in axis space (a vertex of a
    split linear move, or the first vertex of a linear move that starts at the vertex before it)."""
    job = tp.source
    cols = list(tp.columns)
    out = np.zeros(len(tp.axes), bool)
    i = 0
    for move, c in zip([m for m in job.program.moves if m.compensate], job.counts):
        if move.kind == "linear":
            if i > 0 and np.all(np.isfinite(move.start)):
                start = move.start + tp.shift[i, cols]
                if job.frames is not None and job.frames.rotated:  # a rotated work system: the start turned too
                    start = job.frames.place([job.lines[i] - 1], move.start[None], job.program.axis_words.words)[0]
                out[i] = np.abs(start - tp.axes[i - 1, cols]).max() <= JOIN_MM
            out[i + 1:i + c] = True
        i += c
    return out


def true_path_residual_um(tp: ToolPath, comp_axes, truth, machine):
    """The TRUE residual along the program's linear moves as the controller interpolates them (axis
    space, straight between written vertices), at :data:`PATH_SAMPLES` points of every
    :func:`straight_segments` segment: ``(after, before)`` (m, 3) μm — the truth's tool point driven along
    the compensated segment minus the nominal tool point of the programmed segment at the same fraction,
    and the same for the program as written (the truth's error along it). None where there is no segment."""
    seg = np.flatnonzero(straight_segments(tp))
    tool = np.full(len(tp.axes), np.nan) if tp.tool_mm is None else np.asarray(tp.tool_mm, float)
    keys = np.where(np.isfinite(tool), tool, -np.inf)
    seg = seg[keys[seg] == keys[seg - 1]]
    if not seg.size:
        return None
    t = (np.arange(PATH_SAMPLES) + 1.0) / PATH_SAMPLES
    after, before = [], []
    for key in np.unique(keys[seg]):
        i = seg[keys[seg] == key]
        mt, tr = machine, truth
        if np.isfinite(key):
            mt = machine_with_tool(machine, float(key))
            tr = field_with_tool(truth, mt)
        a0, a1, c0, c1 = tp.axes[i - 1], tp.axes[i], comp_axes[i - 1], comp_axes[i]
        qn = (a0[:, None] + t[None, :, None] * (a1 - a0)[:, None]).reshape(-1, a0.shape[1])
        qc = (c0[:, None] + t[None, :, None] * (c1 - c0)[:, None]).reshape(-1, a0.shape[1])
        after.append((nominal_and_jacobian(mt, qc)[0] - nominal_and_jacobian(mt, qn)[0]) * 1e3 + tr.predict(qc))
        before.append(tr.predict(qn))
    return np.concatenate(after), np.concatenate(before)


def cutter_radius_bound_um(field_, machine, tp: ToolPath):
    """Under cutter radius compensation (G41/G42 D) the controller cuts up to the tool radius r away from
    the compensated point, where the error differs by at most |dE/dp|·r (a lathe's nose radius:
    :func:`compensation.turning.nose_radius_bound_um`): that bound (μm, the largest over
    the points under G41/G42; the spectral norm of the field's gradient along the linear axes,
    :func:`compensation.evaluate.gradient_norm`, at the tool each point runs with). None: no G41/G42 in the program."""
    job = tp.source
    if job.frames is None or job.frames.radius_mm is None:
        return None
    r = job.frames.radius(job.lines - 1)
    on = np.flatnonzero(np.isfinite(r))
    if not on.size:
        return None
    if tp.turning is not None:  # a lathe: the imaginary tool tip's arm, over the turn (compensation.turning)
        from ...turning import nose_radius_bound_um
        return nose_radius_bound_um(field_, machine, tp.axes, r, tp.tool_xz, tp.turning)
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    tool = tp.tool_mm[on]
    keys = np.where(np.isfinite(tool), tool, -np.inf)
    out = 0.0
    for key in np.unique(keys):
        idx = on[keys == key]
        f = field_ if not np.isfinite(key) else field_with_tool(field_, machine_with_tool(machine, float(key)))
        out = max(out, float((gradient_norm(f, tp.axes[idx], lin) * r[idx]).max()))
    return out


def orientation_pass(field_, truth, machine, tp: ToolPath, res, targets, true_r):
    """``--compensate-orientation``: tool tip and tool axis compensated with every axis
    (:func:`compensation.tcp_orientation.compensate_orientation`); the TRUE position residual recomputed at the new
    axes."""
    from ...tcp_orientation import compensate_orientation
    if not res.info.get("kept_axes"):
        raise UsageError(f"--compensate-orientation: the solver keeps no rotary axis on {machine.name!r} (it moves "
                         f"{', '.join(res.info.get('compensated_axes', []))}): there is no tool orientation to "
                         "compensate; leave it out")
    tool = np.full(len(tp.axes), np.nan) if tp.tool_mm is None else np.asarray(tp.tool_mm, float)
    try:
        res, _ = compensate_orientation(field_, machine, tp.axes, tool, res, targets)
    except TypeError as exc:
        raise UsageError(f"--compensate-orientation: {exc}") from None
    if truth is None:
        return res, true_r
    out = np.empty_like(true_r)
    keys = np.where(np.isfinite(tool), tool, -np.inf)
    for key in np.unique(keys):
        idx = np.flatnonzero(keys == key)
        mt = machine if not np.isfinite(key) else machine_with_tool(machine, float(key))
        tr = truth if not np.isfinite(key) else field_with_tool(truth, mt)
        out[idx] = true_residual_um(tr, mt, res.axes[idx], targets[idx])
    return res, out


def tcp_entry(tp: ToolPath, res, machine, truth) -> dict:
    """The summary's ``tcp`` entry of a program with tool-centre-point or G93 words (:func:`compensation.tcp.report`):
    with a truth element set, the TRUE orientation residual of the TCP points before/after (μrad)."""
    from ...tcp import report
    from ...tcp_orientation import orientation_residual_urad
    tcp = tp.source.program.tcp
    on = tcp.active(tp.lines - 1) if tcp is not None else np.ones(len(tp.lines), bool)
    before = after = None
    if truth is not None and on.any():
        tool = tp.tool_mm[on]
        after = orientation_residual_urad(truth, machine, res.axes[on], tp.axes[on], tool)
        before = orientation_residual_urad(truth, machine, tp.axes[on], tp.axes[on], tool)
    solved, partly = res.info.get("orientation_solved"), res.info.get("orientation_partly")
    return report(tcp, on, before, after, None if solved is None else np.asarray(solved)[on],
                  None if partly is None else np.asarray(partly)[on])


def cycle_report(tp: ToolPath, res, true_r, true_base):
    """The summary's ``cycles`` entry of a program with canned cycles (None: none): holes, and for kept
    cycles the tilt per source cycle line (|XY correction at R − at the bottom|, μm, the largest of its holes over
    the calls that ran it; keyed as :meth:`compensation.nc_expand.Expanded.named` names it: ``'12'``, ``'3 of
    FILE'`` for a ``--subprograms`` file) and, with a truth, the TRUE residual at the hole bottoms before/after."""
    job = tp.source
    exp = job.program.expanded
    if getattr(exp, "holes", None) is None:
        return None
    out = {"mode": exp.mode, "holes": len(exp.holes)}
    if exp.mode != "keep" or not exp.holes:
        return out
    last = {int(ln): i for i, ln in enumerate(job.lines)}  # the last vertex of each output line
    nominal = {ln: tp.axes[i][list(tp.columns)] for ln, i in last.items()}
    comp = {ln: res.axes[i][list(tp.columns)] for ln, i in last.items()}
    per = {}
    j = [job.program.axis_words.words.index(a) for a in "XY"]
    for h in exp.holes:
        d_r, d_b = (comp[ln][j] - nominal[ln][j] for ln in (h.out_r, h.out_bottom))
        t = float(np.linalg.norm(d_r - d_b) * 1e3)
        key = exp.named(exp.origin[h.out_bottom - 1][0])  # the source cycle line, over every call that ran it
        per[key] = max(per.get(key, 0.0), t)
    worst = max(per, key=per.get)
    out.update({"tilt_um": {str(k): v for k, v in per.items()}, "tilt_max_um": per[worst], "tilt_max_line": worst,
                "tilt": "|XY correction at the R point - at the hole bottom| (um): the error left along the hole"})
    if true_r is not None:
        b = np.array([last[h.out_bottom] for h in exp.holes])
        out["true_bottom"] = stats(true_r[b])
        out["true_bottom_uncompensated"] = stats(true_base[b])
    return out


def stats(r) -> dict:
    nrm = np.linalg.norm(r, axis=1)
    return {"max_um": float(nrm.max()), "rms_um": float(np.sqrt(np.mean(nrm ** 2))), "mean_um": float(nrm.mean())}


def rotary_refusals(res, report) -> int:
    """Points the exact chain solver refused by its rotary continuity guard
    (:func:`compensation.solvers.chain_exact.rotary_guard`): their guard reason (convergence: the point
    is unsolved) is replaced by the solver's own (which axis, by how much, the bound); returns their
    count (0 where the solver moves no rotary axis)."""
    idx = np.asarray(res.info.get("rotary_refused", ()), dtype=np.intp)
    if not len(idx):
        return 0
    why = dict(zip(idx.tolist(), res.info["rotary_reasons"]))
    conv = report.violations["convergence"]
    report.reasons["convergence"] = np.array([why.get(int(i), r) for i, r in zip(conv, report.reasons["convergence"])],
                                             dtype=object)
    return int(len(idx))


def spindle_axis_entry(res, lines_of) -> dict | None:
    """The summary's ``spindle_axis_points`` of one lathe file (None: none): its turning points nearer the spindle
    axis than the tool tip passes it (``res.info["spindle_axis"]``, :func:`compensation.turning.unreachable_radius`),
    written where the tip passes nearest the axis: ``count``, their source ``lines`` (``lines_of(points)``), the
    largest centre height ``height_max_um``, the MODEL residual left there ``residual_max_um`` (the tip's least
    mean radius: the height and its wobble over the turn), ``model_max_here`` (the file's largest model residual is
    one of them), ``why``."""
    from ...turning import SPINDLE_AXIS_WHY
    on_axis = res.info.get("spindle_axis") or {}
    if not on_axis:
        return None
    idx = np.array(sorted(on_axis), dtype=np.intp)
    h = float(max(on_axis.values()))
    norm = np.linalg.norm(np.asarray(res.residual_um), axis=1)
    return {"count": int(len(idx)), "lines": lines_of(idx), "height_max_um": h,
            "residual_max_um": float(norm[idx].max()), "model_max_here": bool(norm[idx].max() >= norm.max()),
            "why": SPINDLE_AXIS_WHY.format(h=h)}


NOTE_CHARS = 250
"""The longest spindle-axis note (with its parentheses): a LinuxCNC line holds at most 255 characters."""


def spindle_axis_line(e: dict) -> str:
    """One line (ASCII, at most :data:`NOTE_CHARS`) of a ``spindle_axis_points`` entry: the console's and the written
    program's header; it names as many of their source lines as fit, without an expanded program's detail (the summary
    names them all: ``'6 (expanded line 9)'`` is line 6 here)."""
    names = list(dict.fromkeys(str(line).split(" ", 1)[0] for line in e["lines"]))
    largest = ", the largest" if e["model_max_here"] else ""
    for k in range(min(len(names), 4), 0, -1):
        lines = ", ".join(names[:k]) + (", ..." if len(names) > k else "")
        text = (f"volcomp: {e['count']} point(s) on the spindle axis (line(s) {lines}), not failures: written where "
                f"the tool tip passes nearest it, {e['height_max_um']:.3g} um off centre height, which X and Z cannot "
                f"correct (residual left max {e['residual_max_um']:.4g} um{largest}); "
                "adjust the tool's centre height").encode("ascii", "replace").decode()
        if len(text) + 2 <= NOTE_CHARS:
            break
    return text
