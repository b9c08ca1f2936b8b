"""``volcomp compensate``: rewrite tool-path files so the tool lands where the program meant.

Each input (CSV axis commands, CSV WCS targets, or G-code; see :mod:`compensation.pathio`
and :mod:`compensation.gcode`) is solved with the chosen method and written to
``DIR/<same name>`` (the input is never touched; an output that would overwrite an input
is refused before any work).

Order of work, so that DIR only ever holds whole files of one run:

1. every input is parsed and validated (a bad one fails the batch with exit 2, naming
   file, line, column and word) before the field is loaded or anything is written;
2. a DIR that already holds files is refused (exit 2) unless ``--force``; with
   ``--force`` the files a previous run listed in its ``compensate_summary.json`` and any
   file at the output path of an input this run refuses are removed;
3. every file is solved, guarded and rendered in memory;
4. the accepted files are written as one set (each in full to a temporary file, then all
   renamed into place); ``compensate_summary.json`` last.

Guards (docs/kinematics.md; :mod:`compensation.guards`), the same for every method: a file whose compensated
commands — or the nominal axes of their targets — leave the strokes (``stroke``) or the
field's calibrated volume (``volume``), whose corrections leave the 250 μm ball
(``ball``), or whose solver did not converge (``convergence``) is refused — not written —
and the command exits with status 3 listing the offending points (first ``--show`` of
them, with file line and reasons). Rapids kept as written are checked against the
strokes too. ``--allow GUARDS`` (comma-separated; bare ``--allow`` = all) overrides those
guards explicitly: the file is written, the override is recorded in the file itself
(a header comment in G-code, a ``#`` line in CSV) and in the summary.
The residual reported per file is the MODEL residual (the solver's own field).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from errormap.io import InputError, write_json
from errormap.machine import load_machine
from errormap.progress import Progress

from ..cli import UsageError
from ...diagnosed_model import add_condition_options, load_path_field
from ...gcode import BLOCK_DELETE_CHOICES, DEFAULT_RAPIDS, RAPIDS_CHOICES
from ...pathio import DEFAULT_ARC_TOLERANCE_UM, align_turns, read_path, render_compensated, replan, write_outputs
from ... import guards
from ..reports.methods import small_batch_threads
from ...solvers import METHODS, solve

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
    p.add_argument("--force", action="store_true",
                   help="write into a DIR that already holds files (removing the previous run's outputs)")
    p.add_argument("--machine", default=None, help="machine file (TOML); default: the built-in grinder")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.add_argument("--seed", type=int, default=0, help="seed of the stochastic solvers (ga, batched-ga)")
    p.add_argument("--allow", nargs="?", const="all", default=None, metavar="GUARDS",
                   help="write commands even where these guards object (comma-separated from "
                        f"{', '.join(guards.GUARDS)}; bare --allow: all of them); violations are still reported")
    p.add_argument("--show", type=int, default=10, help="offending points listed per refused file (default 10)")
    p.add_argument("--rapids", choices=RAPIDS_CHOICES, default=DEFAULT_RAPIDS,
                   help=f"G0 lines: keep as written or compensate their end point (default {DEFAULT_RAPIDS})")
    p.add_argument("--block-delete", choices=BLOCK_DELETE_CHOICES, default=None,
                   help="the controller's block-delete switch: on = '/' lines are skipped, off = they run "
                        "(default: refuse a '/' line that moves or changes modal state)")
    p.add_argument("--arc-tolerance-um", type=float, default=DEFAULT_ARC_TOLERANCE_UM,
                   help="chord tolerance of linearised arcs and split moves, um "
                        f"(default {DEFAULT_ARC_TOLERANCE_UM:g})")
    p.add_argument("--max-segment-mm", default="auto",
                   help="split G1 moves and arcs into segments no longer than this (WCS mm); 'auto' "
                        "(default): from the field's curvature along the file's moves; 'none': no splitting")
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


def parse_max_segment(text):
    """``--max-segment-mm`` value -> ``"auto"``, None (``none``) or a positive float (mm)."""
    t = str(text).strip().lower()
    if t in ("auto", "none"):
        return None if t == "none" else "auto"
    try:
        v = float(t)
    except ValueError:
        v = float("nan")
    if not (np.isfinite(v) and v > 0):
        raise UsageError(f"--max-segment-mm: expected a positive length in mm, 'auto' or 'none', got {text!r}")
    return v


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


def _check_out_dir(out_dir: Path, force: bool) -> list:
    """Refuse a DIR holding files unless ``force``; return the previous run's outputs (to remove)."""
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"--out {out_dir} is not a folder")
    held = sorted(p.name for p in out_dir.iterdir()) if out_dir.is_dir() else []
    if held and not force:
        raise UsageError(f"--out {out_dir} already holds {len(held)} file(s) ({', '.join(held[:3])}"
                         f"{', ...' if len(held) > 3 else ''}); choose an empty folder or pass --force "
                         "(which removes the previous run's outputs)")
    old = []
    summary = out_dir / SUMMARY_NAME
    if held and summary.is_file():
        try:
            doc = json.loads(summary.read_text(encoding="utf-8"))
            old = [out_dir / Path(e["output"]).name for e in doc.get("files", []) if e.get("output")]
        except (ValueError, KeyError, TypeError, AttributeError):
            old = []
    return old


def _kept_stroke_violations(tp, machine) -> list:
    """(line, reason) of rapids kept as written whose nominal end is outside the strokes."""
    job = tp.source if tp.kind == "gcode" else None
    if job is None or not len(job.kept_axes):
        return []
    ax = np.where(np.isfinite(job.kept_axes), job.kept_axes, 0.5 * (machine.stroke_lo + machine.stroke_hi))
    idx, reasons = guards.stroke_violations(ax, machine)
    return [(int(job.kept_lines[i]), f"stroke: kept rapid {r}") for i, r in zip(idx, reasons)]


def _override_note(args, entry) -> str:
    counts = ", ".join(f"{g} {n}" for g, n in entry["guard_violations"].items() if n)
    return (f"volcomp compensate: GUARDS OVERRIDDEN (--allow {','.join(entry['allowed_guards'])}): "
            f"{counts} point(s) violate; method={args.method} model={args.model}")


def run(args) -> int:
    if args.show < 1:
        raise UsageError("--show must be >= 1")
    if not (np.isfinite(args.arc_tolerance_um) and args.arc_tolerance_um > 0):
        raise UsageError(f"--arc-tolerance-um must be > 0, got {args.arc_tolerance_um}")
    max_segment = parse_max_segment(args.max_segment_mm)
    allow = parse_allow(args.allow)
    machine = load_machine(args.machine, expect_kind="grinder")
    out_dir = Path(args.out)
    plan = _plan_outputs(args.files, out_dir)
    old_outputs = _check_out_dir(out_dir, args.force)
    # parse and validate every input first: a bad file fails the batch before any work or output
    read_opts = {"rapids": args.rapids, "block_delete": args.block_delete, "arc_tolerance_um": args.arc_tolerance_um}
    paths = [read_path(src, machine, **read_opts) for src, _ in plan]
    field = load_path_field(args.model, machine, args.tracking_uri, args)
    paths = [replan(tp, machine, max_segment_mm=max_segment, field=field) for tp in paths]
    opts = {"seed": args.seed} if args.method in ("ga", "batched-ga") else {}
    summary, refused, texts = [], [], []
    bar = Progress(len(plan), f"compensate ({args.method})", every_s=0.0)
    for (src, dst), tp in zip(plan, paths):
        with small_batch_threads(args.method, len(tp)):
            res = solve(args.method, field, tp.targets_mm, machine, target_axes=tp.axes, **opts)
        res.axes = np.array(res.axes, dtype=float)
        res.axes[:, 2] = align_turns(res.axes[:, 2], tp.axes[:, 2])
        try:
            report = guards.check(res, machine, field, allow=allow, target_axes=tp.axes)
        except TypeError as exc:  # a field that cannot say where it is calibrated
            raise UsageError(f"{args.model}: {exc}") from None
        viol = [(int(i), int(tp.lines[i]), "; ".join(report.point_reasons(int(i)))) for i in report.indices]
        blocking = set(np.concatenate(list(report.blocking.values())).tolist()) if report.blocking else set()
        kept = _kept_stroke_violations(tp, machine)
        kept_blocking = bool(kept) and "stroke" not in report.allowed
        norm = np.linalg.norm(res.residual_um, axis=1)
        violations = {g: int(len(v)) for g, v in report.violations.items()}
        violations["stroke"] += len(kept)
        entry = {"input": str(src), "output": None, "format": tp.kind, "points": len(tp),
                 "residual": "model", "model_max_um": float(norm.max()), "model_mean_um": float(norm.mean()),
                 "max_correction_um": float(np.max(res.correction_um)),
                 "failures": int(np.count_nonzero(~np.asarray(res.success, bool))),
                 "guard_violations": violations, "allowed_guards": sorted(report.allowed),
                 "overridden": {g: n for g, n in violations.items() if n and g in report.allowed},
                 "seconds": float(res.seconds)}
        if tp.kind == "gcode":
            job = tp.source
            entry.update({"lines": len(job.program.lines),
                          "moves_compensated": len(job.params), "moves_kept": int(len(job.kept_lines)),
                          "rapids": args.rapids, "block_delete": args.block_delete,
                          "arc_tolerance_um": job.arc_tolerance_um, "max_segment_mm": job.max_segment_mm,
                          "field_curvature_um_per_mm2": job.curvature_um_per_mm2})
        text = None
        if blocking or kept_blocking:
            entry["refused"] = True
            refused.append((src, [v for v in viol if v[0] in blocking], sorted(report.blocking) or ["stroke"],
                            kept if kept_blocking else []))
        else:
            comments = [f"compensated by volcomp: method={args.method} model={args.model}",
                        f"model residual max {entry['model_max_um']:.4g} um"]
            if entry["overridden"]:
                comments.insert(0, _override_note(args, entry))
            elif tp.kind == "gcode":
                comments = []  # a clean G-code output gets no added lines
            text = render_compensated(tp, res.axes, res.commands_mm, comments=comments)
        texts.append(text)
        summary.append(entry)
        bar.update(1, extra=src.name)
        status = "REFUSED (not written)" if entry.get("refused") else f"-> {dst}"
        n_viol = len(viol) + len(kept)
        print(f"{src}: {entry['points']} points, model residual max {entry['model_max_um']:.4g} um "
              f"mean {entry['model_mean_um']:.4g} um, max correction {entry['max_correction_um']:.1f} um, "
              f"failures {entry['failures']}, guard violations {n_viol} {status}")
        if entry["overridden"] and text is not None:
            print(f"  warning: guards overridden ({', '.join(f'{g} {n}' for g, n in entry['overridden'].items())} "
                  f"point(s)); recorded in the output file's header and the summary")
    # write: remove what a previous run left, then the accepted files, the summary last
    written = {dst.name for (_, dst), t in zip(plan, texts) if t is not None}
    stale = set(old_outputs) | {dst for (_, dst), t in zip(plan, texts) if t is None}
    removed = []
    for p in sorted(stale):
        if p.is_file() and p.name not in written:
            p.unlink()
            removed.append(str(p))
    write_outputs([(tp, dst, text) for (_, dst), tp, text in zip(plan, paths, texts) if text is not None])
    for (_, dst), text, entry in zip(plan, texts, summary):
        if text is not None:
            entry["output"] = str(dst)
    summary_path = write_json(out_dir / SUMMARY_NAME, {
        "method": args.method, "model": args.model, "machine": machine.path, "allow": list(allow),
        "residual": "model: p_r + E(axes(p_r)) - p_d (um)", "files": summary,
        "removed_stale": removed})
    print(f"wrote summary: {summary_path}")
    if refused:
        for src, viol, names, kept in refused:
            print(f"volcomp compensate: {src}: refused by guard(s) {', '.join(names)}; "
                  f"{len(viol) + len(kept)} offending point(s):", file=sys.stderr)
            for line, reason in kept[:args.show]:
                print(f"  line {line}: {reason}", file=sys.stderr)
            for i, line, reason in viol[:args.show]:
                print(f"  point {i} (line {line}): {reason}", file=sys.stderr)
            if len(viol) > args.show:
                print(f"  ... and {len(viol) - args.show} more", file=sys.stderr)
        print("volcomp compensate: refused files were not written; override explicitly with --allow GUARDS "
              "(or bare --allow for all)", file=sys.stderr)
        return EXIT_REFUSED
    return 0
