"""Simulating a truth grinder and its files (``volcomp simulate``; step 1 of ``volcomp demo``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.featurepoints import make_feature_points
from errormap.chain_field import ChainField
from errormap.io import sha256_file, write_csv, write_json
from errormap.simulator import EFFECT_DEFAULTS, volume_grid
from errormap.seeds import spawn_seeds


def simulate_truth(machine, seed: int, out, effects=(), noise_um: float = 1.0, checks: int = 400,
                   family: str = "default", check_noise_seed=None) -> dict:
    """Write ``out/truth_elements.json``, ``featurepoints.csv``, ``checks.csv`` and ``truth.json``
    for the truth grinder of ``seed`` (``errormap.truth_families.make_truth``); returns the
    ``truth.json`` document (``files``: the paths written, ``max_spatial_error_um`` over the volume).
    ``check_noise_seed``: None (default) the checks' noise from the seed's own stream; an int redraws
    only the checks' noise (same machine, same points and conditions)."""
    from errormap.truth_families import make_truth
    out = Path(out)
    effects = list(effects)
    truth = make_truth(machine, seed, effects=effects, family=family)
    el_path = truth.elements.save(out / "truth_elements.json")
    fp = make_feature_points(machine, ChainField(machine, truth.elements),
                             meta={"elements_file": str(el_path), "source": f"simulate seed={seed}"})
    fp.meta["elements_sha256"] = sha256_file(el_path)
    fp_path = fp.save(out / "featurepoints.csv")
    # the truth takes the seed itself, the check measurements a child stream of it
    measured = truth.check_measurements(n=checks, noise_um=noise_um, seed=spawn_seeds(seed, 1)[0],
                                        noise_seed=check_noise_seed)
    ck_path = write_csv(out / "checks.csv", measured, header_comments=[
        "format: volcomp-checks/1", f"machine: {machine.name}", f"noise_um: {noise_um}",
        f"effects: {','.join(effects) or 'none'}"] + check_noise_comments(check_noise_seed))
    grid = volume_grid(machine)
    e = np.linalg.norm(truth.spatial_error(grid, **truth.default_conditions(len(grid))), axis=1)
    info = {"seed": seed, "machine": machine.name, "machine_file": machine.path,
            "family": family, "effects": {k: EFFECT_DEFAULTS[k] | truth.effects[k] for k in truth.effects},
            "noise_um": noise_um, **check_noise_record(check_noise_seed),
            "max_spatial_error_um": float(e.max()),
            "files": {"elements": str(el_path), "featurepoints": str(fp_path), "checks": str(ck_path)}}
    write_json(out / "truth.json", info)
    return info


def check_noise_comments(check_noise_seed) -> list:
    """The checks file's header line recording ``simulate --seed-check-noise`` (none without it); every
    family writes it the same way."""
    return [] if check_noise_seed is None else [f"check_noise_seed: {check_noise_seed}"]


def check_noise_record(check_noise_seed) -> dict:
    """``truth.json``'s record of ``simulate --seed-check-noise`` (empty without it), every family alike."""
    return {} if check_noise_seed is None else {"check_noise_seed": check_noise_seed}


def summary_lines(info: dict, out) -> list:
    """What ``volcomp simulate`` prints about a simulation (``info``: :func:`simulate_truth`'s)."""
    lines = [f"max spatial error {info['max_spatial_error_um']:.1f} μm over the volume (reference temperature, "
             "positive approach)"]
    lines += [f"wrote {k}: {v}" for k, v in info["files"].items()]
    lines.append(f"wrote truth: {Path(out) / 'truth.json'}")
    return lines
