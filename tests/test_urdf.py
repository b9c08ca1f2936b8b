"""An arm's nominal chain from a URDF (errormap/urdf.py): the UR5/UR10 URDFs written from the published DH
numbers reproduce the built-in tables' kinematics and calibration; an odd URDF (axes along y and -x, a
prismatic joint, fixed joints between) reproduces its own forward kinematics; what a chain cannot
represent is refused naming the element and line; ``--machine robot.urdf`` is recognised by content."""
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from errormap.arm_calibration import fit_model
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.machine import MachineFileError, load_machine
from errormap.urdf import NEARLY_PARALLEL_RAD

DATA = Path(__file__).parent / "data" / "urdf"
FK_TOL_MM = 1e-9
"""The issue's bound: the URDF chain's tool point equals the DH table's (measured 2.3e-13 mm: round-off at 1 m)."""
ROT_TOL = 1e-12    # tool-frame axes, unitless: round-off of a dozen 3x3 products
N_POSES = 500
CAL_POSES = 120
NOISE_MM = 0.02
CAL_TOL_MM = 1e-6
"""Two calibrations of the same data on the same slots from chains equal to 1e-13 mm: their fitted slot values and
predictions agree to far better than this (LM stops at a relative cost change of 1e-10)."""


@pytest.mark.parametrize("name", ["ur5", "ur10"])
def test_urdf_reproduces_the_builtin_dh_chain(name):
    dh = load_machine(name)
    ur = load_machine(DATA / f"{name}-urdf.toml")
    assert ur.param_names == dh.param_names and ur.convention == "urdf"
    assert [j.column for j in ur.joints] == [j.column for j in dh.joints]
    q = np.random.default_rng(7).uniform(-360, 360, (N_POSES, 6))
    assert np.abs(ur.tool_point(q) - dh.tool_point(q)).max() <= FK_TOL_MM
    assert np.abs(ur.fk(q)[:, :3, :3] - dh.fk(q)[:, :3, :3]).max() <= ROT_TOL
    e = np.random.default_rng(8).normal(0, 1e-3, dh.n_params)      # the same slots move the same way
    assert np.abs(ur.tool_point(q, e) - dh.tool_point(q, e)).max() <= FK_TOL_MM


def test_calibration_from_the_urdf_equals_the_dh_files():
    dh = load_machine("ur5")
    ur = load_machine(DATA / "ur5-urdf.toml")
    truth = draw_truth(dh, 3, compliance_rad_per_mm=np.zeros(6))
    q = random_joints(np.full(6, -170.0), np.full(6, 170.0), CAL_POSES, [3, 0])
    p = measure(dh, truth, q, NOISE_MM, [3, 1])
    a, b = fit_model(dh, p), fit_model(ur, p)
    # the same number of identified slots; WHICH slot of an exactly dependent pair is kept (link6.dtheta_rad or
    # link6.da_mm beside the tool point) is decided by the QR pivot on columns equal to round-off, so the slot
    # values are compared through what they predict
    assert a.free.sum() == b.free.sum() > 20
    assert abs(a.fit_rms_mm - b.fit_rms_mm) <= CAL_TOL_MM
    qt = random_joints(np.full(6, -170.0), np.full(6, 170.0), 50, [3, 2])
    assert np.abs(a.predict(qt) - b.predict(qt)).max() <= CAL_TOL_MM
    assert a.fit_rms_mm < 3 * NOISE_MM          # the fit itself worked (3 components of 0.02 mm noise)


ODD = """<?xml version="1.0"?>
<robot name="odd">
  <link name="world"/><link name="a"/><link name="b"/><link name="c"/><link name="d"/><link name="e"/>
  <link name="f"/><link name="tip"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="a"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.1 0.2 -0.3"/></joint>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
    <origin xyz="0.01 0.02 0.15" rpy="0 0 0.4"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="b"/><child link="c"/>
    <origin xyz="0.3 0.05 0.0" rpy="0.3 0 0"/><axis xyz="-1 0 0"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j3" type="continuous"><parent link="c"/><child link="d"/>
    <origin xyz="0.25 0 0.02" rpy="0.3 0 0"/><axis xyz="-1 0 0"/></joint>
  <joint name="slide" type="prismatic"><parent link="d"/><child link="e"/>
    <origin xyz="0 0.1 0" rpy="0 0.5 0"/><axis xyz="0.6 0 0.8"/>
    <limit lower="-0.1" upper="0.2" effort="1" velocity="1"/></joint>
  <joint name="bend" type="fixed"><parent link="e"/><child link="f"/>
    <origin xyz="0.05 0 0.05" rpy="1 0 0"/></joint>
  <joint name="j5" type="revolute"><parent link="f"/><child link="tip"/>
    <origin xyz="0.02 0.03 0.1" rpy="0.2 -0.4 1.1"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
</robot>
"""


def _urdf_fk(q, j3_pitch=0.0):
    """The ODD robot's tip frame straight from its URDF numbers (origin · joint motion per joint), mm."""
    def T(xyz, rpy):
        M = np.eye(4)
        M[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()     # URDF rpy: fixed-axis x, y, z
        M[:3, 3] = np.asarray(xyz) * 1000.0
        return M
    steps = [((0.1, -0.2, 0.3), (0.1, 0.2, -0.3), None), ((0.01, 0.02, 0.15), (0, 0, 0.4), ("r", (0, 1, 0))),
             ((0.3, 0.05, 0), (0.3, 0, 0), ("r", (-1, 0, 0))), ((0.25, 0, 0.02), (0.3, j3_pitch, 0), ("r", (-1, 0, 0))),
             ((0, 0.1, 0), (0, 0.5, 0), ("p", (0.6, 0, 0.8))), ((0.05, 0, 0.05), (1, 0, 0), None),
             ((0.02, 0.03, 0.1), (0.2, -0.4, 1.1), ("r", (0, 0, 1)))]
    out = []
    for qi in q:
        M, k = np.eye(4), 0
        for xyz, rpy, mot in steps:
            M = M @ T(xyz, rpy)
            if mot is not None:
                J = np.eye(4)
                if mot[0] == "r":
                    J[:3, :3] = Rotation.from_rotvec(np.radians(qi[k]) * np.asarray(mot[1], float)).as_matrix()
                else:
                    J[:3, 3] = qi[k] * np.asarray(mot[1])
                M, k = M @ J, k + 1
        out.append(M)
    return np.array(out)


@pytest.mark.parametrize("j3_pitch", [0.0, 3e-7, 1e-3, 0.05])
def test_an_odd_urdf_reproduces_its_own_kinematics(tmp_path, j3_pitch):
    """j2 ∥ j3 exactly, tilted by 3e-7 and 1e-3 rad (nearly parallel: a nominal Hayati β) and by 0.05 rad (skew: the
    common normal, ~0.4 m out)."""
    f = tmp_path / "odd.robot"                      # any name: recognised by content
    f.write_text(ODD.replace('rpy="0.3 0 0"/><axis xyz="-1 0 0"/></joint>',
                             f'rpy="0.3 {j3_pitch!r} 0"/><axis xyz="-1 0 0"/></joint>'))
    c = load_machine(f)
    assert [j.column for j in c.joints] == ["j1_deg", "j2_deg", "j3_deg", "slide_mm", "j5_deg"]
    assert c.joints[3].lo == pytest.approx(-100.0) and c.joints[2].hi == 360.0
    # j2 ∥ j3: the Hayati slot, as a DH file gets it (the nominal β is the tilt); skew axes have none
    assert ("link2.beta_rad" in c.param_names) == (j3_pitch < NEARLY_PARALLEL_RAD)
    beta = [e.value for e in c.ets if e.slot == "link2.beta_rad"]
    assert beta == [] or abs(abs(beta[0]) - j3_pitch) < 1e-12
    rng = np.random.default_rng(11)
    q = rng.uniform(c.joint_lo, np.minimum(c.joint_hi, 170), (N_POSES, 5))
    ref = _urdf_fk(q, j3_pitch)
    F = c.fk(q)
    assert np.abs(F[:, :3, 3] - ref[:, :3, 3]).max() <= FK_TOL_MM
    assert np.abs(F[:, :3, :3] - ref[:, :3, :3]).max() <= ROT_TOL


def _refused(tmp_path, text, *words):
    f = tmp_path / "r.xml"
    f.write_text(text)
    with pytest.raises(MachineFileError) as ei:
        load_machine(f)
    for w in words:
        assert w in str(ei.value), str(ei.value)


@pytest.mark.parametrize("old,new,words", [
    ('type="continuous"', 'type="floating"', ("line 13", "'j3'", "floating")),
    ('type="continuous"', 'type="planar"', ("line 13", "'j3'", "planar")),
    ('<axis xyz="0.6 0 0.8"/>', '<axis xyz="0.6 0 0.8"/><mimic joint="j1"/>', ("line 15", "'slide'", "mimics")),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 2 0"/>', ("line 7", "'j1'", "unit vector")),
    ('<limit lower="-2" upper="2"', '<limit lower="2" upper="-2"', ("line 10", "'j2'", "upper > lower")),
    ('<axis xyz="0 1 0"/>', '<axis xyz="nan 1 0"/>', ("line 7", "'j1'", "<axis xyz> [nan, 1.0, 0.0] is not a finite")),
    ('<limit lower="-2" upper="2"', '<limit lower="-inf" upper="2"', ("line 10", "'j2'", "<limit lower> -inf")),
    ('<link name="e"/>', '<link name="e"/><link name="spare"/>', ("line 3", "2 root links", "'spare'")),
    ('<link name="e"/>', '', ("line 15", "joint 'slide' names link 'e', which the file does not define")),
    ('</robot>', '<joint name="loop" type="fixed"><parent link="tip"/><child link="world"/></joint></robot>',
     ("no root link", "loop")),
    ('</robot>', '<link name="spare"/><joint name="s" type="fixed"><parent link="a"/><child link="spare"/></joint>'
     '</robot>', ("leaf links", "'spare'", "tip_link")),
])
def test_what_a_chain_cannot_represent_is_refused_with_its_line(tmp_path, old, new, words):
    assert old in ODD
    _refused(tmp_path, ODD.replace(old, new, 1), *words)


def test_a_urdf_in_millimetres_is_refused(tmp_path):
    text = re.sub(r'<origin xyz="([^"]*)"', lambda m: '<origin xyz="%s"' % " ".join(
        repr(float(v) * 1000) for v in m.group(1).split()), (DATA / "ur5.urdf").read_text())   # every length in mm
    f = tmp_path / "m.toml"
    (tmp_path / "ur5.urdf").write_text(text)
    f.write_text((DATA / "ur5-urdf.toml").read_text())
    with pytest.raises(MachineFileError, match=r"ur5.urdf: line 34: joint 'elbow_joint'.*1098 m: millimetres rather"):
        load_machine(f)


def test_a_non_robot_xml_and_an_unreachable_base_are_refused(tmp_path):
    _refused(tmp_path, "<?xml version='1.0'?>\n<sdf><model/></sdf>", "line 2", "<sdf>", "<robot>")
    f = tmp_path / "m.toml"
    (tmp_path / "ur5.urdf").write_bytes((DATA / "ur5.urdf").read_bytes())
    f.write_text((DATA / "ur5-urdf.toml").read_text().replace('base_link = "base_link_inertia"', 'base_link = "base"'))
    with pytest.raises(MachineFileError, match="'base' is not an ancestor of the tip link 'tool0'"):
        load_machine(f)
    # the UR URDF itself has two leaves (tool0, base): naming the file alone must say which tip
    with pytest.raises(MachineFileError, match=r"2 leaf links \['tool0', 'base'\]"):
        load_machine(DATA / "ur5.urdf")
