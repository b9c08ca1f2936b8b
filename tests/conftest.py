import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def grinder():
    from errormap.machine import load_machine
    return load_machine()


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
