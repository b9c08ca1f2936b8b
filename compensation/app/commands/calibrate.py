"""``volcomp calibrate POSES --machine FILE --out DIR``: PKM kinematic calibration (pkm-calibration paper).

Identifies joint positions, leg zero lengths and leg scales (``--no-scales`` fixes the scales) with
Tikhonov-regularised Gauss-Newton (lambda by GCV by default), estimates the instrument frame and the
orientation weight, then runs the loop on leg residuals (terms the rigid model lacks, cross-validated),
fits the plain baseline (scipy least squares in leg space, no regularisation) and reports the *measured
residual* on held-out poses: nominal, volcomp, baseline. Never returns a model that loses to the
baseline on the held-out poses; ``success`` is false, with the reasons, when the held-out residual is
not better than before or far above the noise.
Writes ``DIR/model.json``, ``DIR/report.html`` (PNG plots embedded) and the PNGs
(:mod:`compensation.app.workflows.calibration`).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from errormap.machine import MachineFileError, builtin_machine_path, load_machine
from errormap.pkm.calibration_file import LAMBDA_RULES

from compensation.app.validate import UsageError

from ..families import family_of


def register(subparsers):
    p = subparsers.add_parser("calibrate", add_help=False, help="identify a parallel machine's (hexapod/tripod) or a "
                              "serial arm's kinematic parameters from measured poses")
    p.add_argument("-h", "--help", action=KindHelp, help="show this help and exit (after --machine M: only the "
                   "options that apply to M's kind)")
    # a serial chain (``kind = "serial"``, e.g. --machine ur5) goes to the arm calibration
    # (compensation/app/workflows/arm_calibration.py; docs/explanation/serial-arms.md)
    p.add_argument("poses", help="pose-measurement CSV (legs l1_mm.. or q1.., x_mm y_mm z_mm [+ rx_deg.. | qx qy qz qw])")
    p.add_argument("--machine", help="machine file or built-in name (kind hexapod, tripod or serial, e.g. ur5; "
                   "default: the built-in hexapod)")
    p.add_argument("--out", required=True, help="output folder")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--check", help="separate pose CSV for the held-out residual")
    g.add_argument("--holdout", type=float, default=0.2, help="fraction of POSES held out (default 0.2)")
    p.add_argument("--seed", type=int, default=0, help="seed of the hold-out split")
    p.add_argument("--noise-um", type=float, default=None, help="measurement noise per component (um); hexapod / "
                   "tripod: estimated if omitted; serial arm: the tracker's stated σ the verdict judges the held-out "
                   "residual against (default: the poses' sigma_mm column, else not judged)")
    pkm = p.add_argument_group("hexapod / tripod only (refused for a serial arm)")
    pkm.kinds = ("hexapod", "tripod")
    pkm.add_argument("--no-scales", action="store_true", help="keep the leg scales at the machine file's values "
                     "(default: identify them)")
    pkm.add_argument("--scales", action="store_true", help=argparse.SUPPRESS)
    pkm.add_argument("--no-loop", action="store_true", help="skip the loop on leg residuals")
    pkm.add_argument("--no-register", action="store_true", help="the instrument frame is the machine frame")
    pkm.add_argument("--lever-mm", type=float, default=None, help="weight of orientation residuals (mm per rad; "
                     "default: estimated from the data, position noise / orientation noise)")
    pkm.add_argument("--lambda-rule", choices=LAMBDA_RULES, default=None,
                     help="choice of the Tikhonov lambda: GCV (default), Morozov's discrepancy principle (delta from "
                          "--noise-um or estimated by GCV), or the L-curve corner")
    pkm.add_argument("--compare-rules", action="store_true",
                     help="also fit with the other lambda rules and report their held-out residuals "
                          "(always done when --noise-um is omitted)")
    arm = p.add_argument_group("serial arm only (refused for a hexapod / tripod)")
    arm.kinds = ("serial",)
    arm.add_argument("--no-learned", action="store_true", help="skip the learned residual stage")
    arm.add_argument("--folds", type=int, default=None, help="CV folds of every decision inside the fit poses: slot "
                     "set, learned stage (default 5)")
    p.set_defaults(func=run)


class KindHelp(argparse.Action):
    """``-h``/``--help``: with ``--machine M`` given before it, the option groups that do not apply to M's kind (their
    ``kinds``) are left out of the help; without it (or with an unreadable M) every group is shown."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        kind = None
        if getattr(namespace, "machine", None):
            try:
                kind = load_machine(namespace.machine, expect_kind=None).kind
            except (MachineFileError, OSError, ValueError):
                kind = None
        for g in parser._action_groups:
            if kind is not None and kind not in getattr(g, "kinds", (kind,)):
                for a in g._group_actions:
                    a.help = argparse.SUPPRESS
        parser.print_help()
        parser.exit()


DEFAULT_MACHINE = "hexapod"
"""The built-in machine calibrated without ``--machine``."""


def run(args) -> int:
    machine = load_machine(args.machine or builtin_machine_path(DEFAULT_MACHINE))
    family = family_of(machine)
    family.refuse_unsupported("calibrate", args)   # the other family's options: refused by name
    return RUNNERS[family.target("calibrate")](machine, args)


def run_parallel(machine, args) -> int:
    """The parallel branch: leg lengths, joints, scales (Tikhonov), the loop on leg residuals, the plain
    baseline beside them."""
    if args.scales and args.no_scales:
        raise UsageError("--scales and --no-scales contradict each other (scales are identified by default)")
    from ..workflows.calibration import CalibrationSettings, run_calibration  # the solver and figures: to run
    settings = CalibrationSettings(
        poses=args.poses, check=args.check, holdout=args.holdout, noise_um=args.noise_um, scales=not args.no_scales,
        register=not args.no_register, loop=not args.no_loop, lever_mm=args.lever_mm, seed=args.seed,
        lambda_rule=args.lambda_rule or "gcv", compare_rules=args.compare_rules)
    out = Path(args.out)
    cal = run_calibration(machine, settings, out)
    doc, (b_rms, b_max), (a_rms, _), (p_rms, _) = cal.doc, cal.before_um, cal.volcomp_um, cal.baseline_um
    print(f"calibrate: held-out RMS {b_rms:.2f} -> {doc['rms_after_um']:.2f} um (max {b_max:.2f} -> "
          f"{doc['max_after_um']:.2f} um); volcomp {a_rms:.2f} um, plain baseline {p_rms:.2f} um; "
          f"returned: {doc['returned_model']}")
    for n in doc["notes"]:
        print(f"calibrate: note: {n}")
    if not cal.success:
        print("calibrate: success: false: " + "; ".join(doc["success_reasons"]))
    print(f"calibrate: wrote {out / 'model.json'}, {out / 'report.html'} and {len(cal.pngs)} PNGs")
    return 0 if cal.success else 1


def run_serial(chain, args) -> int:
    """The arm branch: geometric + learned stages, plain baselines beside them (docs/explanation/serial-arms.md)."""
    from ..workflows.arm_calibration import ArmCalibrationSettings
    from ..workflows.arm_run import run_arm_calibration
    s = ArmCalibrationSettings(poses=args.poses, check=args.check, holdout=args.holdout, seed=args.seed,
                               learned=not args.no_learned, k_folds=5 if args.folds is None else args.folds,
                               noise_um=args.noise_um)
    out = Path(args.out)
    doc = run_arm_calibration(chain, s, out)
    for r in doc["stages"] + doc["baselines"]:
        print(f"calibrate: held-out {r['name']}: mean {r['mean_mm']:.4f} mm, RMS {r['rms_mm']:.4f} mm, "
              f"max {r['max_mm']:.4f} mm")
    print(f"calibrate: kept stage: {doc['kept_stage']} ({doc['kept_why']})")
    for role, why in ((doc.get("across_sessions") or {}).get("why") or {}).items():
        print(f"calibrate: across sessions, {role}: {why}")
    v = doc["verdict"]
    print("calibrate: verdict: passed" if v["status"] == "passed" else "calibrate: verdict: FAILED: " + "; ".join(v["reasons"]))
    print(f"calibrate: wrote {out / 'model.json'} and {out / 'report.html'}")
    return 1 if v["status"] == "failed" else 0


RUNNERS = {"arm": run_serial, "parallel": run_parallel}
"""The runner of each target of ``calibrate`` (:meth:`compensation.app.families.Family.target`)."""
