import numpy as np
import pytest

from sewtol.mechanisms.needle_208 import Needle208


@pytest.fixture(scope="session")
def nominal() -> Needle208:
    return Needle208.nominal()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)
