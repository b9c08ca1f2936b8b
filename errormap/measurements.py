"""Measurements for the public API: read a file, or simulate one from a truth, into the objects the
estimators fit (:mod:`errormap.estimators`). Every reader validates the whole file first and names
file, row and column in its errors (the same readers as the commands); which reader runs follows the
loaded machine (a machine-tool chain, the grinder file, a serial arm), never the file's name.

Shapes: sweeps grouped per axis and station (:class:`errormap.sweeps.Sweeps`); checks ``axes`` (n, k),
``measured_um`` (n, 3); poses ``q`` (n, nq) joint values, ``xyz_mm`` (n, 3).
"""
from __future__ import annotations


def read_sweeps(paths, machine):
    """Tracker sweeps of one set-up (:class:`errormap.sweeps.Sweeps`) of a machine-tool chain or the grinder
    file's chain: one sweep file, or several naming the same ``# setup:`` (axis words from the machine)."""
    from .estimators import machine_tool
    from .sweeps import read_sweeps as read_machine_sweeps
    return read_machine_sweeps(paths, machine_tool(machine, "read_sweeps(machine=...)"))


def read_checks(path, machine, units: str = "check"):
    """Check measurements of a machine-tool chain or the grinder file
    (:class:`errormap.diagnosis.chain_loop.ChainChecks`, in ``seq`` order: ``axes`` (n, k) mm/deg, ``measured_um``
    (n, 3)). ``units="as-written"`` skips the likely-unit-mistake tests."""
    from .diagnosis.chain_loop import load_chain_checks
    from .estimators import machine_tool
    return load_chain_checks(path, machine_tool(machine, "read_checks(machine=...)"), units=units)


def read_poses(path, chain):
    """Measured poses: of a serial arm (:class:`errormap.arm_poses.ArmPoses`: the pose schema or a tracker grid,
    told apart by content), or of a hexapod / tripod (:class:`errormap.pkm.poses.PoseData`)."""
    from .pkm.machine_file import PKM
    if isinstance(chain, PKM):
        from .pkm.poses import read_poses as read_pkm_poses
        return read_pkm_poses(path, chain)
    from .arm_poses import read_arm_poses
    return read_arm_poses(path, chain)


def read_drift_log(path, **options):
    """A drift log (:class:`errormap.diagnosis.drift.DriftLog`); ``options`` as
    :func:`errormap.diagnosis.drift.load_drift_log` (``causal``, ``time_unit``, ``units`` …)."""
    from .diagnosis.drift import load_drift_log
    return load_drift_log(path, **options)


def simulate_truth(machine, seed: int, family: str = "default"):
    """A hidden truth of a machine-tool chain or the grinder file's chain
    (:class:`errormap.chain_truth.ChainTruth`): seeded random element functions (``family`` ``"default"`` or
    ``"independent"``), no effects. For testing: an estimator is never given it."""
    from .chain_truth import make_chain_truth
    from .estimators import machine_tool
    return make_chain_truth(machine_tool(machine, "simulate_truth(machine=...)"), seed, family=family)


def simulate_sweeps(truth, noise_um: float = 2.0, seed: int = 0, n_stations: int | None = None):
    """Simulated tracker sweeps of ``truth`` (every axis with error slots at ``n_stations`` stations over its
    stroke, None: the command's default, the others parked at their lower stroke ends, an unknown seeded
    tracker pose, N(0, ``noise_um``²) per coordinate) as a :class:`errormap.sweeps.Sweeps` — what
    ``volcomp sweeps --machine`` writes, read back."""
    from .chain_sweeps import DEFAULT_STATIONS, simulated_sweeps, swept_words
    from .sweeps import sweeps_from_columns
    cols = simulated_sweeps(truth, noise_um=noise_um, seed=seed,
                              n_stations=DEFAULT_STATIONS if n_stations is None else n_stations)
    return sweeps_from_columns(cols, source="<simulated sweeps>", axes=swept_words(truth.machine))


def simulate_checks(truth, n: int = 400, noise_um: float = 1.0, seed: int = 0):
    """``n`` simulated check measurements of ``truth`` (:class:`errormap.diagnosis.chain_loop.ChainChecks`):
    what ``volcomp simulate --machine`` writes to ``checks.csv``, read back."""
    from .diagnosis.chain_loop import ChainChecks
    cols = truth.check_measurements(n=n, noise_um=noise_um, seed=seed)
    return ChainChecks.from_columns(truth.machine, cols, path="<simulated checks>")


__all__ = ["read_checks", "read_drift_log", "read_poses", "read_sweeps", "simulate_checks", "simulate_sweeps",
           "simulate_truth"]
