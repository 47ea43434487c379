"""shellsim.film: deformed-space rendering against independent truths.

The test asset is an untrained ``ShellField`` (a sphere SDF of radius 0.25 around an off-centre point with a
kernel size of 0.025, so the band between the shells is semi-transparent, and a colourful, view-dependent
radiance network), icosphere shells bracketing its surface, and a cage made by hand: a Kuhn tet grid over a
box around the shells. Truths that do not come from the renderer:

- the identity motion renders exactly like plain narrow-band rendering of the rest shells;
- moving the object rigidly and the camera with it changes nothing (translations and rotations);
- scaling the object uniformly about a point and the camera's distance with it changes nothing either:
  every deformed section is ``k`` times longer than its rest-space one, which the stretch undoes;
- a bend of the cage's upper half leaves rays through the unmoved lower cells as they were;
- samples outside a cage that cuts off part of the shells are dropped: rays through that part only show
  the background;
- the stretch of :meth:`InverseMap.map_rays` equals the brute-force ``|Phi^-1(x + eps d) - Phi^-1(x)| / eps``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from meshes import kuhn_grid, save_embedded_cage

from neural.asset import load_asset, load_field, save_asset
from neural.data import Cameras, look_at
from neural.field import FieldConfig, ShellField
from neural.field.hashgrid import HashGridConfig
from neural.metrics import psnr
from shellsim.deform.inverse_map import InverseMap, deform_points, map_points_reference
from shellsim.film.cameras import orbit_camera
from shellsim.film.renderer import DeformedRenderer
from shellsim.settings import parse_frames
from shellsim.tetcage.build import Cage, shell_digest
from shellsim.tetcage.embed import embed_points
from shellsim.tetcage.store import load_or_build_cage

CENTER = np.array([0.1, -0.2, 0.3])  # the asset's normalisation centre: the sphere's centre
SCALE = 2.0  # unit space = (x - CENTER) * SCALE; the unit sphere of radius 0.5 has world radius 0.25
SIZE = 40  # test images are SIZE x SIZE


def make_asset(root: Path, cells: int = 3) -> Path:
    """Write the test asset (module docstring) with its cage to ``root``; returns ``root``."""
    torch.manual_seed(0)
    config = FieldConfig(
        hashgrid=HashGridConfig(n_levels=4, log2_table_size=12, max_resolution=64),
        init_inv_s=20.0,
    )
    field = ShellField(config, center=tuple(CENTER), scale=SCALE)
    with torch.no_grad():  # a radiance network with strong spatial and view dependence
        field.rad[0].weight.mul_(4.0)
        field.rad[-1].weight.mul_(6.0)
    outer = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    outer.apply_translation(CENTER)
    inner.apply_translation(CENTER)
    meta = {
        "name": "ball",
        "normalisation": {"center": CENTER.tolist(), "scale": SCALE},
        "up": [0.0, 0.0, 1.0],
        "background": [1.0, 1.0, 1.0],
        "narrowband": {"delta_s": 0.01, "w_s": 0.01, "n_max": 16},
    }
    save_asset(root, field, outer, inner, meta)
    save_embedded_cage(load_asset(root), *kuhn_grid(CENTER - 0.36, CENTER + 0.36, cells)[:2])
    return root


def camera(eye, target=CENTER, up=(0.0, 0.0, 1.0), size: int = SIZE, fov_deg: float = 50.0) -> Cameras:
    """One pinhole camera at ``eye`` looking at ``target``."""
    focal = 0.5 * size / math.tan(0.5 * math.radians(fov_deg))
    c2w = look_at(np.asarray(eye, float), np.asarray(target, float), np.asarray(up, float))
    return Cameras(
        c2w[None], [focal], [focal], [size / 2], [size / 2], [size], [size], np.zeros((1, 4)), ["c"]
    )


def rotation(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` about ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def moved_camera(cameras: Cameras, rot: np.ndarray, shift: np.ndarray) -> Cameras:
    """``cameras`` (one) moved by the rigid map ``x -> rot x + shift``."""
    c2w = cameras.c2w[0].copy()
    c2w[:3, :3] = rot @ c2w[:3, :3]
    c2w[:3, 3] = rot @ c2w[:3, 3] + shift
    return Cameras(
        c2w[None],
        cameras.fx,
        cameras.fy,
        cameras.cx,
        cameras.cy,
        cameras.width,
        cameras.height,
        cameras.distortion,
        cameras.names,
    )


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    return load_asset(make_asset(tmp_path_factory.mktemp("asset")))


@pytest.fixture(scope="module")
def renderer(asset):
    return DeformedRenderer(asset, load_field(asset, "cpu"), load_or_build_cage(asset), "cpu")


EYE = CENTER + np.array([0.9, -0.6, 0.5])


def test_identity_motion_renders_like_the_rest_renderer(renderer):
    view = camera(EYE)
    rest, rest_stats = renderer.render(view, 0)
    moved, stats = renderer.render(view, 0, renderer.cage.vertices)
    assert rest.shape == (SIZE, SIZE, 3)
    assert rest.std() > 0.05  # not a flat image: colours vary over the ball
    assert (rest_stats["counts"] > 0).mean() > 0.2  # the ball fills a good part of the view
    assert stats["dropped_samples"] == 0  # the cage contains the shells
    np.testing.assert_array_equal(stats["counts"], rest_stats["counts"])
    assert psnr(moved, rest) >= 60  # measured ~150 dB: equal up to float32 rounding
    assert all(stats[f"{k}_ms"] > 0 for k in ("build", "sample", "map", "shade"))


@pytest.mark.parametrize(
    "rot, shift",
    [
        (np.eye(3), np.array([0.4, -0.3, 0.25])),  # translation
        (rotation([0.3, -0.5, 1.0], 0.9), np.zeros(3)),  # rotation about the world origin (off-centre)
        (rotation([1.0, 0.2, 0.0], -2.0), np.array([-0.2, 0.5, 0.1])),  # a general rigid motion
    ],
)
def test_rigid_motion_with_the_camera_changes_nothing(renderer, rot, shift):
    view = camera(EYE)
    rest, _ = renderer.render(view, 0)
    positions = renderer.cage.vertices @ rot.T + shift
    moved, stats = renderer.render(moved_camera(view, rot, shift), 0, positions)
    assert stats["dropped_samples"] == 0
    assert psnr(moved, rest) >= 50  # measured ~140 dB


def test_uniform_scaling_is_undone_by_the_stretch(renderer):
    """Object scaled by k about a point, camera distance too: the same image. Without the stretch the
    deformed sections would be k times too long in rest space and the fuzzy band too opaque."""
    k = 1.6
    view = camera(EYE)
    rest, _ = renderer.render(view, 0)
    pivot = CENTER + np.array([0.05, 0.0, -0.1])
    positions = pivot + k * (renderer.cage.vertices - pivot)
    scaled_view = camera(pivot + k * (EYE - pivot), target=pivot + k * (CENTER - pivot))
    moved, stats = renderer.render(scaled_view, 0, positions)
    assert stats["samples_per_pixel"] > renderer.render(view, 0)[1]["samples_per_pixel"]  # more, shorter
    assert psnr(moved, rest) >= 50  # measured ~95 dB; ~33 dB with the stretch left out


def test_a_bend_moves_only_what_it_moves(renderer):
    """A non-rigid bend of the upper half of the cage changes a side view, while rays from straight below,
    which meet only the unmoved bottom layer of cage cells before the inner shell stops them, keep their
    colours."""
    verts = renderer.cage.vertices
    h = np.clip((verts[:, 2] - CENTER[2]) / 0.36, 0, None)  # 0 on and below the centre plane
    positions = verts + np.stack([0.3 * h**2, np.zeros_like(h), np.zeros_like(h)], 1)
    side = camera(EYE)
    assert psnr(renderer.render(side, 0, positions)[0], renderer.render(side, 0)[0]) < 40  # rigid: >= 50
    below = camera(CENTER - np.array([0.0, 0.0, 1.0]), up=(0.0, 1.0, 0.0))
    rest, _ = renderer.render(below, 0)
    bent, _ = renderer.render(below, 0, positions)
    centre = slice(SIZE // 2 - 5, SIZE // 2 + 5)
    assert rest[centre, centre].std() > 0.01
    np.testing.assert_allclose(bent[centre, centre], rest[centre, centre], atol=2e-3)


def test_deformed_shells_are_the_barycentric_interpolation(renderer):
    """The Warp meshes of a deformed frame hold every shell vertex where deform_points puts it (up to their
    float32 rounding); a frame of the wrong shape is refused."""
    c = renderer.cage
    positions = c.vertices + 0.05 * np.sin(4 * c.vertices[:, [2, 0, 1]])
    renderer._frame(positions)
    caster = renderer._deformed
    for which, tet, bary in (("outer", c.outer_tet, c.outer_bary), ("inner", c.inner_tet, c.inner_bary)):
        expected = deform_points(positions, c.tets, tet, bary) - caster.center
        points = caster._scenes[which].points.numpy()
        np.testing.assert_allclose(points, expected, rtol=0, atol=1e-7 * np.abs(expected).max())
    with pytest.raises(ValueError, match="positions"):
        renderer._frame(positions[:, :2])


def test_samples_outside_the_cage_are_dropped(asset, renderer):
    """A cage that cuts off the top of the shells: seen from straight above, central rays meet only the
    cut-off cap before the inner shell stops them, so they show the background."""
    lo, hi = CENTER - 0.36, CENTER + np.array([0.36, 0.36, 0.1])
    verts, tets, _ = kuhn_grid(lo, hi, 3)
    outer, inner = renderer.outer, renderer.inner
    embedded = [*embed_points(verts, tets, outer.vertices), *embed_points(verts, tets, inner.vertices)]
    cage = Cage(verts, tets, *embedded, shell_digest(outer, inner))
    cut = DeformedRenderer(asset, renderer.field, cage, "cpu")
    above = camera(CENTER + np.array([0.0, 0.0, 1.2]), up=(0.0, 1.0, 0.0))
    rest, _ = cut.render(above, 0)
    image, stats = cut.render(above, 0, verts)
    centre = slice(SIZE // 2 - 4, SIZE // 2 + 4)
    assert stats["dropped_samples"] > 0
    assert rest[centre, centre].max() < 0.99
    np.testing.assert_array_equal(image[centre, centre], 1.0)


def test_stretch_matches_brute_force(rng):
    verts, tets, _ = kuhn_grid(np.zeros(3), np.ones(3), 3)
    deformed = verts + 0.08 * np.sin(3 * verts[:, [1, 2, 0]])
    x = deformed[tets[rng.integers(0, len(tets), 200)]].mean(axis=1)  # tet centroids: inside
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    eps = 1e-3
    _, d_rest, stretch, inside = InverseMap(deformed, tets, verts).map_rays(x, d, eps=eps)
    x0, _ = map_points_reference(deformed, tets, verts, x)
    x1, ok = map_points_reference(deformed, tets, verts, x + eps * d)
    assert inside.all() and ok.all()
    np.testing.assert_allclose(stretch, np.linalg.norm(x1 - x0, axis=1) / eps, rtol=1e-9)
    np.testing.assert_allclose(d_rest, (x1 - x0) / np.linalg.norm(x1 - x0, axis=1, keepdims=True), atol=1e-9)


def test_orbit_camera_looks_at_the_centre():
    view = orbit_camera(CENTER, 2.0, (0.0, 0.0, 1.0), 0.7, 30, 20)
    eye, forward = view.c2w[0, :3, 3], -view.c2w[0, :3, 2]
    np.testing.assert_allclose(np.linalg.norm(eye - CENTER), 2.0)
    np.testing.assert_allclose(forward, (CENTER - eye) / 2.0, atol=1e-12)
    assert math.degrees(math.asin((eye - CENTER)[2] / 2.0)) == pytest.approx(25.0)
    assert (view.width[0], view.height[0]) == (30, 20)


@pytest.mark.parametrize(
    "spec, expected",
    [
        (None, range(10)),
        ("2:5", range(2, 5)),
        (":3", range(3)),
        ("7:", range(7, 10)),
        ("4", range(4, 5)),
        ("::2", [0, 2, 4, 6, 8]),
        ("1:8:3", [1, 4, 7]),
        ("1:9:4", [1, 5]),
        ("3::5", [3, 8]),
        (":4:1", [0, 1, 2, 3]),
        ("2:5:10", [2]),
    ],
)
def test_parse_frames(spec, expected):
    assert list(parse_frames(spec, 10)) == list(expected)


@pytest.mark.parametrize(
    "spec", ["a:b", "1:2:3:4", "5:3", "0:11", "-1:2", "10", "::0", "0:5:-1", "1:5:", "::x", "::1.5", "9:9:2"]
)
def test_parse_frames_rejects_bad_specs(spec):
    from shellsim.errors import SettingError

    with pytest.raises(SettingError, match=f"^frames {spec!r}: ") as err:  # the CLI shows --frames instead
        parse_frames(spec, 10)
    assert err.value.name == "frames"


@pytest.mark.parametrize("spec", ["::0", "1:2:3:4", "1:5:"])
def test_a_bad_step_says_what_a_frames_spec_is(spec):
    from shellsim.errors import SettingError

    with pytest.raises(SettingError, match=r"expected START:END\[:STEP\] .*STEP a positive integer"):
        parse_frames(spec, 10)
