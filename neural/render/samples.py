"""Packed ray samples shared by every sampler (full-ray, occupancy grid, narrow band) and the compositor.

Samples of all rays are stored flat, sorted by ray and by distance within a ray (nerfacc style):
``ray_indices`` (S,) int64, ``t_starts`` (S,) and ``t_ends`` (S,) float32 bounding each sample's section
along its ray; the sample itself sits at ``t_mid``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RaySamples:
    """S samples over ``n_rays`` rays. ``t_mid`` defaults to the section midpoints."""

    ray_indices: torch.Tensor  # (S,) int64, non-decreasing
    t_starts: torch.Tensor  # (S,) float32
    t_ends: torch.Tensor  # (S,) float32
    n_rays: int
    t_positions: torch.Tensor | None = None  # (S,) sample positions when not the section midpoints

    @property
    def t_mid(self) -> torch.Tensor:
        """(S,) distance of each sample along its ray."""
        if self.t_positions is not None:
            return self.t_positions
        return 0.5 * (self.t_starts + self.t_ends)

    @property
    def deltas(self) -> torch.Tensor:
        """(S,) section lengths."""
        return self.t_ends - self.t_starts

    def counts(self) -> torch.Tensor:
        """(n_rays,) int64 number of samples per ray."""
        return torch.bincount(self.ray_indices, minlength=self.n_rays)

    def select(self, keep: torch.Tensor) -> RaySamples:
        """The samples where ``keep`` (S,) bool is true, or at the increasing indices ``keep`` (K,) int64,
        over the same rays."""
        return RaySamples(
            self.ray_indices[keep], self.t_starts[keep], self.t_ends[keep], self.n_rays, self.t_mid[keep]
        )

    def points(self, origins: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """(S, 3) sample positions, given ray ``origins`` and ``dirs`` (n_rays, 3)."""
        rays = self.ray_indices  # index_select: a third of the time of origins[rays] on a CPU
        return origins.index_select(0, rays) + self.t_mid[:, None] * dirs.index_select(0, rays)
