"""Static obstacles drawn around a body (shellsim.film.obstacles, shellsim.film.ground): boxes and spheres
in world metres, Lambert-shaded, shadowing the ground and each other, hiding the body behind them.

Truths from outside the code: the pinhole projection of a box's face and of a sphere's silhouette
(``f r / sqrt(D^2 - r^2)`` pixels), Lambert's law, the shadow of a box as the convex hull of its corners
projected along the light (scipy's ``ConvexHull``), a sphere's exact SDF as an opaque body."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scenes import SphereField, look_at
from scipy.spatial import ConvexHull
from test_ground import PLACEMENT, checker_albedo, open_shade, stepped_sampler, to_asset_rays

from neural.config import NarrowBandConfig
from neural.data import Cameras, camera_rays
from neural.render.view import render_camera
from shellsim.film.ground import surface_t_max, world_backdrop
from shellsim.film.motion_frames import motion_world, world_record
from shellsim.film.obstacles import Obstacles
from shellsim.io.png import renderer_identity
from shellsim.world import WorldLook

LOOK = WorldLook(light=(0.3, -0.2, 1.0), ambient=0.3, diffuse=0.7, obstacle_color=(0.9, 0.05, 0.1))
LIGHT = np.asarray(LOOK.light) / np.linalg.norm(LOOK.light)
BOX = (0.1, -0.05, 0.04, 0.08, 0.05, 0.04)  # standing on the ground
SIZE, FOCAL = 64, 60.0


def world_camera(eye, target, up=(0.0, 0.0, 1.0)) -> tuple[Cameras, np.ndarray]:
    """A SIZE x SIZE pinhole camera at world ``eye`` looking at ``target``, in the renderer's frame, and its
    world camera-to-world (4, 4)."""
    c2w_w = look_at(np.asarray(eye, float), np.asarray(target, float), np.asarray(up, float))
    c2w = c2w_w.copy()
    c2w[:3, :3] = PLACEMENT.rotation.T @ c2w_w[:3, :3]
    c2w[:3, 3] = PLACEMENT.to_asset(c2w_w[:3, 3])
    half = SIZE / 2
    return Cameras(
        c2w[None], [FOCAL], [FOCAL], [half], [half], [SIZE], [SIZE], np.zeros((1, 4)), ["c"]
    ), c2w_w


def project(c2w_w: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) pixel coordinates (u, v) of world ``points`` (N, 3): ``u = cx + f x / -z``,
    ``v = cy - f y / -z`` in the OpenGL camera's axes."""
    cam = (points - c2w_w[:3, 3]) @ c2w_w[:3, :3]
    return np.stack([SIZE / 2 + FOCAL * cam[:, 0] / -cam[:, 2], SIZE / 2 - FOCAL * cam[:, 1] / -cam[:, 2]], 1)


def pixel_centres() -> tuple[np.ndarray, np.ndarray]:
    return np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5)


def render(cameras, obstacles, field=None, look=LOOK, sampler=None):
    """Image of ``field`` (None: far away, never sampled) with the world and ``obstacles`` behind and in
    front of it, through the pipeline with the obstacles' ``t_max``."""
    field = SphereField(0.01, 1000.0, (50.0, 50.0, 50.0)) if field is None else field
    sampler = stepped_sampler(1.0, far=0.5) if sampler is None else sampler
    t_max = surface_t_max(look, PLACEMENT, obstacles, *camera_rays(cameras, 0))
    backdrop = world_backdrop(look, PLACEMENT, None, obstacles)
    return render_camera(field, cameras, 0, sampler, torch.ones(3), backdrop=backdrop, t_max=t_max)[0]


def is_obstacle(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixel has the obstacles' hue (red, no green: neither ground, sky nor the body)."""
    return (image[..., 0] > 4 * image[..., 1]) & (image[..., 0] > 0.1)


@pytest.mark.parametrize(
    "eye, normal",
    [((0.1, -0.05, 0.9), (0.0, 0.0, 1.0)), ((0.1, -0.9, 0.04), (0.0, -1.0, 0.0))],
    ids=["top", "front"],
)
def test_a_box_seen_head_on_covers_its_projected_rectangle(eye, normal):
    """Pixels whose centres fall inside the projected face (a rectangle: the face is parallel to the image)
    show the obstacle colour times ambient + diffuse cos(n, l); the others do not show the box."""
    box = np.asarray(BOX)
    normal = np.asarray(normal)
    up = (0.0, 1.0, 0.0) if normal[2] else (0.0, 0.0, 1.0)
    cameras, c2w_w = world_camera(eye, box[:3] + normal * box[3:], up)
    image = render(cameras, Obstacles(boxes=[BOX]))
    # the face's corners: the box's corners on the side of its normal
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
    corners = box[:3] + signs * box[3:]
    face = project(c2w_w, corners[signs @ normal > 0])
    (u0, v0), (u1, v1) = face.min(0), face.max(0)
    u, v = pixel_centres()
    margin = 1e-3  # pixels
    inside = (u > u0 + margin) & (u < u1 - margin) & (v > v0 + margin) & (v < v1 - margin)
    outside = (u < u0 - margin) | (u > u1 + margin) | (v < v0 - margin) | (v > v1 + margin)
    assert 50 < inside.sum() < 0.9 * inside.size and (inside | outside).mean() > 0.9
    shade = LOOK.ambient + LOOK.diffuse * max(normal @ LIGHT, 0.0)
    np.testing.assert_allclose(
        image[inside], np.broadcast_to(np.asarray(LOOK.obstacle_color) * shade, (inside.sum(), 3)), atol=1e-6
    )
    assert not is_obstacle(image)[outside].any()


def test_a_sphere_silhouette_has_the_pinhole_radius():
    """A sphere of radius r at distance D on the optical axis: a disc of ``f r / sqrt(D^2 - r^2)`` pixels,
    its centre pixel shaded with the normal toward the camera."""
    centre, r, distance = np.array([0.0, 0.1, 0.3]), 0.12, 0.6
    direction = np.array([0.6, -0.64, 0.48])
    eye = centre + distance * direction
    cameras, _ = world_camera(eye, centre)
    look = WorldLook(
        ground=False, zenith=(1.0, 1.0, 1.0), horizon=(1.0, 1.0, 1.0), obstacle_color=(0.9, 0, 0)
    )
    image = render(cameras, Obstacles(spheres=[(*centre, r)]), look=look)
    radius = FOCAL * r / np.sqrt(distance**2 - r**2)
    u, v = pixel_centres()
    rho = np.hypot(u - SIZE / 2, v - SIZE / 2)
    clear = np.abs(rho - radius) > 1e-3
    assert radius > 10
    np.testing.assert_array_equal(is_obstacle(image)[clear], (rho < radius)[clear])
    # the four pixels around the image centre see the sphere nearly head on: their mean, to first order
    shade = look.ambient + look.diffuse * max(direction @ look.light_unit(), 0.0)
    assert image[31:33, 31:33, 0].mean() == pytest.approx(0.9 * shade, abs=1e-3)


def opaque_body(centre_w: np.ndarray, radius_w: float) -> SphereField:
    """An opaque sphere body at world ``centre_w`` as a field of the renderer's frame."""
    centre = PLACEMENT.to_asset(centre_w)
    return SphereField(radius_w / PLACEMENT.scale, 20000.0, tuple(centre.tolist()))


@pytest.mark.slow
@pytest.mark.parametrize("wall_y", [-0.35, 0.35], ids=["in front", "behind"])
def test_an_obstacle_hides_the_body_behind_it_and_not_in_front(wall_y):
    """A thin wall over the left half of the view, between the camera and an opaque sphere body (or behind
    it): in front it hides the body (those pixels are exactly the obstacle's), behind it the body's pixels
    are those of the body without the wall."""
    body = np.array([0.0, 0.0, 0.3])
    eye = body + np.array([0.0, -1.0, 0.0])
    cameras, _ = world_camera(eye, body)
    wall = (-0.75, body[1] + wall_y, 0.3, 0.75, 0.01, 1.0)  # x in [-1.5, 0]: the left half of the view
    field = opaque_body(body, 0.25)
    sampler = stepped_sampler(0.25 / PLACEMENT.scale / 300, far=4.0)
    look = WorldLook(ground=False, light=LOOK.light, obstacle_color=(0.9, 0.05, 0.1))
    alone = render(cameras, Obstacles(), field, look, sampler)
    image = render(cameras, Obstacles(boxes=[wall]), field, look, sampler)
    u, v = pixel_centres()
    radius = FOCAL * 0.25 / np.sqrt(1.0 - 0.25**2)  # the body's silhouette (pixels)
    rho = np.hypot(u - SIZE / 2, v - SIZE / 2)
    body_px = rho < radius - 1.0
    left, right = u < SIZE / 2 - 0.5, u > SIZE / 2 + 0.5  # the wall's edge x = 0 projects to u = 32
    assert (body_px & left).sum() > 50 and (body_px & right).sum() > 50
    if wall_y < 0:  # the wall's front face (normal -y) in front of the body's left half
        shade = look.ambient + look.diffuse * max(-LIGHT[1], 0.0)
        colour = np.asarray(look.obstacle_color) * shade
        np.testing.assert_allclose(image[left], np.broadcast_to(colour, (left.sum(), 3)), atol=1e-6)
        np.testing.assert_allclose(image[right], alone[right], atol=1e-6)
    else:  # behind: the body composites over it as without it
        np.testing.assert_allclose(image[body_px], alone[body_px], atol=1e-4)
        assert is_obstacle(image)[left & (rho > radius + 1.0)].all()


@pytest.mark.slow
def test_the_ground_hides_the_body_below_it():
    """An opaque sphere body half sunk into the ground (centre at z = 0), seen from above at a slant: a pixel
    whose ray meets the sphere first below z = 0 shows the ground (the ray meets z = 0 first), one meeting it
    above shows the body; without the ground both show the body."""
    body = np.array([0.0, 0.0, 0.0])
    eye = body + np.array([0.0, -0.8, 0.5])
    cameras, c2w_w = world_camera(eye, body)
    field = opaque_body(body, 0.2)
    sampler = stepped_sampler(0.2 / PLACEMENT.scale / 300, far=4.0)
    look = WorldLook(light=LOOK.light, shadows=False)
    image = render(cameras, Obstacles(), field, look, sampler)
    without = render(cameras, Obstacles(), field, WorldLook(ground=False, light=LOOK.light), sampler)
    u, v = pixel_centres()  # each pixel's world ray, and where it first meets the sphere (closed form)
    cam = np.stack([(u - SIZE / 2) / FOCAL, -(v - SIZE / 2) / FOCAL, -np.ones_like(u)], -1)
    d = cam @ c2w_w[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    oc = eye - body
    b = d @ oc
    disc = b**2 - (oc @ oc - 0.2**2)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    z = eye[2] + t * d[..., 2]
    seen = disc > 0.01  # away from the silhouette
    below, above = seen & (z < -0.005), seen & (z > 0.005)
    assert below.sum() > 20 and above.sum() > 20
    hits = eye + (-eye[2] / d[..., 2])[..., None] * d  # where each ray meets z = 0
    cell = hits[..., :2] / look.square
    below &= (np.abs(cell - np.round(cell)) > 1e-3).all(axis=-1)  # off the checker's edges
    ground = np.array([open_shade(look) * checker_albedo(look, x, y) for x, y, _ in hits[below]])
    np.testing.assert_allclose(image[below], ground, atol=1e-5)
    np.testing.assert_allclose(image[above], without[above], atol=1e-5)
    assert np.abs(without[below] - image[below]).max() > 0.05  # the body was there before the ground hid it


def test_a_box_shadows_the_ground_and_a_sphere_shadows_the_box():
    """Ground points in the box's shadow (the convex hull of its corners projected along the light onto
    z = 0) keep the ambient light only, the others get it all; a sphere above the box shadows its top."""
    box = np.asarray(BOX)
    sphere = (0.15, -0.06, 0.2, 0.03)
    obstacles = Obstacles(boxes=[BOX], spheres=[sphere])
    backdrop = world_backdrop(LOOK, PLACEMENT, None, obstacles)
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
    corners = box[:3] + signs * box[3:]
    shadow = corners[:, :2] - (corners[:, 2] / LIGHT[2])[:, None] * LIGHT[:2]
    hull = ConvexHull(shadow)
    # a grid off the checker's edges (a point on one may take either colour)
    xs, ys = np.meshgrid(np.linspace(-0.1, 0.3, 41) + 0.0037, np.linspace(-0.25, 0.15, 41) + 0.0041)
    points = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)
    signed = (points[:, :2] @ hull.equations[:, :2].T + hull.equations[:, 2]).max(1)  # > 0 outside
    footprint = (np.abs(points[:, :2] - box[:2]) <= box[3:5] + 1e-3).all(1)
    to_centre = np.asarray(sphere[:3]) - points
    along = to_centre @ LIGHT
    in_sphere_shadow = np.linalg.norm(to_centre - along[:, None] * LIGHT, axis=1) < sphere[3] + 1e-3
    under_sphere = np.linalg.norm(points[:, :2] - sphere[:2], axis=1) < sphere[3] + 1e-3  # hides them
    keep = ~footprint & (np.abs(signed) > 1e-3) & ~in_sphere_shadow & ~under_sphere
    points, signed = points[keep], signed[keep]
    o, d = to_asset_rays(points + np.array([0.0, 0.0, 1.0]), np.tile([0.0, 0.0, -1.0], (len(points), 1)))
    albedo = np.array([checker_albedo(LOOK, x, y) for x, y, _ in points])
    shade = (backdrop(o, d).double().numpy() / albedo).mean(1)
    assert (signed < 0).sum() > 20 and (signed > 0).sum() > 20
    np.testing.assert_allclose(shade[signed < 0], LOOK.ambient, atol=1e-6)
    np.testing.assert_allclose(shade[signed > 0], open_shade(LOOK), atol=1e-6)
    # the top of the box under the sphere's centre, seen from above aside (away from the light)
    top = box[2] + box[5]
    q = np.asarray(sphere[:3]) - (sphere[2] - top) / LIGHT[2] * LIGHT
    assert (np.abs(q[:2] - box[:2]) < box[3:5]).all()
    eye = q + np.array([-0.3, 0.3, 0.3])
    o, d = to_asset_rays(eye[None], (q - eye)[None])
    colour = backdrop(o, d).double().numpy()[0]
    np.testing.assert_allclose(colour, np.asarray(LOOK.obstacle_color) * LOOK.ambient, atol=1e-6)


def test_obstacles_are_checked_and_recorded():
    with pytest.raises(ValueError, match="boxes"):
        Obstacles(boxes=[(0.0, 0.0, 0.0, 0.1, -0.1, 0.1)])
    with pytest.raises(ValueError, match="spheres"):
        Obstacles(spheres=[(0.0, 0.0, 0.1)])
    with pytest.raises(ValueError, match="obstacle_color"):
        WorldLook(obstacle_color=(2.0, 0.0, 0.0))
    assert not Obstacles() and Obstacles(spheres=[(0, 0, 0, 1)])
    plain = SimpleNamespace(placement=PLACEMENT.as_dict(), settings={"drop_height": 0.1}, path=None)
    boxed = SimpleNamespace(
        placement=PLACEMENT.as_dict(), settings={"box": [list(BOX)], "sphere": []}, path=None
    )
    assert not motion_world(plain)[2] and motion_world(boxed)[2] == Obstacles(boxes=[BOX])
    asset = SimpleNamespace(narrowband_config=NarrowBandConfig, background=(1.0, 1.0, 1.0))
    records = {renderer_identity(asset, 4, world_record(motion_world(m))) for m in (plain, boxed)}
    assert len(records) == 2
