"""The learned field's inference side: fast paths against references, the A seam closure (issue 4)."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.func import jvp

from compensation.solvers import solve
from errormap.chain_kernel import forward
from errormap.machine import load_machine
from training.model import MLPField, wrap_a

TOL_REL = 1e-12        # fast float64 paths vs references: float64 rounding (relative to the field's max)
TOL_JAC_REL = 1e-10    # hand forward-mode Jacobian vs torch.func.jvp, relative to max |J|
TOL_F32_UM = 1e-3      # float32 predict vs float64 on a ~50 μm field (GA needs ~0.01 μm)
TOL_SEAM_UM = 1e-9     # predict at a and a + 360 (and at both ends of the turn): float precision
EXACT_TOL_UM = 1e-6


@pytest.fixture(scope="module")
def machine():
    return load_machine(None)


def make_model(enc="raw", act="sigmoid", seed=0, hidden=(10, 15, 25, 15, 10)):
    """A random (untrained) network with scalers from a full-turn grid: a non-periodic raw-A field."""
    rng = np.random.default_rng(seed)
    axes = np.column_stack([rng.uniform(0, 200, 300), rng.uniform(0, 60, 300), rng.uniform(0, 360, 300)])
    axes[:2, 2] = [0.0, 360.0]
    m = MLPField(hidden, act, enc).fit_scalers(axes, rng.normal(0.0, 20.0, (300, 3)))
    m.theta_ = m.init_params(seed)
    return m


def reference_predict(m, axes):
    """The bare network through ``forward`` (no seam correction)."""
    with torch.no_grad():
        y = m.forward(m.theta_, torch.from_numpy(m.features(axes))).numpy()
    return m.unscale_errors(y)


def jvp_reference(m, axes):
    """The slow reference Jacobian: ``torch.func.jvp`` on ``m.forward`` of the scaled raw axes, (n, 3, 3),
    with the seam correction of the raw A input."""
    theta, a = m.theta_, wrap_a(axes[:, 2], m.a0_deg_)
    lo, hi = (torch.as_tensor(v, dtype=torch.float64) for v in (m.in_lo_, m.in_hi_))

    def net(x):
        u = 2.0 * (x - lo) / (hi - lo) - 1.0
        if m.a_encoding == "periodic":
            r = torch.deg2rad(x[:, 2])
            u = torch.stack([u[:, 0], u[:, 1], torch.cos(r), torch.sin(r)], dim=1)
        return m.forward(theta, u)

    def jac_and_val(x_np):
        x = torch.from_numpy(np.ascontiguousarray(x_np))
        cols = []
        with torch.no_grad():
            for k in range(3):
                t = torch.zeros_like(x)
                t[:, k] = 1.0
                y, dy = jvp(net, (x,), (t,))
                cols.append(dy.numpy())
        return y.numpy() * m.out_scale_ + m.out_mean_, np.stack(cols, axis=2) * m.out_scale_

    x = np.column_stack([axes[:, 0], axes[:, 1], a])
    e, J = jac_and_val(x)
    w = m._seam_window()
    t = (a - (m.a0_deg_ + 360.0 - w)) / w if w else np.zeros(len(a))
    s = t > 0
    if s.any():
        e0, J0 = jac_and_val(np.column_stack([x[s, :2], np.full(s.sum(), m.a0_deg_)]))
        e1, J1 = jac_and_val(np.column_stack([x[s, :2], np.full(s.sum(), m.a0_deg_ + 360.0)]))
        ts = t[s]
        J[s, :, :2] += (ts * ts * (3 - 2 * ts))[:, None, None] * (J0 - J1)[:, :, :2]
        J[s, :, 2] += (e0 - e1) * (6 * ts * (1 - ts) / w)[:, None]
    return J


def inside_turn(n, lo, hi, seed=1):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0, 200, n), rng.uniform(0, 60, n), rng.uniform(lo, hi, n)])


@pytest.mark.parametrize("enc", ["raw", "periodic"])
@pytest.mark.parametrize("act", ["sigmoid", "tanh", "softplus"])
@pytest.mark.parametrize("n", [7, 5000])  # small (one thread) and large (blocked) batches
def test_fast_predict_equals_forward(enc, act, n):
    m = make_model(enc, act)
    w = m.SEAM_WINDOW_DEG if enc == "raw" else 0.0
    axes = inside_turn(n, 0.0, 360.0 - w)  # outside the seam ramp: the bare network
    ref = reference_predict(m, axes)
    assert np.abs(m.predict(axes) - ref).max() <= TOL_REL * np.abs(ref).max()


@pytest.mark.parametrize("enc", ["raw", "periodic"])
@pytest.mark.parametrize("act", ["sigmoid", "tanh", "softplus"])
def test_hand_jacobian_equals_torch_func(enc, act):
    m = make_model(enc, act)
    axes = inside_turn(3000, -400.0, 800.0)  # multi-turn, seam ramp included
    e, J = m.predict_and_jacobian(axes)
    Jr = jvp_reference(m, axes)
    assert np.abs(J - Jr).max() <= TOL_JAC_REL * np.abs(Jr).max()
    assert np.array_equal(e, m.predict(axes)) and np.array_equal(J, m.jacobian(axes))


@pytest.mark.parametrize("enc", ["raw", "periodic"])
def test_float32_path_is_close_to_float64(enc):
    m = make_model(enc)
    axes = inside_turn(4000, 0.0, 720.0)
    e64, e32 = m.predict(axes), m.predict(axes, dtype=np.float32)
    assert e32.dtype == np.float64 and np.abs(e32 - e64).max() <= TOL_F32_UM


def test_small_batches_restore_the_thread_count():
    m = make_model()
    old = torch.get_num_threads()
    m.predict(inside_turn(5, 0, 360))
    m.predict_and_jacobian(inside_turn(5, 0, 360))
    assert torch.get_num_threads() == old


def test_seam_closure_makes_raw_a_periodic_and_continuous():
    m = make_model("raw")
    xz = inside_turn(200, 0, 1)[:, :2]
    a0 = m.a0_deg_

    def at(a):
        return m.predict(np.column_stack([xz, np.full(len(xz), a)]))

    # the bare network is not periodic (that is what the correction is for)
    bare = reference_predict(m, np.column_stack([xz, np.full(len(xz), a0)]))
    bare_end = reference_predict(m, np.column_stack([xz, np.full(len(xz), a0 + 360.0)]))
    assert np.abs(bare - bare_end).max() > 0.1
    # corrected: both ends of the turn agree, and a, a + 360 agree
    assert np.abs(at(a0) - at(a0 + 360.0)).max() <= TOL_SEAM_UM
    for a in (0.5, 123.0, 345.0, 359.999):
        assert np.abs(at(a) - at(a + 360.0)).max() <= TOL_SEAM_UM
        assert np.abs(at(a) - at(a - 720.0)).max() <= TOL_SEAM_UM
    # continuous across A = 360°·k: a step of 2ε changes E by about |dE/da|·2ε
    eps = 1e-6
    slope = np.abs(m.jacobian(np.column_stack([xz, np.full(len(xz), a0 + 360.0)]))[:, :, 2]).max()
    assert np.abs(at(a0 + 360.0 - eps) - at(a0 + 360.0 + eps)).max() <= 4 * eps * slope + TOL_SEAM_UM
    # and the correction is the seam mismatch, no more: |E - N| ≤ |N(a0) - N(a0 + 360)|
    axes = np.column_stack([xz, np.full(len(xz), a0 + 350.0)])
    assert np.all(np.abs(m.predict(axes) - reference_predict(m, axes)) <= np.abs(bare - bare_end) + 1e-12)


def test_seam_jacobian_matches_central_differences():
    m = make_model("raw")
    axes = inside_turn(50, 335.0, 359.9)  # inside the ramp
    J = m.jacobian(axes)
    h = 1e-5
    fd = np.stack([(m.predict(axes + np.eye(3)[k] * h) - m.predict(axes - np.eye(3)[k] * h)) / (2 * h)
                   for k in range(3)], axis=2)
    assert np.abs(J - fd).max() <= 1e-6 * np.abs(fd).max()


def test_exact_solves_a_multi_turn_path_across_the_seam(machine):
    """A helix over 3 turns through A = 360°·k on a raw-A network: no failures with the closure."""
    m = make_model("raw", seed=3)
    dense = np.concatenate([np.linspace(k - 0.5, k + 0.5, 101) for k in (360.0, 720.0, 1080.0)])
    a = np.sort(np.concatenate([np.linspace(300.0, 1140.0, 841), dense]))
    axes_d = np.column_stack([np.linspace(40, 60, a.size), np.full(a.size, 2.0), a])  # ρ ≈ 2 mm: ~1° corrections
    targets = forward(machine, axes_d)
    r = solve("exact", m, targets, machine, target_axes=axes_d, progress=False)
    assert r.success.all(), np.flatnonzero(~r.success)
    assert r.residual_norm_um.max() <= EXACT_TOL_UM
    assert np.abs(np.diff(r.axes[:, 2])).max() < 5.0
