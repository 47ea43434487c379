"""Whole renders: every camera of a camera file at rest (:func:`render_views`) and the frames of a motion
(:func:`render_motion`, ``DIR/<k:05d>.png`` for motion frame ``k``, optionally an MP4), serially or as Ray
tasks (:func:`render_frames`). A PNG already on disk is kept only when its record matches
(:mod:`shellsim.io.png`).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from pathlib import Path

import numpy as np

from neural.errors import write_failures
from shellsim.film.antialias import ADAPTIVE_THRESHOLD, adaptive, pixel_offsets
from shellsim.film.cameras import MOTION_ANTIALIAS, VIDEO_SIZE, CameraSettings, mass_weights, motion_track
from shellsim.film.result import RenderResult
from shellsim.io.png import asset_identity, digest, frame_record, renderer_identity, save_png, stale_reason
from shellsim.io.video import write_video
from shellsim.settings import parse_frames

log = logging.getLogger(__name__)

#: How frames are rendered: "final" (the size, rays per pixel and shadows asked for) or "preview" (half
#: the size, one ray per pixel through each pixel's centre, no shadow rays): a whole shot in seconds.
QUALITIES = ("final", "preview")


def check_quality(quality: str) -> None:
    """ValueError naming ``quality`` unless it is one of :data:`QUALITIES`."""
    if quality not in QUALITIES:
        raise ValueError(f"quality: expected one of {', '.join(QUALITIES)}, got {quality!r}")


def preview_size(width: int, height: int) -> tuple[int, int]:
    """(W, H) of a preview of frames ``width`` x ``height``: half of each side, at least one pixel."""
    return max(1, int(width) // 2), max(1, int(height) // 2)


def preview_look(look):
    """``look`` (a :class:`shellsim.world.WorldLook`, or None) of a preview: without shadow rays."""
    return None if look is None else dataclasses.replace(look, shadows=False)


def quality_identity(renderer: str, quality: str) -> str:
    """The renderer digest of a frame's record (:func:`shellsim.io.png.frame_record`) for ``quality``:
    ``renderer`` itself for "final" (frames made before there were qualities stay valid), else a digest of
    it and the quality, so that a final render never keeps a preview's frames, whatever their settings."""
    return renderer if quality == "final" else digest(renderer, f"quality {quality}")


def render_frames(
    jobs, out_dir: Path, overwrite: bool, progress: bool, recipe, ray: str | None = None
) -> RenderResult:
    """Render ``jobs`` [(path, record, payload)] into PNGs with ``recipe() -> render_one``,
    ``render_one(payload) -> (image, stats)``, reusing a PNG only when its record matches (unless
    ``overwrite``); logs what was replaced and why. With ``ray`` ("local" or a cluster address) the frames
    are Ray tasks (:func:`shellsim.distributed.run_on_ray`: ``recipe`` runs once per worker) and this
    process writes each PNG as it arrives. Returns the :class:`RenderResult` of every job's frame."""
    from tqdm import tqdm

    todo, skipped, replaced = [], 0, {}
    for path, record, payload in jobs:
        why = "" if overwrite else stale_reason(path, record)
        if why is None:
            skipped += 1
            continue
        if why:
            replaced.setdefault(why, []).append(path.name)
        todo.append((path, record, payload))
    stats = []
    bar = tqdm(total=len(todo), desc="render", unit="frame", disable=not progress or not todo)

    def save(i: int, result) -> None:
        image, frame_stats = result
        kept = f"{skipped + len(stats)} of {skipped + len(todo)} frames kept in {out_dir}"
        with write_failures(todo[i][0], kept=kept):
            save_png(todo[i][0], image, todo[i][1])
        stats.append(frame_stats)
        bar.update()
        bar.set_postfix(ms=f"{frame_stats['ms']:.0f}", spp=f"{frame_stats.get('samples_per_pixel', 0):.1f}")

    with bar:
        if todo and ray is not None:
            from shellsim.distributed import run_on_ray

            run_on_ray([job[2] for job in todo], recipe, save, None if ray == "local" else ray)
        elif todo:
            render_one = recipe()
            for i, (_, _, payload) in enumerate(todo):
                save(i, render_one(payload))
    for why, names in replaced.items():
        log.info(
            "%s: rendered %d frames again (%s..%s): they were made with %s",
            out_dir,
            len(names),
            names[0],
            names[-1],
            why,
        )
    frames, n_replaced = [path for path, _, _ in jobs], sum(len(n) for n in replaced.values())
    return RenderResult.of_frames(out_dir, frames, skipped, n_replaced, stats)


def motion_fps(motion) -> float:
    """Frames per second of a motion: its ``meta["fps"]``, else from its times, else 30."""
    fps = motion.meta.get("fps")
    if isinstance(fps, int | float) and fps > 0 and math.isfinite(fps):
        return float(fps)
    dt = np.diff(motion.times)
    if dt.size and np.median(dt) > 0:
        return float(1.0 / np.median(dt))
    return 30.0


def with_video(result: RenderResult, video, fps: float | None, motion, indices: range) -> RenderResult:
    """``result`` with its frames written as the MP4 ``video`` (None: none) at ``fps`` (None: the motion's
    frames per second divided by the stride of ``indices``, so that the clip plays in real time)."""
    if video is None:
        return result
    fps = motion_fps(motion) / indices.step if fps is None else fps
    log.info("writing %s (%d frames at %g fps)", video, len(indices), fps)
    return dataclasses.replace(result, video=write_video(list(result.frames), video, fps))


def _field(asset, device: str):
    """The torch device picked for ``device`` ("auto", "cpu", "cuda") and the asset's field on it."""
    from neural.asset import load_field
    from neural.device import pick_device

    device = pick_device(device)
    return device, load_field(asset, device)


def render_views(
    asset_spec,
    cameras_path,
    out_dir,
    size: tuple[int, int] | None = None,
    device: str = "auto",
    overwrite: bool = False,
    progress: bool = True,
    ray: str | None = None,
    antialias: int = 1,
    quality: str = "final",
) -> RenderResult:
    """Render every camera of a ``transforms*.json``-style camera file (images may be absent) at rest to
    ``out_dir/<frame name>.png`` (the listed image's name, else ``frame_<index>``); ``size`` = (W, H)
    overrides the file's. A PNG already there is kept only when its record (:func:`frame_record`) says it
    shows this asset from this camera at this size, unless ``overwrite``; others are rendered again. With
    ``ray`` ("local" or a cluster address) each frame is a Ray task. ``antialias``: jittered rays per pixel
    where a pixel's neighbourhood varies (:func:`shellsim.film.antialias.adaptive`; 1, the default: the
    pixel-centre rays ``shellsim eval`` scores); ``quality``
    "preview" (:data:`QUALITIES`): half the size, one ray per pixel. Returns the :class:`RenderResult`
    (counts, mean ms per frame and per stage)."""
    from neural.asset import load_asset
    from neural.data import load_camera_file

    check_quality(quality)
    pixel_offsets(antialias)  # checked before the asset loads
    cameras = load_camera_file(cameras_path, *(size or (None, None)))
    if quality == "preview":
        antialias = 1
        cameras = load_camera_file(cameras_path, *preview_size(cameras.width[0], cameras.height[0]))
    names = list(cameras.names)
    if len(set(names)) != len(names):
        names = [f"{i:05d}" for i in range(len(cameras))]
    asset = load_asset(asset_spec)
    identity = asset_identity(asset)
    settings = quality_identity(renderer_identity(asset, antialias, adaptive=ADAPTIVE_THRESHOLD), quality)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs = []
    for i in range(len(cameras)):
        view = cameras.subset([i])
        jobs.append((out_dir / f"{names[i]}.png", frame_record("rest", view, identity, settings), view))
    if ray is None:
        recipe = functools.partial(_view_frames, asset, None, device, antialias)
    else:
        recipe = functools.partial(view_recipe, str(asset.root.resolve()), device, antialias)
    return render_frames(jobs, out_dir, overwrite, progress, recipe, ray)


def _view_frames(asset, cage, device: str, antialias: int, frame=None, world=None):
    """``render_one(view)`` of :func:`render_frames`: ``view`` (a one-camera ``Cameras``) -> (image, stats)
    with ``antialias`` jittered rays per pixel where its neighbourhood varies
    (:func:`shellsim.film.antialias.adaptive`), at rest, or with ``cage`` and ``frame`` (k -> (V, 3) cage
    positions of frame k, :func:`motion_frames`) for payloads ``(view, k)``; ``world``: (look, placement,
    obstacles) of :func:`motion_world` around the body (None: the asset's background)."""
    device, field = _field(asset, device)
    from shellsim.film.renderer import DeformedRenderer

    renderer = DeformedRenderer(asset, field, cage, device, None, *(world or (None, None, None)))
    if frame is None:
        return lambda view: adaptive(renderer.tracer(), antialias)(view)

    def render_one(job):
        return adaptive(renderer.tracer(frame(job[1])), antialias)(job[0])

    return render_one


def view_recipe(asset_path: str, device: str, antialias: int):
    """In a Ray worker: the rest ``render_one`` of the asset at ``asset_path``."""
    from neural.asset import load_asset

    return _view_frames(load_asset(asset_path), None, device, antialias)


def motion_recipe(asset_path: str, motion_path: str, device: str, antialias: int, look=None):
    """In a Ray worker: the ``render_one((view, frame))`` of a motion of the asset at ``asset_path`` (``look``
    as :func:`motion_world`'s)."""
    from neural.asset import load_asset
    from shellsim.motion.read import read_motion_info
    from shellsim.tetcage.store import cage_for_motion

    asset, motion = load_asset(asset_path), read_motion_info(motion_path)
    cage = cage_for_motion(asset, motion, motion_path)
    frame = motion_frames(motion, motion_path)
    return _view_frames(asset, cage, device, antialias, frame, motion_world(motion, look))


def motion_world(motion, look=None):
    """(look, placement, obstacles) of the world around a motion's body, or None for motions made before the
    world was in metres (no placement: the asset's background). ``look``: a
    :class:`shellsim.world.WorldLook` (None: the default one); its ground is drawn only for motions
    that have one (not simulated without a ground), the others have the sky alone. ``obstacles``: the
    :class:`shellsim.film.obstacles.Obstacles` of the motion's settings (``box``, ``sphere``)."""
    from shellsim.film.obstacles import Obstacles
    from shellsim.world import Placement, WorldLook, has_ground

    if not motion.placement:
        return None
    look = WorldLook() if look is None else look
    placement = Placement.from_dict(motion.placement, motion.path or "motion")
    obstacles = Obstacles(motion.settings.get("box") or (), motion.settings.get("sphere") or ())
    return dataclasses.replace(look, ground=look.ground and has_ground(motion.settings)), placement, obstacles


def world_record(world) -> dict | None:
    """JSON of :func:`motion_world`'s (look, placement, obstacles) for the frames' records (None stays
    None)."""
    if world is None:
        return None
    from shellsim.film.ground import WORLD_RENDERER

    look, placement, obstacles = world
    return {
        "renderer": WORLD_RENDERER,
        "look": dataclasses.asdict(look),
        "placement": placement.as_dict(),
        "obstacles": dataclasses.asdict(obstacles),
    }


def motion_frames(motion, motion_path):
    """``frame(k)``: (V, 3) float32, frame ``k`` of the motion file ``motion_path`` (``motion``: its
    :class:`shellsim.motion.format.MotionInfo`) in the asset's frame, read from the file when asked."""
    from shellsim.motion.read import read_frames

    return lambda k: asset_frame(motion, read_frames(motion_path, [k])[0])


def asset_frame(motion, points) -> np.ndarray:
    """(..., 3) float32: world ``points`` of ``motion`` (its positions, or points framing it) in the asset's
    own frame, where its field, shells and rest cage are: the inverse of the motion's placement
    (:class:`shellsim.world.Placement`; the identity for motions made before the world was in metres)."""
    from shellsim.world import Placement

    placement = Placement.from_dict(motion.placement, motion.path or "motion")
    return placement.to_asset(points).astype(np.float32)


def asset_camera(motion, view):
    """The one-camera :class:`neural.data.Cameras` ``view`` (world frame) of ``motion`` in the asset's frame:
    its camera-to-world composed with the inverse of the placement (``R^T`` turns the axes, the position
    goes through :meth:`Placement.to_asset`); the placement's scale moves the camera with the points, so the
    image is the same."""
    from shellsim.world import Placement

    placement = Placement.from_dict(motion.placement, motion.path or "motion")
    c2w = view.c2w.copy()
    c2w[:, :3, :3] = placement.rotation.T @ c2w[:, :3, :3]
    c2w[:, :3, 3] = placement.to_asset(c2w[:, :3, 3])
    return dataclasses.replace(view, c2w=c2w)


def motion_frame_ids(motion, positions) -> list[str]:
    """Digest of each frame (V, 3) of ``positions`` (an array (n, V, 3) or any iterable of frames) of
    ``motion`` (with its rest cage and tets): (n,) strings."""
    base = digest(motion.rest_vertices, motion.tets)
    return [digest(base, p) for p in positions]


def render_motion(
    asset_spec,
    motion_path,
    out_dir,
    cameras=None,
    camera: CameraSettings | None = None,
    frames: str | None = None,
    size: tuple[int, int] | None = None,
    video=None,
    fps: float | None = None,
    device: str = "auto",
    overwrite: bool = False,
    progress: bool = True,
    ray: str | None = None,
    framing=None,
    antialias: int = MOTION_ANTIALIAS,
    look=None,
    quality: str = "final",
) -> RenderResult:
    """Render frames of a motion to ``out_dir/<k:05d>.png`` (``k`` the motion frame), optionally an MP4.

    asset_spec : asset directory or shipped name; motion_path : ``.npz`` of :mod:`shellsim.motion.format` made
        for this asset's cage (else an :class:`InputError`)
    cameras : camera file in the asset's frame (its first camera views every frame), or None
    camera : :class:`~shellsim.film.cameras.CameraSettings` of a camera in world metres (not with
        ``cameras``; neither: ``CameraSettings()``, an orbit of 30 degrees over the clip)
    frames : ``"a:b"`` spec of :func:`parse_frames` (None: all)
    size : (W, H); default the camera file's, or :data:`VIDEO_SIZE` for ``camera``
    video : MP4 path assembled from the frames ``frames`` at ``fps`` (default: the motion's divided by the
        frames' stride)
    overwrite : render every frame again; without it a PNG on disk is kept only when its record
        (:func:`frame_record`: motion frame, camera, size, asset, renderer settings) matches, so an
        interrupted render resumes and frames of another motion, camera or size are rendered again
    ray : "local" or a Ray cluster address: each frame a Ray task (:func:`render_frames`)
    framing : (N, 3) world points whose box an orbit or preset ``camera`` keeps in view (default: the box of
        every frame), so that several motions can be seen by the same camera
    antialias : jittered rays per pixel, averaged, where a pixel's neighbourhood varies
        (:func:`shellsim.film.antialias.adaptive`; 1: one ray through each pixel's centre)
    look : :class:`shellsim.world.WorldLook` of the world behind the body (ground, light, shadows,
        sky); None: :func:`motion_world`'s default (the ground for a motion that has one)
    quality : "final", or "preview" (:data:`QUALITIES`): half the size (of ``size``, the default or the
        camera file's), one ray per pixel, no shadow rays; its frames' records differ from the final ones'
    The motion, ``frames`` and the camera file are checked before the asset and its field load.
    Returns the :class:`RenderResult` (counts, mean ms per frame and per stage, ``video``).
    """
    from neural.asset import load_asset
    from neural.data import load_camera_file
    from shellsim.motion.read import iter_frames, read_motion_info
    from shellsim.tetcage.store import cage_for_motion
    from shellsim.world import UP

    if cameras is not None and camera is not None:
        raise ValueError("camera: not with cameras (a camera file)")
    if fps is not None and not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps: expected a positive number, got {fps}")
    check_quality(quality)
    pixel_offsets(antialias)
    if quality == "preview":
        antialias = 1
    motion = read_motion_info(motion_path)
    indices = parse_frames(frames, motion.n_frames, source=str(motion_path))
    if cameras is None:  # every frame's box and centre of mass, read a batch at a time
        weights = mass_weights(motion.rest_vertices, motion.tets)
        batches = iter_frames(motion_path, range(motion.n_frames))
        track = motion_track(batches, weights, motion.times)
    else:
        view = load_camera_file(cameras, *(size or (None, None))).subset([0])
        if quality == "preview":
            view = load_camera_file(cameras, *preview_size(view.width[0], view.height[0])).subset([0])
    if quality == "preview" and cameras is None:
        size = preview_size(*(size or VIDEO_SIZE))
    asset = load_asset(asset_spec)
    cage = cage_for_motion(asset, motion, str(motion_path))
    if cameras is None:
        box = None if framing is None else np.stack([np.min(framing, 0), np.max(framing, 0)])
        up = UP if motion.placement else asset.up  # motions made before the world was in metres: the asset's
        shot = (camera or CameraSettings()).shot(track, *(size or VIDEO_SIZE), up=up, box=box)
    if quality == "preview":
        from shellsim.world import WorldLook

        look = preview_look(WorldLook() if look is None else look)
    world = motion_world(motion, look)
    identity = asset_identity(asset, cage)
    identity_of = renderer_identity(asset, antialias, world_record(world), ADAPTIVE_THRESHOLD)
    settings = quality_identity(identity_of, quality)
    frame_ids = motion_frame_ids(motion, (p for batch in iter_frames(motion_path, indices) for p in batch))
    out_dir = Path(out_dir)
    jobs = []
    for k, frame_id in zip(indices, frame_ids, strict=True):
        if cameras is None:
            view = asset_camera(motion, shot.camera_for_frame(k))
        jobs.append((out_dir / f"{k:05d}.png", frame_record(frame_id, view, identity, settings), (view, k)))
    out_dir.mkdir(parents=True, exist_ok=True)
    if ray is None:
        frame = motion_frames(motion, motion_path)
        recipe = functools.partial(_view_frames, asset, cage, device, antialias, frame, world)
    else:
        paths = str(asset.root.resolve()), str(Path(motion_path).resolve())
        recipe = functools.partial(motion_recipe, *paths, device, antialias, look)
    return with_video(
        render_frames(jobs, out_dir, overwrite, progress, recipe, ray), video, fps, motion, indices
    )
