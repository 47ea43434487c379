"""What the training cameras saw (neural.visibility), against closed forms: the opaque depth of an exact
sphere along each ray, and the shadow a sphere casts from cameras that all look down on it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scenes import SphereField, write_sphere_scene

from neural.data import load_dataset
from neural.errors import InputError
from neural.field.network import fibonacci_sphere
from neural.render.view import full_ray_sampler
from neural.visibility import Visibility, measure_visibility, opaque_depth

RADIUS = 0.6


class BoxedSphere(SphereField):
    """A :class:`SphereField` inside the box [-1, 1]^3 that the visibility grid covers (``scale`` 1)."""

    scale = 1.0

    def sdf(self, x):
        return self.geometry(x).sdf


def _ray_sphere(o: np.ndarray, d: np.ndarray, radius: float = RADIUS) -> np.ndarray:
    """(N,) distance to the first hit of unit rays on the sphere at the origin, inf on a miss."""
    b = (o * d).sum(1)
    disc = b * b - ((o * o).sum(1) - radius**2)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc > 0) & (t > 0), t, np.inf)


def test_opaque_depth_is_where_the_exact_sphere_stops_the_light():
    field = BoxedSphere(RADIUS, inv_s=2000.0)
    rng = np.random.default_rng(0)
    o = np.tile([0.0, 0.0, 3.0], (400, 1)) + rng.normal(0, 0.05, (400, 3))
    d = np.stack([rng.uniform(-0.3, 0.3, 400), rng.uniform(-0.3, 0.3, 400), -np.ones(400)], 1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    depth, mean = opaque_depth(
        field, torch.tensor(o).float(), torch.tensor(d).float(), full_ray_sampler(field)
    )
    truth = _ray_sphere(o, d)
    hit = np.isfinite(truth)
    assert 50 < hit.sum() < 350  # both kinds of ray are tested
    b = (o * d).sum(1)
    clear = np.sqrt((o * o).sum(1) - b * b) > RADIUS + 0.01  # misses by 20 kernel widths
    assert clear.sum() > 20
    assert np.isinf(depth.numpy()[~hit]).all() and np.isinf(mean.numpy()[clear]).all()
    # a sharp kernel: the transmittance falls to SEEN_TRANSMITTANCE within a few kernel widths of the hit,
    # a marching step (2 sqrt 3 / 512 in the unit box) at most later
    s = 1.0 / 2000.0
    step = 2.0 * math.sqrt(3.0) / 512
    cos = np.abs(((o[hit] + truth[hit, None] * d[hit]) / RADIUS * d[hit]).sum(1))
    head_on = cos > 0.5
    late = depth.numpy()[hit][head_on] - truth[hit][head_on]
    assert late.min() > -step and late.max() < 8 * s / 0.5 + 2 * step
    assert np.abs(mean.numpy()[hit][head_on] - truth[hit][head_on]).max() < 4 * s / 0.5 + 2 * step


def test_the_unseen_cells_are_the_shadow_of_a_sphere_seen_only_from_above(tmp_path):
    """Cameras at 20-60 degrees of elevation: a cell is seen iff some camera sees its centre (in its frustum)
    along a segment that misses the sphere, checked cell by cell with the exact ray-sphere test."""
    data = load_dataset(write_sphere_scene(tmp_path, n_views=16, size=96, radius=RADIUS, elevation=(20, 60)))
    field = BoxedSphere(RADIUS, inv_s=2000.0)
    visibility, _ = measure_visibility(field, data, full_ray_sampler(field), resolution=64)
    centers = visibility.centers().double().numpy()
    cams = data.cameras
    views = [int(v) for v in data.train_idx]

    def seen_by_truth(radius: float) -> np.ndarray:
        seen = np.zeros(len(centers), bool)
        for v in views:
            eye = cams.c2w[v, :3, 3]
            to = centers - eye
            dist = np.linalg.norm(to, axis=1)
            d = to / dist[:, None]
            local = (to @ cams.c2w[v, :3, :3]) / -(to @ cams.c2w[v, :3, 2])[:, None]  # (x, y, -1) in view
            px = cams.fx[v] * local[:, 0] + cams.cx[v]
            py = -cams.fy[v] * local[:, 1] + cams.cy[v]
            inside = (px >= 0) & (px < cams.width[v]) & (py >= 0) & (py < cams.height[v])
            seen |= inside & (_ray_sphere(np.tile(eye, (len(d), 1)), d, radius) >= dist)
        return seen

    cell = visibility.cell
    # a cell counts as seen up to half its diagonal and a depth pixel's width behind a surface: cells that
    # close to the shadow's edge may go either way; every other cell must match
    band = cell + 3.0 / float(cams.fx[0])
    sure_seen = seen_by_truth(RADIUS + band)
    sure_unseen = ~seen_by_truth(RADIUS - band)
    measured = visibility.seen_views.reshape(-1).numpy() > 0
    assert sure_unseen.sum() > 100 and sure_seen.sum() > 1000
    assert measured[sure_seen].all()
    assert not measured[sure_unseen].any()
    # a camera at distance D and elevation e sees the sphere down to the latitude e - acos(R / D): the lowest
    # camera sets the seen support (the grid's quantile of the seen heights lies a little above it)
    eyes = cams.c2w[views, :3, 3]
    distance = np.linalg.norm(eyes, axis=1)
    latitude = np.arcsin(eyes[:, 2] / distance) - np.arccos(RADIUS / distance)
    lowest = RADIUS * np.sin(latitude.min())
    assert lowest < visibility.support + visibility.lo[2] < lowest + 2 * cell
    # what it reports: the share of the surface that no camera faces (0.11 here), and surface seen only at
    # grazing angles (incidence cosine below 0.2, past 78 degrees) may count as unseen
    share = visibility.unseen_surface_share
    points = RADIUS * fibonacci_sphere(20000).double().numpy()
    unseen, unseen_or_grazing = (1 - _seen_share(points, cams, views, c) for c in (0.0, 0.2))
    assert unseen > 0.05
    assert unseen - 0.01 < share < unseen_or_grazing + 0.01


def _seen_share(points: np.ndarray, cams, views, min_cos: float) -> float:
    """Share of points (N, 3) on the sphere that some camera faces at an incidence cosine above ``min_cos``
    (the sphere is convex: facing the camera is being seen)."""
    seen = np.zeros(len(points), bool)
    normals = points / RADIUS
    for v in views:
        eye = cams.c2w[v, :3, 3]
        to = eye - points
        facing = (normals * to).sum(1) / np.linalg.norm(to, axis=1) > min_cos
        seen |= facing
    return float(seen.mean())


def test_a_visibility_grid_saves_and_loads_and_a_bad_file_is_named(tmp_path):
    grid = Visibility(
        torch.randint(0, 9, (8, 8, 8), dtype=torch.uint8),
        np.array([-1.0, -1, -1]),
        0.25,
        np.array([0, 0, 1.0]),
        0.4,
        7,
        0.25,
    )
    grid.save(tmp_path / "v.safetensors")
    back = Visibility.load(tmp_path / "v.safetensors")
    assert torch.equal(back.seen_views, grid.seen_views) and back.support == 0.4 and back.views == 7
    assert back.unseen_surface_share == 0.25
    assert back.cell == 0.25 and np.array_equal(back.lo, grid.lo)
    (tmp_path / "bad.safetensors").write_bytes(b"not a grid")
    with pytest.raises(InputError, match="bad.safetensors: not a visibility grid"):
        Visibility.load(tmp_path / "bad.safetensors")
