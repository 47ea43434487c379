"""Level-set evolution and adaptive-shell extraction (paper Sec. 3.3, Procedures 1-2) against closed forms.

Truths used: a sphere's SDF ``|x - c| - R``; a level set under constant normal speed v moves by ``v t``;
mean-curvature flow of a sphere ``r(t)^2 = r0^2 - 4 lambda t``; the logistic CDF; and the nesting
``SDF- >= f0 >= SDF+`` that makes M- lie inside M+.
"""

import math

import numpy as np
import pytest
import torch

from neural.shell import (
    ShellConfig,
    dilate,
    dilation_velocity,
    erode,
    evolve_level_set,
    extract_shells,
    grid_spacing,
    marching_cubes_mesh,
    sample_grid,
    shell_width_stats,
    soft_falloff,
    voxel_alpha,
)
from neural.shell._reference import evolve_level_set_reference

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """The grids here are small: one thread is faster than two, and much faster on a shared machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def sphere_grid(n, radius, center=(0.0, 0.0, 0.0), device="cpu"):
    """(n, n, n) SDF of a sphere on the grid over [-1, 1]^3, its spacing and coordinates."""
    x = torch.linspace(-1.0, 1.0, n, dtype=torch.float64, device=device)
    X, Y, Z = torch.meshgrid(x, x, x, indexing="ij")
    f = ((X - center[0]) ** 2 + (Y - center[1]) ** 2 + (Z - center[2]) ** 2).sqrt() - radius
    return f.float(), 2.0 / (n - 1), (X.float(), Y.float(), Z.float())


def volume_radius(mesh):
    """Radius of the sphere with the mesh's enclosed volume."""
    return (3.0 * mesh.volume / (4.0 * math.pi)) ** (1.0 / 3.0)


def zero_level_radius(f, h):
    """Radius of the f = 0 level set of a grid over [-1, 1]^3, by marching cubes."""
    return volume_radius(marching_cubes_mesh(f.cpu().numpy(), [-1.0] * 3, h))


def winding_numbers(mesh, points):
    import igl

    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return igl.winding_number(v, f, np.asarray(points, dtype=float))


# --- Procedure 1 ------------------------------------------------------------------------------------


def test_soft_falloff_closed_form():
    zeta = 0.2
    f = torch.tensor([0.0, 0.1, -0.1, 0.2, -0.25, 0.05])
    expected = torch.tensor([1.0, 0.5, 0.5, 0.0, 0.0, 0.5 * (1 + math.cos(math.pi / 4))])
    assert torch.allclose(soft_falloff(f, zeta), expected, atol=1e-6)
    with pytest.raises(ValueError, match="zeta"):
        soft_falloff(f, 0.0)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("speed", [0.04, -0.04])
def test_constant_velocity_moves_sphere_by_v_t(device, speed):
    R = 0.5
    f, h, _ = sphere_grid(64, R, device=device)
    f_T = evolve_level_set(f, torch.full_like(f, speed), steps=50, dt=0.1, zeta=1.0, spacing=h)
    assert f_T.device.type == device
    assert abs(zero_level_radius(f_T, h) - (R + speed * 50 * 0.1)) < 0.5 * h


def test_fast_speed_is_substepped_and_stays_accurate():
    R = 0.5
    f, h, _ = sphere_grid(48, R)
    speed = 0.4  # dt * speed / h = 0.94 > cfl = 0.5: two sub-steps per step
    f_T = evolve_level_set(f, torch.full_like(f, speed), steps=5, dt=0.1, zeta=1.0, spacing=h)
    assert torch.isfinite(f_T).all()
    assert abs(zero_level_radius(f_T, h) - (R + speed * 0.5)) < 0.5 * h


def test_curvature_flow_shrinks_sphere_like_mean_curvature_flow():
    r0, lam, steps, dt = 0.5, 0.004, 40, 0.1
    f, h, _ = sphere_grid(64, r0)
    f_T = evolve_level_set(f, torch.zeros_like(f), steps=steps, dt=dt, zeta=0.3, lambda_curv=lam, spacing=h)
    expected = math.sqrt(r0**2 - 4 * lam * steps * dt)  # dr/dt = -2 lam / r
    assert abs(zero_level_radius(f_T, h) - expected) < 0.5 * h


def test_band_restriction_leaves_far_values_untouched():
    f, h, _ = sphere_grid(32, 0.5)
    f_T = evolve_level_set(f, torch.full_like(f, 0.05), steps=10, dt=0.1, zeta=0.1, spacing=h)
    far = f.abs() >= 0.1
    assert torch.equal(f_T[far], f[far])
    assert (f_T[~far] <= f[~far]).all()  # outward motion only lowers f


def test_fast_evolution_matches_dense_reference(rng):
    n = 24
    f, h, (X, Y, Z) = sphere_grid(n, 0.55)
    f = f + 0.03 * torch.sin(7 * X) * torch.cos(5 * Y + 1) * torch.sin(6 * Z + 2)
    velocity = 0.02 * torch.from_numpy(rng.standard_normal((n, n, n))).float()  # both signs
    kwargs = dict(steps=8, dt=0.1, zeta=0.15, lambda_curv=2e-4, spacing=h)
    fast = evolve_level_set(f, velocity, chunk=1000, **kwargs)
    slow = evolve_level_set_reference(f, velocity, **kwargs)
    assert (fast != f).any()
    assert torch.allclose(fast, slow, atol=1e-6)


def test_evolve_validates_inputs():
    f = torch.zeros(8, 8, 8)
    with pytest.raises(ValueError, match="velocity"):
        evolve_level_set(f, torch.zeros(8, 8, 7))
    with pytest.raises(ValueError, match="shape"):
        evolve_level_set(torch.zeros(8, 8), torch.zeros(8, 8))
    with pytest.raises(ValueError, match="dt"):
        evolve_level_set(f, f, dt=0.0)
    with pytest.raises(TypeError):
        evolve_level_set(f.numpy(), f)


# --- Procedure 2 ------------------------------------------------------------------------------------


def reference_alpha(f, s, tau):
    """Procedure 2 line 1 (sigmoids in the meaningful order), in float64 straight from the definition."""
    phi = lambda x: 1.0 / (1.0 + np.exp(-x / s))  # noqa: E731
    return (phi(f + tau / 2) - phi(f - tau / 2)) / phi(f + tau / 2)


def test_voxel_alpha_matches_definition_and_limits():
    tau = 0.01
    f = np.linspace(-0.05, 0.05, 201)
    for s in (0.002, 0.01, 0.05):
        got = voxel_alpha(torch.tensor(f), torch.full((f.size,), s, dtype=torch.float64), tau).numpy()
        assert np.allclose(got, reference_alpha(f, s, tau), rtol=1e-9, atol=1e-12)
    # sharp limit: ~1 across the surface and inside (1 - exp(-tau/s)), ~0 a few s outside
    s = 1e-4
    alpha = voxel_alpha(torch.tensor([-1.0, -0.003, 0.0, 0.003, 0.01, 1.0]), torch.full((6,), s), tau)
    assert torch.allclose(alpha[:4], torch.ones(4), atol=1e-6)
    assert float(alpha[4]) < 1e-12 and float(alpha[5]) == 0.0
    # fuzzy limit: alpha ~ (tau/s) sigmoid(-f/s), the NeuS density of Eq. 3 times the voxel length
    s = 1.0
    ff = torch.tensor([-2.0, 0.0, 2.0], dtype=torch.float64)
    fuzzy = voxel_alpha(ff, torch.full((3,), s, dtype=torch.float64), tau)
    assert torch.allclose(fuzzy, tau / s * torch.sigmoid(-ff / s), rtol=1e-2)  # error ~ alpha / 2


def test_dilation_reaches_the_sigma_min_contour():
    """Eq. 6 fills the region where the voxel opacity exceeds sigma_min (zeta wide enough not to bind)."""
    from scipy.optimize import brentq

    n, R = 64, 0.5
    f, h, _ = sphere_grid(n, R)
    config = ShellConfig(zeta_dilate=0.4, lambda_curv_dilate=0.0)
    for s_vox in (0.1, 1.0):
        s = s_vox * h
        reach = brentq(lambda d, s=s: reference_alpha(d, s, h) - config.sigma_min, 0.0, 0.5)
        f_plus = dilate(f, torch.full_like(f, s), h, config)
        got = zero_level_radius(f_plus, h) - R
        assert reach - 0.5 * h < got < reach + h, (s_vox, got / h, reach / h)


def test_erosion_depth_is_t_dt_beta_e_over_alpha():
    """Eq. 7: inside, alpha = 1 - exp(-h/s) is constant, so the front moves T dt beta_e / alpha voxels."""
    n, R = 64, 0.5
    f, h, _ = sphere_grid(n, R)
    config = ShellConfig(zeta_erode=0.4)
    for s_vox in (0.1, 0.5):
        alpha_in = 1.0 - math.exp(-1.0 / s_vox)
        depth = config.steps * config.dt * min(config.v_max, config.beta_e / alpha_in) * h
        f_minus = erode(f, torch.full_like(f, s_vox * h), h, config)
        got = R - zero_level_radius(f_minus, h)
        # first-order upwinding across the jump of the speed at the surface (v_max outside, slower inside)
        # moves the zero crossing up to ~half a voxel further in; it never erodes less
        assert depth - 0.1 * h < got < depth + h, (s_vox, got / h, depth / h)


@pytest.mark.parametrize("device", DEVICES)
def test_clamps_hold_everywhere(device):
    n = 40
    f, h, (X, Y, Z) = sphere_grid(n, 0.5, device=device)
    f = f + 0.04 * torch.sin(9 * X) * torch.sin(8 * Y) * torch.cos(7 * Z)  # not an SDF any more
    s = (0.002 + 0.04 * torch.sigmoid(10 * X)).to(device)
    result = extract_shells(f, s, [-1.0] * 3, h, ShellConfig())
    assert (result.f_dilate <= f).all() and (result.f_erode >= f).all()
    assert result.f_dilate.device.type == device
    assert (result.f_dilate < f).any() and (result.f_erode > f).any()


def sphere_shells(n, s_vox, R=0.5):
    f, h, _ = sphere_grid(n, R)
    return extract_shells(f, torch.full_like(f, s_vox * h), [-1.0] * 3, h, ShellConfig()), h


def check_nested_closed_shells(result):
    outer, inner = result.outer, result.inner
    for mesh in (outer, inner):
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0  # outward normals
    assert (winding_numbers(outer, inner.vertices) > 0.5).all()  # every M- vertex inside M+


def test_shell_width_grows_with_kernel_size():
    widths = []
    for s_vox in (0.05, 0.5, 2.0):
        result, h = sphere_shells(64, s_vox)
        check_nested_closed_shells(result)
        stats = shell_width_stats(result.outer, result.inner, n_samples=4000)
        widths.append(stats["mean"] / h)
        assert stats["median"] <= stats["max"]
    assert widths[0] < 2.5  # sharp: about a voxel out (half a voxel + s ln(1/sigma_min)) + ~1.5 in
    assert widths[0] < widths[1] < widths[2]
    assert widths[2] > 2 * widths[0]


def test_half_sharp_half_fuzzy_sphere_has_wider_fuzzy_half():
    n, R = 64, 0.5
    f, h, (X, _, _) = sphere_grid(n, R)
    s = torch.where(X < 0, 0.05 * h, 2.0 * h)
    result = extract_shells(f, s, [-1.0] * 3, h, ShellConfig())
    check_nested_closed_shells(result)
    verts = np.asarray(result.outer.vertices)
    sharp = shell_width_stats(result.outer, result.inner, points=verts[verts[:, 0] < -0.15])
    fuzzy = shell_width_stats(result.outer, result.inner, points=verts[verts[:, 0] > 0.15])
    assert fuzzy["median"] > 2 * sharp["median"]
    assert sharp["max"] < 3 * h


def test_meshes_close_at_the_grid_border_and_sit_at_origin_plus_index_spacing():
    n, h = 20, 0.1
    origin = np.array([2.0, -1.0, 0.5])
    idx = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1) * h
    center = np.array([0.95, 0.95, 0.95])  # sphere of radius 1.2 cut by all six faces of the box
    f = np.linalg.norm(idx - center, axis=-1) - 1.2
    mesh = marching_cubes_mesh(f, origin, h)
    assert mesh.is_watertight and mesh.volume > 0
    assert np.allclose(mesh.bounds[0], origin - h, atol=0.5 * h)  # closed half a voxel outside the border
    assert np.allclose(mesh.bounds[1], origin + (n - 1) * h + h, atol=0.5 * h)
    small = np.linalg.norm(idx - center, axis=-1) - 0.5
    sphere = marching_cubes_mesh(small, origin, h)
    assert np.allclose(sphere.vertices.mean(0), origin + center, atol=1e-2)


def test_small_parts_are_dropped_with_their_inner_shell():
    n = 48
    big, h, _ = sphere_grid(n, 0.45, center=(-0.3, 0.0, 0.0))
    tiny, _, _ = sphere_grid(n, 0.09, center=(0.7, 0.0, 0.0))  # 0.8% of the big sphere's volume
    both = torch.minimum(big, tiny)
    s = torch.full_like(big, 0.3 * h)
    alone = extract_shells(big, s, [-1.0] * 3, h)
    dropped = extract_shells(both, s, [-1.0] * 3, h)  # default min_part_fraction 0.05
    for got, want in ((dropped.outer, alone.outer), (dropped.inner, alone.inner)):
        np.testing.assert_array_equal(got.faces, want.faces)
        np.testing.assert_allclose(got.vertices, want.vertices, atol=1e-6)
    kept = extract_shells(both, s, [-1.0] * 3, h, ShellConfig(min_part_fraction=0.0))
    check_nested_closed_shells(kept)
    assert len(kept.outer.split(only_watertight=False)) == 2 == len(kept.inner.split(only_watertight=False))
    assert kept.outer.volume > alone.outer.volume + 0.5 * 4 / 3 * math.pi * 0.09**3
    with pytest.raises(ValueError, match="min_part_fraction"):
        ShellConfig(min_part_fraction=1.5)


def test_empty_level_set_gives_empty_meshes():
    f = torch.ones(12, 12, 12)
    result = extract_shells(f, torch.full_like(f, 0.01), [0.0] * 3, 0.1)
    assert len(result.outer.faces) == 0 and len(result.inner.faces) == 0
    assert math.isnan(shell_width_stats(result.outer, result.inner)["mean"])


@pytest.mark.parametrize("n", [64, 101])
def test_default_speeds_need_no_substeps(n, caplog):
    """v_max = 5 voxels per unit time is exactly the CFL limit at dt = 0.1: Procedure 1 without sub-steps."""
    f, h, _ = sphere_grid(n, 0.5)
    s = torch.full_like(f, 1e-4)  # sharp: the speed is v_max in the whole band
    with caplog.at_level("INFO", logger="neural.shell.levelset"):
        dilate(f, s, h, ShellConfig(steps=1))
        erode(f, s, h, ShellConfig(steps=1))
    assert "sub-steps" not in caplog.text


def test_dilation_velocity_zero_below_sigma_min():
    config = ShellConfig()
    f = torch.tensor([0.0, 20.0, -3.0])
    v = dilation_velocity(f, torch.full((3,), 1.0), config)
    assert float(v[0]) == config.v_max and float(v[1]) == 0.0 and float(v[2]) > 0


def test_extraction_validates_inputs():
    f = torch.zeros(8, 8, 8)
    with pytest.raises(ValueError, match="s must"):
        extract_shells(f, torch.zeros(8, 8, 8), [0.0] * 3, 0.1)
    with pytest.raises(ValueError, match="shape"):
        extract_shells(f, torch.ones(8, 8, 9), [0.0] * 3, 0.1)
    with pytest.raises(ValueError, match="origin"):
        extract_shells(f, torch.ones(8, 8, 8), [0.0] * 2, 0.1)
    with pytest.raises(ValueError, match="spacing"):
        extract_shells(f, torch.ones(8, 8, 8), [0.0] * 3, -1.0)
    with pytest.raises(ValueError, match="beta_e"):
        ShellConfig(beta_e=0.0)


# --- grid sampling ----------------------------------------------------------------------------------


def test_sample_grid_evaluates_the_callable_at_the_nodes():
    calls = []

    def fn(x):
        calls.append(len(x))
        return x.norm(dim=1) - 0.5, 0.01 + x[:, 0].abs()

    f, s = sample_grid(fn, [-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], 17, chunk=1000)
    h = grid_spacing([-1.0] * 3, [1.0] * 3, 17)
    assert h == pytest.approx(0.125) and f.shape == (17, 17, 17)
    assert sum(calls) == 17**3 and max(calls) == 1000
    ref, _, (X, _, _) = sphere_grid(17, 0.5)
    assert torch.allclose(f, ref, atol=1e-6)
    assert torch.allclose(s, 0.01 + X.abs(), atol=1e-6)


def test_sample_grid_validates():
    good = lambda x: (x[:, 0], x[:, 1])  # noqa: E731
    with pytest.raises(ValueError, match="cube"):
        sample_grid(good, [0.0, 0.0, 0.0], [1.0, 2.0, 1.0], 8)
    with pytest.raises(ValueError, match=r"\(N,\)"):
        sample_grid(lambda x: (x, x[:, 0]), [0.0] * 3, [1.0] * 3, 8)


class _AnalyticSphere(torch.nn.Module):
    """Exact SDF ``|x| - 1`` with a constant kernel size, in the ``ShellField`` interface the bench uses."""

    scale = torch.tensor(1.0)

    def sdf(self, x):
        return x.norm(dim=1) - 1.0

    def sdf_and_kernel(self, x):
        return self.sdf(x), torch.full((len(x),), 0.01)


def test_adaptive_bench_measures_band_width_on_concentric_spheres():
    import importlib.util
    from pathlib import Path

    import trimesh

    path = Path(__file__).resolve().parents[1] / "bench" / "adaptive_bench.py"
    spec = importlib.util.spec_from_file_location("adaptive_bench", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    outer = trimesh.creation.icosphere(subdivisions=5, radius=1.06)
    inner = trimesh.creation.icosphere(subdivisions=5, radius=0.97)
    points, normals, grad_norm, s = bench.surface_points(_AnalyticSphere(), outer, 500)
    assert len(points) > 490
    np.testing.assert_allclose(np.linalg.norm(points, axis=1), 1.0, atol=1e-3)  # moved onto f = 0
    np.testing.assert_allclose(normals, points / np.linalg.norm(points, axis=1)[:, None], atol=2e-3)
    np.testing.assert_allclose(grad_norm, 1.0, atol=2e-3)
    np.testing.assert_allclose(s, 0.01)
    # 0.06 to M+ and 0.03 to M-, less the icospheres' chord sag (< 1e-3 at 5 subdivisions)
    np.testing.assert_allclose(bench.band_width(points, outer, inner), 0.09, atol=1.5e-3)
    # fur: upward-facing and high on the bunny; skin: low; the pedestal's top and the cube: neither
    z0, z1 = bench.PEDESTAL_TOP, bench.PEDESTAL_TOP + 1.4
    pts = np.array([[0, 0, z0 + 1.3], [0, 0, z0 + 1.3], [0.3, 0, z0 + 0.3], [0.6, 0.6, z0 + 0.05]])
    up, side = [0, 0, 1.0], [1.0, 0, 0]
    labels = bench.label_points(pts, np.array([up, side, side, up]), (z0, z1))
    assert labels.tolist() == [1, -1, 0, -1]
