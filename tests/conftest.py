"""Shared fixtures: small simulated scenes built from poses the tests construct."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import standing_poses


@pytest.fixture(scope="session")
def bank_poses() -> np.ndarray:
    return standing_poses()
