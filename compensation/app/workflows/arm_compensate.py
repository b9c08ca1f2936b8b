"""``volcomp compensate PROGRAM.csv --machine ur5 --model DIR/model.json --out DIR``: arm joint commands.

Each input is a measured-pose-style CSV of the arm: the joint columns (``q1_deg …``: the joint program,
also Newton's starting point) and optionally target tool points ``x_mm, y_mm, z_mm`` in the ROBOT'S BASE FRAME;
without them the targets are the nominal chain's tool points at the programmed joints (the program's intent), in
that frame too. The calibration's base transform (instrument → robot base, :mod:`errormap.arm_frames`) turns them
into the frame the model was fitted in, so no tracker target is needed. The
output ``DIR/<same name>`` holds the compensated joint columns, the targets (base frame) and the MODEL residual
(``model_residual_mm``: target − calibrated model at the compensated joints); a point that did not
converge or leaves the joint limits fails the file (exit 3, nothing written for it).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errormap.arm_frames import from_base_frame, to_base_frame
from errormap.arm_poses import check_joint_values
from errormap.io import InputError, read_table, write_csv

from compensation.app.validate import UsageError

from ...arm_compensation import solve_joints
from ...fields import FAILED_VERDICT, check_verdict
from ...model_file import read_model

EXIT_REFUSED = 3


def joint_values(path, t, chain, columns=None) -> np.ndarray:
    """The joint values (n, nq) in columns ``columns`` (default: the chain's ``q1_deg …``) of table ``t`` read
    from ``path``, refused as radians or outside the joint limits (:func:`check_joint_values`)."""
    columns = list(chain.joint_columns if columns is None else columns)
    t.require(*columns)
    if len(t) == 0:   # a header alone: no joint values (an empty output would look like a result)
        raise InputError(f"{path}: no data rows under the header (columns {', '.join(columns)})")
    q = np.stack([t.float(c) for c in columns], 1)
    check_joint_values(path, q, [t.row_number(k) for k in range(len(t))], chain, columns)
    return q


def nominal_base_points(chain, q) -> np.ndarray:
    """The nominal chain's tool points (n, 3) at the joints ``q`` (n, nq), in the robot's base frame."""
    return to_base_frame(chain, None, chain.tool_point(q))


def read_program(path, chain, t=None):
    """(q (n, nq), targets (n, 3) or None) of a joint-program / target CSV (``t``: its table, already read)."""
    t = read_table(path) if t is None else t
    q = joint_values(path, t, chain)
    xyz = None
    if any(c in t for c in ("x_mm", "y_mm", "z_mm")):
        t.require("x_mm", "y_mm", "z_mm")
        xyz = np.stack([t.float(c) for c in ("x_mm", "y_mm", "z_mm")], 1)
    return q, xyz


def parse_arm_allow(text) -> tuple:
    """``--allow`` on a serial arm: only ``failed-verdict`` (use a calibration whose verdict failed); the machine-tool
    guards (ball, stroke, volume, convergence) have no counterpart here (a point that does not converge or leaves
    the joint limits always fails its file), so naming one, or a bare ``--allow``, is refused, never ignored."""
    if text is None:
        return ()
    names = tuple(t.strip() for t in str(text).split(",") if t.strip())
    other = [n for n in names if n != FAILED_VERDICT]
    if other or not names:
        raise UsageError(f"--allow {text}: a serial arm takes only --allow {FAILED_VERDICT}; its unconverged or "
                         "out-of-limit points are never written")
    return names


def overridden_verdict(verdict) -> list[str]:
    """The header line of a program compensated with a calibration whose verdict failed (``--allow failed-verdict``)."""
    if not verdict or not verdict.get("overridden_by"):
        return []
    return [f"MODEL VERDICT FAILED ({verdict['file']}), used with --allow {FAILED_VERDICT}: "
            + ("; ".join(verdict["reasons"]) or "no reasons recorded")]


@dataclass(frozen=True)
class ArmCompensateSettings:
    """How ``volcomp compensate`` runs on a serial arm: ``model`` (its ``model.json``, ``volcomp
    calibrate``), ``out_dir`` (each program written there under its own name), ``force`` (replace outputs that
    exist), ``allow_failed_verdict`` (use a calibration whose verdict failed; recorded in each output's header)."""
    model: str
    out_dir: Path
    force: bool = False
    allow_failed_verdict: bool = False


def arm_settings_of(method, model, out, allow, force) -> ArmCompensateSettings:
    """``compensate``'s options on an arm as :class:`ArmCompensateSettings` (``--method`` exact or none only)."""
    if method not in (None, "exact"):
        raise UsageError(f"--method {method}: a serial chain is compensated by Newton on its calibrated chain "
                         "(--method exact or none)")
    return ArmCompensateSettings(model=model, out_dir=Path(out), force=bool(force),
                                 allow_failed_verdict=FAILED_VERDICT in parse_arm_allow(allow))


def run_arm_compensate(chain, files, settings: ArmCompensateSettings) -> int:
    """``volcomp compensate`` of the joint programs ``files`` on a serial arm (the options it does not take were
    refused by the family registry, :mod:`compensation.app.families`) → exit status (3: a file refused)."""
    model = settings.model
    cal = read_model(model, chain, family="arm").calibration.require_base_frame(model)
    geo, learner = cal.geometric, cal.learner
    verdict = check_verdict(model, settings.allow_failed_verdict)   # a failed calibration: refused unless allowed
    out = Path(settings.out_dir)
    srcs = [Path(f) for f in files]
    for s in srcs:
        if (out / s.name).resolve() == s.resolve():
            raise UsageError(f"{s}: the output would overwrite the input; choose another --out")
    existing = [str(out / s.name) for s in srcs if (out / s.name).exists()]
    if existing and not settings.force:   # never clobbered silently
        raise UsageError(f"{existing[0]} exists{f' (and {len(existing) - 1} more)' if len(existing) > 1 else ''}; "
                         "give --force to replace or choose another --out")
    jobs = [(s, *read_program(s, chain)) for s in srcs]
    out.mkdir(parents=True, exist_ok=True)
    status = 0
    for src, q, xyz in jobs:
        target = nominal_base_points(chain, q) if xyz is None else xyz       # robot base frame
        sol = solve_joints(geo.chain, geo.params, learner, from_base_frame(chain, geo.params, target), q)
        if not sol.converged.all():
            k = int(np.flatnonzero(~sol.converged)[0])
            print(f"volcomp compensate: {src}: refused (not written): {int((~sol.converged).sum())} point(s) did not "
                  f"converge or leave the joint limits, first: point {k}, model residual {sol.residual_mm[k]:.3g} mm")
            status = EXIT_REFUSED
            continue
        cols = {c: sol.q[:, i] for i, c in enumerate(chain.joint_columns)}
        cols.update({"x_mm": target[:, 0], "y_mm": target[:, 1], "z_mm": target[:, 2],
                     "model_residual_mm": sol.residual_mm})
        write_csv(out / src.name, cols, header_comments=(
            *overridden_verdict(verdict), f"compensated for machine {chain.name} with {model}",
            "x_mm..z_mm: targets in the robot's base frame; residual: MODEL residual (target - calibrated model at the "
            "compensated joints)",
            f"tool orientation kept: {sol.orientation_kept}"), float_fmt="%.10g")
        print(f"{src}: {len(q)} points, model residual max {sol.residual_mm.max():.3g} mm, max joint change "
              f"{np.abs(sol.q - q).max():.4g} deg -> {out / src.name}")
    return status
