"""``volcomp compensate`` on a machine-tool chain (``--machine mill-xyz``, ``five-axis-ac`` ...).

The grinder's order of work (:mod:`compensation.app.workflows.compensate`) over the machine's own
axes: every input is read and checked first (G-code by :mod:`compensation.mt_gcode` with the
machine's axis words, or a CSV with the machine's axis columns ``x_mm, y_mm, z_mm ...``; told apart
by content), then the model (an element set of the chain, recognised by content), the exact chain
solver (:mod:`compensation.solvers.chain_exact`: the tool-tip position with the linear axes, rotary
axes kept, said in the summary), the guards (ball, strokes, calibrated volume, convergence;
``--allow`` overrides and the override is written into the file and the summary), and the
accepted files written as one set with ``compensate_summary.json`` last. The points are solved through
the grinder's chunk plan and executors (:mod:`compensation.batch`, Ray:
:mod:`compensation.app.workflows.cluster`; one unit per file and tool length), and moves are split as
``max_segment_mm`` says (:func:`compensation.mt_gcode.plan_chain_gcode`).

Residuals: the MODEL residual of every file (the solver's own field); with ``truth`` (a truth
element set of the same chain, given by a tester or a benchmark, never to the solver) also the
TRUE residual — the tool point the truth machine reaches when driven with the compensated axes,
minus the target — beside the uncompensated machine's true error (the baseline: the program run
as written), at the vertices and along the linear moves (:func:`true_path_residual_um`).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from errormap.io import InputError, atomic_write, read_table, write_json
from errormap.units import UNITS_CHECK, check_units

from compensation.app.validate import UsageError

from ... import guards
from ...fields import FAILED_VERDICT, check_verdict, load_chain_field, require_kind, resolve_model, verdict_notes
from ...gcode import DEFAULT_RAPIDS
from ...mt_gcode import parse_chain_program, plan_chain_gcode, render_chain_program
from ...nc_state import MACHINE, field_with_tool, machine_with_tool, program_frames, refuse_unknown_frames
from ...pathio import DEFAULT_ARC_TOLERANCE_UM, is_csv
from ...solvers.chain_exact import nominal_and_jacobian, solved_and_kept
from ...batch import CHUNK_POINTS, LocalExecutor
from .compensate import SUMMARY_NAME, WORK_OFFSETS_MACHINE_NOTE, check_out_dir, plan_outputs, progress_callback

DECIMALS = {"mm": 6, "deg": 6}  # 1 nm; 1e-6 deg


@dataclass
class ChainPath:
    """One input: ``kind`` ``"gcode"`` or ``"csv-axes"``, ``axes`` (n, k) nominal MACHINE axes of
    every point (vertex; a program's points placed by its work offsets and tool lengths), ``lines``
    (n,) source line (G-code) or row (CSV), ``source`` the parsed job or table."""

    path: Path
    kind: str
    axes: np.ndarray
    lines: np.ndarray
    source: object
    shift: np.ndarray | None = None
    """Machine minus program axes per point (n, k): work offset and tool length (None: zero)."""
    tool_mm: np.ndarray | None = None
    """The active tool length per point (n,) mm; NaN (or None): the machine file's own tool."""
    columns: tuple = ()
    """G-code: the machine axes (indices) the program's words are, in order (all of them, or a lathe's
    X and Z where the program never commands the spindle's C)."""
    turning: np.ndarray | None = None
    """G-code on a machine with a ``[spindle]``: (n,) points cut while the spindle turns (X, Z only;
    :mod:`compensation.turning`)."""
    kept_machine: np.ndarray | None = None
    """G-code: the kept (not compensated) points' nominal machine axes (m, k); NaN where unknown."""


@dataclass
class ChainSettings:
    """How :func:`compensate_chain_files` compensates (the ``compensate`` options on a chain): ``method``
    (:data:`compensation.solvers.CHAIN_METHODS`), ``model`` (a model file, folder or MLflow reference),
    ``out_dir``; ``force`` (replace earlier outputs), ``allow`` (guards overridden), ``rapids``,
    ``block_delete``, ``arc_tolerance_um``, ``units`` (``"check"`` or ``"as-written"``), ``truth`` (a truth
    file: the TRUE residual too), ``seed`` (seeded methods), ``show`` (offending points listed per refused
    file), ``rotary_limit_deg`` (a solved rotary axis' largest correction, None: the ball's bound),
    ``conditions`` ({name: value} for the model's condition terms), ``tracking_uri`` (MLflow)."""

    method: str
    model: str
    out_dir: Path
    force: bool = False
    allow: tuple = ()
    rapids: str = DEFAULT_RAPIDS
    block_delete: str | None = None
    arc_tolerance_um: float = DEFAULT_ARC_TOLERANCE_UM
    units: str = UNITS_CHECK
    truth: str | None = None
    seed: int = 0
    show: int = 20
    rotary_limit_deg: float | None = None
    conditions: dict = field(default_factory=dict)
    tracking_uri: str | None = None
    dialect: str | None = None   # compensation.dialects: a name, "auto" or None
    work_offsets: object = None  # compensation.nc_state.WorkOffsets (None: not given)
    tool_table: object = None    # compensation.nc_state.ToolTable (None: not given)
    cycles: str = "keep"         # canned cycles: "keep" (holes compensated) or "expand" (compensation.nc_cycles)
    orientation: bool = False    # the tool's orientation compensated too, by the rotary axes (compensation.tcp)
    chunk_points: int = CHUNK_POINTS  # points per chunk of the batch (compensation.batch)
    max_segment_mm: object = "auto"   # "auto" (the field's curvature), None (no splitting) or a length in mm


def read_chain_path(path, machine, s: ChainSettings, field_=None) -> ChainPath:
    """A tool-path file for the chain ``machine``: CSV with its axis columns, or G-code."""
    path = Path(path)
    if is_csv(path):
        t = read_table(path)
        cols = machine.axis_columns
        t.require(*cols)
        if len(t) == 0:
            raise InputError(f"{path}: no data rows")
        axes = np.stack([t.float(c) for c in cols], axis=1)
        rows = t.row_number(0) + np.arange(len(t), dtype=int)
        check_units(path, rows, machine=machine, axes=axes, axes_columns=cols, coverage="path", units=s.units,
                    option="--units")
        return ChainPath(path, "csv-axes", axes, rows, t)
    turning = None
    if getattr(machine, "spindle", None) is not None:  # a lathe: turning mode where the spindle turns
        from ...turning import ColumnsField, parse_lathe_program
        prog, turning = parse_lathe_program(path, machine, s.rapids, s.block_delete, dialect=s.dialect)
    else:
        prog = parse_chain_program(path, machine, rapids=s.rapids, block_delete=s.block_delete, dialect=s.dialect,
                                   cycles=s.cycles)
    frames = program_frames(prog, s.work_offsets, s.tool_table)
    refuse_unknown_frames(prog, frames, s.work_offsets)
    k = len(machine.axes)
    columns = tuple(machine.axis_words.index(w) for w in prog.axis_words.words)
    partial = len(columns) < k

    def nominal(a):  # the tool point of program-column axes (m, len(columns)): a lathe's C never commanded is 0
        q = np.zeros((len(a), k))
        q[:, columns] = a
        return nominal_and_jacobian(machine, q)[0]

    job = plan_chain_gcode(prog, s.arc_tolerance_um,
                           ColumnsField(field_, columns, k) if partial and field_ is not None else field_, frames,
                           max_segment_mm=s.max_segment_mm, nominal=nominal, machine=machine)
    tool_mm = job.tool_mm
    if turning is not None and turning.any() and np.isfinite(tool_mm).any():
        raise UsageError(f"{path}: G43 tool lengths while the spindle turns: turning mode compensates X and Z with "
                         "the machine file's tool; leave --tool-table out for this program")

    def full(a, fill):  # the program's columns placed in the machine's k columns
        out = np.full((len(a), k), fill, dtype=float)
        out[:, columns] = a
        return out

    shift = full(job.shift, 0.0)
    axes = full(job.axes, 0.0) + shift  # the spindle's C never commanded: a placeholder 0 (solved over the turn)
    kept_machine = full(job.kept_machine_axes, np.nan)
    if prog.tcp is not None:  # tool-centre-point lines: the tip through the chain's nominal inverse
        axes = prog.tcp.place(machine, prog, frames, job.lines - 1, job.axes)
        known = np.isfinite(job.kept_axes).all(axis=1) if len(job.kept_lines) else np.zeros(0, bool)
        if known.any():
            kept_machine[known] = prog.tcp.place(machine, prog, frames, job.kept_lines[known] - 1, job.kept_axes[known])
        kept_machine[prog.tcp.active(job.kept_lines - 1) & ~known] = np.nan  # a TCP rapid from an unknown pose: unknown
    if turning is not None:
        comp = np.array([t for m, t in zip(prog.moves, turning) if m.compensate], dtype=bool)
        turning = np.repeat(comp, [len(v) for v in job.vertices])
    check_units(path, job.lines, machine=machine, axes=axes, axes_columns=machine.axis_columns, coverage="path",
                units=s.units, option="--units")
    return ChainPath(path, "gcode", axes, job.lines, job, shift=shift, tool_mm=tool_mm, columns=columns,
                     turning=turning, kept_machine=kept_machine)


def _render(tp: ChainPath, axes, machine, comments) -> str:
    if tp.kind == "csv-axes":
        from ...pathio import _render_csv
        dec = [DECIMALS[a.unit] for a in machine.axes]
        return _render_csv(tp.source, {c: (axes[:, j], dec[j]) for j, c in enumerate(machine.axis_columns)}, comments)
    job = tp.source
    verts, s = [], 0
    axes = axes[:, list(tp.columns)]
    for v in job.vertices:
        verts.append(axes[s:s + len(v)])
        s += len(v)
    return render_chain_program(job.program, verts, header=comments)


def _program_axes(tp: ChainPath, axes, machine) -> np.ndarray:
    """The program axes to write for the compensated machine ``axes`` (n, k): minus the work offset and tool
    length shift; in TCP form on tool-centre-point lines (:mod:`compensation.tcp`)."""
    out = axes - tp.shift if tp.shift is not None else axes
    tcp = tp.source.program.tcp if tp.kind == "gcode" else None
    if tcp is None:
        return out
    return tcp.program_axes(machine, tp.source.program, tp.source.frames, tp.lines - 1, axes, out)


def _line(tp: ChainPath, line):
    """A point's line as the report names it (the source line of an expanded program)."""
    if tp.kind != "gcode":
        return int(line)
    from ...nc_expand import source_line
    return source_line(tp.source.program, int(line))


def true_residual_um(truth_field, machine, axes, targets_mm) -> np.ndarray:
    """TRUE residual (μm), (n, 3): the truth machine's tool point at ``axes`` (nominal + its error)
    minus the targets."""
    p, _ = nominal_and_jacobian(machine, axes)
    return (p - targets_mm) * 1e3 + truth_field.predict(axes)


def tool_context(contexts: dict, key: float, field_, truth, machine) -> int:
    """The index in ``contexts`` ({tool key: (index, field, machine, truth)}) of the chain with the tool
    length ``key`` mm (-inf: the machine file's own tool, index 0), added on first use
    (:func:`compensation.nc_state.machine_with_tool`: the field and the truth at that tool point)."""
    if key not in contexts:
        try:
            mt = machine_with_tool(machine, float(key))
            f = field_with_tool(field_, mt)
            tr = field_with_tool(truth, mt) if truth is not None else None
        except (ValueError, TypeError) as exc:
            raise UsageError(f"--tool-table: tool length {key:g} mm: {exc}") from None
        contexts[key] = (len(contexts), f, mt, tr)
    return contexts[key][0]


def chain_batch(paths, field_, truth, machine):
    """The points of ``paths`` as the batch units of :func:`compensation.batch.solve_batch`: one unit per
    file and tool length (``targets_mm`` (m, 3) the nominal tool points at that tool, ``axes`` (m, k),
    ``context`` the tool's chain), turning points left out (solved over the turn, not by the method).
    Returns ``(units, owners, contexts)``: ``owners[u] = (file, point indices)``, ``contexts`` as in
    :func:`tool_context`."""
    from types import SimpleNamespace
    contexts = {-np.inf: (0, field_, machine, truth)}
    units, owners = [], []
    for f, tp in enumerate(paths):
        n = len(tp.axes)
        tool = np.full(n, np.nan) if tp.tool_mm is None else np.asarray(tp.tool_mm, float)
        keys = np.where(np.isfinite(tool), tool, -np.inf)
        solved = np.ones(n, bool) if tp.turning is None else ~np.asarray(tp.turning, bool)
        for key in np.unique(keys[solved]):
            idx = np.flatnonzero((keys == key) & solved)
            j = tool_context(contexts, float(key), field_, truth, machine)
            mt = next(c[2] for c in contexts.values() if c[0] == j)
            units.append(SimpleNamespace(targets_mm=nominal_and_jacobian(mt, tp.axes[idx])[0], axes=tp.axes[idx],
                                         context=j, path=str(tp.path)))
            owners.append((f, idx))
    return units, owners, contexts


def solve_chain_paths(paths, field_, truth, machine, s: ChainSettings, executor=None, progress=None) -> list:
    """Solve every point of ``paths`` with ``s.method``: the points of all files, one unit per file and
    tool length (:func:`chain_batch`), through the chunk plan of :mod:`compensation.batch` (fixed chunks
    and seeds: threads or Ray give the same bytes) on ``executor``; a lathe's turning points over the
    turn (:func:`compensation.turning.solve_with_turning`). Per path ``(SolveResult, targets (n, 3) mm,
    TRUE residual (n, 3) μm, TRUE residual of the program as written)`` (the last two None without a
    truth, or for a program with turning points: taken over the turn by the caller)."""
    from ...batch import gather_results, solve_batch
    units, owners, contexts = chain_batch(paths, field_, truth, machine)
    ctx = sorted(contexts.values(), key=lambda c: c[0])
    options = {"rotary_limit_deg": s.rotary_limit_deg} if s.rotary_limit_deg is not None else {}
    results = solve_batch(s.method, field_, machine, units, seed=s.seed, options=options,
                          chunk_points=s.chunk_points, executor=executor, progress=progress,
                          contexts=[(c[1], c[2]) for c in ctx[1:]]) if units else []
    out = []
    for f, tp in enumerate(paths):
        mine = [(u, owners[k][1], results[k]) for k, u in enumerate(units) if owners[k][0] == f]
        chunks = sum(r.info["chunks"] for _, _, r in mine)
        turning = tp.turning if tp.turning is not None and tp.turning.any() else None
        if turning is None:
            res = gather_results([r for _, _, r in mine], [idx for _, idx, _ in mine])
            targets = res.targets_mm
            true_r = base = None
            if truth is not None:
                true_r, base = np.empty((len(targets), 3)), np.empty((len(targets), 3))
                for u, idx, r in mine:
                    _, _, mt, tr = ctx[u.context]
                    true_r[idx] = true_residual_um(tr, mt, r.axes, u.targets_mm)
                    base[idx] = true_residual_um(tr, mt, u.axes, u.targets_mm)
        else:
            from ...solvers.base import BALL_RADIUS_UM
            from ...turning import solve_with_turning
            rest = np.flatnonzero(~turning)
            rest_res = gather_results([r for _, _, r in mine], [np.searchsorted(rest, idx) for _, idx, _ in mine]) \
                if mine else None
            targets, _ = nominal_and_jacobian(machine, tp.axes)
            res = solve_with_turning(lambda t, a: rest_res, field_, machine, targets, tp.axes, turning, BALL_RADIUS_UM)
            true_r = base = None  # the TRUE residual of turning points is taken over the turn by the caller
        res.info["chunks"] = chunks
        out.append((res, targets, true_r, base))
    return out


PATH_SAMPLES = 8
"""Points per straight segment at which the TRUE residual along the moves is taken (fractions 1/8 … 8/8)."""
JOIN_MM = 1e-9
"""A move starts at the previous vertex when its start is within this of it (the same point)."""


def straight_segments(tp: ChainPath) -> np.ndarray:
    """(n,) bool: point i is reached from point i-1 by a straight G1 segment in axis space (a vertex of a
    split linear move, or the first vertex of a linear move that starts at the vertex before it)."""
    job = tp.source
    cols = list(tp.columns)
    out = np.zeros(len(tp.axes), bool)
    i = 0
    for m, v in zip([m for m in job.program.moves if m.compensate], job.vertices):
        if m.kind == "linear":
            if i > 0 and np.all(np.isfinite(m.start)):
                out[i] = np.abs(m.start + tp.shift[i, cols] - tp.axes[i - 1, cols]).max() <= JOIN_MM
            out[i + 1:i + len(v)] = True
        i += len(v)
    return out


def true_path_residual_um(tp: ChainPath, comp_axes, truth, machine):
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


CUTTER_STEP_MM = 0.5
"""Step of the central differences of the field's gradient (its elements vary over tens of mm)."""


def cutter_radius_bound_um(field_, machine, tp: ChainPath):
    """Under cutter radius compensation (G41/G42 D) the controller cuts up to the tool radius r away from
    the compensated point, where the error differs by at most |dE/dp|·r: that bound (μm, the largest over
    the points under G41/G42; the spectral norm of the field's gradient along the linear axes, central
    differences of :data:`CUTTER_STEP_MM`, at the tool each point runs with). None: no G41/G42 in the program."""
    job = tp.source
    if job.frames is None or job.frames.radius_mm is None:
        return None
    r = job.frames.radius(job.lines - 1)
    on = np.flatnonzero(np.isfinite(r))
    if not on.size:
        return None
    lin = [j for j, a in enumerate(machine.axes) if a.kind == "linear"]
    tool = tp.tool_mm[on]
    keys = np.where(np.isfinite(tool), tool, -np.inf)
    out = 0.0
    for key in np.unique(keys):
        idx = on[keys == key]
        f = field_ if not np.isfinite(key) else field_with_tool(field_, machine_with_tool(machine, float(key)))
        q = tp.axes[idx]
        G = np.empty((len(idx), 3, len(lin)))
        for c, j in enumerate(lin):
            d = np.zeros(q.shape[1])
            d[j] = CUTTER_STEP_MM
            G[:, :, c] = (f.predict(q + d) - f.predict(q - d)) / (2 * CUTTER_STEP_MM)
        out = max(out, float((np.linalg.norm(G, ord=2, axis=(1, 2)) * r[idx]).max()))
    return out


def orientation_pass(field_, truth, machine, tp: ChainPath, res, targets, true_r):
    """``--compensate-orientation``: tool tip and tool axis compensated with every axis
    (:func:`compensation.tcp.compensate_orientation`); the TRUE position residual recomputed at the new axes."""
    from ...tcp import compensate_orientation
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


def tcp_entry(tp: ChainPath, res, machine, truth) -> dict:
    """The summary's ``tcp`` entry of a program with tool-centre-point or G93 words (:func:`compensation.tcp.report`):
    with a truth element set, the TRUE orientation residual of the TCP points before/after (μrad)."""
    from ...tcp import orientation_residual_urad, report
    tcp = tp.source.program.tcp
    on = tcp.active(tp.lines - 1) if tcp is not None else np.ones(len(tp.lines), bool)
    before = after = None
    if truth is not None and on.any():
        tool = tp.tool_mm[on]
        after = orientation_residual_urad(truth, machine, res.axes[on], tp.axes[on], tool)
        before = orientation_residual_urad(truth, machine, tp.axes[on], tp.axes[on], tool)
    solved = res.info.get("orientation_solved")
    return report(tcp, on, before, after, None if solved is None else np.asarray(solved)[on])


def cycle_report(tp: ChainPath, res, true_r, true_base):
    """The summary's ``cycles`` entry of a program with canned cycles (None: none): holes, and for kept
    cycles the tilt per cycle line (|XY correction at R − at the bottom|, μm, the largest of its holes)
    and, with a truth, the TRUE residual at the hole bottoms before/after."""
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
        key = int(exp.origin[h.out_bottom - 1][0])
        per[key] = max(per.get(key, 0.0), t)
    worst = max(per, key=per.get)
    out.update({"tilt_um": {str(k): v for k, v in per.items()}, "tilt_max_um": per[worst], "tilt_max_line": worst,
                "tilt": "|XY correction at the R point - at the hole bottom| (um): the error left along the hole"})
    if true_r is not None:
        b = np.array([last[h.out_bottom] for h in exp.holes])
        out["true_bottom"] = _stats(true_r[b])
        out["true_bottom_uncompensated"] = _stats(true_base[b])
    return out


def _stats(r) -> dict:
    nrm = np.linalg.norm(r, axis=1)
    return {"max_um": float(nrm.max()), "rms_um": float(np.sqrt(np.mean(nrm ** 2))), "mean_um": float(nrm.mean())}


def chain_conditions(field_, conditions: dict, machine):
    """``field_`` with the constant ``conditions`` its effect terms need (``--temp-c``, ``--dir-x`` …, one
    value for the whole program); a condition given that the model does not use, or one it needs that the
    chain path has no option for or that was not given, is refused in one line (UsageError)."""
    needs = tuple(getattr(field_, "needs", ()))
    extra = [c for c in conditions if c not in needs]
    if extra:
        raise UsageError(f"{', '.join('--' + c.replace('_', '-') for c in extra)}: the model has no effect term that "
                         f"uses it on the machine-tool chain {machine.name!r}; leave it out")
    from ...diagnosed_model import CONDITIONS
    missing = [c for c in needs if c not in conditions]
    if missing:
        opts = [c for c in missing if c in CONDITIONS]
        none = [c for c in missing if c not in CONDITIONS]
        if none:
            raise UsageError(f"the model's effect terms need the condition(s) {none}, which compensate on a chain "
                             "cannot take yet (no option; the program has no condition columns)")
        raise UsageError(f"the model's effect terms need the condition(s) {opts}: give them for the whole program "
                         f"({', '.join('--' + c.replace('_', '-') for c in opts)})")
    if needs:
        if "temp_c" in conditions:
            from errormap.units import temperature_mistake
            m = temperature_mistake([float(conditions["temp_c"])], UNITS_CHECK)
            if m is not None:
                raise UsageError(f"--temp-c: units do not fit: {m[1]}")
        for c in needs:
            if c.startswith("dir_") and float(conditions[c]) not in (-1.0, 1.0):
                raise UsageError(f"--{c.replace('_', '-')}: expected +1 or -1, got {conditions[c]}")
        return field_.with_conditions({c: float(conditions[c]) for c in needs})
    return field_


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


def check_chain_settings(machine, s: ChainSettings) -> None:
    """Refuse (UsageError, naming the option) a method or rotary limit the chain cannot take."""
    from ...solvers import CHAIN_METHODS
    if s.method not in CHAIN_METHODS:
        raise UsageError(f"--method {s.method}: on the machine-tool chain {machine.name!r} the methods are "
                         f"{', '.join(CHAIN_METHODS)}")
    try:  # every chain method moves the three axes read from the chain (a lathe's X, Z, C; a mill's X, Y, Z)
        solved_and_kept(machine)
    except ValueError as exc:
        raise UsageError(f"--machine {machine.name} --method {s.method}: {exc}; compensate is not available "
                         f"on this machine") from None
    if s.rotary_limit_deg is not None:
        sol, _ = solved_and_kept(machine)
        if all(machine.axes[j].kind == "linear" for j in sol):
            raise UsageError(f"--max-rotary-correction-deg: the solver moves no rotary axis on {machine.name!r} "
                             f"(it moves {', '.join(machine.axis_columns[j] for j in sol)}; the rotary axes are kept "
                             "as programmed); leave it out")


def compensate_chain_files(files, machine, s: ChainSettings, executor=None) -> int:
    """Compensate the tool-path ``files`` (G-code or axis CSV, told apart by content) of the machine-tool
    chain ``machine`` as ``s`` says; every input read and checked first, every point solved
    (:func:`solve_chain_paths`, on ``executor``: :class:`compensation.batch.LocalExecutor` by default, or
    Ray), the accepted files written as one set with ``compensate_summary.json`` last. Returns the exit
    status (0, or 3: a file refused by a guard); a
    :class:`~compensation.app.workflows.cluster.ClusterError` leaves nothing written."""
    from ...solvers import solver_spec
    check_chain_settings(machine, s)
    allow, conditions, rotary_limit = s.allow, s.conditions, s.rotary_limit_deg
    plan = plan_outputs(files, s.out_dir)
    old_outputs = check_out_dir(s.out_dir, s.force)
    src = require_kind(resolve_model(s.model), ("elements", "chain-model", "chain-network", "mlflow"),
                       f"on the machine-tool chain {machine.name!r} compensate takes")
    verdict = check_verdict(src.path, FAILED_VERDICT in allow)  # a failed diagnosis: refused unless allowed
    print(f"compensate: model {src.description}", file=sys.stderr)
    if src.kind == "mlflow":  # a chain network recorded in MLflow (train --tracking-uri)
        from ...fields import load_field
        field_ = load_field(s.model, machine, s.tracking_uri, source=src)
    elif src.kind == "chain-model":   # elements + terms (+ the learned residual when the loop kept it)
        from ...mt_hybrid import load_chain_model
        field_ = load_chain_model(src.path, machine)
    else:
        field_ = load_chain_field(src.path, machine, src.kind)
    field_ = chain_conditions(field_, conditions, machine)
    from .mt_loop import load_chain_truth
    truth = load_chain_truth(s.truth, machine) if s.truth else None
    paths = [read_chain_path(p, machine, s, field_) for p, _ in plan]
    advance = progress_callback(sum(len(tp.axes) for tp in paths), s.method)
    solved = solve_chain_paths(paths, field_, truth, machine, s, executor=executor, progress=advance)
    outcomes = []
    for (p, dst), tp, (res, targets, true_r, true_base) in zip(plan, paths, solved):
        turning = tp.turning if tp.turning is not None and tp.turning.any() else None
        if turning is None and s.orientation:
            res, true_r = orientation_pass(field_, truth, machine, tp, res, targets, true_r)
        report = guards.check(res, machine, field_, allow=allow, target_axes=tp.axes)
        rotary_refused = rotary_refusals(res, report)
        kept = []
        if tp.kind == "gcode" and len(tp.source.kept_lines):
            job = tp.source
            mid = 0.5 * (machine.stroke_lo + machine.stroke_hi)
            km = tp.kept_machine
            ka = np.where(np.isfinite(km), km, mid)
            idx, reasons = guards.stroke_violations(ka, machine)
            kept = [(_line(tp, job.kept_lines[i]), f"stroke: kept rapid {r}") for i, r in zip(idx, reasons)]
        norm = np.linalg.norm(res.residual_um, axis=1)
        viol = {g: int(len(v)) for g, v in report.violations.items()}
        viol["stroke"] += len(kept)
        entry = {"input": str(p), "output": None, "format": tp.kind, "points": len(tp.axes), "machine": machine.name,
                 "residual": "model", "model_max_um": float(norm.max()), "model_mean_um": float(norm.mean()),
                 "max_correction_um": float(res.correction_um.max()),
                 "failures": int(np.count_nonzero(~res.success)), "guard_violations": viol,
                 "allowed_guards": sorted(report.allowed),
                 "overridden": {g: n for g, n in viol.items() if n and g in report.allowed},
                 "compensated_axes": res.info["compensated_axes"], "kept_axes": res.info["kept_axes"],
                 "seconds": float(res.seconds), "chunks": res.info["chunks"]}
        if res.info.get("note"):
            entry["note"] = res.info["note"]
        if "rotary_refused" in res.info:
            entry["rotary_refused"] = rotary_refused
            entry["rotary_limit_deg"] = res.info.get("rotary_limit_deg")
        if truth is not None:
            after, before = true_r, true_base
            if turning is not None:
                after = true_residual_um(truth, machine, res.axes, targets)
                before = true_residual_um(truth, machine, tp.axes, targets)
                from ...turning import surface_residual_um
                t = np.flatnonzero(turning)
                (a2, spread), (b2, _) = (surface_residual_um(truth, machine, ax[t], tp.axes[t])
                                         for ax in (res.axes, tp.axes))
                after[t] = np.stack([a2[:, 0], np.zeros(len(t)), a2[:, 1]], axis=1)
                before[t] = np.stack([b2[:, 0], np.zeros(len(t)), b2[:, 1]], axis=1)
                entry["turning"] = {"points": int(len(t)), "residual": "turning points: radial and axial deviation "
                                    "from the programmed surface of revolution, mean over one spindle turn (um)",
                                    "true": _stats(after[t]), "true_uncompensated": _stats(before[t]),
                                    "true_roundness_max_um": float(spread.max())}
            entry["true"] = _stats(after)
            entry["true_uncompensated"] = _stats(before)
            along = true_path_residual_um(tp, res.axes, truth, machine) \
                if tp.kind == "gcode" and turning is None else None
            if along is not None:
                entry["true_path"], entry["true_path_uncompensated"] = _stats(along[0]), _stats(along[1])
                entry["true_path_residual"] = (f"along the linear moves as the controller interpolates them, "
                                               f"{PATH_SAMPLES} points per written segment (um)")
            entry["truth"] = str(s.truth)
            entry["truth_conditions"] = "reference: 20 C, positive approach on every axis"
        if tp.kind == "gcode":
            job = tp.source
            entry.update({"lines": len(job.program.lines), "moves_compensated": len(job.vertices),
                          "moves_kept": int(len(job.kept_lines)), "rapids": s.rapids,
                          "arc_tolerance_um": s.arc_tolerance_um, **job.frames.notes,
                          "dialect": job.program.dialect, "dialect_evidence": job.program.dialect_evidence})
            if job.program.tcp is not None or s.orientation or (truth is not None and res.info.get("kept_axes")):
                entry["tcp"] = tcp_entry(tp, res, machine, truth)
            cyc = cycle_report(tp, res, true_r, true_base)
            if cyc is not None:
                entry["cycles"] = cyc
            bound = cutter_radius_bound_um(field_, machine, tp)
            if bound is not None:
                entry["cutter_radius_bound_um"] = bound
        blocking = report.blocking
        refused = bool(blocking) or (bool(kept) and "stroke" not in report.allowed)
        text = None
        if refused:
            entry["refused"] = True
            bad = np.unique(np.concatenate(list(blocking.values()))) if blocking else np.zeros(0, int)
            listed = [(int(i), _line(tp, tp.lines[i]), "; ".join(r for r in report.point_reasons(int(i))
                                                          if r.split(":")[0] in blocking)) for i in bad]
            entry["refused_guards"] = sorted(blocking) or ["stroke"]
        else:
            listed = []
            comments = []
            if entry["overridden"]:
                counts = ", ".join(f"{g} {n}" for g, n in entry["overridden"].items())
                comments = [f"volcomp compensate: GUARDS OVERRIDDEN (--allow {','.join(entry['allowed_guards'])}): "
                            f"{counts} point(s) violate; method={s.method} model={s.model}"]
            elif tp.kind != "gcode":
                comments = [f"compensated by volcomp: method={s.method} model={s.model} machine={machine.name}",
                            f"model residual max {entry['model_max_um']:.4g} um"]
            if tp.kind == "gcode" and s.work_offsets is not None and s.work_offsets.source == MACHINE:
                comments = [WORK_OFFSETS_MACHINE_NOTE] + comments
            comments = verdict_notes(verdict) + comments   # a failed verdict used on request: said in the program
            text = _render(tp, _program_axes(tp, res.axes, machine), machine, comments)
        outcomes.append((p, dst, tp, entry, text, listed, kept if refused else []))
        status = "REFUSED (not written)" if refused else f"-> {dst}"
        tail = ""
        if truth is not None:
            tail = (f", TRUE residual max {entry['true']['max_um']:.4g} um rms {entry['true']['rms_um']:.4g} um "
                    f"(uncompensated {entry['true_uncompensated']['max_um']:.4g} um max)")
            if "true_path" in entry:
                tail += (f", along the moves max {entry['true_path']['max_um']:.4g} um (uncompensated "
                         f"{entry['true_path_uncompensated']['max_um']:.4g} um)")
        print(f"{p}: {entry['points']} points, model residual max {entry['model_max_um']:.4g} um, max correction "
              f"{entry['max_correction_um']:.1f} um{tail}, guard violations {sum(viol.values())} {status}")
        if entry.get("note"):
            print(f"  {entry['note']}")
        if tp.kind == "gcode":
            print(f"  dialect {entry['dialect']}" + (f" ({entry['dialect_evidence']})" if entry["dialect_evidence"] else "")
                  + f"; work offsets: {entry['work_offsets']}" + (f"; tools {entry['tools_used']}" if entry["tools_used"]
                                                                   else ""))
            if entry["g53_lines"]:
                print(f"  G53 (machine coordinates) on line(s) {', '.join(map(str, entry['g53_lines'][:10]))}: passed "
                      "through unchanged, not compensated")
            if "cycles" in entry:
                c = entry["cycles"]
                print(f"  canned cycles {c['mode']}: {c['holes']} hole(s)" + (
                    f", tilt left along the hole max {c['tilt_max_um']:.3g} um (line {c['tilt_max_line']})"
                    if c["mode"] == "keep" else ""))
            if "cutter_radius_bound_um" in entry:
                print(f"  G41/G42 cutter radius compensation: the path is compensated as programmed; the error it "
                      f"leaves is at most {entry['cutter_radius_bound_um']:.3g} um (field gradient x tool radius)")
        if rotary_refused:
            print(f"  rotary continuity: {rotary_refused} point(s) refused (their rotary correction exceeds "
                  f"asin(ball/r){' or the limit' if rotary_limit is not None else ''}; programmed axes kept)")
    written = {dst.name for _, dst, _, _, text, _, _ in outcomes if text is not None}
    removed = []
    for p in sorted(set(old_outputs) | {dst for _, dst, _, _, text, _, _ in outcomes if text is None}):
        if p.is_file() and p.name not in written:
            p.unlink()
            removed.append(str(p))
    import contextlib
    with contextlib.ExitStack() as stack:  # all files in full to temporary files, then renamed together
        for _, dst, tp, entry, text, _, _ in outcomes:
            if text is not None:
                fh = stack.enter_context(atomic_write(dst, "wb"))
                fh.write(text.encode("latin-1" if tp.kind == "gcode" else "utf-8"))
                entry["output"] = str(dst)
    summary = write_json(s.out_dir / SUMMARY_NAME, {
        "conditions": dict(getattr(field_, "conditions", {}) or {}),
        "method": s.method, "model": s.model, "model_source": src.to_dict(), "model_verdict": verdict,
        "units": s.units,
        **({"seed": s.seed} if solver_spec(s.method).seeded else {}),
        "machine": machine.path, "machine_name": machine.name, "allow": list(allow),
        "residual": "model: p_r + E(axes(p_r)) - p_d (um)"
                    + ("; true: truth tool point at the compensated axes - p_d (um)" if truth is not None else ""),
        "chunk_points": s.chunk_points, "max_segment_mm": s.max_segment_mm,
        "solved_on": (executor or LocalExecutor()).describe(),
        "files": [o[3] for o in outcomes], "removed_stale": removed})
    print(f"wrote summary: {summary}")
    refused = [o for o in outcomes if o[4] is None]
    if refused:
        for p, _, _, entry, _, listed, kept in refused:
            print(f"volcomp compensate: {p}: refused by guard(s) {', '.join(entry['refused_guards'])}; "
                  f"{len(listed) + len(kept)} offending point(s):", file=sys.stderr)
            for line, reason in kept[:s.show]:
                print(f"  line {line}: {reason}", file=sys.stderr)
            for i, line, reason in listed[:s.show]:
                print(f"  point {i} (line {line}): {reason}", file=sys.stderr)
        print("volcomp compensate: refused files were not written; override explicitly with --allow GUARDS "
              "(or bare --allow for all)", file=sys.stderr)
        return 3
    return 0
