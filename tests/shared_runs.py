"""End-to-end runs that several test files assert on, each run once per test session.

Each function runs one user's path through the CLI into ``root`` and returns what the tests read:
the folder, what the commands printed, and (for the closed loop) the in-memory result. The session
fixtures in ``tests/conftest.py`` call them; the files whose tests share one run are one unit of
``.ci/run``'s ``--dist loadscope`` (``SAME_WORKER`` in tests/conftest.py), so the run happens once
there. A test that writes into a shared folder copies it first (:func:`private_copy`): the shared one
stays as the run left it.
"""
from __future__ import annotations

import contextlib
import io
import shutil
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class SharedRun:
    """A finished run: its folder, the stdout/stderr of its last command, anything else it kept."""
    root: Path
    out: str = ""
    err: str = ""
    extra: dict = field(default_factory=dict)


def _main_captured(argv) -> tuple[int, str, str]:
    from compensation.app.cli import main
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def _ok(argv) -> tuple[str, str]:
    rc, out, err = _main_captured(argv)
    assert rc == 0, (argv, err[-2000:])
    return out, err


def private_copy(src: Path, dst: Path) -> Path:
    """A copy of a shared run's folder ``src`` at ``dst`` for a test that writes into it."""
    shutil.copytree(src, dst)
    return dst


def bump_user_path(root: Path) -> SharedRun:
    """The grinder's user's path with an out-of-catalogue bump (seed 1): sweeps (2 μm, noise seed 7) →
    simulate (800 checks at 1 μm) → identify (40 bootstrap draws) → diagnose --track into ``root/d``
    with an MLflow store at ``root/store``. ``extra``: ``uri`` (the store)."""
    q = ["--seed", "1", "--effect", "bump"]
    _ok(["sweeps", *q, "--noise-um", "2", "--seed-noise", "7", "--out", root / "sw.csv"])
    _ok(["simulate", *q, "--checks", "800", "--noise-um", "1", "--out", root / "sim"])
    _ok(["identify", root / "sw.csv", "--out", root / "el.json", "--bootstrap", "40"])
    uri = f"sqlite:///{root / 'store' / 'mlflow.db'}"
    out, err = _ok(["diagnose", root / "sim" / "checks.csv", "--model", root / "el.json", "--out", root / "d",
                    "--track", "--tracking-uri", uri])
    return SharedRun(root, out, err, {"uri": uri})


def mill_reversal(root: Path) -> SharedRun:
    """A machine-tool chain's diagnose run: simulate mill-xyz (seed 2, reversal:Z, 200 checks) → diagnose
    against the truth's element set (no covariance: no update, ``--noise-um 1``) into ``root/diag``; ``out``
    is what diagnose printed."""
    _ok(["simulate", "--machine", "mill-xyz", "--seed", "2", "--effect", "reversal:Z", "--checks", "200",
         "--out", root / "sim"])
    out, err = _ok(["diagnose", root / "sim" / "checks.csv", "--machine", "mill-xyz", "--model",
                    root / "sim" / "truth_elements.json", "--noise-um", "1", "--out", root / "diag"])
    return SharedRun(root, out, err)


def tiny_demo(root: Path) -> SharedRun:
    """``volcomp demo`` with tiny settings (one flute turn of 24 points, 8 s of training, an 8-8 network,
    the per-point GA on 3 points, seed 1) into ``root/demo``, its MLflow store at ``root/mlflow.db``."""
    out, err = _ok(["demo", "--out", root / "demo", "--tracking-uri", f"sqlite:///{root / 'mlflow.db'}", "--turns",
                    "1", "--points-per-turn", "24", "--train-s", "8", "--hidden", "8,8", "--ga-points", "3",
                    "--seed", "1"])
    return SharedRun(root, out, err)


def mill_quick_benchmark(root: Path) -> SharedRun:
    """``volcomp benchmark --machine mill-xyz --quick --no-track`` into ``root/b``; ``out`` is what it printed."""
    out, err = _ok(["benchmark", "--machine", "mill-xyz", "--quick", "--no-track", "--out", root / "b"])
    return SharedRun(root, out, err)
