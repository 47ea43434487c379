"""``shellsim render`` end to end on the small test asset of ``test_render_deformed``: rest renders of a
camera file, motion renders that resume, the MP4, and one-line errors for bad input."""

from __future__ import annotations

import json
import math
import os
import shutil

import numpy as np
import pytest
from PIL import Image
from test_render_deformed import CENTER, make_asset

from neural.asset import load_asset
from shellsim.cli.main import main
from shellsim.motion.format import Motion, save_motion
from shellsim.tetcage.store import load_cage


@pytest.fixture(scope="module")
def asset_dir(tmp_path_factory):
    return make_asset(tmp_path_factory.mktemp("asset"))


def write_cameras(path, n: int, with_size: bool = True):
    """A NeRF-synthetic-style camera file of ``n`` views around the asset (no images on disk)."""
    frames = []
    for i in range(n):
        a = 2 * math.pi * i / n
        eye = CENTER + np.array([math.cos(a), math.sin(a), 0.4])
        back = (eye - CENTER) / np.linalg.norm(eye - CENTER)
        right = np.cross([0.0, 0.0, 1.0], back)
        right /= np.linalg.norm(right)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(back, right), back, eye
        frames.append({"file_path": f"./views/v_{i}", "transform_matrix": c2w.tolist()})
    data = {"camera_angle_x": 0.8, "frames": frames}
    if with_size:
        data.update(w=24, h=18)
    path.write_text(json.dumps(data))
    return path


def write_motion(path, asset_dir, n_frames: int, vertices=None):
    """A motion of the asset's cage: a sideways sway growing with height (or of other ``vertices``)."""
    cage = load_cage(load_asset(asset_dir).cage_path)
    rest = cage.vertices if vertices is None else vertices
    tets = cage.tets if vertices is None else np.zeros((1, 4), np.int64)
    h = np.clip(rest[:, 2] - rest[:, 2].min(), 0, None)
    frames = [rest + np.outer(0.3 * h**2 * math.sin(0.7 * k), [1.0, 0.0, 0.0]) for k in range(n_frames)]
    save_motion(path, Motion(rest, tets, np.stack(frames), np.arange(n_frames) / 10.0, {"fps": 10.0}))
    return path


def render(asset_dir, out, *options, motion=None, cameras=None) -> int:
    """Exit code of ``shellsim render --asset ASSET_DIR [--motion MOTION] [--cameras CAMERAS] --out OUT
    OPTIONS...`` (paths in ``options`` may be ``Path``s)."""
    args = ["render", "--asset", str(asset_dir)]
    if motion is not None:
        args += ["--motion", str(motion)]
    if cameras is not None:
        args += ["--cameras", str(cameras)]
    return main([*args, "--out", str(out), *map(str, options)])


def error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.slow
def test_simulate_video_renders_a_new_motion_anew_and_resume_keeps_its_frames(tmp_path, asset_dir):
    """``simulate --video`` run again with other settings (--overwrite) must not reuse the earlier motion's
    frames; run again with the same settings, it keeps them."""
    video, frames = tmp_path / "drop.mp4", tmp_path / "drop_frames"
    base = ["simulate", "--asset", str(asset_dir), "--frames", "3", "--out", str(tmp_path / "drop.npz")]
    base += ["--video", str(video), "--video-size", "16x12"]

    def images():
        return {p.name: np.asarray(Image.open(p)) for p in sorted(frames.iterdir())}

    assert main([*base, "--drop-height", "0"]) == 0
    low = images()
    assert main([*base, "--drop-height", "0.5", "--overwrite"]) == 0
    high = images()
    assert sorted(low) == sorted(high) == ["00000.png", "00001.png", "00002.png"]
    assert all(not np.array_equal(low[k], high[k]) for k in low)
    stamps = {p.name: p.stat().st_mtime_ns for p in frames.iterdir()}
    assert main([*base, "--drop-height", "0.5", "--resume"]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in frames.iterdir()} == stamps


def test_rest_render_writes_one_png_per_camera(tmp_path, asset_dir, capsys):
    cams = write_cameras(tmp_path / "cams.json", 3, with_size=False)
    out = tmp_path / "views"
    assert render(asset_dir, out, "--width", "20", "--height", "14", cameras=cams) == 0
    assert sorted(p.name for p in out.iterdir()) == ["v_0.png", "v_1.png", "v_2.png"]
    for p in out.iterdir():
        image = np.asarray(Image.open(p))
        assert image.shape == (14, 20, 3)
        assert image.min() < 200 and image.max() == 255  # the ball on the white background
    assert "3 frames rendered" in capsys.readouterr().out
    assert render(asset_dir, out, "--width", "20", "--height", "14", cameras=cams) == 0
    assert "0 frames rendered" in capsys.readouterr().out
    assert render(asset_dir, out, "--width", "16", "--height", "16", cameras=cams) == 0  # another size
    assert "3 frames rendered" in capsys.readouterr().out
    assert all(np.asarray(Image.open(p)).shape == (16, 16, 3) for p in out.iterdir())


def test_motion_render_resumes_and_writes_the_video(tmp_path, asset_dir):
    cams = write_cameras(tmp_path / "cams.json", 2)
    motion = write_motion(tmp_path / "m.npz", asset_dir, 4)
    out = tmp_path / "frames"
    assert render(asset_dir, out, "--frames", "0:2", motion=motion, cameras=cams) == 0
    assert sorted(p.name for p in out.iterdir()) == ["00000.png", "00001.png"]
    first = sorted(out.iterdir())
    for p in first:  # mark the first render: a resumed run must not rewrite these files
        os.utime(p, ns=(1, 1))
    video = tmp_path / "clip.mp4"
    assert render(asset_dir, out, "--frames", "0:4", "--video", video, motion=motion, cameras=cams) == 0
    assert sorted(p.name for p in out.iterdir()) == ["00000.png", "00001.png", "00002.png", "00003.png"]
    assert all(p.stat().st_mtime_ns == 1 for p in first)
    images = [np.asarray(Image.open(out / f"{k:05d}.png")) for k in range(4)]
    assert images[0].shape == (18, 24, 3)  # the camera file's size
    assert (np.abs(images[2].astype(int) - images[0]) > 10).any(axis=2).sum() >= 3  # the sway shows

    import imageio.v2 as imageio

    with imageio.get_reader(video) as reader:
        frames = [frame for frame in reader]
        assert reader.get_meta_data()["fps"] == pytest.approx(10.0)
    assert len(frames) == 4
    assert frames[0].shape[:2] == (18, 24)


def test_orbit_render_with_odd_sizes(tmp_path, asset_dir):
    motion = write_motion(tmp_path / "m.npz", asset_dir, 3)
    out, video = tmp_path / "orbit", tmp_path / "orbit.mp4"
    options = ("--camera", "orbit", "--width", "15", "--height", "11", "--frames", "1:3", "--video", video)
    assert render(asset_dir, out, *options, "--fps", "5", motion=motion) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["00001.png", "00002.png"]
    a, b = (np.asarray(Image.open(out / n)) for n in names)
    assert a.shape == (11, 15, 3) and a.min() < 200  # the asset is in view
    assert not np.array_equal(a, b)  # the camera moved

    import imageio.v2 as imageio

    with imageio.get_reader(video) as reader:
        assert sum(1 for _ in reader) == 2


def test_motion_of_another_cage_is_one_error_line(tmp_path, asset_dir, capsys):
    cams = write_cameras(tmp_path / "cams.json", 1)
    motion = write_motion(
        tmp_path / "other.npz", asset_dir, 2, vertices=np.random.default_rng(0).random((7, 3))
    )
    code = render(asset_dir, tmp_path / "o", motion=motion, cameras=cams)
    assert code == 2
    line = error_line(capsys)
    assert str(motion) in line and "moves 7 cage vertices" in line and "made for another cage" in line


@pytest.mark.parametrize("spec", ["x:y", "3:9", "2:1"])
def test_bad_frames_spec_is_one_error_line(tmp_path, asset_dir, capsys, spec):
    cams = write_cameras(tmp_path / "cams.json", 1)
    motion = write_motion(tmp_path / "m.npz", asset_dir, 3)
    code = render(asset_dir, tmp_path / "o", "--frames", spec, motion=motion, cameras=cams)
    assert code == 2
    assert "--frames" in error_line(capsys)


def test_unbuildable_cage_is_one_error_line(tmp_path, asset_dir, capsys, monkeypatch):
    """No cage.npz and fTetWild failing: one line naming the cage file."""
    broken = tmp_path / "asset"
    shutil.copytree(asset_dir, broken)
    (broken / "cage.npz").unlink()

    def fail(*args, **kwargs):
        raise RuntimeError("fTetWild failed")

    monkeypatch.setattr("shellsim.tetcage.build.build_cage", fail)
    cams = write_cameras(tmp_path / "cams.json", 1)
    motion = write_motion(tmp_path / "m.npz", asset_dir, 2)
    code = render(broken, tmp_path / "o", motion=motion, cameras=cams)
    assert code == 2
    line = error_line(capsys)
    assert str(broken / "cage.npz") in line and "fTetWild failed" in line


def test_options_that_need_a_motion(tmp_path, asset_dir, capsys):
    cams = write_cameras(tmp_path / "cams.json", 1)
    code = render(asset_dir, tmp_path / "o", "--video", tmp_path / "v.mp4", cameras=cams)
    assert code == 2
    assert "--video: needs --motion" in error_line(capsys)


def test_frames_of_another_motion_or_size_are_rendered_again(tmp_path, asset_dir, capsys):
    """A PNG is reused only when it records the same motion frame, camera, size, asset and renderer."""
    cams = write_cameras(tmp_path / "cams.json", 1)
    sway = write_motion(tmp_path / "sway.npz", asset_dir, 3)
    cage = load_cage(load_asset(asset_dir).cage_path)
    still = tmp_path / "still.npz"  # the cage at rest in every frame
    save_motion(still, Motion(cage.vertices, cage.tets, np.stack([cage.vertices] * 3), np.arange(3) / 10.0))
    out, video = tmp_path / "frames", tmp_path / "clip.mp4"

    def images():
        return [np.asarray(Image.open(out / f"{k:05d}.png")) for k in range(3)]

    assert render(asset_dir, out, "--width", "16", "--height", "12", motion=still, cameras=cams) == 0
    rest = images()
    capsys.readouterr()
    assert (
        render(asset_dir, out, "--width", "16", "--height", "12", "--video", video, motion=sway, cameras=cams)
        == 0
    )
    # frame 0 of the sway is the rest pose: kept; the others are rendered again
    assert "2 frames rendered" in capsys.readouterr().out
    swayed = images()
    np.testing.assert_array_equal(swayed[0], rest[0])
    assert all((np.abs(swayed[k].astype(int) - rest[k]) > 10).any() for k in (1, 2))
    import imageio.v2 as imageio

    with imageio.get_reader(video) as reader:  # the video shows the new frames
        last = np.asarray([f for f in reader][-1]).astype(int)
    assert np.abs(last - swayed[2]).mean() < np.abs(last - rest[2]).mean()

    assert render(asset_dir, out, "--width", "20", "--height", "14", motion=sway, cameras=cams) == 0
    assert "3 replaced" in capsys.readouterr().out
    assert all(image.shape == (14, 20, 3) for image in images())
    stamps = [p.stat().st_mtime_ns for p in sorted(out.iterdir())]
    assert render(asset_dir, out, "--width", "20", "--height", "14", motion=sway, cameras=cams) == 0
    assert "0 frames rendered to" in capsys.readouterr().out
    assert [p.stat().st_mtime_ns for p in sorted(out.iterdir())] == stamps


@pytest.mark.parametrize(
    "options", [("--frames", "x:y"), ("--frames", "3:9"), ("--fps", "0"), ("--device", "tpu")]
)
def test_bad_options_fail_before_the_asset_loads(tmp_path, asset_dir, capsys, monkeypatch, options):
    def no_loading(*args, **kwargs):
        raise AssertionError("the asset was loaded before the options were checked")

    monkeypatch.setattr("neural.asset.load_asset", no_loading)
    monkeypatch.setattr("neural.asset.load_field", no_loading)
    motion = write_motion(tmp_path / "m.npz", asset_dir, 3)
    assert render(asset_dir, tmp_path / "o", "--camera", "orbit", *options, motion=motion) == 2
    assert options[0] in error_line(capsys)


def test_wind_example_run_again_at_another_size_renders_again(tmp_path, asset_dir, capsys):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).parents[1] / "examples" / "wind_animation.py"
    spec = importlib.util.spec_from_file_location("wind_animation", path)
    example_module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example_module)
    out = tmp_path / "wind"
    argv = ["--asset", str(asset_dir), "--out", str(out), "--frames", "3", "--fps", "10", "--device", "cpu"]

    def example(*extra):
        return example_module.main([*argv, *extra])

    assert example("--strength", "0.1", "--size", "16x16").rendered == 3
    again = example("--strength", "0.1", "--size", "20x16")  # same wind: the motion file is kept
    assert again.rendered == 3 and again.replaced == 3
    assert all(Image.open(p).size == (20, 16) for p in (out / "frames").iterdir())
    import imageio.v2 as imageio

    with imageio.get_reader(out / "wind.mp4") as reader:
        assert all(frame.shape[:2] == (16, 20) for frame in reader)
    assert example("--strength", "0.1", "--size", "20x16").skipped == 3
    with pytest.raises(
        SystemExit, match=r"wind_animation: error: .*made with other settings \(--strength: 0.1 -> 0.2"
    ):
        example("--strength", "0.2", "--size", "20x16")
    # another wind with --overwrite: the motion is recomputed, and the orbit that frames it moves
    from shellsim.motion.read import load_motion

    assert example("--strength", "0.2", "--size", "20x16", "--overwrite").rendered == 3
    assert load_motion(out / "wind.npz").settings["strength"] == 0.2
