"""The chunk plan of batch compensation (compensation.batch): fixed boundaries, per-chunk seeds,
and results that depend on neither the number of workers nor the other files of a batch."""
from types import SimpleNamespace

import numpy as np
import pytest

from compensation.batch import LocalExecutor, plan_chunks, solve_batch
from compensation.toolpath import flute_path
from errormap.chain_field import ChainField
from errormap.chain_truth import make_chain_truth

# small GA settings: the properties below are about streams and chunks, not convergence
GA_OPTIONS = {"ga": {"generations": 3, "population": 10}, "batched-ga": {"generations": 20}}


@pytest.fixture(scope="module")
def field(grinder):
    return ChainField(grinder, make_chain_truth(grinder, 7).elements)


def _paths(grinder):
    f = flute_path(turns=1, points_per_turn=30)
    ax = f.axes(grinder)
    return [SimpleNamespace(targets_mm=f.targets_mm, axes=ax),
            SimpleNamespace(targets_mm=f.targets_mm[5:16], axes=ax[5:16])]


def test_chunk_boundaries_are_fixed_by_point_count_and_seeds_spawned_per_file():
    chunks = plan_chunks([10, 3, 8], chunk_points=4, seed=5)
    assert [(c.file, c.index, c.lo, c.hi) for c in chunks] == [
        (0, 0, 0, 4), (0, 1, 4, 8), (0, 2, 8, 10), (1, 0, 0, 3), (2, 0, 0, 4), (2, 1, 4, 8)]
    # chunk j of a file: SeedSequence(seed).spawn(k)[j], the same for every file of k chunks
    want = np.random.SeedSequence(5).spawn(2)
    for c, w in zip(chunks[4:], want):
        assert c.seed.entropy == w.entropy and c.seed.spawn_key == w.spawn_key
    assert chunks[4].seed.generate_state(4).tolist() == want[0].generate_state(4).tolist()
    with pytest.raises(ValueError, match="chunk_points"):
        plan_chunks([3], chunk_points=0)


@pytest.mark.parametrize("method", ["traditional", pytest.param("exact", marks=pytest.mark.slow),  # over 5 CPU s in CI (tier rule)
                                    "batched-ga", "ga"])
def test_result_does_not_depend_on_workers_nor_on_the_other_files(method, grinder, field):
    paths = _paths(grinder)
    opts = GA_OPTIONS.get(method, {})
    one = solve_batch(method, field, grinder, paths, seed=3, options=opts, chunk_points=8, executor=LocalExecutor(1))
    three = solve_batch(method, field, grinder, paths, seed=3, options=opts, chunk_points=8,
                        executor=LocalExecutor(3))
    alone = solve_batch(method, field, grinder, paths[1:], seed=3, options=opts, chunk_points=8,
                        executor=LocalExecutor(2))
    for a, b in zip(one, three):
        assert np.array_equal(a.axes, b.axes) and np.array_equal(a.commands_mm, b.commands_mm)
        assert np.array_equal(a.residual_um, b.residual_um)
    assert np.array_equal(one[1].axes, alone[0].axes)
    assert one[0].info["chunks"] == 4 and len(one[0].axes) == 30  # 30 points in chunks of 8
    if method in GA_OPTIONS:  # the seed matters: another seed, other draws
        other = solve_batch(method, field, grinder, paths[1:], seed=4, options=opts, chunk_points=8,
                            executor=LocalExecutor(1))
        assert not np.array_equal(other[0].axes, alone[0].axes)


def test_the_library_and_the_command_do_not_import_ray():
    import subprocess
    import sys
    code = ("import sys, compensation.batch, compensation.app.commands.compensate, compensation.app.commands.fleet; "
            "print('ray' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_cluster_options_are_checked(tmp_path, capsys):
    from compensation.app.cli import main
    base = ["compensate", str(tmp_path / "p.nc"), "--model", "m.json", "--method", "exact", "--out", str(tmp_path / "o")]
    assert main(base + ["--address", "127.0.0.1:6379"]) == 2
    assert "--address needs --cluster ray" in capsys.readouterr().err
    assert main(base + ["--workers", "0"]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err
    assert main(base + ["--chunk-points", "0"]) == 2
    assert "--chunk-points must be >= 1" in capsys.readouterr().err


def small_learned_field(grinder):
    """A small untrained-but-scaled MLP field (random weights, fixed seed): a torch field for the
    determinism checks (its values do not matter here, only that torch computes them)."""
    from training.model import MLPField
    rng = np.random.default_rng(0)
    axes = rng.random((500, 3)) * (grinder.stroke_hi - grinder.stroke_lo) + grinder.stroke_lo
    e = np.column_stack([np.sin(axes[:, 0] / 30) * 5, np.cos(np.deg2rad(axes[:, 2])) * 3, axes[:, 1] / 10])
    f = MLPField(hidden=(12, 12), activation="tanh").fit_scalers(axes, e)
    f.theta_ = f.init_params(3)
    return f


@pytest.mark.parametrize("method", ["exact", "batched-ga"])
def test_a_learned_field_gives_the_same_bits_with_any_workers(method, grinder):
    field = small_learned_field(grinder)
    paths = _paths(grinder)
    opts = GA_OPTIONS.get(method, {})
    one = solve_batch(method, field, grinder, paths, seed=3, options=opts, chunk_points=8, executor=LocalExecutor(1))
    two = solve_batch(method, field, grinder, paths, seed=3, options=opts, chunk_points=8, executor=LocalExecutor(2))
    for a, b in zip(one, two):
        assert np.array_equal(a.axes, b.axes) and np.array_equal(a.residual_um, b.residual_um)
