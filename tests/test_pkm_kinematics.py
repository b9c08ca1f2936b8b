"""Hexapod kinematics: IK∘FK identity, orientation conventions, machine-file errors, interpolation."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from errormap.machine import MachineFileError, load_machine
from errormap.pkm.hexapod import (KinematicsError, angles_to_rotation, forward_kinematics, inverse_kinematics,
                                  quat_to_rotation, tool_axis_euler, tool_axis_to_rotation, workspace_poses)
from errormap.pkm.machine_file import pair_angle_from_side_ratio
from compensation.pkm_interpolation import (_with_tool, circular_move, contour_step_mm, hyperboloid_pass, leg_program,
                                            linear_move, sphere_pass)

FK_POSITION_TOL_MM = 1e-7
FK_ROTATION_TOL = 1e-9
GEOMETRY_TOL = 1e-9


@pytest.fixture(scope="module")
def hexapod():
    return load_machine(expect_kind="hexapod")


def test_default_geometry_matches_paper(hexapod):
    r_b = np.linalg.norm(hexapod.base_joints_mm, axis=1)
    r_p = np.linalg.norm(hexapod.platform_joints_mm, axis=1)
    assert np.allclose(r_b, 500.0, atol=GEOMETRY_TOL) and np.allclose(r_p, 400.0, atol=GEOMETRY_TOL)
    for j in (hexapod.base_joints_mm, hexapod.platform_joints_mm):
        sides = np.linalg.norm(j - np.roll(j, -1, axis=0), axis=1)
        assert sides.min() / sides.max() == pytest.approx(0.365, abs=GEOMETRY_TOL)
    assert pair_angle_from_side_ratio(0.365) == pytest.approx(29.93212, abs=1e-4)
    assert hexapod.leg_min_mm[0] == 600.0 and hexapod.leg_max_mm[0] == 1500.0


def test_ik_fk_identity(hexapod):
    tips, R = workspace_poses(hexapod, 300, seed=3, max_tilt_deg=25.0)
    legs = inverse_kinematics(hexapod, tips, R)
    fk = forward_kinematics(hexapod, legs)
    assert fk.success.all()
    assert np.max(np.abs(fk.x - tips)) < FK_POSITION_TOL_MM
    assert np.max(np.abs(fk.platform2base - R)) < FK_ROTATION_TOL
    assert np.max(np.abs(inverse_kinematics(hexapod, fk.x, fk.platform2base) - legs)) < FK_POSITION_TOL_MM


def test_fk_fails_clearly_out_of_range(hexapod):
    legs = np.full((2, 6), 1000.0)
    legs[1, 2] = 1600.0
    with pytest.raises(KinematicsError, match=r"rows \[1\]"):
        forward_kinematics(hexapod, legs)


def test_tool_axis_convention_no_spin():
    axes = np.array([[0.3, 0.2, 0.9], [0.3, -0.2, 0.9], [-0.1, 0.4, 0.8], [0.0, 0.0, 1.0]])
    R = tool_axis_to_rotation(axes)
    unit = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    assert np.allclose(R[:, :, 2], unit, atol=GEOMETRY_TOL)  # last column = tool axis
    e = tool_axis_euler(axes)
    assert np.allclose(e[:, 2], -e[:, 0])  # gamma = -alpha
    # no spin: the rotation axis is horizontal (a pure tilt)
    rv = Rotation.from_matrix(R[:3]).as_rotvec()
    assert np.allclose(rv[:, 2], 0.0, atol=GEOMETRY_TOL)
    # the paper's sign rule: beta negative when n_y >= 0
    assert e[0, 1] < 0 < e[1, 1]


def test_angles_and_quaternions_agree():
    ang = np.array([[10.0, -5.0, 30.0]])
    R = angles_to_rotation(ang)
    q = Rotation.from_euler("xyz", ang, degrees=True).as_quat()  # qx qy qz qw
    assert np.allclose(quat_to_rotation(q), R, atol=GEOMETRY_TOL)
    Rz, Ry, Rx = (Rotation.from_euler(a, v, degrees=True).as_matrix() for a, v in (("z", 30), ("y", -5), ("x", 10)))
    assert np.allclose(R[0], Rz @ Ry @ Rx, atol=GEOMETRY_TOL)  # fixed-axis X then Y then Z


def test_machine_file_errors_name_key(tmp_path, hexapod):
    p = tmp_path / "h.toml"
    p.write_text('[machine]\nkind = "hexapod"\n[geometry]\nbase_radius_mm = 500.0\nplatform_radius_mm = 400.0\n'
                 'base_side_ratio = 0.365\nplatform_side_ratio = 0.365\ntool_length_mm = 30.0\nbogus = 1\n'
                 '[legs]\nmin_mm = 600.0\nmax_mm = 1500.0\n')
    with pytest.raises(MachineFileError, match="geometry.bogus"):
        load_machine(p)
    p.write_text('[machine]\nkind = "hexapod"\n[geometry]\nbase_joints_mm = [[1,2,3]]\nplatform_joints_mm = [[1,2,3]]\n'
                 'tool_length_mm = 30.0\n[legs]\nmin_mm = 600.0\nmax_mm = 1500.0\n')
    with pytest.raises(MachineFileError, match=r"geometry.base_joints_mm.*shape"):
        load_machine(p)
    # explicit joints reproduce the radii layout
    b, a = hexapod.base_joints_mm.tolist(), hexapod.platform_joints_mm.tolist()
    p.write_text(f'[machine]\nkind = "hexapod"\n[geometry]\nbase_joints_mm = {b}\nplatform_joints_mm = {a}\n'
                 'tool_length_mm = 30.0\n[legs]\nmin_mm = 600.0\nmax_mm = 1500.0\nscale = 2.0\noffset_mm = 100.0\n')
    m = load_machine(p)
    assert np.allclose(m.base_joints_mm, hexapod.base_joints_mm)
    assert np.allclose(m.drive_to_legs(np.array([[450.0] * 6])), 1000.0)


def test_interpolation_steps(hexapod):
    f = contour_step_mm(1200.0, 4.0)  # 20 mm/s * 4 ms
    assert f == pytest.approx(0.08)
    tips, _ = linear_move([0, 0, 980], [10, 0, 980], 0.08)
    assert np.allclose(np.diff(tips[:, 0])[:-1], 0.08) and np.allclose(tips[-1], [10, 0, 980])
    arc = circular_move([0, 0, 880], [0, 0, 980], [1, 0, 0], 30.0, 0.5)
    assert np.allclose(np.linalg.norm(arc - [0, 0, 880], axis=1), 100.0)
    steps = np.linalg.norm(np.diff(arc, axis=0), axis=1)
    assert steps.max() <= 0.5 + 1e-9
    for path in (sphere_pass(2.0), hyperboloid_pass(2.0)):
        prog = leg_program(hexapod, path)
        assert np.all(prog.legs_mm > 600) and np.all(prog.legs_mm < 1500)
        assert np.allclose(np.cumsum(prog.increments_mm, axis=0) + prog.legs_mm[0], prog.legs_mm)
        fk = forward_kinematics(_with_tool(hexapod, path), prog.legs_mm)
        assert np.max(np.abs(fk.x - path.tip_mm)) < FK_POSITION_TOL_MM
    sph = sphere_pass(2.0)
    normal = (sph.tip_mm - [0, 0, 880]) / 100.0
    assert np.allclose(sph.platform2base[:, :, 2], normal, atol=GEOMETRY_TOL)
