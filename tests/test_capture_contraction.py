"""Real captures in contracted space (paper Sec. 4.7) and the object cut out of them (issue 43), on the
synthetic capture of :func:`scenes.write_unbounded_scene`: a sphere on a checkered table inside a distant
textured room, photos without alpha.

The field's box is deliberately too small (``bound`` 0.35 about the cameras' focus, while the sphere reaches
0.6 from it): the old bounded field cuts the object off at its box, the contracted one keeps all of it.
Truths from outside the code: the analytic scene (its colours, the sphere's surface, the table's plane).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scenes import UNBOUNDED, unbounded_object_mask, write_unbounded_scene

from neural.asset import load_asset, load_field
from neural.config import HashGridConfig, PipelineConfig, ShellConfig, Stage1Config, Stage2Config
from neural.data import load_dataset
from neural.metrics import psnr
from neural.pipeline import train_asset
from neural.render.view import asset_sampler, render_camera
from neural.shell.cutout import (
    FLOOR_VOXELS,
    PROPOSAL_GRID,
    Cut,
    RegionMask,
    cut_shells,
    is_table,
    propose_cut,
)
from shellsim.cli.main import main
from shellsim.film.renderer import DeformedRenderer, SceneRenderer
from shellsim.world import WorldLook

BOUND = 0.35  # the object's box half-size: smaller than the sphere (radius 0.5, 0.6 from the focus)
GRID = HashGridConfig(n_levels=8, log2_table_size=14, max_resolution=256)


def _config(space: str) -> PipelineConfig:
    config = PipelineConfig(bound=BOUND, space=space)
    config.field = dataclasses.replace(config.field, hashgrid=GRID, kernel_grid=16)
    config.stage1 = Stage1Config(
        steps=500, target_samples=8192, max_rays=2048, occupancy_resolution=48, eval_every=500, seed=0
    )
    config.stage2 = Stage2Config(steps=60, rays=2048, eval_every=60)
    config.shell = ShellConfig(resolution=96)
    return config


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """The scene's dataset and the contracted asset trained on it for 500 steps."""
    root = tmp_path_factory.mktemp("capture")
    data_dir = write_unbounded_scene(root / "data", n_views=24, width=40, height=30)
    asset = load_asset(train_asset(data_dir, root / "contracted", _config("contracted"), "cpu"))
    return load_dataset(data_dir, bound=BOUND), asset


#: The table's checker period of the scene both spaces are compared on: squares of 1, 8-14 px across in a
#: 40 px view, which the views resolve (the default period's squares, 2-4 px, average to one brown).
COARSE_TABLE = 2.0


@pytest.fixture(scope="module")
def both_spaces(tmp_path_factory):
    """The dataset of the scene with the coarse table and assets of both spaces trained on it for 1500
    steps: ``(data, {"contracted": ..., "bounded": ...})``. The contracted field grows the table out of
    empty space only after about a thousand steps (outside the object, 500 steps: 18.2 against 17.5 dB;
    1000: 18.9 against 17.8; 1500: 20.9 against 17.6)."""
    root = tmp_path_factory.mktemp("spaces")
    data_dir = write_unbounded_scene(
        root / "data", n_views=24, width=40, height=30, table_period=COARSE_TABLE
    )
    assets = {}
    for space in ("contracted", "bounded"):
        config = _config(space)
        config.stage1 = dataclasses.replace(config.stage1, steps=1500, eval_every=1500)
        assets[space] = load_asset(train_asset(data_dir, root / space, config, "cpu"))
    return load_dataset(data_dir, bound=BOUND), assets


def _render(asset, data, view: int) -> np.ndarray:
    field = load_field(asset)
    background = torch.as_tensor(asset.background, dtype=torch.float32)
    return render_camera(field, data.cameras, view, asset_sampler(asset), background)[0]


@pytest.mark.slow  # both spaces trained 1500 steps: 2 min on 2 cores
def test_the_room_around_the_object_is_learnt_better_than_by_an_environment_map(both_spaces):
    data, assets = both_spaces
    scores = {}
    for space, asset in assets.items():
        outside, whole = [], []
        for v in data.test_idx:
            image, photo = _render(asset, data, int(v)), data.images[v]
            mask = ~unbounded_object_mask(data.cameras, int(v), pad=0.05)
            outside.append(psnr(image[mask], photo[mask]))
            whole.append(psnr(image, photo))
        scores[space] = (float(np.mean(outside)), float(np.mean(whole)))
    assert [asset.meta["field"]["contract"] for asset in assets.values()] == [True, False]
    (outside_c, whole_c), (outside_b, whole_b) = scores["contracted"], scores["bounded"]
    # the table seen with parallax, which one colour per direction cannot draw (measured: 20.9 against
    # 17.6 dB outside the object, 21.7 against 17.7 with seed 1; the room sphere lies past the shells'
    # reach and is drawn by the environment map in both), and the frame as a whole (21.4 against 16.1 dB)
    assert outside_c > outside_b + 1.5, scores
    assert whole_c > whole_b + 3.0, scores


#: Half a pixel's footprint on the sphere (focal 34 px, the sphere 1.7-2.2 from the cameras): how far the
#: learnt surface may sit from the true one in a 40 x 30 capture (measured: up to 0.03 inside).
HALF_PIXEL = 0.03


def _sphere_points(n: int = 4000, depth: float = 0.0) -> np.ndarray:
    """(N, 3) points ``depth`` under the sphere's surface, above the table (what the cameras see of it)."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = np.asarray(UNBOUNDED.object_center) + (UNBOUNDED.object_radius - depth) * d
    return points[points[:, 2] > 0.15]


@pytest.mark.slow
def test_no_part_of_an_object_past_the_box_is_cut_off(both_spaces):
    points = _sphere_points(depth=HALF_PIXEL)
    far = (np.abs(points - np.asarray(UNBOUNDED.target)) > BOUND).any(axis=1)
    assert far.mean() > 0.3  # most of the surface lies beyond the old box
    contracted = both_spaces[1]["contracted"].outer_mesh().contains(points)
    bounded = both_spaces[1]["bounded"].outer_mesh().contains(points)
    assert contracted.mean() > 0.99, contracted.mean()  # the whole object is inside M+
    assert bounded[far].mean() < 0.05, bounded[far].mean()  # the bounded field's shells end at its box


@pytest.mark.slow  # the capture trained 500 steps: 45 s
def test_the_proposed_cut_holds_the_object(capture):
    # (after this short training the table is not flat enough for the plane search: no plane is asserted)
    asset = capture[1]
    cut = propose_cut(load_field(asset), asset.up, center=UNBOUNDED.target, radius=0.9)
    centre, radius = np.asarray(UNBOUNDED.object_center), UNBOUNDED.object_radius
    inside = cut.contains(torch.as_tensor(_sphere_points())).numpy()
    assert inside.mean() > 0.99
    assert np.all(cut.lo[:2] > centre[:2] - 1.5 * radius) and np.all(cut.hi[:2] < centre[:2] + 1.5 * radius)


@pytest.mark.slow
def test_body_and_backdrop_at_rest_render_as_the_uncut_capture(capture, tmp_path):
    data, asset = capture
    out = tmp_path / "sphere"
    assert main(["cut", "--asset", str(asset.root), "--out", str(out), "--resolution", "96",
                 "--center", "0,0,0.4", "--radius", "0.9"]) in (0, None)  # fmt: skip
    cut_asset = load_asset(out)
    assert cut_asset.cut is not None
    assert cut_asset.outer_mesh().is_watertight
    field = load_field(cut_asset)
    whole = DeformedRenderer(asset, load_field(asset), None)
    parts = DeformedRenderer(cut_asset, field, None)
    # in a world with a look, the body stands on its own table (no checkered ground under it) and the sky
    # is its capture's environment map: the world adds nothing to the capture, alone or in a scene
    in_world = DeformedRenderer(cut_asset, field, None, look=WorldLook())
    assert in_world.look.ground is False
    scenes = [SceneRenderer([parts], look=WorldLook()), SceneRenderer([parts])]
    for v in data.test_idx:
        uncut, _ = whole.render(data.cameras, int(v))
        for renderer in (parts, in_world, *scenes):
            together, _ = renderer.render(data.cameras, int(v))
            assert psnr(together, uncut) >= 35.0, renderer


def test_the_body_mask_and_the_backdrop_mask_split_every_sample():
    cut = Cut([-1, -1, 0], [1, 1, 2], point=[0, 0, 0.5], normal=[0, 0, 1])
    points = torch.rand(1000, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 4 - 2
    dirs = torch.nn.functional.normalize(torch.ones_like(points), dim=1)
    body = RegionMask(cut, inside=True).map_rays(points, dirs)[3]
    backdrop = RegionMask(cut, inside=False).map_rays(points, dirs)[3]
    assert torch.equal(body, ~backdrop)
    expected = (points.abs()[:, :2] <= 1).all(1) & (points[:, 2] >= 0.5) & (points[:, 2] <= 2)
    assert torch.equal(body, expected)


@pytest.mark.slow
def test_cut_shells_of_a_box_stay_inside_it(capture):
    field = load_field(capture[1])
    cut = Cut([-0.3, -0.3, 0.02], [0.3, 0.3, 0.9])  # slices through the sphere: the body is its middle
    shells = cut_shells(field, cut, ShellConfig(resolution=64))
    assert shells.outer.is_watertight
    lo, hi = shells.outer.bounds
    voxel = 0.88 * 1.1 / 63
    assert np.all(lo > cut.lo - 4 * voxel) and np.all(hi < cut.hi + 4 * voxel)


class _PlaneAndBall:
    """Field-like union of the half-space behind the plane ``n . x = 0`` and a ball of radius 0.35 in front
    of it, touching it: an object on its table (``n`` up) or hanging on its wall (``n`` sideways)."""

    def __init__(self, normal):
        self.normal = torch.tensor(normal, dtype=torch.float64)
        self.ball = 0.35 * self.normal
        self.center, self.scale, self.contraction = torch.zeros(3), 1.0, None

    def sdf_and_kernel(self, x):
        x = x.double()
        sdf = torch.minimum(x @ self.normal, (x - self.ball).norm(dim=1) - 0.35).float()
        return sdf, torch.full_like(sdf, 0.01)


@pytest.mark.slow
@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0)], ids=["table", "wall"])
def test_the_proposed_cut_finds_the_table_or_the_wall_and_boxes_the_object_on_it(normal):
    field = _PlaneAndBall(normal)
    cut = propose_cut(field, up=(0.0, 0.0, 1.0), center=(0.0, 0.0, 0.0), radius=1.0)
    np.testing.assert_allclose(cut.normal, normal, atol=0.02)  # towards the object, whatever the tilt
    floor = FLOOR_VOXELS * 2.0 / (PROPOSAL_GRID - 1)  # the floor is that many voxels over the plane
    assert abs(float(np.dot(cut.point, normal)) - floor) < 0.01
    ball = field.ball.numpy()
    np.testing.assert_allclose(cut.lo, ball - 0.35, atol=0.1)  # the ball's box and its margin
    np.testing.assert_allclose(cut.hi, ball + 0.35, atol=0.1)
    assert is_table(cut.normal, (0.0, 0.0, 1.0)) == (normal[2] == 1.0)
    named = propose_cut(field, up=(0.0, 0.0, 1.0), box=Cut(ball - 0.6, ball + 0.6))  # the user's box
    np.testing.assert_allclose(named.lo, ball - 0.6)
    np.testing.assert_allclose(named.normal, normal, atol=0.02)  # and the floor found inside it
