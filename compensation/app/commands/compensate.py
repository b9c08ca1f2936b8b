"""``volcomp compensate``: rewrite tool-path files so the tool lands where the program meant.

Each input (CSV axis commands, CSV WCS targets, or G-code; :mod:`compensation.pathio`,
:mod:`compensation.gcode`) is solved with the chosen method on the machine's chain and written to
``DIR/<same name>``; the work is :mod:`compensation.app.workflows.compensate` (parse and validate every
input first, exit 2; solve in chunks, in threads or on Ray, exit 4 if a cluster cannot finish; guard;
write the accepted files as one set, ``compensate_summary.json`` last). A file the guards
(:mod:`compensation.guards`) refuse is not written and the command exits 3 (unless ``--allow``). The
residual reported is the MODEL residual (with ``--truth`` the TRUE one beside it). A serial arm
compensates joint programs (:mod:`compensation.app.workflows.arm_compensate`). The options and the order
of work: docs/reference/tool-paths.md ("volcomp compensate").
"""
from __future__ import annotations

import sys
from pathlib import Path

from errormap.io import InputError
from errormap.machine import load_machine

from compensation.app.validate import UsageError, one_line

from ..families import family_of, say_read_as
from ..outputs import check_out_dir, plan_outputs
from ..options import add_cluster_options, add_condition_options, add_units_option, cluster_settings, conditions_from_args
from ..workflows.cluster import EXIT_CLUSTER, ClusterError
from ... import guards
from ...fields import FAILED_VERDICT, resolve_model
from ...gcode_words import BLOCK_DELETE_CHOICES, DEFAULT_RAPIDS, RAPIDS_CHOICES
from ...dialects import DIALECT_NAMES
from ...nc_subfiles import SubprogramFiles
from ...nc_state import read_tool_table, read_work_offsets
from ...pathio import ARC_TOLERANCE_RANGE_UM, DEFAULT_ARC_TOLERANCE_UM, SEGMENT_RANGE_MM
from ...solvers import METHODS

EXIT_REFUSED = 3


def register(sub):
    p = sub.add_parser(
        "compensate", help="compensate tool-path files (CSV or G-code) with an error field",
        description="Compensate each FILE with --model and write DIR/<same name>. Reports the MODEL "
                    "residual. Exit status 3 when the guards refuse a file (unless --allow).")
    p.add_argument("files", nargs="+", metavar="FILE", help="tool path: CSV (a header x_mm,z_mm,a_deg or "
                   "px_mm,py_mm,pz_mm) or G-code, told apart by content whatever the name")
    p.add_argument("--model", required=True, help="MLflow run id, runs:/ URI, element-set file (JSON), or the "
                   "diagnosed model (DIR/model.json of volcomp diagnose: updated elements + accepted terms)")
    p.add_argument("--method", default=None, choices=METHODS, help="compensation solver (required; serial "
                   "chains: Newton on the calibrated chain, docs/explanation/serial-arms.md)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (files keep their names)")
    p.add_argument("--force", action="store_true",
                   help="write into a DIR that already holds files (removing the previous run's outputs)")
    p.add_argument("--machine", default=None, help="machine file (TOML) or built-in name; default: the built-in "
                   "grinder; a serial chain (e.g. ur5) compensates joint programs with its model.json")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for run ids")
    p.add_argument("--seed", type=int, default=0, help="seed of the stochastic solvers (ga, batched-ga)")
    p.add_argument("--allow", nargs="?", const="all", default=None, metavar="GUARDS",
                   help="write commands even where these guards object (comma-separated from "
                        f"{', '.join(guards.GUARDS)}; bare --allow: all of them); violations are still reported; "
                        f"{FAILED_VERDICT}: use a model whose diagnosis verdict failed (named explicitly, never by a "
                        "bare --allow; recorded in the summary)")
    p.add_argument("--truth", default=None, metavar="ELEMENTS",
                   help="machine-tool chains: a truth element set of the same chain (simulated machine, given by a "
                        "tester or benchmark, never used by the solver): the TRUE residual is reported beside the model's")
    p.add_argument("--show", type=int, default=10, help="offending points listed per refused file (default 10)")
    p.add_argument("--rapids", choices=RAPIDS_CHOICES, default=DEFAULT_RAPIDS,
                   help=f"G0 lines: keep as written or compensate their end point (default {DEFAULT_RAPIDS})")
    p.add_argument("--block-delete", choices=BLOCK_DELETE_CHOICES, default=None,
                   help="the controller's block-delete switch: on = '/' lines are skipped, off = they run "
                        "(default: refuse a '/' line that moves or changes modal state)")
    lo, hi = ARC_TOLERANCE_RANGE_UM
    p.add_argument("--arc-tolerance-um", type=float, default=DEFAULT_ARC_TOLERANCE_UM,
                   help="chord tolerance of linearised arcs and split moves, um "
                        f"(default {DEFAULT_ARC_TOLERANCE_UM:g}; in [{lo:g}, {hi:g}]: below 1 nm the 6-decimal program "
                        "cannot state it, above 5 um the chords' sagitta is as large as the error compensation leaves)")
    lo, hi = SEGMENT_RANGE_MM
    p.add_argument("--max-segment-mm", default="auto",
                   help="split each G1 move and arc into pieces of at most this tool-point path length (mm, in "
                        f"[{lo:g}, {hi:g}]); 'auto' (default): pieces per move from the field's second differences "
                        "along it (docs/reference/tool-paths.md, Vertices); 'none': no splitting (arcs keep their "
                        "chords)")
    p.add_argument("--max-rotary-correction-deg", type=float, default=None, metavar="DEG",
                   help="machine-tool chains whose solver moves a rotary axis (lathe-xzc's C): refuse a point whose "
                        "compensated rotary command differs from the programmed one by more than DEG (default: only "
                        "the ball's bound asin(ball/r), r the target's distance from the axis)")
    p.add_argument("--compensate-orientation", action="store_true",
                   help="five-axis machine-tool chains with an element-set model: compensate the tool's orientation "
                        "too, with the rotary axes (written back as corrected rotary words; near a singularity, the "
                        "tool along the last rotary axis, that axis is held and the other turns out what it can, "
                        "counted in the summary)")
    p.add_argument("--dialect", default="auto", choices=("auto", *DIALECT_NAMES),
                   help="the controller the G-code is written for: its harmless M codes, program numbers, look-ahead "
                        "and block-delete rules (compensation/dialects.py); auto (default): recognised from the "
                        "program's content (shown in the summary), else the words every controller shares (a bare "
                        "axis word after G80 then moves in the G0-G3 of before it, as on Fanuc: recorded)")
    p.add_argument("--work-offsets", default=None, metavar="FILE|machine",
                   help="the controller's work offsets (G54..G59.3, G54.1 Pn): a LinuxCNC parameter file (.var) or a CSV "
                        "system,x_mm,y_mm,z_mm[,a_deg,b_deg,c_deg] (by content); 'machine': the program is written in "
                        "machine coordinates (recorded in the summary and the output). Every G-code program is refused "
                        "without it (a controller runs a program in its active work system, G54 at power-on, never at "
                        "an assumed machine zero); CSV axis paths are machine axes and need none")
    p.add_argument("--tool-table", default=None, metavar="FILE",
                   help="machine-tool chains: the tool lengths of G43 Hn: a LinuxCNC tool table (.tbl) or a CSV "
                        "tool,length_mm[,radius_mm] (by content); a lathe's tool X and Z offsets (.tbl X Z, CSV "
                        "tool,x_mm,z_mm[,radius_mm]; G43, or TttOO on Fanuc/Haas); the offset is the Abbe arm of the "
                        "angular errors")
    p.add_argument("--lathe-x", default=None, choices=("diameter", "radius"),
                   help="a Fanuc, Haas or Siemens ISO lathe program: whether its X words are diameters or radii (a "
                        "parameter of the control, not a word of the program; LinuxCNC programs say it with G7/G8). "
                        "Overrides the machine file's [spindle] x_words for this run; without either such a "
                        "program's X is refused")
    p.add_argument("--subprograms", action="append", default=None, metavar="DIR",
                   help="G-code: a folder of subprograms kept outside the program (repeatable, searched in the order "
                        "given, like LinuxCNC's SUBROUTINE_PATH): o<name> call reads DIR/name.ngc; M98/G65 Pn finds "
                        "the file whose program-number line is On or :n (by content, never by file name; a number in "
                        "two files is refused). Calls are expanded into the flat program written; the files read "
                        "and their SHA-256 are in the summary")
    p.add_argument("--expand-cycles", action="store_true",
                   help="machine-tool chains: write drilling canned cycles (G73 G81-G89) as the controller's explicit "
                        "G0/G1/G4 moves, compensated point by point (default: kept as cycles, each hole's X Y Z and R "
                        "compensated at its bottom and R plane and the tilt left along the hole reported); a Fanuc/"
                        "Haas lathe's G70 as its contour's moves, the roughing cycle and contour kept as written; a "
                        "Fanuc lathe's G74/G75 grooving cycles as their pecks, returns and shifts (default: kept where "
                        "only the bottom needs its plunge word compensated)")
    add_condition_options(p)
    add_units_option(p, "CSV tool-path columns")
    add_cluster_options(p)
    p.set_defaults(func=run)


def parse_allow(text) -> tuple:
    """``--allow`` value -> guard names: bare ``--allow`` (``"all"``) overrides every guard."""
    if text is None:
        return ()
    names = tuple(t.strip() for t in str(text).split(",") if t.strip())
    bad = [n for n in names if n not in guards.GUARDS + ("all", FAILED_VERDICT)]
    if bad or not names:
        raise UsageError(f"--allow: expected guard names from {list(guards.GUARDS)} or 'all' (and "
                         f"{FAILED_VERDICT!r}), got {text!r}")
    verdict = (FAILED_VERDICT,) if FAILED_VERDICT in names else ()
    return ("all",) + verdict if "all" in names else names


def parse_max_segment(text):
    """``--max-segment-mm`` value -> ``"auto"``, None (``none``) or a length in mm (its range is
    checked before the run: :class:`compensation.app.validate.SegmentLength`)."""
    t = str(text).strip().lower()
    if t in ("auto", "none"):
        return None if t == "none" else "auto"
    return float(t)


def settings_of(args, options: dict | None = None) -> "CompensateSettings":
    """The options of ``compensate`` as its workflow's
    :class:`~compensation.app.workflows.compensate.CompensateSettings` (``options``: their :func:`option_values`)."""
    from ..workflows.compensate import CompensateSettings  # the G-code reader's kernels load to run, not to parse
    return CompensateSettings(**(option_values(args) if options is None else options))


def option_values(args) -> dict:
    """The fields of ``CompensateSettings`` from the options: ``--allow`` parsed, the files they name (work offsets,
    tool table, subprogram folders) read and checked; nothing of the solver loads."""
    return dict(method=args.method, model=args.model, out_dir=Path(args.out), force=args.force,
                allow=parse_allow(args.allow), rapids=args.rapids, block_delete=args.block_delete,
                arc_tolerance_um=args.arc_tolerance_um, units=args.units, truth=args.truth,
                seed=args.seed, show=args.show, rotary_limit_deg=args.max_rotary_correction_deg,
                conditions=conditions_from_args(args), tracking_uri=args.tracking_uri,
                dialect=args.dialect,
                work_offsets=read_work_offsets(args.work_offsets) if args.work_offsets is not None else None,
                tool_table=read_tool_table(args.tool_table) if args.tool_table else None,
                lathe_x=args.lathe_x,
                subprograms=SubprogramFiles(args.subprograms) if args.subprograms else None,
                cycles="expand" if args.expand_cycles else "keep",
                orientation=bool(args.compensate_orientation), chunk_points=args.chunk_points,
                max_segment_mm=parse_max_segment(args.max_segment_mm))


def on_executor(args, work):
    """``work(executor)`` on the executor ``--cluster``/``--workers`` name (this process's threads, or
    Ray); a cluster that cannot finish: one line and :data:`EXIT_CLUSTER` (nothing was written)."""
    settings = cluster_settings(args)
    try:
        with settings.executor() as executor:
            return work(executor)
    except ClusterError as exc:
        print(file=sys.stderr)  # end a progress line
        print(one_line(f"volcomp compensate: error: {exc}; nothing was written"), file=sys.stderr)
        return EXIT_CLUSTER


def run(args) -> int:
    machine = load_machine(args.machine)  # read once; what it is (content) picks the path
    family = family_of(machine)
    target = family.target("compensate")   # a parallel machine: the registry names interpolate
    family.refuse_unsupported("compensate", args)
    say_read_as(machine)
    if target == "arm":
        from ..workflows.arm_compensate import arm_settings_of, run_arm_compensate
        return run_arm_compensate(machine, args.files, arm_settings_of(args.method, args.model, args.out, args.allow,
                                                                       args.force))
    if args.method is None:
        raise UsageError("the following arguments are required: --method")
    options = option_values(args)   # the files the options name, read (and where the work runs, checked) ...
    cluster_settings(args)
    try:   # ... then a model that is not there: refused before the solver's kernels load (seconds) ...
        resolve_model(args.model)
    except InputError:   # ... after what the work refuses before the model: the inputs and the output folder
        plan_outputs(args.files, Path(args.out))
        check_out_dir(Path(args.out), args.force)
        raise
    from ..workflows.compensate import compensate_files, print_refusals
    settings = settings_of(args, options)
    run_ = on_executor(args, lambda ex: compensate_files(args.files, machine, settings, executor=ex))
    if isinstance(run_, int):
        return run_
    print(f"wrote summary: {run_.summary_path}")
    if run_.refused:
        print_refusals(run_, args.show)
        return EXIT_REFUSED
    return 0
