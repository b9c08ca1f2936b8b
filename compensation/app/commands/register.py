"""``volcomp register POSES --machine ur5 --model DIR/model.json --out DIR2``: re-register a calibrated arm's
base frame (and with ``--tool`` its tool point) in a new measurement session, keeping every link parameter and
learned stage, and keeps for the session whichever of the plain calibration, the geometric stage alone and the kept
stage did best in a CV inside the registration poses (:mod:`compensation.app.workflows.arm_register`; docs/explanation/serial-arms.md)."""
from __future__ import annotations

from pathlib import Path

from errormap.machine import load_machine

from ..families import family_of

from ...fields import FAILED_VERDICT


def register(subparsers):
    p = subparsers.add_parser("register", help="re-register a calibrated arm's base frame (and tool point) in a new "
                                               "measurement session from a few poses")
    p.add_argument("poses", help="the session's measured poses (arm pose CSV, as calibrate reads)")
    p.add_argument("--machine", required=True, help="the serial machine (file or built-in name, e.g. ur5)")
    p.add_argument("--model", required=True, help="model.json of the arm (volcomp calibrate)")
    p.add_argument("--out", required=True, help="output folder: the session's model.json")
    p.add_argument("--tool", action="store_true", help="also fit the tool point (default: the base frame only)")
    p.add_argument("--fit-poses", type=int, default=None, help="register on the first N poses (at least 6) and "
                   "report the held-out error on the rest (default: all poses register)")
    p.add_argument("--seed", type=int, default=0, help="seed of the candidate poses the frame's suggestions come from")
    p.add_argument("--allow", action="append", default=[], choices=(FAILED_VERDICT,),
                   help=f"{FAILED_VERDICT}: re-register a calibration whose verdict failed (refused by default); "
                        "recorded in the output's registration.allowed")
    p.set_defaults(func=run)


def run(args) -> int:
    chain = load_machine(args.machine)
    family_of(chain).target("register")   # an arm's base frame: refused on other families, naming their path
    from ..workflows.arm_register import run_arm_register
    r = run_arm_register(chain, args.poses, args.model, args.out, tool=args.tool, fit_poses=args.fit_poses,
                         seed=args.seed, allow_failed_verdict=FAILED_VERDICT in args.allow)
    for s in r["slots"]:
        print(f"register: {s['name']} = {s['value']:.6g} ± {s['std']:.2g}")
    print(f"register: fit RMS {r['fit_rms_mm']:.4f} mm on {r['n_fit_poses']} poses")
    best = r["poses_that_pin_it_best"]
    print(f"register: {len(best['q'])} poses that would pin the frame best (in model.json, "
          f"registration.poses_that_pin_it_best); with them the standard errors would be "
          + ", ".join(f"{s['name']} {v:.2g}" for s, v in zip(r["slots"], best["std_with_them"])))
    print(f"register: kept {r['kept']}" + (" (the plain fallback)" if r["kept_is_plain_fallback"] else "")
          + f": {r['kept_why']}")
    for name, row in (r["heldout_by_candidate"] or {}).items():
        print(f"register: held out, {name} registered: mean {row['mean_mm']:.4f} mm, RMS {row['rms_mm']:.4f} mm "
              f"on {row['n']} poses" + (" (kept)" if name == r["kept"] else ""))
    if r["heldout_as_calibrated"] is not None:
        h = r["heldout_as_calibrated"]
        print(f"register: held out, as calibrated (not registered): mean {h['mean_mm']:.4f} mm on {h['n']} poses")
    if r.get("learned_carried") is False and r["learned_why"]:
        print(f"register: the learned stage is not carried to this session: {r['learned_why']}")
    sess = r.get("across_sessions") or {}
    for role, ok in (sess.get("carried") or {}).items():
        if ok is False:
            print(f"register: the {role} stage is not weighed for this session: {sess['why'][role]}")
    if r.get("temperature_change_c") is not None:
        expanded = r["kept"].endswith(" + temperature")
        print(f"register: logged temperature {r['temperature_c']['mean']:.2f} °C, "
              f"{r['temperature_change_c']:+.2f} °C from the calibration's"
              + (" (kept: the link lengths expanded to it by the calibration's temperature term)" if expanded else
                 " (the link lengths are the calibration's: a change in temperature shows in the held-out error, "
                 "not in the frame)"))
    if r.get("allowed"):
        print(f"register: {r['allowed']}")
    print(f"register: wrote {Path(args.out) / 'model.json'}")
    return 0
