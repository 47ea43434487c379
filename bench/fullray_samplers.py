"""The full-ray samplers that :mod:`neural.render.fullray`'s stepped sampler was chosen against, kept for
``bench/sampler_bench.py``:

* :func:`uniform_samples` - a fixed number of equal sections between each ray's near and far distance;
* :func:`importance_samples` - NeuS's coarse-to-fine sampler: uniform coarse samples, then rounds of inverse
  CDF sampling of the analytic NeuS weights with a doubling fixed kernel sharpness.

Both return packed :class:`~neural.render.samples.RaySamples` like the library's samplers. Tested in
``tests/test_bench_samplers.py``.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from neural.render.fullray import _check_near_far, _check_rays, pack_dense, step_offsets
from neural.render.neus import neus_alpha
from neural.render.samples import RaySamples


def uniform_samples(
    near: torch.Tensor,
    far: torch.Tensor,
    n_samples: int,
    perturb: bool = False,
    generator: torch.Generator | None = None,
) -> RaySamples:
    """``n_samples`` equal sections between ``near`` and ``far`` on every ray with ``far > near``.

    Section k of ray r is ``[near + (k + u) step, near + (k + 1 + u) step]`` with ``step = (far - near) / n``
    and ``u = 0``, or ``u ~ U[0, 1)`` per ray when ``perturb`` (the last section then reaches past ``far``
    by up to one step). near, far : (R,). Rays that miss get no sample.
    """
    _check_near_far(near, far)
    if n_samples < 1:
        raise ValueError(f"n_samples must be >= 1, got {n_samples}")
    step = (far - near) / n_samples
    k = torch.arange(n_samples, dtype=near.dtype, device=near.device)
    starts = (
        near[:, None] + (k + step_offsets(near.shape[0], near, perturb, generator)[:, None]) * step[:, None]
    )
    valid = (far > near)[:, None].expand(-1, n_samples)
    return pack_dense(starts, starts + step[:, None], valid)


def sample_pdf(bins: torch.Tensor, weights: torch.Tensor, n_samples: int) -> torch.Tensor:
    """Deterministic inverse-CDF sampling of a piecewise-constant density over bins.

    bins : (R, B + 1) sorted bin edges ; weights : (R, B) >= 0 bin masses (a small floor keeps the CDF
    strictly increasing) ; n_samples : N. Returns (R, N) sorted t with ``CDF(t) = (i + 0.5) / N``, where the
    CDF is the piecewise-linear one of the normalised weights.
    """
    weights = weights + 1e-5
    cdf = torch.cumsum(weights, dim=-1) / weights.sum(dim=-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(cdf[:, :1]), cdf], dim=-1)  # (R, B + 1)
    u = (torch.arange(n_samples, dtype=bins.dtype, device=bins.device) + 0.5) / n_samples
    u = u.expand(bins.shape[0], n_samples).contiguous()
    above = torch.searchsorted(cdf, u, right=True).clamp(1, bins.shape[1] - 1)
    below = above - 1
    cdf_lo, cdf_hi = cdf.gather(1, below), cdf.gather(1, above)
    bin_lo, bin_hi = bins.gather(1, below), bins.gather(1, above)
    frac = (u - cdf_lo) / torch.clamp(cdf_hi - cdf_lo, min=1e-12)
    return bin_lo + frac.clamp(0.0, 1.0) * (bin_hi - bin_lo)


def neus_weights(z: torch.Tensor, sdf: torch.Tensor, inv_s: float) -> torch.Tensor:
    """NeuS up-sampling weights (R, N - 1) of the sections between points ``z`` (R, N) with SDF ``sdf``.

    The slope along the ray is estimated by finite differences, taking the smaller of the section's and its
    predecessor's and clamping it to [-1e3, 0] as in NeuS.
    """
    dz = z[:, 1:] - z[:, :-1]
    slope = (sdf[:, 1:] - sdf[:, :-1]) / (dz + 1e-5)
    prev_slope = torch.cat([torch.zeros_like(slope[:, :1]), slope[:, :-1]], dim=1)
    slope = torch.minimum(slope, prev_slope).clamp(-1e3, 0.0)
    mid_sdf = 0.5 * (sdf[:, 1:] + sdf[:, :-1])
    alpha = neus_alpha(
        mid_sdf.reshape(-1), torch.full_like(mid_sdf, inv_s).reshape(-1), slope.reshape(-1), dz.reshape(-1)
    ).reshape(dz.shape)
    keep = torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha[:, :-1] + 1e-7], dim=1)
    return alpha * torch.cumprod(keep, dim=1)


def importance_samples(
    sdf_fn: Callable[[torch.Tensor], torch.Tensor],
    origins: torch.Tensor,
    dirs: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    n_coarse: int = 64,
    n_fine: int = 64,
    n_rounds: int = 4,
    base_inv_s: float = 64.0,
    perturb: bool = False,
    generator: torch.Generator | None = None,
) -> RaySamples:
    """NeuS's hierarchical sampler (Wang et al. 2021, Sec. 3.4), packed.

    ``n_coarse`` points span ``[near, far]`` (shifted together by up to half a spacing when ``perturb``);
    then ``n_rounds`` times, ``n_fine / n_rounds`` points are drawn by inverse CDF from the NeuS weights of
    the current points with the fixed sharpness ``base_inv_s * 2**i`` (slope from finite differences of the
    SDF), and merged. The ``n_coarse + n_fine`` sorted points bound ``n_coarse + n_fine - 1`` sections.

    sdf_fn : x (N, 3) -> sdf (N,), called without gradient on
        ``n_coarse + n_fine * (n_rounds - 1) / n_rounds`` points per ray.
    base_inv_s : first round's sharpness in 1 / world units (NeuS's 64 suits a scene of unit radius).
    origins, dirs : (R, 3) ; near, far : (R,) as from :func:`ray_aabb`. Rays with ``far <= near`` get none.
    """
    _check_rays(origins, dirs)
    _check_near_far(near, far)
    if n_coarse < 2 or n_rounds < 1 or n_fine % n_rounds != 0:
        raise ValueError(
            f"need n_coarse >= 2 and n_fine a multiple of n_rounds >= 1, got {n_coarse}, {n_fine}, {n_rounds}"
        )
    rays = torch.nonzero(far > near).squeeze(1)
    o, d, lo, hi = origins[rays], dirs[rays], near[rays], far[rays]
    frac = torch.linspace(0.0, 1.0, n_coarse, dtype=near.dtype, device=near.device).expand(rays.shape[0], -1)
    if perturb:
        frac = frac + (step_offsets(rays.shape[0], near, perturb, generator)[:, None] - 0.5) / (n_coarse - 1)
    z = lo[:, None] + (hi - lo)[:, None] * frac

    def sdf_at(t: torch.Tensor) -> torch.Tensor:
        return sdf_fn((o[:, None, :] + t[..., None] * d[:, None, :]).reshape(-1, 3)).reshape(t.shape)

    with torch.no_grad():
        sdf = sdf_at(z)
        for i in range(n_rounds):
            new_z = sample_pdf(z, neus_weights(z, sdf, base_inv_s * 2**i), n_fine // n_rounds)
            z, order = torch.sort(torch.cat([z, new_z], dim=1), dim=1)
            if i + 1 < n_rounds:
                sdf = torch.cat([sdf, sdf_at(new_z)], dim=1).gather(1, order)
    n_sections = z.shape[1] - 1
    return RaySamples(
        rays.repeat_interleave(n_sections),
        z[:, :-1].reshape(-1),
        z[:, 1:].reshape(-1),
        origins.shape[0],
    )
