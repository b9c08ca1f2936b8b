"""``volcomp simulate --machine ur5 …``: a simulated serial arm and its tracker measurements.

A seeded truth (random link / base / tool errors, optionally a joint-stiffness sag under gravity and
joint backlash: :mod:`errormap.arm_simulate`) is measured by a tracker with Gaussian noise at random
joint vectors inside the machine's joint limits. The files are the ones a user has after measuring a
real arm, so everything after this step runs the user's path (``volcomp calibrate`` → ``volcomp
compensate``); the truth itself goes to ``truth.json`` for the judge only:

- ``poses.csv``: the fitting poses (measured-pose schema, ``docs/explanation/serial-arms.md``);
- ``checks.csv``: more measured poses, drawn apart from the fitting ones (``calibrate --check``);
- ``program.csv``: a joint program (joint columns only; its targets are the nominal chain's tool
  points, what ``compensate`` aims at), kept ``PROGRAM_MARGIN_DEG`` inside the joint limits;
- ``truth.json``: the hidden truth (every error slot by name, compliance, backlash, noise, seed).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from errormap.arm_poses import write_arm_poses
from errormap.arm_simulate import ArmTruth, draw_truth, measure, random_joints
from errormap.io import InputError, read_document_text, write_csv, write_json
from errormap.seeds import spawn_seeds

ARM_EFFECTS = ("sag", "backlash")
SAG_RAD_PER_MM = 3e-8       # joint compliance of the sag effect: ~0.1 mm of sag at a UR5's reach
BACKLASH_RAD = 2e-5         # lost motion per joint (4 arcsec): ±1e-5 rad by the gravity moment's sign
DEFAULT_ARM_NOISE_UM = 20.0  # a laser tracker's point noise at arm distances (σ per component)
PROGRAM_MARGIN_DEG = 5.0    # program joints this far inside the limits: room for the compensation to move
PROGRAM_POINTS = 100
PROGRAM_MAX_COND = 30.0     # program poses away from singular configurations: condition number of the nominal
# position + lever-scaled orientation Jacobian at most this (a UR5's well-conditioned workspace sits at 5–20; near
# the wrist / elbow singularities it grows without bound and the orientation-keeping Newton step stalls)
PROGRAM_DRAW_FACTOR = 50    # candidates drawn per program point before the condition filter


def check_arm_effects(effects) -> list[str]:
    """The ``--effect`` values of a serial machine, each at most once; anything else is refused."""
    bad = [e for e in effects if e not in ARM_EFFECTS]
    if bad:
        from compensation.app.validate import UsageError
        raise UsageError(f"--effect: unknown effect {bad[0]!r} for a serial arm (expected one of "
                         f"{', '.join(ARM_EFFECTS)})")
    return sorted(set(effects))


def simulate_serial(chain, seed: int, out, effects=(), noise_um: float = DEFAULT_ARM_NOISE_UM, poses: int = 200,
                    checks: int = 100, check_noise_seed=None) -> dict:
    """Write ``poses.csv``, ``checks.csv``, ``program.csv`` and ``truth.json`` under ``out`` for the
    seeded truth arm; returns the ``truth.json`` document. ``check_noise_seed``: None (default) the check
    poses' tracker noise from the seed's own stream; an int redraws only that noise (the same arm, fitting
    poses and check joints)."""
    from .simulate import check_noise_comments, check_noise_record
    effects = check_arm_effects(effects)
    s_truth, s_fit_q, s_fit_n, s_chk_q, s_chk_n, s_prog = spawn_seeds(seed, 6)
    if check_noise_seed is not None:
        s_chk_n = check_noise_seed
    nq = chain.n_joints
    truth = draw_truth(chain, s_truth,
                       compliance_rad_per_mm=np.full(nq, SAG_RAD_PER_MM if "sag" in effects else 0.0),
                       backlash_rad=np.full(nq, BACKLASH_RAD) if "backlash" in effects else None)
    lo, hi = chain.joint_lo, chain.joint_hi
    noise_mm = noise_um / 1000.0
    out = Path(out)
    fit = measure(chain, truth, random_joints(lo, hi, poses, s_fit_q), noise_mm, s_fit_n)
    chk = measure(chain, truth, random_joints(lo, hi, checks, s_chk_q), noise_mm, s_chk_n)
    head = [f"machine: {chain.name}", f"simulated seed={seed}", f"noise_um: {noise_um:g}",
            f"effects: {','.join(effects) or 'none'}"]
    write_arm_poses(out / "poses.csv", chain, fit, comments=head)
    write_arm_poses(out / "checks.csv", chain, chk, comments=head + check_noise_comments(check_noise_seed))
    margin = np.array([PROGRAM_MARGIN_DEG if j.type == "revolute" else 0.0 for j in chain.joints])
    qp = well_conditioned_joints(chain, lo + margin, hi - margin, PROGRAM_POINTS, s_prog)
    write_csv(out / "program.csv", {c: qp[:, i] for i, c in enumerate(chain.joint_columns)},
              header_comments=[f"machine: {chain.name}", "joint program: targets are the nominal tool points"],
              float_fmt="%.10g")
    reach = np.linalg.norm(truth.tool_point(chain, fit.q) - chain.tool_point(fit.q), axis=1)
    info = {"seed": seed, "machine": chain.name, "kind": chain.kind, "effects": effects, "noise_um": noise_um,
            **check_noise_record(check_noise_seed),
            "errors": dict(zip(chain.param_names, map(float, truth.errors))),
            "compliance_rad_per_mm": truth.compliance_rad_per_mm.tolist(),
            "backlash_rad": None if truth.backlash_rad is None else truth.backlash_rad.tolist(),
            "uncompensated_rms_mm": float(np.sqrt(np.mean(reach ** 2))),
            "files": {k: str(out / f"{k}.csv") for k in ("poses", "checks", "program")},
            "note": "the hidden truth: for judging only, never an input of calibrate/compensate"}
    write_json(out / "truth.json", info)
    return info


def well_conditioned_joints(chain, lo, hi, n: int, seed) -> np.ndarray:
    """``n`` joint vectors uniform in [lo, hi] whose nominal Jacobian (position, and orientation scaled by
    the compensation's lever where the chain has ≥ 6 joints) has condition number ≤ :data:`PROGRAM_MAX_COND`;
    shape (n, nq). Refuses (``InputError``) a box with too few such poses."""
    from compensation.arm_compensation import LEVER_MM
    q = random_joints(lo, hi, n * PROGRAM_DRAW_FACTOR, seed)
    orient = chain.n_joints >= 6
    J = chain.joint_jacobian(q, np.zeros(chain.n_params), orientation=orient)
    if orient:
        J = np.concatenate([J[:, :3], LEVER_MM * J[:, 3:]], 1)
    sv = np.linalg.svd(J, compute_uv=False)
    ok = sv[:, -1] * PROGRAM_MAX_COND >= sv[:, 0]
    if ok.sum() < n:
        raise InputError(f"{chain.name}: only {int(ok.sum())} of {len(q)} joint vectors inside the limits are "
                         f"well-conditioned (condition ≤ {PROGRAM_MAX_COND:g}); cannot draw a {n}-point program")
    return q[ok][:n]


def load_serial_truth(path, chain) -> ArmTruth:
    """The :class:`ArmTruth` of a ``truth.json`` written by :func:`simulate_serial` (the judge's side)."""
    try:
        doc = json.loads(read_document_text(path, "a JSON input"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable JSON truth file ({exc})") from None
    if doc.get("kind") != chain.kind or doc.get("machine") != chain.name:
        raise InputError(f"{path}: not a simulated truth of the serial machine {chain.name!r}")
    missing = [n for n in chain.param_names if n not in doc["errors"]]
    if missing:
        raise InputError(f"{path}: key 'errors': no value for slot {missing[0]!r}")
    e = np.array([doc["errors"][n] for n in chain.param_names])
    b = doc.get("backlash_rad")
    return ArmTruth(e, np.asarray(doc["compliance_rad_per_mm"], float), None if b is None else np.asarray(b, float))
