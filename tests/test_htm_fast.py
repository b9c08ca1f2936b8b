"""The fast exact HTM field (issue 20) against the readable reference it replaces.

* :func:`errormap.chain_kernel.spatial_error` (compiled) vs
  :meth:`errormap.machine_tool.MachineTool.spatial_error` (the numpy matrix chain),
  on random points with multi-turn A, for a simulator truth, the same truth ×100, and element
  values drawn independently of the simulator (other shapes, other magnitudes);
* :meth:`ChainElementSet.values` (one vector-valued spline per axis) vs the per-element splines;
* :class:`HTMField` end to end vs reference values pushed through the reference chain.
"""
import numpy as np
import pytest

from errormap.chain_elements import ChainElementSet
from errormap.elements import AXIS_OF, CONSTANT_ELEMENTS, ELEMENT_NAMES, FUNCTION_ELEMENTS
from errormap.chain_field import ChainField
from errormap.chain_kernel import spatial_error
from errormap.chain_truth import make_chain_truth, random_axes

TOL_CLOSED_FORM_UM = 1e-9
"""Both forms compute tool points of ~0.5 m and subtract the nominal one: one ulp of 500 mm is
5.7e-14 mm = 5.7e-11 μm, so a few ulps of round-off in either chain stays well below 1e-9 μm
(observed 7e-12 μm on a simulator truth, 3e-11 μm on the same truth ×100, ~19 mm errors)."""
TOL_SPLINE_REL = 1e-13
"""The per-axis spline solves the same banded interpolation problem per column: equal up to
float64 round-off relative to the largest element value (observed bit-identical)."""


def _axes_multi_turn(machine, n, seed):
    rng = np.random.default_rng(seed)
    ax = random_axes(machine, n, rng)
    ax[:, 2] += 360.0 * rng.integers(-4, 5, n)  # A from -4 to +5 turns
    return ax


def _independent_elements(machine, seed):
    """Element values not shaped by the simulator: sums of random harmonics up to ±500 μm/μrad,
    8 stations per axis (not the simulator's 21), closed A profiles, non-zero constants."""
    rng = np.random.default_rng(seed)
    st = {k: np.linspace(*machine.strokes[k], 8) for k in ("x_mm", "z_mm", "a_deg")}
    st["a_deg"] = np.linspace(st["a_deg"][0], st["a_deg"][0] + 360.0, 8)
    fun = {}
    for k in FUNCTION_ELEMENTS:
        u = (st[AXIS_OF[k]] - st[AXIS_OF[k]][0]) / np.ptp(st[AXIS_OF[k]])
        amp, f, ph = rng.uniform(-500, 500, 3), rng.integers(1, 4, 3), rng.uniform(0, 2 * np.pi, 3)
        fun[k] = sum(amp[j] * np.sin(2 * np.pi * f[j] * u + ph[j]) for j in range(3))
        fun[k] = fun[k] - fun[k][0]
    return ChainElementSet(machine, st, fun, {k: float(rng.uniform(-300, 300)) for k in CONSTANT_ELEMENTS})


def _element_spline(el, k):
    """The reference interpolation of one function element: its own cubic spline through its stations
    (periodic in A), independent of the element set's per-axis vector splines."""
    from scipy.interpolate import make_interp_spline
    return make_interp_spline(el.stations[AXIS_OF[k]], el.functions[k], k=3,
                              bc_type="periodic" if AXIS_OF[k] == "a_deg" else None)


@pytest.mark.parametrize("case", ["truth", "truth_x100", "independent"])
def test_closed_form_equals_matrix_chain(grinder, case):
    el = (_independent_elements(grinder, 7) if case == "independent"
          else make_chain_truth(grinder, 3).elements.scaled(100.0 if case == "truth_x100" else 1.0))
    axes = _axes_multi_turn(grinder, 4000, 11)
    v = el.values(axes)
    ref = grinder.spatial_error(axes, v)
    new = spatial_error(grinder, axes, v)
    assert np.abs(ref).max() > 10.0  # a real field, not zeros
    np.testing.assert_allclose(new, ref, rtol=0, atol=TOL_CLOSED_FORM_UM)


def test_axis_splines_equal_per_element_splines(grinder):
    for el in (make_chain_truth(grinder, 5).elements, _independent_elements(grinder, 8)):
        axes = _axes_multi_turn(grinder, 3000, 12)
        cols = {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": el.wrap("a_deg", axes[:, 2])}
        ref = np.stack([_element_spline(el, k)(cols[AXIS_OF[k]]) for k in FUNCTION_ELEMENTS], axis=1)
        v = el.values(axes)
        tol = TOL_SPLINE_REL * np.abs(ref).max()
        np.testing.assert_allclose(v[:, :len(FUNCTION_ELEMENTS)], ref, rtol=0, atol=tol)
        for j, k in enumerate(CONSTANT_ELEMENTS, start=len(FUNCTION_ELEMENTS)):
            assert np.all(v[:, j] == el.constants[k])
        assert v.shape == (len(axes), len(ELEMENT_NAMES))


def test_field_equals_reference_pipeline_and_periodic_in_a(grinder):
    el = make_chain_truth(grinder, 9).elements
    axes = _axes_multi_turn(grinder, 2000, 13)
    cols = {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": el.wrap("a_deg", axes[:, 2])}
    v_ref = np.stack([_element_spline(el, k)(cols[AXIS_OF[k]]) for k in FUNCTION_ELEMENTS]
                     + [np.full(len(axes), el.constants[k]) for k in CONSTANT_ELEMENTS], axis=1)
    field = ChainField(grinder, el)
    np.testing.assert_allclose(field.predict(axes), grinder.spatial_error(axes, v_ref),
                               rtol=0, atol=TOL_CLOSED_FORM_UM)
    # whole turns of A leave the error unchanged (to the round-off of cos/sin of large angles)
    shifted = axes.copy()
    shifted[:, 2] -= 360.0 * np.round(shifted[:, 2] / 360.0)
    np.testing.assert_allclose(field.predict(shifted), field.predict(axes), rtol=0, atol=TOL_CLOSED_FORM_UM)


def test_values_shape_is_checked(grinder):
    with pytest.raises(ValueError, match="expected slot values of shape"):
        spatial_error(grinder, np.zeros((3, 3)), np.zeros((3, 22)))


FD_STEP = 1e-3
"""Central-difference step (mm, mm, deg) for checking the closed-form Jacobian."""
TOL_JACOBIAN = 1e-5
"""μm per (mm, mm, deg). Central differences with step h err by ~h²/6·|E'''| (truncation) plus
~1e-10 μm / h (round-off of E): at h = 1e-3 observed ≤ 2.4e-6 on the ×100 truth and the
independent elements (|J| up to ~350), 1.1e-7 on the plain truth; the error shrinks 100× from
h = 1e-2 to 1e-3, i.e. it is the differences' truncation, not the closed form. A missing term
of the chain (a spline slope through a lever arm, a product of two element angles on the
×100 field) is 1e-3 or more."""


@pytest.mark.parametrize("case", ["truth", "truth_x100", "independent"])
def test_closed_form_jacobian_matches_finite_differences(grinder, case):
    el = (_independent_elements(grinder, 7) if case == "independent"
          else make_chain_truth(grinder, 3).elements.scaled(100.0 if case == "truth_x100" else 1.0))
    field = ChainField(grinder, el)
    axes = _axes_multi_turn(grinder, 3000, 11)
    E, J = field.predict_and_jacobian(axes)
    np.testing.assert_allclose(E, field.predict(axes), rtol=0, atol=TOL_CLOSED_FORM_UM)
    fd = np.empty_like(J)
    for k in range(3):
        d = np.zeros(3)
        d[k] = FD_STEP
        fd[:, :, k] = (field.predict(axes + d) - field.predict(axes - d)) / (2 * FD_STEP)
    assert np.abs(J).max() > 1.0  # a real slope
    np.testing.assert_allclose(J, fd, rtol=0, atol=TOL_JACOBIAN)
    np.testing.assert_array_equal(field.jacobian(axes), J)


def test_jacobian_is_float64_only(grinder):
    el = make_chain_truth(grinder, 0).elements
    with pytest.raises(ValueError, match="float64"):
        ChainField(grinder, el).predict_and_jacobian(np.zeros((2, 3)), dtype=np.float32)
