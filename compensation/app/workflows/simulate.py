"""Simulating a truth grinder and its files (``volcomp simulate``; step 1 of ``volcomp demo``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from errormap.featurepoints import make_feature_points
from errormap.chain_field import ChainField
from errormap.io import sha256_file, write_csv, write_json
from errormap.chain_truth import make_chain_truth, volume_grid
from errormap.effect_kinds import SIMULATOR_NAMES, effect_kind, simulator_name
from errormap.seeds import spawn_seeds


def simulate_truth(machine, seed: int, out, effects=(), noise_um: float = 1.0, checks: int = 400,
                   family: str = "default", check_noise_seed=None) -> dict:
    """Write ``out/truth_elements.json``, ``featurepoints.csv``, ``checks.csv`` and ``truth.json``
    for the truth grinder of ``seed`` (:func:`errormap.chain_truth.make_chain_truth`); returns the
    ``truth.json`` document (``files``: the paths written, ``max_spatial_error_um`` over the volume).
    ``check_noise_seed``: None (default) the checks' noise from the seed's own stream; an int redraws
    only the checks' noise (same machine, same points and conditions)."""
    out = Path(out)
    effects = list(effects)
    truth = make_chain_truth(machine, seed, effects=effects, family=family)
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
            "family": family, "effects": grinder_effects(truth.effects),
            "noise_um": noise_um, **check_noise_record(check_noise_seed),
            "max_spatial_error_um": float(e.max()),
            "files": {"elements": str(el_path), "featurepoints": str(fp_path), "checks": str(ck_path)}}
    write_json(out / "truth.json", info)
    return info


EFFECT_CHOICES = SIMULATOR_NAMES + tuple(k.name for k in map(effect_kind, SIMULATOR_NAMES)
                                         if k.name != k.simulator)
"""What the grinder's ``--effect`` accepts: the simulator's names and the registry's canonical names of the
same kinds (``periodic`` = ``pitch``, ``harmonic`` = ``worm``)."""
EFFECT_HELP = ", ".join(SIMULATOR_NAMES) + " (" + ", ".join(
    f"{k} = {effect_kind(k).simulator}" for k in EFFECT_CHOICES[len(SIMULATOR_NAMES):]) + ")"
"""The grinder's ``--effect`` help: the names and the canonical names accepted beside them."""


def grinder_effects(effects: dict) -> dict:
    """A truth's ``{"KIND:AXES": parameters}`` as a grinder ``truth.json`` records them: by the simulator's
    names, the stroke fractions by the axes (``x_frac``, ``z_frac``;
    :data:`compensation.evaluate.PARAMETER_NAMES`)."""
    from compensation.evaluate import PARAMETER_NAMES
    back = {v: k for k, v in PARAMETER_NAMES.items()}
    return {simulator_name(key.split(":")[0]): {back.get(k, k): v for k, v in p.items()}
            for key, p in effects.items()}


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
