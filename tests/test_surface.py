"""shellsim.viz.surface: a motion's surface drawn with pyvista, against the pinhole model, and the inspector
and ``render``-style frames of a mesh motion (no neural asset)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid
from PIL import Image

from neural.data import Cameras, look_at
from shellsim.cli.main import main  # noqa: E402
from shellsim.motion.format import Motion, Surface, save_motion
from shellsim.tetcage.embed import embed_points
from shellsim.viz.surface import SurfaceRenderer, render_surface_motion  # noqa: E402

SIZE = 64
FOV_DEG = 30.0
HALF = 0.25  # the cube [-HALF, HALF]^3
DISTANCE = 4.0  # camera at (0, -DISTANCE, 0) looking at the origin, z up


def cube_motion(shifts) -> Motion:
    """A cube's surface in a one-cell Kuhn cage, translated by ``shifts`` (F, 3), one frame each."""
    verts, tets, _ = kuhn_grid(-HALF, HALF, 1)
    box = trimesh.creation.box((2 * HALF,) * 3)
    tet, bary = embed_points(verts, tets, np.asarray(box.vertices, np.float64))
    positions = np.stack([verts + np.asarray(s, float) for s in shifts])
    times = np.arange(len(shifts)) / 10.0
    return Motion(verts, tets, positions, times, {"fps": 10.0}, Surface(tet, bary, np.asarray(box.faces)))


def front_camera() -> Cameras:
    focal = 0.5 * SIZE / math.tan(math.radians(FOV_DEG) / 2)
    c2w = look_at(np.array([0.0, -DISTANCE, 0.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    return Cameras(
        c2w[None], [focal], [focal], [SIZE / 2], [SIZE / 2], [SIZE], [SIZE], np.zeros((1, 4)), ["front"]
    )


def object_box(image: np.ndarray) -> tuple[int, int, int, int]:
    """(first row, last row, first column, last column) of the pixels that are not white background."""
    rows, cols = np.nonzero(image.min(axis=2) < 0.9)
    return rows.min(), rows.max(), cols.min(), cols.max()


def test_frames_follow_the_motion_like_a_pinhole_camera():
    """The cube's silhouette seen head-on is its front face at depth DISTANCE - HALF: it spans
    f * 2 HALF / depth pixels and a sideways shift s moves it by f * s / depth pixels."""
    shift = 0.3
    motion = cube_motion([(0, 0, 0), (shift, 0, 0), (0, 0, shift)])
    camera = front_camera()
    renderer = SurfaceRenderer(motion, SIZE, SIZE)
    try:
        boxes = [np.array(object_box(renderer.render(camera, 0, k)[0])) for k in range(3)]
    finally:
        renderer.close()
    f, depth = float(camera.fx[0]), DISTANCE - HALF
    width = f * 2 * HALF / depth  # 15.9 pixels
    top, bottom, left, right = boxes[0]
    assert right - left + 1 == pytest.approx(width, abs=1.5)
    assert bottom - top + 1 == pytest.approx(width, abs=1.5)
    assert (left + right) / 2 == pytest.approx(SIZE / 2 - 0.5, abs=1.0)  # centred
    moved = f * shift / depth  # 9.55 pixels
    np.testing.assert_allclose(boxes[1] - boxes[0], [0, 0, moved, moved], atol=1.0)  # +x: to the right
    np.testing.assert_allclose(boxes[2] - boxes[0], [-moved, -moved, 0, 0], atol=1.0)  # +z: up


def test_mesh_motion_frames_and_video(tmp_path):
    motion = cube_motion([(0, 0, 0), (0.2, 0, 0), (0.4, 0, 0)])
    path = tmp_path / "cube.npz"
    save_motion(path, motion)
    out, video = tmp_path / "frames", tmp_path / "cube.mp4"
    summary = render_surface_motion(path, out, size=(32, 24), video=video, progress=False)
    assert summary.rendered == 3 and summary.video == video
    images = [np.asarray(Image.open(out / f"{k:05d}.png")) for k in range(3)]
    assert all(image.shape == (24, 32, 3) and image.min() < 200 for image in images)
    assert not np.array_equal(images[0], images[2])
    import imageio.v2 as imageio

    with imageio.get_reader(video) as reader:
        assert sum(1 for _ in reader) == 3
    assert render_surface_motion(path, out, size=(32, 24), progress=False).skipped == 3  # same: kept
    again = render_surface_motion(path, out, size=(40, 30), progress=False)
    assert again.rendered == 3 and again.replaced == 3


def test_inspect_shows_a_mesh_motion_without_an_asset(tmp_path, capsys):
    path = tmp_path / "cube.npz"
    save_motion(path, cube_motion([(0, 0, 0), (0.5, 0, 0)]))
    shots = []
    for frame in ("0", "-1"):
        shot = tmp_path / f"frame{frame}.png"
        assert main(["inspect", "--motion", str(path), "--frame", frame, "--screenshot", str(shot)]) == 0
        shots.append(np.asarray(Image.open(shot).convert("RGB")).astype(int))
    assert shots[0].shape == (768, 1024, 3)
    assert (shots[0].min(axis=2) < 200).sum() > 1000  # the cube is drawn
    assert np.abs(shots[0] - shots[1]).max(axis=2).astype(bool).sum() > 1000  # and moves
    assert main(["inspect", "--motion", str(path), "--color", "kernel", "--screenshot", "x.png"]) == 2
    assert "--color" in capsys.readouterr().err


def test_render_cli_draws_a_motion_without_an_asset(tmp_path, capsys):
    path = tmp_path / "cube.npz"
    save_motion(path, cube_motion([(0, 0, 0), (0.3, 0, 0)]))
    out = tmp_path / "frames"
    argv = [
        "render",
        "--motion",
        str(path),
        "--camera",
        "orbit",
        "--out",
        str(out),
        "--width",
        "24",
        "--height",
        "20",
    ]
    assert main(argv) == 0
    assert "2 frames rendered" in capsys.readouterr().out
    assert [Image.open(p).size for p in sorted(out.iterdir())] == [(24, 20)] * 2
    assert main(["render", "--motion", str(path), "--cameras", "c.json", "--out", str(out)]) == 2
    assert "--asset" in capsys.readouterr().err


def test_a_torn_surface_is_one_clear_error(tmp_path):
    from neural.errors import InputError
    from shellsim.motion.read import load_motion

    m = cube_motion([(0, 0, 0)])
    path = tmp_path / "m.npz"
    arrays = {  # a format-1 file: one npz
        "rest_vertices": m.rest_vertices,
        "tets": m.tets,
        "positions": m.positions,
        "times": m.times,
        "meta": np.array("{}"),
        "surface_tet": m.surface.tet,
        "surface_bary": m.surface.bary,
        "surface_faces": m.surface.faces,
    }
    np.savez(path, **{k: v for k, v in arrays.items() if k != "surface_bary"})
    with pytest.raises(InputError, match="surface_tet, surface_faces but not all"):
        load_motion(path)
    arrays["surface_faces"] = arrays["surface_faces"] + 100  # indices past the 8 surface points
    np.savez(path, **arrays)
    with pytest.raises(InputError, match="surface_faces index its 8 points"):
        load_motion(path)
