"""The error field's layer, read from the source: the solvers and guards depend on the field
protocol alone, the machine-file validators live in one module, and importing any module changes
no global state (docs/explanation/architecture.md). The import walker is ``tests/test_architecture.py``'s.
"""
import ast

from test_architecture import PACKAGES, ROOT, imported_modules, module_name, offenders, sources


def _field_layer_files():
    """compensation/solvers/* and compensation/guards.py: they depend on errormap.field alone."""
    return sources("compensation.solvers") + [ROOT / "compensation" / "guards.py"]


def test_solvers_and_guards_import_neither_torch_nor_training():
    """compensation/solvers/* and guards.py import neither torch nor training, directly or behind
    another import (checked in a fresh interpreter)."""
    import subprocess
    import sys
    assert not offenders(_field_layer_files(), ("torch", "training"))
    code = ("import sys, compensation.guards, compensation.solvers.chain_traditional, compensation.solvers.chain_exact, "
            "compensation.solvers.chain_ga, compensation.solvers.exact, compensation.solvers.ga, "
            "compensation.solvers.batched_ga; "
            "print([m for m in ('torch', 'training') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


FIELD_MEMBERS = {"predict", "predict_columns", "float32_predict", "jacobian", "predict_and_jacobian",
                 "offset_fitness", "calibrated_lo", "calibrated_hi", "axes_bounds", "in_lo_", "in_hi_",
                 "elements", "stations", "calibrated_volume", "capabilities", "needs"}
"""Names a solver or guard might probe a field for (the protocol's members and the old box attributes)."""


def test_solvers_and_guards_never_probe_a_field():
    """Optional field methods are declared (``field.capabilities``), never probed with getattr/hasattr."""
    found = []
    for path in _field_layer_files():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr")
                    and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
                    and node.args[1].value in FIELD_MEMBERS):
                found.append(f"{module_name(path)}:{node.lineno} {node.func.id}(…, {node.args[1].value!r})")
    assert not found, found


def test_machine_file_validators_live_in_one_module_without_a_cycle():
    """Both machine-file parsers take their check_* validators from errormap.machine_checks; the PKM
    parser does not import errormap.machine (which dispatches to it), and the checks import nothing of ours."""
    grinder = imported_modules(ROOT / "errormap" / "machine.py")
    pkm = imported_modules(ROOT / "errormap" / "pkm" / "machine_file.py")
    assert "errormap.machine_checks" in grinder and "errormap.machine_checks" in pkm
    assert not offenders([ROOT / "errormap" / "pkm" / "machine_file.py"], ("errormap.machine",))
    assert not offenders([ROOT / "errormap" / "machine_checks.py"], PACKAGES)


IMPORT_EVERYTHING = """
import importlib, json, logging, os, pkgutil, sys
import torch

def state():
    root = logging.getLogger()
    return {"dtype": str(torch.get_default_dtype()), "threads": torch.get_num_threads(),
            "env": dict(os.environ), "root_logging": [root.level, len(root.handlers)]}

before = state()
names = []
for pkg in %r:
    p = importlib.import_module(pkg)
    names.append(pkg)
    names += [info.name for info in pkgutil.walk_packages(p.__path__, pkg + ".")]
for name in names:
    importlib.import_module(name)
print(json.dumps({"before": before, "after": state(), "modules": names}))
"""


def test_importing_any_module_changes_no_global_state():
    """Importing every module of the three packages leaves torch's default dtype and thread count,
    the environment and the logging configuration as they were (no import-time side effects)."""
    import json
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", IMPORT_EVERYTHING % (PACKAGES,)], cwd=ROOT, capture_output=True,
                         text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    before, after = res["before"], res["after"]
    assert len(res["modules"]) > 50 and "errormap.pkm.calibration" in res["modules"]
    assert after["dtype"] == before["dtype"] == "torch.float32"
    assert after["threads"] == before["threads"]
    changed = sorted(k for k in set(before["env"]) | set(after["env"]) if before["env"].get(k) != after["env"].get(k))
    assert not changed, f"os.environ changed by imports: {changed}"
    assert after["root_logging"] == before["root_logging"]
