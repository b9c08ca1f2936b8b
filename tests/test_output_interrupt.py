"""Two runs into one ``--out`` folder: the second is refused naming the first; Ctrl-C leaves
nothing of the interrupted run, in every command that writes a folder (the same context manager,
:func:`compensation.app.outputs.owned_folder`): ``benchmark`` used to leave ``B/chains/...``
behind while saying "nothing half-written".

Each test starts a real ``volcomp`` process (the installed script's entry), so they are slow.
"""
from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from compensation.app.outputs import LOCK_NAME

from test_cli_robust import INTERRUPT_ANSWER_S, _assert_interrupted, _interrupt, _start, run_cli

# a run's lock appears once its libraries are imported and its options checked: 5-10 s on the loaded
# 2-core test machine; 120 s fails a run that never takes it
LOCK_APPEARS_S = 120.0


def _wait_for(path: Path, proc, timeout_s: float = LOCK_APPEARS_S) -> None:
    t0 = time.monotonic()
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout_s, f"{path} did not appear"
        time.sleep(0.05)


def _tree(root: Path) -> list:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A grinder simulation: checks.csv (200 checks) and truth_elements.json."""
    from compensation.app.cli import main
    d = tmp_path_factory.mktemp("sim") / "sim"
    assert main(["simulate", "--out", str(d), "--checks", "200"]) == 0
    return d


@pytest.mark.slow
def test_benchmark_ctrl_c_leaves_no_chains_folder(tmp_path):
    """Interrupted after its first closed-loop condition wrote ``B/chains/mill-xyz/effect_thermal/`` (the quick
    run's second condition; the ones after it are not needed to have a folder in B): B is gone."""
    proc = _start(["benchmark", "--machine", "mill-xyz", "--quick", "--no-track", "--out", "B"], tmp_path)
    rc, err = _interrupt(proc, 0.5, wait_for="effect=thermal (after closed loop)")
    _assert_interrupted(rc, err, tmp_path)
    assert not (tmp_path / "B").exists(), _tree(tmp_path / "B")


@pytest.mark.slow
def test_second_diagnose_into_the_same_out_is_refused_then_ctrl_c_cleans(tmp_path, sim):
    out = tmp_path / "d"
    argv = ["diagnose", str(sim / "checks.csv"), "--model", str(sim / "truth_elements.json"), "--out", str(out)]
    first = _start(argv, tmp_path)
    _wait_for(out / LOCK_NAME, first)
    rc, _, err = run_cli(argv)
    assert rc == 2 and "Traceback" not in err, err
    assert f"in use by volcomp diagnose (pid {first.pid}" in err and str(out) in err, err
    first.send_signal(signal.SIGINT)
    _, rest = first.communicate(timeout=INTERRUPT_ANSWER_S)
    _assert_interrupted(first.returncode, rest, tmp_path)
    assert not out.exists(), _tree(out)  # the folder the first run created is gone with its lock


@pytest.mark.slow
def test_second_compensate_into_the_same_out_is_refused(tmp_path, sim, grinder):
    from compensation.pathio import write_axes_gcode
    from compensation.toolpath import flute_path
    nc = write_axes_gcode(tmp_path / "in" / "flute.nc", flute_path(turns=40, points_per_turn=2000).axes(grinder))
    out = tmp_path / "c"
    argv = ["compensate", str(nc), "--model", str(sim / "truth_elements.json"), "--method", "exact", "--out", str(out),
            "--work-offsets", "machine"]
    first = _start(argv, tmp_path)
    _wait_for(out / LOCK_NAME, first)
    rc, _, err = run_cli(argv[:-1] + [str(out), "--force"])
    assert rc == 2 and f"in use by volcomp compensate (pid {first.pid}" in err, err
    first.send_signal(signal.SIGINT)
    _, rest = first.communicate(timeout=INTERRUPT_ANSWER_S)
    _assert_interrupted(first.returncode, rest, tmp_path)
    assert not out.exists(), _tree(out)


@pytest.mark.slow
def test_ctrl_c_keeps_what_the_folder_held_before(tmp_path):
    """simulate into a folder holding a file: interrupted mid-work, only that file stays."""
    out = tmp_path / "sim"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    proc = _start(["simulate", "--out", "sim", "--checks", "200000"], tmp_path)
    _wait_for(out / "featurepoints.csv", proc)  # mid-work: one of its three files written
    rc, err = _interrupt(proc, 0.0)
    _assert_interrupted(rc, err, tmp_path)
    assert _tree(out) == ["notes.txt"] and (out / "notes.txt").read_text() == "mine\n"
