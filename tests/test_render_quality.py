"""``--quality preview`` of ``shellsim render`` and ``shellsim scene --video``: half the size, one ray per
pixel, no shadow rays, and frames whose records a final render never keeps.

The truth is a final render made with those settings spelt out (half the size, ``antialias=1``, a look
without shadows): the preview's pixels equal it, its record does not."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from test_render_cli import asset_dir, error_line, render, write_cameras, write_motion  # noqa: F401

from shellsim.errors import SettingError
from shellsim.io.png import RECORD_CHUNK


def record(path) -> dict:
    with Image.open(path) as image:
        return json.loads(image.info[RECORD_CHUNK])


def pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path), np.int16)


def test_a_motion_preview_is_a_half_size_one_ray_unshadowed_render_with_its_own_record(tmp_path, asset_dir):  # noqa: F811
    """``render --motion --quality preview`` at 16x12 writes 8x6 frames equal to a final render at 8x6 with
    one ray and no shadows; a final render into the preview's directory renders every frame again."""
    from shellsim.film.cameras import CameraSettings
    from shellsim.film.motion_frames import render_motion
    from shellsim.world import WorldLook

    motion = write_motion(tmp_path / "sway.npz", asset_dir, 2)
    preview, final = tmp_path / "preview", tmp_path / "final"
    size = ["--width", "16", "--height", "12", "--camera", "side"]
    assert render(asset_dir, preview, *size, "--quality", "preview", motion=motion) == 0
    frames = sorted(preview.glob("*.png"))
    assert [f.name for f in frames] == ["00000.png", "00001.png"]
    assert Image.open(frames[0]).size == (8, 6)
    spelt = dict(camera=CameraSettings(camera="side"), size=(8, 6), antialias=1, progress=False)
    render_motion(asset_dir, motion, final, look=WorldLook(shadows=False), **spelt)
    for name in ("00000.png", "00001.png"):
        assert np.abs(pixels(preview / name) - pixels(final / name)).max() == 0
        a, b = record(preview / name), record(final / name)
        assert a["renderer"] != b["renderer"] and {k: v for k, v in a.items() if k != "renderer"} == {
            k: v for k, v in b.items() if k != "renderer"
        }
    again = render_motion(asset_dir, motion, preview, look=WorldLook(shadows=False), **spelt)
    assert again.rendered == 2 and again.skipped == 0  # the preview's frames are not kept
    kept = render_motion(asset_dir, motion, preview, look=WorldLook(shadows=False), **spelt)
    assert kept.skipped == 2


def test_a_rest_preview_halves_the_camera_files_size(tmp_path, asset_dir):  # noqa: F811
    cameras = write_cameras(tmp_path / "cams.json", 1)  # 24x18
    out = tmp_path / "rest"
    assert render(asset_dir, out, "--quality", "preview", cameras=cameras) == 0
    assert Image.open(next(out.glob("*.png"))).size == (12, 9)


def test_a_preview_with_antialias_is_one_error_line(tmp_path, asset_dir, capsys):  # noqa: F811
    motion = write_motion(tmp_path / "m.npz", asset_dir, 1)
    options = ["--quality", "preview", "--antialias", "4"]
    assert render(asset_dir, tmp_path / "out", *options, motion=motion) == 2
    line = error_line(capsys)
    assert "--antialias" in line and "--quality" in line


def test_scene_quality_needs_a_video():
    from shellsim.jobs.scene import SceneSettings

    with pytest.raises(SettingError, match="video"):
        SceneSettings(scene="shot.toml", quality="preview")
    assert SceneSettings(scene="shot.toml", video="shot.mp4", quality="preview").quality == "preview"


def test_scene_video_preview_films_half_size_frames(tmp_path):
    """``scene --video --quality preview``: 256x256 frames recorded as a preview; ``render --scene`` of the
    same camera, final, at that size with one ray and no shadows, renders them again and sees the same."""
    import trimesh

    from shellsim.cli.main import main

    ball = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=2, radius=0.05).export(ball)
    scene = tmp_path / "shot.toml"
    scene.write_text(f'[world]\nframes = 2\ngravity = 0\n\n[[body]]\nname = "ball"\nmesh = "{ball}"\n')
    out = tmp_path / "shot"
    args = ["scene", str(scene), "--out", str(out), "--video", str(tmp_path / "shot.mp4")]
    assert main([*args, "--quality", "preview"]) == 0
    frames = sorted((out / "frames").glob("*.png"))
    assert len(frames) == 2 and Image.open(frames[0]).size == (256, 256)
    preview = pixels(frames[1])
    from shellsim.film.shot_frames import render_scene
    from shellsim.world import WorldLook

    again = render_scene(
        out, out / "frames", size=(256, 256), antialias=1, look=WorldLook(shadows=False), progress=False
    )
    assert again.rendered == 2  # a final render keeps no preview frame
    assert np.abs(pixels(frames[1]) - preview).max() <= 1
