"""Every machine's feature points name their axis columns (header key ``axis_columns``), the grinder's too; only an
older file without it is read as the grinder's columns (with its one-line note). The data CSV is unchanged by the
key: it is metadata only."""
import numpy as np
import pytest

from compensation.app.commands.train import _machine
from errormap.featurepoints import FeaturePoints, make_feature_points
from errormap.machine import load_machine

GRID = 4
"""Points per axis of the small grids here (4³ = 64 ≥ the 10 a feature-point file needs)."""


class SmoothField:
    """A smooth stand-in error field over any three axes (μm), shape (n, 3) -> (n, 3)."""

    def predict(self, axes):
        a = np.asarray(axes, dtype=float)
        return np.stack([np.sin(a[:, 0] / 50.0), 2.0 * np.cos(a[:, 1] / 30.0), 1.5 + a[:, 2] / 100.0], axis=1)


@pytest.mark.parametrize("name", ["grinder", "mill-xyz", "lathe-xzc"])
def test_every_machine_names_its_axis_columns_and_the_csv_is_unchanged(name, tmp_path):
    m = load_machine(name)
    fp = make_feature_points(m, SmoothField(), n=GRID)
    assert fp.meta["axis_columns"] == ",".join(m.axis_columns)
    new = FeaturePoints.load(fp.save(tmp_path / "new" / "featurepoints.csv"))
    assert new.meta["axis_columns"] == ",".join(m.axis_columns) and new.axis_columns == m.axis_columns
    old_meta = {k: v for k, v in fp.meta.items() if k != "axis_columns"}
    old = FeaturePoints(fp.axes, fp.errors_um, old_meta, axis_columns=fp.axis_columns)
    old_path = old.save(tmp_path / "old" / "featurepoints.csv")
    assert (tmp_path / "new" / "featurepoints.csv").read_bytes() == old_path.read_bytes()


def test_only_an_older_grinder_file_gets_the_fallback_note(tmp_path, capsys):
    g = load_machine(None)
    fp = make_feature_points(g, SmoothField(), n=GRID)
    new = FeaturePoints.load(fp.save(tmp_path / "new.csv"))
    assert _machine(new).sha256 == g.sha256 and "no header key 'axis_columns'" not in capsys.readouterr().err
    meta = {k: v for k, v in fp.meta.items() if k != "axis_columns"}
    old = FeaturePoints.load(FeaturePoints(fp.axes, fp.errors_um, meta).save(tmp_path / "old.csv"))
    assert _machine(old).sha256 == g.sha256 and "no header key 'axis_columns'" in capsys.readouterr().err


def test_a_grinder_file_whose_machine_file_moved_finds_the_default_by_its_sha(tmp_path, capsys):
    """The built-in machine file is recorded by its absolute path; from another install that path is gone and
    the default grinder is found by the recorded SHA-256 (its name is not a file name)."""
    g = load_machine(None)
    fp = make_feature_points(g, SmoothField(), n=GRID)
    fp.meta["machine_file"] = str(tmp_path / "elsewhere" / "grinder.toml")
    moved = FeaturePoints.load(fp.save(tmp_path / "moved.csv"))
    assert _machine(moved).sha256 == g.sha256
