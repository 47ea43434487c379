"""The neural picture of the viewer's current view (``shellsim view``): what a shot's frame shows, rendered on
a background thread at low resolution while the camera or the bodies move and refined when they rest, with
its depth, for viser's ``set_background_image(rgb, depth=depth)`` (meshes drawn in the browser are hidden
behind it where they are farther).

The image is the one :class:`shellsim.film.renderer.SceneRenderer` makes of a shot's frame (neural bodies
through their deformed shells, mesh bodies and colliders as opaque meshes, the lit ground, the sky and the
shadows of the scene's look): the frame is built once per set of cage positions (shells deformed, BVHs
refitted, inverse map updated, the opaque meshes' scene) and its rays are rendered by
:func:`neural.render.view.render_bodies` in tiles of rows, so that a newer request stops a refinement between
two tiles. The render state machine follows nerfstudio's ``viewer/render_state_machine.py``: the server
renders, the browser shows; low resolution while requests keep coming, full resolution and then
anti-aliasing once none came for :attr:`PictureSettings.settle` seconds; a move interrupts a refinement but
never a low-resolution picture (so that a camera that never stops still gets pictures).

Depth is what viser's background shader reads (``viser/client/src/App.tsx``: ``viewZToPerspectiveDepth``):
the distance along the camera's viewing axis (OpenCV +z) in world units, of the first surface the pixel's
centre ray meets: a neural body's zero level set (its SDF's first sign change along the ray among the
narrow-band samples, linearly interpolated), a mesh body, a collider or the ground; :data:`FAR_DEPTH` where
the ray meets nothing (viser clips depths at 167.77).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: Depth (world units) of pixels whose ray meets no surface: beyond everything (viser clips at 167.77).
FAR_DEPTH = 1000.0

#: Stages of a request's pictures, in order: low resolution (one ray per pixel), the refined size with one
#: ray per pixel, the refined size anti-aliased.
LOW, FULL, FINAL = 0, 1, 2


@dataclass(frozen=True)
class PictureSettings:
    """How :class:`NeuralPicture` renders.

    low_side : long side in pixels of the pictures made while requests keep coming (one ray per pixel)
    max_side : cap of the refined pictures' long side (the window's size when the camera gives it, else this)
    antialias : jittered rays per pixel of the last refinement
        (:func:`shellsim.film.antialias.antialiased`; 1: none)
    settle : seconds without a new request before refining
    tile_rows : rows per tile of a refinement (a newer request is seen between two tiles)
    moving_shadows : shadow rays in the low-resolution pictures (False: the light is never blocked there)
    """

    low_side: int = 80
    max_side: int = 512
    antialias: int = 4
    settle: float = 0.3
    tile_rows: int = 32
    moving_shadows: bool = True

    def __post_init__(self):
        from shellsim.film.antialias import pixel_offsets

        for name in ("low_side", "max_side", "tile_rows"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"{name}: expected a positive integer, got {value!r}")
        pixel_offsets(self.antialias)
        if not (math.isfinite(self.settle) and self.settle >= 0):
            raise ValueError(f"settle: expected seconds >= 0, got {self.settle!r}")


@dataclass(frozen=True)
class Pinhole:
    """A pinhole camera as viser gives it: ``position`` (3,) in the world, ``rotation`` (3, 3)
    world-from-camera in OpenCV axes (+x right, +y down, +z forward), ``fov`` the vertical field of view in
    radians, ``aspect`` width / height, ``size`` (W, H) of the window in pixels (None: unknown)."""

    position: np.ndarray
    rotation: np.ndarray
    fov: float
    aspect: float
    size: tuple[int, int] | None = None

    def __post_init__(self):
        position = np.asarray(self.position, np.float64).reshape(-1)
        rotation = np.asarray(self.rotation, np.float64)
        if rotation.shape == (4,):
            rotation = quaternion_matrix(rotation)
        if position.shape != (3,) or not np.isfinite(position).all():
            raise ValueError(f"position: expected 3 finite numbers, got {self.position!r}")
        if rotation.shape != (3, 3) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5):
            raise ValueError(
                f"rotation: expected a (3, 3) rotation or a wxyz quaternion, got {self.rotation!r}"
            )
        if not (0 < self.fov < math.pi):
            raise ValueError(f"fov: expected a vertical field of view in (0, pi) radians, got {self.fov!r}")
        if not (math.isfinite(self.aspect) and self.aspect > 0):
            raise ValueError(f"aspect: expected width / height > 0, got {self.aspect!r}")
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "rotation", rotation)
        if self.size is not None:
            object.__setattr__(self, "size", (max(1, int(self.size[0])), max(1, int(self.size[1]))))

    @classmethod
    def of(cls, camera) -> Pinhole:
        """A :class:`Pinhole` (returned as is) or a snapshot of anything with viser's camera attributes
        (``position``, ``wxyz`` or ``rotation``, ``fov``, ``aspect``, optionally ``image_width`` and
        ``image_height``), e.g. a client's ``viser.CameraHandle``."""
        if isinstance(camera, cls):
            return camera
        rotation = getattr(camera, "wxyz", None)
        rotation = camera.rotation if rotation is None else rotation
        width, height = getattr(camera, "image_width", None), getattr(camera, "image_height", None)
        size = (width, height) if width and height else None
        return cls(camera.position, rotation, float(camera.fov), float(camera.aspect), size)

    @classmethod
    def looking_at(
        cls, eye, target, fov: float, aspect: float = 1.0, up=(0.0, 0.0, 1.0), size=None
    ) -> Pinhole:
        """The camera at ``eye`` (3,) looking at ``target`` (3,), its image's up towards ``up``."""
        from neural.data import look_at

        c2w = look_at(eye, target, up)  # OpenGL axes: y up, looking down -z
        return cls(c2w[:3, 3], c2w[:3, :3] * [1.0, -1.0, -1.0], fov, aspect, size)

    def pixels(self, long_side: int) -> tuple[int, int]:
        """(W, H) with the camera's aspect and the longer side ``long_side``, or the window's size when it
        is smaller."""
        if self.size is not None:
            long_side = min(long_side, max(self.size))
        if self.aspect >= 1:
            return long_side, max(1, round(long_side / self.aspect))
        return max(1, round(long_side * self.aspect)), long_side

    def cameras(self, width: int, height: int):
        """The one-camera :class:`neural.data.Cameras` of this view at ``width`` x ``height`` (OpenGL
        camera-to-world, square pixels, the vertical field of view kept)."""
        from neural.data import Cameras

        c2w = np.eye(4)
        c2w[:3, :3] = self.rotation * [1.0, -1.0, -1.0]  # OpenCV -> OpenGL: flip y and z
        c2w[:3, 3] = self.position
        focal = 0.5 * height / math.tan(0.5 * self.fov)
        return Cameras(
            c2w[None],
            [focal],
            [focal],
            [width / 2],
            [height / 2],
            [width],
            [height],
            np.zeros((1, 4)),
            ["view"],
        )

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit viewing direction in the world (the camera's +z)."""
        return self.rotation[:, 2]


def quaternion_matrix(wxyz) -> np.ndarray:
    """(3, 3) rotation of the quaternion ``wxyz`` (4,) (normalised first)."""
    w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass
class _Request:
    generation: int
    camera: Pinhole
    positions: np.ndarray | None
    on_picture: object
    time: float


@dataclass
class _Frame:
    """One set of cage positions made ready to render: the renderer's
    :class:`shellsim.film.renderer.SceneFrame` and its backdrop, with and without shadows."""

    positions: np.ndarray | None
    scene: object
    backdrop: object
    backdrop_moving: object

    @property
    def bodies(self) -> list:
        return self.scene.bodies


class NeuralPicture:
    """The neural picture of the viewer's current view, rendered on a background thread (module docstring).

    Build it with :meth:`from_scene` (a recorded scene: :func:`shellsim.shot.recorded.read_scene_motion`),
    :meth:`from_bodies` (a scene file's spec and its bodies built at rest,
    :func:`shellsim.shot.bodies.build_body`) or :meth:`from_asset` (one asset, optionally with its cage, a
    placement and a world), or directly from a :class:`~shellsim.film.renderer.SceneRenderer` and the layout
    of the positions.

    - ``request(camera, positions, on_picture)``: ask for the picture of ``camera`` (a :class:`Pinhole`, or
      a viser ``CameraHandle``, read at once) with the bodies' cages at ``positions`` ((N, 3) world metres,
      every body's cage one after the other as the scene motion holds them; None: at rest). Returns at
      once. ``on_picture(rgb (H, W, 3) uint8, depth (H, W) float32)`` is called later from the picture's
      thread, first at low resolution, then (after :attr:`PictureSettings.settle` s without a newer request)
      at the refined size with one ray per pixel, then anti-aliased. A newer request replaces an older one:
      the older's refinements stop between two tiles and are never delivered; pictures arrive in the order
      of their requests (never one of an older request after one of a newer).
    - ``render(camera, positions, width, height, antialias)``: the same picture, here and now (tests,
      benches; not while requests are being rendered).
    - ``close()``: stop the thread (a render in progress stops at its next tile); idempotent.
    - ``generation``: the number of the latest request (1, 2, ...).
    - ``stages``: ``[(generation, stage, seconds)]`` of the pictures delivered (``stage``: :data:`LOW`,
      :data:`FULL`, :data:`FINAL`; seconds since the request), the last 100.

    renderer : :class:`~shellsim.film.renderer.SceneRenderer`
    neural : per neural body of ``renderer.bodies`` (same order), ``(vertices (slice), placement)`` its cage's
        rows in the positions and its :class:`~shellsim.world.Placement`
    meshes : per mesh body, ``(vertices (slice), bary (S, 4), corners (S, 4), faces (F, 3), albedo (3,))``
        its surface carried by its cage (corner indices into the body's own cage vertices)
    settings : :class:`PictureSettings`
    """

    def __init__(self, renderer, neural=(), meshes=(), settings: PictureSettings | None = None):
        self.renderer = renderer
        self.neural = list(neural)
        self.meshes = list(meshes)
        if len(self.neural) != len(renderer.bodies):
            raise ValueError(
                f"neural: expected {len(renderer.bodies)} bodies like the renderer, got {len(self.neural)}"
            )
        self.settings = PictureSettings() if settings is None else settings
        self.stages: list[tuple[int, int, float]] = []
        self._frame: _Frame | None = None
        self._lock = threading.Condition()
        self._request: _Request | None = None
        self._generation = 0
        self._closed = False
        self._thread: threading.Thread | None = None

    # -- construction ------------------------------------------------------------------------------------

    @classmethod
    def from_scene(cls, scene, device: str = "auto", look=None, settings: PictureSettings | None = None):
        """The picture of a :class:`~shellsim.shot.recorded.SceneMotion` (its assets loaded) in ``look``
        (:class:`~shellsim.world.WorldLook`; None: the scene's own ``[look]``)."""
        from shellsim.film.shot_frames import scene_renderer
        from shellsim.film.world import look_of

        look = look_of(scene.look, True) if look is None else look
        renderer = scene_renderer(scene, device, look)
        neural = [(b.vertices, b.placement) for b in scene.bodies if b.asset is not None]
        meshes = [
            (b.vertices, b.surface_bary, b.surface_corners, b.surface_faces, b.color)
            for b in scene.bodies
            if b.asset is None
        ]
        return cls(renderer, neural, meshes, settings)

    @classmethod
    def from_bodies(
        cls, spec, bodies, device: str = "auto", look=None, settings: PictureSettings | None = None
    ):
        """The picture of a scene file's ``spec`` (:class:`~shellsim.shot.spec.SceneSpec`) whose bodies are
        ``bodies`` (:class:`~shellsim.shot.bodies.SceneBody`, e.g. ``SceneSimulation.bodies``); positions
        are their cages one after the other (``SceneSimulation.rest``)."""
        from types import SimpleNamespace

        from neural.asset import load_asset
        from shellsim.film.shot_frames import scene_renderer
        from shellsim.film.world import look_of
        from shellsim.shot.recorded import body_color

        look = look_of(spec.look, True) if look is None else look
        start, records, neural, meshes = 0, [], [], []
        for k, body in enumerate(bodies):
            rows = slice(start, start + len(body.rest))
            start = rows.stop
            asset = None if body.spec.asset is None else load_asset(body.spec.asset)
            color = body_color(body.spec.color, k, asset is None)
            records.append(
                SimpleNamespace(asset=asset, cage=body.cage, placement=body.placement, color=color)
            )
            if asset is not None:
                neural.append((rows, body.placement))
            else:
                s = body.surface
                meshes.append((rows, s.bary, s.corners, s.faces, color))
        scene = SimpleNamespace(bodies=records, colliders=list(spec.colliders), ground=spec.world.ground)
        return cls(scene_renderer(scene, device, look), neural, meshes, settings)

    @classmethod
    def from_asset(
        cls, asset, cage=None, placement=None, look=None, device: str = "auto", settings=None, obstacles=None
    ):
        """The picture of one asset (:class:`neural.asset.Asset`) placed in the world by ``placement``
        (:class:`~shellsim.world.Placement`; None: the identity, the world is the asset's frame), deformed
        by its ``cage`` (None: at rest only), in ``look`` (None: over the asset's background, as
        :class:`~shellsim.film.renderer.DeformedRenderer` draws it) among ``obstacles``."""
        from neural.asset import load_field
        from neural.device import pick_device
        from shellsim.film.renderer import DeformedRenderer, SceneRenderer
        from shellsim.world import Placement

        device = pick_device(device)
        placement = Placement() if placement is None else placement
        body = DeformedRenderer(asset, load_field(asset, device), cage, device, placement=placement)
        renderer = SceneRenderer([body], look, obstacles, (), device, background=asset.background)
        rows = slice(0, 0 if cage is None else len(cage.vertices))
        return cls(renderer, [(rows, placement)], (), settings)

    # -- the state machine -------------------------------------------------------------------------------

    def request(self, camera, positions, on_picture) -> None:
        """Ask for the picture of ``camera`` with the cages at ``positions`` (class docstring)."""
        camera = Pinhole.of(camera)
        positions = None if positions is None else np.array(positions, np.float64)
        with self._lock:
            if self._closed:
                raise RuntimeError("request: this picture is closed")
            self._generation += 1
            self._request = _Request(self._generation, camera, positions, on_picture, time.perf_counter())
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="shellsim-picture", daemon=True)
                self._thread.start()
            self._lock.notify_all()

    @property
    def generation(self) -> int:
        """The number of the latest request (1 for the first; 0 before any)."""
        return self._generation

    def close(self) -> None:
        """Stop the thread (class docstring)."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _stale(self, generation: int) -> bool:
        return self._closed or self._generation != generation

    def _next(self, done: tuple[int, int]):
        """Wait for work: ``(request, stage)`` to render next, or None once closed. ``done``: (generation,
        stage) of the last picture made."""
        s = self.settings
        last = FINAL if s.antialias > 1 else FULL
        with self._lock:
            while not self._closed:
                r = self._request
                if r is None or (done[0] == r.generation and done[1] >= last):
                    self._lock.wait()
                    continue
                if done[0] != r.generation:
                    return r, LOW
                wait = r.time + s.settle - time.perf_counter()
                if done[1] == LOW and wait > 0:
                    self._lock.wait(wait)
                    continue
                return r, done[1] + 1
        return None

    def _run(self) -> None:
        done = (0, FINAL)
        depth = None
        while (job := self._next(done)) is not None:
            r, stage = job
            try:
                picture = self._picture(r, stage, depth if stage == FINAL else None)
            except Exception:  # a failed picture must not stop the viewer's thread
                log.exception("the neural picture of request %d failed", r.generation)
                done = (r.generation, FINAL)
                continue
            done = (r.generation, stage)
            if picture is None:  # superseded mid-render
                continue
            rgb, depth = picture
            with self._lock:
                if stage != LOW and self._stale(r.generation):
                    continue  # superseded after its last tile: a newer request's pictures come next
                self.stages.append((r.generation, stage, time.perf_counter() - r.time))
                del self.stages[:-100]
            try:
                r.on_picture(rgb, depth)
            except Exception:
                log.exception("on_picture of request %d failed", r.generation)

    def _picture(self, r: _Request, stage: int, depth):
        """(rgb uint8, depth float32) of request ``r`` at ``stage``, or None when a newer request came before
        it was done (refinements only); ``depth``: the full stage's, reused by the final one."""
        s = self.settings
        side = s.low_side if stage == LOW else s.max_side
        width, height = r.camera.pixels(side)
        antialias = s.antialias if stage == FINAL else 1
        stop = None if stage == LOW else (lambda: self._stale(r.generation))
        out = self._render(r.camera, r.positions, width, height, antialias, depth is None, stop, stage == LOW)
        if out is None:
            return None
        image, new_depth = out
        rgb = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        return rgb, (depth if new_depth is None else new_depth)

    # -- rendering ---------------------------------------------------------------------------------------

    def render(
        self, camera, positions=None, width: int | None = None, height: int | None = None, antialias: int = 1
    ):
        """(image (H, W, 3) float32 in [0, 1], depth (H, W) float32) of ``camera`` with the cages at
        ``positions`` (class docstring), at ``width`` x ``height`` (None: :attr:`PictureSettings.max_side`
        on the long side), ``antialias`` jittered rays per pixel; synchronous."""
        camera = Pinhole.of(camera)
        if width is None or height is None:
            width, height = camera.pixels(self.settings.max_side)
        positions = None if positions is None else np.asarray(positions, np.float64)
        return self._render(camera, positions, width, height, antialias, True)

    def _render(self, camera, positions, width, height, antialias, with_depth, stop=None, moving=False):
        """:meth:`render`, tile by tile; None when ``stop()`` turns true between two tiles; depth None
        unless ``with_depth``; ``moving``: the backdrop of :attr:`PictureSettings.moving_shadows`."""
        import torch

        from shellsim.film.antialias import pixel_offsets

        frame = self._frame_of(positions)
        view = camera.cameras(width, height)
        offsets = pixel_offsets(antialias)
        image = np.zeros((height, width, 3), np.float64)
        depth = np.full((height, width), FAR_DEPTH, np.float32) if with_depth else None
        rows = self.settings.tile_rows
        for top in range(0, height, rows):
            if stop is not None and stop():
                return None
            bottom = min(height, top + rows)
            for dx, dy in offsets:
                tile = dataclasses.replace(
                    view, height=np.array([bottom - top]), cy=view.cy - top - dy, cx=view.cx - dx
                )
                with torch.no_grad():
                    colors, t = self._render_tile(frame, tile, with_depth and dx == dy == 0, moving)
                image[top:bottom] += colors.reshape(bottom - top, width, 3)
                if t is not None:
                    depth[top:bottom] = t.reshape(bottom - top, width)
            if with_depth and antialias > 1:  # depth at the pixels' centres
                tile = dataclasses.replace(view, height=np.array([bottom - top]), cy=view.cy - top)
                with torch.no_grad():
                    depth[top:bottom] = self._tile_depth(frame, tile).reshape(bottom - top, width)
        return (image / len(offsets)).astype(np.float32), depth

    def _frame_of(self, positions) -> _Frame:
        """The :class:`_Frame` of ``positions`` (the last one again when they are the same): the renderer's
        :meth:`shellsim.film.renderer.SceneRenderer.frame` and backdrops."""
        last = self._frame
        if last is not None and (
            (positions is None and last.positions is None)
            or (
                positions is not None
                and last.positions is not None
                and np.array_equal(positions, last.positions)
            )
        ):
            return last
        r = self.renderer
        if positions is None:
            cages, surfaces = [None] * len(r.bodies), []
        else:
            cages = [
                None if rows.stop == rows.start else p.to_asset(positions[rows]) for rows, p in self.neural
            ]
            surfaces = []
            for rows, bary, corners, faces, albedo in self.meshes:
                points = np.einsum("sk,ski->si", bary, positions[rows][corners])
                surfaces.append((points, faces, albedo))
        if positions is None and self.meshes:  # mesh bodies at rest need their cages
            raise ValueError("positions: needed to draw mesh bodies (their surfaces follow their cages)")
        scene = r.frame(cages, surfaces)
        backdrop = r.backdrop(scene)
        moving = backdrop
        if r.look is not None and not self.settings.moving_shadows:
            moving = r.backdrop(scene, dataclasses.replace(r.look, shadows=False))
        self._frame = _Frame(positions, scene, backdrop, moving)
        return self._frame

    def _render_tile(self, frame: _Frame, tile, with_depth: bool, moving: bool = False):
        """Colours (R, 3) float64 in [0, 1] of the one-camera ``tile``'s pixels (row-major) and, with
        ``with_depth``, their depths (R,) (else None)."""
        from neural.data import camera_rays
        from neural.render.view import render_bodies

        r = self.renderer
        origins, dirs = camera_rays(tile, 0, device=r.device)
        t_max = self._t_max(frame, origins, dirs)
        backdrop = frame.backdrop_moving if moving else frame.backdrop
        colors, _ = render_bodies(frame.bodies, origins, dirs, r.background, backdrop=backdrop, t_max=t_max)
        colors = colors.clamp(0, 1).double().cpu().numpy()
        depth = self._depth(frame, tile, origins, dirs, t_max) if with_depth else None
        return colors, depth

    def _tile_depth(self, frame: _Frame, tile) -> np.ndarray:
        """Depths (R,) of the one-camera ``tile``'s pixel centres."""
        from neural.data import camera_rays

        origins, dirs = camera_rays(tile, 0, device=self.renderer.device)
        return self._depth(frame, tile, origins, dirs, self._t_max(frame, origins, dirs))

    def _t_max(self, frame: _Frame, origins, dirs):
        return self.renderer.t_max(frame.scene, origins, dirs)

    def _depth(self, frame: _Frame, tile, origins, dirs, t_max) -> np.ndarray:
        """(R,) float32 depth along the camera's axis of the first surface on each ray (module docstring)."""
        import torch

        t = surface_depth(frame.bodies, origins, dirs)
        if t_max is not None:
            t = torch.minimum(t, t_max.to(t))
        forward = -torch.as_tensor(tile.c2w[0, :3, 2], dtype=torch.float64, device=dirs.device)
        z = t * (dirs.double() @ forward)
        return (
            torch.where(torch.isfinite(z), z, torch.full_like(z, FAR_DEPTH))
            .clamp(max=FAR_DEPTH)
            .float()
            .cpu()
            .numpy()
        )


def surface_depth(bodies, origins, dirs):
    """(R,) float64 ray parameter (unit ``dirs``: distance) of the first zero level set that world rays
    ``origins``, ``dirs`` (R, 3) meet among ``bodies`` (:class:`~neural.render.bodies.FieldBody`), inf where
    none: each body's narrow-band samples on the rays crossing its box, mapped to its rest space, its SDF
    there, the first sample inside (SDF <= 0), its crossing interpolated linearly from the sample before it
    on the ray when that one is outside."""
    import torch

    from neural.render.bodies import body_share, locate

    t_hit = torch.full((len(origins),), math.inf, dtype=torch.float64, device=origins.device)
    for body in bodies:
        rays, o, d = body_share(body, origins, dirs)
        if len(o) == 0:
            continue
        samples = body.sampler(o, d)
        if len(samples.ray_indices) == 0:
            continue
        index = torch.arange(len(samples.ray_indices), device=o.device)
        index, points, *_ = locate(index, o, d, samples, body.rest_map)
        if len(index) == 0:
            continue
        sdf_of = getattr(body.field, "sdf", None)
        sdf = (sdf_of(points) if sdf_of is not None else body.field.sdf_and_kernel(points)[0]).double()
        on = samples.ray_indices.index_select(0, index)
        t = samples.t_mid.index_select(0, index).double()
        same = torch.zeros_like(on, dtype=torch.bool)
        same[1:] = on[1:] == on[:-1]
        before = torch.roll(sdf, 1)
        t_before = torch.roll(t, 1)
        crossing = same & (before > 0)
        frac = torch.where(crossing, before / (before - sdf).clamp_min(1e-30), torch.ones_like(sdf))
        t_cross = torch.where(crossing, t_before + frac * (t - t_before), t)
        inside = torch.nonzero(sdf <= 0).squeeze(1)
        first = torch.full((len(o),), math.inf, dtype=torch.float64, device=o.device)
        first.scatter_reduce_(0, on.index_select(0, inside), t_cross.index_select(0, inside), "amin")
        if rays is None:
            t_hit = torch.minimum(t_hit, first)
        else:
            t_hit.scatter_reduce_(0, rays, first, "amin")
    return t_hit
