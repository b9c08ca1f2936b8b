"""Nominal kinematics: closed form equals the transform chains; FK∘IK is the identity."""
import numpy as np

from errormap.grinder_file import rho0_mm
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st


from errormap.chain_kernel import forward, inverse
from errormap.transforms import rot_x, rot_z

TOL_MM = 1e-9


def chain_tool_point(m, x, z, a_deg):
    """Direct 4x4 evaluation of p = T_work⁻¹ · T_tool · origin (docs/explanation/kinematics.md)."""
    def T(R=np.eye(3), t=(0, 0, 0)):
        M = np.eye(4); M[:3, :3] = R; M[:3, 3] = t
        return M
    tool = (T(rot_z(np.deg2rad(m.geometry["theta1_deg"]))[0]) @ T(t=(m.geometry["l2"], 0, m.geometry["l1"])) @ T(t=(0, 0, z))
            @ T(t=(m.geometry["l3"], 0, m.geometry["l4"])) @ T(t=(0, 0, -m.geometry["R"])))
    work = T(t=(m.geometry["l5"], 0, m.geometry["l6"])) @ T(t=(x, 0, 0)) @ T(t=(m.geometry["l7"], 0, m.geometry["l8"])) @ T(rot_x(np.deg2rad(a_deg))[0])
    return (np.linalg.inv(work) @ tool @ np.array([0, 0, 0, 1.0]))[:3]


def test_closed_form_matches_chains(grinder, rng):
    axes = np.c_[rng.uniform(0, 200, 20), rng.uniform(0, 60, 20), rng.uniform(-720, 720, 20)]
    p = forward(grinder, axes)
    for k in range(len(axes)):
        np.testing.assert_allclose(p[k], chain_tool_point(grinder, *axes[k]), atol=TOL_MM)
    # the nominal formula of docs/explanation/kinematics.md
    rho = rho0_mm(grinder) + axes[:, 1]
    a = np.deg2rad(axes[:, 2])
    np.testing.assert_allclose(p, np.c_[-(grinder.geometry["l5"] + grinder.geometry["l7"] + axes[:, 0]), rho * np.sin(a), rho * np.cos(a)], atol=TOL_MM)
    # and the zero-error exact HTM model
    np.testing.assert_allclose(grinder.tool_point(axes, np.zeros((20, 23))), p, atol=TOL_MM)


@settings(max_examples=200, deadline=None)
@given(x=st.floats(0, 200), z=st.floats(0, 60), a=st.floats(0, 359.999))
def test_fk_ik_identity_single_points(grinder, x, z, a):
    axes = np.array([[x, z, a]])
    back = inverse(grinder, forward(grinder, axes), unwrap=False)
    assert abs(back[0, 0] - x) < TOL_MM and abs(back[0, 1] - z) < TOL_MM
    da = (back[0, 2] - a + 180.0) % 360.0 - 180.0
    assert abs(da) < 1e-7


def test_fk_ik_identity_multi_turn_path(grinder):
    # 7 turns, A running 0 → 2520°, radius growing, x advancing
    u = np.linspace(0, 1, 2801)
    axes = np.c_[20 + 150 * u, 0.2 + 0.3 * u, 2520.0 * u]
    back = inverse(grinder, forward(grinder, axes), unwrap=True)
    np.testing.assert_allclose(back, axes, atol=1e-7)
    assert back[-1, 2] == pytest.approx(2520.0, abs=1e-7)


def test_fk_ik_path_starting_above_a_turn(grinder):
    axes = np.c_[np.full(50, 10.0), np.full(50, 5.0), np.linspace(400, 700, 50)]
    back = inverse(grinder, forward(grinder, axes), unwrap=True, a_start_deg=400.0)
    np.testing.assert_allclose(back, axes, atol=1e-7)


def test_ik_with_tool_off_the_manual_axis(tmp_path, grinder, rng):
    from errormap.machine import builtin_machine_path, load_machine
    p = tmp_path / "m.toml"
    p.write_text(builtin_machine_path().read_text().replace("l3 = -160.0", "l3 = -150.0"))
    m = load_machine(p)
    axes = np.c_[rng.uniform(0, 200, 30), rng.uniform(0, 60, 30), rng.uniform(0, 359, 30)]
    np.testing.assert_allclose(inverse(m, forward(m, axes), unwrap=False), axes, atol=1e-7)
