"""Frames as Ray tasks: on a local Ray instance sized to the machine, or on a cluster (``ray start --head``).

:func:`run_on_ray` sends each payload to a task that runs ``recipe()(payload)``. ``recipe`` (a picklable
callable, e.g. a ``functools.partial`` of a module-level function) builds the expensive state once per
worker process (loading the asset and its field): the worker keeps it for every later task of the same
recipe. Each task limits torch and OpenMP to ``threads`` threads so that the workers do not oversubscribe
the cores. A worker that dies mid-task is replaced and its task run again (``max_retries``); the caller's
``on_result`` sees each payload's result once, in completion order, so it can write each frame as it comes.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence

from neural.errors import InputError
from shellsim.errors import SettingError

log = logging.getLogger(__name__)

#: The install line for the distributed options, printed when ``ray`` is missing.
RAY_HINT = "Ray is not installed: pip install 'shellsim[cluster]'"

_STATE: dict = {}  # per worker process: recipe -> what it built


def require_ray():
    """The ``ray`` module, or an :class:`InputError` with the install line."""
    try:
        import ray
    except ImportError:
        raise InputError(RAY_HINT) from None
    return ray


def _run(recipe: Callable, payload, threads: int):
    """In a worker: limit threads, flush denormals (:func:`neural.device.flush_denormals`, as the entry point
    of a program would), build ``recipe()`` once per process, run it on ``payload``."""
    import torch

    from neural.device import flush_denormals

    flush_denormals()
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    key = repr(recipe)
    if key not in _STATE:
        _STATE.clear()  # one recipe at a time: a new job's state replaces the last one's
        _STATE[key] = recipe()
    return _STATE[key](payload)


def connect(address: str | None = None):
    """Connect to the Ray cluster at ``address`` ("auto": the one this machine belongs to), or start a local
    instance using every core when None. Returns the ``ray`` module."""
    ray = require_ray()
    if ray.is_initialized():
        return ray
    env = {"env_vars": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}}
    try:
        if address is None:
            ray.init(
                num_cpus=os.cpu_count(),
                include_dashboard=False,
                log_to_driver=False,
                runtime_env=env,
                configure_logging=False,
            )
        else:
            ray.init(address=address, log_to_driver=False, runtime_env=env, configure_logging=False)
    except (ConnectionError, RuntimeError, ValueError) as err:
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        raise SettingError("ray", f"cannot start or reach {where} ({err})") from None
    return ray


def run_on_ray(
    payloads: Sequence,
    recipe: Callable,
    on_result: Callable[[int, object], None],
    address: str | None = None,
    threads: int = 1,
    max_retries: int = 3,
) -> None:
    """Run ``recipe()(payload)`` for every payload as a Ray task (each on ``threads`` cores) and call
    ``on_result(index, result)`` in the driver as each one finishes. A task whose worker dies is run again
    up to ``max_retries`` times; other errors are raised as they were in the worker."""
    ray = connect(address)
    task = ray.remote(num_cpus=threads, max_retries=max_retries)(_run)
    recipe_ref = ray.put(recipe)
    pending = {task.remote(recipe_ref, payload, threads): i for i, payload in enumerate(payloads)}
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                index = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayTaskError as err:
                    raise err.as_instanceof_cause() from None
                on_result(index, result)
    finally:
        for ref in pending:  # interrupted or failed: stop what is still queued
            ray.cancel(ref, force=True)
