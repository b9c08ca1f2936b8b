"""errormap: physics and data for volcomp.

Transforms, machine models (the grinder's 23-error HTM model, machine-tool chains, serial arms, the PKM
models), error elements, the truth simulator, feature points, identification and diagnosis, and the I/O
schemas. Imports neither ``training`` nor ``compensation``.

The public names below (``errormap.__all__``; docs/reference/python-api.md) load lazily on first use, so
``import errormap`` imports nothing heavy and has no side effects:

* machines — :func:`load_machine` (a built-in name such as ``"mill-xyz"`` or ``"ur5"``, or a file),
  :func:`builtin_machines`; the grinder file is identified, looped and compensated as its chain;
* measurements — :func:`read_sweeps`, :func:`read_checks`, :func:`read_poses`, :func:`read_drift_log`,
  and simulated ones: :func:`simulate_truth`, :func:`simulate_sweeps`, :func:`simulate_checks`;
* estimators (scikit-learn contract) — :class:`Identification`, :class:`ClosedLoop`,
  :class:`ArmCalibration`, :class:`PKMCalibration`, :class:`DriftSelector` (its fitted :class:`DriftModel`);
  :class:`NotFittedError`;
* error fields — :class:`ChainField` (an element set of a chain), :class:`ChainModelField` (elements plus
  effect terms), :class:`ChainElementSet`;
* errors — :class:`InputError` (a file that cannot be read exactly), :class:`MachineFileError`.
"""

__version__ = "0.1.0"

_LAZY = {
    "load_machine": "errormap.machine",
    "builtin_machines": "errormap.machine",
    "MachineFileError": "errormap.machine",
    "InputError": "errormap.io",
    "read_sweeps": "errormap.measurements",
    "read_checks": "errormap.measurements",
    "read_poses": "errormap.measurements",
    "read_drift_log": "errormap.measurements",
    "simulate_truth": "errormap.measurements",
    "simulate_sweeps": "errormap.measurements",
    "simulate_checks": "errormap.measurements",
    "Identification": "errormap.estimators",
    "ClosedLoop": "errormap.estimators",
    "ArmCalibration": "errormap.estimators",
    "PKMCalibration": "errormap.estimators",
    "NotFittedError": "errormap.estimators",
    "DriftSelector": "errormap.diagnosis.drift_models",
    "DriftModel": "errormap.diagnosis.drift_models",
    "ChainField": "errormap.chain_field",
    "ChainModelField": "errormap.diagnosis.loop_model",
    "ChainElementSet": "errormap.chain_elements",
}

__all__ = sorted(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'errormap' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
