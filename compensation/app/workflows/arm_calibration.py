"""Arm (serial-chain) calibration (``volcomp calibrate POSES --machine ur5``): stages, validation, document.

The poses are split into fit and held-out poses (``--check`` file, else a hold-out fraction); on the
fit poses: the nominal chain, the plain baselines (nominal + fitted base/tool; plain least-squares
calibration; a plain GP on the plain calibration's residual), volcomp's geometric stage
(:class:`errormap.arm_calibration.ArmCalibrator`) and the learned residual stage
(:class:`training.arm_residual.ArmResidualRegressor`). Every figure is the *measured residual*
(measured − model) on the held-out poses. The kept stage: geometric, or volcomp's plain-LSQ
fallback if the plain calibration did better on the held-out poses (never return a model that loses
to the plain baseline), and the learned stage on top only if it beats the geometric stage there.
Writes ``calibration.json`` and ``report.html`` (:mod:`compensation.app.reports.arm_calibration`).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.arm_calibration import (ArmCalibrator, GeometricResult, check_pose_set, fit_base_tool,
                                      fit_plain_lsq)
from errormap.arm_poses import read_arm_poses
from errormap.io import InputError, write_json

from ..reports.arm_calibration import write_report
from .calibration import holdout_split

MODEL_FORMAT = "volcomp-arm-calibration/1"


@dataclass
class ArmCalibrationSettings:
    """``check``: held-out pose file (else ``holdout`` of the poses by ``seed``); ``learned``: run the
    learned stage; ``k_folds``/``n_restarts``: its CV folds and marginal-likelihood restarts."""

    poses: str
    check: str | None = None
    holdout: float = 0.2
    seed: int = 0
    learned: bool = True
    k_folds: int = 5
    n_restarts: int = 1


def errors_mm(poses, pred) -> np.ndarray:
    """Position error norm per pose, mm, shape (n,)."""
    return np.linalg.norm(poses.xyz_mm - pred, axis=1)


def stage_row(name, e, what) -> dict:
    return {"name": name, "mean_mm": float(e.mean()), "rms_mm": float(np.sqrt(np.mean(e ** 2))),
            "max_mm": float(e.max()), "what": what}


def split(chain, s: ArmCalibrationSettings, data):
    if s.check:
        return data, read_arm_poses(s.check, chain)
    return holdout_split(data, s.holdout, s.seed)


def calibrate_arm(chain, fit, check, learned=True, k_folds=5, n_restarts=1, seed=0, log=None, families=None) -> dict:
    """Every stage and baseline on ``fit``, judged on ``check``. Returns the document's core:
    ``stages``, ``baselines``, ``kept_stage``, the models (geometric result, learner or None)."""
    from training.arm_residual import ArmResidualRegressor
    say = (lambda m: print(f"calibrate: {m}", file=log or sys.stderr))
    nominal = errors_mm(check, chain.tool_point(check.q))
    base_tool = fit_base_tool(chain, fit)
    plain = fit_plain_lsq(chain, fit)
    geo = ArmCalibrator(chain).fit(fit).result_
    e_bt, e_plain, e_geo = (errors_mm(check, m.predict(check.q)) for m in (base_tool, plain, geo))
    say(f"held-out mean error: nominal {nominal.mean():.4f} mm, base/tool {e_bt.mean():.4f}, plain LSQ "
        f"{e_plain.mean():.4f}, geometric {e_geo.mean():.4f}")
    geo_kept = geo
    notes = []
    if e_plain.mean() < e_geo.mean():
        geo_kept, e_geo_kept = plain, e_plain
        notes.append(f"the plain least-squares calibration beat volcomp's geometric stage on the held-out poses "
                     f"({e_plain.mean():.6f} vs {e_geo.mean():.6f} mm mean): it is the geometric stage returned")
    else:
        e_geo_kept = e_geo
    stages = [stage_row("nominal", nominal, "nominal chain of the machine file"),
              stage_row("geometric", e_geo_kept, f"{geo_kept.method}: LM on the identifiable error slots")]
    baselines = [stage_row("nominal + base/tool", e_bt, "nominal chain, fitted base frame and tool point"),
                 stage_row("plain geometric LSQ", e_plain, "scipy least_squares, every DH slot + base + tool, "
                                                           "no identifiability handling"),
                 stage_row("volcomp geometric", e_geo, "LM on the identifiable slots (unidentifiable fixed)")]
    learner, plain_gp, kept, why = None, None, "geometric", "learned stage not run (--no-learned)"
    coverage_check = None
    if learned:
        rng_seeds = np.random.SeedSequence(seed).spawn(2)
        plain_gp = ArmResidualRegressor(chain, families=("gp_sincos",), k_folds=k_folds, n_restarts=n_restarts,
                                        seed=rng_seeds[0]).fit(fit.q, fit.xyz_mm - plain.predict(fit.q),
                                                               errors=plain.params)
        e_pgp = errors_mm(check, plain.predict(check.q) + plain_gp.predict(check.q))
        baselines.append(stage_row("plain GP on plain LSQ residual", e_pgp,
                                   "Gaussian process (ARD RBF) on joint sin/cos, fitted to the plain calibration's residual"))
        fam = {} if families is None else {"families": tuple(families)}
        learner = ArmResidualRegressor(chain, k_folds=k_folds, n_restarts=n_restarts, seed=rng_seeds[1], **fam).fit(
            fit.q, fit.xyz_mm - geo_kept.predict(fit.q), errors=geo_kept.params)
        m, sd = learner.predict(check.q, return_std=True)
        r = check.xyz_mm - geo_kept.predict(check.q) - m
        e_l = np.linalg.norm(r, axis=1)
        coverage_check = float(np.mean(np.abs(r) <= 1.959963984540054 * sd))
        stages.append(stage_row("learned", e_l, f"geometric + {learner.chosen_} on its residual (chosen by "
                                                f"{learner.k_folds}-fold CV in the fit set)"))
        say(f"learned stage ({learner.chosen_}): held-out mean {e_l.mean():.4f} mm; plain GP {e_pgp.mean():.4f} mm")
        if e_l.mean() < e_geo_kept.mean():
            kept, why = "learned", (f"the learned stage beat the geometric stage on the held-out poses "
                                    f"({e_l.mean():.4f} vs {e_geo_kept.mean():.4f} mm mean)")
        else:
            why = (f"the learned stage did not beat the geometric stage on the held-out poses "
                   f"({e_l.mean():.4f} vs {e_geo_kept.mean():.4f} mm mean): not kept")
    else:
        why = "learned stage not run"
    return {"stages": stages, "baselines": baselines, "kept_stage": kept, "kept_why": why, "notes": notes,
            "geometric_model": geo_kept, "volcomp_geometric": geo, "learner": learner,
            "base_tool_model": base_tool, "plain_model": plain, "plain_gp": plain_gp,
            "coverage95_heldout": coverage_check}


def model_document(chain, core, s, n_fit, n_check) -> dict:
    geo: GeometricResult = core["geometric_model"]
    learner = core["learner"]
    doc = {"format": MODEL_FORMAT, "machine": {"name": chain.name, "kind": chain.kind, "path": chain.path,
                                               "sha256": chain.sha256, "joints": chain.joint_columns},
           "residual_kind": "measured residual (measured − model) on the held-out poses, position norm, mm",
           "poses_file": str(s.poses), "check_file": s.check, "n_fit_poses": n_fit, "n_check_poses": n_check,
           "holdout": None if s.check else {"fraction": s.holdout, "seed": s.seed, "split": "random"},
           "stages": core["stages"], "baselines": core["baselines"], "kept_stage": core["kept_stage"],
           "kept_why": core["kept_why"], "notes": core["notes"],
           "geometric": geo.to_dict(), "learned": None}
    if learner is not None:
        doc["learned"] = learner.to_dict() if core["kept_stage"] == "learned" else None
        doc["learned_summary"] = {"chosen": learner.chosen_, "cv_table": learner.cv_table_,
                                  "coverage95_cv": learner.coverage_,
                                  "coverage95_heldout": core["coverage95_heldout"], "kept": core["kept_stage"] == "learned"}
    return doc


def load_arm_model(chain, path):
    """(GeometricResult, learner or None) of a ``calibration.json`` written for ``chain``."""
    import json
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable calibration.json ({exc})") from None
    if not isinstance(d, dict) or d.get("format") != MODEL_FORMAT:
        raise InputError(f"{path}: key 'format': expected {MODEL_FORMAT!r} (an arm calibration.json)")
    if d["machine"]["name"] != chain.name or d["machine"]["joints"] != chain.joint_columns:
        raise InputError(f"{path}: key 'machine': calibrated for {d['machine']['name']!r}, not {chain.name!r}")
    geo = GeometricResult.from_dict(chain, d["geometric"])
    learner = None
    if d.get("kept_stage") == "learned" and d.get("learned"):
        from training.arm_residual import ArmResidualRegressor
        learner = ArmResidualRegressor.from_dict(chain, d["learned"])
    return geo, learner


def run_arm_calibration(chain, s: ArmCalibrationSettings, out, log=None) -> dict:
    """Calibrate ``chain`` from ``s.poses``; write ``out/calibration.json`` and ``out/report.html``."""
    log = sys.stderr if log is None else log
    data = read_arm_poses(s.poses, chain)
    check_pose_set(chain, data)
    fit, check = split(chain, s, data)
    check_pose_set(chain, fit)
    print(f"calibrate: {len(fit)} fit poses, {len(check)} held-out poses, machine {chain.name}", file=log)
    core = calibrate_arm(chain, fit, check, learned=s.learned, k_folds=s.k_folds, n_restarts=s.n_restarts,
                         seed=s.seed, log=log)
    doc = model_document(chain, core, s, len(fit), len(check))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "calibration.json", doc)
    write_report(doc, chain, core, check, out)
    return doc
