"""Shared test settings: small thread counts and deterministic seeds."""

import os

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture
def rng():
    return np.random.default_rng(0)
