"""The exact solver at scale (issue 20): the HTM field's closed-form Jacobian and the compiled
Newton kernels give the answer of the finite-difference path, to float precision."""
import numpy as np
import pytest

from compensation.solvers import solve
from errormap.chain_field import ChainField
from errormap.chain_kernel import forward
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes

EXACT_TOL_UM = 1e-6
"""As tests/test_solvers.py: both solves iterate to float precision (|F| ≤ 1e-9 μm or round-off)."""
CMD_TOL_UM = 1e-6
"""Two roots found to float precision from different Jacobians: the commands differ by the
residuals' size (|I + 1e-3·dE/dp| is ~1), observed ≤ 7e-9 μm on 100,000 points."""


class FiniteDifferenceOnly:
    """The same HTM field declaring no capabilities: the solver differentiates it by finite differences."""

    capabilities = frozenset()

    def __init__(self, field):
        self.field = field
        self.calibrated_volume = field.calibrated_volume

    def predict(self, axes):
        return self.field.predict(axes)


@pytest.mark.parametrize("truth_seed", [2, 5])
def test_closed_form_jacobian_solve_equals_finite_differences(truth_seed):
    m = load_machine()
    field = ChainField(m, make_chain_truth(m, truth_seed).elements)
    rng = np.random.default_rng(21)
    axes = random_axes(m, 3000, rng)
    axes[:, 2] += 360.0 * rng.integers(-2, 3, len(axes))
    targets = forward(m, axes)
    fast = solve("exact", field, targets, m, target_axes=axes, progress=False)
    ref = solve("exact", FiniteDifferenceOnly(field), targets, m, target_axes=axes, progress=False)
    both = fast.success & ref.success
    assert both.mean() > 0.99  # points nearer the A axis than the error may be unreachable
    np.testing.assert_array_equal(fast.success, ref.success)
    assert fast.residual_norm_um[both].max() <= EXACT_TOL_UM
    np.testing.assert_allclose(fast.commands_mm[both], ref.commands_mm[both], rtol=0, atol=CMD_TOL_UM * 1e-3)
    # the closed-form Jacobian replaces three evaluations per point at the start
    assert fast.nfev < ref.nfev
