"""The compiled kernels' fast paths against the forms they replace (errormap/chain_kernel.py): the
small-angle cosine and sine against the library's, the spline interval search on unevenly spaced
stations against the numpy reference field, and the compiled closed-form inverse against the chain's
numpy closed form (errormap/machine_tool.py ``closed_form_inverse``)."""

import numpy as np
import pytest
from numba import njit

from errormap.chain_kernel import forward, inverse
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from chain_reference import predict_and_jacobian_numpy, predict_numpy
from errormap.chain_kernel import SMALL_ANGLE_RAD, CompiledChain, _cos_sin, closed_form_solver

from chain_fixtures import axes_beyond_strokes, grinder_variant

TOL_KERNEL_UM = 1e-9
"""The kernel against the numpy reference field: same transforms, different operation order (as
tests/test_chain_kernel.py): one ulp of a 1 m tool point is 1.1e-10 μm; observed ≤ 3.2e-10 μm on these
uneven element sets (errors up to ~800 μm beyond the strokes), the same before this kernel's
interval search."""
TOL_KERNEL_JAC = 1e-9
"""Axis Jacobians against the numpy reference: round-off only (as tests/test_chain_kernel.py)."""
TOL_INVERSE_MM = 1e-11
"""Compiled closed-form inverse vs the numpy one: the same closed form with the two roots by the
angle-addition rule instead of acos/cos/sin. Compared where it is well conditioned: the linear axes
(mm) and the tool point the axes reach (mm; the angle alone is ill-conditioned near the rotary axis,
where one ulp of a 200 mm point turns it by ulp/ρ). Round-off of ~500 mm sums, one ulp 5.7e-14 mm;
observed ≤ 4e-13 mm."""


@njit(cache=False)
def _cos_sin_array(x, c, s):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        c[i], s[i] = _cos_sin(x[i])


@njit(cache=False)
def _library_array(x, c, s):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        c[i], s[i] = np.cos(x[i]), np.sin(x[i])


def test_small_angle_cos_sin_is_the_librarys_bit_for_bit():
    """The series below SMALL_ANGLE_RAD gives the library's cosine and sine exactly (μrad error
    angles and the range up to the switch, log-spread down to 1e-300, both signs, the ends)."""
    rng = np.random.default_rng(5)
    n = 200_000
    x = np.concatenate([rng.uniform(-SMALL_ANGLE_RAD, SMALL_ANGLE_RAD, n),
                        np.exp(rng.uniform(np.log(1e-300), np.log(SMALL_ANGLE_RAD), n)) * rng.choice([-1.0, 1.0], n),
                        rng.normal(0.0, 100e-6, n),
                        [0.0, -0.0, SMALL_ANGLE_RAD, -SMALL_ANGLE_RAD, np.nextafter(SMALL_ANGLE_RAD, 0.0), 0.5, 3.0]])
    c, s, c0, s0 = (np.empty_like(x) for _ in range(4))
    _cos_sin_array(x, c, s)
    _library_array(x, c0, s0)
    np.testing.assert_array_equal(c, c0)
    np.testing.assert_array_equal(s, s0)


def _uneven_elements(mt, seed, n_stations=9):
    """Random element values at unevenly spaced stations (the interval search's guess from the mean
    spacing is then wrong by several intervals), full-turn axes closed."""
    rng = np.random.default_rng(seed)
    z = ChainElementSet.zeros(mt, n_stations)
    stations = {}
    for a in mt.axes:
        if a.column not in z.stations:
            continue
        lo, hi = a.stroke
        u = (np.arange(1, n_stations - 1) + rng.uniform(-0.45, 0.45, n_stations - 2)) / (n_stations - 1)
        stations[a.column] = np.concatenate([[lo], lo + (hi - lo) * u ** 1.5, [hi]])  # crowded at the low end
    full = {a.word for a in mt.axes if a.full_turn}
    fun = {}
    for s in mt.slots:
        if s.is_function:
            f = rng.normal(0.0, 40.0, n_stations)
            if s.axis in full:
                f[-1] = f[0]
            fun[s.name] = f
    return ChainElementSet(mt, stations, fun, {k: rng.normal(0.0, 40.0) for k in mt.constant_slots})


@pytest.mark.parametrize("name", ["grinder-chain", "mill-xyz", "five-axis-ac"])
def test_kernel_on_uneven_stations_equals_numpy_reference(name):
    mt = load_machine(name)
    el = _uneven_elements(mt, 21)
    rng = np.random.default_rng(22)
    ax = axes_beyond_strokes(mt, rng, 1000, 0.05, 2)
    for col, st in el.stations.items():  # exactly on every station, where the interval changes
        j = mt.axis_columns.index(col)
        ax[:len(st), j] = st
    cc = CompiledChain(mt, el)
    E1, J1 = cc.predict_and_jacobian(ax)
    _, J0 = predict_and_jacobian_numpy(mt, el, ax)
    E0 = predict_numpy(mt, el, ax)
    assert np.abs(cc.predict(ax) - E0).max() < TOL_KERNEL_UM
    assert np.abs(E1 - E0).max() < TOL_KERNEL_UM
    assert np.abs(J1 - J0).max() < TOL_KERNEL_JAC


@pytest.mark.parametrize("theta1_deg", [None, 7.0])
def test_compiled_closed_form_inverse_equals_numpy_form(theta1_deg):
    """Inside the strokes, beyond them, on several turns and on the rotary axis itself."""
    m = load_machine()
    m = m if theta1_deg is None else grinder_variant({"theta1_deg": theta1_deg, "l3": -150.0})
    mt = m
    rng = np.random.default_rng(9)
    span = m.stroke_hi - m.stroke_lo
    ax = rng.uniform(m.stroke_lo - 0.3 * span, m.stroke_hi + 0.3 * span, (50_000, 3))
    ax[:, 2] += 360.0 * rng.integers(-3, 4, len(ax))
    p = forward(m, ax)
    p[:5, 1:] = 0.0  # on the A axis: A undefined, 0
    ref = mt.closed_form_inverse()(p)
    got = closed_form_solver(mt)(p)
    assert np.abs(got[:, :2] - ref[:, :2]).max() < TOL_INVERSE_MM
    assert np.abs(forward(m, got) - forward(m, ref)).max() < TOL_INVERSE_MM
    folded = inverse(m, p, unwrap=False)
    a_lo = m.strokes["a_deg"][0]
    assert np.all((folded[:, 2] >= a_lo) & (folded[:, 2] < a_lo + 360.0))
    assert np.abs(folded[:, :2] - ref[:, :2]).max() < TOL_INVERSE_MM
    assert np.abs(forward(m, folded) - forward(m, ref)).max() < TOL_INVERSE_MM
    # a path: unwrapped A continuous and the first point on the stroke's turn, as the numpy form
    path = forward(m, np.column_stack([np.full(2000, 50.0), np.full(2000, 30.0), np.linspace(-400.0, 900.0, 2000)]))
    q = inverse(m, path)
    q_ref = mt.inverse_closed(path)
    assert np.abs(q - q_ref).max() < TOL_INVERSE_MM  # away from the A axis the angle is well conditioned
    assert np.abs(np.diff(q[:, 2])).max() < 1.0
    assert a_lo <= q[0, 2] < a_lo + 360.0
    np.testing.assert_allclose(forward(m, q), path, rtol=0, atol=TOL_INVERSE_MM)
