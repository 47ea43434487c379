"""One rendering pipeline (neural.render.view): ``shellsim eval`` and ``shellsim render --cameras`` render
with the same code, so the image that eval scores for a held-out view is, pixel for pixel, the PNG that
render writes for that camera (up to its 8-bit rounding); a deformed frame with the identity motion is the
rest image; and a map to rest space is applied as documented (points and directions mapped, sections
stretched, samples outside dropped), checked on a scaled and shifted copy of the scene with a map written
here."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image
from scenes import look_at
from test_render_deformed import CENTER, EYE, camera, make_asset

import neural.train
from neural.asset import load_asset, load_field
from neural.config import NarrowBandConfig
from neural.data import load_dataset
from neural.metrics import psnr
from neural.render.raycast import EmbreeCaster
from neural.render.view import asset_sampler, narrow_band_sampler, render_camera
from shellsim.cli.main import main
from shellsim.film.renderer import DeformedRenderer
from shellsim.tetcage.store import load_or_build_cage

SIZE = 24
N_VIEWS = 9  # views 0 and 8 are held out


def write_views(root, angle_x: float = 0.8):
    """A NeRF-synthetic dataset of ``N_VIEWS`` cameras circling the test asset's ball (flat grey images: the
    pictures do not matter, only the cameras)."""
    (root / "train").mkdir(parents=True)
    frames = []
    for k in range(N_VIEWS):
        a = 2 * np.pi * k / N_VIEWS
        eye = CENTER + np.array([np.cos(a), np.sin(a), 0.5]) * 0.9
        Image.new("RGBA", (SIZE, SIZE), (128, 128, 128, 255)).save(root / "train" / f"r_{k}.png")
        frames.append({"file_path": f"./train/r_{k}", "transform_matrix": look_at(eye, CENTER).tolist()})
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": angle_x, "frames": frames}))
    return root


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("one_renderer")
    return make_asset(root / "asset"), write_views(root / "data")


def test_eval_scores_the_image_render_writes(scene, tmp_path, monkeypatch):
    asset_dir, data_dir = scene
    scored = []

    def spy(image, target):
        scored.append(np.array(image))
        return psnr(image, target)

    monkeypatch.setattr(neural.train, "psnr", spy)
    report = tmp_path / "eval.json"
    argv = ["eval", "--asset", str(asset_dir), "--data", str(data_dir), "--no-full-ray", "--device", "cpu"]
    assert main([*argv, "--json", str(report)]) == 0
    assert json.loads(report.read_text())["heldout_views"] == [0, 8]
    assert len(scored) == 2

    out = tmp_path / "frames"
    assert main(["render", "--asset", str(asset_dir), "--cameras", str(data_dir), "--out", str(out)]) == 0
    for view, image in zip((0, 8), scored, strict=True):
        written = np.asarray(Image.open(out / f"r_{view}.png"), dtype=np.float64) / 255
        assert image.shape == written.shape == (SIZE, SIZE, 3)
        assert image.std() > 0.05 and (image < 0.95).mean() > 0.2  # the ball fills part of the view
        np.testing.assert_allclose(written, image, atol=0.5 / 255 + 1e-6)  # PNG rounding only


def test_identity_motion_renders_the_rest_image_of_eval(scene):
    """The deformed pipeline with the cage at rest (inverse map on) equals the rest pipeline that eval
    runs (no map): same samples per pixel, same colours up to float32 rounding."""
    asset_dir, data_dir = scene
    asset = load_asset(asset_dir)
    field = load_field(asset, "cpu")
    data = load_dataset(data_dir, background=asset.background)
    renderer = DeformedRenderer(asset, field, load_or_build_cage(asset), "cpu")
    rest, rest_stats = render_camera(field, data.cameras, 0, asset_sampler(asset), renderer.background)
    moved, stats = renderer.render(data.cameras, 0, renderer.cage.vertices)
    np.testing.assert_array_equal(stats["counts"], rest_stats["counts"])
    assert stats["dropped_samples"] == 0 and stats["map_ms"] > 0 and rest_stats["map_ms"] == 0
    np.testing.assert_allclose(moved, rest, atol=1e-5)


def test_chunks_of_rays_do_not_change_the_image(scene):
    """An image rendered in chunks of 37 rays (shading rounds, early termination and the colour skip all
    per chunk) equals the image the narrow band renders in one pass, sample counts included."""
    asset_dir, data_dir = scene
    asset = load_asset(asset_dir)
    field = load_field(asset, "cpu")
    data = load_dataset(data_dir, background=asset.background)
    background = torch.as_tensor(asset.background, dtype=torch.float32)
    sampler = asset_sampler(asset)
    assert sampler.rays_per_chunk >= SIZE * SIZE  # the default: one pass
    whole, stats = render_camera(field, data.cameras, 8, sampler, background)
    chunked, chunked_stats = render_camera(field, data.cameras, 8, sampler, background, chunk=37)
    assert stats["samples_per_pixel"] > 0.5
    np.testing.assert_array_equal(chunked_stats["counts"], stats["counts"])
    np.testing.assert_allclose(chunked, whole, atol=1e-5)


class ScaleShift:
    """The map to rest space of the scene scaled by ``k`` about ``pivot`` (3,) and shifted by ``shift`` (3,),
    dropping rest points above the height ``top``: ``x_rest = pivot + (x - pivot - shift) / k``, directions
    unchanged, ``stretch = 1 / k``."""

    def __init__(self, k, pivot, shift, top):
        self.k, self.top = k, top
        self.pivot, self.shift = (torch.as_tensor(v, dtype=torch.float32) for v in (pivot, shift))

    def forward(self, x):
        return self.pivot.numpy() + self.k * (np.asarray(x) - self.pivot.numpy()) + self.shift.numpy()

    def map_rays(self, points, unit_dirs):
        x_rest = self.pivot + (points - self.pivot - self.shift) / self.k
        stretch = torch.full_like(points[:, 0], 1 / self.k)
        return x_rest, unit_dirs, stretch, x_rest[:, 2] <= self.top


def test_a_map_to_rest_space_is_applied_as_documented(scene):
    """Rays through the scaled, shifted shells with the map back show the rest scene; a sample the map
    drops is one the rest image lacks: the truth is the rest image without the samples above ``top``."""
    asset = load_asset(scene[0])
    field = load_field(asset, "cpu")
    bg = torch.as_tensor(asset.background, dtype=torch.float32)
    k, top = 1.7, CENTER[2] + 0.08
    to_rest = ScaleShift(k, CENTER + [0.05, 0.0, -0.1], np.array([0.3, -0.2, 0.5]), top)
    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    for mesh in (outer, inner):
        mesh.vertices = to_rest.forward(mesh.vertices)
    config = NarrowBandConfig(**asset.meta["narrowband"])
    moved_sampler = narrow_band_sampler(EmbreeCaster(outer, inner), config.scaled(k))
    moved_view = camera(to_rest.forward(EYE), target=to_rest.forward(CENTER))
    image, stats = render_camera(field, moved_view, 0, moved_sampler, bg, to_rest)

    rest_sampler = asset_sampler(asset)

    def below_top(origins, dirs):
        samples = rest_sampler(origins, dirs)
        return samples.select(samples.points(origins, dirs)[:, 2] <= top)

    rest, rest_stats = render_camera(field, camera(EYE), 0, rest_sampler, bg)
    truth, truth_stats = render_camera(field, camera(EYE), 0, below_top, bg)
    np.testing.assert_array_equal(stats["counts"], rest_stats["counts"])  # dropped samples counted
    assert stats["dropped_samples"] == rest_stats["counts"].sum() - truth_stats["counts"].sum() > 100
    assert psnr(truth, rest) < 40  # the dropped samples matter (measured 21 dB)
    assert psnr(image, truth) > 60  # measured 145 dB; 35 dB without the stretch
