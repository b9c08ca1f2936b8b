"""The joint-error table slot set of the arm calibration (``dh+compliance+table``, errormap/arm_calibration.py):
per joint Δθ_i(q_i) linear between knots every TABLE_STEP_DEG, acting through the chain like the harmonic slots."""
import json

import numpy as np
import pytest

from errormap.arm_calibration import (MODELS, TABLE_MIN_SUPPORT, TABLE_MODEL, TABLE_STEP_DEG, ExtendedChain,
                                      GeometricResult, fit_model, table_held)
from errormap.arm_poses import ArmPoses
from errormap.arm_simulate import draw_truth, random_joints
from errormap.machine import load_machine

UR5_LO = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0])   # the real UR5 grid's joint box (deg)
UR5_HI = np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
NOISE_MM = 0.02                                                  # tracker noise per component
NOISE_FLOOR_MM = np.sqrt(3) * NOISE_MM                           # RMS 3-D error of a perfect model
FLOOR_FACTOR = 1.25                                              # the bound on held-out error vs the noise
# error Jacobian against central differences: step 1e-6 per slot unit; truncation ~ step² × curvature (≤ 1e3 mm per
# unit²) ≈ 1e-9 mm, rounding ~ 1e-16 × 1e3 mm / 1e-6 ≈ 1e-7 mm: 1e-5 leaves two decades
JAC_FD_STEP = 1e-6
JAC_FD_ATOL = 1e-5
# joint Jacobian: step 1e-4 deg (no pose of the seeded draw lies within it of a knot, where the hat's slope jumps);
# truncation ~ (1.7e-6 rad)² × 1e3 mm ≈ 3e-9, rounding ~ 1e-16 × 1e3 / 1e-4 ≈ 1e-9 mm/deg
JOINT_FD_STEP_DEG = 1e-4
JOINT_JAC_ATOL = 1e-6
TABLE_SLOT_VALUE = 1e-3   # rad per knot (≈ 200 arcsec, ~5× the real UR5's): makes ∂Δθ/∂q visible above the tolerance
# the simulated cyclic joint error: 50 arcsec (the real UR5 joint 1's size) at 6 cycles per turn (60° period); linear
# interpolation between 5° knots misses at most A (ω h)² / 8 = 3.4 % of it (1.7 arcsec ≈ 0.004 mm at 0.5 m)
CYCLIC_AMPLITUDE_RAD = 50 / 206265
CYCLIC_PER_TURN = 6
# the once-per-turn harmonic slots cannot follow it: its held-out RMS stays above this many noise floors (measured
# 2.75× on 400 poses of these seeds)
HARMONIC_MISS_FACTOR = 1.5
# fit poses: the real UR5 grid's fit part (800). The table has ~140 identified slots; on 800 poses it predicts held-out
# poses at 1.01× the floor (measured), on 400 at 1.28× (its weakly supported edge knots fit the noise)
N_FIT = 800


@pytest.fixture(scope="module")
def ur5():
    return load_machine("ur5")


def _table_chain(ur5):
    return ExtendedChain(ur5, compliance=True, table=True)


def test_table_is_the_last_slot_set_and_its_knots_are_multiples_of_the_step(ur5):
    c = _table_chain(ur5)
    assert MODELS[-1] == TABLE_MODEL and c.model == TABLE_MODEL
    assert np.allclose(np.mod(c._table_knot_deg, TABLE_STEP_DEG), 0.0)
    # no table on the joint that does not move the tool point (UR5 joint 6: the tool sits 0.09 mm off its axis)
    assert 5 not in set(c._table_joint.tolist())


def test_table_chain_jacobians_match_differences(ur5):
    c = _table_chain(ur5)
    q = random_joints(UR5_LO, UR5_HI, 5, [3, 0])
    x = np.random.default_rng(1).normal(0, 1e-4, c.n_params)
    x[c.n_geo + c._table_idx] = TABLE_SLOT_VALUE * np.random.default_rng(2).normal(size=len(c._table_idx))
    J = c.error_jacobian(q, x)
    active = np.flatnonzero(np.abs(J).sum((0, 1)) > 0)
    n_tab = len(np.unique(c._table_joint))
    assert len(set(active) & set(c.n_geo + c._table_idx)) >= 2 * n_tab   # ≥ the two hats around a pose, per joint
    for k in active:
        d = np.zeros(c.n_params)
        d[k] = JAC_FD_STEP
        fd = (c.tool_point(q, x + d) - c.tool_point(q, x - d)) / (2 * JAC_FD_STEP)
        assert np.allclose(J[:, :, k], fd, rtol=0, atol=JAC_FD_ATOL), c.param_names[k]
    Jq = c.joint_jacobian(q, x)
    fd = np.empty_like(Jq)
    for j in range(ur5.n_joints):
        qp, qm = q.copy(), q.copy()
        qp[:, j] += JOINT_FD_STEP_DEG
        qm[:, j] -= JOINT_FD_STEP_DEG
        fd[:, :, j] = (c.tool_point(qp, x) - c.tool_point(qm, x)) / (2 * JOINT_FD_STEP_DEG)
    assert np.allclose(Jq, fd, rtol=0, atol=JOINT_JAC_ATOL)
    without = ur5.joint_jacobian(q, x[:c.n_geo], frames=c.frames(q, x))
    assert np.abs(without - fd).max() > 100 * JOINT_JAC_ATOL   # the table's slope is in it


def test_table_held_knots(ur5):
    """Knots with less support than TABLE_MIN_SUPPORT poses and one anchor per joint (its best-supported knot) are
    held; a knot inside dense data is not."""
    c = _table_chain(ur5)
    q = random_joints(UR5_LO, UR5_HI, 300, [4, 0])
    held = table_held(c, q)
    assert held[:c.n_geo].sum() == 0
    w = c._basis(q)[:, c._table_idx].sum(0)
    t_held = held[c.n_geo + c._table_idx]
    assert np.all(t_held[w < TABLE_MIN_SUPPORT])
    for j in np.unique(c._table_joint):
        k = np.flatnonzero(c._table_joint == j)
        assert t_held[k[np.argmax(w[k])]]
        assert t_held[k].sum() == (w[k] < TABLE_MIN_SUPPORT).sum() + 1
    assert table_held(ExtendedChain(ur5, compliance=True, harmonic=True), q) is None


def _cyclic_poses(ur5, truth, n, seed):
    """Poses measured on the truth with a cyclic joint-1 error Δθ₁ = A sin(6 q₁): (n, 6) deg → ArmPoses."""
    q = random_joints(UR5_LO, UR5_HI, n, [seed, 0])
    dq = q.copy()
    dq[:, 0] += np.degrees(CYCLIC_AMPLITUDE_RAD * np.sin(CYCLIC_PER_TURN * np.radians(q[:, 0])))
    xyz = truth.tool_point(ur5, dq) + np.random.default_rng(seed).normal(0, NOISE_MM, (n, 3))
    return ArmPoses(q, xyz, None, None, None, np.arange(2, n + 2), "simulated", "schema")


@pytest.mark.slow
def test_table_learns_a_cyclic_joint_error_and_round_trips(ur5):
    """A simulated UR5 (draw_truth: link errors + sag) with a 50-arcsec, 6-per-turn joint-1 error, 800 fit poses (slow:
    10-40 s): the table slot set
    predicts held-out poses at the noise floor, the harmonic one does not; model.json's geometric stage
    written and read back predicts bit for bit; outside the data the table is zero."""
    truth = draw_truth(ur5, 11)
    fit, check = _cyclic_poses(ur5, truth, N_FIT, 11), _cyclic_poses(ur5, truth, 200, 12)
    rms = {}
    for m in ("dh+compliance+harmonic", TABLE_MODEL):
        g = fit_model(ur5, fit, m)
        rms[m] = float(np.sqrt(np.mean(np.sum((check.xyz_mm - g.predict(check.q)) ** 2, 1))))
    assert rms[TABLE_MODEL] <= FLOOR_FACTOR * NOISE_FLOOR_MM, rms
    assert rms["dh+compliance+harmonic"] >= HARMONIC_MISS_FACTOR * NOISE_FLOOR_MM, rms
    d = json.loads(json.dumps(g.to_dict()))
    g2 = GeometricResult.from_dict(ur5, d)
    assert g2.model == TABLE_MODEL
    assert np.array_equal(g2.predict(check.q), g.predict(check.q))
    # beyond the data by more than one step the table adds nothing: the effective joint 1 is the commanded one
    q_out = check.q[:3].copy()
    q_out[:, 0] = UR5_HI[0] + 2 * TABLE_STEP_DEG
    assert np.array_equal(g.chain.effective_joints(q_out, g.params)[:, 0], q_out[:, 0])


def test_report_counts_a_tables_held_knots_per_joint_and_names_every_other_fixed_slot():
    """The identifiability line of the arm report: a table's held knots (~60 a joint on the real UR5) are counted per
    joint, every other fixed slot is named; the stage table's sentence column is the one that wraps."""
    from compensation.app.reports.arm_calibration import fixed_slots_text
    names = ["base.z_mm", "table.q1.at_-180deg_rad", "table.q1.at_+5deg_rad", "link2.dd_mm", "table.q3.at_+0deg_rad",
             "table.q1.at_+2.5deg_rad"]
    assert fixed_slots_text(names) == "base.z_mm, link2.dd_mm, table.q1: 3 knots, table.q3: 1 knot"
    assert fixed_slots_text([]) == "none"
    assert fixed_slots_text(["tablet.q1.at_5deg_rad"]) == "tablet.q1.at_5deg_rad"   # not a table knot: named
    # the names the chain writes are the names the report counts (one format, errormap.arm_calibration)
    from errormap.arm_calibration import TABLE_KNOT_RE, table_knot_name
    assert [TABLE_KNOT_RE.match(table_knot_name("q2", k)).group(1) for k in (-180.0, 0.0, 2.5)] == ["q2"] * 3
