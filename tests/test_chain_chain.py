"""Machine tools as chain files (issue 26): the chain engine's machine-tool extensions, the grinder
reproduced from its chain file, the mill against a hand-written HTM, Jacobians against finite
differences, the generic element set and field."""

import numpy as np
import pytest

from errormap.chain import Chain, Joint, et, inverted
from errormap.elements import A_ELEMENTS, CONSTANT_ELEMENTS, ELEMENT_NAMES, FUNCTION_ELEMENTS
from errormap.field import check_field
from errormap.chain_field import ChainField
from errormap.chain_kernel import error_jacobian, spatial_error
from errormap.io import InputError
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet

TOL_EQUIV_UM = 1e-9
"""Two exact evaluations of the same transforms in different operation order: tool points of
~0.5–1 m, one ulp of 1000 mm is 1.1e-13 mm = 1.1e-10 μm; a few ulps stay below 1e-9 μm (observed
2.8e-10 μm on the grinder with ±60 μm / μrad elements)."""
TOL_JAC_EQUIV = 1e-9
"""Axis Jacobians (μm per mm / per deg, values up to ~1e2) of two exact forms: round-off only
(observed 5e-12)."""
TOL_FD_REL = 1e-5
"""Central differences with a step of 1e-3 mm / 1e-3 deg on cubic splines and trig terms: the
truncation error h²·f'''/6 is ~1e-7 of the Jacobian's scale, cancellation ~1e-13/1e-3 μm; 1e-5
relative to the largest entry leaves a margin of 100."""
N_EQUIV = 100_000
"""The issue's equivalence sample."""


def _grinder_elements(machine, seed, scale_um=30.0):
    """Random element values (not the simulator's): ±scale per station, closed A profiles,
    non-zero constants."""
    rng = np.random.default_rng(seed)
    el = ChainElementSet.zeros(machine)
    fun = {}
    for k in FUNCTION_ELEMENTS:
        v = rng.normal(0.0, scale_um, 21)
        if k in A_ELEMENTS:
            v[-1] = v[0]
        fun[k] = v
    return ChainElementSet(machine, el.stations, fun, {k: rng.normal(0.0, scale_um) for k in CONSTANT_ELEMENTS},
                           machine.name, machine.sha256)


def _grinder_axes(machine, n, seed):
    rng = np.random.default_rng(seed)
    ax = rng.uniform(machine.stroke_lo, machine.stroke_hi, (n, 3))
    ax[:, 2] += 360.0 * rng.integers(-2, 3, n)  # multi-turn A
    return ax


# -- the chain engine ---------------------------------------------------------------------------
def test_inverted_ets_give_the_inverse_transform():
    rng = np.random.default_rng(3)
    ets = [et("tx", 12.0), et("rz", 0.4), et("ty", 0.0, joint=0), et("rx", -0.3), et("tz", 7.0)]
    ch = Chain.compile(ets, (Joint("q", "prismatic", -10, 10),))
    inv = Chain.compile(inverted(ets), (Joint("q", "prismatic", -10, 10),))
    q = rng.uniform(-10, 10, (50, 1))
    prod = np.einsum("nij,njk->nik", ch.fk(q), inv.fk(q))
    np.testing.assert_allclose(prod, np.broadcast_to(np.eye(4), prod.shape), atol=1e-12)


def test_shared_slot_with_coefficients_and_per_pose_errors():
    """A slot in two ETs (+c, -c) and per-pose values: error Jacobian = finite differences; per-pose
    values equal to a constant vector give the constant path's result."""
    ets = [et("ry", 0.0, slot="s", coef=1e-6), et("tz", 0.0, joint=0), et("ry", 0.0, slot="s", coef=-1e-6),
           et("tx", 0.0, slot="d", coef=1e-3), et("tz", 100.0)]
    ch = Chain.compile(ets, (Joint("z", "prismatic", 0, 500),), shared_slots=True)
    assert ch.param_names == ("s", "d") and not ch.plain_slots
    with pytest.raises(ValueError, match="duplicate"):
        Chain.compile(ets, (Joint("z", "prismatic", 0, 500),))
    q = np.linspace(0, 500, 7)[:, None]
    e = np.array([50.0, 3.0])
    np.testing.assert_array_equal(ch.tool_point(q, e), ch.tool_point(q, np.tile(e, (7, 1))))
    # tilt s (μrad) moves the Z motion towards +x by z·sin(s): d(x)/ds = z·1e-6 at s = 0
    J = ch.error_jacobian(q)
    np.testing.assert_allclose(J[:, 0, 0], q[:, 0] * 1e-6, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(J[:, 0, 1], 1e-3, rtol=1e-12)


# -- the grinder from its chain file ------------------------------------------------------------
def test_grinder_chain_file_names_and_axes():
    mt = load_machine("grinder-chain")
    assert mt.slot_names == ELEMENT_NAMES
    assert mt.axis_columns == ("x_mm", "z_mm", "a_deg")
    assert mt.iso_names[-1] == "EB0Z" and mt.iso_names[18:22] == ("EY0A", "EZ0A", "EB0A", "EC0A")
    g = load_machine()
    assert mt.strokes == g.strokes
    for k in ("X", "Z", "A"):
        np.testing.assert_array_equal(mt.targets[k], g.targets[k])


def _grinder_equivalence(n, seed):
    g, mt = load_machine(), load_machine("grinder-chain")
    el = _grinder_elements(g, seed, scale_um=60.0)
    f0 = ChainField(g, el)
    f1 = ChainField(mt, ChainElementSet(mt, el.stations, el.functions, el.constants))
    ax = _grinder_axes(g, n, seed + 1)
    E0, J0 = f0.predict_and_jacobian(ax)
    E1, J1 = f1.predict_and_jacobian(ax)
    assert np.abs(E1 - E0).max() < TOL_EQUIV_UM
    assert np.abs(J1 - J0).max() < TOL_JAC_EQUIV
    # per-pose element values through the chain vs the hand-written exact form
    v = el.values(ax[:2000])
    assert np.abs(mt.spatial_error(ax[:2000], v) - spatial_error(g, ax[:2000], v)).max() < TOL_EQUIV_UM
    # error-transfer Jacobian (first order) vs the hand-written one
    assert np.abs(mt.error_jacobian(ax[:2000]) - error_jacobian(g, ax[:2000])).max() < TOL_JAC_EQUIV


def test_grinder_chain_equals_htm_field():
    _grinder_equivalence(5_000, 11)


def test_grinder_chain_equals_htm_field_100k():  # ~1.5 s: both compiled kernels
    _grinder_equivalence(N_EQUIV, 12)


def test_grinder_element_file_loads_for_the_chain(tmp_path):
    g, mt = load_machine(), load_machine("grinder-chain")
    el = _grinder_elements(g, 5)
    p = el.save(tmp_path / "el.json")
    ce = ChainElementSet.load(p, mt)
    ax = _grinder_axes(g, 500, 6)
    np.testing.assert_array_equal(ce.values(ax), el.values(ax))
    ce.save(tmp_path / "el2.json")
    np.testing.assert_array_equal(ChainElementSet.load(tmp_path / "el2.json", g).values(ax), el.values(ax))
    np.testing.assert_array_equal(ce.scaled(2.0).values(ax), 2.0 * el.values(ax))
    with pytest.raises(InputError, match=r"key 'stations': no 'y_mm'"):   # the grinder's file on another machine
        ChainElementSet.load(p, load_machine("mill-xyz"))


# -- the mill against a hand-written HTM --------------------------------------------------------
def _T(d):
    n = d.shape[0]
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    T[:, :3, 3] = d
    return T


def _R(axis, a):
    n = a.shape[0]
    c, s = np.cos(a), np.sin(a)
    R = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    R[:, i, i], R[:, i, j], R[:, j, i], R[:, j, j] = c, -s, s, c
    return R


def _E(v, names):
    """Trans(δ)·RotX·RotY·RotZ of one axis from its six values (μm, μrad)."""
    d = np.stack([v[names[0]], v[names[1]], v[names[2]]], axis=1) * 1e-3
    return _T(d) @ _R("x", v[names[3]] * 1e-6) @ _R("y", v[names[4]] * 1e-6) @ _R("z", v[names[5]] * 1e-6)


def _mill_by_hand(geo, axes, v):
    """The mill of mill-xyz.toml written out: Y saddle along (sin s_xy, cos s_xy, 0), X table,
    table top; head, Z along (sin s_xz cos s_yz, sin s_yz, cos s_xz cos s_yz), tool. Returns the
    tool point in the workpiece frame (mm), (n, 3)."""
    x, y, z = axes[:, 0], axes[:, 1], axes[:, 2]
    n = x.shape[0]
    sxy, sxz, syz = v["s_xy"] * 1e-6, v["s_xz"] * 1e-6, v["s_yz"] * 1e-6
    ydir = np.stack([np.sin(sxy), np.cos(sxy), np.zeros(n)], axis=1)
    zdir = np.stack([np.sin(sxz) * np.cos(syz), np.sin(syz), np.cos(sxz) * np.cos(syz)], axis=1)
    comp = lambda w: tuple(f"{c}_{w}" for c in ("dx", "dy", "dz", "ex", "ey", "ez"))  # noqa: E731
    work = (_T(ydir * y[:, None]) @ _E(v, comp("y")) @ _T(np.stack([x, 0 * x, 0 * x], 1)) @ _E(v, comp("x"))
            @ _T(np.tile([0.0, 0.0, geo["table_height"]], (n, 1))))
    tool = (_T(np.tile([0.0, 0.0, geo["head_height"]], (n, 1))) @ _T(zdir * z[:, None]) @ _E(v, comp("z"))
            @ _T(np.tile([0.0, 0.0, -geo["tool_length"]], (n, 1))))
    return (np.linalg.inv(work) @ tool)[:, :3, 3]


def test_mill_equals_hand_written_htm():
    mt = load_machine("mill-xyz")
    assert len(mt.function_slots) == 18 and mt.constant_slots == ("s_xy", "s_xz", "s_yz")
    rng = np.random.default_rng(21)
    n = 20_000
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (n, 3))
    vals = rng.normal(0.0, 40.0, (n, len(mt.slots)))
    v = {k: vals[:, j] for j, k in enumerate(mt.slot_names)}
    zero = {k: np.zeros(n) for k in mt.slot_names}
    e_hand = (_mill_by_hand(mt.geometry, ax, v) - _mill_by_hand(mt.geometry, ax, zero)) * 1e3
    assert np.abs(mt.spatial_error(ax, vals) - e_hand).max() < TOL_EQUIV_UM
    assert np.abs(mt.nominal(ax) - _mill_by_hand(mt.geometry, ax, zero)).max() < 1e-9


def _random_chain_elements(mt, seed, scale=25.0, n_stations=9):
    rng = np.random.default_rng(seed)
    z = ChainElementSet.zeros(mt, n_stations)
    fun = {}
    for k in mt.function_slots:
        f = rng.normal(0.0, scale, n_stations)
        ax = next(a for a in mt.axes if a.word == next(s.axis for s in mt.slots if s.name == k))
        if ax.full_turn:
            f[-1] = f[0]
        fun[k] = f
    return ChainElementSet(mt, z.stations, fun, {k: rng.normal(0.0, scale) for k in mt.constant_slots})


@pytest.mark.parametrize("name", ["mill-xyz", "grinder-chain"])
def test_field_jacobian_matches_finite_differences(name):
    mt = load_machine(name)
    f = check_field(ChainField(mt, _random_chain_elements(mt, 31)), mt.axis_columns)
    rng = np.random.default_rng(32)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (200, len(mt.axes)))
    E, J = f.predict_and_jacobian(ax)
    h = 1e-3
    for j in range(len(mt.axes)):
        d = np.zeros(len(mt.axes))
        d[j] = h
        fd = (f.predict(ax + d) - f.predict(ax - d)) / (2 * h)
        assert np.abs(J[:, :, j] - fd).max() < TOL_FD_REL * max(1.0, np.abs(J).max())
    np.testing.assert_allclose(E, f.predict(ax), rtol=0, atol=1e-12)


def test_error_jacobian_is_the_first_order_model():
    """Small elements: the exact error equals J·v to second order in the elements."""
    mt = load_machine("mill-xyz")
    rng = np.random.default_rng(41)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (500, 3))
    for scale in (1.0, 10.0):
        v = rng.normal(0.0, scale, (500, len(mt.slots)))
        lin = np.einsum("nij,nj->ni", mt.error_jacobian(ax), v)
        # second-order remainder: |ε|·(|δ| + |ε|·L) with ε in rad, L ~ 1.5 m reach, in μm
        bound = 10 * (scale * 1e-6) * (scale + scale * 1e-6 * 1.5e6) * len(mt.slots)
        assert np.abs(mt.spatial_error(ax, v) - lin).max() < bound


def test_body_frames_equal_the_grinder_sweep_frames():
    """The body frames and target balls of the grinder's chain against those of the grinder-chain file."""
    g, mt = load_machine(), load_machine("grinder-chain")
    el = _grinder_elements(g, 51, scale_um=60.0)
    ax = _grinder_axes(g, 3000, 52)
    v = el.values(ax)
    for word in ("X", "Z", "A"):
        R0, t0 = g.body_frames(word, ax, v)
        R1, t1 = mt.body_frames(word, ax, v)
        assert np.abs(t1 - t0).max() * 1e3 < TOL_EQUIV_UM
        assert np.abs(R1 - R0).max() < TOL_EQUIV_UM * 1e-3   # a rotation entry × 1 m lever, in μm
        balls = np.einsum("nij,kj->nki", R0, np.asarray(g.targets[word], float)) + t0[:, None, :]
        assert np.abs(mt.target_points(word, ax, v) - balls).max() * 1e3 < TOL_EQUIV_UM


TOL_INVERSE_MM = 1e-9
"""Newton converges quadratically to 1e-10 mm (its stopping tolerance); 1e-9 mm leaves round-off room."""


def test_inverse_grinder_equals_closed_form_and_round_trips():
    from errormap.chain_kernel import forward, inverse
    g, mt = load_machine(), load_machine("grinder-chain")
    rng = np.random.default_rng(61)
    ax = rng.uniform(g.stroke_lo, g.stroke_hi, (2000, 3))
    ax[:, 1] = rng.uniform(5.0, 60.0, 2000)   # off the A axis (ρ > 0): A is defined
    p = forward(g, ax)
    start = ax + rng.normal(0.0, [2.0, 2.0, 3.0], ax.shape)
    q, ok = mt.inverse(p, start)
    assert ok.all()
    assert np.abs(mt.nominal(q) - p).max() < TOL_INVERSE_MM
    closed = inverse(g, p, unwrap=False)
    d = q - closed
    d[:, 2] = (d[:, 2] + 180.0) % 360.0 - 180.0
    assert np.abs(d).max() < 1e-6


def test_inverse_five_axis_keeps_rotary_axes():
    mt = load_machine("five-axis-ac")
    rng = np.random.default_rng(62)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (500, 5))
    p = mt.nominal(ax)
    start = ax.copy()
    start[:, :3] = 0.0
    q, ok = mt.inverse(p, start)
    assert ok.all()
    np.testing.assert_array_equal(q[:, 3:], ax[:, 3:])
    assert np.abs(mt.nominal(q) - p).max() < TOL_INVERSE_MM
    np.testing.assert_allclose(q[:, :3], ax[:, :3], atol=1e-8)

