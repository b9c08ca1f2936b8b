"""errormap.stats.residual_stats: the one key scheme, on residuals whose statistics are known."""
import numpy as np
import pytest

from errormap.stats import COLUMN_KEYS, STAT_KEYS, residual_stats

EXACT = 1e-12  # closed-form values computed in float64: agreement to rounding only


def test_vector_residual_norm_statistics():
    r = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [6.0, 0.0, -8.0]])  # norms 5, 0, 1, 10
    s = residual_stats(r, ("dx_um", "dy_um", "dz_um"))
    assert set(s) == set(STAT_KEYS) | {"dx_um", "dy_um", "dz_um"}
    assert s["n"] == 4
    assert s["max_um"] == pytest.approx(10.0, abs=EXACT)
    assert s["mean_um"] == pytest.approx(4.0, abs=EXACT)
    assert s["rms_um"] == pytest.approx(np.sqrt((25 + 0 + 1 + 100) / 4), abs=EXACT)
    assert s["p95_um"] == pytest.approx(np.percentile([5, 0, 1, 10], 95), abs=EXACT)
    assert set(s["dy_um"]) == set(COLUMN_KEYS)
    assert s["dy_um"]["max_abs_um"] == pytest.approx(4.0, abs=EXACT)
    assert s["dy_um"]["mean_um"] == pytest.approx(0.75, abs=EXACT)  # signed: (4 − 1) / 4
    assert s["dz_um"]["rms_um"] == pytest.approx(np.sqrt(64 / 4), abs=EXACT)


def test_scalar_residual_uses_absolute_value():
    s = residual_stats(np.array([-2.0, 1.0, 1.0]))
    assert s["max_um"] == pytest.approx(2.0, abs=EXACT)
    assert s["mean_um"] == pytest.approx(4.0 / 3.0, abs=EXACT)
    assert s["rms_um"] == pytest.approx(np.sqrt(2.0), abs=EXACT)


def test_nonfinite_rows_propagate_unless_dropped():
    r = np.array([[1.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.0, 3.0, 0.0]])
    assert np.isnan(residual_stats(r)["rms_um"])  # a diverged fit cannot hide
    s = residual_stats(r, drop_nonfinite=True)
    assert s["n"] == 2 and s["max_um"] == pytest.approx(3.0, abs=EXACT)
    empty = residual_stats(np.full((2, 3), np.nan), drop_nonfinite=True)
    assert empty["n"] == 0 and empty["max_um"] is None and empty["rms_um"] is None


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="Expected"):
        residual_stats(np.zeros((2, 3, 1)))
    with pytest.raises(ValueError, match="Expected 3 column names"):
        residual_stats(np.zeros((2, 3)), ("dx_um",))
