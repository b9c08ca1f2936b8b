"""``volcomp calibrate``: an option of the other machine kind is refused by name, never silently ignored."""
import subprocess
import sys

import pytest


def cli(*args):
    return subprocess.run([sys.executable, "-m", "compensation.app.cli", *map(str, args)], capture_output=True,
                          text=True)


@pytest.mark.parametrize("opts,named", [
    (["--no-register"], "--no-register"), (["--lambda-rule", "gcv"], "--lambda-rule"),
    (["--lever-mm", "100"], "--lever-mm"), (["--no-scales", "--no-loop"], "--no-scales, --no-loop"),
])
def test_parallel_machine_options_refused_on_an_arm(tmp_path, opts, named):
    r = cli("calibrate", tmp_path / "poses.csv", "--machine", "ur5", "--out", tmp_path / "o", *opts)
    assert r.returncode == 2
    assert f"{named}: do" in r.stderr and "serial arm" in r.stderr
    assert not (tmp_path / "o").exists()


def test_arm_options_refused_on_a_hexapod(tmp_path):
    r = cli("calibrate", tmp_path / "poses.csv", "--out", tmp_path / "o", "--folds", "3")
    assert r.returncode == 2 and "--folds: does not apply to a hexapod" in r.stderr


def test_help_groups_the_options_by_machine_kind():
    h = cli("calibrate", "--help").stdout
    h = h[h.index("options:"):]          # the option list (the usage line above names every option)
    pkm, arm = h.index("hexapod / tripod only"), h.index("serial arm only")
    assert all(pkm < h.index(o) < arm for o in ("--no-register", "--lambda-rule", "--lever-mm"))
    assert h.index("--noise-um") < pkm   # both kinds: the PKM's noise, the arm's stated tracker σ (its verdict)
    assert all(h.index(o) > arm for o in ("--no-learned", "--folds"))


@pytest.mark.slow
def test_help_after_machine_shows_only_what_applies_to_its_kind():
    arm = cli("calibrate", "--machine", "ur5", "--help")
    assert arm.returncode == 0 and "--folds" in arm.stdout and "--no-learned" in arm.stdout
    assert not any(o in arm.stdout for o in ("--no-register", "--lambda-rule", "--lever-mm", "--no-scales", "hexapod / tripod only"))
    pkm = cli("calibrate", "--machine", "hexapod", "--help")
    assert pkm.returncode == 0 and "--lambda-rule" in pkm.stdout and "--folds" not in pkm.stdout
