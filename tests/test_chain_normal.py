"""The chain identification's block normal equations (errormap/chain_normal.py) against the dense pivoted-QR
solve they replaced, on the same sweeps: the same estimate, covariance, leverage and (first-station gauge, where
the dense solve's basis is the free parameters themselves) condition."""
import numpy as np
import pytest

from errormap import chain_normal
from errormap.chain_normal import BlockLayout, Undecided
from errormap.chain_sweeps import simulated_sweeps, swept_words
from errormap.chain_truth import make_chain_truth
from errormap.identification import ChainIdentification, parameter_vector
from errormap.machine import load_machine
from errormap.sweeps import sweeps_from_columns

VALUE_TOL = 1e-6
"""μm / μrad: both solves iterate Gauss–Newton to the same fixed point (tol 1e-7 on the update); measured 5e-9."""
COV_RTOL = 1e-8
"""Relative to the largest covariance entry: normal equations square the (scaled) condition ~1e2; measured 1e-11."""
LEV_TOL = 1e-9
COND_RTOL = 1e-6
"""The Lanczos estimates of the extreme eigenvalues (chain_normal.CONDITION_TOL 1e-10); measured 3e-12."""


def _fit(monkeypatch, dense: bool, gauge: str, machine="mill-xyz"):
    mt = load_machine(machine)
    sw = sweeps_from_columns(simulated_sweeps(make_chain_truth(mt, 1), n_stations=7, seed=101), axes=swept_words(mt))
    if dense:
        def refuse(*a, **k):
            raise Undecided("forced")
        monkeypatch.setattr("errormap.identification.BlockLayout", refuse)
    res = ChainIdentification(gauge=gauge).fit(sw, mt).result_
    monkeypatch.undo()
    return res


@pytest.mark.parametrize("machine, gauge", [("mill-xyz", "first-station"), ("mill-xyz", "station-mean"),
                                            ("five-axis-ac", "reference-line"), ("five-axis-ac", "station-mean")])
def test_block_solve_equals_dense(monkeypatch, machine, gauge):
    new, old = _fit(monkeypatch, False, gauge, machine), _fit(monkeypatch, True, gauge, machine)
    v_new = parameter_vector(new.elements_, new.param_slot, new.param_station)
    v_old = parameter_vector(old.elements_, old.param_slot, old.param_station)
    assert np.abs(v_new - v_old).max() < VALUE_TOL
    assert np.abs(new.cov - old.cov).max() < COV_RTOL * np.abs(old.cov).max()
    for w in new.leverage:
        assert np.abs(new.leverage[w] - old.leverage[w]).max() < LEV_TOL
    assert new.sigma_um == pytest.approx(old.sigma_um, rel=1e-9)
    if gauge == "first-station":
        assert new.condition == pytest.approx(old.condition, rel=COND_RTOL)
    assert not new.unobservable and not old.unobservable


def test_undecided_layouts_fall_back():
    """A parameter no ball sees, or one entering a block twice, is left to the dense pivoted QR."""
    with pytest.raises(Undecided, match="no ball sees"):
        BlockLayout([np.array([[0, 1], [0, 1]])], 3)
    with pytest.raises(Undecided, match="twice"):
        BlockLayout([np.array([[0, 0], [0, 1]])], 2)


def test_singular_station_block_is_undecided():
    """Two identical local columns: the station's own parameters are not determined by its balls."""
    lay = BlockLayout([np.array([[0, 1, 2], [0, 3, 4]])], 5)
    JL, JG = lay.assemble([np.tile(np.array([1.0, 2.0, 2.0]), (2, 9, 1)) * np.arange(1, 10)[None, :, None]])
    with pytest.raises(Undecided):
        chain_normal.BlockNormal(lay, JL, JG, np.zeros((0, 5)))


def test_a_decidable_fit_never_builds_the_dense_jacobian(monkeypatch):
    """On sweeps the blocks can decide (every built-in machine tool's), no (rows × unknowns) Jacobian is built."""
    def refuse(*a, **k):
        raise AssertionError("the dense Jacobian was built")
    monkeypatch.setattr(ChainIdentification, "_dense", refuse)
    mt = load_machine("mill-xyz")
    sw = sweeps_from_columns(simulated_sweeps(make_chain_truth(mt, 2), n_stations=7, seed=102), axes=swept_words(mt))
    res = ChainIdentification(gauge="station-mean").fit(sw, mt).result_
    assert res.cov.shape == (len(res.param_slot),) * 2 and not res.unobservable
