"""Cameras for rendering motions, in world metres (z up): fixed (a position and a look-at point, or a preset
framed to the motion), an orbit over a given arc per clip, or a camera that follows the body's centre of mass.

:class:`CameraSettings` is the one vocabulary (its option fields are those of ``render``, ``simulate`` and
``sweep``, copied by :func:`camera_option`); :func:`motion_track` sums a motion up for it (each frame's box
and centre of mass); :meth:`CameraSettings.shot` turns both into a :class:`Shot`, whose
:meth:`Shot.camera_for_frame` is a pinhole camera in the world's frame. The asset renderer maps it into the
asset's frame (:func:`shellsim.film.motion_frames.asset_camera`); the pyvista surface renderer draws the
world.
:func:`scene_shot` is the :class:`Shot` of a scene file's ``[[camera]]`` (:func:`default_scene_camera` where
the file has none); a ``capture`` camera moves along a camera file's own cameras (:func:`capture_path`).
:func:`orbit_camera` and :func:`orbit_framing` are one camera about a point and the distance of a sphere.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from neural.errors import InputError
from shellsim.errors import SettingError
from shellsim.settings import check_choice, check_range, floats, option
from shellsim.world import CAMERA_PRESETS, UP

if TYPE_CHECKING:
    from shellsim.shot.spec import CameraSpec
    from shellsim.world import Placement

#: (W, H) of a motion's frames when neither a size nor a camera file gives one.
VIDEO_SIZE = (512, 512)
#: Jittered rays per pixel of a motion's frames by default (:func:`shellsim.film.antialias.adaptive`);
#: rest views take 1, the pixel-centre rays that ``shellsim eval`` scores.
MOTION_ANTIALIAS = 4
MAX_ANTIALIAS = 64  # jittered rays per pixel at most


def check_antialias(rays: int) -> None:
    """:class:`SettingError` for ``antialias`` unless ``rays`` lies in 1 to :data:`MAX_ANTIALIAS`."""
    if not 1 <= rays <= MAX_ANTIALIAS:
        raise SettingError("antialias", f"expected 1 to {MAX_ANTIALIAS} rays per pixel, got {rays}")


#: Horizontal field of view of the cameras, degrees, and the elevation above the horizon of the orbit, the
#: follow camera and the three-quarter preset.
ORBIT_FOV_DEG = 40.0
ORBIT_ELEVATION_DEG = 25.0
#: The orbit's arc over a clip, degrees; the follow camera's smoothing time constant, seconds.
ORBIT_DEGREES = 30.0
FOLLOW_SECONDS = 0.5
#: Room around the framed box: each half field of view is used up to 1 / MARGIN of its tangent.
MARGIN = 1.05
#: Presets (:data:`shellsim.world.CAMERA_PRESETS`) look at the centre of the framed box; an elevation None is
#: the settings' elevation.
CAMERAS = ("orbit", "fixed", "follow", *CAMERA_PRESETS)
#: The fields of :class:`CameraSettings` that are command-line options of the jobs that render motions.
OPTIONS = ("camera", "orbit_degrees", "camera_position", "look_at")


@dataclass(frozen=True)
class CameraSettings:
    """The camera of a motion's frames, in world metres; ``fov`` (horizontal, degrees), ``elevation``
    (degrees above the horizon) and ``follow_seconds`` (the follow camera's smoothing time constant) are
    settable from Python only."""

    camera: str | None = option(
        help="camera of a motion's frames, in world metres (z up): orbit (an arc of --orbit-degrees about "
        "the motion), fixed (at --camera-position looking at --look-at), follow (tracks the body's centre of "
        "mass smoothly) or a preset that keeps the whole motion in view: front (from -y), side (from +x), "
        "top (from +z), three-quarter",
        choices=CAMERAS,
        shown_default="orbit",
    )
    orbit_degrees: float | None = option(
        help="the orbit's arc over the whole clip in degrees (360: one turn)",
        shown_default=f"{ORBIT_DEGREES:g} degrees with the orbit camera",
    )
    camera_position: tuple[float, float, float] | None = option(
        help="X,Y,Z in metres of the fixed camera", parse=floats(3), metavar="X,Y,Z"
    )
    look_at: tuple[float, float, float] | None = option(
        help="X,Y,Z in metres the fixed camera looks at",
        parse=floats(3),
        metavar="X,Y,Z",
        shown_default="the centre of the motion's box",
    )
    fov: float = ORBIT_FOV_DEG
    elevation: float = ORBIT_ELEVATION_DEG
    follow_seconds: float = FOLLOW_SECONDS

    def __post_init__(self):
        if self.camera is not None:
            check_choice("camera", self.camera, CAMERAS)
        if self.orbit_degrees is not None:
            if self.kind != "orbit":
                raise SettingError("orbit_degrees", f"sets an orbit's arc, not the {self.kind} {{camera}}")
            check_range("orbit_degrees", self.orbit_degrees, -3600, 3600, "an arc in degrees")
        if (self.kind == "fixed") != (self.camera_position is not None):
            raise SettingError("camera_position", "needed by the fixed {camera}, and by no other")
        if self.look_at is not None:
            if self.kind != "fixed":
                raise SettingError("look_at", "sets where the fixed {camera} looks")
            if np.allclose(self.look_at, self.camera_position):
                raise SettingError("look_at", "must differ from {camera_position}")
        check_range("fov", self.fov, 0, 180, "a field of view in degrees", "()")
        check_range("elevation", self.elevation, -90, 90, "an angle in degrees")
        check_range("follow_seconds", self.follow_seconds, 0, math.inf, "a time in seconds", "()")

    @classmethod
    def of(cls, settings) -> CameraSettings:
        """The camera of a job's ``settings``, which declare the :data:`OPTIONS` (:func:`camera_option`)."""
        return cls(**{name: getattr(settings, name) for name in OPTIONS})

    @property
    def kind(self) -> str:
        """The camera: ``camera``, else "orbit"."""
        return self.camera or "orbit"

    def shot(self, track: MotionTrack, width: int, height: int, up=UP, box=None) -> Shot:
        """The :class:`Shot` of this camera over the motion summed up by ``track``, ``width`` x ``height``
        pixels, ``up`` (3,) the world's up axis. Orbit and presets keep ``box`` (2, 3) (default: the box of
        every frame) in view at every frame; follow keeps each frame's box in view."""
        up = _unit(up)
        n = len(track.times)
        box = np.stack([track.lo.min(0), track.hi.max(0)]) if box is None else np.asarray(box, np.float64)
        centre = np.broadcast_to(box.mean(0), (n, 3))
        corners = np.broadcast_to(_corners(box), (n, 8, 3))
        focal = 0.5 * width / math.tan(0.5 * math.radians(self.fov))
        if self.kind == "fixed":
            target = centre[0] if self.look_at is None else np.asarray(self.look_at, np.float64)
            c2w = _look_at(np.asarray(self.camera_position, np.float64), target, up)
            return Shot(np.broadcast_to(c2w, (n, 4, 4)).copy(), focal, width, height, self.kind)
        elevation = self.elevation
        if self.kind == "orbit":
            degrees = ORBIT_DEGREES if self.orbit_degrees is None else self.orbit_degrees
            steps = np.arange(n) / (n - 1) if n > 1 else np.full(1, 0.5)
            azimuth = CAMERA_PRESETS["three-quarter"][0] + degrees * (steps - 0.5)
        elif self.kind == "follow":
            azimuth = np.full(n, CAMERA_PRESETS["three-quarter"][0])
            centre = smoothed(track.centre, track.times, self.follow_seconds)
            corners = np.stack([_corners(b) for b in np.stack([track.lo, track.hi], 1)])
        else:
            azimuth, preset_elevation = CAMERA_PRESETS[self.kind]
            azimuth = np.full(n, azimuth)
            elevation = self.elevation if preset_elevation is None else preset_elevation
        rotation = _rotations(up, np.radians(azimuth), math.radians(elevation))  # (n, 3, 3)
        distance = _fit_distance(corners, centre, rotation, 0.5 * width / focal, 0.5 * height / focal)
        c2w = np.tile(np.eye(4), (n, 1, 1))
        c2w[:, :3, :3] = rotation
        c2w[:, :3, 3] = centre + distance[:, None] * rotation[:, :, 2]
        return Shot(c2w, focal, width, height, self.kind)


def scene_shot(
    spec: CameraSpec,
    tracks: dict[str, MotionTrack],
    width: int,
    height: int,
    placements: dict[str, Placement] | None = None,
) -> Shot:
    """The :class:`Shot` of the scene camera ``spec`` (one ``[[camera]]`` of a scene file, z up) over a
    scene's motion, ``width`` x ``height`` pixels, horizontal field of view ``spec.fov``: ``tracks`` maps each
    body's name to its :class:`MotionTrack` and "" to the track of all the bodies together (the same times);
    ``placements`` maps each body's name to the :class:`~shellsim.world.Placement` of its asset's frame in the
    world (needed by a capture camera only).

    - orbit: about ``target`` (None: the centre of the bodies' box at frame 0), its azimuth going linearly
      from ``azimuth - degrees / 2`` at the first frame to ``azimuth + degrees / 2`` at the last, at one
      distance (None: the least that keeps the box of every body over the whole motion in view at every
      frame, :func:`_fit_distance`);
    - fixed: at ``position`` looking at ``target`` (None: as the orbit's);
    - follow: at the :func:`smoothed` (:data:`FOLLOW_SECONDS`) centre of mass of ``body`` plus the offset
      ``position - target`` (None: the body's centre of mass at frame 0), looking at that smoothed centre;
    - path: position and target of :func:`_spline` through the keyframes at each frame's time;
    - a preset of :data:`~shellsim.world.CAMERA_PRESETS`: the shot of ``CameraSettings(camera=kind,
      fov=spec.fov, elevation=spec.elevation)`` over ``tracks[""]``, keeping every body over the whole motion
      in view;
    - capture: along the cameras of the file ``spec.path`` (:func:`shellsim.shot.file.capture_cameras`, in
      the asset's frame of ``spec.body``) once over the shot, :func:`capture_path` with ``spec.smooth``,
      each camera-to-world moved into the world by ``placements[spec.body]`` (rotation ``R c2w``, position
      :meth:`~shellsim.world.Placement.to_world`): the inverse of
      :func:`shellsim.film.motion_frames.asset_camera`, so that a frame on a camera of the file casts that
      camera's rays; ``spec.fov`` None: the median of the cameras' own horizontal fields of view. The
      shot's pinhole keeps neither their principal points nor ``fy`` nor their distortion.

    A camera that stands where it looks at some frame, or a capture's camera file that cannot be read, is a
    :class:`~shellsim.shot.spec.SceneError` naming the spec's ``where``."""
    from shellsim.shot.file import capture_cameras, problem

    up, every = _unit(UP), tracks[""]
    if spec.kind in CAMERA_PRESETS:
        preset = CameraSettings(camera=spec.kind, fov=spec.fov, elevation=spec.elevation)
        return dataclasses.replace(preset.shot(every, width, height), name=spec.name)
    n = len(every.times)
    if spec.kind == "capture":
        if placements is None or spec.body not in placements:
            raise ValueError(f"placements: the capture camera {spec.name!r} needs the body {spec.body!r}")
        try:
            cameras = capture_cameras(spec.path, width, height)
        except InputError as err:
            raise problem(spec.where, "path", str(err)) from None
        placement = placements[spec.body]
        c2w = capture_path(cameras.c2w, n, spec.smooth)
        c2w[:, :3, :3] = placement.rotation @ c2w[:, :3, :3]
        c2w[:, :3, 3] = placement.to_world(c2w[:, :3, 3])
        fov = spec.fov
        focal = float(np.median(cameras.fx)) if fov is None else 0.5 * width / math.tan(math.radians(fov / 2))
        return Shot(c2w, focal, width, height, spec.name)
    focal = 0.5 * width / math.tan(0.5 * math.radians(spec.fov))
    centre = 0.5 * (every.lo[0] + every.hi[0])
    target = centre if spec.target is None else np.asarray(spec.target, np.float64)
    if spec.kind == "orbit":
        steps = np.arange(n) / (n - 1) if n > 1 else np.full(1, 0.5)
        azimuth = np.radians(spec.azimuth + spec.degrees * (steps - 0.5))
        rotation = _rotations(up, azimuth, math.radians(spec.elevation))
        distance = spec.distance
        if distance is None:
            box = _corners(np.stack([every.lo.min(0), every.hi.max(0)]))
            tan_x, tan_y = 0.5 * width / focal, 0.5 * height / focal
            distance = _fit_distance(np.tile(box, (n, 1, 1)), np.tile(target, (n, 1)), rotation, tan_x, tan_y)
            distance = distance.max()
        c2w = np.tile(np.eye(4), (n, 1, 1))
        c2w[:, :3, :3] = rotation
        c2w[:, :3, 3] = target + distance * rotation[:, :, 2]
        return Shot(c2w, focal, width, height, spec.name)
    if spec.kind == "fixed":
        eyes, targets = np.tile(spec.position, (n, 1)), np.tile(target, (n, 1))
    elif spec.kind == "follow":
        body = tracks[spec.body]
        start = body.centre[0] if spec.target is None else target
        targets = smoothed(body.centre, body.times, FOLLOW_SECONDS)
        eyes = targets + (np.asarray(spec.position, np.float64) - start)
    else:
        times = [k.time for k in spec.keyframes]
        eyes = _spline(times, [k.position for k in spec.keyframes], every.times)
        targets = _spline(times, [k.target for k in spec.keyframes], every.times)
    met = np.flatnonzero(~(np.linalg.norm(eyes - targets, axis=1) > 0))
    if met.size:
        k = met[0]
        raise problem(
            spec.where,
            "keyframes" if spec.kind == "path" else "position",
            f"the camera stands where it looks, at {_point(targets[k])} m, at t = {every.times[k]:g} s",
        )
    c2w = np.stack([_look_at(eye, at, up) for eye, at in zip(eyes, targets, strict=True)])
    return Shot(c2w, focal, width, height, spec.name)


def capture_path(c2w, frames: int, smooth: float) -> np.ndarray:
    """(frames, 4, 4) OpenGL camera-to-world along the cameras ``c2w`` (M, 4, 4), M >= 2, in their order.

    Their centres and their back and image-up axes (columns 2 and 1) are smoothed along the path by a
    Gaussian of ``smooth`` views (its standard deviation; 0: none), reflected at the ends so that the mean
    centre is kept, then made orthonormal keeping the viewing direction (right = up x back). Frame k is at
    ``u_k = k (M - 1) / (frames - 1)`` views (one frame: halfway), the first frame on the first camera and
    the last on the last: its centre the Catmull-Rom :func:`_spline` through the centres at ``u_k``, its
    rotation the slerp of the rotations of the views either side; exactly camera ``u_k`` when ``u_k`` is
    whole and ``smooth`` is 0."""
    from scipy.ndimage import gaussian_filter1d
    from scipy.spatial.transform import Rotation, Slerp

    c2w = np.asarray(c2w, np.float64)
    centres, up, back = c2w[:, :3, 3], c2w[:, :3, 1], c2w[:, :3, 2]
    if smooth > 0:
        smoothed = [gaussian_filter1d(a, smooth, axis=0, mode="reflect") for a in (centres, up, back)]
        centres, up, back = smoothed
    back = back / np.linalg.norm(back, axis=1, keepdims=True)
    right = np.cross(up, back)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    views = np.arange(len(c2w))
    at = np.linspace(0, views[-1], frames) if frames > 1 else np.full(1, 0.5 * views[-1])
    slerp = Slerp(views, Rotation.from_matrix(np.stack([right, np.cross(back, right), back], axis=2)))
    out = np.tile(np.eye(4), (frames, 1, 1))
    out[:, :3, :3] = slerp(at).as_matrix()
    out[:, :3, 3] = _spline(views, centres, at)
    return out


def default_scene_camera() -> CameraSpec:
    """The camera of a scene file without any: a three-quarter view (azimuth -45 degrees, elevation 20)
    orbiting 30 degrees over the shot, framed to the bodies."""
    from shellsim.shot.spec import CameraSpec

    return CameraSpec(name="default", kind="orbit", elevation=20.0, azimuth=-45.0, degrees=30.0)


def camera_option(name: str):
    """A dataclass field for a job's settings: the option ``name`` of :class:`CameraSettings` (its help,
    parser and default), so that every job that renders a motion declares the same camera options."""
    field = CameraSettings.__dataclass_fields__[name]
    return dataclasses.field(default=field.default, metadata=field.metadata)


@dataclass(frozen=True)
class Shot:
    """The world-frame camera of every frame of a clip: ``c2w`` (F, 4, 4) OpenGL camera-to-world in metres,
    ``focal`` in pixels, ``width`` x ``height`` pixels, principal point at the image centre."""

    c2w: np.ndarray
    focal: float
    width: int
    height: int
    name: str

    def camera_for_frame(self, k: int):
        """A one-camera :class:`neural.data.Cameras` (world frame) of motion frame ``k``."""
        from neural.data import Cameras

        f, w, h = self.focal, self.width, self.height
        c2w = self.c2w[k][None]
        return Cameras(c2w, [f], [f], [0.5 * w], [0.5 * h], [w], [h], np.zeros((1, 4)), [self.name])


@dataclass(frozen=True)
class MotionTrack:
    """What cameras frame, per frame of a motion (world metres): ``lo``, ``hi`` (F, 3) the corners of frame
    k's box, ``centre`` (F, 3) its centre of mass, ``times`` (F,) seconds."""

    lo: np.ndarray
    hi: np.ndarray
    centre: np.ndarray
    times: np.ndarray


def mass_weights(rest_vertices, tets) -> np.ndarray:
    """(V,) each vertex's share of the rest volume: a quarter of the volume of each tet (T, 4) it belongs
    to, so that ``weights @ positions / weights.sum()`` is the centre of mass of a body of uniform density
    whose tets keep their mass (linear in the positions, exact for a rigid motion)."""
    from shellsim.tetcage.geometry import tet_volumes

    tets = np.asarray(tets)
    weights = np.zeros(len(rest_vertices))
    np.add.at(weights, tets.reshape(-1), np.repeat(np.abs(tet_volumes(rest_vertices, tets)) / 4, 4))
    return weights


def motion_track(batches, weights, times) -> MotionTrack:
    """The :class:`MotionTrack` of a motion whose frames, in order, are the arrays (n, V, 3) of ``batches``
    (e.g. :func:`shellsim.motion.read.iter_frames`), ``weights`` (V,) of :func:`mass_weights`, ``times``
    (F,) seconds."""
    weights = np.asarray(weights, np.float64) / float(np.sum(weights))
    lo, hi, centre = [], [], []
    for batch in batches:
        batch = np.asarray(batch, np.float64)
        lo.append(batch.min(axis=1))
        hi.append(batch.max(axis=1))
        centre.append(np.einsum("v,nvi->ni", weights, batch))
    times = np.asarray(times, np.float64)
    return MotionTrack(np.concatenate(lo), np.concatenate(hi), np.concatenate(centre), times)


def smoothed(points, times, seconds: float) -> np.ndarray:
    """(F, 3) exponential smoothing of ``points`` (F, 3) at ``times`` (F,) with time constant ``seconds``:
    ``s_0 = p_0``, ``s_k = s_(k-1) + (1 - exp(-(t_k - t_(k-1)) / seconds)) (p_k - s_(k-1))``; computed over
    the whole motion, so each frame's value is the same whichever frames are rendered."""
    points = np.asarray(points, np.float64)
    gains = 1.0 - np.exp(-np.diff(np.asarray(times, np.float64)) / seconds)
    out = points.copy()
    for k, gain in enumerate(gains, start=1):
        out[k] = out[k - 1] + gain * (points[k] - out[k - 1])
    return out


def _spline(times, points, at) -> np.ndarray:
    """(F, 3) the Catmull-Rom spline through ``points`` (K, 3) at increasing ``times`` (K,), K >= 2, at the
    times ``at`` (F,): cubic Hermite on each interval, the tangent at an inner keyframe the slope
    ``(p[i+1] - p[i-1]) / (t[i+1] - t[i-1])``, zero at the first and last (clamped: the motion starts and
    stops smoothly); held at the first point before ``times[0]`` and at the last after ``times[-1]``; exact
    at every keyframe time."""
    t, p = np.asarray(times, np.float64), np.asarray(points, np.float64)
    tangents = np.zeros_like(p)
    tangents[1:-1] = (p[2:] - p[:-2]) / (t[2:] - t[:-2])[:, None]
    at = np.asarray(at, np.float64)
    i = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    h = t[i + 1] - t[i]
    s = np.clip((at - t[i]) / h, 0.0, 1.0)[:, None]
    s2, s3 = s * s, s * s * s
    return (
        (2 * s3 - 3 * s2 + 1) * p[i]
        + (s3 - 2 * s2 + s) * h[:, None] * tangents[i]
        + (3 * s2 - 2 * s3) * p[i + 1]
        + (s3 - s2) * h[:, None] * tangents[i + 1]
    )


def _look_at(eye, target, up) -> np.ndarray:
    """(4, 4) :func:`neural.data.look_at` from ``eye`` (3,) to ``target`` (3,), image up ``up`` (3,) unit,
    or the second axis of :func:`_basis` when looking along ``up`` (straight down or up)."""
    from neural.data import look_at

    vertical = np.linalg.norm(np.cross(_unit(eye - target), up)) < 1e-6
    return look_at(eye, target, _basis(up)[1] if vertical else up)


def _point(v) -> str:
    """``[x, y, z]`` of a point (3,), as a scene file writes it."""
    return f"[{', '.join(f'{x:g}' for x in v)}]"


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _basis(up) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) that make a right-handed frame with ``up``: +x and +y for up = +z."""
    e1 = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(e1 - (e1 @ up) * up)
    return e1, np.cross(up, e1)


def _rotations(up, azimuth, elevation: float) -> np.ndarray:
    """(n, 3, 3) camera axes (columns: right, image up, back) of cameras at ``azimuth`` (n,) radians about
    ``up`` (3,) and ``elevation`` radians above the horizon, looking at their target; image up is ``up``
    tilted with the view (at elevation 90 degrees the horizontal direction away from the camera)."""
    e1, e2 = _basis(up)
    flat = np.cos(azimuth)[:, None] * e1 + np.sin(azimuth)[:, None] * e2  # (n, 3)
    back = math.cos(elevation) * flat + math.sin(elevation) * up
    image_up = -math.sin(elevation) * flat + math.cos(elevation) * up
    return np.stack([np.cross(image_up, back), image_up, back], axis=2)


def _corners(box) -> np.ndarray:
    """(8, 3) corners of the box (2, 3) of lower and upper corners."""
    box = np.asarray(box, np.float64)
    return np.array([[box[(k >> a) & 1, a] for a in range(3)] for k in range(8)])


def _fit_distance(corners, target, rotation, tan_x: float, tan_y: float) -> np.ndarray:
    """(n,) the least distance from ``target`` (n, 3) along each camera's back axis (column 2 of
    ``rotation`` (n, 3, 3)) at which every point of ``corners`` (n, P, 3) projects inside the image whose
    half widths are ``tan_x``, ``tan_y`` (tangents of the half fields of view) shrunk by :data:`MARGIN`: a
    point at (x, y, z) in the camera's axes about the target needs ``D >= z + MARGIN |x| / tan_x`` and
    ``D >= z + MARGIN |y| / tan_y``."""
    local = np.einsum("npi,nij->npj", corners - target[:, None], rotation)
    x, y, z = np.abs(local[..., 0]), np.abs(local[..., 1]), local[..., 2]
    need = np.maximum(z + MARGIN * x / tan_x, z + MARGIN * y / tan_y).max(axis=1)
    size = np.linalg.norm(corners - target[:, None], axis=2).max(axis=1)
    return np.maximum(need, z.max(axis=1) + 1e-3 * np.maximum(size, 1e-9))


def orbit_camera(
    center,
    distance: float,
    up,
    azimuth: float,
    width: int,
    height: int,
    elevation_deg: float = ORBIT_ELEVATION_DEG,
    fov_deg: float = ORBIT_FOV_DEG,
):
    """One pinhole camera (a ``Cameras`` of length 1) at ``distance`` from ``center`` (3,), ``elevation_deg``
    above the plane normal to ``up`` (3,), at ``azimuth`` radians around ``up``, looking at ``center``
    with a horizontal field of view ``fov_deg``, imaging ``width`` x ``height`` pixels."""
    rotation = _rotations(_unit(up), np.array([azimuth]), math.radians(elevation_deg))[0]
    c2w = np.eye(4)
    c2w[:3, :3] = rotation
    c2w[:3, 3] = np.asarray(center, np.float64) + distance * rotation[:, 2]
    focal = 0.5 * width / math.tan(0.5 * math.radians(fov_deg))
    return Shot(c2w[None], focal, width, height, "orbit").camera_for_frame(0)


def orbit_framing(points) -> tuple[np.ndarray, float]:
    """Centre (3,) and distance of an orbit that keeps ``points`` (N, 3) in view: the bounding box's
    centre and the distance at which its circumscribed sphere fills ``ORBIT_FOV_DEG`` (with 5% room)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    lo, hi = points.min(axis=0), points.max(axis=0)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    return 0.5 * (lo + hi), MARGIN * radius / math.sin(0.5 * math.radians(ORBIT_FOV_DEG))
