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
from shellsim.deform.renderer import DeformedRenderer
from shellsim.io.png import asset_identity, digest, frame_record, renderer_identity, save_png, stale_reason
from shellsim.io.video import write_video
from shellsim.render.cameras import orbit_camera, orbit_framing
from shellsim.render.result import RenderResult
from shellsim.settings import parse_frames

log = logging.getLogger(__name__)


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
) -> RenderResult:
    """Render every camera of a ``transforms*.json``-style camera file (images may be absent) at rest to
    ``out_dir/<frame name>.png`` (the listed image's name, else ``frame_<index>``); ``size`` = (W, H)
    overrides the file's. A PNG already there is kept only when its record (:func:`frame_record`) says it
    shows this asset from this camera at this size, unless ``overwrite``; others are rendered again. With
    ``ray`` ("local" or a cluster address) each frame is a Ray task. Returns the :class:`RenderResult`
    (counts, mean ms per frame and per stage)."""
    from neural.asset import load_asset
    from neural.data import load_camera_file

    cameras = load_camera_file(cameras_path, *(size or (None, None)))
    names = list(cameras.names)
    if len(set(names)) != len(names):
        names = [f"{i:05d}" for i in range(len(cameras))]
    asset = load_asset(asset_spec)
    identity, settings = asset_identity(asset), renderer_identity(asset)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs = []
    for i in range(len(cameras)):
        view = cameras.subset([i])
        jobs.append((out_dir / f"{names[i]}.png", frame_record("rest", view, identity, settings), view))
    if ray is None:
        recipe = functools.partial(_view_frames, asset, None, device)
    else:
        recipe = functools.partial(view_recipe, str(asset.root.resolve()), device)
    return render_frames(jobs, out_dir, overwrite, progress, recipe, ray)


def _view_frames(asset, cage, device: str, frame=None):
    """``render_one(view)`` of :func:`render_frames`: ``view`` (a one-camera ``Cameras``) -> (image, stats),
    at rest, or with ``cage`` and ``frame`` (k -> (V, 3) cage positions of frame k, :func:`motion_frames`)
    for payloads ``(view, k)``."""
    device, field = _field(asset, device)
    renderer = DeformedRenderer(asset, field, cage, device)
    if frame is None:
        return lambda view: renderer.render(view, 0)
    return lambda job: renderer.render(job[0], 0, frame(job[1]))


def view_recipe(asset_path: str, device: str):
    """In a Ray worker: the rest ``render_one`` of the asset at ``asset_path``."""
    from neural.asset import load_asset

    return _view_frames(load_asset(asset_path), None, device)


def motion_recipe(asset_path: str, motion_path: str, device: str):
    """In a Ray worker: the ``render_one((view, frame))`` of a motion of the asset at ``asset_path``."""
    from neural.asset import load_asset
    from shellsim.cage.store import cage_for_motion
    from shellsim.motion.read import read_motion_info

    asset, motion = load_asset(asset_path), read_motion_info(motion_path)
    cage = cage_for_motion(asset, motion, motion_path)
    return _view_frames(asset, cage, device, motion_frames(motion, motion_path))


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


def asset_up(motion, asset) -> np.ndarray:
    """(3,) the world's up axis in the asset's frame for ``motion`` (the asset's own up for motions made
    before the world was in metres)."""
    from shellsim.world import UP, Placement

    if not motion.placement:
        return np.asarray(asset.up, np.float64)
    return Placement.from_dict(motion.placement, motion.path or "motion").rotation.T @ np.array(UP)


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
    orbit: bool = False,
    frames: str | None = None,
    size: tuple[int, int] | None = None,
    video=None,
    fps: float | None = None,
    device: str = "auto",
    overwrite: bool = False,
    progress: bool = True,
    ray: str | None = None,
    framing=None,
) -> RenderResult:
    """Render frames of a motion to ``out_dir/<k:05d>.png`` (``k`` the motion frame), optionally an MP4.

    asset_spec : asset directory or shipped name; motion_path : ``.npz`` of :mod:`shellsim.motion.format` made
        for this asset's cage (else an :class:`InputError`)
    cameras : camera file (its first camera views every frame) or None with ``orbit``: a camera circling the
        bounding box of the cage over the whole motion about the asset's up axis, one revolution over the
        whole motion
    frames : ``"a:b"`` spec of :func:`parse_frames` (None: all)
    size : (W, H); default the camera file's, or 400 x 400 for the orbit
    video : MP4 path assembled from the frames ``frames`` at ``fps`` (default: the motion's)
    overwrite : render every frame again; without it a PNG on disk is kept only when its record
        (:func:`frame_record`: motion frame, camera, size, asset, renderer settings) matches, so an
        interrupted render resumes and frames of another motion, camera or size are rendered again
    ray : "local" or a Ray cluster address: each frame a Ray task (:func:`render_frames`)
    framing : (N, 3) world points the orbit keeps in view (default: every cage vertex of the whole motion),
        so that several motions can be seen by the same orbit
    The motion, ``frames`` and the camera file are checked before the asset and its field load.
    Returns the :class:`RenderResult` (counts, mean ms per frame and per stage, ``video``).
    """
    from neural.asset import load_asset
    from neural.data import load_camera_file
    from shellsim.cage.store import cage_for_motion
    from shellsim.motion.read import frame_bounds, iter_frames, read_motion_info

    if (cameras is None) == (not orbit):
        raise ValueError("give exactly one of cameras and orbit=True")
    if fps is not None and not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps: expected a positive number, got {fps}")
    motion = read_motion_info(motion_path)
    indices = parse_frames(frames, motion.n_frames, source=str(motion_path))
    if orbit:
        width, height = size or (400, 400)
        if framing is None:  # the box of every frame, read a batch at a time
            points = frame_bounds(motion_path, lambda positions: asset_frame(motion, positions))
        else:
            points = asset_frame(motion, framing)
        center, distance = orbit_framing(points)
    else:
        view = load_camera_file(cameras, *(size or (None, None))).subset([0])
    asset = load_asset(asset_spec)
    cage = cage_for_motion(asset, motion, str(motion_path))
    up = asset_up(motion, asset)
    identity, settings = asset_identity(asset, cage), renderer_identity(asset)
    frame_ids = motion_frame_ids(motion, (p for batch in iter_frames(motion_path, indices) for p in batch))
    out_dir = Path(out_dir)
    jobs = []
    for k, frame_id in zip(indices, frame_ids, strict=True):
        if orbit:
            view = orbit_camera(center, distance, up, 2 * math.pi * k / motion.n_frames, width, height)
        jobs.append((out_dir / f"{k:05d}.png", frame_record(frame_id, view, identity, settings), (view, k)))
    out_dir.mkdir(parents=True, exist_ok=True)
    if ray is None:
        recipe = functools.partial(_view_frames, asset, cage, device, motion_frames(motion, motion_path))
    else:
        paths = str(asset.root.resolve()), str(Path(motion_path).resolve())
        recipe = functools.partial(motion_recipe, *paths, device)
    result = render_frames(jobs, out_dir, overwrite, progress, recipe, ray)
    if video is not None:
        fps = motion_fps(motion) if fps is None else fps
        result = dataclasses.replace(result, video=write_video(list(result.frames), video, fps))
        log.info("wrote %s (%d frames at %g fps)", video, len(indices), fps)
    return result
