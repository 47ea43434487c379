"""``shellsim eval`` and ``shellsim render --cameras`` render with the same code: the image that eval scores
for a held-out view is, pixel for pixel, the PNG that render writes for that camera (up to its 8-bit
rounding); and a deformed frame with the identity motion is the rest image."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from scenes import look_at
from test_render_deformed import CENTER, make_asset

import neural.train
from neural.asset import load_asset, load_field
from neural.data import load_dataset
from neural.render.view import asset_sampler, render_camera
from shellsim.cage import load_or_build_cage
from shellsim.cli import main
from shellsim.render import DeformedRenderer

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

    psnr = neural.train.psnr
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
