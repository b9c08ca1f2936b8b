"""``volcomp compensate`` on a machine-tool chain (``--machine mill-xyz``, ``five-axis-ac`` ...).

The grinder's order of work (:mod:`compensation.app.workflows.compensate`) over the machine's own
axes: every input is read and checked first (G-code by :mod:`compensation.mt_gcode` with the
machine's axis words, or a CSV with the machine's axis columns ``x_mm, y_mm, z_mm ...``; told apart
by content), then the model (an element set of the chain, recognised by content), the exact chain
solver (:mod:`compensation.solvers.chain_exact`: the tool-tip position with the linear axes, rotary
axes kept, said in the summary), the guards (ball, strokes, calibrated volume, convergence;
``--allow`` overrides and the override is written into the file and the summary), and the
accepted files written as one set with ``compensate_summary.json`` last.

Residuals: the MODEL residual of every file (the solver's own field); with ``truth`` (a truth
element set of the same chain, given by a tester or a benchmark, never to the solver) also the
TRUE residual — the tool point the truth machine reaches when driven with the compensated axes,
minus the target — beside the uncompensated machine's true error (the baseline: the program run
as written).
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
from ...fields import load_chain_field, require_kind, resolve_model
from ...gcode import DEFAULT_RAPIDS
from ...mt_gcode import parse_chain_program, plan_chain_gcode, render_chain_program
from ...pathio import DEFAULT_ARC_TOLERANCE_UM, is_csv
from ...solvers.chain_exact import nominal_and_jacobian, solved_and_kept
from .compensate import SUMMARY_NAME, check_out_dir, plan_outputs

DECIMALS = {"mm": 6, "deg": 6}  # 1 nm; 1e-6 deg


@dataclass
class ChainPath:
    """One input: ``kind`` ``"gcode"`` or ``"csv-axes"``, ``axes`` (n, k) nominal axes of every
    point (vertex), ``lines`` (n,) source line (G-code) or row (CSV), ``source`` the parsed job or
    table."""

    path: Path
    kind: str
    axes: np.ndarray
    lines: np.ndarray
    source: object
    columns: tuple = ()
    """G-code: the machine axes (indices) the program's words are, in order (all of them, or a lathe's
    X and Z where the program never commands the spindle's C)."""
    turning: np.ndarray | None = None
    """G-code on a machine with a ``[spindle]``: (n,) points cut while the spindle turns (X, Z only;
    :mod:`compensation.turning`)."""


@dataclass
class ChainSettings:
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
    outcomes: list = field(default_factory=list)


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
        prog, turning = parse_lathe_program(path, machine, s.rapids, s.block_delete)
    else:
        prog = parse_chain_program(path, machine, rapids=s.rapids, block_delete=s.block_delete)
    k = len(machine.axes)
    columns = tuple(machine.axis_words.index(w) for w in prog.axis_words.words)
    partial = len(columns) < k
    job = plan_chain_gcode(prog, s.arc_tolerance_um,
                           ColumnsField(field_, columns, k) if partial and field_ is not None else field_)
    axes = job.axes
    if partial:  # the spindle's C never commanded: a placeholder 0 (turning points are solved over the turn)
        axes = np.zeros((len(job.axes), k))
        axes[:, columns] = job.axes
        kept_axes = np.full((len(job.kept_axes), k), np.nan)
        kept_axes[:, columns] = job.kept_axes
        job.kept_axes = kept_axes
    if turning is not None:
        comp = np.array([t for m, t in zip(prog.moves, turning) if m.compensate], dtype=bool)
        turning = np.repeat(comp, [len(v) for v in job.vertices])
    check_units(path, job.lines, machine=machine, axes=axes, axes_columns=machine.axis_columns, coverage="path",
                units=s.units, option="--units")
    return ChainPath(path, "gcode", axes, job.lines, job, columns, turning)


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


def run_chain_compensate(machine, args, allow) -> int:
    """The ``compensate`` command on a machine-tool chain; returns the exit status."""
    from ...solvers import CHAIN_METHODS, solve, solver_spec
    if args.method not in CHAIN_METHODS:
        raise UsageError(f"--method {args.method}: on the machine-tool chain {machine.name!r} the methods are "
                         f"{', '.join(CHAIN_METHODS)}")
    from ..options import conditions_from_args
    from ...batch import CHUNK_POINTS
    unsupported = {"--cluster": getattr(args, "cluster", None), "--workers": getattr(args, "workers", None),
                   "--max-segment-mm": None if str(args.max_segment_mm).strip().lower() == "auto" else args.max_segment_mm,
                   "--chunk-points": None if getattr(args, "chunk_points", CHUNK_POINTS) == CHUNK_POINTS else args.chunk_points}
    given = [k for k, v in unsupported.items() if v is not None]
    if given:  # refused, never silently ignored
        raise UsageError(f"{', '.join(given)}: not available on the machine-tool chain {machine.name!r} (one process; "
                         "moves split from the field's curvature)")
    conditions = {k: v for k, v in conditions_from_args(args).items() if v is not None}
    try:  # every chain method moves the three axes read from the chain (a lathe's X, Z, C; a mill's X, Y, Z)
        solved_and_kept(machine)
    except ValueError as exc:
        raise UsageError(f"--machine {machine.name} --method {args.method}: {exc}; compensate is not available "
                         f"on this machine") from None
    rotary_limit = getattr(args, "max_rotary_correction_deg", None)
    if rotary_limit is not None:
        sol, _ = solved_and_kept(machine)
        if all(machine.axes[j].kind == "linear" for j in sol):
            raise UsageError(f"--max-rotary-correction-deg: the solver moves no rotary axis on {machine.name!r} "
                             f"(it moves {', '.join(machine.axis_columns[j] for j in sol)}; the rotary axes are kept "
                             "as programmed); leave it out")
    s = ChainSettings(method=args.method, model=args.model, out_dir=Path(args.out), force=args.force, allow=allow,
                      rapids=args.rapids, block_delete=args.block_delete, arc_tolerance_um=args.arc_tolerance_um,
                      units=args.units, truth=args.truth)
    plan = plan_outputs(args.files, s.out_dir)
    old_outputs = check_out_dir(s.out_dir, s.force)
    src = require_kind(resolve_model(s.model), ("elements", "chain-model", "chain-network", "mlflow"),
                       f"on the machine-tool chain {machine.name!r} compensate takes")
    print(f"compensate: model {src.description}", file=sys.stderr)
    if src.kind == "mlflow":  # a chain network recorded in MLflow (train --tracking-uri)
        from ...fields import load_field
        field_ = load_field(s.model, machine, getattr(args, "tracking_uri", None), source=src)
    elif src.kind == "chain-model":   # elements + terms (+ the learned residual when the loop kept it)
        from ...mt_hybrid import load_chain_model
        field_ = load_chain_model(src.path, machine)
    else:
        field_ = load_chain_field(src.path, machine, src.kind)
    field_ = chain_conditions(field_, conditions, machine)
    from .mt_loop import load_chain_truth
    truth = load_chain_truth(s.truth, machine) if s.truth else None
    paths = [read_chain_path(p, machine, s, field_) for p, _ in plan]
    outcomes = []
    for (p, dst), tp in zip(plan, paths):
        targets, _ = nominal_and_jacobian(machine, tp.axes)
        seeded = {"seed": args.seed} if solver_spec(s.method).seeded else {}
        limit = {"rotary_limit_deg": rotary_limit} if rotary_limit is not None else {}
        turning = tp.turning if tp.turning is not None and tp.turning.any() else None
        if turning is None:
            res = solve(s.method, field_, targets, machine, target_axes=tp.axes, progress=False, **seeded, **limit)
        else:
            from ...solvers.base import BALL_RADIUS_UM
            from ...turning import solve_with_turning
            res = solve_with_turning(lambda t, a: solve(s.method, field_, t, machine, target_axes=a, progress=False,
                                                        **seeded, **limit),
                                     field_, machine, targets, tp.axes, turning, BALL_RADIUS_UM)
        report = guards.check(res, machine, field_, allow=allow, target_axes=tp.axes)
        rotary_refused = rotary_refusals(res, report)
        kept = []
        if tp.kind == "gcode" and len(tp.source.kept_lines):
            job = tp.source
            mid = 0.5 * (machine.stroke_lo + machine.stroke_hi)
            ka = np.where(np.isfinite(job.kept_axes), job.kept_axes, mid)
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
                 "seconds": float(res.seconds)}
        if res.info.get("note"):
            entry["note"] = res.info["note"]
        if "rotary_refused" in res.info:
            entry["rotary_refused"] = rotary_refused
            entry["rotary_limit_deg"] = res.info.get("rotary_limit_deg")
        if truth is not None:
            after = true_residual_um(truth, machine, res.axes, targets)
            before = true_residual_um(truth, machine, tp.axes, targets)
            if turning is not None:
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
            entry["truth"] = str(s.truth)
            entry["truth_conditions"] = "reference: 20 C, positive approach on every axis"
        if tp.kind == "gcode":
            job = tp.source
            entry.update({"lines": len(job.program.lines), "moves_compensated": len(job.vertices),
                          "moves_kept": int(len(job.kept_lines)), "rapids": s.rapids,
                          "arc_tolerance_um": s.arc_tolerance_um})
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
            text = _render(tp, res.axes, machine, comments)
        outcomes.append((p, dst, tp, entry, text, listed, kept if refused else []))
        status = "REFUSED (not written)" if refused else f"-> {dst}"
        tail = ""
        if truth is not None:
            tail = (f", TRUE residual max {entry['true']['max_um']:.4g} um rms {entry['true']['rms_um']:.4g} um "
                    f"(uncompensated {entry['true_uncompensated']['max_um']:.4g} um max)")
        print(f"{p}: {entry['points']} points, model residual max {entry['model_max_um']:.4g} um, max correction "
              f"{entry['max_correction_um']:.1f} um{tail}, guard violations {sum(viol.values())} {status}")
        if entry.get("note"):
            print(f"  {entry['note']}")
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
        "method": s.method, "model": s.model, "model_source": src.to_dict(), "units": s.units,
        **({"seed": args.seed} if solver_spec(s.method).seeded else {}),
        "machine": machine.path, "machine_name": machine.name, "allow": list(allow),
        "residual": "model: p_r + E(axes(p_r)) - p_d (um)"
                    + ("; true: truth tool point at the compensated axes - p_d (um)" if truth is not None else ""),
        "files": [o[3] for o in outcomes], "removed_stale": removed})
    print(f"wrote summary: {summary}")
    refused = [o for o in outcomes if o[4] is None]
    if refused:
        for p, _, _, entry, _, listed, kept in refused:
            print(f"volcomp compensate: {p}: refused by guard(s) {', '.join(entry['refused_guards'])}; "
                  f"{len(listed) + len(kept)} offending point(s):", file=sys.stderr)
            for line, reason in kept[:args.show]:
                print(f"  line {line}: {reason}", file=sys.stderr)
            for i, line, reason in listed[:args.show]:
                print(f"  point {i} (line {line}): {reason}", file=sys.stderr)
        print("volcomp compensate: refused files were not written; override explicitly with --allow GUARDS "
              "(or bare --allow for all)", file=sys.stderr)
        return 3
    return 0
