"""``volcomp compensate``: rewrite tool-path files so the tool lands where the program meant.

Each input (CSV axis commands, CSV WCS targets, or G-code; see :mod:`compensation.pathio`)
is solved with the chosen method and written to ``DIR/<same name>`` atomically (the input
is never touched; an output that would overwrite an input is refused before any work).
Files are done one at a time, each complete or absent, so an interrupted batch leaves only
whole files; ``DIR/compensate_summary.json`` is written last.

Guards (DESIGN.md): a file whose compensated commands leave the 250 μm search ball, the
axis strokes or the calibrated volume is refused — not written — and the command exits
with status 3 listing the offending points (first ``--show`` of them, with reasons), unless
``--allow`` is given, in which case the file is written and the violations are reported.
The residual reported per file is the MODEL residual (the solver's own field).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from errormap.io import InputError, write_json
from errormap.machine import load_machine
from errormap.progress import Progress

from ..cli import UsageError
from ..fields import load_field
from ..pathio import align_turns, read_path, write_compensated
from ..solvers import METHODS, solve

EXIT_REFUSED = 3
SUMMARY_NAME = "compensate_summary.json"


def register(sub):
    p = sub.add_parser(
        "compensate", help="compensate tool-path files (CSV or G-code) with an error field",
        description="Compensate each FILE with --model and write DIR/<same name>. Reports the MODEL "
                    "residual. Exit status 3 when the guards refuse a file (unless --allow).")
    p.add_argument("files", nargs="+", metavar="FILE", help="tool path: .csv (x_mm,z_mm,a_deg or "
                   "px_mm,py_mm,pz_mm) or G-code (any other suffix)")
    p.add_argument("--model", required=True, help="MLflow run id, runs:/ URI, or element-set file (JSON)")
    p.add_argument("--method", required=True, choices=METHODS, help="compensation solver")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (files keep their names)")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.add_argument("--seed", type=int, default=0, help="seed of the stochastic solvers (ga, batched-ga)")
    p.add_argument("--allow", action="store_true",
                   help="write commands even where the guards object (ball, strokes, calibrated volume)")
    p.add_argument("--show", type=int, default=10, help="offending points listed per refused file (default 10)")
    p.set_defaults(func=run)


def _guard_violations(result, machine, points_lines) -> list:
    """``[(point index, file line, reason), ...]`` for the compensated commands of ``result``.

    Uses :mod:`compensation.guards` when it is present; falls back to the solver's own
    ``success`` flags and the X/Z strokes.
    """
    try:
        from .. import guards
    except ImportError:
        guards = None
    if guards is not None and hasattr(guards, "violations"):
        return [(int(i), int(points_lines[i]), str(reason)) for i, reason in guards.violations(result, machine)]
    out = []
    for i in np.flatnonzero(~np.asarray(result.success, bool)):
        out.append((int(i), int(points_lines[i]),
                    f"solver did not succeed (correction {result.correction_um[i]:.1f} um, "
                    f"model residual {np.linalg.norm(result.residual_um[i]):.3g} um)"))
    for j, key in ((0, "x_mm"), (1, "z_mm")):
        lo, hi = machine.strokes[key]
        for i in np.flatnonzero((result.axes[:, j] < lo) | (result.axes[:, j] > hi)):
            out.append((int(i), int(points_lines[i]), f"{key} = {result.axes[i, j]:.6f} outside stroke [{lo}, {hi}]"))
    return sorted(out)


def _plan_outputs(files, out_dir: Path) -> list:
    """Output path per input; refuses duplicates and outputs that would overwrite an input."""
    inputs = [Path(f) for f in files]
    for p in inputs:
        if not p.is_file():
            raise InputError(f"{p}: no such file")
    outs = [out_dir / p.name for p in inputs]
    seen = {}
    for p, o in zip(inputs, outs):
        if o.name in seen:
            raise UsageError(f"two inputs would both be written to {o}: {seen[o.name]} and {p}")
        seen[o.name] = p
    resolved_inputs = {p.resolve() for p in inputs}
    for o in outs:
        if o.resolve() in resolved_inputs:
            raise UsageError(f"--out {out_dir} would overwrite the input {o}; choose another folder")
    return list(zip(inputs, outs))


def run(args) -> int:
    if args.show < 1:
        raise UsageError("--show must be >= 1")
    machine = load_machine(args.machine, expect_kind="grinder")
    out_dir = Path(args.out)
    plan = _plan_outputs(args.files, out_dir)
    # read everything first: a bad file fails the batch before any work or output
    paths = [read_path(src, machine) for src, _ in plan]
    field = load_field(args.model, machine, args.tracking_uri)
    opts = {"seed": args.seed} if args.method in ("ga", "batched-ga") else {}
    summary, refused = [], []
    bar = Progress(len(plan), f"compensate ({args.method})", every_s=0.0)
    for (src, dst), tp in zip(plan, paths):
        res = solve(args.method, field, tp.targets_mm, machine, target_axes=tp.axes, **opts)
        res.axes = np.array(res.axes, dtype=float)
        res.axes[:, 2] = align_turns(res.axes[:, 2], tp.axes[:, 2])
        viol = _guard_violations(res, machine, tp.lines)
        norm = np.linalg.norm(res.residual_um, axis=1)
        entry = {"input": str(src), "output": None, "format": tp.kind, "points": len(tp),
                 "residual": "model", "model_max_um": float(norm.max()), "model_mean_um": float(norm.mean()),
                 "max_correction_um": float(np.max(res.correction_um)),
                 "failures": int(np.count_nonzero(~np.asarray(res.success, bool))),
                 "guard_violations": len(viol), "seconds": float(res.seconds)}
        if viol and not args.allow:
            entry["refused"] = True
            refused.append((src, viol))
        else:
            comments = [f"compensated by volcomp: method={args.method} model={args.model}",
                        f"model residual max {entry['model_max_um']:.4g} um"]
            write_compensated(tp, dst, res.axes, res.commands_mm, comments=comments)
            entry["output"] = str(dst)
        summary.append(entry)
        bar.update(1, extra=src.name)
        status = "REFUSED (not written)" if entry.get("refused") else f"-> {dst}"
        print(f"{src}: {entry['points']} points, model residual max {entry['model_max_um']:.4g} um "
              f"mean {entry['model_mean_um']:.4g} um, max correction {entry['max_correction_um']:.1f} um, "
              f"failures {entry['failures']}, guard violations {len(viol)} {status}")
    summary_path = write_json(out_dir / SUMMARY_NAME, {
        "method": args.method, "model": args.model, "machine": machine.path, "allow": bool(args.allow),
        "residual": "model: p_r + E(axes(p_r)) - p_d (um)", "files": summary})
    print(f"wrote summary: {summary_path}")
    if refused:
        for src, viol in refused:
            print(f"volcomp compensate: {src}: refused, {len(viol)} offending point(s):", file=sys.stderr)
            for i, line, reason in viol[:args.show]:
                print(f"  point {i} (line {line}): {reason}", file=sys.stderr)
            if len(viol) > args.show:
                print(f"  ... and {len(viol) - args.show} more", file=sys.stderr)
        print("volcomp compensate: refused files were not written; pass --allow to override", file=sys.stderr)
        return EXIT_REFUSED
    return 0
