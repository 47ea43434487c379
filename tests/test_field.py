"""Field: SH basis against quadrature and scipy, sphere initialisation, world units, forward/backward."""

import json
import math

import numpy as np
import pytest
import torch
from scipy.special import sph_harm_y

from neural.errors import InputError
from neural.field import FieldConfig, HashGridConfig, ShellField, spherical_harmonics

SMALL_GRID = HashGridConfig(log2_table_size=12, base_resolution=4, max_resolution=128)


def small_config(**kw) -> FieldConfig:
    return FieldConfig(hashgrid=SMALL_GRID, **kw)


def sphere_quadrature(n_z=8, n_phi=16):
    """Gauss-Legendre in z times uniform phi: exact for polynomials of degree <= 15 on the sphere."""
    z, wz = np.polynomial.legendre.leggauss(n_z)
    phi = 2 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    dirs = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    weights = (wz[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None]).reshape(-1)
    return torch.from_numpy(dirs), torch.from_numpy(weights)


def test_sh_basis_is_orthonormal_on_the_sphere():
    dirs, weights = sphere_quadrature()
    y = spherical_harmonics(dirs)  # float64 in, float64 out
    gram = y.T @ (weights[:, None] * y)
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), rtol=0, atol=1e-12)


def test_sh_basis_equals_scipy_real_harmonics():
    """Real SH from scipy's complex Y_l^m (Condon-Shortley phase): sqrt2 Im for m<0, sqrt2 Re for m>0."""
    rng = np.random.default_rng(3)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    theta, phi = np.arccos(d[:, 2]), np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    expected = []
    for l in range(4):
        for m in range(-l, l + 1):
            y = sph_harm_y(l, abs(m), theta, phi)
            expected.append(np.sqrt(2) * y.imag if m < 0 else y.real if m == 0 else np.sqrt(2) * y.real)
    got = spherical_harmonics(torch.from_numpy(d)).numpy()
    np.testing.assert_allclose(got, np.stack(expected, 1), atol=1e-12)


def test_sh_closed_form_values_on_the_pole():
    y = spherical_harmonics(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))[0]
    for l in range(4):  # Y_l^0 at the north pole = sqrt((2l+1) / 4pi); every m != 0 vanishes
        band = y[l * l : (l + 1) * (l + 1)]
        assert band[l].item() == pytest.approx(math.sqrt((2 * l + 1) / (4 * math.pi)), rel=1e-12)
        assert torch.count_nonzero(torch.cat([band[:l], band[l + 1 :]])) == 0


def unit_ball_points(n, seed=0):
    gen = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=1)
    return d * torch.rand(n, 1, generator=gen) * 0.95


def test_sphere_initialisation_gives_the_sphere_sdf_and_normals():
    field = ShellField(small_config(init_radius=0.4, init_inv_s=30.0))
    u = unit_ball_points(4000)
    r = u.norm(dim=1)
    with torch.no_grad():
        geo = field.geometry(u)
    err = (geo.sdf - (r - 0.4)).abs()
    assert err[(r - 0.4).abs() < 0.15].max() < 0.01  # near the surface
    assert err.max() < 0.04  # the softplus rounds the cone tip at u = 0
    away = r > 0.05
    assert (geo.normal[away] - u[away] / r[away, None]).norm(dim=1).max() < 0.03
    torch.testing.assert_close(geo.normal.norm(dim=1), torch.ones(len(u)))
    torch.testing.assert_close(geo.inv_s, torch.full((len(u),), 30.0))
    torch.testing.assert_close(field.sdf(u), geo.sdf)


def finite_difference_gradient(fn, x, eps):
    offsets = torch.eye(3) * eps
    return torch.stack([(fn(x + o) - fn(x - o)) / (2 * eps) for o in offsets], dim=1)


def test_world_units_scale_sdf_and_kernel_and_keep_the_eikonal_norm():
    center, scale = torch.tensor([1.0, -2.0, 0.5]), 4.0
    unit = ShellField(small_config())
    world = ShellField(small_config(), center=center, scale=scale)
    with torch.no_grad():
        noise = torch.Generator().manual_seed(0)
        for p in unit.geo_hidden.parameters():  # some non-radial content, so this is not only a sphere
            p.add_(0.05 * torch.randn(p.shape, generator=noise))
        world.load_state_dict(unit.state_dict() | {"center": center, "scale": torch.tensor(scale)})
        x = center + unit_ball_points(500, seed=1) / scale
        u = (x - center) * scale  # the unit points of x as the field computes them: the same cells
        g_unit, g_world = unit.geometry(u), world.geometry(x)
        torch.testing.assert_close(g_world.sdf, g_unit.sdf / scale)
        torch.testing.assert_close(g_world.inv_s, g_unit.inv_s * scale)
        torch.testing.assert_close(g_world.sdf * g_world.inv_s, g_unit.sdf * g_unit.inv_s)  # f / s scale-free
        torch.testing.assert_close(g_world.normal, g_unit.normal, rtol=0, atol=1e-4)
        sdf, s = world.sdf_and_kernel(x, chunk=77)
        torch.testing.assert_close(sdf, g_world.sdf)
        torch.testing.assert_close(s, 1.0 / g_world.inv_s)
        grad_u = finite_difference_gradient(unit.sdf, u, 1e-3).norm(dim=1)
        grad_x = finite_difference_gradient(world.sdf, x, 1e-3 / scale).norm(dim=1)
        torch.testing.assert_close(grad_x, grad_u, rtol=2e-3, atol=2e-3)


def test_eikonal_norm_is_one_at_initialisation():
    field = ShellField(small_config(), center=(0.3, 0.0, 0.0), scale=2.0)
    u = unit_ball_points(500, seed=2)
    u = u[u.norm(dim=1) > 0.2]
    with torch.no_grad():
        grad = finite_difference_gradient(field.sdf, field.center + u / 2.0, 1e-3)
    assert (grad.norm(dim=1) - 1).abs().max() < 0.05


@pytest.mark.parametrize("backend", ["warp", "torch"])
def test_forward_backward_on_cpu(backend):
    torch.manual_seed(0)
    field = ShellField(small_config(backend=backend), center=(0.0, 0.0, 1.0), scale=2.0)
    with torch.no_grad():  # what one Adam step does: the encoding's weights leave zero
        field.geo_hidden.weight[:, : field.encoding.out_dim].normal_(0.0, 0.1)
    x = torch.tensor([0.0, 0.0, 1.0]) + unit_ball_points(256) / 2.0
    d = torch.randn(256, 3)
    geo, rgb = field(x, d)
    assert geo.sdf.shape == geo.inv_s.shape == (256,) and geo.feature.shape == (256, 26)
    assert (
        geo.normal.shape == rgb.shape == (256, 3) and ((rgb > 0) & (rgb < 1)).all() and (geo.inv_s > 0).all()
    )
    (rgb.sum() + geo.sdf.square().sum() + geo.inv_s.log().sum() + geo.normal.sum()).backward()
    for name, p in field.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name


def test_backends_give_the_same_field():
    torch.manual_seed(0)
    fields = [ShellField(small_config(backend=b)) for b in ("warp", "torch")]
    fields[1].load_state_dict(fields[0].state_dict())
    grads = []
    for f in fields:
        with torch.no_grad():
            f.geo_hidden.weight[:, : f.encoding.out_dim] = 0.5
            f.encoding.table.normal_(0.0, 0.1, generator=torch.Generator().manual_seed(1))
        geo, rgb = f(unit_ball_points(300), torch.randn(300, 3, generator=torch.Generator().manual_seed(2)))
        (geo.sdf.sum() + rgb.sum()).backward()
        grads.append((geo.sdf.detach(), rgb.detach(), f.encoding.table.grad))
    for a, b in zip(*grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_config_round_trip_and_rebuild():
    field = ShellField(small_config(init_inv_s=25.0), center=(1, 2, 3), scale=0.5)
    data = json.loads(json.dumps(field.config_dict()))
    rebuilt = ShellField.from_config_dict(data, center=(1, 2, 3), scale=0.5)
    assert rebuilt.config == field.config
    rebuilt.load_state_dict(field.state_dict())
    x = torch.randn(10, 3)
    torch.testing.assert_close(rebuilt.sdf_and_kernel(x), field.sdf_and_kernel(x))
    with pytest.raises(InputError, match="unknown keys \\['hidden'\\]"):
        FieldConfig.from_dict(data | {"hidden": 3})
    with pytest.raises(InputError, match="init_radius"):
        FieldConfig.from_dict(data | {"init_radius": 2.0})
    with pytest.raises(InputError, match="hashgrid"):
        FieldConfig.from_dict(data | {"hashgrid": {"levels": 3}})


def test_invalid_inputs_are_rejected():
    field = ShellField(small_config())
    with pytest.raises(ValueError, match="x: expected a \\(N, 3\\)"):
        field.geometry(torch.zeros(4, 2))
    geo = field.geometry(torch.zeros(4, 3))
    with pytest.raises(ValueError, match="d: expected 4 directions"):
        field.radiance(torch.zeros(4, 3), torch.ones(3, 3), geo)
    with pytest.raises(ValueError, match="scale"):
        ShellField(small_config(), scale=0.0)
    with pytest.raises(ValueError, match="center"):
        ShellField(small_config(), center=(0.0, 1.0))
    with pytest.raises(ValueError, match="backend"):
        small_config(backend="jax")
    sdf, s = field.sdf_and_kernel(torch.zeros(0, 3))
    assert sdf.shape == s.shape == (0,)


def test_geometry_activation_is_softplus_and_the_same_with_and_without_autograd():
    """The hidden layer computes ln(1 + exp(100 z)) / 100 of its pre-activations (float64 closed form,
    numpy's logaddexp), and a field under no_grad (rendering's chunked path) gives the same geometry as with
    autograd (training's)."""
    field = ShellField(small_config(kernel_grid=4))
    with torch.no_grad():
        for p in field.parameters():
            p.add_(0.05 * torch.randn_like(p))
    x = torch.rand(500, 3) * 2 - 1
    u = field.to_unit(x)
    with torch.no_grad():
        z = field.geo_hidden(field._geometry_input(u)).double().numpy()
        hidden = field._hidden(u).double().numpy()
    np.testing.assert_allclose(hidden, np.logaddexp(0.0, 100.0 * z) / 100.0, rtol=1e-5, atol=1e-7)
    assert (np.abs(100.0 * z) < 15).mean() > 0.1  # the curved part of softplus is exercised
    trained = field.geometry(x)
    assert trained.sdf.requires_grad
    with torch.no_grad():
        rendered = field.geometry(x)
    for a, b in zip(trained, rendered, strict=True):
        torch.testing.assert_close(a.detach(), b, rtol=0, atol=1e-6)


def test_files_without_the_newer_settings_mean_the_papers_field():
    """A field config written before kernel_grid and view_encoding existed (lego as shipped until 2026-12-02)
    loads as the paper's field: no kernel grid, SH of the view direction."""
    old = {k: v for k, v in small_config().to_dict().items() if k not in ("kernel_grid", "view_encoding")}
    config = FieldConfig.from_dict(old)
    assert (config.kernel_grid, config.view_encoding) == (0, "direction")
    assert "kernel_grid" not in dict(ShellField(config).named_parameters())
    new = small_config(kernel_grid=8)
    assert FieldConfig.from_dict(json.loads(json.dumps(new.to_dict()))) == new
    with pytest.raises(InputError, match="kernel_grid"):
        FieldConfig.from_dict(old | {"kernel_grid": 1})
    with pytest.raises(InputError, match="view_encoding"):
        FieldConfig.from_dict(old | {"view_encoding": "normal"})


def trilinear_reference(grid: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Slow twin: trilinear value of grid[z, y, x] (K, K, K) at unit points u (N, 3); node (i, j, k) sits at
    u = -1 + 2 (k, j, i) / (K - 1)."""
    k = grid.shape[0]
    out = np.zeros(len(u))
    for n, p in enumerate(u):
        g = (p + 1.0) * 0.5 * (k - 1)  # (x, y, z) in node units
        lo = np.floor(g).astype(int).clip(0, k - 2)
        t = g - lo
        for corner in np.ndindex(2, 2, 2):
            w = np.prod([t[a] if corner[a] else 1 - t[a] for a in range(3)])
            out[n] += w * grid[lo[2] + corner[2], lo[1] + corner[1], lo[0] + corner[0]]
    return out


def test_kernel_grid_adds_a_trilinear_log_kernel_offset_and_leaves_the_sdf_alone():
    """log(1/s) = the network's value + the grid's trilinear value (a slow twin), per place; f is unchanged
    and only the grid's nodes around a point get its gradient."""
    plain = ShellField(small_config(kernel_grid=0), scale=0.5)
    field = ShellField(small_config(kernel_grid=5), scale=0.5)
    field.load_state_dict(plain.state_dict() | {"kernel_grid": field.kernel_grid.detach()})
    values = torch.randn(1, 1, 5, 5, 5, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    with torch.no_grad():
        field.kernel_grid.copy_(values)
    x = (torch.rand(200, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1) * 1.9  # world; u = x / 2
    offset = torch.log(field.geometry(x).inv_s) - torch.log(plain.geometry(x).inv_s)
    ref = trilinear_reference(values[0, 0].numpy(), (x * 0.5).double().numpy())
    np.testing.assert_allclose(offset.detach().numpy(), ref, atol=2e-5)
    torch.testing.assert_close(field.sdf(x), plain.sdf(x))
    node = torch.tensor([[-1.0, 0.0, 1.0]]) * 2.0  # u = (-1, 0, 1): node x=0, y=2, z=4
    torch.log(field.geometry(node).inv_s).sum().backward()
    grad = field.kernel_grid.grad[0, 0]
    assert float(grad[4, 2, 0]) == pytest.approx(1.0)
    assert float(grad.abs().sum()) == pytest.approx(1.0)


def test_reflected_view_encoding_sees_the_direction_mirrored_about_the_normal():
    """A 'reflected' field's colour along d is the same network's colour along d - 2 (d.n) n under the
    'direction' encoding (a twin that mirrors by hand); mirroring twice gives d back."""
    reflected = ShellField(small_config(view_encoding="reflected"))
    direct = ShellField(small_config(view_encoding="direction"))
    direct.load_state_dict(reflected.state_dict())
    x = unit_ball_points(64)
    d = torch.nn.functional.normalize(torch.randn(64, 3, generator=torch.Generator().manual_seed(3)), dim=1)
    geo = reflected.geometry(x)
    n = geo.normal
    mirrored = d - 2 * (d * n).sum(1, keepdim=True) * n
    torch.testing.assert_close(reflected.radiance(x, d, geo), direct.radiance(x, mirrored, geo))
    torch.testing.assert_close(mirrored - 2 * (mirrored * n).sum(1, keepdim=True) * n, d)
    assert not torch.allclose(reflected.radiance(x, d, geo), direct.radiance(x, d, geo))
