"""The frames of a scene motion (``shellsim scene``): every body in one image, in the world, seen by a camera
of the scene file (or any world camera), ``DIR/<k:05d>.png`` for motion frame ``k`` and optionally an MP4.

Each frame is drawn by :class:`shellsim.film.renderer.SceneRenderer`: the neural bodies through their
deformed shells (samples merged by depth, each shaded by its own field), the mesh bodies' surfaces and the
colliders as opaque meshes (a box without rotation and a sphere met in closed form), on the world's lit
ground under its sky, with the shadows of every body. Frames run serially or as Ray tasks, and a PNG on disk
is kept only when its record matches, as for one asset's motion (:mod:`shellsim.film.motion_frames`).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
from pathlib import Path

import numpy as np

from shellsim.errors import SettingError
from shellsim.film.antialias import ADAPTIVE_THRESHOLD, adaptive, pixel_offsets
from shellsim.film.cameras import MOTION_ANTIALIAS, VIDEO_SIZE, MotionTrack
from shellsim.film.motion_frames import (
    check_quality,
    preview_look,
    preview_size,
    quality_identity,
    render_frames,
    with_video,
)
from shellsim.film.result import RenderResult
from shellsim.io.png import asset_identity, digest, frame_record

log = logging.getLogger(__name__)


def scene_tracks(scene) -> dict[str, MotionTrack]:
    """What the cameras frame in a :class:`shellsim.shot.recorded.SceneMotion`: each body's
    :class:`MotionTrack` (its cage's box and centre of mass per frame) by name, and under "" that of all
    the bodies together; frames read a batch at a time."""
    from shellsim.film.cameras import mass_weights
    from shellsim.motion.read import iter_frames

    info = scene.info
    weights = mass_weights(info.rest_vertices, info.tets)
    parts = [(b.name, b.vertices) for b in scene.bodies] + [("", slice(0, len(weights)))]
    lo, hi, centre = ({name: [] for name, _ in parts} for _ in range(3))
    for batch in iter_frames(scene.path, range(info.n_frames)):
        batch = np.asarray(batch, np.float64)
        for name, share in parts:
            mine, w = batch[:, share], weights[share] / weights[share].sum()
            lo[name].append(mine.min(axis=1))
            hi[name].append(mine.max(axis=1))
            centre[name].append(np.einsum("v,nvi->ni", w, mine))
    times = np.asarray(info.times, np.float64)
    return {
        name: MotionTrack(
            np.concatenate(lo[name]), np.concatenate(hi[name]), np.concatenate(centre[name]), times
        )
        for name, _ in parts
    }


def scene_world(scene, look):
    """(look, obstacles, statics) of a scene's world: ``look`` (:class:`shellsim.world.WorldLook`) with
    its ground drawn only where the scene has one; its colliders as
    :class:`shellsim.film.obstacles.Obstacles` (boxes without rotation, spheres, in the look's
    ``obstacle_color``) and as static meshes ``(vertices, faces, albedo)`` (the others, and every collider
    with a ``color`` of its own)."""
    from shellsim.film.obstacles import Obstacles
    from shellsim.shot.bodies import collider_mesh

    boxes, spheres, statics = [], [], []
    for c in scene.colliders:
        if c.color is None and c.shape == "box" and not any(c.rotation):
            boxes.append((*c.position, *c.half_extents))
        elif c.color is None and c.shape == "sphere":
            spheres.append((*c.position, c.radius))
        else:
            statics.append((*collider_mesh(c), look.obstacle_color if c.color is None else c.color))
    return scene_look(scene, look), Obstacles(boxes, spheres), statics


def scene_look(scene, look):
    """``look`` with its ground drawn only where ``scene`` has one."""
    return dataclasses.replace(look, ground=look.ground and scene.ground)


def scene_renderer(scene, device: str, look):
    """The :class:`~shellsim.film.renderer.SceneRenderer` of ``scene``'s neural bodies (each asset's field
    loaded once on the device picked for ``device``, its colours times the body's ``color``, a tint, when it
    has one) in the world of ``look`` (:func:`scene_world`)."""
    from neural.asset import load_field
    from neural.device import pick_device
    from shellsim.film.renderer import DeformedRenderer, SceneRenderer, TintedField

    device = pick_device(device)
    fields, renderers = {}, []
    for body in scene.bodies:
        if body.asset is None:
            continue
        key = str(body.asset.root.resolve())
        if key not in fields:
            fields[key] = load_field(body.asset, device)
        field = fields[key] if body.color is None else TintedField(fields[key], body.color)
        renderers.append(DeformedRenderer(body.asset, field, body.cage, device, placement=body.placement))
    look, obstacles, statics = scene_world(scene, look)
    return SceneRenderer(renderers, look, obstacles, statics, device)


def _scene_frames(scene, device: str, antialias: int, look):
    """``render_one((view, k))`` of :func:`render_frames`: motion frame ``k`` of ``scene`` seen by the
    one-camera ``view`` (world frame), ``antialias`` jittered rays per pixel where its neighbourhood varies
    (:func:`shellsim.film.antialias.adaptive`), the static world kept while the view repeats."""
    from shellsim.motion.read import read_frames

    renderer = scene_renderer(scene, device, look)
    neural = [b for b in scene.bodies if b.asset is not None]
    meshes = [b for b in scene.bodies if b.asset is None]

    def render_one(job):
        view, k = job
        positions = read_frames(scene.path, [k])[0]
        cages = [b.placement.to_asset(positions[b.vertices]) for b in neural]
        surfaces = [(b.surface_points(positions[b.vertices]), b.surface_faces, b.color) for b in meshes]
        return adaptive(renderer.tracer(cages, surfaces), antialias)(view)

    return render_one


def scene_recipe(motion_path: str, device: str, antialias: int, look, spec=None):
    """In a Ray worker: the ``render_one`` of the scene motion at ``motion_path`` (coloured as ``spec``
    says, :func:`_as_file_says`)."""
    from shellsim.shot.recorded import read_scene_motion

    return _scene_frames(_as_file_says(read_scene_motion(motion_path), spec), device, antialias, look)


def _as_file_says(scene, spec):
    """``scene`` with the cameras, look and colours of the scene file's ``spec``
    (:meth:`shellsim.shot.recorded.SceneMotion.as_file_says`); None: as the motion recorded them."""
    return scene if spec is None else scene.as_file_says(spec)


def scene_identity(scene) -> str:
    """Digest of what a scene's images depend on besides its frames: each neural body's asset and cage
    (:func:`asset_identity`), each mesh body's surface, the colliders (with their colours)."""
    parts = []
    for b in scene.bodies:
        if b.asset is not None:
            parts.append(asset_identity(b.asset, b.cage))
        else:
            parts += [b.surface_faces, b.surface_bary, b.surface_corners]
    colliders = json.dumps([dataclasses.asdict(c) for c in scene.colliders], sort_keys=True)
    return digest(colliders, *parts)


def scene_renderer_identity(scene, antialias: int, look) -> str:
    """Digest of the renderer's settings for ``scene``: each neural body's narrow band, each body's colour
    (a mesh's albedo, an asset's tint), the jittered rays per pixel, the world's look and renderer
    version."""
    from shellsim.film.ground import WORLD_RENDERER

    settings = {
        "narrowband": [dataclasses.asdict(b.asset.narrowband_config()) for b in scene.bodies if b.asset],
        "colors": [b.color for b in scene.bodies],
        "antialias": antialias,
        "adaptive": ADAPTIVE_THRESHOLD,
        "world": {"renderer": WORLD_RENDERER, "look": dataclasses.asdict(scene_look(scene, look))},
    }
    return digest("scene", json.dumps(settings, sort_keys=True))


def scene_camera(scene, name: str | None):
    """The :class:`~shellsim.shot.spec.CameraSpec` named ``name`` among the scene's cameras (None: its
    first, else :func:`~shellsim.film.cameras.default_scene_camera`); a :class:`SettingError` of
    ``scene_camera`` naming the cameras there are otherwise."""
    from shellsim.film.cameras import default_scene_camera

    if name is None:
        return scene.cameras[0] if scene.cameras else default_scene_camera()
    for camera in scene.cameras:
        if camera.name == name:
            return camera
    known = ", ".join(c.name for c in scene.cameras) or "none"
    raise SettingError("scene_camera", f"{scene.path}: no [[camera]] named {name!r} (it has: {known})")


def render_scene(
    scene_path,
    out_dir,
    scene_camera_name: str | None = None,
    camera=None,
    frames: str | None = None,
    size: tuple[int, int] | None = None,
    video=None,
    fps: float | None = None,
    device: str = "auto",
    overwrite: bool = False,
    progress: bool = True,
    ray: str | None = None,
    antialias: int = MOTION_ANTIALIAS,
    look=None,
    ground: bool = True,
    spec=None,
    quality: str = "final",
) -> RenderResult:
    """Render frames of a scene motion to ``out_dir/<k:05d>.png`` (``k`` the motion frame), optionally an MP4.

    scene_path : a ``shellsim scene`` output directory or its ``motion.npz``
    scene_camera_name : the scene file's ``[[camera]]`` that views the frames (None: its first, or a
        three-quarter orbit framed to the bodies when it has none)
    camera : a :class:`~shellsim.film.cameras.CameraSettings` instead (framed to every body)
    frames : ``"a:b[:step]"`` of :func:`shellsim.settings.parse_frames` (None: all)
    size : (W, H) (default :data:`VIDEO_SIZE`); video, fps : MP4 of the frames (default fps: the motion's
        divided by the step)
    look : :class:`shellsim.world.WorldLook`, or a :class:`~shellsim.film.world.WorldSettings` whose
        options set to other than their defaults replace those of the scene's ``[look]``
        (:meth:`WorldSettings.over`); None: the scene's look
    ground : draw the ground where the scene has one (False: nowhere)
    spec : the :class:`~shellsim.shot.spec.SceneSpec` of the scene file as it says now, whose cameras, look
        and colours replace those the motion recorded (they do not change the motion)
    quality : "final", or "preview" (:data:`shellsim.film.motion_frames.QUALITIES`): half the size, one ray
        per pixel, no shadow rays; its frames' records differ from the final ones'
    Other arguments as :func:`shellsim.film.motion_frames.render_motion`'s. Returns its :class:`RenderResult`.
    """
    from shellsim.film.cameras import scene_shot
    from shellsim.film.motion_frames import motion_frame_ids
    from shellsim.film.world import look_of
    from shellsim.motion.read import iter_frames
    from shellsim.settings import parse_frames
    from shellsim.shot.recorded import read_scene_motion
    from shellsim.world import WorldLook

    check_quality(quality)
    pixel_offsets(antialias)
    scene = _as_file_says(read_scene_motion(scene_path, load_assets=False), spec)
    if not isinstance(look, WorldLook):
        own = look_of(scene.look, ground)
        look = own if look is None else look.over(own)
    look = dataclasses.replace(look, ground=look.ground and ground)
    info = scene.info
    indices = parse_frames(frames, info.n_frames, source=str(scene.path))
    width, height = size or VIDEO_SIZE
    if quality == "preview":
        (width, height), antialias, look = preview_size(width, height), 1, preview_look(look)
    tracks = scene_tracks(scene)
    shot = (
        camera.shot(tracks[""], width, height)
        if camera is not None
        else scene_shot(
            scene_camera(scene, scene_camera_name),
            tracks,
            width,
            height,
            {b.name: b.placement for b in scene.bodies},
        )
    )
    scene = _as_file_says(read_scene_motion(scene_path), spec)
    identity = scene_identity(scene)
    settings = quality_identity(scene_renderer_identity(scene, antialias, look), quality)
    frame_ids = motion_frame_ids(info, (p for batch in iter_frames(scene.path, indices) for p in batch))
    out_dir = Path(out_dir)
    jobs = []
    for k, frame_id in zip(indices, frame_ids, strict=True):
        view = shot.camera_for_frame(k)
        jobs.append((out_dir / f"{k:05d}.png", frame_record(frame_id, view, identity, settings), (view, k)))
    out_dir.mkdir(parents=True, exist_ok=True)
    if ray is None:
        recipe = functools.partial(_scene_frames, scene, device, antialias, look)
    else:
        recipe = functools.partial(scene_recipe, str(scene.path.resolve()), device, antialias, look, spec)
    return with_video(
        render_frames(jobs, out_dir, overwrite, progress, recipe, ray), video, fps, info, indices
    )
