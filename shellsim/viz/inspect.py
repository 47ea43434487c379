"""Inspection views of an asset (the ``inspect`` job of docs/architecture.md): the shells, the cage and a
motion's frames with pyvista.

The scene is three meshes in the asset's own frame at rest, in the world (metres, z up, the ground at z = 0)
with a motion, which also draws the ground and the obstacles it was simulated with (:func:`world_scene`):

- ``"outer"``: ``M+``, drawn translucent and coloured per vertex by either

  * ``color="width"``: the shell width, the distance from each ``M+`` vertex to the surface ``M-``
    (libigl point-to-mesh distance), or
  * ``color="kernel"``: the field's kernel size ``s`` (asset units) at each ``M+`` vertex, the quantity
    whose size made the shell wide or narrow (paper Sec. 3.3, Eq. 4-7);

  both are computed in rest space and stay attached to the vertices when the cage moves;
- ``"inner"``: ``M-``, opaque;
- ``"cage"``: the cage's boundary triangles, drawn as a wireframe. Its points are all ``V`` cage vertices
  (interior ones are referenced by no face and not drawn), so a frame's points are the motion's positions.

With a motion, frame ``k`` moves the cage to ``motion.positions[k]`` and the shells with it by barycentric
interpolation of the cage vertices (paper Sec. 5, :func:`shellsim.tetcage.embed.interpolate`).

:func:`build_scene` makes the meshes (no rendering, testable), :func:`pose_scene` moves them to a frame,
:func:`make_plotter` puts them in a pyvista plotter, :func:`show` opens an interactive window with a frame
slider and :func:`screenshot` renders the same view off-screen to a PNG.

pyvista (and VTK) are imported on first use: everything else in shellsim works without them. Off-screen
rendering needs no display: VTK >= 9.4 wheels fall back to EGL (system Mesa: ``libegl1``,
``libegl-mesa0``, ``libgl1-mesa-dri``) or OSMesa (``libosmesa6``) when no X server is reachable.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from neural.errors import InputError, ShellsimError
from shellsim.tetcage.embed import interpolate
from shellsim.world import GROUND_Z, has_ground

#: Point-data array of ``M+`` holding the colouring, per ``color`` option.
SCALARS = {"width": "shell width", "kernel": "kernel size s"}
#: Default image size of :func:`screenshot`, (width, height) pixels.
DEFAULT_SIZE = (1024, 768)
OUTER_OPACITY = 0.35
INNER_COLOR = "lightgray"
CAGE_COLOR = "black"
GROUND_COLOR = "tan"
OBSTACLE_COLOR = "steelblue"
#: The colour bar's box (x, y, width, height) as fractions of the window, labels included; its title is above.
BAR_BOX = (0.3, 0.04, 0.55, 0.08)


def _pyvista():
    try:
        import pyvista
    except ImportError as err:
        raise ShellsimError(
            f"inspecting needs pyvista, which cannot be imported ({err}): pip install pyvista"
        ) from None
    return pyvista


def quiet_vtk() -> None:
    """Keep VTK's own warnings off stderr (e.g. "bad X server connection" when it falls back to off-screen
    rendering without a display); its errors still show."""
    from vtkmodules.vtkCommonCore import vtkLogger, vtkObject

    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    vtkObject.GlobalWarningDisplayOff()


def _check_frame(motion, frame: int) -> int:
    if isinstance(frame, bool) or not isinstance(frame, int | np.integer):
        raise TypeError(f"frame: expected an int, got {type(frame).__name__}")
    n = 1 if motion is None else motion.n_frames
    if not -n <= frame < n:
        raise ValueError(f"frame: expected a frame index in 0..{n - 1} (or -{n}..-1), got {frame}")
    return int(frame) % n


def shell_width(outer_vertices, inner_vertices, inner_faces) -> np.ndarray:
    """Distance from each ``M+`` vertex to the surface ``M-``.

    outer_vertices : (Vo, 3) float, inner_vertices : (Vi, 3) float, inner_faces : (Fi, 3) int
    returns : (Vo,) float64, unsigned distance to the nearest point of the triangles of ``M-``
    """
    import igl

    outer_vertices = np.asarray(outer_vertices, dtype=np.float64)
    sq_dist, _, _ = igl.point_mesh_squared_distance(
        outer_vertices, np.asarray(inner_vertices, np.float64), np.asarray(inner_faces, np.int64)
    )
    return np.sqrt(sq_dist)


def kernel_size(asset, points, device: str = "cpu") -> np.ndarray:
    """The field's kernel size ``s`` (asset units) at asset-frame points (N, 3) -> (N,) float64.

    Loads the asset's field (torch); a field that cannot be loaded is a :class:`ShellsimError` naming why.
    """
    from neural.asset import load_field

    try:
        import torch

        field = load_field(asset, device)
    except ImportError as err:
        raise ShellsimError(
            f"colouring by kernel size needs the neural field, which cannot be imported ({err}); "
            "colour by shell width instead"
        ) from None
    x = torch.as_tensor(np.asarray(points, dtype=np.float32), device=device)
    _, s = field.sdf_and_kernel(x)
    return s.double().cpu().numpy()


def frame_points(cage, positions) -> dict[str, np.ndarray]:
    """Points of the scene's meshes for cage vertices ``positions`` (V, 3).

    returns : {"outer": (Vo, 3), "inner": (Vi, 3), "cage": (V, 3)} float64
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.shape != cage.vertices.shape:
        raise ValueError(f"positions: expected {cage.vertices.shape}, got {positions.shape}")
    return {
        "outer": interpolate(positions, cage.tets, cage.outer_tet, cage.outer_bary),
        "inner": interpolate(positions, cage.tets, cage.inner_tet, cage.inner_bary),
        "cage": positions,
    }


def pose_scene(scene: dict, cage, positions) -> None:
    """Move the meshes of :func:`build_scene` in place to cage vertices ``positions`` (V, 3)."""
    for name, points in frame_points(cage, positions).items():
        scene[name].points = points


def build_scene(asset, cage, motion=None, color: str = "width", frame: int = 0, device: str = "cpu") -> dict:
    """The meshes to draw (module docstring), posed at ``frame`` of ``motion`` (None: the rest state).

    asset : :class:`neural.asset.Asset`, cage : its :class:`shellsim.tetcage.build.Cage`,
    motion : :class:`shellsim.motion.format.Motion` of this cage or None, color : "width" or "kernel",
    frame : frame index (negative counts from the end), device : torch device of the kernel-size colouring.
    returns : {"outer": pyvista.PolyData with point data ``SCALARS[color]`` (Vo,), "inner": pyvista.PolyData,
        "cage": pyvista.PolyData of the cage's boundary triangles over all V cage vertices}
    """
    if color not in SCALARS:
        raise ValueError(f"color: expected one of {sorted(SCALARS)}, got {color!r}")
    if motion is not None:
        motion.check_against(cage)
    frame = _check_frame(motion, frame)
    pv = _pyvista()
    from shellsim.tetcage.geometry import boundary_faces

    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    for name, mesh in (("outer", outer), ("inner", inner)):
        if len(getattr(cage, f"{name}_tet")) != len(mesh.vertices):
            raise InputError(
                f"{asset.cage_path}: the cage embeds {len(getattr(cage, f'{name}_tet'))} vertices of the "
                f"{name} shell, which has {len(mesh.vertices)}; rebuild the cage"
            )
    if color == "width":
        values = shell_width(outer.vertices, inner.vertices, inner.faces)
    else:
        values = kernel_size(asset, outer.vertices, device)
    scene = {
        "outer": pv.PolyData.from_regular_faces(np.asarray(outer.vertices, np.float64), outer.faces),
        "inner": pv.PolyData.from_regular_faces(np.asarray(inner.vertices, np.float64), inner.faces),
        "cage": pv.PolyData.from_regular_faces(
            np.asarray(cage.vertices, np.float64), boundary_faces(cage.tets)
        ),
    }
    scene["outer"].point_data[SCALARS[color]] = values
    scene["outer"].set_active_scalars(SCALARS[color])
    if motion is not None:
        pose_scene(scene, cage, motion.positions[frame])
    return scene


def world_scene(motion) -> dict:
    """The world a motion was simulated in, to draw beside its body: ``"ground"`` (the plane z = 0 under
    the motion, 1.5 times its extent, when it has one: :func:`shellsim.world.has_ground`) and ``"sphere k"``
    / ``"box k"``
    (its obstacles, as its settings give them), pyvista meshes in the motion's frame (world metres; the
    asset's units for motions made before the world was in metres, which draw no ground). Empty for a
    motion without them."""
    pv = _pyvista()
    scene = {}
    settings = motion.settings or {}
    for k, (x, y, z, r) in enumerate(settings.get("sphere") or ()):
        scene[f"sphere {k + 1}"] = pv.Sphere(r, (x, y, z), theta_resolution=32, phi_resolution=32)
    for k, (x, y, z, hx, hy, hz) in enumerate(settings.get("box") or ()):
        scene[f"box {k + 1}"] = pv.Box(bounds=(x - hx, x + hx, y - hy, y + hy, z - hz, z + hz))
    if motion.placement and has_ground(settings):
        points = motion.positions.reshape(-1, 3)
        lo, hi = points.min(0), points.max(0)
        centre, extent = 0.5 * (lo + hi), 1.5 * float((hi - lo)[:2].max())
        scene["ground"] = pv.Plane(
            center=(centre[0], centre[1], GROUND_Z), direction=(0, 0, 1), i_size=extent, j_size=extent
        )
    return scene


def frame_label(motion, frame: int) -> str:
    """``"frame 3 of 0..9, t = 0.300 s"`` for frame index ``frame`` of ``motion`` ("" without a motion)."""
    if motion is None:
        return ""
    frame = _check_frame(motion, frame)
    return f"frame {frame} of 0..{motion.n_frames - 1}, t = {motion.times[frame]:.3f} s"


def make_plotter(
    asset,
    cage,
    motion=None,
    frame: int = 0,
    color: str = "width",
    size: tuple[int, int] = DEFAULT_SIZE,
    off_screen: bool | None = None,
    slider: bool = False,
    device: str = "cpu",
):
    """A ``pyvista.Plotter`` showing :func:`build_scene` with a title and a scalar bar.

    size : (width, height) pixels; off_screen : None follows ``pyvista.OFF_SCREEN``;
    slider : with a motion, add a frame slider that moves cage and shells and updates the title's time.
    """
    pv = _pyvista()
    if len(size) != 2 or not all(isinstance(v, int | np.integer) and v > 0 for v in size):
        raise ValueError(f"size: expected (width, height) positive ints, got {size!r}")
    scene = build_scene(asset, cage, motion, color, frame, device)
    frame = _check_frame(motion, frame)
    plotter = pv.Plotter(
        off_screen=off_screen, window_size=[int(v) for v in size], theme=pv.themes.DocumentTheme()
    )
    scalars = SCALARS[color]
    plotter.add_mesh(
        scene["outer"],
        name="outer",
        scalars=scalars,
        cmap="viridis" if color == "width" else "plasma",
        log_scale=color == "kernel",
        opacity=OUTER_OPACITY,
        smooth_shading=True,
        scalar_bar_args={  # untitled: VTK sets a horizontal bar's title over its middle label
            "title": "",
            "n_labels": 3,
            "fmt": "%.3g",
            "position_x": BAR_BOX[0],
            "position_y": BAR_BOX[1],
            "width": BAR_BOX[2],
            "height": BAR_BOX[3],
        },
    )
    bar_title = plotter.add_text(  # centred over the bar's labels, 6 pixels above its box
        f"{scalars} (asset units)",
        position=(BAR_BOX[0] + BAR_BOX[2] / 2, BAR_BOX[1] + BAR_BOX[3] + 6 / size[1]),
        viewport=True,
        font_size=12,
        name="bar title",
    )
    bar_title.GetTextProperty().SetJustificationToCentered()
    plotter.add_mesh(scene["inner"], name="inner", color=INNER_COLOR, smooth_shading=True)
    plotter.add_mesh(
        scene["cage"], name="cage", style="wireframe", color=CAGE_COLOR, line_width=1, opacity=0.5
    )
    for name, mesh in (world_scene(motion) if motion is not None else {}).items():
        color = GROUND_COLOR if name == "ground" else OBSTACLE_COLOR
        plotter.add_mesh(mesh, name=name, color=color, smooth_shading=name.startswith("sphere"))

    def title(k: int) -> None:
        text = " - ".join(filter(None, (asset.name, frame_label(motion, k))))
        plotter.add_text(text, position="upper_left", font_size=12, name="title")

    title(frame)
    if slider and motion is not None and motion.n_frames > 1:
        shown = [frame]

        def set_frame(value: float) -> None:
            k = int(round(value))
            if k != shown[0]:
                shown[0] = k
                pose_scene(scene, cage, motion.positions[k])
                title(k)

        plotter.add_slider_widget(
            set_frame,
            [0, motion.n_frames - 1],
            value=frame,
            title="frame",
            fmt="%.0f",
            pointa=(0.55, 0.92),
            pointb=(0.95, 0.92),
            interaction_event="always",
        )
    plotter.view_isometric()
    plotter.reset_camera()
    return plotter


def _has_display() -> bool:
    return not sys.platform.startswith("linux") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )


def check_display() -> None:
    """A :class:`ShellsimError` unless a window can be opened (a display, or pyvista set off-screen)."""
    if not _pyvista().OFF_SCREEN and not _has_display():
        raise ShellsimError("no display to open a window on (DISPLAY is not set)")


def show_plotter(plotter) -> None:
    """Open ``plotter``'s interactive window; returns when it is closed."""
    check_display()
    plotter.show()


def save_screenshot(plotter, path) -> Path:
    """Render the off-screen ``plotter`` to the PNG ``path`` and close it."""
    try:
        plotter.screenshot(str(path))
    finally:
        plotter.close()
    return Path(path)


def show(
    asset, cage, motion=None, frame: int = 0, color: str = "width", size=DEFAULT_SIZE, device="cpu"
) -> None:
    """Open an interactive window of the scene (a frame slider with a motion); returns when it is closed."""
    check_display()  # before the scene is built
    show_plotter(make_plotter(asset, cage, motion, frame, color, size, slider=True, device=device))


def screenshot(
    asset, cage, path, motion=None, frame: int = 0, color: str = "width", size=DEFAULT_SIZE, device="cpu"
) -> Path:
    """Render the scene off-screen at ``frame`` to the PNG ``path`` of ``size`` (width, height) pixels."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: the screenshot is written as PNG; give a file name ending in .png")
    if not path.parent.is_dir():
        raise InputError(f"{path}: directory {path.parent} does not exist")
    plotter = make_plotter(asset, cage, motion, frame, color, size, off_screen=True, device=device)
    return save_screenshot(plotter, path)
