"""The blocked band rule of an arm calibration (training/arm_residual.py ``blocked_band_scale``): the kept stage's band
is scaled so that its 95 % band holds 95 % on blocked inner CVs of the fit poses (acquisition-order runs, sectors of the
first joint), checked on a constructed case whose scale is known, and carried by the file to ``predict --band``."""
import json

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import norm

from errormap.arm_calibration import content_blocks
from errormap.arm_poses import ArmPoses
from errormap.arm_simulate import draw_truth, random_joints
from errormap.io import InputError
from errormap.machine import load_machine
from errormap.seeds import spawn_rngs
from training.arm_residual import BAND_COVERAGE, band_factor, blocked_band_scale, combine_band_factors

UR5_LO = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0])
UR5_HI = np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
NOISE_MM = 0.02            # tracker noise per component on the quiet part of the session
NOISY_FACTOR = 3.0         # the last quarter of the session (by row order) is this much noisier
N_POSES = 1200             # 3,600 components: the 95 % quantile of the pooled |residual| / std to ~3 % (one SE)
N_BLOCKS = 4
# the measured factor against the analytic one: the quantile of 3,600 components has a standard error of ~3 % at this
# mixture's density; the fit's J Σ Jᵀ (27 slots, ~2,700 fit components) widens the std by ~1–2 % and the fitted σ̂ is
# an RMS of ~2,700 residuals (±1.4 %): 12 % is ~3.5 standard errors plus that bias
FACTOR_RTOL = 0.12
# band_factor on pure normal draws with a known scale: 300,000 components, the 95 % quantile to ~0.3 %
KNOWN_SCALE_RTOL = 0.01
COVERAGE_ATOL = 1e-3       # after the factor the 95 % band holds ≥ 95 % of the components up to one in 1,000


def _q95_of_mixture(parts):
    """The 95 % quantile of |z| for a mixture [(weight, sd), ...] of zero-mean normals, over 1.96: the exact factor."""
    f = (lambda q: sum(w * (2 * norm.cdf(q / s) - 1) for w, s in parts) - BAND_COVERAGE)
    return brentq(f, 1e-6, 100.0) / norm.ppf(0.975)


def test_band_factor_recovers_a_known_scale():
    rng = spawn_rngs(5, 1)[0]
    for scale in (0.5, 1.0, 2.5):
        y = rng.normal(0.0, scale, (100_000, 3))
        c = band_factor(y, np.zeros_like(y), np.ones_like(y))
        assert c == pytest.approx(scale, rel=KNOWN_SCALE_RTOL)


def test_factors_combine_to_the_largest_capped_by_the_interleaved_cv_never_below_one():
    assert combine_band_factors([1.3, 1.1]) == (1.3, 1.3)
    assert combine_band_factors([1.3, 1.1], cap=1.2) == (1.3, 1.2)      # 98 % on the interleaved CV bounds it
    assert combine_band_factors([0.8, 0.9], cap=1.2) == (1.0, 1.0)      # never narrower than the stage's own band
    assert combine_band_factors([1.3], cap=0.7) == (1.3, 1.0)


def test_content_blocks_follow_time_else_row_order_and_the_first_joint():
    q = np.array([[30.0, 0], [10, 0], [20, 0], [0, 0]])
    p = ArmPoses(q, np.zeros((4, 3)), None, None, None, np.array([5, 2, 3, 4]), "x", "schema")
    b = content_blocks(p, 2)
    assert b["order"].tolist() == [1, 0, 0, 1] and b["sector"].tolist() == [1, 0, 1, 0]
    p.time_s = np.array([0.0, 3.0, 1.0, 2.0])
    assert content_blocks(p, 2)["order"].tolist() == [0, 1, 0, 1]
    with pytest.raises(ValueError):
        content_blocks(p, 1)


@pytest.mark.slow
def test_blocked_rule_recovers_the_scale_of_a_noisier_later_stretch():
    """An exact chain (no sag) measured with σ on the first three quarters of the session and 3σ on the last: on the
    acquisition-order blocking the fold fits' residual σ̂ is σ√(11/3) (blocks 0–2) or σ (block 3), on the first-joint
    sectors σ√3 — each blocking's factor is the 95 % quantile of a known normal mixture."""
    ur5 = load_machine("ur5")
    truth = draw_truth(ur5, 11, compliance_rad_per_mm=np.zeros(ur5.n_joints))
    q = random_joints(UR5_LO, UR5_HI, N_POSES, [11, 0])
    sd = np.where(np.arange(N_POSES) >= 3 * N_POSES // 4, NOISY_FACTOR * NOISE_MM, NOISE_MM)
    xyz = truth.tool_point(ur5, q) + spawn_rngs([11, 1], 1)[0].normal(0.0, 1.0, (N_POSES, 3)) * sd[:, None]
    poses = ArmPoses(q, xyz, None, None, None, np.arange(2, N_POSES + 2), "simulated", "schema")
    cal = blocked_band_scale(ur5, poses, {"dh": ("dh", None)}, content_blocks(poses, N_BLOCKS), N_BLOCKS, 0)
    k2 = NOISY_FACTOR ** 2
    order = _q95_of_mixture([(3 / 4, np.sqrt(3 / (2 + k2))), (1 / 4, NOISY_FACTOR)])
    sector = _q95_of_mixture([(3 / 4, np.sqrt(4 / (3 + k2))), (1 / 4, NOISY_FACTOR * np.sqrt(4 / (3 + k2)))])
    b = cal["blockings"]
    assert b["order"]["factor"] == pytest.approx(order, rel=FACTOR_RTOL)
    assert b["sector"]["factor"] == pytest.approx(sector, rel=FACTOR_RTOL)
    assert cal["factor"] == max(1.0, b["order"]["factor"], b["sector"]["factor"])
    assert b["order"]["coverage95_before"] < BAND_COVERAGE          # the unscaled band is too narrow there
    for v in b.values():
        assert v["coverage95_after"] >= BAND_COVERAGE - COVERAGE_ATOL
