"""``volcomp calibrate POSES --machine FILE --out DIR``: PKM kinematic calibration (pkm-calibration paper).

Identifies joint positions, leg zero lengths and leg scales (``--no-scales`` fixes the scales) with
Tikhonov-regularised Gauss-Newton (lambda by GCV by default), estimates the instrument frame and the
orientation weight, then runs the loop on leg residuals (terms the rigid model lacks, cross-validated),
fits the plain baseline (scipy least squares in leg space, no regularisation) and reports the *measured
residual* on held-out poses: nominal, volcomp, baseline. Never returns a model that loses to the
baseline on the held-out poses; ``success`` is false, with the reasons, when the held-out residual is
not better than before or far above the noise.
Writes ``DIR/calibration.json``, ``DIR/report.html`` (PNG plots embedded) and the PNGs.
"""
from __future__ import annotations

import base64
import sys
from pathlib import Path

import numpy as np

from errormap.io import InputError, atomic_write, write_json
from errormap.machine import load_machine
from errormap.pkm.calibration import PKMCalibrator, calibration_to_dict, read_poses
from errormap.pkm.checks import check_pose_set
from errormap.pkm.hexapod import KinematicsError
from errormap.pkm.pipeline import rms_um, validated_calibration



def register(subparsers):
    p = subparsers.add_parser("calibrate", help="identify a hexapod/tripod's kinematic parameters from measured poses")
    p.add_argument("poses", help="pose-measurement CSV (legs l1_mm.. or q1.., x_mm y_mm z_mm [+ rx_deg.. | qx qy qz qw])")
    p.add_argument("--machine", help="machine file (kind hexapod or tripod; default: the built-in hexapod)")
    p.add_argument("--out", required=True, help="output folder")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--check", help="separate pose CSV for the held-out residual")
    g.add_argument("--holdout", type=float, default=0.2, help="fraction of POSES held out (default 0.2)")
    p.add_argument("--noise-um", type=float, default=None, help="measurement noise per component (um); estimated if omitted")
    p.add_argument("--no-scales", action="store_true", help="keep the leg scales at the machine file's values "
                   "(default: identify them)")
    p.add_argument("--scales", action="store_true", help=argparse_suppress())
    p.add_argument("--no-loop", action="store_true", help="skip the loop on leg residuals")
    p.add_argument("--no-register", action="store_true", help="the instrument frame is the machine frame")
    p.add_argument("--lever-mm", type=float, default=None, help="weight of orientation residuals (mm per rad; "
                   "default: estimated from the data, position noise / orientation noise)")
    p.add_argument("--seed", type=int, default=0, help="seed of the hold-out split")
    p.add_argument("--lambda-rule", choices=PKMCalibrator.RULES, default="gcv",
                   help="choice of the Tikhonov lambda: GCV (default), Morozov's discrepancy principle (delta from "
                        "--noise-um or estimated by GCV), or the L-curve corner")
    p.add_argument("--compare-rules", action="store_true",
                   help="also fit with the other lambda rules and report their held-out residuals "
                        "(always done when --noise-um is omitted)")
    p.set_defaults(func=run)


def argparse_suppress():
    import argparse
    return argparse.SUPPRESS


def _save(fig, path: Path) -> None:
    """Save a figure as PNG atomically."""
    import io
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


def _plots(result, before, after, out: Path) -> list[Path]:
    from ..reports.figures import pyplot
    plt = pyplot()
    paths = []
    fig, ax = plt.subplots(figsize=(6, 3.5))
    s = result.singular_values
    if result.singular_values_raw is not None:
        sr = result.singular_values_raw
        ax.semilogy(np.arange(1, sr.size + 1), np.maximum(sr, 1e-18), "x", ms=4, color="0.5",
                    label=f"raw (all directions), cond {result.condition_number_raw:.3g}")
    ax.semilogy(np.arange(1, s.size + 1), np.maximum(s, 1e-18), "o-", ms=3,
                label=f"identifiable subspace, cond {result.condition_number:.3g}")
    if result.lam > 0:
        ax.axhline(np.sqrt(result.lam), color="r", ls="--", label=f"sqrt(lambda) ({result.lambda_rule})")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled J)")
    ax.set_title(f"condition number {result.condition_number:.3g} (raw {result.condition_number_raw:.3g})")
    ax.legend()
    fig.tight_layout()
    paths.append(out / "singular_values.png")
    _save(fig, paths[-1])
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(before, "o", ms=3, label=f"nominal (RMS {np.sqrt(np.mean(before ** 2)):.1f} um)")
    ax.plot(after, "o", ms=3, label=f"calibrated (RMS {np.sqrt(np.mean(after ** 2)):.1f} um)")
    ax.set_yscale("log")
    ax.set_xlabel("held-out pose")
    ax.set_ylabel("measured residual |dp| (um)")
    ax.legend()
    fig.tight_layout()
    paths.append(out / "heldout_residual.png")
    _save(fig, paths[-1])
    plt.close(fig)
    c = result.lcurve
    if "residual_norm" in c:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.loglog(c["residual_norm"], c["solution_norm"], "-")
        for lam, lab, col in ((result.lambda_lcurve, "L-curve corner", "g"), (result.lambda_gcv, "GCV", "b"),
                              (result.lambda_morozov, "Morozov", "r")):
            if np.isfinite(lam) and lam > 0:
                i = int(np.argmin(np.abs(np.log(c["lambda"]) - np.log(lam))))
                ax.plot(c["residual_norm"][i], c["solution_norm"][i], "o", color=col, label=f"{lab} {lam:.3g}")
        ax.legend(fontsize=8)
        ax.set_xlabel("|J w - b| (mm)")
        ax.set_ylabel("|w| (scaled)")
        ax.set_title("L-curve of the final linearisation")
        fig.tight_layout()
        paths.append(out / "lcurve.png")
        _save(fig, paths[-1])
        plt.close(fig)
    return paths


def _html(doc: dict, pngs: list[Path], out: Path) -> Path:
    rows = "".join(f"<tr><td>{k}</td><td>{v['value']:.6f}</td><td>{v['delta']:+.4f}</td><td>{v['std_error']:.2g}</td></tr>"
                   for k, v in doc["parameters"].items())
    imgs = "".join(f'<p><img src="data:image/png;base64,{base64.b64encode(p.read_bytes()).decode()}"></p>' for p in pngs)
    summary = (f"<p>Measured residual (measurement minus model) on {doc['n_check_poses']} held-out poses: "
               f"RMS {doc['rms_before_um']:.2f} &rarr; {doc['rms_after_um']:.2f} um, max {doc['max_before_um']:.2f} "
               f"&rarr; {doc['max_after_um']:.2f} um. Fit poses: {doc['n_fit_poses']}. lambda ({doc['lambda_rule']}) "
               f"{doc['lambda']:.3g}, GCV {doc['lambda_gcv']:.3g}, L-curve {doc['lambda_lcurve']:.3g}; delta "
               f"{doc['delta_um']:.3g} um ({'estimated' if doc['delta_estimated'] else 'given'}); condition number "
               f"{doc['condition_number']:.3g} on the identifiable subspace (raw, gauge directions included: "
               f"{doc['condition_number_raw'] if doc['condition_number_raw'] is not None else float('inf'):.3g}); "
               f"{len(doc['unidentifiable'])} unidentifiable combinations ({doc['n_gauge']} fixed by the gauge).</p>")
    summary += (f"<p><b>success: {str(doc['success']).lower()}</b>"
                + "".join(f"<br>reason: {r}" for r in doc["success_reasons"])
                + "".join(f"<br>note: {n}" for n in doc["notes"]) + "</p>")
    summary += ("<h2>Held-out poses: nominal, volcomp, plain baseline</h2><table border=1><tr><th>model</th>"
                "<th>RMS / max um</th></tr>"
                f"<tr><td>nominal</td><td>{doc['rms_before_um']:.2f} / {doc['max_before_um']:.2f}</td></tr>"
                f"<tr><td>volcomp rigid</td><td>{doc['volcomp']['rigid_rms_um']:.2f}</td></tr>"
                f"<tr><td>volcomp (returned model candidate)</td><td>{doc['volcomp']['rms_um']:.2f} / "
                f"{doc['volcomp']['max_um']:.2f}</td></tr>"
                f"<tr><td>{doc['baseline']['what']}</td><td>{doc['baseline']['rms_um']:.2f} / "
                f"{doc['baseline']['max_um']:.2f}</td></tr></table><p>returned: {doc['returned_model']}</p>")
    loop = doc.get("loop", {})
    if loop.get("run"):
        summary += ("<h2>Loop on leg residuals</h2><table border=1><tr><th>round</th><th>term</th><th>leg</th>"
                    "<th>CV RSS before / after mm^2</th><th>gain</th><th>F</th><th>p</th><th>accepted</th></tr>"
                    + "".join(f"<tr><td>{r['round']}</td><td>{r['family']}</td><td>{r['leg']}</td>"
                              f"<td>{r['cv_rss_before_mm2']:.4g} / {r['cv_rss_after_mm2']:.4g}</td>"
                              f"<td>{r['cv_gain']:.1%}</td><td>{r['F']:.3g}</td><td>{r['p_value']:.2g}</td>"
                              f"<td>{r['passes']}</td></tr>" for rows in loop["rounds"] for r in rows)
                    + "</table>")
    if "lambda_comparison" in doc:
        summary += ("<h2>Choice of lambda</h2><table border=1><tr><th>rule</th><th>lambda</th><th>delta um</th>"
                    "<th>held-out RMS / max um</th></tr>" + "".join(
                        f"<tr><td>{r['rule']}</td><td>{r['lambda']:.3g}</td><td>{r['delta_um']:.3g}</td>"
                        f"<td>{r['heldout_rms_um']:.2f} / {r['heldout_max_um']:.2f}</td></tr>"
                        for r in doc["lambda_comparison"]["rules"]) + "</table>")
    html = (f"<!doctype html><html><head><meta charset='utf-8'><title>PKM calibration</title></head><body>"
            f"<h1>PKM calibration: {doc['machine']['name']}</h1>{summary}{imgs}"
            f"<h2>Parameters</h2><table border=1><tr><th>name</th><th>value</th><th>delta</th><th>std error</th></tr>"
            f"{rows}</table></body></html>")
    with atomic_write(out / "report.html", "w", encoding="utf-8") as fh:
        fh.write(html)
    return out / "report.html"


def _compare_rules(machine, args, fit, check, res, after) -> dict:
    """Fit with each lambda rule; chosen lambda, delta, fit and held-out measured residual per rule."""
    rows = []
    for rule in PKMCalibrator.RULES:
        if rule == args.lambda_rule:
            r, e = res, after
        else:
            r = PKMCalibrator(machine, estimate_scales=not args.no_scales, register=not args.no_register,
                              noise_um=args.noise_um, lever_mm=res.lever_mm, lambda_rule=rule).fit(fit)
            e = r.pose_errors_um(check)
        pos = e["position_um"]
        rows.append({"rule": rule, "lambda": r.lam, "delta_um": r.delta_mm * 1e3,
                     "delta_estimated": r.delta_estimated, "success": r.success,
                     "fit_rms_um": float(1e3 * np.sqrt(np.mean(np.sum(r.residuals[:, :3] ** 2, axis=1)))),
                     "heldout_rms_um": float(np.sqrt(np.mean(pos ** 2))), "heldout_max_um": float(pos.max())})
        print(f"calibrate: lambda rule {rule}: lambda {r.lam:.3g}, held-out RMS {rows[-1]['heldout_rms_um']:.2f} um",
              file=sys.stderr)
    return {"residual_kind": "measured residual (measurement minus model) on the held-out poses, position norm; "
                             "fit_rms_um on the fit poses",
            "delta": "morozov uses --noise-um when given, else delta estimated from the GCV fit "
                     "(delta^2 = RSS / (m - trace H))",
            "rules": rows}


def run(args) -> int:
    from compensation.app.cli import UsageError
    machine = load_machine(args.machine, expect_kind=None) if args.machine else load_machine(expect_kind="hexapod")
    if machine.kind not in ("hexapod", "tripod"):
        raise UsageError(f"{machine.path}: calibrate needs a hexapod or tripod machine file, got kind {machine.kind!r}")
    if args.scales and args.no_scales:
        raise UsageError("--scales and --no-scales contradict each other (scales are identified by default)")
    data = read_poses(args.poses, machine)
    k = machine.n_legs
    d = 6 if (machine.kind == "hexapod" and data.rotation is not None) else 3
    check_pose_set(data.source, machine, data.q, (8 if not args.no_scales else 7) * k + 6 * (not args.no_register), d)
    if args.check:
        fit, check = data, read_poses(args.check, machine)
    else:
        if not 0 < args.holdout < 1:
            raise UsageError(f"--holdout must be in (0, 1), got {args.holdout}")
        idx = np.random.default_rng(args.seed).permutation(len(data))
        n_check = max(1, int(round(args.holdout * len(data))))
        check, fit = data.subset(idx[:n_check]), data.subset(idx[n_check:])
    print(f"calibrate: {len(fit)} fit poses, {len(check)} held-out poses, machine {machine.name}", file=sys.stderr)
    scales = not args.no_scales
    try:
        v = validated_calibration(machine, fit, check, scales=scales, register=not args.no_register,
                                  noise_um=args.noise_um, lever_mm=args.lever_mm, lambda_rule=args.lambda_rule,
                                  loop=not args.no_loop, progress=lambda msg: print(f"calibrate: {msg}", file=sys.stderr))
        if v.loop.get("run"):
            print(f"calibrate: loop on leg residuals: {len(v.loop['accepted_terms'])} term(s) accepted"
                  + "".join(f"; {t['family']} leg {t['leg']}" for t in v.loop["accepted_terms"])
                  + ("" if v.loop.get("kept", True) else " (rejected on the held-out poses)"), file=sys.stderr)
        comparison = (_compare_rules(machine, args, fit, check, v.rigid, v.rigid_e)
                      if args.compare_rules or args.noise_um is None else None)
    except KinematicsError as exc:
        raise InputError(f"{args.poses}: {exc}") from None
    except ValueError as exc:
        raise InputError(str(exc)) from None
    res, base, before, after = v.result, v.baseline, v.before, v.after
    b_rms, b_max = rms_um(before)
    a_rms, a_max = rms_um(after)
    p_rms, p_max = rms_um(v.baseline_e)
    returned, notes, reasons, success, loop_doc = v.returned, v.notes, v.reasons, v.success, v.loop
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    doc = calibration_to_dict(res)
    if returned != "volcomp":
        doc["identified_machine"] = {"base_joints_mm": base.machine.base_joints_mm,
                                     "platform_joints_mm": base.machine.platform_joints_mm,
                                     "leg_offset_mm": base.machine.leg_offset_mm, "leg_scale": base.machine.leg_scale,
                                     "tool_in_platform_mm": base.machine.tool_in_platform_mm}
        from scipy.spatial.transform import Rotation
        rot = Rotation.from_matrix(base.frame_rotation)
        doc["frame"].update({"translation_mm": base.frame_translation_mm, "rotation_qx_qy_qz_qw": rot.as_quat(),
                             "rotation_deg_fixed_xyz": rot.as_euler("xyz", degrees=True)})
        doc["leg_terms"] = []
    else:
        doc["leg_terms"] = res.leg_terms.to_list() if res.leg_terms else []
    doc.update({"residual_kind": "measured residual (measurement minus model) on held-out poses, position norm",
                "rms_before_um": b_rms, "rms_after_um": min(a_rms, p_rms) if returned != "volcomp" else a_rms,
                "max_before_um": b_max, "max_after_um": p_max if returned != "volcomp" else a_max,
                "n_check_poses": len(check), "poses_file": str(args.poses), "check_file": args.check,
                "scales_estimated": scales, "lever_mm": res.lever_mm, "lever_estimated": res.lever_estimated,
                "returned_model": returned,
                "volcomp": {"rms_um": a_rms, "max_um": a_max, "rigid_rms_um": rms_um(v.rigid_e)[0]},
                "baseline": {"what": f"plain least squares in {base.objective} space (scipy least_squares, LM, no "
                                     "regularisation) of the same parameters and the frame",
                             "objective": base.objective, "rms_um": p_rms, "max_um": p_max,
                             "fit_rms_mm": base.fit_rms_mm, "converged": base.success},
                "loop": loop_doc, "noise": v.noise_source, "success": success, "success_reasons": reasons, "notes": notes,
                "message": res.message if success else "; ".join(reasons)})
    if "angle_urad" in after:
        doc.update({"rms_angle_before_urad": float(np.sqrt(np.mean(before["angle_urad"] ** 2))),
                    "rms_angle_after_urad": float(np.sqrt(np.mean(after["angle_urad"] ** 2)))})
    if comparison is not None:
        doc["lambda_comparison"] = comparison
    write_json(out / "calibration.json", doc)
    pngs = _plots(res, before["position_um"], after["position_um"], out)
    _html(doc, pngs, out)
    print(f"calibrate: held-out RMS {b_rms:.2f} -> {doc['rms_after_um']:.2f} um (max {b_max:.2f} -> "
          f"{doc['max_after_um']:.2f} um); volcomp {a_rms:.2f} um, plain baseline {p_rms:.2f} um; returned: {returned}")
    for n in notes:
        print(f"calibrate: note: {n}")
    if not success:
        print("calibrate: success: false: " + "; ".join(reasons))
    print(f"calibrate: wrote {out / 'calibration.json'}, {out / 'report.html'} and {len(pngs)} PNGs")
    return 0 if success else 1
