"""A visible world behind a field: a checkered ground lit by a directional light and a sky, with the field's
shadows on it (issue 41).

The world is metres, z up, the ground at z = 0; how it looks is a :class:`~shellsim.world.WorldLook`. The
renderer works in the field's (asset's) frame, which a similarity ``x_world = s R x + t`` (a
:class:`~shellsim.world.Placement`) places in the world; a ray ``o + t d`` there is the world ray
``(s R o + t) + t' (s R d)`` with the same parameter. :func:`world_backdrop` gives what each camera ray sees
behind the field (the ``backdrop`` of :func:`neural.render.view.render_pixels`, composited under the field's
samples with their transmittance, Eq. 2):

- **ground**: a ray from above the ground that goes down meets it at ``t_g = -z(o_w) / z(d_w)``, the point
  ``p = o_w + t_g d_w``; its albedo is the checker of ``square`` metres,
  ``ground_colors[(floor(p_x / square) + floor(p_y / square)) mod 2]``, lit by Lambert's law with ambient
  (sky) light: ``albedo * (ambient + diffuse * max(l_z, 0) * V)``, ``l`` the unit direction toward the light
  and ``V`` the light's visibility from ``p``: the field's transmittance ``T = prod_i (1 - alpha_i)`` along
  the shadow ray from ``p`` toward the light (:func:`neural.render.view.transmittance`, with the camera rays'
  sampler and map to rest space, so a deformed body's shadow moves with it and fur casts a soft one);
- **obstacles** (:mod:`shellsim.film.obstacles`: boxes and spheres met in closed form) where one is nearer
  than the ground: ``obstacle_color * (ambient + diffuse * max(n.l, 0) * V)``, ``n`` the outward normal;
- **sky** elsewhere: ``horizon + (zenith - horizon) * max(d_z / |d|, 0)`` (a plain colour when both agree).

``V`` is also 0 where an obstacle stands between the point and the light (a shadow ray from ``p + eps n``,
``eps`` = :data:`SHADOW_OFFSET`, met in closed form; obstacles are opaque). An obstacle hides the body's
samples behind it, and the ground those below z = 0: :func:`surface_t_max` (the ground and the obstacles)
is the ``t_max`` of :func:`neural.render.view.render_pixels`.

**What stands still and what moves.** The ground, the obstacles and the static meshes (a scene's colliders),
lit as far as they let the light through, look the same in every frame: :func:`static_layer` computes what a
set of rays sees of them (a :class:`StaticLayer`, ``base + lit V``), which
:class:`shellsim.film.static.StaticWorld` keeps per camera view, and :func:`world_colors` adds, each frame,
what moves: a scene's mesh bodies (drawn where nearer, casting shadows) and the fields' transmittance ``V``.
:func:`world_backdrop` does both for rays of any view (``shellsim/film/_reference.py`` keeps the drawing of
everything in one pass, the twin the tests compare it with).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from shellsim.film.obstacles import Meshes, Obstacles, blocked, obstacle_hits

if TYPE_CHECKING:  # torch is imported where the images are made: the settings stay light for the jobs
    import torch

    from shellsim.world import Placement, WorldLook

#: Metres a shadow ray starts off its surface, along the normal (so that the surface does not shadow itself).
SHADOW_OFFSET = 1e-6


#: Version of how the world is drawn, kept in the frames' records (:mod:`shellsim.io.png`): raise it when the
#: shading of the ground, the obstacles, the shadows or the sky changes, so that frames made before re-render.
WORLD_RENDERER = 2


def to_world(frame: Placement, origins: torch.Tensor, dirs: torch.Tensor):
    """World rays ``(s R o + t, s R d)`` (R, 3) float64 of rays ``origins``, ``dirs`` (R, 3) of the renderer's
    frame (the same ray parameter)."""
    import torch

    rotation = torch.as_tensor(frame.rotation, dtype=torch.float64, device=origins.device)
    translation = torch.as_tensor(frame.translation, dtype=torch.float64, device=origins.device)
    return frame.scale * origins.double() @ rotation.T + translation, frame.scale * dirs.double() @ rotation.T


def surface_t_max(
    look: WorldLook,
    frame: Placement,
    obstacles: Obstacles | None,
    origins,
    dirs,
    meshes: Meshes | Sequence[Meshes] = (),
):
    """(R,) float64 ray parameter of the nearest opaque world surface in front of rays ``origins``, ``dirs``
    (R, 3) of the renderer's frame: the ground (when drawn), the obstacles and the ``meshes`` (inf where
    none). The bodies' samples beyond it are hidden: a body resting on the ground shows nothing of its shells
    below z = 0, and an obstacle hides what is behind it."""
    import torch

    o_w, d_w = to_world(frame, origins, dirs)
    t = _ground_t(look, o_w, d_w)
    if obstacles or _meshes(meshes):
        t = torch.minimum(t, _surface_hits(look, obstacles, meshes, o_w, d_w)[0])
    return t


def _ground_t(look: WorldLook, origins_w, dirs_w):
    """(R,) float64 ray parameter where world rays ``origins_w``, ``dirs_w`` (R, 3) float64 meet the drawn
    ground from above (inf where they do not, or without ``look.ground``)."""
    import torch

    hit = (origins_w[:, 2] > 0) & (dirs_w[:, 2] < 0) & look.ground
    return torch.where(hit, -origins_w[:, 2] / torch.where(hit, dirs_w[:, 2], -1.0), math.inf)


def _meshes(meshes: Meshes | Sequence[Meshes] | None) -> tuple[Meshes, ...]:
    """The non-empty :class:`~shellsim.film.obstacles.Meshes` of ``meshes`` (one, several or None)."""
    if meshes is None:
        return ()
    return tuple(m for m in ((meshes,) if isinstance(meshes, Meshes) else meshes) if m)


def _surface_hits(look: WorldLook, obstacles: Obstacles | None, meshes, origins_w, dirs_w):
    """The nearest obstacle or mesh (of ``meshes``: one :class:`~shellsim.film.obstacles.Meshes` or
    several) in front of world rays ``origins_w``, ``dirs_w`` (R, 3) float64: ``t`` (R,) (inf where none),
    the unit normal ``normals`` (R, 3) facing the ray and the ``albedo`` (R, 3) there (the obstacles':
    ``look.obstacle_color``)."""
    import torch

    t, normals = obstacle_hits(obstacles or Obstacles(), origins_w, dirs_w)
    albedo = torch.tensor(look.obstacle_color, dtype=torch.float64, device=dirs_w.device).expand(len(t), 3)
    for mesh in _meshes(meshes):
        t_mesh, mesh_normals, mesh_albedo = mesh.hits(origins_w, dirs_w)
        nearer = (t_mesh < t)[:, None]
        t = torch.minimum(t, t_mesh)
        normals, albedo = torch.where(nearer, mesh_normals, normals), torch.where(nearer, mesh_albedo, albedo)
    return t, normals, albedo


def _blocked(obstacles: Obstacles | None, meshes, origins_w, dirs_w):
    """(R,) bool: world rays ``origins_w``, ``dirs_w`` (R, 3) float64 cross an obstacle or one of
    ``meshes`` at some t > 0."""
    hit = blocked(obstacles or Obstacles(), origins_w, dirs_w)
    for mesh in _meshes(meshes):
        hit |= mesh.blocked(origins_w, dirs_w)
    return hit


def checker(look: WorldLook, points: torch.Tensor) -> torch.Tensor:
    """Albedo (R, 3) of the ground at world ``points`` (R, 3): ``ground_colors[(floor(x / square) +
    floor(y / square)) mod 2]``."""
    import torch

    cells = torch.floor(points[:, :2] / look.square).long().sum(dim=1) % 2
    colors = torch.tensor(look.ground_colors, dtype=points.dtype, device=points.device)
    return colors[cells]


def sky(look: WorldLook, dirs_w: torch.Tensor) -> torch.Tensor:
    """Sky colour (R, 3) along world directions ``dirs_w`` (R, 3): ``horizon + (zenith - horizon) *
    max(d_z / |d|, 0)``."""
    import torch

    up = (dirs_w[:, 2] / dirs_w.norm(dim=1).clamp_min(1e-30)).clamp_min(0.0)[:, None]
    zenith = torch.tensor(look.zenith, dtype=dirs_w.dtype, device=dirs_w.device)
    horizon = torch.tensor(look.horizon, dtype=dirs_w.dtype, device=dirs_w.device)
    return horizon + (zenith - horizon) * up


@dataclass
class StaticLayer:
    """What the static world (ground, obstacles, static meshes, light, sky) shows along R rays, whatever moves
    in front of it (:func:`static_layer`): the colour of each ray's nearest static surface is ``base + lit
    V``, ``V`` the light's visibility through what moves (the fields, the moving meshes; 1 without them).

    t : (R,) float64 ray parameter of that surface (inf: none, the sky)
    base : (R, 3) ``albedo * ambient`` there, or the sky's colour; without the look's shadows, all of it
    lit : (R, 3) ``albedo * diffuse * max(n.l, 0)`` where no obstacle or static mesh blocks the light, else
        zero (zero on the sky and without the look's shadows: nothing dims it then)
    normal : (R, 3) its outward unit normal (zeros on the sky)

    ``base``, ``lit`` and ``normal`` in the rays' dtype.
    """

    t: torch.Tensor
    base: torch.Tensor
    lit: torch.Tensor
    normal: torch.Tensor

    def select(self, rays) -> StaticLayer:
        """The layer of the rays ``rays`` (K,) int64 among its R (None: all)."""
        if rays is None:
            return self
        return StaticLayer(*(getattr(self, f.name).index_select(0, rays) for f in fields(self)))

    @classmethod
    def cat(cls, layers) -> StaticLayer:
        """The layers ``layers`` of consecutive rays as one."""
        import torch

        return cls(*(torch.cat([getattr(layer, f.name) for layer in layers]) for f in fields(cls)))

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, f.name).nbytes for f in fields(self))


def static_layer(
    look: WorldLook,
    frame: Placement,
    origins,
    dirs,
    obstacles: Obstacles | None = None,
    meshes: Meshes | Sequence[Meshes] = (),
    sky_colors: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> StaticLayer:
    """The :class:`StaticLayer` of rays ``origins``, ``dirs`` (R, 3) of the renderer's frame (``frame``
    places it in the world): the nearest of the ground (``look.ground``), the ``obstacles`` and the
    ``meshes`` (one or several :class:`~shellsim.film.obstacles.Meshes`, in their own albedo), lit by
    Lambert's law (module docstring), its shadow ray from ``p + eps n`` met with the obstacles and meshes
    (with ``look.shadows``); the look's sky, or ``sky_colors(dirs_w (K, 3)) -> (K, 3)`` (a capture's
    environment map), where a ray meets none."""
    import torch

    o_w, d_w = to_world(frame, origins, dirs)
    t = _ground_t(look, o_w, d_w)
    ground = torch.isfinite(t)
    normal = torch.zeros_like(o_w)
    normal[:, 2] = ground.double()
    albedo = torch.zeros_like(o_w)
    solid = bool(obstacles or _meshes(meshes))
    if solid:
        t_solid, n_solid, a_solid = _surface_hits(look, obstacles, meshes, o_w, d_w)
        nearer = t_solid < t
        t = torch.where(nearer, t_solid, t)
        normal = torch.where(nearer[:, None], n_solid, normal)
        albedo = torch.where(nearer[:, None], a_solid, albedo)
        ground &= ~nearer
    seen = torch.isfinite(t)
    points = o_w + torch.where(seen, t, 0.0)[:, None] * d_w
    on_ground = torch.nonzero(ground).squeeze(1)
    albedo[on_ground] = checker(look, points.index_select(0, on_ground))
    light = torch.as_tensor(look.light_unit(), device=d_w.device)
    cos = look.diffuse * (normal @ light).clamp_min(0.0)
    if look.shadows and solid:
        lit = torch.nonzero(cos > 0).squeeze(1)
        starts = points[lit] + SHADOW_OFFSET * normal[lit]
        cos[lit] = torch.where(_blocked(obstacles, meshes, starts, light.expand(len(lit), 3)), 0.0, cos[lit])
    base, lit = albedo * look.ambient, albedo * cos[:, None]
    if not look.shadows:
        base, lit = base + lit, torch.zeros_like(lit)
    empty = torch.nonzero(~seen).squeeze(1)
    if len(empty):
        d_sky = d_w.index_select(0, empty)
        base[empty] = sky(look, d_sky) if sky_colors is None else sky_colors(d_sky).to(base.dtype)
    return StaticLayer(t, base.to(dirs.dtype), lit.to(dirs.dtype), normal.to(dirs.dtype))


def world_colors(
    look: WorldLook,
    frame: Placement,
    layer: StaticLayer,
    origins,
    dirs,
    visibility: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    moving: Meshes | None = None,
    obstacles: Obstacles | None = None,
    meshes: Meshes | Sequence[Meshes] = (),
):
    """Colours (R, 3) that rays ``origins``, ``dirs`` (R, 3) of the renderer's frame see behind the fields:
    their static ``layer`` (:func:`static_layer` of the same rays with ``obstacles`` and the static
    ``meshes``) and what moves in front of it: the ``moving`` meshes, drawn where nearer (lit and shadowed
    as the static ones, by everything) and casting shadows; the light's visibility through the fields,
    ``visibility(origins (G, 3), dirs (G, 3)) -> (G,)`` along the shadow rays of the renderer's frame (e.g.
    :func:`neural.render.view.bodies_transmittance`), asked once for every lit point (None: the fields
    block no light; nothing does without ``look.shadows``)."""
    import torch

    t, base, lit, normal = layer.t, layer.base, layer.lit, layer.normal
    visible = torch.ones(len(t), dtype=torch.float64, device=dirs.device)
    if moving:
        o_w, d_w = to_world(frame, origins, dirs)
        near = torch.nonzero(moving.hits(o_w, d_w)[0] < t).squeeze(1)
        if len(near):  # the moving mesh in front: drawn as a static one, all of it
            mine = static_layer(look, frame, origins[near], dirs[near], obstacles, (*_meshes(meshes), moving))
            t, base, lit, normal = (x.clone() for x in (t, base, lit, normal))
            t[near], base[near], lit[near], normal[near] = mine.t, mine.base, mine.lit, mine.normal
        if look.shadows:  # its shadow on the static surfaces
            shaded = lit.amax(dim=1) > 0
            shaded[near] = False
            rays = torch.nonzero(shaded).squeeze(1)
            starts_w = o_w[rays] + t[rays, None] * d_w[rays] + SHADOW_OFFSET * normal[rays].double()
            light_w = torch.as_tensor(look.light_unit(), device=dirs.device).expand(len(rays), 3)
            visible[rays] = (~moving.blocked(starts_w, light_w)).double()
    if look.shadows and visibility is not None:
        rays = torch.nonzero((lit.amax(dim=1) > 0) & (visible > 0)).squeeze(1)
        if len(rays):
            light_here = torch.as_tensor(np.asarray(frame.rotation).T @ look.light_unit())
            starts = origins[rays] + t[rays, None].to(dirs.dtype) * dirs[rays]
            visible[rays] *= visibility(starts, light_here.to(starts).expand(len(rays), 3)).double()
    return (base + lit * visible[:, None].to(lit.dtype)).to(dirs.dtype)


def world_backdrop(
    look: WorldLook,
    frame: Placement,
    visibility: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    obstacles: Obstacles | None = None,
    meshes: Meshes | Sequence[Meshes] = (),
    sky_colors: Callable[[torch.Tensor], torch.Tensor] | None = None,
    moving: Meshes | None = None,
):
    """``backdrop(origins (R, 3), dirs (R, 3), rays=None) -> (R, 3)`` of
    :func:`neural.render.view.render_bodies`: what rays of the renderer's frame (``frame`` places it in the
    world) see behind the fields, :func:`world_colors` of their :func:`static_layer` computed for them (the
    ground of ``look``, the ``obstacles``, the static ``meshes``, the sky or ``sky_colors``) with the light's
    ``visibility`` through the fields and the ``moving`` meshes. ``rays``, their indices among the
    renderer's, are not needed: :class:`shellsim.film.static.StaticWorld` keeps the layers of a view."""

    def backdrop(origins: torch.Tensor, dirs: torch.Tensor, rays=None) -> torch.Tensor:
        layer = static_layer(look, frame, origins, dirs, obstacles, meshes, sky_colors)
        return world_colors(look, frame, layer, origins, dirs, visibility, moving, obstacles, meshes)

    return backdrop
