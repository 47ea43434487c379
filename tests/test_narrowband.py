"""Narrow-band sampling (Procedure 3): Embree fast path vs. brute-force twin, closed forms on spheres."""

import numpy as np
import pytest
import torch
import trimesh

from neural.config import NarrowBandConfig
from neural.render._reference import narrow_band_samples_reference
from neural.render.narrowband import (
    intervals_from_hits,
    narrow_band_samples,
    samples_from_intervals,
    samples_per_interval,
)
from neural.render.raycast import EmbreeCaster, WarpCaster, ray_triangle_hits


def sphere(radius, center=(0.0, 0.0, 0.0), subdivisions=3):
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(center)
    return mesh


def concentric(r_out=1.0, r_in=0.7, subdivisions=3):
    return sphere(r_out, subdivisions=subdivisions), sphere(r_in, subdivisions=subdivisions)


def row_of_three():
    """Three disjoint shells along x (outer radius 1, inner 0.5, centres 2.2 apart)."""
    centers = [(-2.2, 0.0, 0.0), (0.0, 0.0, 0.0), (2.2, 0.0, 0.0)]
    outer = trimesh.util.concatenate([sphere(1.0, c) for c in centers])
    inner = trimesh.util.concatenate([sphere(0.5, c) for c in centers])
    return outer, inner


def torus_shells():
    outer = trimesh.creation.torus(major_radius=1.0, minor_radius=0.45, major_sections=48, minor_sections=24)
    inner = trimesh.creation.torus(major_radius=1.0, minor_radius=0.2, major_sections=48, minor_sections=24)
    return outer, inner


def rays_at_scene(rng, n, distance, spread):
    """Rays from a sphere of radius ``distance`` towards random points in a box of half-size ``spread``."""
    origins = rng.normal(size=(n, 3))
    origins *= distance / np.linalg.norm(origins, axis=1, keepdims=True)
    targets = rng.uniform(-1, 1, size=(n, 3)) * np.asarray(spread)
    dirs = targets - origins
    return origins, dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def ambiguous_rays(stats, origins, dirs, config, n_rays, contraction=None):
    """Rays with an interval whose width (world, or contracted with ``contraction``) sits on a step of N's
    ceil (float32 Embree vs float64 may differ)."""
    widths = (stats.interval_exit - stats.interval_enter) * np.linalg.norm(dirs[stats.interval_rays], axis=1)
    if contraction is not None:
        o, d = origins[stats.interval_rays], dirs[stats.interval_rays]
        ends = [o + t[:, None] * d for t in (stats.interval_enter, stats.interval_exit)]
        widths = np.linalg.norm(
            contraction.to_field(torch.as_tensor(ends[1])).numpy()
            - contraction.to_field(torch.as_tensor(ends[0])).numpy(),
            axis=1,
        )
    x = (widths - config.w_s) / config.delta_s
    near_step = (np.abs(x - np.round(x)) < 2e-3) | (widths < 1e-4)
    flagged = np.zeros(n_rays, dtype=bool)
    flagged[stats.interval_rays[near_step]] = True
    return flagged


def assert_matches_reference(
    outer, inner, origins, dirs, config, near=0.0, intersector=None, contraction=None
):
    """The fast sampler on ``intersector`` (default: Embree on ``outer``, ``inner``) against the per-ray
    float64 twin on ``outer``, ``inner``."""
    n = len(origins)
    intersector = EmbreeCaster(outer, inner) if intersector is None else intersector
    kwargs = dict(near=near, contraction=contraction)
    fast, fast_stats = narrow_band_samples(intersector, origins, dirs, config, **kwargs)
    ref, ref_stats = narrow_band_samples_reference(outer, inner, origins, dirs, config, **kwargs)
    skip = ambiguous_rays(fast_stats, origins, dirs, config, n, contraction)
    skip |= ambiguous_rays(ref_stats, origins, dirs, config, n, contraction)
    assert skip.mean() < 0.02
    ok = torch.as_tensor(~skip)
    np.testing.assert_array_equal(fast_stats.counts[~skip], ref_stats.counts[~skip])
    np.testing.assert_array_equal(fast.counts().numpy(), fast_stats.counts)
    fast_keep, ref_keep = ok[fast.ray_indices], ok[ref.ray_indices]
    assert torch.equal(fast.ray_indices[fast_keep], ref.ray_indices[ref_keep])
    for name in ("t_starts", "t_ends", "t_mid"):
        a, b = getattr(fast, name)[fast_keep], getattr(ref, name)[ref_keep]
        torch.testing.assert_close(a, b, atol=1e-4, rtol=0)
    fi, ri = ~skip[fast_stats.interval_rays], ~skip[ref_stats.interval_rays]
    np.testing.assert_array_equal(fast_stats.interval_rays[fi], ref_stats.interval_rays[ri])
    np.testing.assert_allclose(fast_stats.interval_enter[fi], ref_stats.interval_enter[ri], atol=1e-4)
    np.testing.assert_allclose(fast_stats.interval_exit[fi], ref_stats.interval_exit[ri], atol=1e-4)
    np.testing.assert_allclose(fast_stats.t_inner, ref_stats.t_inner, atol=1e-4)
    return fast, fast_stats


def test_concentric_spheres_match_reference(rng):
    outer, inner = concentric()
    origins, dirs = rays_at_scene(rng, 300, 3.0, (1.2, 1.2, 1.2))
    config = NarrowBandConfig(delta_s=0.03, w_s=0.02, n_max=16, max_peel=8)
    samples, stats = assert_matches_reference(outer, inner, origins, dirs, config)
    assert (stats.counts == 0).any() and (stats.counts > 1).any()  # misses and wide grazing bands both seen


@pytest.mark.parametrize("max_peel", [8, 4])
def test_row_of_shells_several_bands_match_reference(rng, max_peel):
    outer, inner = row_of_three()
    origins = np.column_stack([np.full(300, -5.0), rng.uniform(-1.1, 1.1, (300, 2))])
    dirs = np.column_stack([np.ones(300), rng.normal(scale=0.05, size=(300, 2))])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    config = NarrowBandConfig(delta_s=0.05, w_s=0.05, n_max=8, max_peel=max_peel)
    _, stats = assert_matches_reference(outer, inner, origins, dirs, config)
    intervals_per_ray = np.bincount(stats.interval_rays, minlength=300)
    assert intervals_per_ray.max() == (3 if max_peel == 8 else 2)


def test_row_of_shells_counted_in_contracted_space_match_reference(rng):
    """With a contraction about the middle shell (unit ball radius 0.8), the outer shells lie beyond it and
    their intervals are counted by their contracted widths, alike in both samplers."""
    from neural.field.contraction import ContractionMap

    outer, inner = row_of_three()
    origins = np.column_stack([np.full(300, -5.0), rng.uniform(-1.1, 1.1, (300, 2))])
    dirs = np.column_stack([np.ones(300), rng.normal(scale=0.05, size=(300, 2))])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    config = NarrowBandConfig(delta_s=0.05, w_s=0.05, n_max=16, max_peel=8)
    contraction = ContractionMap((0.0, 0.0, 0.0), 0.8)
    _, stats = assert_matches_reference(outer, inner, origins, dirs, config, contraction=contraction)
    _, world = narrow_band_samples(EmbreeCaster(outer, inner), origins, dirs, config)
    assert stats.counts.sum() < world.counts.sum()  # the far shells' intervals are narrower there


def test_torus_matches_reference(rng):
    outer, inner = torus_shells()
    origins, dirs = rays_at_scene(rng, 300, 3.0, (1.5, 1.5, 0.5))
    _, stats = assert_matches_reference(outer, inner, origins, dirs, NarrowBandConfig(0.04, 0.03, 16, 8))
    assert np.bincount(stats.interval_rays).max() >= 2


def bend(vertices):
    """A smooth non-affine deformation (V, 3) -> (V, 3): a bend about the y axis, a twist about z, a shift."""
    x, y, z = vertices.T
    angle = 0.4 * z
    x, y = x * np.cos(angle) - y * np.sin(angle), x * np.sin(angle) + y * np.cos(angle)
    return np.column_stack([x + 0.15 * x**2, y, z + 0.2 * np.sin(x)]) + [0.1, -0.2, 0.05]


@pytest.mark.parametrize("shells", [torus_shells, row_of_three])
def test_refitted_warp_intersector_matches_reference_before_and_after_moving(rng, shells):
    """Warp meshes built on the rest shells, then refitted to bent shells: the samples equal the brute-force
    twin's on the bent meshes themselves (a fresh Embree build is not needed)."""
    outer, inner = shells()
    intersector = WarpCaster(outer, inner, device="cpu", cpu_threads=2)
    config = NarrowBandConfig(0.04, 0.03, 16, 8)
    origins, dirs = rays_at_scene(rng, 400, 4.0, (2.0, 1.5, 0.6))
    assert_matches_reference(outer, inner, origins, dirs, config, intersector=intersector)
    bent = [trimesh.Trimesh(bend(m.vertices), m.faces, process=False) for m in (outer, inner)]
    intersector.refit(bent[0].vertices, bent[1].vertices)
    _, stats = assert_matches_reference(*bent, origins, dirs, config, intersector=intersector)
    assert (stats.counts > 0).mean() > 0.3
    # rays split over two threads find exactly the hits of one thread
    many = rays_at_scene(rng, 10000, 4.0, (2.0, 1.5, 0.6))
    split = intersector.all_hits("outer", *many, 8)
    intersector.cpu_threads = 1
    for a, b in zip(split, intersector.all_hits("outer", *many, 8), strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="outer_vertices: expected shape"):
        intersector.refit(bent[0].vertices[:-1], bent[1].vertices)
    with pytest.raises(ValueError, match="inner_vertices: contain NaN"):
        intersector.refit(bent[0].vertices, np.full_like(bent[1].vertices, np.nan))


def test_origins_inside_outer_and_inner_match_reference(rng):
    outer, inner = concentric()
    radii = np.concatenate([rng.uniform(0.75, 0.95, 150), rng.uniform(0.0, 0.6, 150)])
    origins = random_unit(rng, 300) * radii[:, None]
    dirs = random_unit(rng, 300)
    config = NarrowBandConfig(delta_s=0.03, w_s=0.02)
    _, stats = assert_matches_reference(outer, inner, origins, dirs, config)
    in_band = stats.interval_rays < 150
    assert np.all(stats.interval_enter[in_band][np.r_[True, np.diff(stats.interval_rays[in_band]) > 0]] == 0)
    assert (stats.counts > 0).all()


def test_near_plane_matches_reference(rng):
    outer, inner = torus_shells()
    origins, dirs = rays_at_scene(rng, 200, 3.0, (1.5, 1.5, 0.5))
    assert_matches_reference(outer, inner, origins, dirs, NarrowBandConfig(0.04, 0.03), near=2.6)


def test_closed_form_concentric_spheres(rng):
    r_out, r_in, d = 1.0, 0.7, 3.0
    intersector = EmbreeCaster(*concentric(r_out, r_in, subdivisions=5))
    dirs = random_unit(rng, 50)
    origins = -d * dirs  # every ray passes through the centre
    tol = 1e-3  # icosphere facets lie within 3e-4 of the sphere
    # (w - w_s) / delta_s = 5.6 -> N = 7 samples at linspace(d - R+, d - R-, 9)[1:-1].
    samples, stats = narrow_band_samples(intersector, origins, dirs, NarrowBandConfig(0.05, 0.02, 16, 8))
    np.testing.assert_array_equal(stats.counts, 7)
    expected = np.tile(np.linspace(d - r_out, d - r_in, 9)[1:-1], 50)
    np.testing.assert_allclose(samples.t_mid.numpy(), expected, atol=tol)
    np.testing.assert_allclose(stats.interval_enter, d - r_out, atol=tol)
    np.testing.assert_allclose(stats.interval_exit, d - r_in, atol=tol)
    t0, t1 = samples.t_starts.view(50, 7), samples.t_ends.view(50, 7)
    torch.testing.assert_close(t0[:, 1:], t1[:, :-1])  # sections tile the interval
    torch.testing.assert_close(t0[:, 0].double(), torch.as_tensor(stats.interval_enter))
    torch.testing.assert_close(t1[:, -1].double(), torch.as_tensor(stats.interval_exit))
    assert torch.all((samples.t_starts < samples.t_mid) & (samples.t_mid < samples.t_ends))
    np.testing.assert_allclose(
        samples.points(torch.as_tensor(origins).float(), torch.as_tensor(dirs).float()).norm(dim=1).numpy(),
        np.tile(np.linspace(r_out, r_in, 9)[1:-1], 50),
        atol=tol,
    )

    # w < w_s: one sample at the interval centre, its section the whole interval.
    one, stats = narrow_band_samples(intersector, origins, dirs, NarrowBandConfig(0.05, 0.5, 16, 8))
    np.testing.assert_array_equal(stats.counts, 1)
    np.testing.assert_allclose(one.t_mid.numpy(), d - 0.5 * (r_out + r_in), atol=tol)
    np.testing.assert_allclose(one.t_starts.numpy(), d - r_out, atol=tol)
    np.testing.assert_allclose(one.t_ends.numpy(), d - r_in, atol=tol)

    # Fine spacing: N capped at n_max.
    _, stats = narrow_band_samples(intersector, origins, dirs, NarrowBandConfig(0.001, 0.0, 12, 8))
    np.testing.assert_array_equal(stats.counts, 12)

    # Non-unit directions: distances in units of dirs, same world samples.
    scaled, _ = narrow_band_samples(intersector, origins, 2.5 * dirs, NarrowBandConfig(0.05, 0.02, 16, 8))
    torch.testing.assert_close(scaled.t_mid * 2.5, samples.t_mid)


def test_rays_through_vertices_and_edges_cross_each_shell_once():
    """Degenerate hits: rays through the centre aimed at mesh vertices and edge midpoints, where several
    triangles share the hit point, still give one band [d - R+, d - R-] (no double or missed crossing)."""
    outer, inner = concentric(1.0, 0.7, subdivisions=2)
    targets = np.concatenate([outer.vertices, outer.vertices[outer.edges_unique].mean(axis=1)])
    dirs = targets / np.linalg.norm(targets, axis=1, keepdims=True)
    for d in (3.0, 0.0):  # from outside, and from the common centre (inside M-)
        _, stats = narrow_band_samples(EmbreeCaster(outer, inner), -d * dirs, dirs, NarrowBandConfig())
        np.testing.assert_array_equal(stats.interval_rays, np.arange(len(dirs)))
        if d > 0:
            np.testing.assert_allclose(stats.interval_enter, d - 1.0, atol=5e-2)
            np.testing.assert_allclose(stats.interval_exit, stats.t_inner)
    ray_idx, t, entering = EmbreeCaster(outer, inner).all_hits("outer", -3 * dirs, dirs, max_hits=8)
    np.testing.assert_array_equal(ray_idx, np.repeat(np.arange(len(dirs)), 2))
    np.testing.assert_array_equal(entering, np.tile([True, False], len(dirs)))


def test_rays_that_miss_get_no_samples(rng):
    intersector = EmbreeCaster(*concentric())
    origins = np.tile([0.0, 0.0, -3.0], (20, 1))
    dirs = random_unit(rng, 20)
    dirs[:, 2] = -np.abs(dirs[:, 2])  # pointing away from the spheres
    dirs[:10] = [[1.0, 0.0, 0.0]]  # passing beside them
    samples, stats = narrow_band_samples(intersector, origins, torch.as_tensor(dirs))
    assert samples.ray_indices.numel() == 0 and samples.n_rays == 20
    np.testing.assert_array_equal(stats.counts, 0)
    assert np.isinf(stats.t_inner).all() and stats.mean_samples_per_ray == 0.0


class RecordingCaster(EmbreeCaster):
    """An Embree caster that records which mesh each cast goes to and how many rays it takes."""

    def __init__(self, outer, inner):
        super().__init__(outer, inner)
        self.casts = []

    def _cast(self, scene, starts, units, reach=None):
        which = next(w for w, s in self._scenes.items() if s is scene)
        self.casts.append((which, len(starts)))
        return super()._cast(scene, starts, units, reach)


def test_only_rays_that_meet_the_outer_shell_are_cast_further(rng):
    """One M+ cast takes every ray; M- and the peeling rounds take only the rays whose brute-force float64
    cast meets M+ (a ray that misses the closed M+ has no interval), and the samples stay the twin's."""
    outer, inner = concentric()
    origins, dirs = rays_at_scene(rng, 300, 3.0, (2.0, 2.0, 2.0))
    triangles = np.asarray(outer.triangles, dtype=np.float64)
    meets = sum(len(ray_triangle_hits(triangles, o, d)[0]) > 0 for o, d in zip(origins, dirs, strict=True))
    assert 50 < meets < 250  # both kinds of rays are there
    caster = RecordingCaster(outer, inner)
    assert_matches_reference(outer, inner, origins, dirs, NarrowBandConfig(), intersector=caster)
    assert caster.casts[0] == ("outer", 300)
    assert caster.casts[1] == ("inner", meets)
    assert caster.casts[2] == ("outer", meets)
    assert all(which == "outer" and n <= meets for which, n in caster.casts[3:])


def test_peeling_cap_through_row_of_shells():
    """A ray along x between inner (0.5) and outer (1) radius crosses three bands and no M-."""
    intersector = EmbreeCaster(*row_of_three())
    origins, dirs = np.array([[-5.0, 0.7, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    expected_intervals = {8: 3, 6: 3, 5: 2, 4: 2, 3: 1, 2: 1, 1: 0}
    for max_peel, n_intervals in expected_intervals.items():
        _, stats = narrow_band_samples(intersector, origins, dirs, NarrowBandConfig(max_peel=max_peel))
        assert len(stats.interval_rays) == n_intervals
    ray_idx, t, entering = intersector.all_hits("outer", origins, dirs, max_hits=8)
    half_chord = np.sqrt(1 - 0.7**2)
    expected_t = 5 + np.array([c + s * half_chord for c in (-2.2, 0.0, 2.2) for s in (-1, 1)])
    np.testing.assert_allclose(t, expected_t, atol=5e-3)
    np.testing.assert_array_equal(entering, [True, False] * 3)
    np.testing.assert_array_equal(ray_idx, 0)


def test_intervals_from_hits_rules():
    # ray 0: first hit exits (origin inside); ray 1: two entries, the later wins; ray 2: a stray second exit
    # is skipped; ray 3: exit clipped at d_M-; ray 4: a band opening beyond d_M- is dropped; ray 5: two bands;
    # ray 6: an entry whose exit was not cast (beyond d_M-) closes at d_M-; ray 7: an entry with no M- hit
    # stays open (no samples).
    hits = [
        (0, 1.0, False),
        (1, 1.0, True), (1, 2.0, True), (1, 3.0, False),
        (2, 1.0, True), (2, 2.0, False), (2, 3.0, False),
        (3, 1.0, True), (3, 5.0, False),
        (4, 1.0, True), (4, 2.0, False), (4, 4.0, True), (4, 5.0, False),
        (5, 1.0, True), (5, 2.0, False), (5, 3.0, True), (5, 4.0, False),
        (6, 1.0, True), (6, 1.5, False), (6, 2.0, True),
        (7, 1.0, True),
    ]  # fmt: skip
    ray_idx = np.array([h[0] for h in hits])
    t = np.array([h[1] for h in hits])
    entering = np.array([h[2] for h in hits])
    t_inner = np.array([np.inf, np.inf, np.inf, 3.0, 3.0, np.inf, 3.0, np.inf])
    rays, d_enter, d_exit = intervals_from_hits(ray_idx, t, entering, t_inner, max_peel=8)
    np.testing.assert_array_equal(rays, [0, 1, 2, 3, 4, 5, 5, 6, 6])
    np.testing.assert_array_equal(d_enter, [0.0, 2.0, 1.0, 1.0, 1.0, 1.0, 3.0, 1.0, 2.0])
    np.testing.assert_array_equal(d_exit, [1.0, 3.0, 2.0, 3.0, 2.0, 2.0, 4.0, 1.5, 3.0])
    # With the cap reached at ray 6's third hit, Procedure 3 never sees the exit: its band stays open.
    rays, _, _ = intervals_from_hits(ray_idx, t, entering, t_inner, max_peel=3)
    np.testing.assert_array_equal(np.bincount(rays, minlength=8), [1, 1, 1, 1, 1, 1, 1, 0])
    rays, _, _ = intervals_from_hits(ray_idx[:0], t[:0], entering[:0], t_inner, max_peel=8)
    assert rays.shape == (0,)


def test_samples_per_interval_and_packing():
    config = NarrowBandConfig(delta_s=0.1, w_s=0.05, n_max=5)
    widths = np.array([0.0, 0.04, 0.05, 0.0501, 0.15, 0.1501, 10.0])
    np.testing.assert_array_equal(samples_per_interval(widths, config), [1, 1, 1, 2, 2, 3, 5])
    rays, starts, ends, positions = samples_from_intervals(  # ray 1's interval asks for no sample
        np.array([0, 0, 1, 2]),
        np.array([1.0, 3.0, 5.0, 0.0]),
        np.array([2.0, 3.0, 6.0, 4.0]),
        np.array([3, 1, 0, 1]),
    )
    np.testing.assert_array_equal(rays, [0, 0, 0, 0, 2])
    np.testing.assert_allclose(positions, [1.25, 1.5, 1.75, 3.0, 2.0])
    np.testing.assert_allclose(starts, [1.0, 1.375, 1.625, 3.0, 0.0])
    np.testing.assert_allclose(ends, [1.375, 1.625, 2.0, 3.0, 4.0])


def test_config_validation_and_scaling():
    config = NarrowBandConfig(delta_s=0.005, w_s=0.01).scaled(3.0)
    assert config.delta_s == pytest.approx(0.015) and config.w_s == pytest.approx(0.03)
    assert config.n_max == 16 and config.max_peel == 16
    for kwargs, word in [({"delta_s": 0}, "delta_s"), ({"w_s": -1}, "w_s"), ({"n_max": 0}, "n_max"),
                         ({"max_peel": 2.5}, "max_peel")]:  # fmt: skip
        with pytest.raises(ValueError, match=word):
            NarrowBandConfig(**kwargs)


def test_input_validation():
    intersector = EmbreeCaster(*concentric(subdivisions=1))
    with pytest.raises(ValueError, match="origins"):
        narrow_band_samples(intersector, np.zeros((4, 2)), np.ones((4, 3)))
    with pytest.raises(ValueError, match="same shape"):
        narrow_band_samples(intersector, np.zeros((4, 3)), np.ones((5, 3)))
    with pytest.raises(ValueError, match="non-zero"):
        narrow_band_samples(intersector, np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="mesh_which"):
        intersector.all_hits("middle", np.zeros((1, 3)), np.ones((1, 3)), 4)
    with pytest.raises(ValueError, match="max_hits"):
        intersector.all_hits("outer", np.zeros((1, 3)), np.ones((1, 3)), 0)
    with pytest.raises(ValueError, match="t_stop"):
        intersector.all_hits("outer", np.zeros((1, 3)), np.ones((1, 3)), 4, t_stop=np.ones(2))
    with pytest.raises(ValueError, match="near"):
        narrow_band_samples(intersector, np.zeros((1, 3)), np.ones((1, 3)), near=-1.0)
    with pytest.raises(TypeError, match="outer"):
        EmbreeCaster("sphere.ply", sphere(0.5))
    inverted = sphere(0.5, subdivisions=1)
    inverted.invert()
    with pytest.raises(ValueError, match="inner .*wound inward"):
        EmbreeCaster(sphere(1.0, subdivisions=1), inverted)
