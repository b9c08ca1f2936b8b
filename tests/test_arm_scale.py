"""Arm calibration at scale: the identifiability check without (3n)² matrices, and the decisions made on a seeded
subset of a large fit set with the geometric fits on every pose (docs/explanation/serial-arms.md, "Large pose files")."""
import io

import numpy as np
import pytest

from errormap.arm_calibration import fit_model, identifiable_slots
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.machine import load_machine

UR5_LO = np.array([-60.0, -150.0, -150.0, -180.0, -120.0, -180.0])
UR5_HI = np.array([60.0, -30.0, 150.0, 0.0, 120.0, 180.0])
NOISE_MM = 0.02
SV_RTOL = 1e-10        # singular values of Js and of its triangular factor: the same numbers up to round-off of a QR
NULL_LEAK = 0.05       # a named combination lies in the null space of the full SVD but for the weights below the
# display cut (|w| <= 0.1 of the largest) it leaves out
INDEPENDENT_RTOL = 1e-6   # the freed columns' smallest singular value: exact dependencies sit at round-off (<= 1e-13)
SAME_FIT_ATOL_MM = 1e-12   # the same LM on the same poses: the same tool points to round-off


@pytest.fixture(scope="module")
def ur5():
    return load_machine("ur5")


def _sim(chain, n, seed):
    t = draw_truth(chain, seed)
    return measure(chain, t, random_joints(UR5_LO, UR5_HI, n, [seed, 0]), NOISE_MM, [seed, 1])


def test_identifiability_matches_the_full_decomposition(ur5):
    """The triangular factor gives the full Jacobian's rank, singular values and null space; the free set is an
    independent set of that size with every frame slot (base, tool) in it."""
    from scipy.linalg import qr
    from errormap.arm_calibration import RANK_RTOL, _scaled
    q = random_joints(UR5_LO, UR5_HI, 60, [3, 0])
    free, combos, sv = identifiable_slots(ur5, q)
    Js, _ = _scaled(ur5.error_jacobian(q).reshape(-1, ur5.n_params))
    _, R, piv = qr(Js, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > RANK_RTOL * d[0]))
    assert free.sum() == rank
    assert all(f for n, f in zip(ur5.param_names, free) if n.startswith(("base.", "tool.")))
    assert np.linalg.svd(Js[:, free], compute_uv=False)[-1] > INDEPENDENT_RTOL * sv[0]
    ref_sv = np.linalg.svd(Js, compute_uv=False)
    np.testing.assert_allclose(sv, ref_sv, rtol=0, atol=SV_RTOL * ref_sv[0])
    _, _, Vt = np.linalg.svd(Js, full_matrices=True)
    assert len(combos) == ur5.n_params - rank > 0
    N_ref = Vt[rank:].T @ Vt[rank:]
    # each named combination is a null vector of Js (scaled to max |weight| 1; weights below the display cut dropped)
    for c in combos:
        v = np.zeros(ur5.n_params)
        v[[ur5.param_names.index(n) for n in c["slots"]]] = c["weights"]
        assert np.linalg.norm(N_ref @ v) > (1 - NULL_LEAK) * np.linalg.norm(v)


@pytest.mark.slow
def test_decisions_on_a_subset_geometric_fits_on_every_pose(ur5):
    """With more fit poses than decide_max the CVs run on decide_max of them (said on the log, counted in the
    result) and the returned geometric stage is the fit on all the fit poses."""
    from compensation.app.workflows.arm_calibration import calibrate_arm, decision_subset
    fit, check = _sim(ur5, 240, 5), _sim(ur5, 40, 6)
    log = io.StringIO()
    core = calibrate_arm(ur5, fit, check, learned=False, k_folds=2, decide_max=120, log=log, band_blocked=False)
    assert core["decision_poses"] == 120
    assert "on a seeded subset of 120" in log.getvalue()
    ref = fit_model(ur5, fit, core["geometric_fits"]["dh"].model)
    np.testing.assert_allclose(core["geometric_fits"]["dh"].predict(check.q), ref.predict(check.q), atol=SAME_FIT_ATOL_MM)
    assert decision_subset(100, 120, 0) is None
    idx = decision_subset(240, 120, 0)
    assert len(np.unique(idx)) == 120 and np.array_equal(idx, decision_subset(240, 120, 0))
