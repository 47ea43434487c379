"""Shared test settings: small thread counts, deterministic seeds, a cage cache of the test run's own, and
the process-wide settings that the entry points make (:func:`neural.device.configure_process`)."""

import os
import tempfile

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ["SHELLSIM_CACHE"] = tempfile.mkdtemp(prefix="shellsim-test-cache-")  # never the user's cache

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from neural.device import configure_process  # noqa: E402

configure_process()


@pytest.fixture
def rng():
    return np.random.default_rng(0)
