"""bench/fullray_samplers.py (the samplers bench/sampler_bench.py compares with the library's stepped one):
uniform sections, inverse-CDF sampling against its closed form, NeuS weights and importance sampling on an
analytic sphere."""

import sys
from pathlib import Path

import pytest
import torch
from scenes import SphereField
from test_fullray import random_rays, sphere_sdf

from neural.render.fullray import ray_aabb, render_rays

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from fullray_samplers import importance_samples, neus_weights, sample_pdf, uniform_samples  # noqa: E402


@pytest.mark.parametrize("perturb", [False, True])
def test_uniform_samples_fixed_count_contiguous(perturb):
    near = torch.tensor([1.0, 2.0, 0.5, 3.0])
    far = torch.tensor([3.0, 2.0, 4.0, 1.0])  # rays 1 and 3 miss
    s = uniform_samples(near, far, 16, perturb=perturb, generator=torch.Generator().manual_seed(0))
    assert s.counts().tolist() == [16, 0, 16, 0]
    starts, ends = s.t_starts.reshape(2, 16), s.t_ends.reshape(2, 16)
    step = ((far - near)[[0, 2]] / 16)[:, None]
    assert torch.allclose(ends - starts, step.expand(2, 16))
    assert torch.allclose(starts[:, 1:], ends[:, :-1])
    shift = starts[:, :1] - near[[0, 2], None]
    if perturb:
        assert ((shift >= 0) & (shift < step)).all() and (shift > 0).any()
    else:
        assert torch.allclose(starts[:, 0], near[[0, 2]]) and torch.allclose(ends[:, -1], far[[0, 2]])


def test_sample_pdf_inverts_the_piecewise_linear_cdf():
    g = torch.Generator().manual_seed(2)
    bins = torch.sort(torch.rand(5, 9, generator=g, dtype=torch.float64) * 3, dim=1).values
    weights = torch.rand(5, 8, generator=g, dtype=torch.float64)
    weights[0, 2:6] = 0.0  # empty bins get (almost) no samples
    n = 200
    t = sample_pdf(bins, weights, n)
    u = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    w = weights + 1e-5
    cdf = torch.cat([torch.zeros(5, 1, dtype=torch.float64), torch.cumsum(w, 1) / w.sum(1, keepdim=True)], 1)
    for r in range(5):  # closed form: CDF at the samples, by linear interpolation within each bin
        k = torch.clamp(torch.searchsorted(bins[r], t[r], right=True), 1, 8)
        frac = (t[r] - bins[r, k - 1]) / (bins[r, k] - bins[r, k - 1])
        assert torch.allclose(cdf[r, k - 1] + frac * (cdf[r, k] - cdf[r, k - 1]), u, atol=1e-9)
    assert (t[:, 1:] >= t[:, :-1]).all()
    assert ((t[0] > bins[0, 2]) & (t[0] < bins[0, 6])).sum() <= 1


def testneus_weights_peak_at_the_surface():
    z = torch.linspace(0.0, 4.0, 81)[None]
    sdf = 2.0 - z  # surface at z = 2
    w = neus_weights(z, sdf, inv_s=64.0)
    mid = 0.5 * (z[0, 1:] + z[0, :-1])
    assert abs(float(mid[w[0].argmax()]) - 2.0) <= 0.05
    assert abs(float(w.sum()) - 1.0) < 1e-3


def test_importance_samples_concentrate_at_the_surface_and_render_accurately():
    radius = 0.7
    field = SphereField(radius, inv_s=400.0)
    origins, dirs = random_rays(128, 4, spread=0.35)  # every ray hits the sphere
    near, far = ray_aabb(origins, dirs, -torch.ones(3), torch.ones(3))
    s = importance_samples(sphere_sdf(radius), origins, dirs, near, far, n_coarse=32, n_fine=32, n_rounds=4)
    assert s.counts().tolist() == [63] * 128
    starts = s.t_starts.reshape(128, 63)
    assert torch.allclose(starts[:, 1:], s.t_ends.reshape(128, 63)[:, :-1])
    assert (starts[:, 0] >= near - 1e-6).all() and (s.t_ends.reshape(128, 63)[:, -1] <= far + 1e-6).all()
    b = (origins * dirs).sum(1)
    t_hit = -b - torch.sqrt(b * b - (origins * origins).sum(1) + radius**2)
    near_surface = (s.t_mid - t_hit[s.ray_indices]).abs() < 0.05
    assert near_surface.float().mean() > 0.3  # vs 0.1 / 2.6 ~ 4% for uniform samples
    out = render_rays(field, origins, dirs, s)
    assert torch.allclose(out["opacity"], torch.ones(128), atol=1e-3)
    assert (out["depth"] - t_hit).abs().max() < 0.01
    uniform = render_rays(field, origins, dirs, uniform_samples(near, far, 63))
    assert (uniform["depth"] - t_hit).abs().max() > (out["depth"] - t_hit).abs().max()


def test_importance_samples_skip_missing_rays():
    origins = torch.tensor([[0.0, 0.0, -3.0], [5.0, 5.0, -3.0]])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    near, far = ray_aabb(origins, dirs, -torch.ones(3), torch.ones(3))
    s = importance_samples(sphere_sdf(0.5), origins, dirs, near, far, n_coarse=8, n_fine=8, n_rounds=2)
    assert s.counts().tolist() == [15, 0] and s.n_rays == 2
