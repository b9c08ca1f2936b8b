"""``volcomp report`` and ``volcomp compensate`` solve through one chunk plan (issue 20): the same
``--seed`` gives the GA methods the same streams, hence the same commands, in both."""
import io
from types import SimpleNamespace

import numpy as np
import pytest

from compensation.app.workflows.compare import compare_methods
from compensation.app.workflows.compensate import CompensateSettings, solve_paths
from errormap.chain_field import ChainField
from errormap.chain_kernel import forward
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes

SEED = 5


@pytest.mark.parametrize("method,points", [("batched-ga", 40), ("ga", 2)])  # the per-point GA: ~1 s a point
def test_report_and_compensate_give_the_same_ga_commands(tmp_path, method, points):
    m = load_machine()
    field = ChainField(m, make_chain_truth(m, 1).elements)
    axes = random_axes(m, points, np.random.default_rng(3))
    targets = forward(m, axes)
    path = SimpleNamespace(targets_mm=targets, axes=axes, path="p.csv", tool_mm=None, turning=None)

    def compensate(seed):
        s = CompensateSettings(method=method, model="elements.json", out_dir=tmp_path, seed=seed)
        return solve_paths([path], field, None, m, s)[0][0].commands_mm

    cmp = compare_methods(field, targets, m, methods=(method,), seed=SEED, ga_points=points, nominal_axes=axes,
                          log=io.StringIO())
    run = cmp.runs[method]
    assert len(run.index) == points  # the whole path, as compensate solves it
    np.testing.assert_array_equal(run.result.commands_mm, compensate(SEED))
    assert not np.array_equal(run.result.commands_mm, compensate(SEED + 1))  # the seed matters: not vacuous
