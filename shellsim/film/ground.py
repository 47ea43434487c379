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
"""

from __future__ import annotations

import math
from collections.abc import Callable
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


def ground_hits(frame: Placement, origins: torch.Tensor, dirs: torch.Tensor):
    """Where rays ``origins``, ``dirs`` (R, 3) of the renderer's frame meet the ground z = 0 of the world:
    ``hit`` (R,) bool (from above it, going down), ``t`` (R,) ray parameter (inf without a hit),
    ``points`` (R, 3) world hit points and the world directions ``dirs_w`` (R, 3) (``scale R d``)."""
    import torch

    o_w, d_w = to_world(frame, origins, dirs)
    hit = (o_w[:, 2] > 0) & (d_w[:, 2] < 0)
    t = torch.where(hit, -o_w[:, 2] / torch.where(hit, d_w[:, 2], -1.0), math.inf)
    points = o_w + torch.where(hit, t, 0.0)[:, None] * d_w
    return hit, t, points, d_w


def surface_t_max(
    look: WorldLook,
    frame: Placement,
    obstacles: Obstacles | None,
    origins,
    dirs,
    meshes: Meshes | None = None,
):
    """(R,) float64 ray parameter of the nearest opaque world surface in front of rays ``origins``, ``dirs``
    (R, 3) of the renderer's frame: the ground (when drawn), the obstacles and the ``meshes`` (inf where
    none). The bodies' samples beyond it are hidden: a body resting on the ground shows nothing of its shells
    below z = 0, and an obstacle hides what is behind it."""
    import torch

    t = (
        ground_hits(frame, origins, dirs)[1]
        if look.ground
        else torch.full_like(origins[:, 0], math.inf).double()
    )
    if obstacles or meshes:
        t = torch.minimum(t, _surface_hits(look, obstacles, meshes, *to_world(frame, origins, dirs))[0])
    return t


def _surface_hits(look: WorldLook, obstacles: Obstacles | None, meshes: Meshes | None, origins_w, dirs_w):
    """The nearest obstacle or mesh in front of world rays ``origins_w``, ``dirs_w`` (R, 3) float64: ``t``
    (R,) (inf where none), the unit normal ``normals`` (R, 3) facing the ray and the ``albedo`` (R, 3) there
    (the obstacles': ``look.obstacle_color``)."""
    import torch

    t, normals = obstacle_hits(obstacles or Obstacles(), origins_w, dirs_w)
    albedo = torch.tensor(look.obstacle_color, dtype=torch.float64, device=dirs_w.device).expand(len(t), 3)
    if meshes:
        t_mesh, mesh_normals, mesh_albedo = meshes.hits(origins_w, dirs_w)
        nearer = (t_mesh < t)[:, None]
        t = torch.minimum(t, t_mesh)
        normals, albedo = torch.where(nearer, mesh_normals, normals), torch.where(nearer, mesh_albedo, albedo)
    return t, normals, albedo


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


def world_backdrop(
    look: WorldLook,
    frame: Placement,
    visibility: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    obstacles: Obstacles | None = None,
    meshes: Meshes | None = None,
    sky_colors: Callable[[torch.Tensor], torch.Tensor] | None = None,
):
    """``backdrop(origins (R, 3), dirs (R, 3)) -> (R, 3)`` of :func:`neural.render.view.render_pixels`: the
    sky, with ``look.ground`` the lit checkered ground and the lit ``obstacles`` (module docstring) behind
    rays of the renderer's frame (``frame`` places it in the world), the nearest surface of each ray.
    ``visibility(origins (G, 3), dirs (G, 3)) -> (G,)``: the light's visibility along shadow rays of the
    renderer's frame (the field's transmittance, e.g. :func:`neural.render.view.transmittance`); None: the
    field blocks no light. With ``look.shadows`` False nothing blocks it. ``meshes``: opaque triangle meshes
    (:class:`~shellsim.film.obstacles.Meshes`), drawn and casting shadows as the obstacles do, in their own
    albedo. ``sky_colors(dirs_w (R, 3)) -> (R, 3)``: what rays that meet nothing see along world directions
    instead of the look's sky (a capture's environment map)."""
    import torch

    obstacles = Obstacles() if obstacles is None else obstacles
    meshes = Meshes() if meshes is None else meshes
    solid = bool(obstacles or meshes)
    light = look.light_unit()
    light_here = torch.as_tensor(np.asarray(frame.rotation).T @ light)  # toward the light, renderer's frame

    def backdrop(origins: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        light_w = torch.as_tensor(light, device=dirs.device)

        def shade(rays, t, points_w, normals_w):
            """Lambert shade (K,) float64 of the world ``points_w`` (K, 3) with outward ``normals_w`` (K, 3)
            that rays ``rays`` (K,) meet at ``t`` (K,): ``ambient + diffuse * max(n.l, 0) * V``."""
            cos = look.diffuse * (normals_w @ light_w).clamp_min(0.0)
            value = look.ambient + cos
            lit = torch.nonzero(cos > 0).squeeze(1)
            if not look.shadows or not len(lit) or (visibility is None and not solid):
                return value
            visible = torch.ones(len(lit), dtype=torch.float64, device=dirs.device)
            if solid:
                starts_w = points_w[lit] + SHADOW_OFFSET * normals_w[lit]
                towards = light_w.expand(len(lit), 3)
                visible = visible * ~(
                    blocked(obstacles, starts_w, towards) | meshes.blocked(starts_w, towards)
                )
            if visibility is not None:
                on = rays[lit]
                starts = origins.index_select(0, on) + t[lit, None].to(dirs.dtype) * dirs.index_select(0, on)
                visible = visible * visibility(starts, light_here.to(starts).expand(len(lit), 3)).double()
            value[lit] = look.ambient + cos[lit] * visible
            return value

        hit, t, points, dirs_w = ground_hits(frame, origins, dirs)
        color = sky(look, dirs_w) if sky_colors is None else sky_colors(dirs_w).to(dirs_w.dtype).clone()
        t_obstacle = None
        if solid:
            o_w = to_world(frame, origins, dirs)[0]
            t_obstacle, normals, albedo = _surface_hits(look, obstacles, meshes, o_w, dirs_w)
            hit = hit & (t < t_obstacle)
        if look.ground:
            ground = torch.nonzero(hit).squeeze(1)
            up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64, device=dirs.device).expand(len(ground), 3)
            ground_points = points.index_select(0, ground)
            shades = shade(ground, t[ground], ground_points, up)
            color[ground] = checker(look, ground_points) * shades[:, None]
        else:
            t = torch.full_like(t, math.inf)
        if t_obstacle is not None:
            seen = torch.nonzero(torch.isfinite(t_obstacle) & (t_obstacle < t)).squeeze(1)
            t_seen = t_obstacle[seen]
            points_w = o_w[seen] + t_seen[:, None] * dirs_w[seen]
            shades = shade(seen, t_seen, points_w, normals[seen])
            color[seen] = albedo[seen] * shades[:, None]
        return color.to(dirs.dtype)

    return backdrop
