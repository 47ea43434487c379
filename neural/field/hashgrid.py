"""Multi-resolution hash encoding (Mueller et al. 2022, Instant-NGP), as used by the paper's field (Sec. 4.1).

Level ``l`` of ``L`` is a grid of resolution ``N_l = floor(base * b^l)``,
``b = exp((ln max - ln base) / (L-1))``, with a feature vector of ``F`` floats at each of its ``(N_l+1)^3``
vertices. The vertex features live in row ``l`` of one table ``(L, T, F)``: one-to-one
(``x + y (N_l+1) + z (N_l+1)^2``) where ``(N_l+1)^3 <= T``, otherwise through the spatial hash
``(x * 1 xor y * 2654435761 xor z * 805459861) mod T`` (uint32 arithmetic). A point ``p`` in ``[0,1]^3``
(clamped) sits in the cell ``floor(p N_l)`` (the last cell for ``p = 1``); its level feature is the trilinear
interpolation of the cell's 8 corners. The levels' features are concatenated level-major: ``out[:, l F + f]``.

:func:`hash_encode_torch` is the slow, obviously-correct reference; the Warp kernels of
:mod:`neural.field.hashgrid_warp` compute the same values and table gradients.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..config import BACKENDS, HashGridConfig
from ..device import cpu_threads

PRIMES = (1, 2654435761, 805459861)


def is_dense(resolution: int, table_size: int) -> bool:
    """True where a level of this resolution is stored one-to-one (``(N+1)^3 <= T``)."""
    return (resolution + 1) ** 3 <= table_size


def check_encode_inputs(x: torch.Tensor, table: torch.Tensor, resolutions: Sequence[int]) -> None:
    """Shared validation of :func:`hash_encode_torch` and the Warp twin; raises ValueError."""
    if not isinstance(x, torch.Tensor) or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x: expected a (N, 3) tensor, got {getattr(x, 'shape', type(x))}")
    if not isinstance(table, torch.Tensor) or table.ndim != 3:
        raise ValueError(f"table: expected a (L, T, F) tensor, got {getattr(table, 'shape', type(table))}")
    n_levels, table_size, _ = table.shape
    if table_size & (table_size - 1):
        raise ValueError(f"table: T must be a power of two, got shape {tuple(table.shape)}")
    if len(resolutions) != n_levels or any(int(r) < 1 for r in resolutions):
        raise ValueError(
            f"resolutions: expected {n_levels} positive ints (one per table level), got {list(resolutions)}"
        )
    if x.device != table.device:
        raise ValueError(f"x: on {x.device}, table on {table.device}; they must share a device")


def corner_index(corner: torch.Tensor, resolution: int, table_size: int) -> torch.Tensor:
    """Table row of integer grid vertices ``corner`` (N, 3) int64 of one level -> (N,) int64."""
    if is_dense(resolution, table_size):
        side = resolution + 1
        return corner[:, 0] + side * (corner[:, 1] + side * corner[:, 2])
    h = (corner[:, 0] * PRIMES[0]) ^ (corner[:, 1] * PRIMES[1]) ^ (corner[:, 2] * PRIMES[2])
    return (h & 0xFFFFFFFF) % table_size


def hash_encode_torch(x: torch.Tensor, table: torch.Tensor, resolutions: Sequence[int]) -> torch.Tensor:
    """Reference hash encoding, differentiable by autograd in ``table`` (and, almost everywhere, in ``x``).

    x (N, 3) points in [0, 1]^3 (clamped), table (L, T, F), resolutions L ints
    -> (N, L*F) in the dtype of ``table``.
    """
    check_encode_inputs(x, table, resolutions)
    n_levels, table_size, _ = table.shape
    x = x.to(table.dtype).clamp(0.0, 1.0)
    corners = torch.tensor(
        [[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], device=x.device, dtype=torch.int64
    )
    features = []
    for level, resolution in enumerate(int(r) for r in resolutions):
        p = x * resolution
        cell = torch.floor(p).clamp(max=resolution - 1)
        frac = p - cell  # (N, 3) in [0, 1]
        cell = cell.to(torch.int64)
        acc = 0.0
        for offset in corners:
            weight = torch.where(offset.bool(), frac, 1.0 - frac).prod(dim=1)  # (N,)
            rows = corner_index(cell + offset, resolution, table_size)
            acc = acc + weight[:, None] * table[level, rows]
        features.append(acc)
    return torch.cat(features, dim=1)


class HashGridEncoding(nn.Module):
    """Psi(x): (N, 3) points in [0,1]^3 -> (N, L*F) features, with a learnable table (L, T, F) float32.

    ``backend`` "warp" (default; CPU and CUDA kernels, table gradient only) or "torch" (the reference).
    ``cpu_threads`` Python threads split the levels of a Warp CPU launch (see :mod:`.hashgrid_warp`).
    The table starts uniform in (-1e-4, 1e-4) as in Instant-NGP.
    """

    def __init__(self, config: HashGridConfig | None = None, backend: str = "warp", cpu_threads: int = 2):
        super().__init__()
        self.config = config or HashGridConfig()
        if backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
        if not isinstance(cpu_threads, int) or cpu_threads < 1:
            raise ValueError(f"cpu_threads: expected a positive int, got {cpu_threads!r}")
        self.backend = backend
        self.cpu_threads = cpu_threads
        self.resolutions = self.config.resolutions()
        shape = (self.config.n_levels, self.config.table_size, self.config.n_features_per_level)
        self.table = nn.Parameter(torch.empty(shape, dtype=torch.float32).uniform_(-1e-4, 1e-4))

    @property
    def out_dim(self) -> int:
        return self.config.out_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) in [0,1]^3 -> (N, L*F). The Warp backend gives no gradient with respect to ``x``."""
        if self.backend == "torch":
            return hash_encode_torch(x, self.table, self.resolutions)
        from .hashgrid_warp import hash_encode_warp

        threads = min(self.cpu_threads, cpu_threads())  # no more than this process was given
        return hash_encode_warp(x, self.table, self.resolutions, cpu_threads=threads)

    def extra_repr(self) -> str:
        return f"{self.config}, backend={self.backend!r}"
