"""Full-ray samplers: ray/box slabs against brute force, stepped sampling, and the
occupancy grid (closed-form cell marking on a sphere, loop twin, subset of the dense sampler, same render)."""

import math

import pytest
import torch
from scenes import RecordingSphereField, SphereField

from neural.render import fullray
from neural.render.composite import transmittance
from neural.render.fullray import (
    pack_dense,
    ray_aabb,
    render_rays,
    step_offsets,
    step_range,
    stepped_samples,
    visible_samples,
)
from neural.render.occupancy import OccupancyConfig, OccupancyGrid
from neural.render.occupancy_warp import march_occupied

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
LO, HI = torch.tensor([-1.0, -1.2, -0.9]), torch.tensor([1.1, 0.8, 1.3])


def random_rays(n, seed, distance=3.0, spread=1.0, device="cpu"):
    g = torch.Generator().manual_seed(seed)
    origins = torch.randn(n, 3, generator=g)
    origins = distance * origins / origins.norm(dim=1, keepdim=True)
    target = spread * (torch.rand(n, 3, generator=g) * 2 - 1)
    dirs = torch.nn.functional.normalize(target - origins, dim=1)
    return origins.to(device), dirs.to(device)


def inside(x, lo, hi, tol=0.0):
    return ((x >= lo - tol) & (x <= hi + tol)).all(dim=-1)


def sphere_sdf(radius, center=(0.0, 0.0, 0.0)):
    c = torch.tensor(center)

    def fn(x):
        return (x - c.to(x)).norm(dim=1) - radius

    return fn


# ---------------------------------------------------------------- ray / box


def test_ray_aabb_against_brute_force():
    origins, dirs = random_rays(300, 0, distance=2.5, spread=2.0)
    origins[:20] = torch.rand(20, 3) * 0.5  # some rays start inside the box
    dirs[20:30, 1] = 0.0  # and some have zero direction components
    dirs[30:35, 0] = 0.0
    dirs[30:35, 2] = 0.0
    dirs = torch.nn.functional.normalize(dirs, dim=1)
    o, d, lo, hi = origins.double(), dirs.double(), LO.double(), HI.double()
    near, far = ray_aabb(o, d, lo, hi)
    hit = far > near
    t = torch.linspace(0.0, 8.0, 4001, dtype=torch.float64)
    ins = inside(o[:, None, :] + t[None, :, None] * d[:, None, :], lo, hi)
    assert not ins[~hit].any()  # misses stay outside
    assert hit.sum() > 150 and torch.equal(hit[ins.any(dim=1)], torch.ones_like(hit[ins.any(dim=1)]))

    def at(tt):
        return inside(o + tt[:, None] * d, lo, hi)

    eps = 1e-9
    assert at(near + eps)[hit].all() and at(far - eps)[hit].all()
    assert not at(far + eps)[hit].any()
    outside_start = hit & (near > 0)
    assert not at(near - eps)[outside_start].any()
    assert (near[:20] == 0).all() and hit[:20].all()  # origin inside: enter at the near plane
    assert (near[~hit] == far[~hit]).all()


def test_ray_aabb_rejects_bad_shapes():
    with pytest.raises(ValueError, match="origins and dirs"):
        ray_aabb(torch.zeros(4, 3), torch.zeros(4, 2), LO, HI)


# ---------------------------------------------------------------- stepped


def test_stepped_samples_count_and_cap():
    near = torch.tensor([0.0, 1.0, 2.0])
    far = torch.tensor([1.05, 1.0, 9.0])
    s = stepped_samples(near, far, 0.1, max_samples=40)
    assert s.counts().tolist() == [11, 0, 40]  # ceil(1.05 / 0.1) = 11; the third is capped
    assert torch.allclose(s.deltas, torch.full_like(s.deltas, 0.1))
    assert (s.t_starts < far[s.ray_indices]).all()


# ---------------------------------------------------------------- occupancy grid


def cell_boxes(grid):
    res = grid.resolution
    i, j, k = torch.meshgrid(*[torch.arange(res)] * 3, indexing="ij")
    ijk = torch.stack([i, j, k], -1).reshape(-1, 3).float()
    lo = grid.aabb_min.cpu() + ijk * grid.cell_size.cpu()
    return lo, lo + grid.cell_size.cpu()


@pytest.mark.parametrize("jitter", [False, True])
def test_occupancy_marks_exactly_a_band_around_the_sphere(jitter):
    radius, inv_s, res = 0.6, 200.0, 24
    config = OccupancyConfig(jitter=jitter)
    grid = OccupancyGrid(LO, HI, res, config)
    sdf = sphere_sdf(radius)
    grid.update(lambda x: (sdf(x), torch.full((x.shape[0],), inv_s)), step=0)
    lo, hi = cell_boxes(grid)
    nearest = torch.maximum(torch.minimum(torch.zeros(3), hi), lo).norm(dim=1)  # closest point to the centre
    farthest = torch.maximum(lo.abs(), hi.abs()).norm(dim=1)
    crosses = (nearest <= radius) & (farthest >= radius)
    occ = grid.occupied.cpu()
    assert occ[crosses].all()  # every cell the surface passes through
    # and only cells within band_widths kernel sizes of the surface, plus the probe's reach in the cell
    dist_to_surface = torch.where(
        crosses, 0.0, torch.minimum((nearest - radius).abs(), (farthest - radius).abs())
    )
    reach = config.band_widths / inv_s + grid.cell_size.norm() * (1.0 if jitter else 0.5)
    assert (dist_to_surface[occ] <= reach + 1e-5).all()
    assert occ.float().mean() < 0.5


def test_occupancy_scores_decay_like_instant_ngp():
    """Geometry leaves: a cell first scored s0 stays occupied while s0 decay^m > exp(-band_widths)."""
    config = OccupancyConfig(jitter=False, warmup_steps=10**6)
    grid = OccupancyGrid(-torch.ones(3), torch.ones(3), 8, config)
    inv_s = 50.0

    def far_away(x):
        return torch.full((x.shape[0],), 100.0), torch.full((x.shape[0],), inv_s)

    def near_centre(x):
        return x.norm(dim=1) - 0.3, torch.full((x.shape[0],), inv_s)

    grid.update(near_centre, 0)
    lo, hi = cell_boxes(grid)
    half_diag = float(grid.cell_size.norm()) / 2
    s0 = torch.exp(-inv_s * torch.relu(((0.5 * (lo + hi)).norm(dim=1) - 0.3).abs() - half_diag))
    log_thr, log_decay = -config.band_widths, math.log(config.ema_decay)
    lifetime = torch.ceil((log_thr - torch.log(s0)) / log_decay)  # first m with s0 decay^m <= threshold
    assert (lifetime == math.ceil(config.band_widths / -log_decay)).sum() > 0  # cells on the surface: s0 = 1
    for m in range(1, int(lifetime.max()) + 2):
        grid.update(far_away, m)
        assert torch.equal(grid.occupied, m < lifetime), m


def test_occupancy_partial_updates_and_state_round_trip():
    config = OccupancyConfig(warmup_steps=4, update_fraction=0.1)
    grid = OccupancyGrid(LO, HI, 16, config)

    def fn(x):
        return sphere_sdf(0.5)(x), torch.full((x.shape[0],), 100.0)

    assert grid.occupied.all()  # never probed: dense
    grid.update(fn, step=100)  # unprobed cells force a full update even after warm-up
    assert (grid.scores >= 0).all()
    scores = grid.scores.clone()
    grid.update(fn, step=101, generator=torch.Generator().manual_seed(0))
    changed = (grid.scores != scores).float().mean()
    assert 0 < changed < 0.3
    other = OccupancyGrid(LO, HI, 16, config)
    other.load_state(grid.state())
    assert torch.equal(other.occupied, grid.occupied)
    with pytest.raises(ValueError, match="occupancy_scores"):
        OccupancyGrid(LO, HI, 8).load_state(grid.state())


def sphere_grid(radius, inv_s, res=32, device="cpu"):
    grid = OccupancyGrid(LO.to(device), HI.to(device), res, OccupancyConfig(jitter=False))
    sdf = sphere_sdf(radius)
    grid.update(lambda x: (sdf(x), torch.full((x.shape[0],), inv_s, device=x.device)), step=0)
    return grid


def test_occupancy_sample_matches_loop_twin():
    grid = sphere_grid(0.6, 100.0, res=16)
    origins, dirs = random_rays(24, 5, spread=1.2)
    fast = grid.sample(origins, dirs, 0.05, 256)
    slow = grid.sample_reference(origins, dirs, 0.05, 256)
    assert torch.equal(fast.ray_indices, slow.ray_indices)
    assert torch.allclose(fast.t_starts, slow.t_starts) and torch.allclose(fast.t_ends, slow.t_ends)


@pytest.mark.parametrize("device", DEVICES)
def test_occupancy_sampling_renders_like_dense_sampling(device):
    radius, inv_s, step = 0.6, 300.0, 0.01
    field = SphereField(radius, inv_s)
    grid = sphere_grid(radius, inv_s, device=device)
    origins, dirs = random_rays(256, 6, spread=0.9, device=device)
    near, far = ray_aabb(origins, dirs, LO.to(device), HI.to(device))
    dense = stepped_samples(near, far, step, 1024)
    sparse = grid.sample(origins, dirs, step, 1024)

    # a subset of the dense sections, ray by ray
    def key(s):
        return set(zip(s.ray_indices.tolist(), torch.round(s.t_starts * 1e5).long().tolist(), strict=True))

    assert key(sparse) <= key(dense)
    assert sparse.t_starts.numel() < 0.3 * dense.t_starts.numel()
    bg = torch.tensor([0.2, 0.9, 0.4], device=device)
    a = render_rays(field, origins, dirs, dense, bg)
    b = render_rays(field, origins, dirs, sparse, bg)
    hits = (a["opacity"] > 0.5).sum()
    assert 50 < hits < 250  # both hits and misses are exercised
    for key in ("opacity", "color", "depth"):  # skipped cells could add at most ~exp(-band_widths) = 3e-4
        assert (a[key] - b[key]).abs().max() < 1e-4, key


@pytest.mark.parametrize("inv_s, left", [(30.0, 0.9), (1000.0, 0.6)])
def test_visible_samples_drop_a_tail_that_changes_colours_by_at_most_the_threshold(inv_s, left):
    field = SphereField(0.6, inv_s)
    origins, dirs = random_rays(256, 7, spread=0.9)
    near, far = ray_aabb(origins, dirs, LO, HI)
    samples = stepped_samples(near, far, 0.01, 1024, perturb=True, generator=torch.Generator().manual_seed(1))
    bg = torch.tensor([0.2, 0.9, 0.4])
    full = render_rays(field, origins, dirs, samples, bg)
    for threshold in (1e-2, 1e-4):
        kept = visible_samples(field, origins, dirs, samples, threshold)
        # a prefix of every ray: per ray, the kept count and the first samples coincide
        counts = samples.counts()
        first = torch.cumsum(counts, 0) - counts
        rank = torch.arange(len(samples.ray_indices)) - first[samples.ray_indices]
        assert torch.equal(kept.t_starts, samples.t_starts[rank < kept.counts()[samples.ray_indices]])
        # what a dropped tail can add to a colour in [0, 1] is at most T at its start
        part = render_rays(field, origins, dirs, kept, bg)
        assert (part["color"] - full["color"]).abs().max() <= threshold
        # the samples behind the sphere's front go: all but ``left`` of them on rays through the solid
        hit = full["opacity"] > 0.99
        assert hit.sum() > 50 and kept.counts()[hit].sum() < left * counts[hit].sum()
    assert visible_samples(field, origins, dirs, samples, 0.0) is samples


@pytest.mark.parametrize(("first_round", "last_round"), [(2, 0), (16, 300), (1 << 20, 0)])
def test_visible_samples_keep_what_one_pass_over_every_sample_keeps(monkeypatch, first_round, last_round):
    """Rounds change which samples the network sees, not which are kept: the kept samples are those with
    ``T_i > threshold`` from one pass of every sample's opacity (the definition), whatever the rounds; rays
    through the sphere are not evaluated far behind its front once rounds are small."""
    monkeypatch.setattr(fullray, "VISIBLE_FIRST_ROUND", first_round)
    monkeypatch.setattr(fullray, "VISIBLE_LAST_ROUND_SAMPLES", last_round)
    field = RecordingSphereField(0.6, 200.0)
    origins, dirs = random_rays(300, 11, spread=1.1)
    near, far = ray_aabb(origins, dirs, LO, HI)
    samples = stepped_samples(near, far, 0.01, 1024, perturb=True, generator=torch.Generator().manual_seed(4))
    alpha = render_rays(field, origins, dirs, samples)["alpha"]  # one pass over every sample
    before = transmittance(alpha, samples.ray_indices, samples.n_rays)
    for threshold in (1e-1, 1e-4):
        field.geometry_calls.clear()
        kept = visible_samples(field, origins, dirs, samples, threshold)
        expected = samples.select(before > threshold)
        assert torch.equal(kept.ray_indices, expected.ray_indices)
        assert torch.equal(kept.t_starts, expected.t_starts) and torch.equal(kept.t_ends, expected.t_ends)
        assert 0 < len(expected.ray_indices) < 0.8 * len(samples.ray_indices)
        if first_round == 2:  # rounds [0, 2), [2, 4), [4, 8), ...: a ray stops after its last kept sample's
            count, k = samples.counts(), kept.counts()
            end = 2 ** (torch.log2((k - 1).clamp_min(1).double()).floor().long() + 1)
            evaluated = torch.where(k < count, end.clamp_max(count), count)
            rows = field.geometry_calls
            assert len(rows) > 4 and sum(rows) == int(evaluated.sum()) < len(samples.ray_indices)
        if first_round > 1000:
            assert field.geometry_calls == [len(samples.ray_indices)]


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_occupancy_march_equals_the_dense_formulation(threads):
    """The Warp march keeps exactly the sections that the dense (rays x steps) torch formulation keeps:
    same rays, same starts, bit for bit, with perturbed offsets and however the rays are split over
    threads (an odd count included)."""
    grid = sphere_grid(0.6, 100.0, res=24)
    origins, dirs = random_rays(301, 11, spread=1.1)
    step, max_samples = 0.013, 512
    near, far = ray_aabb(origins, dirs, LO, HI)
    shift = step_offsets(len(near), near, True, torch.Generator().manual_seed(4))
    first, end = step_range(near, far, step, max_samples, shift)
    k = first[:, None] + torch.arange(int((end - first).max()), dtype=near.dtype)
    starts = near[:, None] + (k + shift[:, None]) * step
    ends = starts + step
    valid = (starts < far[:, None]) & (k < end[:, None])
    centres = origins[:, None, :] + (0.5 * (starts + ends))[..., None] * dirs[:, None, :]
    valid &= grid.query(centres.reshape(-1, 3)).reshape(valid.shape)
    dense = pack_dense(starts, ends, valid)
    args = (origins, dirs, near, far, shift, first, end, step, grid.aabb_min, grid.cell_size, grid.occupied)
    marched = march_occupied(*args, grid.resolution, cpu_threads=threads)
    assert dense.ray_indices.numel() > 1000
    assert torch.equal(marched.ray_indices, dense.ray_indices)
    assert torch.equal(marched.t_starts, dense.t_starts) and torch.equal(marched.t_ends, dense.t_ends)


def test_occupancy_perturbed_samples_lie_in_occupied_cells():
    grid = sphere_grid(0.6, 100.0, res=16)
    origins, dirs = random_rays(64, 8, spread=1.0)
    s = grid.sample(origins, dirs, 0.03, 512, perturb=True, generator=torch.Generator().manual_seed(1))
    assert grid.query(s.points(origins, dirs)).all()
    near, _ = ray_aabb(origins, dirs, LO, HI)
    offset = torch.remainder(s.t_starts - near[s.ray_indices], 0.03)
    assert not torch.allclose(offset, torch.zeros_like(offset), atol=1e-4)


def test_empty_occupancy_grid_gives_no_samples():
    grid = OccupancyGrid(LO, HI, 8, OccupancyConfig(jitter=False))
    grid.update(lambda x: (torch.full((x.shape[0],), 10.0), torch.full((x.shape[0],), 50.0)), step=0)
    assert not grid.occupied.any()
    origins, dirs = random_rays(16, 9)
    s = grid.sample(origins, dirs, 0.01, 512)
    assert s.t_starts.numel() == 0 and s.n_rays == 16
