"""Machine files: the built-in grinder loads; malformed grinder files are rejected naming the key."""
import re
from pathlib import Path

import numpy as np
import pytest

from errormap.grinder_file import rho0_mm
from errormap.machine import MachineFileError, load_machine

GOOD = (Path(__file__).parent / "data" / "machines" / "grinder_kind_grinder.toml").read_text()
"""A ``kind = "grinder"`` file (the older schema, read as its chain)."""


def write(tmp_path, text):
    p = tmp_path / "m.toml"
    p.write_text(text)
    return p


def test_builtin_default_values(grinder):
    assert grinder.kind == "machine-tool" and grinder.name == "micro-drill flute grinder"
    assert grinder.geometry["l1"] == 420.0 and grinder.geometry["l8"] == 119.9 and grinder.geometry["theta1_deg"] == 30.0
    assert grinder.strokes["x_mm"] == (0.0, 200.0)
    assert grinder.targets["A"].shape == (3, 3)
    assert rho0_mm(grinder) == pytest.approx(0.1, abs=1e-9)
    assert len(grinder.sha256) == 64


@pytest.mark.parametrize("mutate, key", [
    (lambda s: s.replace("l5 = -240.0\n", ""), "geometry.l5"),
    (lambda s: s.replace("l5 = -240.0", "l5 = -240.0\nl9 = 1.0"), "geometry.l9"),
    (lambda s: s.replace("l7 = 40.0", 'l7 = "forty"'), "geometry.l7"),
    (lambda s: s.replace("z_mm = [0.0, 60.0]", "z_mm = [60.0, 0.0]"), "strokes.z_mm"),
    (lambda s: s.replace("x_mm = [0.0, 200.0]", "x_mm = [0.0]"), "strokes.x_mm"),
    (lambda s: s.replace('kind = "grinder"', 'kind = "lathe"'), "machine.kind"),
    (lambda s: re.sub(r"\nA = .*\n", "\n", s), "targets.A"),
])
def test_malformed_file_names_key(tmp_path, mutate, key):
    p = write(tmp_path, mutate(GOOD))
    with pytest.raises(MachineFileError) as exc:
        load_machine(p)
    assert key in str(exc.value)
    assert str(p) in str(exc.value)


def test_not_toml_and_missing_file(tmp_path):
    with pytest.raises(MachineFileError, match="not valid TOML"):
        load_machine(write(tmp_path, "[machine\nkind="))
    with pytest.raises(MachineFileError, match="no such machine file"):
        load_machine(tmp_path / "absent.toml")


def test_other_machine_file_changes_geometry(tmp_path):
    p = write(tmp_path, GOOD.replace("l7 = 40.0", "l7 = 50.0"))
    m = load_machine(p)
    assert m.geometry["l7"] == 50.0
    from errormap.chain_kernel import forward
    assert forward(m, np.array([[0.0, 0.0, 0.0]]))[0, 0] == pytest.approx(190.0, abs=1e-12)
