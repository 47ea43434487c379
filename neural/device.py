"""Device choice shared by torch and Warp code: ``cuda`` when present, else ``cpu``."""

from __future__ import annotations

from .errors import InputError

DEVICES = ("auto", "cpu", "cuda")


def pick_device(name: str | None = None) -> str:
    """Return ``"cuda"`` or ``"cpu"``.

    ``name`` None or ``"auto"`` picks ``cuda`` when torch sees a GPU; an explicit ``"cuda"`` without one
    is an :class:`InputError`.
    """
    import torch

    if name in (None, "auto"):
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name not in DEVICES:
        raise InputError(f"device: expected cpu, cuda or auto, got {name!r}")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError("device cuda: no CUDA device is available on this machine")
    return name


def warp_device(torch_device: str) -> str:
    """The Warp device string matching a torch device (``"cpu"`` or ``"cuda:0"``)."""
    return "cpu" if str(torch_device).startswith("cpu") else "cuda:0"


def run_in_chunks(n: int, launch, threads: int, min_chunk: int) -> None:
    """Call ``launch(lo, hi)`` over ``[0, n)`` cut into contiguous chunks, one per Python thread: at most
    ``threads`` chunks of at least ``min_chunk`` items (one chunk, on this thread, when ``n`` is small).

    Warp runs a CPU launch on one core and releases the GIL meanwhile, so chunked launches writing disjoint
    outputs use every core. Compile the kernel first (``wp.load_module``) so the threads do not race to."""
    if n <= 0:
        return
    threads = max(1, min(threads, n // max(min_chunk, 1)))
    if threads == 1:
        launch(0, n)
        return
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    bounds = np.linspace(0, n, threads + 1).astype(np.int64)
    with ThreadPoolExecutor(threads, thread_name_prefix="warp-chunks") as pool:
        futures = [pool.submit(launch, int(bounds[k]), int(bounds[k + 1])) for k in range(threads)]
        for future in futures:
            future.result()
