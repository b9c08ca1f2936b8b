"""The exact solver's ``roundoff_ulps`` setting (compensation/solvers/exact.py, on the grinder's chain): the default stop is
unchanged, a tighter stop drives the MODEL residual below the default's round-off band, and bad
values are refused before any work."""
import numpy as np
import pytest

from compensation.solvers import solve
from compensation.solvers.exact import ROUNDOFF_ULPS
from errormap.chain_field import ChainField
from errormap.chain_kernel import forward
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth

N_POINTS = 2000
SEED = 4
TIGHT_ULPS = 16.0
TIGHT_XTOL_UM = 1e-10
TIGHT_RESIDUAL_UM = 2e-9
"""Largest MODEL residual under the tight stop: |F| ≤ max(1e-10 μm, 16 ulps of a ≤ 300 mm
coordinate = 1.1e-9 μm), and points that stagnate first stop within a few ulps more (benchmark:
7.1e-10 μm max on 100,000 points)."""
DEFAULT_BAND_UM = 1024 * np.finfo(float).eps * 300.0 * 1e3
"""The default stop's band: 1,024 ulps of a ≤ 300 mm coordinate, in μm (6.8e-8 μm)."""


@pytest.fixture(scope="module")
def problem():
    m = load_machine()
    rng = np.random.default_rng(SEED)
    ax = rng.uniform(m.stroke_lo, m.stroke_hi, (N_POINTS, 3))
    return m, ChainField(m, make_chain_truth(m, SEED).elements), forward(m, ax), ax


def test_default_is_the_documented_stop(problem):
    m, f, tg, ax = problem
    a = solve("exact", f, tg, m, target_axes=ax, progress=False)
    b = solve("exact", f, tg, m, target_axes=ax, progress=False, roundoff_ulps=ROUNDOFF_ULPS)
    np.testing.assert_array_equal(a.commands_mm, b.commands_mm)
    assert np.linalg.norm(a.residual_um[a.success], axis=1).max() <= DEFAULT_BAND_UM


def test_tight_stop_converges_below_the_default_band(problem):
    m, f, tg, ax = problem
    d = solve("exact", f, tg, m, target_axes=ax, progress=False)
    t = solve("exact", f, tg, m, target_axes=ax, progress=False, roundoff_ulps=TIGHT_ULPS, xtol_um=TIGHT_XTOL_UM)
    np.testing.assert_array_equal(t.success, d.success)  # success is tol_um's, not the stop's
    assert np.linalg.norm(t.residual_um[t.success], axis=1).max() <= TIGHT_RESIDUAL_UM
    # the tight stop moves the commands by no more than the default's band
    assert np.abs(t.commands_mm - d.commands_mm)[d.success].max() * 1e3 <= 2 * DEFAULT_BAND_UM


@pytest.mark.parametrize("bad", [-1.0, 2e6, float("nan"), "16", True])
def test_bad_roundoff_ulps_refused(problem, bad):
    m, f, tg, ax = problem
    with pytest.raises(ValueError, match="roundoff_ulps"):
        solve("exact", f, tg[:3], m, target_axes=ax[:3], progress=False, roundoff_ulps=bad)
