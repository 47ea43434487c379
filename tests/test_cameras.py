"""shellsim.render.cameras: world cameras of a motion against the pinhole model in closed form, and a fixed
camera at rest against the same view given in the asset's frame."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from shellsim.render.cameras import CAMERAS, PRESETS, CameraSettings, MotionTrack, mass_weights, motion_track

W, H = 32, 20


def project(view, points) -> np.ndarray:
    """(N, 2) pixel coordinates of world ``points`` (N, 3) in the one-camera ``view`` (OpenGL axes, pixel y
    down), and asserts they lie in front of it."""
    c2w = view.c2w[0]
    local = (np.asarray(points, np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    assert (local[:, 2] < 0).all()
    depth = -local[:, 2]
    return np.stack(
        [view.cx[0] + view.fx[0] * local[:, 0] / depth, view.cy[0] - view.fy[0] * local[:, 1] / depth], 1
    )


def corners(lo, hi) -> np.ndarray:
    return np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)], np.float64)


def swaying_track(n: int = 9) -> MotionTrack:
    """A box 0.2 x 0.1 x 0.3 m on the ground, swaying along x."""
    lo = np.array([-0.1, -0.05, 0.0]) + np.outer(0.05 * np.sin(np.arange(n)), [1.0, 0.0, 0.0])
    return MotionTrack(lo, lo + [0.2, 0.1, 0.3], lo + [0.1, 0.05, 0.15], np.arange(n) / 30.0)


def test_a_fixed_camera_sees_its_look_at_point_at_the_image_centre():
    settings = CameraSettings(camera="fixed", camera_position=(1.0, -2.0, 0.5), look_at=(0.1, 0.2, 0.3))
    view = settings.shot(swaying_track(), W, H).camera_for_frame(4)
    np.testing.assert_allclose(project(view, [[0.1, 0.2, 0.3]]), [[W / 2, H / 2]], atol=1e-9)
    np.testing.assert_allclose(view.c2w[0, :3, 3], [1.0, -2.0, 0.5])
    above = CameraSettings(camera="fixed", camera_position=(0.0, 0.0, 2.0), look_at=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(-above.shot(swaying_track(), W, H).c2w[0, :3, 2], [0.0, 0.0, -1.0])


def test_the_top_preset_looks_down_and_front_and_side_look_along_the_axes():
    track = swaying_track()
    for name, forward in (("top", [0, 0, -1]), ("front", [0, 1, 0]), ("side", [-1, 0, 0])):
        c2w = CameraSettings(camera=name).shot(track, W, H).c2w
        np.testing.assert_allclose(-c2w[:, :3, 2], np.broadcast_to(forward, (len(c2w), 3)), atol=1e-12)
    np.testing.assert_allclose(
        CameraSettings(camera="top").shot(track, W, H).c2w[0, :3, 1], [0, 1, 0], atol=1e-12
    )


@pytest.mark.parametrize("camera", CAMERAS)
def test_every_frame_keeps_the_framed_box_inside_the_image(camera):
    track = swaying_track()
    position = (0.5, -1.5, 0.4) if camera == "fixed" else None
    shot = CameraSettings(camera=camera, camera_position=position).shot(track, W, H)
    for k in range(len(track.times)):
        box = (track.lo[k], track.hi[k]) if camera == "follow" else (track.lo.min(0), track.hi.max(0))
        pixels = project(shot.camera_for_frame(k), corners(*box))
        assert (pixels >= 0).all() and (pixels[:, 0] <= W).all() and (pixels[:, 1] <= H).all(), (camera, k)
        if camera in PRESETS:  # framed tightly: the box reaches an edge of the image within the margin
            room = np.minimum(pixels, [W, H] - pixels).min(axis=0) / [W / 2, H / 2]
            assert room.min() < 0.06


@pytest.mark.parametrize("degrees", [30.0, -75.0, 200.0])
def test_the_orbit_sweeps_exactly_its_arc_from_the_first_frame_to_the_last(degrees):
    track = swaying_track(7)
    shot = CameraSettings(orbit_degrees=degrees).shot(track, W, H)
    centre = 0.5 * (track.lo.min(0) + track.hi.max(0))
    eyes = shot.c2w[:, :3, 3] - centre
    azimuth = np.unwrap(np.arctan2(eyes[:, 1], eyes[:, 0]))
    assert azimuth[-1] - azimuth[0] == pytest.approx(math.radians(degrees), abs=1e-12)
    np.testing.assert_allclose(np.diff(azimuth), math.radians(degrees) / 6, atol=1e-12)
    for k in range(7):  # the orbit looks at the box's centre
        np.testing.assert_allclose(project(shot.camera_for_frame(k), [centre]), [[W / 2, H / 2]], atol=1e-9)
    default = CameraSettings().shot(track, W, H).c2w[:, :3, 3] - centre
    arc = np.arctan2(default[-1, 1], default[-1, 0]) - np.arctan2(default[0, 1], default[0, 0])
    assert arc == pytest.approx(math.radians(30.0))


def test_follow_tracks_the_smoothed_centre_of_mass_of_a_rigid_translation():
    # two tets of unequal volume: the centre of mass weighs each by its volume
    rest = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [3, 3, 3]], np.float64)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    volumes = np.array([1 / 6, abs(np.linalg.det(rest[[2, 3, 4]] - rest[1])) / 6])
    com = volumes @ rest[tets].mean(axis=1) / volumes.sum()
    n, dt, tau, v = 40, 1 / 30, 0.25, np.array([0.6, -0.2, 0.1])
    times = np.arange(n) * dt
    frames = rest + times[:, None, None] * v
    track = motion_track([frames[:17], frames[17:]], mass_weights(rest, tets), times)
    np.testing.assert_allclose(track.centre, com + times[:, None] * v, atol=1e-12)
    shot = CameraSettings(camera="follow", follow_seconds=tau).shot(track, W, H)
    a = 1 - math.exp(-dt / tau)  # exponential smoothing of a ramp: the lag grows to v dt (1 - a) / a
    lag = np.outer(dt * (1 - a) * (1 - (1 - a) ** np.arange(n)) / a, v)
    target = com + times[:, None] * v - lag
    for k in range(n):
        np.testing.assert_allclose(
            project(shot.camera_for_frame(k), [target[k]]), [[W / 2, H / 2]], atol=1e-8
        )
    np.testing.assert_allclose(np.diff(shot.c2w[:, :3, :3], axis=0), 0, atol=1e-15)  # turns never


def test_a_fixed_camera_at_rest_renders_the_asset_frame_view(tmp_path):
    """A body placed by a similarity (scale 1.7, a rotation, a translation) and at rest: a fixed world
    camera renders the image that the same camera, given in the asset's frame, renders."""
    pytest.importorskip("torch")
    from test_render_deformed import make_asset

    from neural.asset import load_asset
    from neural.data import look_at
    from shellsim.cage.store import load_cage
    from shellsim.motion.format import Motion, cage_digest, save_motion
    from shellsim.render.frames import render_motion
    from shellsim.world import Placement, up_rotation

    asset_dir = make_asset(tmp_path / "asset")
    cage = load_cage(load_asset(asset_dir).cage_path)
    rotation = up_rotation([0.3, -1.0, 0.4])
    placement = Placement(1.7, rotation, np.array([0.4, -0.3, 0.2]))
    world = placement.to_world(cage.vertices)
    motion = tmp_path / "rest.npz"
    moved = Motion(world, cage.tets, np.stack([world, world]).astype(np.float32), np.array([0.0, 0.1]))
    moved.placement, moved.cage_digest = placement.as_dict(), cage_digest(cage.vertices, cage.tets)
    save_motion(motion, moved)
    eye, target = world.mean(0) + [1.5, -2.5, 1.0], world.mean(0)
    camera = CameraSettings(camera="fixed", camera_position=tuple(eye), look_at=tuple(target))
    common = dict(frames="1:2", size=(W, H), progress=False, antialias=1)
    fixed = render_motion(asset_dir, motion, tmp_path / "fixed", camera=camera, **common)
    c2w = look_at(placement.to_asset(eye), placement.to_asset(target), rotation.T @ [0.0, 0.0, 1.0])
    cams = tmp_path / "cams.json"
    frame = {"file_path": "./v", "transform_matrix": c2w.tolist()}
    cams.write_text(
        json.dumps({"camera_angle_x": math.radians(camera.fov), "frames": [frame], "w": W, "h": H})
    )
    direct = render_motion(asset_dir, motion, tmp_path / "direct", cameras=cams, **common)
    a, b = (np.asarray(Image.open(r.frames[0]), np.int16) for r in (fixed, direct))
    assert (a != 255).any(), "the body is in view"
    assert np.abs(a - b).max() <= 1
