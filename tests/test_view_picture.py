"""shellsim.view.picture: the viewer's neural picture against the batch renderers and closed forms.

Truths from outside the picture's code: the images of :class:`DeformedRenderer` and :class:`SceneRenderer`
(anti-aliased by :func:`antialiased`) of the same camera; the depth of the ground plane and of a sphere met
head-on (closed forms: the camera's height over the plane, the distance to the centre less the radius);
the order of pictures against the order of requests.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
import torch
from test_render_deformed import CENTER, make_asset

from shellsim.view.picture import FAR_DEPTH, FINAL, FULL, LOW, NeuralPicture, PictureSettings, Pinhole

EYE = CENTER + np.array([0.9, -0.6, 0.5])
FOV = math.radians(50.0)
RADIUS = 0.25  # of the test asset's sphere (world units)


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    from neural.asset import load_asset, load_field
    from shellsim.tetcage.store import load_or_build_cage

    asset = load_asset(make_asset(tmp_path_factory.mktemp("ball")))
    return asset, load_field(asset, "cpu"), load_or_build_cage(asset)


def placed(cage):
    """The placement that stands the ball's cage on the ground (z = 0) at the origin, turned about z."""
    from shellsim.world import Placement

    turn = np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    bottom = cage.vertices[:, 2].min()
    return Placement(1.0, turn, -turn @ CENTER + np.array([0.0, 0.0, CENTER[2] - bottom + 0.01]))


def test_pinhole_converts_viser_cameras():
    """A viser-like camera (wxyz, OpenCV axes) becomes the OpenGL camera looking the same way, and the
    quaternion of a look-at rotation gives that rotation."""
    from scipy.spatial.transform import Rotation

    view = Pinhole.looking_at(EYE, CENTER, FOV, 2.0)
    forward = (CENTER - EYE) / np.linalg.norm(CENTER - EYE)
    assert np.allclose(view.forward, forward)
    x, y, z, w = Rotation.from_matrix(view.rotation).as_quat()

    class Handle:  # viser.CameraHandle's attributes
        position, wxyz, fov, aspect, image_width, image_height = EYE, (w, x, y, z), FOV, 2.0, 800, 400

    again = Pinhole.of(Handle())
    assert np.allclose(again.rotation, view.rotation) and again.size == (800, 400)
    assert again.pixels(512) == (512, 256) and again.pixels(2000) == (800, 400)
    c2w = again.cameras(64, 32).c2w[0]
    assert np.allclose(-c2w[:3, 2], forward) and np.allclose(c2w[:3, 1], -view.rotation[:, 1])
    with pytest.raises(ValueError, match="fov"):
        Pinhole(EYE, view.rotation, 4.0, 1.0)


def test_a_lone_asset_equals_the_deformed_renderer(ball):
    """At rest and with the cage moved rigidly (with the identity placement: world = asset frame), the
    picture is the image of :meth:`DeformedRenderer.render` of the same camera, pixel for pixel."""
    from shellsim.film.renderer import DeformedRenderer

    asset, field, cage = ball
    picture = NeuralPicture.from_asset(asset, cage, device="cpu")
    reference = DeformedRenderer(asset, field, cage, "cpu")
    view = Pinhole.looking_at(EYE, CENTER, FOV, 1.25)
    shift = np.array([0.03, -0.02, 0.01])
    for positions in (None, cage.vertices + shift):
        image, depth = picture.render(view, positions, 30, 24)
        expected, _ = reference.render(view.cameras(30, 24), 0, positions)
        assert image.shape == (24, 30, 3) and depth.shape == (24, 30)
        assert np.abs(image - expected).max() < 1e-5


def test_the_refined_picture_equals_the_scene_renderer_anti_aliased(ball):
    """The ball on the lit ground with its shadow, its cage bent: the anti-aliased picture, rendered in
    tiles, equals :func:`antialiased` of :meth:`SceneRenderer.render` (every channel within 2e-3), and the
    refined size keeps the camera's aspect under the cap."""
    from neural.metrics import psnr
    from shellsim.film.antialias import antialiased
    from shellsim.film.renderer import DeformedRenderer, SceneRenderer
    from shellsim.world import WorldLook

    asset, field, cage = ball
    placement, look = placed(cage), WorldLook()
    settings = PictureSettings(max_side=40, tile_rows=7, antialias=2)
    picture = NeuralPicture.from_asset(asset, cage, placement, look, "cpu", settings)
    reference = SceneRenderer([DeformedRenderer(asset, field, cage, "cpu", placement=placement)], look)
    bent = cage.vertices.copy()
    top = bent[:, 2] > CENTER[2]
    bent[top, 0] += 0.2 * (bent[top, 2] - CENTER[2])  # a shear of the upper half
    world = placement.to_world(bent)
    eye, target = np.array([0.7, -0.8, 0.5]), np.array([0.0, 0.0, 0.2])
    view = Pinhole.looking_at(eye, target, FOV, 4 / 3, size=(800, 600))
    width, height = view.pixels(settings.max_side)
    assert (width, height) == (40, 30)
    image, _ = picture.render(view, world, width, height, antialias=2)
    expected, _ = antialiased(lambda v: reference.render(v, 0, [bent]), 2)(view.cameras(width, height))
    assert np.abs(image - expected).max() < 2e-3
    assert psnr(torch.tensor(image), torch.tensor(expected)) > 40.0


def test_depth_of_the_ground_and_of_the_sphere_is_the_closed_form(ball):
    """Looking straight down from height h at open ground: the centre pixel's depth is h; looking at the
    sphere's centre from distance D: D - r (to the width of the narrow band's samples); a ray into the sky:
    :data:`FAR_DEPTH`. Depth is along the camera's axis: a pixel off the centre sees the ground at the same
    depth h."""
    from shellsim.world import WorldLook

    asset, field, cage = ball
    placement = placed(cage)
    picture = NeuralPicture.from_asset(asset, cage, placement, WorldLook(), "cpu")
    rest = placement.to_world(cage.vertices)
    h = 1.3
    down = Pinhole.looking_at((2.0, 1.0, h), (2.0, 1.0, 0.0), FOV, 1.0, up=(0.0, 1.0, 0.0))
    _, depth = picture.render(down, rest, 21, 21)
    assert depth[10, 10] == pytest.approx(h, abs=1e-4)
    assert depth[2, 17] == pytest.approx(h, abs=1e-4)
    centre = placement.to_world(CENTER[None])[0]
    eye = centre + np.array([0.0, -1.1, 0.0])
    ahead = Pinhole.looking_at(eye, centre, math.radians(20.0), 1.0)
    _, depth = picture.render(ahead, rest, 21, 21)
    assert depth[10, 10] == pytest.approx(1.1 - RADIUS, abs=0.005)
    up = Pinhole.looking_at(eye, eye + np.array([0.0, 0.3, 1.0]), math.radians(20.0), 1.0)
    _, depth = picture.render(up, rest, 9, 9)
    assert np.all(depth == FAR_DEPTH)


class Recorder:
    """Records the pictures delivered to each request's ``on_picture``: ``(tag, shape)`` in order."""

    def __init__(self):
        self.got: list[tuple[str, tuple]] = []
        self.event = threading.Event()

    def callback(self, tag: str):
        def on_picture(rgb, depth):
            assert rgb.dtype == np.uint8 and depth.dtype == np.float32 and rgb.shape[:2] == depth.shape
            self.got.append((tag, rgb.shape[:2]))
            self.event.set()

        return on_picture

    def wait(self, predicate, seconds: float = 60.0) -> None:
        deadline = time.perf_counter() + seconds
        while not predicate():
            assert time.perf_counter() < deadline, f"waited {seconds} s; got {self.got}"
            time.sleep(0.01)


def test_a_request_superseded_mid_refinement_is_never_delivered_after_the_newer_one(ball):
    """A new request while the first one is being refined: the refinement stops between two tiles, and no
    picture of the first request comes after one of the second, whose refinement arrives."""
    asset, _, cage = ball
    settings = PictureSettings(low_side=8, max_side=24, tile_rows=4, antialias=2, settle=0.0)
    picture = NeuralPicture.from_asset(asset, cage, device="cpu", settings=settings)
    in_refinement, go_on = threading.Event(), threading.Event()
    tiles = picture._render_tile

    def slow_tile(frame, tile, with_depth, moving=False):  # the first refinement's first tile waits
        if int(tile.width[0]) == 24 and not in_refinement.is_set():
            in_refinement.set()
            go_on.wait(10)
        return tiles(frame, tile, with_depth, moving)

    picture._render_tile = slow_tile
    record = Recorder()
    first = Pinhole.looking_at(EYE, CENTER, FOV, 1.0)
    second = Pinhole.looking_at(EYE + [0.1, 0, 0], CENTER, FOV, 1.0)
    with picture:
        picture.request(first, None, record.callback("first"))
        assert in_refinement.wait(30)
        picture.request(second, None, record.callback("second"))
        go_on.set()
        record.wait(lambda: any(s == FINAL for g, s, _ in picture.stages if g == 2))
    tags = [tag for tag, _ in record.got]
    assert tags[0] == "first" and record.got[0][1] == (8, 8)  # its low picture, made before the second came
    assert "second" in tags and "first" not in tags[tags.index("second") :]
    assert tags.count("first") == 1  # neither refinement of the first
    assert [s for g, s, _ in picture.stages if g == 2] == [LOW, FULL, FINAL]


def test_low_pictures_come_while_requests_keep_coming(ball):
    """Requests every 20 ms for 0.6 s (settle 0.2 s): every picture then is low resolution, and once they
    stop, the last request's refined and anti-aliased pictures follow, in that order."""
    asset, _, cage = ball
    settings = PictureSettings(low_side=8, max_side=20, antialias=2, settle=0.2)
    picture = NeuralPicture.from_asset(asset, cage, device="cpu", settings=settings)
    record = Recorder()
    with picture:
        start = time.perf_counter()
        k = 0
        while time.perf_counter() - start < 0.6:
            eye = CENTER + np.array([0.9 * math.cos(0.1 * k), 0.9 * math.sin(0.1 * k), 0.4])
            picture.request(Pinhole.looking_at(eye, CENTER, FOV, 1.0), None, record.callback(str(k)))
            k += 1
            time.sleep(0.02)
        moving = len(record.got)
        last = str(k - 1)
        record.wait(
            lambda: (
                any(tag == last and shape == (20, 20) for tag, shape in record.got[moving:])
                and (sum(tag == last for tag, _ in record.got) >= 3)
            )
        )
    assert moving >= 2 and all(shape == (8, 8) for _, shape in record.got[:moving])
    assert [shape for tag, shape in record.got if tag == last] == [(8, 8), (20, 20), (20, 20)]
    assert [s for g, s, _ in picture.stages if g == picture.generation] == [LOW, FULL, FINAL]
