"""Render an asset to PNG frames (and an MP4): every camera of a camera file at rest, or the frames of a
motion deformed by its cage (paper Sec. 5), or of a scene's motion (every body in one image), or a motion's
own surface without an asset.

The renderers are :func:`shellsim.film.motion_frames.render_views`,
:func:`shellsim.film.motion_frames.render_motion`,
:func:`shellsim.film.shot_frames.render_scene` and :func:`shellsim.viz.surface.render_surface_motion`;
this module checks the settings and outputs first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from neural.device import DEVICES
from shellsim.errors import SettingError
from shellsim.film.cameras import (
    MOTION_ANTIALIAS,
    OPTIONS,
    VIDEO_SIZE,
    CameraSettings,
    camera_option,
    check_antialias,
)
from shellsim.film.motion_frames import QUALITIES
from shellsim.film.result import RenderResult
from shellsim.film.world import WorldSettings, world_option
from shellsim.io.outputs import check_writable_dir, check_writable_file, holds_outputs, lock_output
from shellsim.memory import check_memory, render_bytes
from shellsim.settings import check_choice, check_required, device_setting, option

MOTION_ONLY = ("frames", "video", "fps", *OPTIONS)


@dataclass(frozen=True)
class RenderSettings:
    """What ``shellsim render`` takes; ``quiet`` keeps VTK's warnings off stderr."""

    asset: str | None = option(
        help="asset directory or shipped asset name; without it, --motion draws the surface the motion "
        "carries (e.g. from 'simulate --mesh') with pyvista"
    )
    motion: str | None = option(help="motion file (.npz) from 'shellsim simulate' or 'shellsim wind'")
    scene: str | None = option(
        help="output directory of 'shellsim scene' (or its motion.npz): every body in one image, on the "
        "scene's ground among its colliders, seen by one of its [[camera]] tables or by --camera"
    )
    scene_camera: str | None = option(
        help="with --scene: the scene file's [[camera]] of this name",
        shown_default="its first, or a three-quarter orbit framed to the bodies",
        metavar="NAME",
    )
    cameras: str | None = option(
        help="camera file or dataset directory, any format 'train --data' reads (NeRF-synthetic "
        "transforms_*.json, instant-ngp / nerfstudio transforms.json with fl_x fl_y cx cy k1 k2 p1 p2 w h); "
        "every listed frame is a camera (in the asset's frame), its image may be absent; with --motion, "
        "instead of --camera, its first camera views every frame",
    )
    camera: str | None = camera_option("camera")
    orbit_degrees: float | None = camera_option("orbit_degrees")
    camera_position: tuple[float, float, float] | None = camera_option("camera_position")
    look_at: tuple[float, float, float] | None = camera_option("look_at")
    out: str = option(help="directory of the PNG frames", required=True)
    frames: str | None = option(
        help="with --motion: frames START:END[:STEP] (END exclusive; every STEP-th frame)",
        shown_default="all",
    )
    width: int | None = option(
        help="image width", shown_default=f"the camera file's; --camera: {VIDEO_SIZE[0]}"
    )
    height: int | None = option(
        help="image height; the file's pixel intrinsics are scaled to the size",
        shown_default="the camera file's, or its aspect ratio with --width alone; --camera: as --width",
    )
    video: str | None = option(help="with --motion: also write the frames as this MP4")
    fps: float | None = option(help="video frame rate", shown_default="the motion's")
    antialias: int | None = option(
        help="jittered rays per pixel, averaged, where a pixel's neighbourhood varies (edges, texture, "
        "silhouettes; one ray elsewhere); 1: one ray through each pixel's centre, as 'eval' scores",
        shown_default=f"{MOTION_ANTIALIAS} with --motion, else 1",
    )
    ground: bool = option(
        True, help="with --motion: draw no ground, only the sky", flag="--no-ground", negate=True
    )
    ground_colors: tuple[float, ...] = world_option("ground_colors")
    light: tuple[float, ...] = world_option("light")
    sky: tuple[float, ...] = world_option("sky")
    quality: str = option(
        "final",
        help="final: the frames asked for; preview: half the size, one ray per pixel, no shadows (a look at "
        "a whole shot in seconds; a final render later renders them again)",
        choices=QUALITIES,
    )
    overwrite: bool = option(False, help="render frames already in OUT again")
    device: str = option("auto", help="cpu, cuda or auto")
    ray: str | None = option(
        help="render the frames as Ray tasks: alone, on a local Ray instance using every core; with an "
        "ADDRESS, on that cluster ('auto': the one this machine belongs to; the asset and motion paths must "
        "exist on every node)",
        const="local",
        metavar="ADDRESS",
    )
    quiet: bool = True

    def __post_init__(self):
        check_required(self)
        if self.scene is not None:
            for name in ("motion", "asset", "cameras"):
                if getattr(self, name) is not None:
                    raise SettingError(name, "not with {scene} (its bodies name their own assets)")
        elif self.scene_camera is not None:
            raise SettingError("scene_camera", "needs {scene}")
        if self.scene_camera is not None and self.camera is not None:
            raise SettingError("scene_camera", "give one of {scene_camera} and {camera}")
        moving = self.motion or self.scene
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise SettingError(name, f"expected a positive size, got {value}")
        if moving is None:
            for name in MOTION_ONLY:
                if getattr(self, name) not in (None, False):
                    raise SettingError(name, "needs {motion} (without it every camera is rendered at rest)")
        world = WorldSettings.of(self)
        for name in ([] if self.ground else ["ground"]) + world.changed():
            if moving is None:
                raise SettingError(name, "needs {motion} (views at rest show no world)")
        if moving is None and self.cameras is None:
            raise SettingError("cameras", "needed to render at rest (without a {motion})")
        if self.cameras is not None and any(getattr(self, name) is not None for name in OPTIONS):
            raise SettingError("cameras", "give one of {cameras} and {camera}")
        CameraSettings.of(self)
        if self.fps is not None and not (self.fps > 0 and math.isfinite(self.fps)):
            raise SettingError("fps", f"expected a positive number, got {self.fps}")
        if self.antialias is not None:
            check_antialias(self.antialias)
        check_choice("quality", self.quality, QUALITIES)
        if self.quality == "preview" and self.antialias is not None:
            raise SettingError("antialias", "not with {quality} preview (one ray per pixel)")
        check_choice("device", self.device, DEVICES)
        if self.scene is not None:
            return
        if self.asset is None and not (self.motion is not None and self.cameras is None):
            raise SettingError("asset", "needed, unless a {motion} without {cameras} draws its own surface")
        if self.asset is None and self.ray is not None:
            raise SettingError("ray", "renders an asset's frames; a motion's own surface is drawn here")
        if self.asset is None and self.antialias is not None:
            raise SettingError("antialias", "renders an asset's frames; pyvista draws a motion's own surface")
        if self.asset is None and self.quality != "final":
            raise SettingError("quality", "renders an asset's frames; pyvista draws a motion's own surface")
        for name in ([] if self.ground else ["ground"]) + world.changed():
            if self.asset is None:
                raise SettingError(
                    name, "sets the world around an asset's frames; pyvista draws a motion's own surface"
                )

    def size(self) -> tuple[int | None, int | None] | None:
        """(W, H) of the frames: None, the camera file's; a missing side keeps the file's aspect ratio;
        a motion's world camera makes square ones."""
        if self.cameras is None:
            side = self.width or self.height or VIDEO_SIZE[0]
            return (self.width or side, self.height or side)
        if self.width is None and self.height is None:
            return None
        return (self.width, self.height)


@holds_outputs
def render(settings: RenderSettings) -> RenderResult:
    """Render what ``settings`` ask for; returns the :class:`~shellsim.film.result.RenderResult` (the
    frames, how many were rendered, kept and replaced, mean ms per frame and per stage, the video). Outputs
    and the frame range are checked before torch or pyvista is imported."""
    lock_output(check_writable_dir(settings.out, "out"), "out")
    if settings.ray is not None:
        from shellsim.distributed import require_ray

        require_ray()
    if settings.video:
        lock_output(check_writable_file(settings.video, "video"), "video")
    if settings.motion is not None or settings.scene is not None:
        from shellsim.motion.read import read_motion_info
        from shellsim.settings import parse_frames
        from shellsim.shot.recorded import motion_path

        path = motion_path(settings.scene) if settings.scene else settings.motion
        parse_frames(settings.frames, read_motion_info(path).n_frames, str(path))
    size = settings.size()
    if size and None not in size:
        what = f"a frame of {size[0]}x{size[1]} pixels"
        check_memory("width", render_bytes(*size), what, "to render", device_setting(settings.device))
    common = dict(size=size, overwrite=settings.overwrite)
    frames = dict(  # of a motion's frames drawn by a field
        frames=settings.frames,
        video=settings.video,
        fps=settings.fps,
        device=settings.device,
        ray=settings.ray,
        antialias=settings.antialias or MOTION_ANTIALIAS,
        look=WorldSettings.of(settings).look(settings.ground),
        quality=settings.quality,
        **common,
    )
    if settings.scene is not None:
        from shellsim.film.shot_frames import render_scene

        camera = CameraSettings.of(settings) if settings.camera else None
        frames.update(look=WorldSettings.of(settings), ground=settings.ground)  # over the scene's own look
        return render_scene(settings.scene, settings.out, settings.scene_camera, camera=camera, **frames)
    if settings.asset is None:
        from shellsim.viz.inspect import quiet_vtk
        from shellsim.viz.surface import render_surface_motion

        if settings.quiet:
            quiet_vtk()
        return render_surface_motion(
            settings.motion,
            settings.out,
            settings.frames,
            video=settings.video,
            fps=settings.fps,
            camera=CameraSettings.of(settings),
            **common,
        )
    if settings.motion is None:
        from shellsim.film.motion_frames import render_views

        return render_views(
            settings.asset,
            settings.cameras,
            settings.out,
            device=settings.device,
            ray=settings.ray,
            antialias=settings.antialias or 1,
            quality=settings.quality,
            **common,
        )
    from shellsim.film.motion_frames import render_motion

    camera = None if settings.cameras else CameraSettings.of(settings)
    return render_motion(
        settings.asset, settings.motion, settings.out, cameras=settings.cameras, camera=camera, **frames
    )
