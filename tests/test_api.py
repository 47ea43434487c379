"""The public API (``import shellsim``): every name resolves lazily (that it loads no torch is checked by
tests/test_imports.py), the jobs return the dataclasses their docstrings describe, a job run from Python
writes the files the command line writes, and the README's "From Python" example runs as printed."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import numpy as np
import pytest
import trimesh
from meshes import write_asset_dir
from PIL import Image
from scenes import write_sphere_scene
from test_render_cli import write_cameras, write_motion
from test_render_deformed import make_asset

import shellsim
from shellsim.cli.main import main

ROOT = Path(__file__).resolve().parents[1]

#: Each job function of the API -> the result it is annotated to return.
JOBS = {
    "train": "TrainResult",
    "extract": "ExtractResult",
    "poses": "PosesResult",
    "cage": "CageResult",
    "simulate": "SimulateResult",
    "wind": "WindResult",
    "render": "RenderResult",
    "render_views": "RenderResult",
    "render_motion": "RenderResult",
    "evaluate": "EvalResult",
    "export": "ExportResult",
    "sweep": "SweepResult",
}


def test_every_public_name_resolves_and_the_docstring_lists_it():
    assert len(set(shellsim.__all__)) == len(shellsim.__all__)
    for name in shellsim.__all__:
        assert getattr(shellsim, name) is not None, name
        assert re.search(rf"\b{name}\b", shellsim.__doc__), f"the module docstring does not list {name}"
        # a sub-package of that name would replace the function once it is imported
        assert importlib.util.find_spec(f"shellsim.{name}") is None, name
    assert set(shellsim.__all__) <= set(dir(shellsim))
    with pytest.raises(AttributeError, match="no attribute 'simulation'"):
        shellsim.simulation  # noqa: B018


def test_jobs_return_dataclasses_whose_docstrings_describe_every_field():
    for job, result_name in JOBS.items():
        result = getattr(shellsim, result_name)
        assert typing.get_type_hints(getattr(shellsim, job))["return"] is result, job
    for name in [*set(JOBS.values()), "ViewMetrics"]:
        result = getattr(shellsim, name)
        assert dataclasses.is_dataclass(result), name
        for field in dataclasses.fields(result):
            assert re.search(rf"\b{field.name}\b", result.__doc__), f"{name}.{field.name} is not documented"


@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ("TrainSettings", "data"),
        ("ExtractSettings", "asset"),
        ("PosesSettings", "images"),
        ("CageSettings", "asset"),
        ("EvalSettings", "asset"),
        ("RenderSettings", "out"),
        ("ExportSettings", "motion"),
        ("SweepSettings", "asset"),
    ],
)
def test_required_settings_are_required_from_python_too(settings, field):
    """The command line's required options; from Python the settings name the field that is missing."""
    with pytest.raises(shellsim.SettingError, match=rf"^{field}: needed$"):
        getattr(shellsim, settings)()


def test_render_settings_take_a_camera_file_or_a_camera():
    with pytest.raises(shellsim.SettingError, match="^cameras: needed to render at rest"):
        shellsim.RenderSettings(asset="a", out="o")
    with pytest.raises(shellsim.SettingError, match="^cameras: give one of cameras and camera"):
        shellsim.RenderSettings(asset="a", motion="m.npz", cameras="c.json", camera="top", out="o")
    with pytest.raises(shellsim.SettingError, match="^camera_position: needed by the fixed camera"):
        shellsim.RenderSettings(asset="a", motion="m.npz", camera="fixed", out="o")
    with pytest.raises(shellsim.SettingError, match="^orbit_degrees: sets an orbit's arc"):
        shellsim.RenderSettings(asset="a", motion="m.npz", camera="follow", orbit_degrees=90, out="o")


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """(asset directory, camera file of 3 views, motion of 3 frames) of the small test asset."""
    root = tmp_path_factory.mktemp("api")
    asset = make_asset(root / "ball")
    return asset, write_cameras(root / "cams.json", 3), write_motion(root / "sway.npz", asset, 3)


def _same_files(a: Path, b: Path) -> list[str]:
    """The names of the files of directory ``a``, asserting that ``b`` holds the same bytes under them."""
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    return names


def test_render_from_python_writes_the_cli_frames(ball, tmp_path):
    asset, cameras, motion = ball
    out = tmp_path / "py"
    settings = shellsim.RenderSettings(asset=str(asset), cameras=str(cameras), out=str(out), width=20)
    result = shellsim.render(settings)
    argv = ["render", "--asset", str(asset), "--cameras", str(cameras), "--width", "20"]
    assert main([*argv, "--out", str(tmp_path / "cli")]) == 0
    assert _same_files(out, tmp_path / "cli") == ["v_0.png", "v_1.png", "v_2.png"]
    assert result.out == out and result.frames == tuple(sorted(out.iterdir()))
    assert (result.rendered, result.skipped, result.replaced, result.video) == (3, 0, 0, None)
    assert result.ms > 0 and result.samples_per_pixel > 0
    assert set(result.stage_ms) == {"build", "sample", "map", "shade", "world", "static", "shadow"}
    again = shellsim.render(settings)
    assert (again.rendered, again.skipped, again.replaced) == (0, 3, 0)
    assert (again.ms, again.samples_per_pixel, again.stage_ms) == (None, None, {})

    out, video = tmp_path / "py_motion", tmp_path / "py.mp4"
    moved = shellsim.render_motion(asset, motion, out, size=(16, 16), video=video)
    argv = ["render", "--asset", str(asset), "--motion", str(motion), "--camera", "orbit", "--width", "16"]
    assert main([*argv, "--out", str(tmp_path / "cli_motion")]) == 0
    assert _same_files(out, tmp_path / "cli_motion") == ["00000.png", "00001.png", "00002.png"]
    assert moved.rendered == 3 and moved.video == video and video.stat().st_size > 0
    assert [np.asarray(Image.open(p)).shape for p in moved.frames] == [(16, 16, 3)] * 3


def test_the_cage_job_describes_the_cage_the_cli_prints(ball, capsys):
    asset, _, _ = ball
    result = shellsim.cage(shellsim.CageSettings(asset=str(asset)))
    assert result.path == asset / "cage.npz" and result.name == "ball"
    cage = shellsim.load_or_build_cage(shellsim.load_asset(asset))
    assert (result.vertices, result.tets) == (len(cage.vertices), len(cage.tets))
    assert result.outside == 0 and result.outer_vertices == len(cage.outer_tet)
    assert main(["cage", "--asset", str(asset)]) == 0
    printed = capsys.readouterr().out
    assert f"{result.vertices} vertices, {result.tets} tets, volume {result.volume:.6g}" in printed


@pytest.mark.parametrize(("format", "out"), [("ply", "shell"), ("vtu", "cage.pvd")])
def test_export_from_python_writes_the_cli_files(ball, tmp_path, format, out):
    asset, _, motion = ball
    py, cli = tmp_path / "py", tmp_path / "cli"
    py.mkdir()
    cli.mkdir()
    settings = shellsim.ExportSettings(motion=str(motion), out=str(py / out), format=format, asset=str(asset))
    result = shellsim.export(settings, progress=False)
    argv = ["export", "--motion", str(motion), "--asset", str(asset), "--format", format]
    assert main([*argv, "--out", str(cli / out)]) == 0
    files = sorted(p.relative_to(py) for p in py.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(cli) for p in cli.rglob("*") if p.is_file()) and files
    for name in files:
        assert (py / name).read_bytes() == (cli / name).read_bytes(), name
    assert (result.out, result.format, result.frames) == (py / out, format, 3)
    assert sorted(p.relative_to(py) for p in result.files) == files
    if format == "vtu":
        assert result.files[-1] == py / out  # the index last


def test_wind_from_python_moves_the_cage_as_the_cli_does(ball, tmp_path):
    asset, _, _ = ball
    result = shellsim.wind(shellsim.WindSettings(asset=str(asset), frames=3, out=str(tmp_path / "py.npz")))
    assert main(["wind", "--asset", str(asset), "--frames", "3", "--out", str(tmp_path / "cli.npz")]) == 0
    py, cli = shellsim.load_motion(result.out), shellsim.load_motion(tmp_path / "cli.npz")
    assert result.frames == py.n_frames == 3
    assert np.array_equal(py.positions, cli.positions) and py.settings == cli.settings


def test_evaluate_from_python_measures_what_the_cli_writes(ball, tmp_path):
    asset, _, _ = ball
    data = write_sphere_scene(tmp_path / "data", n_views=8, size=16)
    result = shellsim.evaluate(
        shellsim.EvalSettings(asset=str(asset), data=str(data), views=1, full_ray=False, device="cpu")
    )
    argv = ["eval", "--asset", str(asset), "--data", str(data), "--views", "1", "--no-full-ray"]
    assert main([*argv, "--device", "cpu", "--json", str(tmp_path / "eval.json")]) == 0
    written = json.loads((tmp_path / "eval.json").read_text())
    assert set(written) == set(result.as_dict()) and "full_ray" not in written
    assert result.full_ray is None and result.speedup is None and result.heldout_views == [0]
    nb = result.narrow_band
    assert isinstance(nb, shellsim.ViewMetrics) and nb.views == [0]
    for key in ("psnr", "ssim", "samples_per_pixel"):
        assert written["narrow_band"][key] == getattr(nb, key), key


def test_extract_from_python_writes_the_cli_shells(ball, tmp_path):
    import shutil

    asset, _, _ = ball
    py, cli = (shutil.copytree(asset, tmp_path / name) for name in ("py", "cli"))
    result = shellsim.extract(shellsim.ExtractSettings(asset=str(py), resolution=32, device="cpu"))
    assert main(["extract", "--asset", str(cli), "--resolution", "32", "--device", "cpu"]) == 0
    for name in ("shell_outer.ply", "shell_inner.ply"):
        assert (py / name).read_bytes() == (cli / name).read_bytes(), name
    assert result.asset == py and result.seconds > 0
    outer = shellsim.load_asset(py).outer_mesh()
    assert result.outer_faces == len(outer.faces) and result.width_max >= result.width_mean > 0


@pytest.mark.slow
def test_poses_returns_what_its_transforms_file_lists(tmp_path):
    from test_poses import ring_cameras, write_images

    images, out = tmp_path / "images", tmp_path / "out"
    write_images(images, ring_cameras())
    (images / "broken.jpg").write_bytes(b"\xff\xd8\xff not really a jpeg")
    result = shellsim.poses(shellsim.PosesSettings(images=str(images), out=str(out)))
    written = json.loads((out / "transforms.json").read_text())
    assert result.transforms == out / "transforms.json"
    assert (result.posed, result.photos) == (len(written["frames"]), 25) and result.posed >= 20
    assert result.unregistered == [u["file_path"] for u in written["unregistered"]]
    assert "../images/broken.jpg" in result.unregistered


def test_train_returns_the_figures_its_asset_records(tmp_path, monkeypatch):
    """The result of training is read from the asset.json it writes (training itself, and what it records:
    tests/test_pipeline.py); here a stand-in for the pipeline writes that file."""
    import neural.pipeline

    figures = {"psnr": 25.0, "ssim": 0.9, "samples_per_pixel": 2.0, "ms_per_frame": 9.0, "views": [0, 8]}

    def pipeline(data, out, config, device, name=None, keep_checkpoints=False, init=None):
        sphere = trimesh.creation.icosphere(subdivisions=1)
        root = write_asset_dir(out, sphere, sphere, name or "fake")
        meta = json.loads((root / "asset.json").read_text())
        stage1 = {**figures, "psnr": 24.0, "step": 10, "train_seconds": 5.0}
        meta["metrics"] = {"stage1_full_ray": stage1, "stage2_narrow_band": {**figures, "step": 2}}
        meta["training"] = {"wall_minutes": 1.5}
        (root / "asset.json").write_text(json.dumps(meta))
        return root

    monkeypatch.setattr(neural.pipeline, "train_asset", pipeline)
    out = tmp_path / "asset"
    result = shellsim.train(shellsim.TrainSettings(data=str(tmp_path / "data"), out=str(out), device="cpu"))
    stage2 = shellsim.ViewMetrics(**figures)
    assert result == shellsim.TrainResult(out, dataclasses.replace(stage2, psnr=24.0), stage2, 1.5)


def _readme_example() -> str:
    """The fenced python block under the README's heading "From Python"."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## From Python\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"^```python\n(.*?)^```$", section, flags=re.S | re.M)
    assert len(blocks) == 1, "the section holds one python block"
    return blocks[0]


@pytest.mark.slow
def test_the_readme_example_runs(tmp_path):
    """The shipped LEGO simulated for 4 frames and 2 of them rendered at 64x64: about 4 s with Warp's kernels
    compiled, 12 s without."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    done = subprocess.run(
        [sys.executable, "-c", _readme_example()],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    printed = done.stdout.splitlines()  # with Warp's lines on loading its kernels
    assert any(line.startswith("drop.npz: 4 frames of ") for line in printed), done.stdout
    assert printed[-1].startswith("2 frames of (64, 64, 3) in frames, "), done.stdout
    assert shellsim.load_motion(tmp_path / "drop.npz").n_frames == 4
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["00002.png", "00003.png"]
