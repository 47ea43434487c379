"""Device choice shared by torch and Warp code (``cuda`` when present, else ``cpu``), and the process-wide
settings a program's entry point makes first (:func:`configure_process`)."""

from __future__ import annotations

import functools
import logging
import os
import platform
import sys
from pathlib import Path

from .errors import InputError

DEVICES = ("auto", "cpu", "cuda")

#: Spins (``GOMP_SPINCOUNT``) an idle thread of torch's OpenMP pool (GNU libgomp, read when torch loads it)
#: makes before it sleeps, unless the environment sets ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY``. libgomp's
#: 300,000 kept torch's threads spinning after each of its operations, taking the cores from the Warp and
#: Embree threads that run between them: on the 2-core CPU a lego stage-1 step took 148-154 ms at 10,000 and
#: 148-161 ms at 30,000 against 184-185 ms at 300,000 and 183-208 ms at PASSIVE's none (threads that sleep at
#: once are slow to wake), and orbit frames of the lego 32-33 ms at rest and 46-47 deformed against 40-42
#: and 57-63 ms.
OPENMP_SPIN_COUNT = "30000"

log = logging.getLogger(__name__)


def configure_process(verbose: bool = False) -> None:
    """Make the process-wide settings of a program that runs this library; its entry point (the ``shellsim``
    command, each example and bench) calls this first, before torch is imported. Importing :mod:`neural` or
    :mod:`shellsim` makes none of them.

    - ``GOMP_SPINCOUNT`` = :data:`OPENMP_SPIN_COUNT` unless the environment sets it or ``OMP_WAIT_POLICY``
      (torch's libgomp reads it when torch loads: a warning says when torch came first);
    - float denormals flushed to zero (:func:`flush_denormals`) on this thread and so on every thread torch
      starts later;
    - Warp initialised with its banner, its "Module ... load" lines (``warp.config.log_level``) and the
      "Could not find or load the NVIDIA CUDA driver" of its CUDA probe hidden, unless ``verbose``.
    """
    if "GOMP_SPINCOUNT" not in os.environ and "OMP_WAIT_POLICY" not in os.environ:
        if "torch" in sys.modules:
            log.warning("torch was imported before configure_process: GOMP_SPINCOUNT does not apply to it")
        os.environ["GOMP_SPINCOUNT"] = OPENMP_SPIN_COUNT
    flush_denormals()
    import warp

    # warp 1.19 reads config.log_level (it has no config.quiet): LOG_WARNING hides the banner and the
    # "Module ... load" lines that it prints on stdout
    warp.config.log_level = warp.LOG_INFO if verbose else warp.LOG_WARNING
    if not verbose:
        _init_warp_quietly(warp)


def _init_warp_quietly(warp) -> None:
    """Initialise Warp with file descriptor 2 silenced: its native CUDA probe writes "Could not find or load
    the NVIDIA CUDA driver" straight to stderr on every machine without a GPU, whatever the log level."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            warp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def pick_device(name: str | None = "auto", warp: bool = False) -> str:
    """The device to run on: torch's ``"cpu"`` or ``"cuda"``, or with ``warp`` Warp's ``"cpu"`` or
    ``"cuda:0"``.

    ``name`` is one of :data:`DEVICES`: ``"auto"`` (or None) picks CUDA when the library that will run on
    it (torch, or Warp with ``warp``) sees a CUDA device, else the CPU. Another name, or ``"cuda"`` without
    a CUDA device, is an :class:`InputError` that speaks of the value (the CLI adds the option's name).
    """
    name = "auto" if name is None else name
    if name not in DEVICES:
        raise InputError(f"device {name!r}: expected one of {', '.join(map(repr, DEVICES))}")
    if name == "cpu":
        return "cpu"
    if warp:
        import warp as wp

        has_cuda = wp.get_cuda_device_count() > 0
    else:
        import torch

        has_cuda = torch.cuda.is_available()
    if not has_cuda:
        if name == "cuda":
            raise InputError("device 'cuda' requested but no CUDA device is available")
        return "cpu"
    return "cuda:0" if warp else "cuda"


def processor(device: str = "cpu") -> str:
    """What a torch ``device`` runs on, for the record next to a timing: the GPU's name on ``cuda``; on the
    CPU :func:`cpu_description` of this machine's ``/proc/cpuinfo`` (elsewhere ``platform.processor()``)
    and the cores. Minutes and milliseconds mean little without it: two hosts both sold as "AMD EPYC"
    with two cores have run the same bench 2x apart."""
    if str(device).startswith("cuda"):
        import torch

        return torch.cuda.get_device_name(torch.device(device))
    cpuinfo = Path("/proc/cpuinfo")
    name = cpu_description(cpuinfo.read_text()) if cpuinfo.is_file() else platform.processor()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{name or platform.machine()}, {cores} cores"


def cpu_description(cpuinfo: str) -> str:
    """The first processor of a Linux ``/proc/cpuinfo`` text: its model name with family, model and
    stepping (a virtual machine's model name alone often says only the vendor's line) and AVX-512 when its
    flags have ``avx512f``, e.g. ``"AMD EPYC (family 26, model 2, stepping 1; AVX-512)"``; "" without one."""
    fields = {}
    for line in cpuinfo.splitlines():
        key, sep, value = line.partition(":")
        if not sep:
            if fields:  # a blank line ends the first processor's block
                break
            continue
        fields.setdefault(key.strip(), value.strip())
    name = fields.get("model name") or fields.get("vendor_id", "")
    ids = [f"{k.split()[-1]} {fields[k]}" for k in ("cpu family", "model", "stepping") if k in fields]
    details = "; ".join(
        part for part in (", ".join(ids), "AVX-512" * ("avx512f" in fields.get("flags", "").split())) if part
    )
    return f"{name} ({details})" if name and details else name


def initialised_warp():
    """The ``warp`` module, initialised: imported on first use, so that modules whose kernels are built on
    demand stay cheap to import."""
    import warp as wp

    wp.init()
    return wp


def warp_device(torch_device: str) -> str:
    """The Warp device string matching a torch device (``"cpu"`` or ``"cuda:0"``)."""
    return "cpu" if str(torch_device).startswith("cpu") else "cuda:0"


def flush_denormals() -> bool:
    """Flush float denormals (below 1.2e-38 in float32) to zero on the CPU (x86 FTZ and DAZ), as TensorFlow
    and XLA do by default; returns whether the CPU supports it.

    A few percent of a training step's gradients are denormals (counted on lego at step 300: 1.3-3.9% of
    those flowing through each layer of the networks), and every vector operation that meets one takes a
    slow path: a weight-gradient product ran 3.7x slower with 3% of its entries denormal, and the backward
    pass of a lego step from one checkpoint took 170 instead of 260 ms. Values that small change nothing
    that is rendered or learned. The setting holds for this thread and for the threads started after it
    (POSIX threads inherit the floating-point environment), so call it before torch starts its thread pool:
    :func:`configure_process` does."""
    import torch

    return torch.set_flush_denormal(True)


def cpu_threads() -> int:
    """CPU threads this process may use for its parallel work: torch's thread count (the cores, unless
    ``OMP_NUM_THREADS`` or ``torch.set_num_threads`` says fewer, as a Ray worker does), so that Warp's
    chunked launches never oversubscribe what torch was given."""
    import torch

    return max(1, torch.get_num_threads())


@functools.cache
def kept_pool(workers: int, name: str):
    """A thread pool of ``workers`` threads named ``name``, kept for the process (a new pool per call costs
    ~0.2 ms); each use names its own, so that work waiting in one pool never holds up another's."""
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(workers, thread_name_prefix=name)


def run_in_chunks(n: int, launch, threads: int, min_chunk: int) -> None:
    """Call ``launch(lo, hi)`` over ``[0, n)`` cut into contiguous chunks, one per thread: at most ``threads``
    chunks of at least ``min_chunk`` items (one chunk, on this thread, when ``n`` is small); this thread
    runs the first chunk, a kept pool the others.

    Warp (and Embree) run a CPU cast or launch on one core and release the GIL meanwhile, so chunked
    launches writing disjoint outputs use every core. Compile the kernel first (``wp.load_module``) so the
    threads do not race to."""
    if n <= 0:
        return
    threads = max(1, min(threads, n // max(min_chunk, 1)))
    if threads == 1:
        launch(0, n)
        return
    import numpy as np

    bounds = np.linspace(0, n, threads + 1).astype(np.int64)
    pool = kept_pool(threads - 1, "warp-chunks")
    futures = [pool.submit(launch, int(bounds[k]), int(bounds[k + 1])) for k in range(1, threads)]
    launch(int(bounds[0]), int(bounds[1]))
    for future in futures:
        future.result()
