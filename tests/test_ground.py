"""The world behind a body (shellsim.film.ground): a checkered ground plane at world z = 0 seen through a
placement, lit by ambient + diffuse Lambert light, with shadows attenuated by the field's transmittance.

Truths from outside the code: the pixel -> ground point map of a camera looking straight down (similar
triangles), Lambert's law, a sphere's exact SDF, and the NeuS transmittance of a ray integrated by brute
force, ``T = exp(sum_k min(log Phi(f(t_k+1)) - log Phi(f(t_k)), 0))`` over 200,000 steps of the exact
SDF."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scenes import SphereField
from test_render_deformed import EYE, camera, make_asset, rotation

from neural.asset import load_asset, load_field
from neural.data import Cameras
from neural.render.fullray import stepped_samples
from neural.render.view import render_camera, transmittance
from shellsim.errors import SettingError
from shellsim.film.ground import world_backdrop
from shellsim.film.motion_frames import motion_world, world_record
from shellsim.film.obstacles import Obstacles
from shellsim.film.renderer import DeformedRenderer
from shellsim.film.world import WorldSettings
from shellsim.io.png import renderer_identity
from shellsim.tetcage.store import load_or_build_cage
from shellsim.world import Placement, WorldLook, place_on_ground

# The renderer's (asset's) frame: world = 0.5 * R x + t, a turned, scaled and shifted frame.
PLACEMENT = Placement(0.5, rotation((1.0, 2.0, 3.0), 0.7), np.array([0.2, -0.1, 0.05]))
LOOK = WorldLook(square=0.1, light=(0.3, -0.2, 1.0), ambient=0.3, diffuse=0.7)
SPHERE_CENTER = np.array([0.05, 0.1, 0.3])  # world metres
SPHERE_RADIUS = 0.1
FAR = 3.0  # shadow rays are marched over t in [0, FAR] (asset units)


def open_shade(look: WorldLook) -> float:
    """Lambert's law for an unoccluded ground point: ambient + diffuse * cos(light, +z)."""
    light = np.asarray(look.light, float)
    return look.ambient + look.diffuse * light[2] / np.linalg.norm(light)


def checker_albedo(look: WorldLook, x: float, y: float) -> np.ndarray:
    return np.asarray(look.ground_colors[(math.floor(x / look.square) + math.floor(y / look.square)) % 2])


def stepped_sampler(step: float, far: float = FAR):
    """Fixed steps of ``step`` over t in [0, far] of every ray (unit directions)."""

    def sample(origins, dirs):
        n = len(origins)
        return stepped_samples(origins.new_zeros(n), origins.new_full((n,), far), step, int(far / step) + 2)

    return sample


def sphere_in_asset_frame(inv_s: float) -> SphereField:
    """The world sphere (SPHERE_CENTER, SPHERE_RADIUS) as a field of the renderer's frame."""
    center = PLACEMENT.to_asset(SPHERE_CENTER)
    return SphereField(SPHERE_RADIUS / PLACEMENT.scale, inv_s, tuple(center.tolist()))


def to_asset_rays(origins_w: np.ndarray, dirs_w: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """World rays (N, 3) as rays of the renderer's frame with unit directions."""
    o = PLACEMENT.to_asset(origins_w)
    d = dirs_w @ PLACEMENT.rotation  # R^T d
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return torch.tensor(o, dtype=torch.float32), torch.tensor(d, dtype=torch.float32)


def shade_at(backdrop, ground_points_w: np.ndarray, look: WorldLook) -> np.ndarray:
    """Shade (N,) of world ground points (colour / checker albedo), seen from 1 m above and aside."""
    eyes = ground_points_w + np.array([-0.2, -0.3, 1.0])
    o, d = to_asset_rays(eyes, ground_points_w - eyes)
    color = backdrop(o, d).double().numpy()
    albedo = np.array([checker_albedo(look, x, y) for x, y, _ in ground_points_w])
    return (color / albedo).mean(axis=1)


def shadow_point(offset=(0.0, 0.0)) -> np.ndarray:
    """The world ground point whose ray toward LOOK's light passes through the sphere's centre, moved by
    ``offset`` metres in x, y."""
    light = np.asarray(LOOK.light, float)
    point = SPHERE_CENTER - SPHERE_CENTER[2] / light[2] * light
    return point + np.array([*offset, 0.0])


def brute_force_transmittance(origin, direction, field: SphereField, far: float = FAR, n=200_000) -> float:
    """NeuS transmittance of a ray through the exact SDF: sum of min(log Phi(f_k+1) - log Phi(f_k), 0)."""
    t = np.linspace(0.0, far, n + 1)
    points = origin[None] + t[:, None] * direction[None]
    f = np.linalg.norm(points - field.center.numpy()[None], axis=1) - field.radius
    log_phi = -np.logaddexp(0.0, -field.inv_s * f)  # log sigmoid(s f)
    return float(np.exp(np.minimum(np.diff(log_phi), 0.0).sum()))


def test_pixels_show_the_checker_where_the_ray_meets_the_ground():
    """A camera 1.3 m above world (x0, y0), looking straight down: pixel (u, v) (centre) sees the ground
    point (x0 + h (u - cx) / f, y0 - h (v - cy) / f), whose checker colour times ambient + diffuse cos is the
    pixel (no field in view)."""
    size, focal, h, x0, y0 = 32, 40.0, 1.3, 0.137, -0.211
    eye_w = np.array([x0, y0, h])
    c2w = np.eye(4)
    c2w[:3, :3] = PLACEMENT.rotation.T  # camera axes = world axes, in the renderer's frame
    c2w[:3, 3] = PLACEMENT.to_asset(eye_w)
    cameras = Cameras(c2w[None], [focal], [focal], [16.0], [16.0], [size], [size], np.zeros((1, 4)), ["c"])
    field = sphere_in_asset_frame(1000.0)  # far outside the sampled range: no sample lands on it
    backdrop = world_backdrop(LOOK, PLACEMENT)
    empty = stepped_sampler(1.0, far=0.5)  # samples only near the camera, where the field is empty
    image, stats = render_camera(field, cameras, 0, empty, torch.ones(3), backdrop=backdrop)
    u, v = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    x, y = x0 + h * (u - 16.0) / focal, y0 - h * (v - 16.0) / focal
    expected = np.array(
        [
            [checker_albedo(LOOK, a, b) for a, b in zip(ra, rb, strict=True)]
            for ra, rb in zip(x, y, strict=True)
        ]
    )
    expected = expected * open_shade(LOOK)
    # pixels whose point lies within 1e-4 m of a square's edge may round to either side
    margin = 1e-4 / LOOK.square
    fx, fy = (x / LOOK.square) % 1.0, (y / LOOK.square) % 1.0
    clear = (np.minimum(fx, 1 - fx) > margin) & (np.minimum(fy, 1 - fy) > margin)
    assert clear.mean() > 0.9 and len(np.unique(expected[..., 0])) == 2
    np.testing.assert_allclose(image[clear], expected[clear], atol=1e-5)
    assert stats["world_ms"] > 0


def test_the_sky_is_a_vertical_gradient_and_rays_from_below_see_no_ground():
    look = WorldLook(zenith=(0.2, 0.4, 0.8), horizon=(0.9, 0.9, 0.9))
    backdrop = world_backdrop(look, PLACEMENT)
    dirs_w = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, 0.0, -1.0]])
    origins_w = np.array([[0.0, 0.0, 1.0]] * 3 + [[0.0, 0.0, -1.0]])  # the last one starts under the ground
    o, d = to_asset_rays(origins_w, dirs_w)
    up = np.array([1.0, 0.0, 0.8, 0.0])
    expected = np.asarray(look.horizon) + (np.asarray(look.zenith) - np.asarray(look.horizon)) * up[:, None]
    np.testing.assert_allclose(backdrop(o, d).numpy(), expected, atol=1e-6)


def test_an_opaque_sphere_leaves_only_the_ambient_light():
    """Under an opaque sphere the ground keeps exactly the ambient share; beside its shadow all the light."""
    field = sphere_in_asset_frame(2000.0)
    sampler = stepped_sampler(SPHERE_RADIUS / PLACEMENT.scale / 400)

    def visibility(o, d):
        return transmittance(field, o, d, sampler)

    backdrop = world_backdrop(LOOK, PLACEMENT, visibility)
    points = np.array([shadow_point(), shadow_point((0.02, -0.03)), shadow_point((0.3, 0.0))])
    shade = shade_at(backdrop, points, LOOK)
    np.testing.assert_allclose(shade, [LOOK.ambient, LOOK.ambient, open_shade(LOOK)], atol=1e-5)


@pytest.mark.parametrize("inv_s", [4.0, 8.0])
def test_a_soft_field_casts_a_partial_shadow_of_its_transmittance(inv_s):
    """A wide kernel lets part of the light through: the shade is ambient + diffuse cos T with T in (0, 1),
    T the brute-force NeuS transmittance along the shadow ray."""
    field = sphere_in_asset_frame(inv_s)
    sampler = stepped_sampler(FAR / 20000)

    def visibility(o, d):
        return transmittance(field, o, d, sampler)

    backdrop = world_backdrop(LOOK, PLACEMENT, visibility)
    point = shadow_point((0.01, 0.0))
    shade = shade_at(backdrop, point[None], LOOK)[0]
    origin, direction = to_asset_rays(point[None], np.asarray(LOOK.light, float)[None])
    truth = brute_force_transmittance(origin[0].double().numpy(), direction[0].double().numpy(), field)
    assert 0.05 < truth < 0.95
    light = np.asarray(LOOK.light, float)
    cos = light[2] / np.linalg.norm(light)
    assert shade == pytest.approx(LOOK.ambient + LOOK.diffuse * cos * truth, abs=2e-4)
    assert LOOK.ambient < shade < open_shade(LOOK)


def test_transmittance_matches_brute_force_through_the_pipeline():
    field = sphere_in_asset_frame(6.0)
    rng = np.random.default_rng(0)
    origins = PLACEMENT.to_asset(SPHERE_CENTER) + rng.normal(size=(5, 3)) * 0.1 - np.array([0.0, 0.0, 1.0])
    dirs = np.array([0.0, 0.0, 1.0]) + rng.normal(size=(5, 3)) * 0.1
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o, d = torch.tensor(origins, dtype=torch.float32), torch.tensor(dirs, dtype=torch.float32)
    got = transmittance(field, o, d, stepped_sampler(FAR / 20000)).numpy()
    truth = [brute_force_transmittance(a, b, field) for a, b in zip(origins, dirs, strict=True)]
    np.testing.assert_allclose(got, truth, atol=2e-4)


def test_a_deformed_body_on_the_ground_casts_its_shadow(tmp_path):
    """The test ball placed on the ground, rendered as a deformed frame (its rest cage): a ground pixel away
    from it shows Lambert's shade of its checker colour, the ground under it toward the light is darker."""
    asset = load_asset(make_asset(tmp_path))
    placement = place_on_ground(asset.outer_mesh().vertices, size=0.3)
    look = WorldLook(light=(0.0, 0.0, 1.0))  # straight down: the shadow is right under the ball
    field, cage = load_field(asset, "cpu"), load_or_build_cage(asset)
    renderer = DeformedRenderer(asset, field, cage, "cpu", None, look, placement)
    sampler, to_rest = renderer._frame(renderer.cage.vertices)

    def visibility(o, d):
        return transmittance(renderer.field, o, d, sampler, to_rest)

    backdrop = world_backdrop(look, placement, visibility)
    points = np.array([[0.005, 0.007, 0.0], [0.53, 0.37, 0.0]])
    eyes = points + np.array([0.0, -1.0, 0.4])
    o = torch.tensor(placement.to_asset(eyes), dtype=torch.float32)
    d = torch.tensor((points - eyes) @ placement.rotation, dtype=torch.float32)
    shade = (backdrop(o, d).double().numpy() / [checker_albedo(look, x, y) for x, y, _ in points]).mean(1)
    assert shade[1] == pytest.approx(open_shade(look), abs=1e-5)
    assert look.ambient <= shade[0] < look.ambient + 0.25 * look.diffuse  # the ball lets 13% through
    image, stats = renderer.render(camera(EYE, size=24), 0, renderer.cage.vertices)
    assert image.shape == (24, 24, 3) and stats["world_ms"] > 0 and not np.allclose(image[-1], 1.0)
    # the frames' record holds the world; views at rest keep the record they had
    world = world_record((look, placement, Obstacles()))
    assert renderer_identity(asset, 1, None) == renderer_identity(asset)
    assert renderer_identity(asset, 1, world) != renderer_identity(asset)


def test_motions_standing_on_a_ground_show_it_by_default():
    placement = PLACEMENT.as_dict()
    legacy = SimpleNamespace(placement={}, settings={}, path=None)
    floating = SimpleNamespace(placement=placement, settings={"drop_height": None}, path=None)
    dropped = SimpleNamespace(placement=placement, settings={"drop_height": 0.1}, path=None)
    windy = SimpleNamespace(placement=placement, settings={}, path=None)
    assert motion_world(legacy) is None and motion_world(legacy, LOOK) is None
    assert not motion_world(floating)[0].ground and not motion_world(floating, LOOK)[0].ground
    assert motion_world(dropped)[0] == WorldLook() and motion_world(windy, LOOK)[0] == LOOK
    assert not motion_world(dropped, WorldLook(ground=False))[0].ground
    np.testing.assert_allclose(motion_world(windy)[1].rotation, PLACEMENT.rotation)


def test_world_options_are_checked_and_make_the_look():
    look = WorldSettings(ground_colors=(0, 0, 0, 1, 1, 1), light=(1, 0, 1), sky=(0.5, 0.5, 0.5)).look(False)
    assert look.ground_colors == ((0, 0, 0), (1, 1, 1)) and look.light == (1, 0, 1) and not look.ground
    assert look.zenith == look.horizon == (0.5, 0.5, 0.5)
    for bad in ({"light": (0.0, 0.0, 0.0)}, {"sky": (1.0, 2.0, 0.0)}, {"ground_colors": (0.1,) * 3}):
        with pytest.raises(SettingError, match=next(iter(bad))):
            WorldSettings(**bad)
    with pytest.raises(ValueError, match="square"):
        WorldLook(square=0.0)
