"""shellsim.film.cameras: world cameras of a motion against the pinhole model in closed form, and a fixed
camera at rest against the same view given in the asset's frame."""

from __future__ import annotations

import json
import math
import types

import numpy as np
import pytest
import torch
from PIL import Image
from scenes import look_at

from neural.data import camera_rays, load_camera_file
from shellsim.film.cameras import (
    CAMERAS,
    FOLLOW_SECONDS,
    CameraSettings,
    MotionTrack,
    default_scene_camera,
    mass_weights,
    motion_track,
    scene_shot,
)
from shellsim.film.motion_frames import asset_camera
from shellsim.shot.spec import CameraKeyframe, CameraSpec, SceneError
from shellsim.world import CAMERA_PRESETS, Placement, up_rotation

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
        if camera in CAMERA_PRESETS:  # framed tightly: the box reaches an edge of the image within the margin
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
    from shellsim.film.motion_frames import render_motion
    from shellsim.motion.format import Motion, save_motion
    from shellsim.tetcage.geometry import cage_digest
    from shellsim.tetcage.store import load_cage

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


def scene_tracks(n: int = 11, fps: float = 10.0) -> dict[str, MotionTrack]:
    """Two bodies of a scene: ``a`` swaying along x (:func:`swaying_track`), ``b`` a 0.1 m cube sliding
    along +y at 0.3 m/s; "" the track of both together."""
    a = swaying_track(n)
    times = np.arange(n) / fps
    lo = np.array([0.3, 0.0, 0.0]) + np.outer(times, [0.0, 0.3, 0.0])
    b = MotionTrack(lo, lo + 0.1, lo + 0.05, times)
    a = MotionTrack(a.lo, a.hi, a.centre, times)
    both = MotionTrack(np.minimum(a.lo, b.lo), np.maximum(a.hi, b.hi), 0.5 * (a.centre + b.centre), times)
    return {"a": a, "b": b, "": both}


def hand_look_at(eye, target) -> np.ndarray:
    """(4, 4) OpenGL camera-to-world of a camera at ``eye`` looking at ``target``, image up toward +z."""
    back = (np.asarray(eye) - target) / np.linalg.norm(np.asarray(eye) - target)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([right, np.cross(back, right), back], axis=1)
    c2w[:3, 3] = eye
    return c2w


def test_a_fixed_scene_camera_is_the_look_at_of_its_position_and_target():
    tracks = scene_tracks()
    spec = CameraSpec(name="c", kind="fixed", position=(1.0, -2.0, 0.5), target=(0.1, 0.2, 0.3))
    shot = scene_shot(spec, tracks, W, H)
    assert shot.c2w.shape == (11, 4, 4) and shot.name == "c"
    assert shot.focal == pytest.approx(0.5 * W / math.tan(math.radians(20.0)))
    np.testing.assert_allclose(
        shot.c2w, np.broadcast_to(hand_look_at(spec.position, spec.target), (11, 4, 4))
    )
    centre0 = 0.5 * (tracks[""].lo[0] + tracks[""].hi[0])  # no target: the bodies' box centre at frame 0
    untargeted = scene_shot(CameraSpec(name="c", kind="fixed", position=(1.0, -2.0, 0.5)), tracks, W, H)
    np.testing.assert_allclose(untargeted.c2w[7], hand_look_at(spec.position, centre0))
    above = CameraSpec(name="c", kind="fixed", position=(0.0, 0.0, 2.0), target=(0.0, 0.0, 0.0))
    c2w = scene_shot(above, tracks, W, H).c2w[0]  # straight down: image up is +y
    np.testing.assert_allclose(c2w[:3, :3], np.diag([1.0, 1.0, 1.0]), atol=1e-12)


@pytest.mark.parametrize(
    "spec, first, last",
    [
        (CameraSpec(name="o", azimuth=30.0, degrees=90.0, elevation=15.0, distance=2.0), -15.0, 75.0),
        (
            CameraSpec(name="o", azimuth=10.0, degrees=-200.0, elevation=-30.0, target=(0, 0, 0.1)),
            110.0,
            -90.0,
        ),
        (default_scene_camera(), -60.0, -30.0),
    ],
)
def test_a_scene_orbit_turns_from_azimuth_minus_half_its_arc_to_plus_half(spec, first, last):
    tracks = scene_tracks()
    shot = scene_shot(spec, tracks, W, H)
    centre0 = 0.5 * (tracks[""].lo[0] + tracks[""].hi[0])
    target = centre0 if spec.target is None else np.asarray(spec.target)
    eyes = shot.c2w[:, :3, 3] - target
    distance = np.linalg.norm(eyes, axis=1)
    np.testing.assert_allclose(distance, distance[0], rtol=1e-12)  # one distance: a circle
    if spec.distance is not None:
        np.testing.assert_allclose(distance, spec.distance, rtol=1e-12)
    azimuth = np.degrees(np.unwrap(np.arctan2(eyes[:, 1], eyes[:, 0])))
    assert (azimuth[0] - first) % 360 == pytest.approx(0, abs=1e-9)
    assert azimuth[-1] - azimuth[0] == pytest.approx(last - first, abs=1e-9)
    np.testing.assert_allclose(np.diff(azimuth), (last - first) / 10, atol=1e-9)
    np.testing.assert_allclose(np.degrees(np.arcsin(eyes[:, 2] / distance)), spec.elevation, atol=1e-9)
    for k in range(11):  # looks at the target
        np.testing.assert_allclose(project(shot.camera_for_frame(k), [target]), [[W / 2, H / 2]], atol=1e-9)


@pytest.mark.parametrize("size", [(W, H), (H, W)])
@pytest.mark.parametrize("target", [None, (0.1, 0.1, 0.3)])
def test_a_framed_scene_orbit_keeps_every_body_in_view_at_every_frame_and_no_farther(size, target):
    tracks = scene_tracks()
    w, h = size
    shot = scene_shot(CameraSpec(name="o", degrees=120.0, elevation=35.0, target=target), tracks, w, h)
    box = corners(tracks[""].lo.min(0), tracks[""].hi.max(0))  # every body over the whole motion
    room = []
    for k in range(11):
        pixels = project(shot.camera_for_frame(k), box)
        assert (pixels >= 0).all() and (pixels[:, 0] <= w).all() and (pixels[:, 1] <= h).all(), k
        room.append((np.minimum(pixels, [w, h] - pixels) / [w / 2, h / 2]).min())
    assert min(room) < 0.06  # the least distance: at its tightest frame a corner reaches an edge's margin


def test_a_scene_follow_camera_keeps_its_offset_from_the_smoothed_centre_of_mass():
    tracks = scene_tracks(n=150, fps=30.0)  # 5 s: 10 time constants
    b = tracks["b"]  # at constant velocity v
    v, dt = np.array([0.0, 0.3, 0.0]), 1 / 30
    # exponential smoothing of a ramp: the lag behind it grows to v dt (1 - a) / a
    a = 1 - math.exp(-dt / FOLLOW_SECONDS)
    lag = np.outer(dt * (1 - a) * (1 - (1 - a) ** np.arange(150)) / a, v)
    position = np.array([1.2, -0.8, 0.6])
    for target, offset in ((None, position - b.centre[0]), ((0.0, 0.0, 0.2), position - [0.0, 0.0, 0.2])):
        spec = CameraSpec(name="f", kind="follow", position=tuple(position), target=target, body="b")
        shot = scene_shot(spec, tracks, W, H)
        np.testing.assert_allclose(shot.c2w[:, :3, 3], b.centre - lag + offset, atol=1e-12)
        np.testing.assert_allclose(shot.c2w[:, :3, :3], np.broadcast_to(shot.c2w[0, :3, :3], (150, 3, 3)))
        np.testing.assert_allclose(shot.c2w[0], hand_look_at(b.centre[0] + offset, b.centre[0]), atol=1e-12)
        for j in (0, 30, 149):  # looking at the smoothed centre
            view = shot.camera_for_frame(j)
            np.testing.assert_allclose(project(view, [b.centre[j] - lag[j]]), [[W / 2, H / 2]], atol=1e-8)
        # once smoothed (the last second), the camera keeps the offset less a constant lag
        steady = b.centre[-30:] + offset - shot.c2w[-30:, :3, 3]
        np.testing.assert_allclose(steady, np.tile(v * dt * (1 - a) / a, (30, 1)), rtol=1e-3, atol=1e-12)


@pytest.mark.parametrize("kind", CAMERA_PRESETS)
def test_a_preset_scene_camera_is_the_presets_shot_over_every_body(kind):
    tracks = scene_tracks()
    spec = CameraSpec(name="p", kind=kind, fov=50.0, elevation=35.0)
    shot = scene_shot(spec, tracks, W, H)
    settings = CameraSettings(camera=kind, fov=50.0, elevation=35.0).shot(tracks[""], W, H)
    np.testing.assert_array_equal(shot.c2w, settings.c2w)
    assert (shot.focal, shot.width, shot.height, shot.name) == (settings.focal, W, H, "p")
    box = corners(tracks[""].lo.min(0), tracks[""].hi.max(0))  # every body over the whole motion
    for k in range(11):
        pixels = project(shot.camera_for_frame(k), box)
        assert (pixels >= 0).all() and (pixels[:, 0] <= W).all() and (pixels[:, 1] <= H).all(), k
    back = shot.c2w[0, :3, 2]
    elevation = 35.0 if CAMERA_PRESETS[kind][1] is None else CAMERA_PRESETS[kind][1]
    assert math.degrees(math.asin(back[2])) == pytest.approx(elevation, abs=1e-9)


PATH = (
    CameraKeyframe(0.3, (1.0, -1.0, 0.5), (0.0, 0.0, 0.1)),
    CameraKeyframe(0.8, (1.5, 0.0, 0.8), (0.1, 0.0, 0.2)),
    CameraKeyframe(1.2, (0.5, 1.2, 0.3), (0.0, 0.1, 0.0)),
    CameraKeyframe(1.5, (-0.8, 0.8, 1.5), (0.0, 0.0, 0.2)),
)


def test_a_scene_path_passes_through_every_keyframe_and_holds_outside_them():
    tracks = scene_tracks(n=21)  # frames at 0, 0.1, ..., 2 s
    shot = scene_shot(CameraSpec(name="p", kind="path", keyframes=PATH), tracks, W, H)
    times = tracks[""].times
    for key in PATH:
        k = int(np.flatnonzero(times == key.time)[0])
        np.testing.assert_array_equal(shot.c2w[k, :3, 3], key.position)
        np.testing.assert_allclose(shot.c2w[k], hand_look_at(key.position, key.target), atol=1e-12)
    for k in range(4):  # before the first keyframe (0.3 s) and after the last (1.5 s): held
        np.testing.assert_array_equal(shot.c2w[k], shot.c2w[3])
    for k in range(15, 21):
        np.testing.assert_array_equal(shot.c2w[k], shot.c2w[15])
    # halfway through each interval, the cubic Hermite (p_i + p_i+1) / 2 + h (m_i - m_i+1) / 8 of Catmull-Rom
    # tangents m_i = (p_i+1 - p_i-1) / (t_i+1 - t_i-1), zero at the ends (clamped)
    t, p = np.array([key.time for key in PATH]), np.array([key.position for key in PATH])
    m = np.zeros_like(p)
    m[1:-1] = (p[2:] - p[:-2]) / (t[2:] - t[:-2])[:, None]
    h = np.diff(t)[:, None]
    halves = MotionTrack(np.zeros((3, 3)), np.ones((3, 3)), np.zeros((3, 3)), 0.5 * (t[1:] + t[:-1]))
    eyes = scene_shot(CameraSpec(name="p", kind="path", keyframes=PATH), {"": halves}, W, H).c2w[:, :3, 3]
    np.testing.assert_allclose(eyes, 0.5 * (p[:-1] + p[1:]) + h * (m[:-1] - m[1:]) / 8, atol=1e-12)


def test_a_two_keyframe_path_is_a_smoothstep():
    keys = PATH[0], CameraKeyframe(1.3, (2.0, 1.0, 1.5), (0.0, 0.0, 0.1))
    tracks = scene_tracks(n=21)
    eyes = scene_shot(CameraSpec(name="p", kind="path", keyframes=keys), tracks, W, H).c2w[:, :3, 3]
    s = np.clip((tracks[""].times - 0.3) / 1.0, 0, 1)[:, None]
    np.testing.assert_allclose(eyes, keys[0].position + (3 * s**2 - 2 * s**3) * [1.0, 2.0, 1.0], atol=1e-12)


def test_a_scene_camera_standing_where_it_looks_names_the_camera():
    tracks = scene_tracks()
    centre0 = 0.5 * (tracks[""].lo[0] + tracks[""].hi[0])
    where = "scene.toml: [[camera]] #2 (c)"
    fixed = CameraSpec(name="c", kind="fixed", position=tuple(centre0), where=where)
    with pytest.raises(SceneError, match=r"^scene.toml: \[\[camera\]\] #2 \(c\) position: the camera stands"):
        scene_shot(fixed, tracks, W, H)
    swap = (  # position and target trade places: they meet halfway, at 0.5 s
        CameraKeyframe(0.0, (1.0, 0.0, 0.5), (0.0, 0.0, 0.5)),
        CameraKeyframe(1.0, (0.0, 0.0, 0.5), (1.0, 0.0, 0.5)),
    )
    with pytest.raises(
        SceneError, match=r"\(c\) keyframes: the camera stands where it looks, at \[0.5, 0, 0.5\] m"
    ):
        scene_shot(CameraSpec(name="c", kind="path", keyframes=swap, where=where), tracks, W, H)


def write_capture(path, c2w, **intrinsics) -> str:
    """A camera file at ``path`` (``transforms.json``: instant-ngp, else NeRF-synthetic) of the cameras
    ``c2w`` (M, 4, 4) in their order, without images; ``intrinsics`` its top-level keys (w, h, a focal)."""
    frames = [{"file_path": f"./r_{k}", "transform_matrix": m.tolist()} for k, m in enumerate(c2w)]
    path.write_text(json.dumps({**intrinsics, "frames": frames}))
    return str(path)


def capture_spec(path, smooth: float, fov=None) -> CameraSpec:
    where = "scene.toml: [[camera]] #1 (walk)"
    return CameraSpec(name="walk", kind="capture", path=path, body="a", smooth=smooth, fov=fov, where=where)


def rotation_z(degrees: float) -> np.ndarray:
    a = math.radians(degrees)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def test_a_capture_shot_on_its_cameras_casts_the_captures_own_rays(tmp_path):
    """Smooth 0 and a frame per camera: after the world->asset map of the asset renderer, each frame is the
    file's camera (its c2w and its pixels' rays), whatever the body's placement."""
    target = np.array([0.3, -0.2, 0.1])  # a capture with y up, the cameras going round and up and down
    angles = np.radians([0.0, 50.0, 110.0, 150.0, 230.0, 300.0])
    eyes = [target + [2.5 * math.cos(a), 0.4 + 0.3 * math.sin(3 * a), 2.0 * math.sin(a)] for a in angles]
    c2w = np.stack([look_at(eye, target, up=(0.1, 1.0, 0.0)) for eye in eyes])
    path = write_capture(tmp_path / "transforms.json", c2w, fl_x=70.0, fl_y=70.0, w=80, h=50)
    placement = Placement(1.7, up_rotation([0.3, -1.0, 0.4]), np.array([0.4, -0.3, 0.2]))
    motion = types.SimpleNamespace(placement=placement.as_dict(), path="scene.npz")
    tracks = {"": scene_tracks(n=6)[""]}
    shot = scene_shot(capture_spec(path, smooth=0.0), tracks, 80, 50, {"a": placement, "b": Placement()})
    assert shot.focal == pytest.approx(70.0) and (shot.width, shot.height, shot.name) == (80, 50, "walk")
    assert not np.allclose(shot.c2w[:, :3, 3], c2w[:, :3, 3], atol=0.1)  # in the world, not the asset frame
    capture = load_camera_file(path)
    for k in range(6):
        view = asset_camera(motion, shot.camera_for_frame(k))
        np.testing.assert_allclose(view.c2w[0], c2w[k], atol=1e-6)
        for ours, theirs in zip(camera_rays(view, 0), camera_rays(capture, k), strict=True):
            torch.testing.assert_close(ours, theirs, atol=1e-5, rtol=0)
    # at another size the horizontal field of view is the file's, unless the camera sets one
    assert scene_shot(capture_spec(path, 0.0), tracks, 40, 40, {"a": placement}).focal == pytest.approx(35.0)
    fov = scene_shot(capture_spec(path, 0.0, fov=60.0), tracks, 40, 40, {"a": placement}).focal
    assert fov == pytest.approx(20.0 / math.tan(math.radians(30.0)))


def test_a_capture_shot_between_two_cameras_moves_along_their_segment_and_turns_about_their_axis(tmp_path):
    """Two cameras, 60 degrees apart about z at one elevation: frame k of 9 is on the segment at the
    clamped Catmull-Rom smoothstep 3 s^2 - 2 s^3 of s = k / 8, turned 60 s degrees from the first camera."""
    target = np.array([0.1, 0.2, 0.3])
    eyes = target + [2.0, 0.0, 1.0], target + 3.0 * np.array([0.5, math.sqrt(0.75), 0.5])
    c2w = np.stack([look_at(eye, target) for eye in eyes])
    path = write_capture(tmp_path / "transforms_train.json", c2w, camera_angle_x=0.8, w=W, h=H)
    shot = scene_shot(capture_spec(path, smooth=0.0), {"": scene_tracks(n=9)[""]}, W, H, {"a": Placement()})
    s = np.arange(9)[:, None] / 8
    np.testing.assert_allclose(shot.c2w[:, :3, 3], eyes[0] + (3 * s**2 - 2 * s**3) * (eyes[1] - eyes[0]))
    for k in range(9):
        np.testing.assert_allclose(shot.c2w[k, :3, :3], rotation_z(60.0 * k / 8) @ c2w[0, :3, :3], atol=1e-12)
    assert shot.focal == pytest.approx(0.5 * W / math.tan(0.4))
    one = scene_shot(capture_spec(path, smooth=0.0), {"": scene_tracks(n=1)[""]}, W, H, {"a": Placement()})
    np.testing.assert_allclose(one.c2w[0, :3, 3], 0.5 * (eyes[0] + eyes[1]))  # one frame: halfway


def test_smoothing_a_zig_zag_capture_straightens_it_and_keeps_its_mean(tmp_path):
    """A walk along +x zig-zagging 5 cm sideways, its view turning 15 degrees left and right, smoothed over
    2 views: the centres' second differences and the views' turns shrink, the mean centre stays."""
    n = 16
    zig = (-1.0) ** np.arange(n)
    centres = np.stack([0.1 * np.arange(n), 0.05 * zig, np.full(n, 1.2)], 1)
    yaw = np.radians(90.0 + 15.0 * zig)
    ahead = np.stack([np.cos(yaw), np.sin(yaw), np.full(n, -0.2)], 1)
    c2w = np.stack([look_at(c, c + a) for c, a in zip(centres, ahead, strict=True)])
    path = write_capture(tmp_path / "transforms_train.json", c2w, camera_angle_x=0.8, w=W, h=H)
    tracks = {"": scene_tracks(n=n)[""]}
    shot = scene_shot(capture_spec(path, smooth=2.0), tracks, W, H, {"a": Placement()})
    smooth = shot.c2w[:, :3, 3]
    np.testing.assert_allclose(smooth.mean(0), centres.mean(0), atol=1e-12)
    second = np.linalg.norm(np.diff(smooth, 2, axis=0), axis=1)
    assert second.max() < 0.25 * np.linalg.norm(np.diff(centres, 2, axis=0), axis=1).min()
    looks = -shot.c2w[:, :3, 2]
    turns = np.degrees(np.abs(np.diff(np.arctan2(looks[:, 1], looks[:, 0]))))
    assert turns.max() < 0.25 * 30.0
    np.testing.assert_allclose(
        shot.c2w[:, :3, :3] @ shot.c2w[:, :3, :3].transpose(0, 2, 1),
        np.tile(np.eye(3), (n, 1, 1)),
        atol=1e-12,
    )
    assert np.linalg.det(shot.c2w[:, :3, :3]) == pytest.approx(np.ones(n))
    exact = scene_shot(capture_spec(path, smooth=0.0), tracks, W, H, {"a": Placement()})
    np.testing.assert_allclose(exact.c2w, c2w, atol=1e-9)


def test_a_capture_whose_file_is_gone_names_the_camera(tmp_path):
    c2w = np.stack([look_at(np.array([2.0, 0.0, k]), np.zeros(3)) for k in (0.5, 1.0)])
    path = write_capture(tmp_path / "transforms_train.json", c2w, camera_angle_x=0.8, w=W, h=H)
    tracks = {"": scene_tracks()[""]}
    with pytest.raises(ValueError, match="placements: the capture camera 'walk' needs the body 'a'"):
        scene_shot(capture_spec(path, 1.0), tracks, W, H, {"b": Placement()})
    (tmp_path / "transforms_train.json").unlink()
    with pytest.raises(SceneError) as caught:
        scene_shot(capture_spec(path, 1.0), tracks, W, H, {"a": Placement()})
    assert str(caught.value) == f"scene.toml: [[camera]] #1 (walk) path: {path}: camera file not found"
