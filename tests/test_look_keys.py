"""The colours a scene file gives its bodies and colliders (``color``), seen in the frames of ``scene
--video`` at the size and rays per pixel asked for: a lit face is its colour times Lambert's shade; an asset
body's tint multiplies what its field shows; a colour changed later films anew without simulating again."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from meshes import save_collision_surface
from PIL import Image
from scenes import SphereField
from test_ground import stepped_sampler
from test_render_deformed import CENTER, make_asset

from neural.data import camera_rays
from neural.render.bodies import FieldBody
from neural.render.view import render_bodies
from shellsim.cli.main import main
from shellsim.film.cameras import scene_shot
from shellsim.film.renderer import TintedField
from shellsim.film.shot_frames import scene_camera, scene_tracks
from shellsim.shot.recorded import read_scene_motion
from shellsim.world import WorldLook

BOX = 0.1  # [m] side of the body's cube and of the collider
TOP = BOX  # [m] both tops, the body standing on z = 0 and the collider centred at BOX / 2


def test_a_tint_multiplies_what_the_field_shows_over_black():
    """Composited over black, every pixel is the sum of the samples' weights times their colours: tinting
    the colours tints the pixel by the same factors, wherever the sphere is translucent or opaque."""
    field = SphereField(radius=0.3, inv_s=40.0)
    tint = (0.2, 0.9, 0.5)
    angles = torch.linspace(-0.5, 0.5, 64, dtype=torch.float32)
    origins = torch.tensor([[0.0, -1.5, 0.0]]).expand(len(angles), 3)
    dirs = torch.stack([torch.sin(angles), torch.cos(angles), 0.3 * angles], 1)
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    black = torch.zeros(3)

    def image(f):
        return render_bodies([FieldBody(f, stepped_sampler(2e-3, 3.0))], origins, dirs, black)[0].numpy()

    plain, tinted = image(field), image(TintedField(field, tint))
    assert plain.max() > 0.3
    np.testing.assert_allclose(tinted, plain * np.asarray(tint), atol=1e-6)


@pytest.mark.slow
def test_a_mesh_body_and_a_collider_show_their_own_colours_in_scene_video(tmp_path):
    """A cube body (``color``) beside a box collider (``color``, over the look's ``collider_color``), filmed
    by ``scene --video --width 40 --height 30 --antialias 1``: every pixel that sees a cube's top is that
    colour times ``ambient + diffuse l_z`` (its normal +z, both tops at one height: nothing shadows them)."""
    pytest.importorskip("ipctk")
    cube = trimesh.creation.box((BOX, BOX, BOX))
    vertices, faces = trimesh.remesh.subdivide_to_size(cube.vertices, cube.faces, 0.03)
    trimesh.Trimesh(vertices, faces).export(tmp_path / "cube.ply")
    body, collider = (0.9, 0.3, 0.1), (0.1, 0.5, 0.8)
    scene = tmp_path / "colours.toml"
    scene.write_text(
        f"""
[world]
frames = 1
gravity = 0
ground = false

[[body]]
name = "cube"
mesh = "cube.ply"
position = [-0.1, 0, 0]
color = {list(body)}

[[collider]]
name = "crate"
shape = "box"
position = [0.1, 0, {BOX / 2}]
half_extents = [{BOX / 2}, {BOX / 2}, {BOX / 2}]
color = {list(collider)}

[[camera]]
name = "above"
kind = "fixed"
position = [0, -0.3, 0.9]
target = [0, 0, 0.05]

[look]
collider_color = [1, 1, 0]
"""
    )
    out = tmp_path / "colours"
    args = ["scene", str(scene), "--out", str(out), "--video", str(tmp_path / "c.mp4")]
    assert main([*args, "--width", "40", "--height", "30", "--antialias", "1"]) == 0
    image = np.asarray(Image.open(out / "frames" / "00000.png"), np.float64)[..., :3] / 255
    assert image.shape == (30, 40, 3)
    recorded = read_scene_motion(out, load_assets=False)
    view = scene_shot(scene_camera(recorded, "above"), scene_tracks(recorded), 40, 30).camera_for_frame(0)
    origins, dirs = (x.double().numpy() for x in camera_rays(view, 0))
    top = origins + ((TOP - origins[:, 2]) / dirs[:, 2])[:, None] * dirs  # where each ray meets z = TOP
    look = WorldLook()
    shade = look.ambient + look.diffuse * look.light_unit()[2]
    for centre, color in ((-0.1, body), (0.1, collider)):
        seen = (np.abs(top[:, 0] - centre) < 0.4 * BOX) & (np.abs(top[:, 1]) < 0.4 * BOX)
        assert seen.sum() >= 6
        np.testing.assert_allclose(
            image.reshape(-1, 3)[seen], np.tile(np.multiply(color, shade), (seen.sum(), 1)), atol=2 / 255
        )


def test_an_asset_bodys_tint_multiplies_its_frames_and_changes_no_motion(tmp_path):
    """The test asset over a black sky without ground: filmed again with ``color = [0.5, 1, 0.25]`` (the
    file changed, the motion kept), each pixel is the untinted one times the tint (within PNG rounding)."""
    pytest.importorskip("ipctk")
    from neural.asset import load_asset
    from shellsim.tetcage.store import load_or_build_cage

    root = make_asset(tmp_path / "orb")
    asset = load_asset(root)
    sphere = trimesh.creation.icosphere(2, radius=0.25).apply_translation(CENTER)
    save_collision_surface(asset, load_or_build_cage(asset), sphere)
    text = f"""
[world]
frames = 1
gravity = 0
ground = false

[[body]]
name = "orb"
asset = "{root}"
size = 0.3
position = [0, 0, 0.2]
{{color}}

[look]
sky = [0, 0, 0]
"""
    scene, out = tmp_path / "tint.toml", tmp_path / "tint"

    def film(color: str):
        scene.write_text(text.replace("{color}", color))
        args = ["scene", str(scene), "--out", str(out), "--video", str(tmp_path / "t.mp4"), "--width", "24"]
        assert main([*args, "--antialias", "1"]) == 0
        return np.asarray(Image.open(out / "frames" / "00000.png"), np.float64)[..., :3] / 255

    plain = film("")
    made = (out / "motion.npz").stat().st_mtime_ns
    tint = np.array([0.5, 1.0, 0.25])
    tinted = film(f"color = {tint.tolist()}")
    assert (out / "motion.npz").stat().st_mtime_ns == made  # a colour does not change the motion
    assert plain.max() > 0.3
    np.testing.assert_allclose(tinted, plain * tint, atol=1 / 255)
