"""Training checkpoints as safetensors + JSON (no pickle): model weights, Adam state, extra tensors.

A checkpoint ``NAME.safetensors`` holds tensors under prefixes ``model.``, ``optim.<param>.<key>`` and
``extra.``; its JSON metadata (safetensors' string header) holds the step and any JSON-able facts. Writes
are atomic (temporary file + rename), so an interrupted run keeps the previous checkpoint.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from .errors import InputError


def save_checkpoint(
    path,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer | None,
    extra: dict[str, torch.Tensor] | None = None,
    meta: dict | None = None,
) -> None:
    """Write model (+ optimizer state, extra tensors, JSON ``meta``) to ``path`` atomically; a disk full or
    I/O error is a :class:`neural.errors.WriteError` and keeps the previous checkpoint."""
    from .asset import write_safetensors

    tensors = {f"model.{k}": v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    if optimizer is not None:
        state = optimizer.state_dict()
        for pid, pstate in state["state"].items():
            for key, value in pstate.items():
                tensors[f"optim.{pid}.{key}"] = torch.as_tensor(value).detach().contiguous().cpu()
    for key, value in (extra or {}).items():
        tensors[f"extra.{key}"] = value.detach().contiguous().cpu()
    header = {"meta": json.dumps(meta or {})}
    write_safetensors(path, tensors, header)


def load_checkpoint(
    path, model: torch.nn.Module, optimizer: torch.optim.Optimizer | None = None
) -> tuple[dict, dict[str, torch.Tensor]]:
    """Restore ``model`` (and ``optimizer``) from ``path``; returns (meta, extra tensors)."""
    from safetensors import safe_open

    path = Path(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = json.loads((f.metadata() or {}).get("meta", "{}"))
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as err:  # safetensors raises several error types for corrupt files
        raise InputError(f"{path}: cannot read checkpoint ({err})") from None
    device = next(model.parameters()).device
    model_state = {k[len("model.") :]: v for k, v in tensors.items() if k.startswith("model.")}
    try:
        model.load_state_dict(model_state)
    except RuntimeError as err:
        raise InputError(f"{path}: weights do not fit this field configuration ({err})") from None
    if optimizer is not None:
        state = optimizer.state_dict()
        restored: dict = {}
        for key, value in tensors.items():
            if key.startswith("optim."):
                _, pid, name = key.split(".", 2)
                restored.setdefault(int(pid), {})[name] = value if name == "step" else value.to(device)
        state["state"] = restored
        optimizer.load_state_dict(state)
    extra = {k[len("extra.") :]: v.to(device) for k, v in tensors.items() if k.startswith("extra.")}
    return meta, extra
