"""Rules of the house read from the source: which module may import what, and what importing does.

Each rule is its own test function (other issues add theirs beside them).
"""
from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("errormap", "training", "compensation")


def imported_modules(path: Path) -> set[str]:
    """Every module a file imports (top level or inside functions), relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)
    return out


def _field_layer_files():
    return sorted((ROOT / "compensation" / "solvers").glob("*.py")) + [ROOT / "compensation" / "guards.py"]


def test_solvers_and_guards_import_neither_torch_nor_training():
    """compensation/solvers/* and guards.py depend on errormap.field, not on the network's libraries."""
    offenders = {}
    for path in _field_layer_files():
        bad = sorted(m for m in imported_modules(path) if m.split(".")[0] in ("torch", "training"))
        if bad:
            offenders[str(path.relative_to(ROOT))] = bad
    assert not offenders, f"solvers/guards import torch or training: {offenders}"
    # and at run time: nothing they import pulls torch or training in behind them
    code = ("import sys, compensation.guards, compensation.solvers.traditional, compensation.solvers.exact, "
            "compensation.solvers.ga, compensation.solvers.batched_ga; "
            "print([m for m in ('torch', 'training') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


CAPABILITY_ATTRIBUTES = {"predict", "predict_columns", "float32_predict", "jacobian", "predict_and_jacobian",
                         "offset_fitness", "calibrated_lo", "calibrated_hi", "axes_bounds", "in_lo_", "in_hi_",
                         "elements", "stations", "calibrated_volume", "capabilities", "needs"}


def test_solvers_and_guards_never_probe_a_field():
    """Optional field methods are declared (``field.capabilities``), never probed with getattr/hasattr."""
    offenders = []
    for path in _field_layer_files():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr")
                    and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
                    and node.args[1].value in CAPABILITY_ATTRIBUTES):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.func.id}(…, {node.args[1].value!r})")
    assert not offenders, offenders


def test_machine_file_validators_live_in_one_module_without_a_cycle():
    """Both machine-file parsers take their check_* validators from errormap.machine_checks; the PKM
    parser does not import errormap.machine (which dispatches to it)."""
    grinder = imported_modules(ROOT / "errormap" / "machine.py")
    pkm = imported_modules(ROOT / "errormap" / "pkm" / "machine_file.py")
    assert "errormap.machine_checks" in grinder and "errormap.machine_checks" in pkm
    assert not any(m == "errormap.machine" or m.startswith("errormap.machine.") for m in pkm), sorted(pkm)
    checks = imported_modules(ROOT / "errormap" / "machine_checks.py")
    assert not any(m.split(".")[0] == "errormap" for m in checks), sorted(checks)


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
