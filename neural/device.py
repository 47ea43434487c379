"""Device choice shared by torch and Warp code: ``cuda`` when present, else ``cpu``."""

from __future__ import annotations

from .errors import InputError


def pick_device(name: str | None = None) -> str:
    """Return ``"cuda"`` or ``"cpu"``.

    ``name`` None or ``"auto"`` picks ``cuda`` when torch sees a GPU; an explicit ``"cuda"`` without one
    is an :class:`InputError`.
    """
    import torch

    if name in (None, "auto"):
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name not in ("cpu", "cuda"):
        raise InputError(f"--device: expected cpu, cuda or auto, got {name!r}")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available on this machine")
    return name


def warp_device(torch_device: str) -> str:
    """The Warp device string matching a torch device (``"cpu"`` or ``"cuda:0"``)."""
    return "cpu" if str(torch_device).startswith("cpu") else "cuda:0"
