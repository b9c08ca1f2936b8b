"""Commands over machine-tool chains (issue 26 point 5): predict and featurepoints over a chain's
axes, the exact chain solver (Newton on the linear axes, rotary axes kept), G-code over a chain
(axis words from the machine) compensated with a TRUE residual against a truth element set."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.solvers.chain_exact import nominal_and_jacobian, solve_exact_chain
from errormap.machine import load_machine
from errormap.mt_elements import ChainElementSet
from errormap.mt_field import ChainField

DATA = Path(__file__).resolve().parent / "data"

TOL_MODEL_RESIDUAL_UM = 1e-6
"""Model residual of the exact chain solver: Newton goes on to round-off of the ~400–700 mm tool
point (ulp 1e-10 μm; observed ≤ 1.1e-7 μm on 1M points), so 1e-6 μm (the issue's bound) has a
margin of 10."""
TOL_KINEMATICS_MM = 1e-9
"""Compiled nominal forward kinematics and axis Jacobian vs the numpy chain: round-off of a few
float64 operations on ~1000 mm values (observed ≤ 2.3e-13 mm)."""
TOL_PREDICT_UM = 1e-9
"""predict's CSV (written with 12 significant digits... as %.17g by write_csv) vs ChainField.predict:
round-off of the text round trip only."""
ELEMENT_SCALE_UM = 20.0
"""Element values of ±20 μm / μrad (1 σ): the size of a real machine tool's geometric errors."""


def chain_elements(mt, seed, scale=ELEMENT_SCALE_UM, n_stations=11):
    """A seeded smooth element set of ``mt`` (values at 11 stations per axis, a cubic spline)."""
    rng = np.random.default_rng(seed)
    z = ChainElementSet.zeros(mt, n_stations)
    fun = {}
    for s in mt.slots:
        if s.is_function:
            f = rng.normal(0.0, scale, n_stations)
            if next(a for a in mt.axes if a.word == s.axis).full_turn:
                f[-1] = f[0]
            fun[s.name] = f
    return ChainElementSet(mt, z.stations, fun, {k: rng.normal(0.0, scale) for k in mt.constant_slots})


@pytest.mark.parametrize("name", ["mill-xyz", "five-axis-ac", "lathe-xzc", "grinder-chain"])
def test_compiled_nominal_and_axis_jacobian_equal_the_chain(name):
    mt = load_machine(name)
    rng = np.random.default_rng(5)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (2000, len(mt.axes)))
    P, J = nominal_and_jacobian(mt, ax)
    assert np.abs(P - mt.nominal(ax)).max() < TOL_KINEMATICS_MM
    assert np.abs(J - mt.axis_jacobian(ax)).max() < TOL_KINEMATICS_MM


@pytest.mark.parametrize("name", ["mill-xyz", "five-axis-ac"])
def test_exact_chain_solver_model_residual(name):
    mt = load_machine(name)
    f = ChainField(mt, chain_elements(mt, 11))
    rng = np.random.default_rng(12)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (5000, len(mt.axes)))
    targets = mt.nominal(ax)
    r = solve_exact_chain(f, targets, mt, target_axes=ax, progress=False)
    assert r.success.all()
    # the model residual recomputed independently: numpy chain + the field at the returned axes
    model = (mt.nominal(r.axes) - targets) * 1e3 + f.predict(r.axes)
    assert np.abs(model).max() < TOL_MODEL_RESIDUAL_UM
    assert np.abs(r.residual_um - model).max() < TOL_MODEL_RESIDUAL_UM
    assert np.abs(r.commands_mm - mt.nominal(r.axes)).max() < TOL_KINEMATICS_MM
    rot = [j for j, a in enumerate(mt.axes) if a.kind == "rotary"]
    assert np.array_equal(r.axes[:, rot], ax[:, rot])  # tool orientation kept exactly
    assert r.info["kept_axes"] == [mt.axis_columns[j] for j in rot]
    if rot:
        assert "kept as commanded" in r.info["note"]
    # the correction is the error itself to first order: it cancels the field
    assert np.abs(r.correction_um - np.linalg.norm(f.predict(ax), axis=1)).max() < 0.05 * r.correction_um.max()


def test_exact_chain_solver_without_target_axes_on_a_linear_machine():
    mt = load_machine("mill-xyz")
    f = ChainField(mt, chain_elements(mt, 13))
    ax = np.random.default_rng(14).uniform(mt.stroke_lo, mt.stroke_hi, (300, 3))
    r = solve_exact_chain(f, mt.nominal(ax), mt, progress=False)
    assert np.abs(r.residual_um).max() < TOL_MODEL_RESIDUAL_UM


def test_exact_chain_solver_ball_is_a_hard_limit():
    mt = load_machine("mill-xyz")
    f = ChainField(mt, chain_elements(mt, 15, scale=400.0))  # errors beyond the 250 μm ball
    ax = np.random.default_rng(16).uniform(mt.stroke_lo, mt.stroke_hi, (400, 3))
    r = solve_exact_chain(f, mt.nominal(ax), mt, target_axes=ax, progress=False)
    out = r.info["outside_ball"]
    assert len(out) and not r.success[out].any()
    assert np.all(r.correction_um <= 250.0 * (1 + 1e-9))


def test_exact_chain_solver_refuses_a_machine_without_three_linear_axes():
    mt = load_machine("lathe-xzc")
    f = ChainField(mt, chain_elements(mt, 17))
    with pytest.raises(ValueError, match="three linear axes"):
        solve_exact_chain(f, np.zeros((2, 3)), mt, target_axes=np.zeros((2, 3)), progress=False)
