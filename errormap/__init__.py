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


def lazy_exports(package: str, names: dict):
    """``(__getattr__, __dir__)`` of a package whose public ``names`` ({name: module}) load on first use."""
    import importlib
    import sys

    def get(name):
        if name in names:
            return getattr(importlib.import_module(names[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def listing():
        return sorted(set(vars(sys.modules[package])) | set(names))
    return get, listing


__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
