"""One frame of an asset at rest or deformed by its cage (paper Sec. 5; docs/architecture.md, "one rendering
pipeline").

Images are made by the one pipeline of :mod:`neural.render.view` (sample, optional map to rest space,
shade); this module supplies, for one frame with cage vertices ``p`` (V, 3), the deformed sampler and the map
to rest space. :class:`DeformedRenderer`

1. **deforms the shells**: every ``M+`` / ``M-`` vertex is the barycentric interpolation of ``p`` in its
   rest tet (:func:`~shellsim.deform.inverse_map.deform_points`, as
   :meth:`~neural.render.raycast.WarpCaster.refit_blended`
   computes it in a Warp kernel); the BVHs of their Warp meshes, built once from the rest shells, are
   refitted, and meanwhile the inverse map (:class:`~shellsim.deform.inverse_map.InverseMap`) is updated;
2. **samples**: casts the camera rays against the deformed shells and places samples in the deformed narrow
   band (Procedure 3, the asset's ``NarrowBandConfig`` in world units);
3. **maps** every sample back to rest space: ``x_rest = Phi^-1(x)``, the ray direction by finite
   differences ``d_rest = normalize(Phi^-1(x + eps d) - Phi^-1(x))`` and the local stretch
   ``|Phi^-1(x + eps d) - Phi^-1(x)| / eps``, which turns a deformed section of length ``delta`` into a
   rest-space one of length ``stretch * delta`` (:meth:`InverseMap.map_rays`). Samples outside the deformed
   cage (``inside = False``) are dropped: the cage contains everything the field shows;
4. **shades** the rest-space samples with the field and composites them along the deformed rays (Eq. 2-3),
   over the asset's background, or, given a :class:`~shellsim.world.WorldLook` and the body's
   :class:`~shellsim.world.Placement`, over the world's lit ground, obstacles and sky
   (:func:`trace_world`): their static part (lit as far as the obstacles let the light through) drawn once
   per camera view (:class:`~shellsim.film.static.StaticWorld`), the body's shadow added each frame
   (:func:`~shellsim.film.ground.world_colors`) by shadow rays cast through the same deformed shells,
   mapped to rest space alike and attenuated by the field's transmittance
   (:func:`~neural.render.view.bodies_transmittance`, each stopped once below
   :data:`~neural.render.view.SHADOW_CUTOFF`); the obstacles hide the body's samples behind them, and the
   ground hides the shells below z = 0 (each ray's ``t_max``, the layer's nearest surface).

A frame is built once (:meth:`DeformedRenderer.tracer`: step 1 and the box of the deformed outer shell,
outside which no ray is cast) and traced for any pixels of any view: the passes of anti-aliasing
(:mod:`shellsim.film.antialias`).

With no cage positions it renders the rest shells directly (plain narrow-band rendering, Sec. 3.4): the
pipeline without a map, with the asset's rest sampler, exactly what ``shellsim eval`` measures.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

#: Stages of a frame, in :meth:`DeformedRenderer.render`'s ``stats`` as ``<stage>_ms``: building the
#: deformed frame, then the stages of :data:`neural.render.view.STAGES` ("world": what the rays see behind the
#: fields, drawn each frame), the world's ``static`` layer (drawn, or kept from an earlier frame:
#: :class:`shellsim.film.static.StaticWorld`) and its ``shadow`` rays through the fields (out of "world").
STAGES = ("build", "sample", "map", "shade", "world", "static", "shadow")


class DeformedRenderer:
    """Renders an asset's field through its shells, at rest or with its cage deformed: the pipeline of
    :mod:`neural.render.view` (sample, map to rest space, shade) with, for a deformed frame, a sampler on the
    deformed shells and the cage's inverse map as its map to rest space.

    asset : :class:`neural.asset.Asset` (shells, background, narrow-band settings)
    field : its ``ShellField`` on ``device``
    cage : :class:`shellsim.tetcage.build.Cage` embedding the asset's shells; None renders at rest only
    device : torch device of the field ("cpu", "cuda"); the inverse map runs on the matching Warp device
    config : narrow-band settings; None takes the asset's ``meta["narrowband"]`` (or the defaults)
    look : :class:`shellsim.world.WorldLook` of the world behind the body (ground, light, shadows,
        sky; a body cut out of a capture has no ground: it stands on its own table); None: the asset's
        background colour
    placement : :class:`shellsim.world.Placement` of the asset's frame in the world (with ``look``; None: the
        identity)
    obstacles : :class:`shellsim.film.obstacles.Obstacles` of the world, drawn with ``look`` (None: none)

    State: the rest sampler (:func:`neural.render.view.asset_sampler`, Embree scenes built once), the field,
    the cage, Warp meshes of the shells refitted to each deformed frame and the inverse map updated to it
    (both built on the first one): the renderer draws one frame at a time.
    """

    def __init__(
        self, asset, field, cage, device: str = "cpu", config=None, look=None, placement=None, obstacles=None
    ):
        from neural.device import warp_device
        from neural.render.view import asset_sampler
        from shellsim.film.obstacles import Obstacles
        from shellsim.film.static import StaticWorld
        from shellsim.world import Placement

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
        self.cut = asset.cut  # a cut asset: its shells hold the object, the backdrop's the rest
        self._backdrop = None
        if self.cut is not None:
            self._backdrop = asset_sampler(asset, self.config, asset.backdrop_meshes())
            look = _without_ground(look)  # it stands on its own room's table
        self.look = look
        self.obstacles = Obstacles() if obstacles is None else obstacles
        self.world = Placement() if placement is None else placement  # the asset's frame in the world
        self._deformed = None  # WarpCaster, built for the first deformed frame
        self._inverse = None  # the InverseMap, built for the first deformed frame and updated for the next
        self.static = None  # the world's static part, drawn once per view
        if look is not None:
            self.static = StaticWorld(look, self.world, self.obstacles, sky_colors=self.capture_sky())

    def _frame(self, positions):
        """The sampler and the map to rest space (None at rest) of cage vertices ``positions`` (V, 3)."""
        from neural.device import kept_pool
        from neural.render.raycast import WarpCaster
        from neural.render.view import narrow_band_sampler
        from shellsim.deform.inverse_map import InverseMap

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

    def field_body(self, positions=None, framed: bool = True):
        """The :class:`neural.render.bodies.FieldBody` of this asset with its cage at ``positions`` (V, 3)
        in the asset's frame (None: at rest): its sampler, map to rest space, placement in the world and the
        world box of its outer shell (deformed: every sample lies inside it); not ``framed``: in the asset's
        frame, its box there."""
        from neural.render.bodies import FieldBody

        sampler, to_rest = self._frame(positions)
        points = self.outer.vertices if positions is None else self._deformed.outer_points()
        placed = self.world.to_world(points) if framed else points
        lo, hi = placed.min(0), placed.max(0)
        pad = 1e-6 * (np.linalg.norm(hi - lo) + 1.0)  # a ray grazing the box's face is cast
        frame = self.world if framed else None
        return FieldBody(self.field, sampler, self._cut_away(to_rest), frame, np.stack([lo - pad, hi + pad]))

    def _cut_away(self, to_rest):
        """``to_rest`` followed, for a cut asset, by keeping only the samples inside the cut (the field's
        content outside it is the backdrop's)."""
        from neural.render.bodies import ChainedMap
        from neural.shell.cutout import RegionMask

        if self.cut is None:
            return to_rest
        mask = RegionMask(self.cut, inside=True)
        return mask if to_rest is None else ChainedMap(to_rest, mask)

    def backdrop_body(self, framed: bool = True):
        """The :class:`neural.render.bodies.FieldBody` of a cut asset's backdrop: the rest of its field, at
        rest, through the backdrop's shells, without the cut's samples; placed in the world (``framed``) or in
        the asset's frame. None for an asset that is not a cut."""
        from neural.render.bodies import FieldBody
        from neural.shell.cutout import RegionMask

        if self.cut is None:
            return None
        frame = self.world if framed else None
        return FieldBody(self.field, self._backdrop, RegionMask(self.cut, inside=False), frame)

    def capture_sky(self):
        """``sky(dirs_w (R, 3)) -> (R, 3)`` of a cut asset whose field has an environment map: what its
        capture saw beyond the field along world directions (turned into the asset's frame by its
        placement), the sky of a world it is drawn in; None for any other asset."""
        if self.cut is None or getattr(self.field, "env", None) is None:
            return None
        rotation = torch.as_tensor(self.world.rotation, dtype=torch.float32, device=self.device)

        def sky(dirs_w: torch.Tensor) -> torch.Tensor:
            return self.field.environment(dirs_w.to(rotation) @ rotation)  # rows of R^T d

        return sky

    def tracer(self, positions=None):
        """``trace(view, pixels=None) -> (colors (P, 3) float32 in [0, 1], stats)``: the pixels ``pixels``
        (P,) int64 (row-major; None: all) of the one-camera ``view`` (the asset's frame) with the cage at
        ``positions`` (V, 3) (None: at rest), the frame built once for every trace (shells deformed, their
        BVHs refitted, the inverse map updated). Only rays that cross the (deformed) outer shell's box are
        cast against the shells. With a ``look`` the world is behind the body (:func:`trace_world`), its
        static part kept per view (:class:`~shellsim.film.static.StaticWorld`); a cut asset's room is drawn
        with it. Stats: :func:`trace_world`'s, the first trace's with ``build_ms``."""
        from neural.render.fullray import ray_background

        start = time.perf_counter()
        bodies = [self.field_body(positions, framed=False)]
        if self.cut is not None:
            bodies.append(self.backdrop_body(framed=False))
        build = [time.perf_counter() - start]
        if self.static is not None:
            self.static.next_frame()
        sky = None
        if self.cut is not None and self.look is None:

            def sky(dirs):
                return ray_background(self.field, dirs, self.background).expand(len(dirs), 3)

        def trace(view, pixels=None):
            colors, stats = trace_world(
                bodies, view, pixels, self.background, self.device, self.static, sky=sky
            )
            stats["build_ms"] = 1000.0 * build.pop() if build else 0.0
            return colors, stats

        return trace

    def render(self, cameras, index: int, positions=None) -> tuple[np.ndarray, dict]:
        """Image (H, W, 3) float32 in [0, 1] of camera ``index`` of ``cameras`` with the cage at ``positions``
        (V, 3) (None: at rest, :func:`neural.render.view.render_camera` with the asset's sampler), and the
        stats of :meth:`tracer` (``counts`` (H, W); ``ms`` with the build). With a ``look`` the world is
        behind the body, its shadow rays sampled and mapped as the camera rays are, and its obstacles hide
        what is behind them."""
        start = time.perf_counter()
        colors, stats = self.tracer(positions)(cameras.subset([index]))
        return _camera_image(colors, stats, cameras, index, start)


def trace_world(bodies, view, pixels, background, device, static=None, moving=None, sky=None):
    """Colours (P, 3) float32 in [0, 1] of the pixels ``pixels`` (P,) int64 (row-major; None: all) of the
    one-camera ``view`` through the fields of ``bodies`` (:class:`neural.render.bodies.FieldBody`,
    :func:`neural.render.view.render_bodies`) over what lies behind them: with ``static`` (a
    :class:`~shellsim.film.static.StaticWorld`) its layer of these pixels (kept per view), the ``moving``
    meshes (:class:`~shellsim.film.obstacles.Meshes`) and the bodies' shadows
    (:func:`~shellsim.film.ground.world_colors`; shadow rays through every body,
    :func:`neural.render.view.bodies_transmittance`), the nearest surface of each ray hiding the fields
    behind it; else ``sky(dirs (P, 3)) -> (P, 3)`` (None: ``background`` (3,)). Stats: those of
    ``render_bodies`` with ``static_ms`` (the layer and the surfaces' ``t_max``), ``shadow_ms`` (the shadow
    rays, out of ``world_ms``) and ``ms`` with the rays."""
    from neural.data import camera_rays
    from neural.render.view import bodies_transmittance, render_bodies
    from shellsim.film.ground import surface_t_max, world_colors

    start = time.perf_counter()
    origins, dirs = camera_rays(view, 0, device=device, pixels=pixels)
    backdrop = t_max = None
    static_s, shadow_s = 0.0, [0.0]
    if static is not None:
        tick = time.perf_counter()
        layer = static.view_layer(view, pixels, origins, dirs)
        look = static.look
        if look.ground or static.obstacles or static.meshes or moving:
            t_max = layer.t
            if moving:
                t_max = torch.minimum(t_max, surface_t_max(look, static.frame, None, origins, dirs, moving))
        static_s = time.perf_counter() - tick

        def visibility(o, d):
            tick = time.perf_counter()
            seen = bodies_transmittance(bodies, o, d)
            shadow_s[0] += time.perf_counter() - tick
            return seen

        shadows = visibility if bodies else None

        def backdrop(o, d, rays):
            return world_colors(
                look, static.frame, layer.select(rays), o, d, shadows, moving, static.obstacles, static.meshes
            )

    elif sky is not None:

        def backdrop(o, d, rays):
            return sky(d)

    colors, stats = render_bodies(bodies, origins, dirs, background, backdrop=backdrop, t_max=t_max)
    stats["static_ms"] = 1000.0 * static_s
    stats["shadow_ms"] = 1000.0 * shadow_s[0]
    stats["world_ms"] -= stats["shadow_ms"]
    stats["ms"] = 1000.0 * (time.perf_counter() - start)
    return colors.clamp(0, 1), stats


class TintedField:
    """``field`` with its colours multiplied by ``tint`` (3,) in [0, 1] (an asset body's ``color``): its
    ``radiance`` (N, 3) times the tint; its geometry, and everything else, the field's own."""

    def __init__(self, field, tint):
        self.field = field
        self.tint = torch.as_tensor(tint, dtype=torch.float32)

    def radiance(self, x, d, geometry):
        rgb = self.field.radiance(x, d, geometry)
        return rgb * self.tint.to(rgb)

    def __getattr__(self, name):
        if name == "field":  # not set yet (a copy being made): no field to ask
            raise AttributeError(name)
        return getattr(self.field, name)


@dataclasses.dataclass
class SceneFrame:
    """What one frame of a scene draws, whatever the camera (:meth:`SceneRenderer.frame`): ``bodies`` the
    :class:`neural.render.bodies.FieldBody` of every neural body (and a cut body's room), ``moving`` the
    :class:`shellsim.film.obstacles.Meshes` of the mesh bodies, ``capture_sky`` a cut body's environment map
    (or None)."""

    bodies: list
    moving: object
    capture_sky: object


class SceneRenderer:
    """Renders frames of a scene in the world (metres, z up): its neural bodies, each a
    :class:`DeformedRenderer` placed by its placement, whose samples are merged by depth and composited once
    (:func:`neural.render.view.render_bodies`); the surfaces of its mesh bodies and its static colliders as
    opaque meshes (:class:`shellsim.film.obstacles.Meshes`) and ``obstacles``; the world's ground, light,
    sky and shadows of ``look`` (:class:`shellsim.world.WorldLook`; shadow rays through every body's field,
    :func:`neural.render.view.bodies_transmittance`), its static part (ground, colliders, their shadows on
    each other) drawn once per camera view (:class:`shellsim.film.static.StaticWorld`). A body cut out of a
    capture (:mod:`neural.shell.cutout`) brings its room, the backdrop of its asset, drawn at rest where the
    asset is placed, and the world's ground is not drawn: the body stands on its own table; the environment
    map of its capture is the sky (:meth:`DeformedRenderer.capture_sky`).

    bodies : one :class:`DeformedRenderer` per neural body (made with its ``placement``, without a look)
    statics : ``(vertices (N, 3) world, faces (F, 3), albedo (3,))`` of the static meshes (one Embree scene,
        built here)
    obstacles : :class:`shellsim.film.obstacles.Obstacles` (boxes and spheres met in closed form)
    background : RGB behind everything without a ``look`` (with a cut body: its capture's environment map)
    """

    def __init__(
        self, bodies, look=None, obstacles=None, statics=(), device: str = "cpu", background=(1, 1, 1)
    ):
        from shellsim.film.obstacles import Meshes, Obstacles
        from shellsim.film.static import StaticWorld
        from shellsim.world import Placement

        self.bodies = list(bodies)
        if any(r.cut is not None for r in self.bodies):
            look = _without_ground(look)  # a cut-out body stands on its own room's table
        self.look = look
        self.obstacles = Obstacles() if obstacles is None else obstacles
        self.statics = Meshes(statics)
        self.device = torch.device(device)
        self.background = torch.as_tensor(background, dtype=torch.float32, device=self.device)
        self.capture_sky = next((sky for sky in (r.capture_sky() for r in self.bodies) if sky), None)
        self.static = None  # the world's static part, drawn once per view
        if look is not None:  # the bodies and the cameras are in the world
            self.static = StaticWorld(look, Placement(), self.obstacles, (self.statics,), self.capture_sky)

    def frame(self, positions=(), meshes=()) -> SceneFrame:
        """What a frame draws whatever the camera (:class:`SceneFrame`): each neural body's cage at
        ``positions[b]`` (V_b, 3) in its asset's frame (None: at rest; empty: every body at rest), the mesh
        bodies' surfaces ``meshes`` (``(vertices (S, 3) world, faces, albedo)``)."""
        from shellsim.film.obstacles import Meshes

        positions = list(positions) or [None] * len(self.bodies)
        bodies = [r.field_body(p) for r, p in zip(self.bodies, positions, strict=True)]
        bodies += [r.backdrop_body() for r in self.bodies if r.cut is not None]  # cut assets' rooms, at rest
        return SceneFrame(bodies, Meshes(meshes), self.capture_sky)

    def backdrop(self, frame: SceneFrame, look=None):
        """What the rays of ``frame`` that leave every body meet (``backdrop(origins, dirs, rays=None)``): the
        world of ``look`` (None: the renderer's; its sky, lit ground and colliders, the mesh bodies, the
        shadows of all on them), drawn whole for any rays, else a cut body's capture sky, else None (the
        background colour)."""
        from neural.render.view import bodies_transmittance
        from shellsim.film.ground import world_backdrop
        from shellsim.world import Placement

        look = self.look if look is None else look
        if look is not None:

            def visibility(o, d):
                return bodies_transmittance(frame.bodies, o, d)

            shadows = visibility if frame.bodies else None
            return world_backdrop(
                look, Placement(), shadows, self.obstacles, self.statics, frame.capture_sky, frame.moving
            )
        if frame.capture_sky is not None:
            sky = frame.capture_sky

            def backdrop(o, d, rays=None):
                return sky(d)

            return backdrop
        return None

    def t_max(self, frame: SceneFrame, origins, dirs):
        """(R,) where the world's ground, colliders and mesh bodies cut the rays ``origins``, ``dirs``
        (R, 3), or None when nothing can."""
        from shellsim.film.ground import surface_t_max
        from shellsim.world import Placement

        look = self.look
        if look is None or not (look.ground or self.obstacles or self.statics or frame.moving):
            return None
        return surface_t_max(look, Placement(), self.obstacles, origins, dirs, (self.statics, frame.moving))

    def tracer(self, positions=(), meshes=()):
        """``trace(view, pixels=None) -> (colors (P, 3) float32 in [0, 1], stats)``: the pixels ``pixels``
        (P,) int64 (row-major; None: all) of the one-camera ``view`` (world frame) of the :meth:`frame` of
        ``positions`` and ``meshes``, built once for every trace (:func:`trace_world`; the static world kept
        per view). Stats: :func:`trace_world`'s, the first trace's with ``build_ms``."""
        start = time.perf_counter()
        frame = self.frame(positions, meshes)
        build = [time.perf_counter() - start]
        if self.static is not None:
            self.static.next_frame()

        def trace(view, pixels=None):
            colors, stats = trace_world(
                frame.bodies,
                view,
                pixels,
                self.background,
                self.device,
                self.static,
                frame.moving,
                frame.capture_sky,
            )
            stats["build_ms"] = 1000.0 * build.pop() if build else 0.0
            return colors, stats

        return trace

    def render(self, cameras, index: int, positions=(), meshes=()) -> tuple[np.ndarray, dict]:
        """Image (H, W, 3) float32 in [0, 1] of camera ``index`` of ``cameras`` (world frame) of the
        :meth:`frame` of ``positions`` and ``meshes``, and the stats of :meth:`tracer` (``counts`` (H, W),
        ``ms`` with the build)."""
        start = time.perf_counter()
        colors, stats = self.tracer(positions, meshes)(cameras.subset([index]))
        return _camera_image(colors, stats, cameras, index, start)


def _camera_image(colors, stats: dict, cameras, index: int, start: float):
    """Image (H, W, 3) float32 of camera ``index``'s colours (H W, 3) in [0, 1] from a tracer, and its
    ``stats`` with ``counts`` (H, W) and ``ms`` since ``start`` (``time.perf_counter``)."""
    h, w = int(cameras.height[index]), int(cameras.width[index])
    stats["counts"] = stats["counts"].reshape(h, w)
    stats["ms"] = 1000.0 * (time.perf_counter() - start)
    return colors.reshape(h, w, 3).cpu().numpy(), stats


def _without_ground(look):
    """``look`` (a :class:`shellsim.world.WorldLook`, or None) without its ground."""
    return None if look is None else dataclasses.replace(look, ground=False)
