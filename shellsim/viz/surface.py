"""Seeing a motion without a neural asset: the moving surface drawn with pyvista off-screen.

A motion made by ``shellsim simulate --mesh`` carries the mesh's surface embedded in its cage
(:class:`shellsim.motion.format.Surface`): frame ``k`` puts every surface point at the barycentric
interpolation of the frame's cage vertices in its rest tet (paper Sec. 5). A motion without one shows the
boundary of its cage. :class:`SurfaceRenderer` draws that surface, opaque and shaded, through a pinhole
camera of :class:`neural.data.Cameras`; :func:`render_surface_motion` renders a motion's frames to PNGs
(and an MP4) with the cameras of :mod:`shellsim.film.cameras` and the frame records of
:func:`shellsim.film.motion_frames.render_motion`
(a PNG already there is kept only when it records the same motion frame, camera, size and surface);
:func:`surface_plotter` is the inspector's view of it (surface, cage wireframe, frame slider).
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from shellsim.film.result import RenderResult
from shellsim.viz.inspect import CAGE_COLOR, _pyvista, frame_label

log = logging.getLogger(__name__)

SURFACE_COLOR = "lightsteelblue"


def surface_faces(motion) -> np.ndarray:
    """(F, 3) int64 triangles of the motion's surface (or of its cage's boundary)."""
    from shellsim.tetcage.geometry import boundary_faces

    return motion.surface.faces if motion.surface is not None else boundary_faces(motion.tets)


def surface_points(motion, k: int) -> np.ndarray:
    """(S, 3) float64 points of the motion's surface in frame ``k`` (the cage vertices without a surface)."""
    if motion.surface is None:
        return np.asarray(motion.positions[k], np.float64)
    return motion.surface_points(k)


def point_camera(plotter, cameras, index: int = 0) -> None:
    """Make ``plotter``'s camera camera ``index`` of ``cameras`` (OpenGL camera-to-world, looking along -z);
    VTK's camera is a centred pinhole, so a principal point off the image centre or a lens distortion is a
    ValueError."""
    w, h = int(cameras.width[index]), int(cameras.height[index])
    cx, cy = float(cameras.cx[index]), float(cameras.cy[index])
    if abs(cx - w / 2) > 0.5 or abs(cy - h / 2) > 0.5 or np.any(cameras.distortion[index] != 0):
        raise ValueError(f"cameras: camera {index} is not a centred pinhole camera without distortion")
    c2w = np.asarray(cameras.c2w[index], np.float64)
    camera = plotter.camera
    camera.position = tuple(c2w[:3, 3])
    camera.focal_point = tuple(c2w[:3, 3] - c2w[:3, 2])
    camera.up = tuple(c2w[:3, 1])
    camera.view_angle = math.degrees(2 * math.atan(0.5 * h / float(cameras.fy[index])))
    plotter.renderer.ResetCameraClippingRange()


class SurfaceRenderer:
    """Draws a motion's surface off-screen at ``width`` x ``height`` pixels.

    State: the pyvista plotter (one window, reused for every frame); :meth:`close` releases it.
    """

    def __init__(self, motion, width: int, height: int):
        pv = _pyvista()
        self.motion = motion
        self.faces = surface_faces(motion)
        theme = pv.themes.DocumentTheme()
        self.plotter = pv.Plotter(off_screen=True, window_size=[width, height], theme=theme)
        self.size = (width, height)

    def render(self, cameras, index: int, k: int) -> tuple[np.ndarray, dict]:
        """Image (H, W, 3) float32 in [0, 1] of motion frame ``k`` seen by camera ``index`` of ``cameras``
        (of this renderer's size), and stats {"ms": ...}."""
        pv = _pyvista()
        if (int(cameras.width[index]), int(cameras.height[index])) != self.size:
            raise ValueError(f"cameras: camera {index} is not {self.size[0]}x{self.size[1]} as rendered")
        start = time.perf_counter()
        mesh = pv.PolyData.from_regular_faces(surface_points(self.motion, k), self.faces)
        self.plotter.add_mesh(
            mesh, name="surface", color=SURFACE_COLOR, smooth_shading=True, split_sharp_edges=True
        )
        point_camera(self.plotter, cameras, index)
        image = self.plotter.screenshot(return_img=True)[..., :3]
        return image.astype(np.float32) / 255.0, {"ms": 1000.0 * (time.perf_counter() - start)}

    def close(self) -> None:
        self.plotter.close()


def _motion_up(motion) -> np.ndarray:
    """The up axis a motion was simulated with (``meta["up"]``; format 1: ``meta["params"]["up"]``), else
    +z."""
    up = motion.meta.get("up") or motion.meta.get("params", {}).get("up", [0.0, 0.0, 1.0])
    return np.asarray(up, np.float64)


def render_surface_motion(
    motion_path,
    out_dir,
    frames: str | None = None,
    size: tuple[int, int] | None = None,
    video=None,
    fps: float | None = None,
    overwrite: bool = False,
    progress: bool = True,
    camera=None,
) -> RenderResult:
    """Render a motion's surface to ``out_dir/<k:05d>.png`` (and an MP4) seen by ``camera``
    (:class:`~shellsim.film.cameras.CameraSettings` in world metres about the motion's up axis; None:
    the default orbit) as :func:`shellsim.film.motion_frames.render_motion` would; ``frames``, ``size``
    (default
    :data:`~shellsim.film.cameras.VIDEO_SIZE`), ``video``, ``fps`` and ``overwrite`` as there. Returns its
    :class:`~shellsim.film.result.RenderResult` (counts, ``ms``, ``video``)."""
    from shellsim.film.cameras import VIDEO_SIZE, CameraSettings, mass_weights, motion_track
    from shellsim.film.motion_frames import motion_frame_ids, render_frames, with_video
    from shellsim.io.png import digest, frame_record
    from shellsim.motion.read import load_motion
    from shellsim.settings import parse_frames

    motion = load_motion(motion_path)
    indices = parse_frames(frames, motion.n_frames, source=str(motion_path))
    if fps is not None and not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps: expected a positive number, got {fps}")
    width, height = size or VIDEO_SIZE
    track = motion_track([motion.positions], mass_weights(motion.rest_vertices, motion.tets), motion.times)
    shot = (camera or CameraSettings()).shot(track, width, height, up=_motion_up(motion))
    s = motion.surface
    drawn = digest("surface", *((s.tet, s.bary, s.faces) if s is not None else ("cage boundary",)))
    settings = digest("pyvista surface", SURFACE_COLOR)
    frame_ids = motion_frame_ids(motion, motion.positions)
    out_dir = Path(out_dir)
    jobs = []
    for k in indices:
        view = shot.camera_for_frame(k)
        jobs.append((out_dir / f"{k:05d}.png", frame_record(frame_ids[k], view, drawn, settings), (view, k)))
    out_dir.mkdir(parents=True, exist_ok=True)
    renderer = SurfaceRenderer(motion, width, height)
    try:
        result = render_frames(
            jobs, out_dir, overwrite, progress, lambda: lambda job: renderer.render(job[0], 0, job[1])
        )
    finally:
        renderer.close()
    return with_video(result, video, fps, motion, indices)


def surface_plotter(motion, frame: int = 0, size=(1024, 768), off_screen: bool | None = None, slider=False):
    """A ``pyvista.Plotter`` of the motion's surface (opaque) and its cage (wireframe) at ``frame``, with a
    title; ``slider`` adds a frame slider."""
    pv = _pyvista()
    from shellsim.tetcage.geometry import boundary_faces

    n = motion.n_frames
    if not -n <= frame < n:
        raise ValueError(f"frame: expected a frame index in 0..{n - 1} (or -{n}..-1), got {frame}")
    frame %= n
    faces, cage_faces = surface_faces(motion), boundary_faces(motion.tets)
    plotter = pv.Plotter(off_screen=off_screen, window_size=list(size), theme=pv.themes.DocumentTheme())

    def pose(k: int) -> None:
        surface = pv.PolyData.from_regular_faces(surface_points(motion, k), faces)
        plotter.add_mesh(
            surface, name="surface", color=SURFACE_COLOR, smooth_shading=True, split_sharp_edges=True
        )
        cage = pv.PolyData.from_regular_faces(np.asarray(motion.positions[k], np.float64), cage_faces)
        plotter.add_mesh(cage, name="cage", style="wireframe", color=CAGE_COLOR, line_width=1, opacity=0.3)
        plotter.add_text(frame_label(motion, k), position="upper_left", font_size=12, name="title")

    pose(frame)
    if slider and n > 1:
        plotter.add_slider_widget(
            lambda value: pose(int(round(value))),
            [0, n - 1],
            value=frame,
            title="frame",
            fmt="%.0f",
            pointa=(0.55, 0.92),
            pointb=(0.95, 0.92),
        )
    from shellsim.film.cameras import orbit_camera, orbit_framing

    center, distance = orbit_framing(motion.positions)  # every frame in view, also in a wide window's height
    distance *= max(1.0, size[0] / size[1])
    point_camera(plotter, orbit_camera(center, distance, _motion_up(motion), math.pi / 4, *size))
    return plotter
