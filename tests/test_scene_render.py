"""Several bodies in one image (neural.render.bodies, view.render_bodies,
shellsim.film.renderer.SceneRenderer).

Truths from outside the code: a per-ray composite of two analytic spheres marched by brute force (NeuS
opacities ``max((Phi(s f_k) - Phi(s f_k+1)) / Phi(s f_k), 0)`` of each sphere's exact SDF over 20,000 steps,
both spheres' steps merged by depth), the invariance of an image under a change of a body's frame, and the
invariance of a rigidly moved scene seen by a camera carried with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scenes import RecordingSphereField, SphereField
from test_ground import stepped_sampler
from test_render_deformed import CENTER, camera, make_asset, rotation

from neural.data import camera_rays
from neural.metrics import psnr
from neural.render.bodies import FieldBody
from neural.render.view import SHADOW_CUTOFF, bodies_transmittance, render_bodies
from shellsim.world import Placement

FAR = 3.0
STEP = 2e-3
BACKGROUND = torch.tensor([1.0, 1.0, 1.0])


class PaintedSphere(SphereField):
    """A :class:`SphereField` of one constant colour."""

    def __init__(self, color, **kwargs):
        super().__init__(**kwargs)
        self.color = torch.tensor(color, dtype=torch.float32)

    def radiance(self, x, d, geo):
        return self.color.expand(len(x), 3)


# Two world spheres, (centre, radius, colour): the red one nearer the camera, overlapping the blue one.
RED = (np.array([0.0, -0.15, 0.0]), 0.25, (0.9, 0.1, 0.1))
BLUE = (np.array([0.1, 0.25, 0.05]), 0.3, (0.1, 0.2, 0.9))
EYE = np.array([0.0, -1.6, 0.2])
INV_S = 60.0  # world units^-1
FRAMES = (
    Placement(0.5, rotation((1.0, 2.0, 3.0), 0.7), np.array([0.05, -0.1, 0.02])),
    Placement(2.0, rotation((0.0, 1.0, -1.0), -1.1), np.array([-0.2, 0.3, 0.1])),
)


def body_of(sphere, frame: Placement, field_class=PaintedSphere, box: bool = False) -> FieldBody:
    """The world sphere ``(centre, radius, colour)`` as a field of ``frame`` (inverse-placed), marched in
    fixed steps of its frame's ray parameter; ``box``: its world box (else every ray is cast)."""
    centre, radius, color = sphere
    local = (frame.rotation.T @ (centre - frame.translation)) / frame.scale
    kwargs = dict(radius=radius / frame.scale, inv_s=INV_S * frame.scale, center=tuple(local.tolist()))
    field = field_class(color, **kwargs) if field_class is PaintedSphere else field_class(**kwargs)
    reach = radius + 12.0 / INV_S  # where the field's opacity is below 1e-5
    corners = np.stack([centre - reach, centre + reach]) if box else None
    return FieldBody(field, stepped_sampler(STEP, FAR), None, frame, corners)


def reference_composite(origins: np.ndarray, dirs: np.ndarray, spheres, steps: int = 20000) -> np.ndarray:
    """(R, 3) colours by brute force: every ray marched over t in [0, FAR] (unit directions), each sphere's
    NeuS opacity per step from its exact world SDF, all spheres' steps composited front to back by depth."""
    t = np.linspace(0.0, FAR, steps + 1)
    points = origins[:, None] + t[None, :, None] * dirs[:, None]  # (R, N+1, 3)
    alphas, colors = [], []
    for centre, radius, color in spheres:
        phi = 1.0 / (1.0 + np.exp(-INV_S * (np.linalg.norm(points - centre, axis=2) - radius)))
        alphas.append(np.clip((phi[:, :-1] - phi[:, 1:]) / np.maximum(phi[:, :-1], 1e-30), 0.0, 1.0))
        colors.append(np.asarray(color))
    # at one depth both spheres' opacities combine: 1 - (1 - a1)(1 - a2), colour weighted by each
    keep = np.prod([1.0 - a for a in alphas], axis=0)  # (R, N)
    total = 1.0 - keep
    mix = sum(a[..., None] * c for a, c in zip(alphas, colors, strict=True))
    mix = mix / np.maximum(sum(alphas), 1e-30)[..., None]
    transmit = np.concatenate([np.ones((len(origins), 1)), np.cumprod(keep, axis=1)[:, :-1]], axis=1)
    weights = transmit * total
    return (weights[..., None] * mix).sum(1) + transmit[:, -1:] * keep[:, -1:] * 1.0


@pytest.mark.slow
def test_overlapping_spheres_match_the_reference_composite():
    """Two bodies in frames of their own, overlapping on screen: every pixel matches the brute-force
    composite, and where they overlap the nearer (red) one is seen."""
    view = camera(EYE, target=np.array([0.05, 0.0, 0.02]), size=24, fov_deg=45.0)
    origins, dirs = camera_rays(view, 0)
    bodies = [body_of(RED, FRAMES[0]), body_of(BLUE, FRAMES[1])]
    colors, _ = render_bodies(bodies, origins, dirs, BACKGROUND)
    expected = reference_composite(origins.double().numpy(), dirs.double().numpy(), [RED, BLUE])
    assert np.abs(colors.numpy() - expected).max() < 0.02
    # the pixel through both centres' midpoint, inside both spheres' silhouettes: red
    both = np.nonzero(
        (np.abs(expected - np.asarray(RED[2])).max(1) < 0.05)
        & _crosses(origins, dirs, BLUE[0], BLUE[1])
        & _crosses(origins, dirs, RED[0], RED[1])
    )[0]
    assert len(both) > 5
    assert np.abs(colors.numpy()[both] - np.asarray(RED[2])).max() < 0.05  # the soft edge lets 5% through


def _crosses(origins, dirs, centre, radius) -> np.ndarray:
    """(R,) bool: the rays pass within ``0.9 radius`` of ``centre`` (well inside the silhouette)."""
    o, d = origins.double().numpy(), dirs.double().numpy()
    closest = o + np.einsum("ij,ij->i", centre - o, d)[:, None] * d
    return np.linalg.norm(closest - centre, axis=1) < 0.9 * radius


def test_the_image_does_not_depend_on_the_bodies_frames():
    """The same world spheres as fields of other frames (one the world's own) give the same image."""
    view = camera(EYE, target=np.array([0.05, 0.0, 0.02]), size=16, fov_deg=45.0)
    rays = camera_rays(view, 0)
    a, _ = render_bodies([body_of(RED, FRAMES[0]), body_of(BLUE, FRAMES[1])], *rays, BACKGROUND)
    b, _ = render_bodies([body_of(RED, Placement()), body_of(BLUE, FRAMES[0])], *rays, BACKGROUND)
    assert torch.allclose(a, b, atol=2e-3)


def test_a_ray_costs_only_the_bodies_whose_box_it_crosses():
    """With boxes, a body's field is evaluated only on the rays that cross its box (here 160 of 256),
    and the image is the one without boxes."""
    from neural.render.fullray import ray_aabb

    view = camera(EYE, target=np.array([0.6, 0.0, 0.02]), size=16, fov_deg=30.0)
    rays = camera_rays(view, 0)
    loose = [body_of(RED, FRAMES[0], RecordingSphereField), body_of(BLUE, FRAMES[1], RecordingSphereField)]
    boxed = [
        body_of(RED, FRAMES[0], RecordingSphereField, True),
        body_of(BLUE, FRAMES[1], RecordingSphereField, True),
    ]
    a, _ = render_bodies(loose, *rays, BACKGROUND)
    b, _ = render_bodies(boxed, *rays, BACKGROUND)
    assert torch.allclose(a, b, atol=1e-6)
    lo, hi = (torch.tensor(c, dtype=torch.float32) for c in boxed[0].box)
    near, far = ray_aabb(*rays, lo, hi)
    crossing = int((far > near).sum())
    assert 0 < crossing < len(rays[0])
    assert sum(boxed[0].field.geometry_calls) < 0.8 * sum(loose[0].field.geometry_calls)


def test_shadow_rays_multiply_the_bodies_transmittance():
    """A ray through both spheres lets through the product of what each lets through alone (every sample
    taken: ``cutoff`` 0); stopped once below the cutoff, it stays below it."""
    origins = torch.tensor([[0.0, -1.0, 0.02], [0.5, -1.0, 0.9]], dtype=torch.float32)
    dirs = torch.nn.functional.normalize(torch.tensor([[0.1, 2.0, 0.0], [0.0, 1.0, 0.0]]), dim=1)
    red, blue = body_of(RED, FRAMES[0]), body_of(BLUE, FRAMES[1])
    both = bodies_transmittance([red, blue], origins, dirs, cutoff=0)
    alone = [bodies_transmittance([b], origins, dirs, cutoff=0) for b in (red, blue)]
    assert torch.allclose(both, alone[0] * alone[1], atol=1e-6)
    assert both[0] < 1e-3 and both[1] > 0.999  # through both spheres; above them
    stopped = bodies_transmittance([red, blue], origins, dirs)
    assert stopped[0] < SHADOW_CUTOFF and stopped[1] == both[1]


def test_a_shadow_ray_stops_only_in_the_dark():
    """Shadow rays through a sphere from its rim to its centre: a ray whose light never falls below the
    cutoff is what taking every sample gives; one that does stops there, within the cutoff of it, and its
    later samples are never evaluated."""
    heights = np.linspace(-0.3, 0.3, 61)  # across the red sphere's silhouette (radius 0.25)
    origins = torch.tensor([[0.0, -1.0, z] for z in RED[0][2] + heights], dtype=torch.float32)
    origins[:, 0] += float(RED[0][0])
    dirs = torch.tensor([[0.0, 1.0, 0.0]]).expand(len(origins), 3).contiguous()
    full_body = body_of(RED, FRAMES[0], RecordingSphereField, box=True)
    full = bodies_transmittance([full_body], origins, dirs, cutoff=0)
    stopped_body = body_of(RED, FRAMES[0], RecordingSphereField, box=True)
    stopped = bodies_transmittance([stopped_body], origins, dirs)
    lit = full > SHADOW_CUTOFF
    assert 10 < int(lit.sum()) < len(full) - 10 and (full[lit] < 0.99).any()  # a soft rim, a dark core
    assert torch.allclose(stopped[lit], full[lit], atol=1e-6)
    dark = ~lit
    assert ((stopped[dark] - full[dark]).abs() < SHADOW_CUTOFF).all()
    assert (stopped[dark] < SHADOW_CUTOFF).all()
    assert sum(stopped_body.field.geometry_calls) < 0.8 * sum(full_body.field.geometry_calls)  # measured 0.71


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    from neural.asset import load_asset, load_field
    from shellsim.tetcage.store import load_or_build_cage

    asset = load_asset(make_asset(tmp_path_factory.mktemp("ball")))
    return asset, load_field(asset, "cpu"), load_or_build_cage(asset)


def test_a_rigidly_moved_two_body_scene_equals_its_rest_view(ball):
    """Two bodies placed side by side, both cages moved by one rigid motion (turned and shifted in the
    world): the frame equals the rest frame seen from the camera carried back by that motion (>= 35 dB)."""
    from shellsim.film.renderer import DeformedRenderer, SceneRenderer
    from shellsim.world import Placement

    asset, field, cage = ball
    placements = [
        Placement(1.0, np.eye(3), -CENTER + np.array([-0.2, 0.0, 0.3])),
        Placement(
            0.8,
            rotation((0, 0, 1), 0.6),
            np.array([0.25, 0.1, 0.25]) - 0.8 * rotation((0, 0, 1), 0.6) @ CENTER,
        ),
    ]
    turn, shift = rotation((1.0, 0.5, 2.0), 0.5), np.array([0.05, -0.1, 0.08])
    renderers = [DeformedRenderer(asset, field, cage, placement=p) for p in placements]
    scene = SceneRenderer(renderers)
    eye, target = np.array([0.2, -1.2, 0.6]), np.array([0.0, 0.0, 0.3])
    view = camera(eye, target=target, size=48, fov_deg=40.0)
    rest, _ = scene.render(view, 0)
    moved_positions = []
    for p in placements:  # world = turn (p.to_world(x)) + shift, in each asset's frame
        world = p.to_world(cage.vertices) @ turn.T + shift
        moved_positions.append(p.to_asset(world))
    moved_view = camera(
        turn @ eye + shift,
        target=turn @ target + shift,
        up=turn @ np.array([0, 0, 1.0]),
        size=48,
        fov_deg=40.0,
    )
    moved, stats = scene.render(moved_view, 0, moved_positions)
    assert stats["samples_per_pixel"] > 0.5
    assert psnr(torch.tensor(moved), torch.tensor(rest)) >= 35.0
    assert math.isfinite(stats["ms"])


SHOT = """
[world]
fps = 30
frames = 4
substeps = 2

[[body]]
name = "ball"
mesh = "{ball}"

[[collider]]
name = "block"
shape = "box"
half_extents = [0.05, 0.05, 0.05]
position = [0.2, 0.0, 0.05]
rotation = [0, 0, 30]

[[camera]]
name = "top"
kind = "fixed"
position = [0.0, 0.0, 1.0]
target = [0.0, 0.0, 0.0]

[[camera]]
name = "side"
kind = "fixed"
position = [0.0, -1.0, 0.1]
target = [0.0, 0.0, 0.05]
"""
RADIUS = 0.05


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    """A 5 cm ball (a mesh body) resting on the ground beside a turned box, simulated for 4 frames and
    filmed by ``shellsim scene --video``; returns the output directory."""
    import trimesh

    from shellsim.cli.main import main

    root = tmp_path_factory.mktemp("shot")
    ball = root / "ball.ply"
    trimesh.creation.icosphere(subdivisions=3, radius=RADIUS).export(ball)
    (root / "shot.toml").write_text(SHOT.format(ball=ball))
    out = root / "shot"
    assert main(["scene", str(root / "shot.toml"), "--out", str(out), "--video", str(root / "shot.mp4")]) == 0
    return out


@pytest.mark.slow
def test_scene_video_films_every_frame(shot):
    from PIL import Image

    frames = sorted((shot / "frames").glob("*.png"))
    assert [f.name for f in frames] == [f"{k:05d}.png" for k in range(4)]
    assert Image.open(frames[0]).size == (512, 512)
    assert (shot.parent / "shot.mp4").stat().st_size > 1000


@pytest.mark.slow
def test_render_scene_takes_other_cameras_sizes_and_strides(shot, tmp_path, capsys):
    import imageio_ffmpeg
    from PIL import Image

    from shellsim.cli.main import main

    out = tmp_path / "side"
    args = ["render", "--scene", str(shot), "--out", str(out), "--width", "48", "--antialias", "1"]
    video = tmp_path / "side.mp4"
    assert main([*args, "--frames", "0:4:2", "--scene-camera", "side", "--video", str(video)]) == 0
    assert sorted(f.name for f in out.glob("*.png")) == ["00000.png", "00002.png"]
    assert Image.open(out / "00002.png").size == (48, 48)
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(video))
    assert frames == 2 and seconds == pytest.approx(2 / 15, abs=0.01)  # every second frame of 30: 15 fps
    capsys.readouterr()
    assert main([*args, "--scene-camera", "front"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'front'" in err and "top, side" in err
    assert main([*args, "--motion", str(shot / "motion.npz")]) == 2
    assert "--scene" in capsys.readouterr().err


@pytest.mark.slow
def test_a_mesh_body_is_lit_and_shadows_the_ground_as_lambert_says(shot, tmp_path):
    """Seen from straight above, frame 0: the ball's top is its albedo times the open light; open ground is
    the checker times ``ambient + diffuse l_z``; ground points whose ray to the light meets the ball (the
    exact sphere, clear of its edge by 5 mm) get the ambient light alone, at most 40% of the open ground's."""
    from PIL import Image

    from neural.data import camera_rays
    from shellsim.film.cameras import scene_shot
    from shellsim.film.shot_frames import render_scene, scene_camera, scene_tracks
    from shellsim.shot.recorded import MESH_BODY_COLORS, read_scene_motion
    from shellsim.world import WorldLook

    size = 96
    render_scene(shot, tmp_path, "top", frames="0:1", size=(size, size), antialias=1, progress=False)
    image = np.asarray(Image.open(tmp_path / "00000.png"), np.float64)[..., :3].reshape(-1, 3) / 255
    scene = read_scene_motion(shot, load_assets=False)
    view = scene_shot(scene_camera(scene, "top"), scene_tracks(scene), size, size).camera_for_frame(0)
    origins, dirs = (x.double().numpy() for x in camera_rays(view, 0))
    look = WorldLook()
    light = look.light_unit()
    centre = scene.bodies[0].surface_points(scene.info.rest_vertices[scene.bodies[0].vertices]).mean(0)
    ground = origins + (-origins[:, 2] / dirs[:, 2])[:, None] * dirs
    checker = np.asarray(look.ground_colors)[(np.floor(ground[:, :2] / look.square).sum(1) % 2).astype(int)]
    open_light = look.ambient + look.diffuse * light[2]

    def miss_by(points, d):  # distance from the sphere's centre of the lines points + s d, s > 0
        along = np.clip(((centre - points) * d).sum(1), 0, None)
        return np.linalg.norm(points + along[:, None] * d - centre, axis=1)

    seen_ball = miss_by(origins, dirs) < RADIUS - 0.005
    box = np.abs(ground[:, :2] - [0.2, 0.0]).max(1) < 0.15  # the turned box and its shadow
    far = ~seen_ball & ~box & (miss_by(origins, dirs) > RADIUS + 0.005)
    to_light = np.broadcast_to(light, ground.shape)
    shadowed = far & (miss_by(ground, to_light) < RADIUS - 0.005)
    lit = far & (miss_by(ground, to_light) > RADIUS + 0.005) & (np.linalg.norm(ground[:, :2], axis=1) < 0.2)
    top = miss_by(origins, dirs) < 0.2 * RADIUS
    assert top.sum() > 3 and shadowed.sum() > 10 and lit.sum() > 100
    albedo = np.asarray(MESH_BODY_COLORS[0])
    assert np.abs(image[top] - albedo * (look.ambient + look.diffuse * light[2])).max() < 0.03
    assert np.abs(image[lit] - checker[lit] * open_light).max() < 0.01
    assert np.abs(image[shadowed] - checker[shadowed] * look.ambient).max() < 0.01
    assert look.ambient / open_light <= 0.40


@pytest.mark.slow
def test_the_scene_files_look_paints_its_frames_and_the_command_line_overrides_it(tmp_path, capsys):
    """A ``[look]`` with a plain sky fills the background of ``scene --video`` with it; changing only the look
    and running again films anew without simulating again; ``render --scene --sky`` replaces it."""
    import trimesh
    from PIL import Image

    from shellsim.cli.main import main
    from shellsim.motion.read import read_motion_info

    ball = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=2, radius=RADIUS).export(ball)
    text = f"""
[world]
frames = 2
ground = false
gravity = 0

[[body]]
name = "ball"
mesh = "{ball}"
position = [0, 0, 0.3]

[look]
sky = {{sky}}
"""
    scene, out = tmp_path / "plain.toml", tmp_path / "plain"

    def film(sky):
        scene.write_text(text.replace("{sky}", str(list(sky))))
        assert main(["scene", str(scene), "--out", str(out), "--video", str(tmp_path / "plain.mp4")]) == 0
        corner = np.asarray(Image.open(out / "frames" / "00001.png"), np.float64)[0, 0, :3] / 255
        return corner, read_motion_info(out / "motion.npz").n_frames

    corner, frames = film((0.1, 0.5, 0.2))
    assert frames == 2 and np.abs(corner - (0.1, 0.5, 0.2)).max() < 0.003
    written = (out / "motion.npz").stat().st_mtime_ns
    corner, _ = film((0.6, 0.3, 0.7))
    assert np.abs(corner - (0.6, 0.3, 0.7)).max() < 0.003
    assert (out / "motion.npz").stat().st_mtime_ns == written  # the motion was not made again
    other = tmp_path / "other"
    args = ["render", "--scene", str(out), "--out", str(other), "--width", "16", "--sky", "0.9,0.9,0.2"]
    assert main(args) == 0
    corner = np.asarray(Image.open(other / "00000.png"), np.float64)[0, 0, :3] / 255
    assert np.abs(corner - (0.9, 0.9, 0.2)).max() < 0.003
