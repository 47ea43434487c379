"""Frames as Ray tasks on a local instance: the results equal the serial ones, each worker builds its state
once, and a worker killed mid-task is replaced without losing a frame."""

from __future__ import annotations

import functools
import os
import signal
import time

import numpy as np
import pytest

from shellsim.distributed import run_on_ray

pytestmark = pytest.mark.slow


def _frame_maker(seed: int, pause: float):
    """A recipe: state built once per process (its build count is reported with every result)."""
    _frame_maker.builds = getattr(_frame_maker, "builds", 0) + 1
    table = np.random.default_rng(seed).random(1000)

    def render(k: int):
        time.sleep(pause)
        return k, float(np.sin(table * k).sum()), os.getpid(), _frame_maker.builds

    return render


def serial(k: int, seed: int = 3) -> float:
    return float(np.sin(np.random.default_rng(seed).random(1000) * k).sum())


@pytest.fixture(scope="module")
def ray_local():
    import ray

    ray.shutdown()  # a Ray instance of an earlier test lacks this test's environment
    here = os.path.dirname(__file__)  # the workers import this module to unpickle the recipe
    path = os.pathsep.join(filter(None, [here, os.environ.get("PYTHONPATH")]))
    env = {"env_vars": {"PYTHONPATH": path, "OMP_NUM_THREADS": "1"}}
    ray.init(
        num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False, runtime_env=env
    )
    yield ray
    ray.shutdown()


def test_results_match_serial_and_each_worker_builds_once(ray_local):
    got = {}
    run_on_ray(list(range(12)), functools.partial(_frame_maker, 3, 0.05), lambda i, r: got.setdefault(i, r))
    assert sorted(got) == list(range(12))
    assert all(got[i][0] == i and got[i][1] == serial(i) for i in got)
    assert {r[3] for r in got.values()} == {1}  # every worker process built the state once


def test_a_killed_worker_loses_no_frame(ray_local):
    got, killed = {}, []

    def on_result(i, r):
        got[i] = r
        if not killed:  # kill the worker that made the first frame while it works on its next one
            os.kill(r[2], signal.SIGKILL)
            killed.append(r[2])

    run_on_ray(list(range(10)), functools.partial(_frame_maker, 3, 0.4), on_result)
    assert sorted(got) == list(range(10))
    assert all(got[i][1] == serial(i) for i in got)
    assert any(r[2] != killed[0] for r in got.values())  # a new worker took over
