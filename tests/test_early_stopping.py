"""Early stopping on the off-grid selection points (``TrainSettings.select_patience``, the demo's budget)."""
import numpy as np
import pytest

PATIENCE = 6        # accepted LM steps without a better selection error before stopping (small: a quick test)
MAX_ITER = 200      # the cap a run without patience goes to; far beyond where this tiny net stops improving


@pytest.fixture(scope="module")
def fp_and_machine(tmp_path_factory):
    from errormap.featurepoints import make_feature_points
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    tmp = tmp_path_factory.mktemp("patience")
    m = load_machine()
    el = make_chain_truth(m, 5).elements
    el_path = el.save(tmp / "el.json")
    return make_feature_points(m, ChainField(m, el), n=4, meta={"elements_file": str(el_path)}), m


def _fit(fp, **kw):
    from training import fit_field
    return fit_field(fp, seed=0, track=False, quiet=True, threads=1, n_validation=500, n_select=500,
                     select_every=1, hidden=(6,), activation="tanh", **kw)


def test_patience_stops_early_and_keeps_what_a_run_to_that_iteration_keeps(fp_and_machine):
    """The stopped run ends PATIENCE steps after its best selection iterate, and its network is bit
    for bit the one a plain run capped at the same iteration count keeps (early stopping only saves
    the iterations after it; it never picks another iterate)."""
    fp, _ = fp_and_machine
    early = _fit(fp, max_iter=MAX_ITER, select_patience=PATIENCE)
    n, kept = early.metrics["iterations"], early.metrics["selected_iteration"]
    assert early.history.stop_reason.startswith(f"selection error not improved in {PATIENCE} iterations")
    assert n == kept + PATIENCE < MAX_ITER
    assert early.params["select_patience"] == PATIENCE
    capped = _fit(fp, max_iter=n)
    assert capped.metrics["selected_iteration"] == kept
    assert capped.metrics["selection_max_um"] == early.metrics["selection_max_um"]
    assert np.array_equal(capped.field.theta_.numpy(), early.field.theta_.numpy())


def test_patience_off_by_default_and_validated():
    from training import TrainSettings
    assert TrainSettings().select_patience == 0
    for bad in (-1, 2.5):
        with pytest.raises(ValueError, match="select_patience"):
            TrainSettings(select_patience=bad)
