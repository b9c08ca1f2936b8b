"""``volcomp simulate --machine hexapod|tripod``: a simulated parallel machine and its measured poses.

The truth and the measurements are the benchmark's (:func:`errormap.pkm.simulate.simulate_poses`: leg
scale, zero-length and joint errors of a real platform, an unknown instrument frame, Gaussian noise), written
as the files a user has after measuring a real machine, so that everything after this step runs the user's
path (``volcomp calibrate poses.csv --machine M --check checks.csv``):

- ``poses.csv``: the fitting poses (pose-measurement schema, ``docs/explanation/parallel-kinematics.md``);
- ``checks.csv``: more poses of the same truth, drawn apart from the fitting ones (``calibrate --check``);
- ``truth.json``: the hidden truth (its parameters and the instrument frame), for the judge only.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.io import write_json
from errormap.seeds import spawn_seeds

from ..families import family_of

DEFAULT_PKM_NOISE_UM = 5.0
"""The instrument's noise σ per position component: the benchmark's base condition (``pkm_base_noise_um``)."""
DEFAULT_PKM_POSES = 100
"""Fitting poses: the benchmark's base condition (``pkm_base_poses``)."""


def simulate_pkm(machine, seed: int, out, noise_um: float = DEFAULT_PKM_NOISE_UM, poses: int = DEFAULT_PKM_POSES,
                 checks: int = 100, check_noise_seed=None) -> dict:
    """Write ``poses.csv``, ``checks.csv`` and ``truth.json`` under ``out`` for the seeded truth of ``machine``
    (a hexapod or tripod); returns the ``truth.json`` document. ``check_noise_seed``: None the check poses'
    noise from the seed's own stream; an int redraws only that noise (the same truth and check poses)."""
    from errormap.pkm.simulate import simulate_hexapod_poses, simulate_tripod_poses
    from .simulate import check_noise_comments, check_noise_record
    sim = simulate_hexapod_poses if family_of(machine).facts.platform_orientation else simulate_tripod_poses
    s_fit, s_chk = spawn_seeds(seed, 2)
    out = Path(out)
    fit = sim(machine, poses, noise_um, s_fit)
    chk = sim(machine, checks, noise_um, s_chk, truth=fit.truth, noise_seed=check_noise_seed)
    fit.write_csv(out / "poses.csv", [f"machine: {machine.name}", f"simulated seed={seed}"])
    chk.write_csv(out / "checks.csv", [f"machine: {machine.name}", f"simulated seed={seed}",
                                       *check_noise_comments(check_noise_seed)])
    t = fit.truth
    info = {"seed": seed, "machine": machine.name, "kind": machine.kind, "noise_um": noise_um,
            **check_noise_record(check_noise_seed),
            "truth": {"leg_scale": t.machine.leg_scale.tolist(), "leg_offset_mm": t.machine.leg_offset_mm.tolist(),
                      "base_joints_mm": t.machine.base_joints_mm.tolist(),
                      "platform_joints_mm": t.machine.platform_joints_mm.tolist(),
                      "frame_translation_mm": np.asarray(t.frame_translation_mm).tolist(),
                      "frame_rotation": np.asarray(t.frame_rotation).tolist()},
            "files": {k: str(out / f"{k}.csv") for k in ("poses", "checks")},
            "note": "the hidden truth: for judging only, never an input of calibrate"}
    write_json(out / "truth.json", info)
    return info
