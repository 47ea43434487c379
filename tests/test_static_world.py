"""The static world drawn once per view (shellsim.film.static, shellsim.film.ground.static_layer /
world_colors, shellsim.film.renderer.trace_world).

Truths from outside the code under test: the world drawn whole for every ray of every frame, its meshes
static and moving in one (``shellsim/film/_reference.py``, the drawing before the static part was kept), with
shadow rays through the body that take every sample (``cutoff`` 0): a frame whose static part is kept from
earlier frames equals one drawn anew to float32 rounding, and the full reference to within the shadow
rays' cutoff and the termination's tolerance (the light a terminated ray would still let through)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import trimesh
from test_ground import stepped_sampler
from test_scene_render import PaintedSphere

from neural.data import Cameras, camera_rays
from neural.render.bodies import FieldBody
from neural.render.fullray import WEIGHT_TOLERANCE
from neural.render.view import SHADOW_CUTOFF, bodies_transmittance, render_bodies
from shellsim.film._reference import world_backdrop_reference
from shellsim.film.ground import surface_t_max, world_backdrop
from shellsim.film.obstacles import Meshes, Obstacles
from shellsim.film.renderer import trace_world
from shellsim.film.static import StaticWorld, view_key
from shellsim.world import Placement, WorldLook

LOOK = WorldLook(square=0.1, light=(0.3, -0.2, 1.0), ambient=0.3, diffuse=0.7)
OBSTACLES = Obstacles(boxes=[(0.3, 0.2, 0.1, 0.1, 0.1, 0.1)], spheres=[(-0.35, 0.25, 0.12, 0.12)])
W, H = 64, 48
BACKGROUND = torch.ones(3)
FRAME = Placement(0.5, np.eye(3), np.array([0.05, -0.1, 0.02]))  # the sphere body's own frame


def plate() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A static slab floating above the ground (casts a shadow on it), in the world."""
    box = trimesh.creation.box(extents=(0.25, 0.2, 0.04))
    return box.vertices + (0.0, 0.35, 0.3), box.faces, np.array([0.2, 0.6, 0.3])


def ball(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mesh body moving along x, frame ``k``."""
    sphere = trimesh.creation.icosphere(1, radius=0.06)
    return sphere.vertices + (-0.15 + 0.05 * k, -0.15, 0.1), sphere.faces, np.array([0.8, 0.7, 0.2])


def field_body(k: int) -> FieldBody:
    """A painted sphere (a field) moving the other way, frame ``k``, drawn in its frame :data:`FRAME`."""
    centre, radius = np.array([0.15 - 0.04 * k, -0.25, 0.1]), 0.08
    local = (centre - FRAME.translation) / FRAME.scale
    field = PaintedSphere((0.2, 0.3, 0.9), radius=radius / FRAME.scale, inv_s=200.0, center=tuple(local))
    box = np.stack([centre - radius - 0.1, centre + radius + 0.1])
    return FieldBody(field, stepped_sampler(4e-3, 4.0), None, FRAME, box)


def view(cx: float = W / 2, eye=(0.25, -1.3, 0.75)) -> Cameras:
    """A camera looking at the scene's middle (OpenGL axes), focal 60 pixels."""
    eye, target = np.asarray(eye, float), np.array([0.0, 0.05, 0.1])
    back = (eye - target) / np.linalg.norm(eye - target)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([right, np.cross(back, right), back], 1)
    c2w[:3, 3] = eye
    return Cameras(c2w[None], [60.0], [60.0], [cx], [H / 2], [W], [H], np.zeros((1, 4)), ["c"])


def static_world(look=LOOK) -> StaticWorld:
    return StaticWorld(look, Placement(), OBSTACLES, (Meshes([plate()]),))


def reference(k: int, camera: Cameras, look=LOOK) -> np.ndarray:
    """(H W, 3) frame ``k`` drawn whole: every mesh in one, every shadow sample taken, the backdrop of every
    ray."""
    bodies = [field_body(k)]
    meshes = Meshes([plate(), ball(k)])

    def visibility(o, d):
        return bodies_transmittance(bodies, o, d, cutoff=0)

    backdrop = world_backdrop_reference(look, Placement(), visibility, OBSTACLES, meshes)
    origins, dirs = camera_rays(camera, 0)
    t_max = surface_t_max(look, Placement(), OBSTACLES, origins, dirs, meshes)
    colors, _ = render_bodies(bodies, origins, dirs, BACKGROUND, backdrop=backdrop, t_max=t_max)
    return colors.clamp(0, 1).numpy()


def traced(static: StaticWorld, k: int, camera: Cameras, pixels=None) -> np.ndarray:
    """(P, 3) frame ``k`` through :func:`trace_world` with ``static``'s kept layers."""
    static.next_frame()
    colors, _ = trace_world([field_body(k)], camera, pixels, BACKGROUND, "cpu", static, Meshes([ball(k)]))
    return colors.numpy()


def test_a_fixed_view_draws_its_static_world_twice_and_matches_the_whole_drawing():
    """Frame 0 draws the layer of its rays, frame 1 the layer of the whole view (the view repeated), which
    every later frame takes; each frame equals the one drawn anew (float32 rounding) and the whole reference
    (within the shadows' cutoff and the termination's tolerance)."""
    static, camera = static_world(), view()
    for k in range(4):
        kept = traced(static, k, camera)
        anew = traced(static_world(), k, camera)
        np.testing.assert_allclose(kept, anew, atol=1e-6)
        whole = reference(k, camera)
        assert np.abs(kept - whole).max() < SHADOW_CUTOFF + WEIGHT_TOLERANCE
        assert (static.drawn, static.kept) == (1 + (k > 0), max(k, 0))
    assert np.abs(reference(0, camera) - reference(3, camera)).max() > 0.3  # the frames differ


def test_a_moving_camera_keeps_nothing():
    static = static_world()
    for k in range(3):
        camera = view(eye=(0.25 + 0.05 * k, -1.3, 0.75))
        np.testing.assert_allclose(traced(static, k, camera), reference(k, camera), atol=2e-3)
    assert static.kept == 0 and static.drawn == 3


def test_a_view_is_kept_by_what_its_rays_depend_on():
    """A view shifted by a third of a pixel (another anti-aliasing offset) is another key and another
    layer; the same view made again is the same key."""
    assert view_key(view()) == view_key(view())
    assert view_key(view()) != view_key(view(cx=W / 2 + 1 / 3))
    static = static_world()
    for k in range(3):
        traced(static, k, view())
    shifted = view(cx=W / 2 + 1 / 3)
    np.testing.assert_allclose(traced(static, 3, shifted), traced(static_world(), 3, shifted), atol=1e-6)


def test_some_pixels_are_those_pixels_of_the_whole_view():
    static, camera = static_world(), view()
    whole = [traced(static, k, camera) for k in range(3)]
    pixels = torch.tensor([0, 5, 700, 1500, 2000, W * H - 1])
    np.testing.assert_allclose(traced(static, 2, camera, pixels), whole[2][pixels], atol=1e-6)
    assert static.kept >= 2


@pytest.mark.parametrize(
    "look", [dataclasses.replace(LOOK, shadows=False), dataclasses.replace(LOOK, ground=False)]
)
def test_without_shadows_or_ground_it_still_matches(look):
    static, camera = static_world(look), view()
    for k in range(3):
        np.testing.assert_allclose(
            traced(static, k, camera), reference(k, camera, look), atol=SHADOW_CUTOFF + WEIGHT_TOLERANCE
        )


def test_the_world_backdrop_of_any_rays_is_the_reference():
    """:func:`world_backdrop` (a layer drawn for the rays given, then what moves) against the reference on
    rays of every kind: sky, ground, the obstacles, the static and the moving mesh, lit and in shadow."""
    camera = view()
    origins, dirs = camera_rays(camera, 0)
    meshes, moving = Meshes([plate()]), Meshes([ball(1)])

    def visibility(o, d):  # a made-up soft shadow, the same for both
        return torch.sigmoid(20.0 * (o[:, 0] + 0.1 * o[:, 1]))

    new = world_backdrop(LOOK, Placement(), visibility, OBSTACLES, meshes, None, moving)
    old = world_backdrop_reference(LOOK, Placement(), visibility, OBSTACLES, Meshes([plate(), ball(1)]))
    a, b = new(origins, dirs), old(origins, dirs)
    np.testing.assert_allclose(a.numpy(), b.numpy(), atol=1e-6)
    assert len(torch.unique((b * 255).round(), dim=0)) > 20  # many kinds of rays
    assert math.isfinite(float(a.sum()))
