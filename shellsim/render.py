"""Rendering an asset at rest and deformed by a motion of its cage (paper Sec. 5, DESIGN.md step 7).

Images are made by the one pipeline of :mod:`neural.render.view` (sample, optional map to rest space,
shade); this module supplies, for one frame with cage vertices ``p`` (V, 3), the deformed sampler and the map
to rest space. :class:`DeformedRenderer`

1. **deforms the shells**: every ``M+`` / ``M-`` vertex is the barycentric interpolation of ``p`` in its
   rest tet (:func:`shellsim.deform.deform_points`, as :meth:`~neural.render.raycast.WarpCaster.refit_blended`
   computes it in a Warp kernel); the BVHs of their Warp meshes, built once from the rest shells, are
   refitted, and meanwhile the inverse map (:class:`shellsim.deform.InverseMap`) is updated to the frame;
2. **samples**: casts the camera rays against the deformed shells and places samples in the deformed narrow
   band (Procedure 3, the asset's ``NarrowBandConfig`` in world units);
3. **maps** every sample back to rest space: ``x_rest = Phi^-1(x)``, the ray direction by finite
   differences ``d_rest = normalize(Phi^-1(x + eps d) - Phi^-1(x))`` and the local stretch
   ``|Phi^-1(x + eps d) - Phi^-1(x)| / eps``, which turns a deformed section of length ``delta`` into a
   rest-space one of length ``stretch * delta`` (:meth:`InverseMap.map_rays`). Samples outside the deformed
   cage (``inside = False``) are dropped: the cage contains everything the field shows;
4. **shades** the rest-space samples with the field and composites them along the deformed rays (Eq. 2-3),
   over the asset's background.

With no cage positions it renders the rest shells directly (plain narrow-band rendering, Sec. 3.4): the
pipeline without a map, with the asset's rest sampler, exactly what ``shellsim eval`` measures.

:func:`render_motion` renders a motion file frame by frame to ``DIR/00000.png ...`` (frame ``k`` of the
motion is ``k:05d.png``) and optionally assembles an MP4; :func:`render_views` renders every camera of a
camera file at rest. Every PNG records what made it (:func:`frame_record`: the motion frame, camera, size,
asset and renderer settings, as JSON in a PNG text chunk); a PNG already on disk is kept only when its record
matches, so an interrupted render resumes and frames of another motion, camera or size are rendered again.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import math
import os
import time
from pathlib import Path

import numpy as np
import torch

from .motion import parse_frames

log = logging.getLogger(__name__)

#: Horizontal field of view of the orbit camera, degrees, and its elevation above the horizon.
ORBIT_FOV_DEG = 40.0
ORBIT_ELEVATION_DEG = 25.0
#: Stages of a frame, in :meth:`DeformedRenderer.render`'s ``stats`` as ``<stage>_ms``: building the
#: deformed frame, then the stages of :data:`neural.render.view.STAGES`.
STAGES = ("build", "sample", "map", "shade")
#: PNG text chunk of a rendered frame holding its :func:`frame_record` as JSON.
RECORD_CHUNK = "shellsim-frame"


class DeformedRenderer:
    """Renders an asset's field through its shells, at rest or with its cage deformed: the pipeline of
    :mod:`neural.render.view` (sample, map to rest space, shade) with, for a deformed frame, a sampler on the
    deformed shells and the cage's inverse map as its map to rest space.

    asset : :class:`neural.asset.Asset` (shells, background, narrow-band settings)
    field : its ``ShellField`` on ``device``
    cage : :class:`shellsim.cage.Cage` embedding the asset's shells; None renders at rest only
    device : torch device of the field ("cpu", "cuda"); the inverse map runs on the matching Warp device
    config : narrow-band settings; None takes the asset's ``meta["narrowband"]`` (or the defaults)

    State: the rest sampler (:func:`neural.render.view.asset_sampler`, Embree scenes built once), the field,
    the cage, Warp meshes of the shells refitted to each deformed frame and the inverse map updated to it
    (both built on the first one): the renderer draws one frame at a time.
    """

    def __init__(self, asset, field, cage, device: str = "cpu", config=None):
        from neural.device import warp_device
        from neural.render.view import asset_sampler

        self.outer, self.inner = asset.outer_mesh(), asset.inner_mesh()
        for name, mesh in (("outer", self.outer), ("inner", self.inner)):
            embedded = len(mesh.vertices) if cage is None else len(getattr(cage, f"{name}_tet"))
            if embedded != len(mesh.vertices):
                raise ValueError(
                    f"cage: embeds {embedded} {name}-shell vertices but the asset's {name} shell has "
                    f"{len(mesh.vertices)}"
                )
        self.field = field
        self.cage = cage
        self.device = torch.device(device)
        self.warp_device = warp_device(str(device))
        self.config = asset.narrowband_config() if config is None else config
        self.background = torch.as_tensor(asset.background, dtype=torch.float32, device=self.device)
        self._rest = asset_sampler(asset, self.config, (self.outer, self.inner))
        self._deformed = None  # WarpCaster, built for the first deformed frame
        self._inverse = None  # the InverseMap, built for the first deformed frame and updated for the next

    def _frame(self, positions):
        """The sampler and the map to rest space (None at rest) of cage vertices ``positions`` (V, 3)."""
        from neural.device import kept_pool
        from neural.render.raycast import WarpCaster
        from neural.render.view import narrow_band_sampler

        from .deform import InverseMap

        if positions is None:
            return self._rest, None
        if self.cage is None:
            raise ValueError("positions: this renderer has no cage; it renders at rest only")
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != self.cage.vertices.shape:
            raise ValueError(
                f"positions: expected {self.cage.vertices.shape} like the cage, got {positions.shape}"
            )
        if self._deformed is None:
            c = self.cage
            self._deformed = WarpCaster(self.outer, self.inner, device=self.warp_device)
            self._deformed.set_blend(
                outer=(c.tets[c.outer_tet], c.outer_bary), inner=(c.tets[c.inner_tet], c.inner_bary)
            )

        def inverse_map():  # of these positions: built for the first frame, then updated
            if self._inverse is None:
                return InverseMap(positions, self.cage.tets, self.cage.vertices, self.warp_device)
            self._inverse.update(positions)
            return self._inverse

        # on the CPU the inverse map is made ready while the shells' BVHs are refitted (0.7x the time)
        on_cpu = self.warp_device == "cpu"
        future = kept_pool(1, "shellsim-frame").submit(inverse_map) if on_cpu else None
        self._deformed.refit_blended(positions)
        self._inverse = inverse_map() if future is None else future.result()
        return narrow_band_sampler(self._deformed, self.config), self._inverse

    def render(self, cameras, index: int, positions=None) -> tuple[np.ndarray, dict]:
        """Image (H, W, 3) float32 in [0, 1] of camera ``index`` of ``cameras`` with the cage at ``positions``
        (V, 3) (None: at rest, exactly :func:`neural.render.view.render_camera` with the asset's sampler),
        and the stats of ``render_camera`` plus ``build_ms`` (shell deformation, refitting their BVHs and
        updating the inverse map; both built on the first deformed frame) and ``ms`` with it."""
        from neural.render.view import render_camera

        start = time.perf_counter()
        sampler, to_rest = self._frame(positions)
        build = time.perf_counter() - start
        image, stats = render_camera(self.field, cameras, index, sampler, self.background, to_rest)
        stats["build_ms"] = 1000.0 * build
        stats["ms"] = 1000.0 * (time.perf_counter() - start)
        return image, stats


# --------------------------------------------------------------------------- cameras and frames


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
    from neural.data import Cameras, look_at

    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    el = math.radians(elevation_deg)
    view = math.cos(el) * (math.cos(azimuth) * e1 + math.sin(azimuth) * e2) + math.sin(el) * up
    c2w = look_at(np.asarray(center, dtype=np.float64) + distance * view, center, up)
    focal = 0.5 * width / math.tan(0.5 * math.radians(fov_deg))
    return Cameras(
        c2w[None],
        [focal],
        [focal],
        [0.5 * width],
        [0.5 * height],
        [width],
        [height],
        np.zeros((1, 4)),
        ["orbit"],
    )


def orbit_framing(points) -> tuple[np.ndarray, float]:
    """Centre (3,) and distance of an orbit that keeps ``points`` (N, 3) in view: the bounding box's
    centre and the distance at which its circumscribed sphere fills ``ORBIT_FOV_DEG`` (with 5% room)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = points.min(axis=0), points.max(axis=0)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    return 0.5 * (lo + hi), 1.05 * radius / math.sin(0.5 * math.radians(ORBIT_FOV_DEG))


# --------------------------------------------------------------------------- files


def save_png(path: Path, image: np.ndarray, record: dict | None = None) -> None:
    """Write an (H, W, 3) float image in [0, 1] as an 8-bit PNG atomically (temporary file + rename), so a
    PNG on disk is always complete; ``record`` (see :func:`frame_record`) goes into its text chunk
    ``RECORD_CHUNK`` as JSON."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    if record is not None:
        info.add_text(RECORD_CHUNK, json.dumps(record, sort_keys=True))
    tmp = path.with_name(path.stem + ".tmp.png")
    Image.fromarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8), "RGB").save(tmp, pnginfo=info)
    os.replace(tmp, path)


def digest(*parts) -> str:
    """Short SHA-256 of ``parts``: arrays (their dtype, shape and bytes), strings, bytes or files (Path)."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, Path):
            with open(part, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        elif isinstance(part, bytes | str):
            h.update(part.encode() if isinstance(part, str) else part)
        else:
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        h.update(b"|")
    return h.hexdigest()[:16]


def asset_identity(asset, cage=None) -> str:
    """Digest of what an asset's images depend on: its field weights and configuration, normalisation,
    shells and the rest ``cage`` (:class:`shellsim.cage.Cage`, when it deforms them) by content."""
    meta = {k: asset.meta.get(k) for k in ("normalisation", "field")}
    files = [asset.file("field"), asset.file("shell_outer"), asset.file("shell_inner")]
    return digest(json.dumps(meta, sort_keys=True), *files, *([cage.vertices, cage.tets] if cage else []))


def frame_record(motion: str, camera, asset: str, renderer: str) -> dict:
    """What makes a frame, stored in its PNG: ``motion`` (digest of the cage frame, "rest" without one),
    ``camera`` (digest of the one camera of the ``Cameras`` ``camera``), ``size`` ("WxH"), ``asset``
    (:func:`asset_identity` or another digest of what is drawn) and ``renderer`` (digest of its settings)."""
    c = camera
    return {
        "motion": motion,
        "camera": digest(c.c2w, c.fx, c.fy, c.cx, c.cy, c.distortion),
        "size": f"{int(c.width[0])}x{int(c.height[0])}",
        "asset": asset,
        "renderer": renderer,
    }


#: How a record field that differs is named in the log.
_RECORD_NAMES = {
    "motion": "motion frame",
    "camera": "camera",
    "size": "size",
    "asset": "asset",
    "renderer": "renderer settings",
}


def stale_reason(path: Path, record: dict) -> str | None:
    """None when the PNG ``path`` exists and was made as ``record`` says; else why it must be rendered:
    "" (no such file) or what differs, e.g. "another size (32x32, now 48x48)"."""
    from PIL import Image

    if not path.is_file():
        return ""
    try:
        with Image.open(path) as image:
            stored = json.loads(image.info[RECORD_CHUNK])
    except (OSError, KeyError, ValueError):
        return "no record of what made it"
    if not isinstance(stored, dict):
        return "no record of what made it"
    differ = [k for k in record if stored.get(k) != record[k]]
    if not differ:
        return None
    parts = [f"another {_RECORD_NAMES[k]}" for k in differ]
    if "size" in differ:
        parts[differ.index("size")] += f" ({stored.get('size')}, now {record['size']})"
    return ", ".join(parts)


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
            from .distributed import run_on_ray

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


def write_video(frames: list[Path], path, fps: float) -> Path:
    """Assemble PNG ``frames`` into an H.264 MP4 at ``fps`` with imageio-ffmpeg (odd sizes are padded by
    one edge row / column: H.264's 4:2:0 chroma needs even sizes)."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("frames: nothing to assemble")
    if not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps: expected a positive number, got {fps}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    with imageio.get_writer(
        tmp, fps=fps, codec="libx264", macro_block_size=1, quality=8, pixelformat="yuv420p", format="FFMPEG"
    ) as writer:
        for frame in frames:
            image = np.asarray(imageio.imread(frame))[..., :3]
            h, w = image.shape[:2]
            writer.append_data(np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge"))
    os.replace(tmp, path)
    return path


def motion_fps(motion) -> float:
    """Frames per second of a motion: its ``meta["fps"]``, else from its times, else 30."""
    fps = motion.meta.get("fps")
    if isinstance(fps, int | float) and fps > 0 and math.isfinite(fps):
        return float(fps)
    dt = np.diff(motion.times)
    if dt.size and np.median(dt) > 0:
        return float(1.0 / np.median(dt))
    return 30.0


# --------------------------------------------------------------------------- whole renders


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


def renderer_identity(asset) -> str:
    """Digest of the narrow-band renderer's settings for ``asset`` (its sampling and background)."""
    from dataclasses import asdict

    settings = {"narrowband": asdict(asset.narrowband_config()), "background": list(asset.background)}
    return digest("narrow band", json.dumps(settings, sort_keys=True))


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

    from .cage import cage_for_motion
    from .motion import load_motion

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

    asset_spec : asset directory or shipped name; motion_path : ``.npz`` of :mod:`shellsim.motion` made
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

    from .cage import cage_for_motion
    from .motion import load_motion

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
