"""The compiled chain kernel (errormap/chain_kernel.py) against the numpy reference (errormap/chain_field.py),
as tests/test_htm_fast.py checks the grinder's kernels: every built-in machine-tool chain, random
element values (not the simulator's), points beyond the strokes and several turns of full-turn axes."""
import numpy as np
import pytest

from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from chain_reference import predict_and_jacobian_numpy, predict_numpy
from errormap.chain_field import ChainField
from errormap.chain_kernel import CompiledChain, error_jacobian

from chain_fixtures import axes_beyond_strokes

TOL_KERNEL_UM = 1e-9
"""Same transforms, different operation order (running 3×3 frame vs 4×4 frame products): tool
points up to ~1 m, one ulp 1.1e-10 μm; observed ≤ 4e-12 μm."""
TOL_KERNEL_JAC = 1e-9
"""Forward-mode derivatives vs the numpy joint/error Jacobians: round-off only (observed ≤ 1.2e-11)."""


@pytest.mark.parametrize("name", ["grinder-chain", "mill-xyz", "five-axis-ac", "lathe-xzc"])
def test_kernel_equals_numpy_reference(name):
    mt = load_machine(name)
    el = ChainElementSet.random(mt, 13, 40.0)
    rng = np.random.default_rng(14)
    ax = axes_beyond_strokes(mt, rng, 3000, 0.1, 3)
    cc = CompiledChain(mt, el)
    E0 = predict_numpy(mt, el, ax)
    E1, J1 = cc.predict_and_jacobian(ax)
    _, J0 = predict_and_jacobian_numpy(mt, el, ax)
    assert np.abs(cc.predict(ax) - E0).max() < TOL_KERNEL_UM
    assert np.abs(E1 - E0).max() < TOL_KERNEL_UM
    assert np.abs(J1 - J0).max() < TOL_KERNEL_JAC
    f = ChainField(mt, el)
    np.testing.assert_array_equal(f.predict(ax), cc.predict(ax))
    # the error-transfer Jacobian (identification), compiled vs numpy
    Je = error_jacobian(mt, ax)
    assert np.abs(Je - mt.error_jacobian(ax)).max() < TOL_KERNEL_JAC
    np.testing.assert_array_equal(f.error_jacobian(ax), Je)


def test_field_refuses_wrong_axes_shape():
    mt = load_machine("mill-xyz")
    f = ChainField(mt, ChainElementSet.random(mt, 1, 40.0))
    with pytest.raises(ValueError, match=r"x_mm, y_mm, z_mm"):
        f.predict(np.zeros((4, 2)))
