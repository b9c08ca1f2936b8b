"""``volcomp compensate``: rewrite tool-path files so the tool lands where the program meant.

Each input (CSV axis commands, CSV WCS targets, or G-code; see :mod:`compensation.pathio`)
is solved with the chosen method and written to ``DIR/<same name>`` atomically (the input
is never touched; an output that would overwrite an input is refused before any work).
Files are done one at a time, each complete or absent, so an interrupted batch leaves only
whole files; ``DIR/compensate_summary.json`` is written last.

Guards (DESIGN.md; :mod:`compensation.guards`): a file whose compensated commands leave the
250 μm search ball (``ball``), the axis strokes (``stroke``) or the field's calibrated volume
(``volume``), or whose solver did not converge (``convergence``), is refused — not written —
and the command exits with status 3 listing the offending points (first ``--show`` of them,
with file line and reasons). ``--allow GUARDS`` (comma-separated; bare ``--allow`` = all)
overrides those guards explicitly: the file is written and the violations are reported.
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
from ..diagnosed_model import add_condition_options, load_path_field
from ..pathio import align_turns, read_path, write_compensated
from .. import guards
from ..report import small_batch_threads
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
    p.add_argument("--model", required=True, help="MLflow run id, runs:/ URI, element-set file (JSON), or the "
                   "diagnosed model (DIR/model.json of volcomp diagnose: updated elements + accepted terms)")
    p.add_argument("--method", required=True, choices=METHODS, help="compensation solver")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (files keep their names)")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.add_argument("--seed", type=int, default=0, help="seed of the stochastic solvers (ga, batched-ga)")
    p.add_argument("--allow", nargs="?", const="all", default=None, metavar="GUARDS",
                   help="write commands even where these guards object (comma-separated from "
                        f"{', '.join(guards.GUARDS)}; bare --allow: all of them); violations are still reported")
    p.add_argument("--show", type=int, default=10, help="offending points listed per refused file (default 10)")
    add_condition_options(p)
    p.set_defaults(func=run)


def parse_allow(text) -> tuple:
    """``--allow`` value -> guard names: bare ``--allow`` (``"all"``) overrides every guard."""
    if text is None:
        return ()
    names = tuple(t.strip() for t in str(text).split(",") if t.strip())
    bad = [n for n in names if n not in guards.GUARDS + ("all",)]
    if bad or not names:
        raise UsageError(f"--allow: expected guard names from {list(guards.GUARDS)} or 'all', got {text!r}")
    return ("all",) if "all" in names else names


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
    allow = parse_allow(args.allow)
    machine = load_machine(args.machine, expect_kind="grinder")
    out_dir = Path(args.out)
    plan = _plan_outputs(args.files, out_dir)
    # read everything first: a bad file fails the batch before any work or output
    paths = [read_path(src, machine) for src, _ in plan]
    field = load_path_field(args.model, machine, args.tracking_uri, args)
    opts = {"seed": args.seed} if args.method in ("ga", "batched-ga") else {}
    summary, refused = [], []
    bar = Progress(len(plan), f"compensate ({args.method})", every_s=0.0)
    for (src, dst), tp in zip(plan, paths):
        with small_batch_threads(args.method, len(tp)):
            res = solve(args.method, field, tp.targets_mm, machine, target_axes=tp.axes, **opts)
        res.axes = np.array(res.axes, dtype=float)
        res.axes[:, 2] = align_turns(res.axes[:, 2], tp.axes[:, 2])
        try:
            report = guards.check(res, machine, field, allow=allow)
        except TypeError as exc:  # a field that cannot say where it is calibrated
            raise UsageError(f"{args.model}: {exc}") from None
        viol = [(int(i), int(tp.lines[i]), "; ".join(report.point_reasons(int(i)))) for i in report.indices]
        blocking = set(np.concatenate(list(report.blocking.values())).tolist()) if report.blocking else set()
        norm = np.linalg.norm(res.residual_um, axis=1)
        entry = {"input": str(src), "output": None, "format": tp.kind, "points": len(tp),
                 "residual": "model", "model_max_um": float(norm.max()), "model_mean_um": float(norm.mean()),
                 "max_correction_um": float(np.max(res.correction_um)),
                 "failures": int(np.count_nonzero(~np.asarray(res.success, bool))),
                 "guard_violations": {g: int(len(v)) for g, v in report.violations.items()},
                 "allowed_guards": sorted(report.allowed), "seconds": float(res.seconds)}
        if blocking:
            entry["refused"] = True
            refused.append((src, [v for v in viol if v[0] in blocking], sorted(report.blocking)))
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
        if viol and not blocking:
            print(f"  warning: {len(viol)} point(s) violate allowed guard(s) {', '.join(sorted(report.allowed))}; "
                  f"first: point {viol[0][0]} (line {viol[0][1]}): {viol[0][2]}")
    summary_path = write_json(out_dir / SUMMARY_NAME, {
        "method": args.method, "model": args.model, "machine": machine.path, "allow": list(allow),
        "residual": "model: p_r + E(axes(p_r)) - p_d (um)", "files": summary})
    print(f"wrote summary: {summary_path}")
    if refused:
        for src, viol, names in refused:
            print(f"volcomp compensate: {src}: refused by guard(s) {', '.join(names)}; "
                  f"{len(viol)} offending point(s):", file=sys.stderr)
            for i, line, reason in viol[:args.show]:
                print(f"  point {i} (line {line}): {reason}", file=sys.stderr)
            if len(viol) > args.show:
                print(f"  ... and {len(viol) - args.show} more", file=sys.stderr)
        print("volcomp compensate: refused files were not written; override explicitly with --allow GUARDS "
              "(or bare --allow for all)", file=sys.stderr)
        return EXIT_REFUSED
    return 0
