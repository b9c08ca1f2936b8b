"""Networks saved before the grinder's network and the chain's network became one class still load and predict.

``tests/data/networks/`` holds three folders written by main's code at 705fbdf (``training.model.MLPField`` raw
and periodic A over x_mm, z_mm, a_deg with A's training turn at -90..270 deg; ``training.chain_model.ChainMLPField``
over five-axis-ac), hidden (6, 5), random weights (``init_params(seed=7)``), scalers from seeded random points, and
beside each the value and Jacobian that code predicted at 40 points (A in the seam window, past the turn, turns away).
"""
from pathlib import Path

import numpy as np
import pytest

from errormap.machine import load_machine
from training.model import CHAIN_FORMAT, FORMAT, MLPField

DATA = Path(__file__).parent / "data" / "networks"
JAC_TOL = 1e-15
"""Absolute (μm per mm / deg, on Jacobians of order 1): the chain's Jacobian was summed in another order before."""
VALUE_ULPS = 8
"""Values are compared to this many units in the last place of the largest value: the saved values were computed by
one numpy/OpenBLAS build, and a matrix product sums in the order the BLAS kernel picks for the CPU and the build
(numpy 2.4.6's OpenBLAS 0.3.31 differs from the saved values by 2 ulp, 3.6e-15 μm on these ~8 μm values)."""
F32_TOL_UM = 1e-5
"""float32 against float64 on these ~5 μm fields (the float32 path's documented few-nm error, with margin)."""


@pytest.mark.parametrize("name,fmt", [("grinder_raw", FORMAT), ("grinder_periodic", FORMAT),
                                      ("chain_five_axis_ac", CHAIN_FORMAT)])
def test_a_network_saved_by_either_old_class_loads_and_predicts_as_then(name, fmt, tmp_path):
    f = MLPField.load(DATA / name)
    ref = np.load(DATA / f"{name}.npz")
    e, J = f.predict_and_jacobian(ref["axes"])
    value_tol_um = VALUE_ULPS * np.spacing(np.abs(ref["e_um"]).max())
    assert np.abs(e - ref["e_um"]).max() <= value_tol_um                # values to a few ulp
    assert np.abs(J - ref["jac"]).max() <= JAC_TOL
    cols = f.predict_columns(np.ascontiguousarray(ref["axes"].T)).T
    assert np.abs(cols - e).max() <= 1e-12 * np.abs(e).max()
    assert np.abs(f.predict(ref["axes"], dtype=np.float32) - e).max() <= F32_TOL_UM
    g = MLPField.load(f.save(tmp_path / "again"))                      # saved again: the same format and files
    assert g.config() == f.config()
    for file in ("weights.npy", "scalers.json", "config.json"):
        assert (tmp_path / "again" / file).read_bytes() == (DATA / name / file).read_bytes()
    np.testing.assert_array_equal(g.predict(ref["axes"]), e)


def test_one_class_picks_the_layout_from_the_machine():
    grinder, mill = MLPField.for_machine(load_machine("grinder")), MLPField.for_machine(load_machine("five-axis-ac"))
    assert grinder.format == FORMAT and grinder.turn_axis == 2 and "offset_fitness" in grinder.capabilities
    assert mill.format == CHAIN_FORMAT and mill.turn_axis is None and mill.periodic == (False,) * 4 + (True,)
    assert "offset_fitness" not in mill.capabilities and "float32" in mill.capabilities
