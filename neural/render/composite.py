"""Front-to-back compositing of packed samples (paper Eq. 2).

``weights_i = T_i alpha_i`` with the transmittance ``T_i = prod_{j < i} (1 - alpha_j)`` taken over the
samples of the same ray, in the packed layout of :class:`~neural.render.samples.RaySamples` (samples sorted by
ray, then by distance). :func:`composite` is the vectorised path; :func:`composite_reference` is its per-ray
loop twin, used by the tests.
"""

from __future__ import annotations

import torch

# 1 - alpha is clamped to this before the logarithm: a fully opaque sample ends its ray (T <= 1e-30).
MIN_TRANSMITTANCE = 1e-30


def _check_inputs(
    alpha: torch.Tensor,
    rgb: torch.Tensor,
    ray_indices: torch.Tensor,
    n_rays: int,
    t_mid: torch.Tensor | None,
    background: torch.Tensor | None,
) -> None:
    if alpha.dim() != 1:
        raise ValueError(f"alpha must have shape (S,), got {tuple(alpha.shape)}")
    n = alpha.shape[0]
    if tuple(rgb.shape) != (n, 3):
        raise ValueError(f"rgb must have shape ({n}, 3), got {tuple(rgb.shape)}")
    if tuple(ray_indices.shape) != (n,) or ray_indices.dtype not in (torch.int32, torch.int64):
        raise ValueError(
            f"ray_indices must be an int tensor of shape ({n},), "
            f"got {ray_indices.dtype} {tuple(ray_indices.shape)}"
        )
    if t_mid is not None and tuple(t_mid.shape) != (n,):
        raise ValueError(f"t_mid must have shape ({n},), got {tuple(t_mid.shape)}")
    if background is not None and tuple(background.shape) not in ((3,), (n_rays, 3)):
        raise ValueError(f"background must have shape (3,) or ({n_rays}, 3), got {tuple(background.shape)}")


def _finish(
    weights: torch.Tensor,
    rgb: torch.Tensor,
    ray_indices: torch.Tensor,
    n_rays: int,
    t_mid: torch.Tensor | None,
    background: torch.Tensor | None,
) -> dict[str, torch.Tensor]:
    """Accumulate per-ray colour, opacity and depth from the sample ``weights`` (S,)."""
    zeros = weights.new_zeros(n_rays)
    color = weights.new_zeros(n_rays, 3).index_add(0, ray_indices, weights[:, None] * rgb)
    opacity = zeros.index_add(0, ray_indices, weights)
    depth = zeros.index_add(0, ray_indices, weights * t_mid) if t_mid is not None else zeros
    if background is not None:
        color = color + (1.0 - opacity)[:, None] * background.to(color.dtype).expand(n_rays, 3)
    return {"color": color, "opacity": opacity, "depth": depth, "weights": weights}


def log_transmittance(alpha: torch.Tensor, ray_indices: torch.Tensor, n_rays: int) -> torch.Tensor:
    """(S,) float64 ``log T_i = sum_{j < i, same ray} log(1 - alpha_j)`` of packed samples: a segmented
    exclusive cumulative sum in float64 (so that the global running sum over many rays loses no precision)
    minus each ray's value at its first sample; ``1 - alpha`` is clamped to :data:`MIN_TRANSMITTANCE`.

    alpha : (S,) in [0, 1]; ray_indices : (S,) sorted; n_rays : R.
    """
    log_keep = torch.log(torch.clamp(1.0 - alpha.double(), min=MIN_TRANSMITTANCE))
    exclusive = torch.cumsum(log_keep, dim=0) - log_keep  # global exclusive sum over all rays
    counts = torch.bincount(ray_indices, minlength=n_rays)
    first = torch.cumsum(counts, dim=0) - counts  # (R,) index of each ray's first sample
    return exclusive - exclusive[first[ray_indices]]


def transmittance(alpha: torch.Tensor, ray_indices: torch.Tensor, n_rays: int) -> torch.Tensor:
    """Exclusive per-ray product ``T_i = prod_{j < i, same ray} (1 - alpha_j)`` of packed samples, the
    exponential of :func:`log_transmittance`. Differentiable; a sample with alpha == 1 passes no gradient.

    alpha : (S,) in [0, 1]; ray_indices : (S,) sorted; n_rays : R. Returns T (S,) in alpha's dtype.
    """
    return torch.exp(log_transmittance(alpha, ray_indices, n_rays)).to(alpha.dtype)


def composite(
    alpha: torch.Tensor,
    rgb: torch.Tensor,
    ray_indices: torch.Tensor,
    n_rays: int,
    t_mid: torch.Tensor | None = None,
    background: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Volume rendering of packed samples (Eq. 2 with ``1 - exp(-sigma_i delta_i)`` replaced by ``alpha_i``).

    alpha : (S,) sample opacities in [0, 1].
    rgb : (S, 3) sample colours.
    ray_indices : (S,) int, ray of each sample, non-decreasing (samples sorted by distance within a ray).
    n_rays : R.
    t_mid : (S,) sample distances, for the depth; None gives depth 0.
    background : (3,) or (R, 3) colour behind the samples, weighted by ``1 - opacity``; None adds nothing.
    Returns a dict with ``color`` (R, 3), ``opacity`` (R,) = sum of weights, ``depth`` (R,) = sum of
    ``weights * t_mid`` (not divided by the opacity) and ``weights`` (S,) = ``T_i alpha_i``.
    Rays without samples get opacity 0, depth 0 and the background colour.
    """
    _check_inputs(alpha, rgb, ray_indices, n_rays, t_mid, background)
    weights = transmittance(alpha, ray_indices, n_rays) * alpha
    return _finish(weights, rgb, ray_indices, n_rays, t_mid, background)


def composite_reference(
    alpha: torch.Tensor,
    rgb: torch.Tensor,
    ray_indices: torch.Tensor,
    n_rays: int,
    t_mid: torch.Tensor | None = None,
    background: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Slow twin of :func:`composite`: a python loop over rays with ``torch.cumprod`` inside each ray."""
    _check_inputs(alpha, rgb, ray_indices, n_rays, t_mid, background)
    pieces = []
    for ray in range(n_rays):
        a = alpha[ray_indices == ray]
        keep = torch.cat([a.new_ones(1), 1.0 - a[:-1]])
        pieces.append(torch.cumprod(keep, dim=0) * a)
    weights = torch.cat(pieces) if pieces else alpha.new_zeros(0)
    return _finish(weights, rgb, ray_indices, n_rays, t_mid, background)
