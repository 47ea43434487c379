"""NeuS opacity with a per-sample kernel (Eq. 3) and packed compositing (Eq. 2): closed forms on a sphere,
brute-force integration of the density, and the vectorised compositor against its per-ray loop twin."""

import pytest
import torch
from scenes import RecordingSphereField, SphereField

from neural.render import fullray
from neural.render.composite import composite, composite_reference, transmittance
from neural.render.fullray import render_rays, render_samples, shade_samples, stepped_samples
from neural.render.neus import annealed_cos, neus_alpha, neus_density
from neural.render.samples import RaySamples

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def phi(f, inv_s):
    return torch.sigmoid(f * inv_s)


class NoField:
    def geometry(self, x):
        raise AssertionError("the field must not be evaluated without samples")

    radiance = geometry


def sections(t_edges, ray=0, n_rays=1):
    """RaySamples of the contiguous sections between consecutive ``t_edges`` of one ray."""
    t_edges = torch.as_tensor(t_edges)
    n = t_edges.shape[0] - 1
    return RaySamples(torch.full((n,), ray, dtype=torch.int64), t_edges[:-1], t_edges[1:], n_rays)


# ---------------------------------------------------------------- neus_alpha


def test_annealed_cos_formula():
    cos = torch.tensor([-1.0, -0.5, 0.0, 0.5, 1.0])
    assert torch.allclose(annealed_cos(cos, 1.0), torch.tensor([-1.0, -0.5, 0.0, 0.0, 0.0]))
    assert torch.allclose(annealed_cos(cos, 0.0), torch.tensor([-1.0, -0.75, -0.5, -0.25, 0.0]))
    assert torch.allclose(annealed_cos(cos, 0.5), torch.tensor([-1.0, -0.625, -0.25, -0.125, 0.0]))
    with pytest.raises(ValueError, match="cos_anneal"):
        annealed_cos(cos, 1.5)


def test_alpha_equals_neus_ratio_formula():
    """The log-space evaluation equals the literal (Phi(f_prev) - Phi(f_next)) / Phi(f_prev), clamped."""
    g = torch.Generator().manual_seed(0)
    n = 2000
    sdf = torch.rand(n, generator=g, dtype=torch.float64) * 0.4 - 0.1
    inv_s = 10 ** (torch.rand(n, generator=g, dtype=torch.float64) * 3)
    cos = torch.rand(n, generator=g, dtype=torch.float64) * 2 - 1
    deltas = torch.rand(n, generator=g, dtype=torch.float64) * 0.05
    for anneal in (0.0, 0.3, 1.0):
        it = annealed_cos(cos, anneal)
        prev, nxt = phi(sdf - it * deltas / 2, inv_s), phi(sdf + it * deltas / 2, inv_s)
        literal = ((prev - nxt) / prev).clamp(0, 1)
        got = neus_alpha(sdf, inv_s, cos, deltas, anneal)
        assert torch.allclose(got, literal, rtol=1e-9, atol=1e-12)


def test_alpha_is_one_minus_exp_of_integrated_density():
    """SDF linear along the section: alpha = 1 - exp(-int sigma dtau), Eq. 3 integrated numerically."""
    g = torch.Generator().manual_seed(1)
    n = 64
    sdf = torch.rand(n, generator=g, dtype=torch.float64) * 0.2 - 0.1
    inv_s = 10 ** (torch.rand(n, generator=g, dtype=torch.float64) * 2 + 0.5)
    cos = -torch.rand(n, generator=g, dtype=torch.float64)  # entering: slope df/dtau = cos <= 0
    deltas = torch.rand(n, generator=g, dtype=torch.float64) * 0.1 + 0.01
    u = torch.linspace(-0.5, 0.5, 20001, dtype=torch.float64)
    f = sdf[:, None] + cos[:, None] * deltas[:, None] * u[None, :]  # SDF along the section
    phi_s = phi(f, inv_s[:, None])
    sigma = (-(inv_s[:, None] * phi_s * (1 - phi_s)) * cos[:, None] / phi_s).clamp(min=0)  # -dPhi/dtau / Phi
    optical_depth = torch.trapezoid(sigma, u, dim=1) * deltas
    expected = 1 - torch.exp(-optical_depth)
    assert torch.allclose(neus_alpha(sdf, inv_s, cos, deltas), expected, rtol=1e-6, atol=1e-9)
    assert torch.allclose(neus_density(f[:, 0], inv_s, cos), sigma[:, 0], rtol=1e-9)


def test_alpha_deep_inside_and_exiting():
    inv_s = torch.tensor([50.0, 50.0])
    deltas = torch.tensor([0.01, 0.01])
    sdf = torch.tensor([-5.0, -5.0])
    alpha = neus_alpha(sdf, inv_s, torch.tensor([-1.0, 1.0]), deltas)
    # entering deep inside: density -> inv_s |cos| (Eq. 3 as Phi -> 0); exiting: no density.
    assert torch.allclose(alpha[0], 1 - torch.exp(torch.tensor(-50.0 * 0.01)), rtol=1e-5)
    assert alpha[1] == 0.0


def test_alpha_gradients_finite_at_extremes():
    vals = torch.tensor([-100.0, -1.0, -1e-3, 0.0, 1e-3, 1.0, 100.0])
    sdf, inv_s, cos, deltas = torch.meshgrid(
        vals, torch.tensor([1e-3, 1.0, 1e2, 1e5]), torch.tensor([-1.0, -0.3, 0.0, 1.0]),
        torch.tensor([0.0, 1e-4, 0.1, 10.0]), indexing="ij",
    )  # fmt: skip
    leaves = [t.reshape(-1).clone().requires_grad_() for t in (sdf, inv_s, cos, deltas)]
    for anneal in (0.0, 1.0):
        alpha = neus_alpha(*leaves, cos_anneal=anneal)
        assert torch.isfinite(alpha).all() and (alpha >= 0).all() and (alpha <= 1).all()
        grads = torch.autograd.grad(alpha.sum(), leaves)
        assert all(torch.isfinite(gr).all() for gr in grads)


def test_alpha_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="shapes"):
        neus_alpha(torch.zeros(3), torch.ones(3), torch.zeros(2), torch.ones(3))


# ---------------------------------------------------------------- sphere closed forms through render_rays


@pytest.mark.parametrize("device", DEVICES)
def test_sphere_accumulated_opacity_telescopes(device):
    """Ray through the centre, sections up to it: 1 - T after sample k = 1 - Phi(f(t_k+1)) / Phi(f(t_0))."""
    radius, inv_s = 1.0, 20.0
    field = SphereField(radius, inv_s)
    origins = torch.tensor([[0.0, 0.0, -3.0]], device=device, dtype=torch.float64)
    dirs = torch.tensor([[0.0, 0.0, 1.0]], device=device, dtype=torch.float64)
    edges = torch.linspace(1.2, 2.9, 41, dtype=torch.float64)  # centre at t = 3
    out = render_rays(field, origins, dirs, _to(sections(edges), device))
    f_edges = (3.0 - edges) - radius
    expected = 1 - phi(f_edges[1:], inv_s) / phi(f_edges[0], inv_s)
    assert torch.allclose(torch.cumsum(out["weights"], 0).cpu(), expected, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("tolerance", [0.0, 1e-3, 0.05])
def test_shading_leaves_out_light_samples_within_its_bound(monkeypatch, tolerance):
    """shade_samples evaluates the geometry only until a ray's transmittance falls to tolerance / 2 and the
    radiance only where a sample's weight matters, and stays within its stated bound of the full composite
    of every sample: |full - fast| <= tolerance in every channel; with tolerance 0 the same colours. (Its
    46k samples would take a last round after the first: rounds double to the end here.)"""
    monkeypatch.setattr(fullray, "LAST_ROUND_SAMPLES", 0)

    field = RecordingSphereField(radius=1.0, inv_s=40.0)
    grid = torch.linspace(-1.2, 1.2, 24)
    xy = torch.stack(torch.meshgrid(grid, grid, indexing="ij"), -1)
    origins = torch.cat([xy.reshape(-1, 2), torch.full((576, 1), -3.0)], 1).double()
    dirs = torch.tensor([[0.1, 0.0, 1.0]], dtype=torch.float64).expand(576, 3)
    samples = stepped_samples(torch.full((576,), 1.0), torch.full((576,), 5.0), 0.05, 100)
    norm = dirs.norm(dim=1)[samples.ray_indices]
    points, unit = samples.points(origins, dirs), dirs[samples.ray_indices] / norm[:, None]
    deltas, fronts = samples.deltas * norm, (samples.t_mid - samples.t_starts) * norm
    bg = torch.tensor([0.2, 0.9, 0.5], dtype=torch.float64)
    full_out = render_samples(field, points, unit, deltas, fronts, samples, bg)
    full = full_out["color"]
    field.geometry_calls.clear()
    field.radiance_calls.clear()

    def locate(index):
        return index, points[index], unit[index], deltas[index], fronts[index]

    fast, located = shade_samples(field, samples, locate, bg, tolerance=tolerance)
    assert (full - fast).abs().max() <= tolerance + 1e-12
    assert sum(field.geometry_calls) == int(located.sum())
    if tolerance == 0:
        torch.testing.assert_close(fast, full, rtol=0, atol=1e-12)
        assert torch.equal(located, samples.counts())
    else:
        # rays through the sphere stop inside it: their samples behind it are never evaluated
        core = xy.reshape(-1, 2).norm(dim=1) < 0.5
        miss = full_out["opacity"] < 1 - tolerance / 2  # light still reaches the last sample
        assert bool((located[core] < samples.counts()[core]).all())
        assert float(located[core].double().mean()) < 0.5 * float(samples.counts()[core].double().mean())
        assert torch.equal(located[miss], samples.counts()[miss])
        assert sum(field.radiance_calls) < 0.5 * len(points)  # most samples lie before the sphere or behind
        assert (full - fast).abs().max() > 0  # weights above 0 were left out


@pytest.mark.parametrize(
    ("last_round", "rounds"),
    [(0, [60, 60, 120, 240, 480, 960, 1080]), (2100, [60, 60, 120, 240, 480, 2040]), (4096, [3000])],
)
def test_shading_takes_a_small_remainder_in_one_round(monkeypatch, last_round, rounds):
    """Rounds double (2, 2, 4, 8, ... samples per ray from a first round of 2) until at most
    LAST_ROUND_SAMPLES samples of live rays are left, which one round takes; every sample is still taken
    once, and the colours are the composite's. 30 rays of 100 samples pass far from the sphere, so light
    reaches all their samples."""
    monkeypatch.setattr(fullray, "LAST_ROUND_SAMPLES", last_round)
    field = RecordingSphereField(radius=1.0, inv_s=40.0)
    origins = torch.cat(
        [torch.full((30, 1), 4.0), torch.linspace(-1, 1, 30)[:, None], torch.full((30, 1), -3.0)], 1
    )
    dirs = torch.tensor([[0.0, 0.0, 1.0]]).expand(30, 3)
    samples = stepped_samples(torch.full((30,), 1.0), torch.full((30,), 6.0), 0.05, 100)
    assert torch.equal(samples.counts(), torch.full((30,), 100))
    points, unit = samples.points(origins, dirs), dirs[samples.ray_indices]
    deltas, fronts = samples.deltas, samples.t_mid - samples.t_starts
    bg = torch.tensor([0.2, 0.9, 0.5])
    full = render_samples(SphereField(radius=1.0, inv_s=40.0), points, unit, deltas, fronts, samples, bg)[
        "color"
    ]

    def locate(index):
        return index, points[index], unit[index], deltas[index], fronts[index]

    fast, located = shade_samples(field, samples, locate, bg, first_round=2)
    assert field.geometry_calls == rounds
    assert torch.equal(located, samples.counts())
    torch.testing.assert_close(fast, full, rtol=0, atol=1e-6)


def _to(samples, device):
    return RaySamples(
        samples.ray_indices.to(device), samples.t_starts.to(device), samples.t_ends.to(device), samples.n_rays
    )


@pytest.mark.parametrize("device", DEVICES)
def test_sharp_kernel_opacity_one_and_depth_at_surface(device):
    radius, inv_s = 0.8, 2000.0
    field = SphereField(radius, inv_s, center=(0.1, -0.2, 0.05))
    g = torch.Generator().manual_seed(3)
    # rays from a sphere of radius 3 around the centre towards points within 0.5 of it: all hit the sphere
    origins = torch.randn(64, 3, generator=g)
    origins = 3.0 * origins / origins.norm(dim=1, keepdim=True) + field.center
    target = field.center + 0.5 * (torch.rand(64, 3, generator=g) - 0.5)
    dirs = torch.nn.functional.normalize(target - origins, dim=1)
    n, t0, t1 = 512, 1.0, 5.0
    edges = torch.linspace(t0, t1, n + 1)
    samples = RaySamples(
        torch.arange(64).repeat_interleave(n), edges[:-1].repeat(64), edges[1:].repeat(64), 64
    )
    out = render_rays(field, origins.to(device), dirs.to(device), _to(samples, device))
    oc = origins - field.center
    b = (oc * dirs).sum(1)
    t_hit = -b - torch.sqrt(b * b - (oc * oc).sum(1) + radius**2)
    assert torch.allclose(out["opacity"].cpu(), torch.ones(64), atol=1e-4)
    step = (t1 - t0) / n
    assert (out["depth"].cpu() - t_hit).abs().max() < 0.5 * step + 5.0 / inv_s


def test_single_sample_straddling_surface_is_opaque():
    """One sample at the centre of a 0.2-wide interval around an opaque surface (the narrow-band case)."""
    field = SphereField(1.0, inv_s=1000.0)
    origins = torch.tensor([[0.0, 0.0, -3.0]] * 3)
    dirs = torch.tensor([[0.0, 0.0, 1.0]] * 3)
    centres = torch.tensor([2.0, 1.96, 2.04])  # surface at t = 2, within the interval in each case
    samples = RaySamples(torch.arange(3), centres - 0.1, centres + 0.1, 3)
    out = render_rays(field, origins, dirs, samples, background=torch.zeros(3))
    assert (out["alpha"] > 0.999).all()
    assert torch.allclose(out["opacity"], out["alpha"])
    assert torch.allclose(out["color"], out["rgb"] * out["alpha"][:, None])


def test_rays_without_samples_show_background():
    field = SphereField(1.0, inv_s=100.0)
    origins = torch.tensor([[0.0, 0.0, -3.0]] * 3)
    dirs = torch.tensor([[0.0, 0.0, 1.0]] * 3)
    bg = torch.tensor([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]])
    samples = RaySamples(torch.tensor([1, 1]), torch.tensor([1.9, 2.0]), torch.tensor([2.0, 2.1]), 3)
    out = render_rays(field, origins, dirs, samples, background=bg)
    assert torch.equal(out["color"][[0, 2]], bg[[0, 2]])
    assert torch.equal(out["opacity"][[0, 2]], torch.zeros(2))
    empty = RaySamples(torch.zeros(0, dtype=torch.int64), torch.zeros(0), torch.zeros(0), 3)
    out = render_rays(NoField(), origins, dirs, empty, background=bg)
    assert torch.equal(out["color"], bg) and torch.equal(out["opacity"], torch.zeros(3))
    assert out["weights"].shape == (0,) and out["geometry"] is None


def test_render_rays_scales_non_unit_directions():
    """Scaling d by k divides t by k: the same world sections give the same colour and opacity."""
    field = SphereField(1.0, inv_s=30.0)
    origins = torch.tensor([[0.0, 0.2, -3.0]], dtype=torch.float64)
    dirs = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    edges = torch.linspace(1.0, 5.0, 101, dtype=torch.float64)
    a = render_rays(field, origins, dirs, sections(edges), background=torch.ones(3, dtype=torch.float64))
    b = render_rays(
        field, origins, 2.5 * dirs, sections(edges / 2.5), background=torch.ones(3, dtype=torch.float64)
    )
    assert torch.allclose(a["color"], b["color"]) and torch.allclose(a["opacity"], b["opacity"])


# ---------------------------------------------------------------- composite


def packed_batch(generator, counts, dtype=torch.float64):
    counts = torch.as_tensor(counts)
    ray_indices = torch.repeat_interleave(torch.arange(len(counts)), counts)
    s = int(counts.sum())
    alpha = torch.rand(s, generator=generator, dtype=dtype) * 0.85 + 0.05
    rgb = torch.rand(s, 3, generator=generator, dtype=dtype)
    t_mid = torch.rand(s, generator=generator, dtype=dtype) * 4
    return alpha, rgb, ray_indices, t_mid


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("counts", [[3], [0, 4, 1, 0, 7], [5, 0, 0, 2, 6, 1, 0]])
def test_composite_matches_loop_twin_values_and_gradients(device, counts):
    g = torch.Generator().manual_seed(len(counts))
    alpha, rgb, ray_indices, t_mid = packed_batch(g, counts)
    bg = torch.rand(len(counts), 3, generator=g, dtype=torch.float64)
    leaves = [t.to(device).requires_grad_() for t in (alpha, rgb, t_mid, bg)]
    a, b = [
        fn(leaves[0], leaves[1], ray_indices.to(device), len(counts), leaves[2], leaves[3])
        for fn in (composite, composite_reference)
    ]
    probe = {k: torch.rand(v.shape, generator=g, dtype=torch.float64).to(device) for k, v in a.items()}
    for key in a:
        assert torch.allclose(a[key], b[key], rtol=1e-12, atol=1e-14), key
    ga = torch.autograd.grad(sum((a[k] * probe[k]).sum() for k in a), leaves)
    gb = torch.autograd.grad(sum((b[k] * probe[k]).sum() for k in b), leaves)
    for x, y in zip(ga, gb, strict=True):
        assert torch.allclose(x, y, rtol=1e-10, atol=1e-12)


def test_composite_gradcheck():
    g = torch.Generator().manual_seed(7)
    alpha, rgb, ray_indices, t_mid = packed_batch(g, [2, 0, 3, 1])
    bg = torch.rand(3, generator=g, dtype=torch.float64)

    def fn(alpha, rgb, t_mid, bg):
        out = composite(alpha, rgb, ray_indices, 4, t_mid, bg)
        return out["color"], out["opacity"], out["depth"], out["weights"]

    inputs = tuple(t.clone().requires_grad_() for t in (alpha, rgb, t_mid, bg))
    assert torch.autograd.gradcheck(fn, inputs)


def test_composite_closed_forms():
    """Constant alpha a over n samples: opacity 1 - (1 - a)^n, weights a (1 - a)^i."""
    a, n = 0.3, 6
    alpha = torch.full((n,), a, dtype=torch.float64)
    out = composite(alpha, torch.ones(n, 3, dtype=torch.float64), torch.zeros(n, dtype=torch.int64), 1,
                    background=torch.zeros(3, dtype=torch.float64))  # fmt: skip
    assert torch.allclose(out["weights"], a * (1 - a) ** torch.arange(n, dtype=torch.float64))
    assert torch.allclose(out["opacity"], torch.tensor([1 - (1 - a) ** n], dtype=torch.float64))
    assert torch.allclose(out["color"], out["opacity"][:, None].expand(1, 3))


def test_transmittance_stays_exact_over_many_rays():
    """Float64 segmented sums: the last ray of a long batch still gets the exact per-ray product."""
    n_rays, per_ray = 20000, 50
    alpha = torch.full((n_rays * per_ray,), 0.5)
    ray_indices = torch.arange(n_rays).repeat_interleave(per_ray)
    trans = transmittance(alpha, ray_indices, n_rays).reshape(n_rays, per_ray)
    expected = 0.5 ** torch.arange(per_ray, dtype=torch.float32)
    assert torch.allclose(trans, expected.expand(n_rays, -1), rtol=1e-6, atol=0)


def test_opaque_sample_ends_the_ray_with_finite_gradient():
    alpha = torch.tensor([0.2, 1.0, 0.5, 0.7], requires_grad=True)
    rgb = torch.rand(4, 3)
    out = composite(alpha, rgb, torch.zeros(4, dtype=torch.int64), 1)
    assert torch.allclose(out["weights"].detach(), torch.tensor([0.2, 0.8, 0.0, 0.0]))
    (grad,) = torch.autograd.grad(out["color"].sum(), alpha)
    assert torch.isfinite(grad).all()


def test_composite_validates_shapes():
    with pytest.raises(ValueError, match="rgb"):
        composite(torch.zeros(3), torch.zeros(3, 4), torch.zeros(3, dtype=torch.int64), 1)
    with pytest.raises(ValueError, match="background"):
        composite(
            torch.zeros(3), torch.zeros(3, 3), torch.zeros(3, dtype=torch.int64), 2, background=torch.ones(4)
        )
