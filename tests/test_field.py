"""The error-field protocol (errormap/field.py): who implements it, what check_field refuses,
the network's numpy column path, and the one thread-limit helper."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from errormap.field import (CAPABILITIES, GRINDER_AXES, JACOBIAN, OFFSET_FITNESS, PREDICT_AND_JACOBIAN, CalibratedVolume, ErrorField,
                            check_field)
from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth
from errormap.threads import limit_threads

COLUMNS_NUMPY_TOL = 0.0  # the numpy column path wraps the torch one: the same numbers, bit for bit


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def small_network(enc="raw"):
    from training.model import MLPField
    rng = np.random.default_rng(0)
    axes = np.column_stack([rng.uniform(0, 200, 50), rng.uniform(0, 60, 50), rng.uniform(0, 360, 50)])
    m = MLPField((6, 6), "sigmoid", enc).fit_scalers(axes, rng.normal(0.0, 20.0, (50, 3)))
    m.theta_ = m.init_params(0)
    return m, axes


def test_the_fields_implement_the_protocol(machine):
    from compensation.export import TableField
    from errormap.diagnosis.corrected import CorrectedField
    from training.model import MLPField
    from training.pose_field import PoseMLP
    htm = ChainField(machine, make_chain_truth(machine, 0).elements)
    net, axes = small_network()
    for f in (htm, net, CorrectedField(machine, htm, []), TableField(htm.predict)):
        assert check_field(f) is f and isinstance(f, ErrorField)
    # the grinder's chain field has its closed-form Jacobian (issue 20)
    assert htm.capabilities == frozenset({JACOBIAN, PREDICT_AND_JACOBIAN}) and net.capabilities == CAPABILITIES
    assert htm.calibrated_volume == CalibratedVolume(machine.stroke_lo, machine.stroke_hi)
    assert net.calibrated_volume == CalibratedVolume(axes.min(axis=0), axes.max(axis=0))
    assert MLPField().calibrated_volume is None  # untrained: it cannot say
    assert CorrectedField(machine, htm, []).calibrated_volume == htm.calibrated_volume
    pose = PoseMLP(6, 6).fit_scalers(np.arange(36.0).reshape(6, 6), np.zeros((6, 6)))
    assert pose.capabilities == frozenset()  # none of the grinder network's options
    assert pose.calibrated_volume.names == ("x_mm", "y_mm", "z_mm", "rx_rad", "ry_rad", "rz_rad")
    check_field(pose, names=pose.input_names)
    with pytest.raises(TypeError, match="axes"):
        check_field(pose)  # not a field over the grinder's axes
    assert check_field(htm, names=GRINDER_AXES) is htm


class _Declared:
    calibrated_volume = None

    def __init__(self, capabilities):
        self.capabilities = capabilities

    def predict(self, axes):
        return np.zeros((len(axes), 3))


def test_check_field_refuses_undeclared_or_unbacked_capabilities():
    check_field(_Declared(frozenset()))
    with pytest.raises(TypeError, match="without the method"):
        check_field(_Declared(frozenset({JACOBIAN})))  # declared, but no jacobian()
    with pytest.raises(TypeError, match="without the method"):
        check_field(_Declared(frozenset({OFFSET_FITNESS})))
    with pytest.raises(TypeError, match="frozenset"):
        check_field(_Declared({JACOBIAN}))  # a set is not a declaration (mutable)
    with pytest.raises(TypeError, match="frozenset"):
        check_field(_Declared(frozenset({"gradient"})))  # not a known capability

    class NoCaps:
        calibrated_volume = None

        def predict(self, axes):
            return np.zeros((len(axes), 3))

    with pytest.raises(TypeError, match="error field"):
        check_field(NoCaps())  # capabilities are declared, never assumed


@pytest.mark.parametrize("enc", ["raw", "periodic"])
def test_network_columns_numpy_equals_torch(enc):
    net, _ = small_network(enc)
    cols = np.ascontiguousarray(np.random.default_rng(1).uniform([[0], [0], [-400]], [[200], [60], [800]], (3, 500)))
    via_numpy = net.predict_columns(cols)
    via_torch = net.predict_columns(torch.from_numpy(cols)).numpy()
    assert isinstance(via_numpy, np.ndarray) and via_numpy.shape == (3, 500)
    assert np.abs(via_numpy - via_torch).max() <= COLUMNS_NUMPY_TOL


def test_limit_threads_limits_and_restores():
    before = torch.get_num_threads()
    with limit_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with limit_threads(None):
        assert torch.get_num_threads() == before
    with limit_threads(1, libraries=("blas",)):
        assert torch.get_num_threads() == before  # BLAS only: torch untouched
    with pytest.raises(ValueError, match="libraries"):
        with limit_threads(1, libraries=("openmp",)):
            pass
