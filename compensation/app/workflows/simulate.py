"""What every family's ``volcomp simulate`` shares: the record of ``--seed-check-noise`` and the lines it prints
about a machine tool's simulation (:func:`compensation.app.workflows.measurement.simulate_chain`; step 1 of
``volcomp demo``)."""
from __future__ import annotations

from pathlib import Path


def check_noise_comments(check_noise_seed) -> list:
    """The checks file's header line recording ``simulate --seed-check-noise`` (none without it); every
    family writes it the same way."""
    return [] if check_noise_seed is None else [f"check_noise_seed: {check_noise_seed}"]


def check_noise_record(check_noise_seed) -> dict:
    """``truth.json``'s record of ``simulate --seed-check-noise`` (empty without it), every family alike."""
    return {} if check_noise_seed is None else {"check_noise_seed": check_noise_seed}


def summary_lines(info: dict, out) -> list:
    """What ``volcomp simulate`` prints about a machine tool's simulation (``info``: the ``truth.json`` document
    of :func:`compensation.app.workflows.measurement.simulate_chain`): the maximum spatial error, then the files
    written, the truth last."""
    lines = [f"max spatial error {info['max_spatial_error_um']:.1f} μm over the volume (reference temperature, "
             "positive approach)"]
    lines += [f"wrote {k}: {v}" for k, v in info["files"].items()]
    lines.append(f"wrote truth: {Path(out) / 'truth.json'}")
    return lines
