"""errormap: physics and data for volcomp.

Transforms, machine models (machine-tool chains, serial arms, the PKM models), error elements, the truth
simulator, identification and diagnosis, and the I/O schemas; imports neither ``training`` nor
``compensation``. The public names (``errormap.__all__``, listed in :data:`_LAZY`;
``docs/reference/python-api.md``) load lazily on first use, so ``import errormap`` imports nothing heavy."""

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
