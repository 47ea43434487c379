"""Whole renders: every camera of a camera file at rest (:func:`render_views`) and the frames of a motion
(:func:`render_motion`, ``DIR/<k:05d>.png`` for motion frame ``k``, optionally an MP4), serially or as Ray
tasks (:func:`render_frames`). A PNG already on disk is kept only when its record matches
(:mod:`shellsim.io.png`).
"""

from __future__ import annotations

import functools
import logging
import math
from pathlib import Path

import numpy as np

from shellsim.deform.renderer import DeformedRenderer
from shellsim.io.png import asset_identity, digest, frame_record, renderer_identity, save_png, stale_reason
from shellsim.io.video import write_video
from shellsim.render.cameras import orbit_camera, orbit_framing
from shellsim.settings import parse_frames

log = logging.getLogger(__name__)


def render_frames(
    jobs, out_dir: Path, overwrite: bool, progress: bool, recipe, ray: str | None = None
) -> dict:
    """Render ``jobs`` [(path, record, payload)] into PNGs with ``recipe() -> render_one``,
    ``render_one(payload) -> (image, stats)``, reusing a PNG only when its record matches (unless
    ``overwrite``); logs what was replaced and why. With ``ray`` ("local" or a cluster address) the frames
    are Ray tasks (:func:`shellsim.distributed.run_on_ray`: ``recipe`` runs once per worker) and this
    process writes each PNG as it arrives. Returns the summary of :func:`_summary`."""
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
    written, stats = [], []
    bar = tqdm(total=len(todo), desc="render", unit="frame", disable=not progress or not todo)

    def save(i: int, result) -> None:
        image, frame_stats = result
        save_png(todo[i][0], image, todo[i][1])
        written.append(todo[i][0])
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
    summary = _summary(out_dir, written, skipped, stats)
    summary["replaced"] = sum(len(n) for n in replaced.values())
    return summary


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


def _summary(out_dir: Path, written: list, skipped: int, stats: list[dict]) -> dict:
    """Counts and the mean of every ``*ms`` and ``samples_per_pixel`` figure of the frames' ``stats``."""
    summary = {"out": str(out_dir), "rendered": len(written), "skipped": skipped}
    if stats:
        for key in stats[0]:
            if key.endswith("ms") or key == "samples_per_pixel":
                summary[key] = float(np.mean([s[key] for s in stats]))
        log.debug(
            "%d frames rendered to %s (%d already there): %s",
            len(written),
            out_dir,
            skipped,
            {k: round(v, 2) for k, v in summary.items() if isinstance(v, float)},
        )
    return summary


def render_views(
    asset_spec,
    cameras_path,
    out_dir,
    size: tuple[int, int] | None = None,
    device: str = "auto",
    overwrite: bool = False,
    progress: bool = True,
    ray: str | None = None,
) -> dict:
    """Render every camera of a ``transforms*.json``-style camera file (images may be absent) at rest to
    ``out_dir/<frame name>.png`` (the listed image's name, else ``frame_<index>``); ``size`` = (W, H)
    overrides the file's. A PNG already there is kept only when its record (:func:`frame_record`) says it
    shows this asset from this camera at this size, unless ``overwrite``; others are rendered again. With
    ``ray`` ("local" or a cluster address) each frame is a Ray task. Returns a summary with the mean ms per
    frame and per stage."""
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


def _view_frames(asset, cage, device: str, positions=None):
    """``render_one(view)`` of :func:`render_frames`: ``view`` (a one-camera ``Cameras``) -> (image, stats),
    at rest, or with ``cage`` and ``positions`` (F, V, 3) for payloads ``(view, frame)``."""
    device, field = _field(asset, device)
    renderer = DeformedRenderer(asset, field, cage, device)
    if positions is None:
        return lambda view: renderer.render(view, 0)
    return lambda job: renderer.render(job[0], 0, positions[job[1]])


def view_recipe(asset_path: str, device: str):
    """In a Ray worker: the rest ``render_one`` of the asset at ``asset_path``."""
    from neural.asset import load_asset

    return _view_frames(load_asset(asset_path), None, device)


def motion_recipe(asset_path: str, motion_path: str, device: str):
    """In a Ray worker: the ``render_one((view, frame))`` of a motion of the asset at ``asset_path``."""
    from neural.asset import load_asset
    from shellsim.cage.store import cage_for_motion
    from shellsim.motion.format import load_motion

    asset, motion = load_asset(asset_path), load_motion(motion_path)
    return _view_frames(asset, cage_for_motion(asset, motion, motion_path), device, motion.positions)


def motion_frame_ids(motion) -> list[str]:
    """Digest of each frame of ``motion`` (its rest cage, tets and the frame's positions): (F,) strings."""
    base = digest(motion.rest_vertices, motion.tets)
    return [digest(base, p) for p in motion.positions]


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
) -> dict:
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
    framing : (N, 3) points the orbit keeps in view (default: every cage vertex of the whole motion), so
        that several motions can be seen by the same orbit
    The motion, ``frames`` and the camera file are checked before the asset and its field load.
    Returns a summary: counts, mean ms per frame and per stage, ``video``.
    """
    from neural.asset import load_asset
    from neural.data import load_camera_file
    from shellsim.cage.store import cage_for_motion
    from shellsim.motion.format import load_motion

    if (cameras is None) == (not orbit):
        raise ValueError("give exactly one of cameras and orbit=True")
    if fps is not None and not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps: expected a positive number, got {fps}")
    motion = load_motion(motion_path)
    indices = parse_frames(frames, motion.n_frames, source=str(motion_path))
    if orbit:
        width, height = size or (400, 400)
        center, distance = orbit_framing(motion.positions if framing is None else framing)
    else:
        view = load_camera_file(cameras, *(size or (None, None))).subset([0])
    asset = load_asset(asset_spec)
    cage = cage_for_motion(asset, motion, str(motion_path))
    identity, settings = asset_identity(asset, cage), renderer_identity(asset)
    frame_ids = motion_frame_ids(motion)
    out_dir = Path(out_dir)
    jobs = []
    for k in indices:
        if orbit:
            view = orbit_camera(center, distance, asset.up, 2 * math.pi * k / motion.n_frames, width, height)
        jobs.append(
            (out_dir / f"{k:05d}.png", frame_record(frame_ids[k], view, identity, settings), (view, k))
        )
    out_dir.mkdir(parents=True, exist_ok=True)
    if ray is None:
        recipe = functools.partial(_view_frames, asset, cage, device, motion.positions)
    else:
        paths = str(asset.root.resolve()), str(Path(motion_path).resolve())
        recipe = functools.partial(motion_recipe, *paths, device)
    summary = render_frames(jobs, out_dir, overwrite, progress, recipe, ray)
    if video is not None:
        fps = motion_fps(motion) if fps is None else fps
        summary["video"] = str(write_video([path for path, _, _ in jobs], video, fps))
        log.info("wrote %s (%d frames at %g fps)", video, len(indices), fps)
    return summary
