"""Slow, obviously-correct twins of the film package's fast paths, for tests and benches only.

- :func:`world_backdrop_reference`: what a ray sees behind the bodies, every part of it (ground, obstacles,
  meshes, the light's visibility through each) computed anew for every ray of every frame, as the world was
  drawn before its static part was kept per view (:class:`shellsim.film.static.StaticWorld`); the meshes
  static and moving alike in one.

Nothing in the library imports this module.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from shellsim.film.ground import SHADOW_OFFSET, checker, sky, to_world
from shellsim.film.obstacles import Meshes, Obstacles, blocked, obstacle_hits
from shellsim.world import Placement, WorldLook


def world_backdrop_reference(
    look: WorldLook,
    frame: Placement,
    visibility: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    obstacles: Obstacles | None = None,
    meshes: Meshes | None = None,
    sky_colors: Callable[[torch.Tensor], torch.Tensor] | None = None,
):
    """``backdrop(origins (R, 3), dirs (R, 3), rays=None) -> (R, 3)`` of
    :func:`neural.render.view.render_bodies`: the sky, with ``look.ground`` the lit checkered ground and the
    lit ``obstacles`` (:mod:`shellsim.film.ground`) behind rays of the renderer's frame (``frame`` places it
    in the world), the nearest surface of each ray.
    ``visibility(origins (G, 3), dirs (G, 3)) -> (G,)``: the light's visibility along shadow rays of the
    renderer's frame (the field's transmittance, e.g. :func:`neural.render.view.transmittance`); None: the
    field blocks no light. With ``look.shadows`` False nothing blocks it. ``meshes``: opaque triangle meshes
    (:class:`~shellsim.film.obstacles.Meshes`), drawn and casting shadows as the obstacles do, in their own
    albedo. ``sky_colors(dirs_w (R, 3)) -> (R, 3)``: what rays that meet nothing see along world directions
    instead of the look's sky (a capture's environment map). The backdrop takes its rays' indices, third,
    as :func:`neural.render.view.render_bodies` gives them, and ignores them."""
    obstacles = Obstacles() if obstacles is None else obstacles
    meshes = Meshes() if meshes is None else meshes
    solid = bool(obstacles or meshes)
    light = look.light_unit()
    light_here = torch.as_tensor(np.asarray(frame.rotation).T @ light)  # toward the light, renderer's frame

    def backdrop(origins: torch.Tensor, dirs: torch.Tensor, rays=None) -> torch.Tensor:
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
            t_obstacle, normals, albedo = _nearest_surface(look, obstacles, meshes, o_w, dirs_w)
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


def _nearest_surface(look: WorldLook, obstacles: Obstacles, meshes: Meshes, origins_w, dirs_w):
    """The nearest obstacle or mesh in front of world rays ``origins_w``, ``dirs_w`` (R, 3) float64: ``t``
    (R,) (inf where none), the unit normal ``normals`` (R, 3) and the ``albedo`` (R, 3) there."""
    t, normals = obstacle_hits(obstacles, origins_w, dirs_w)
    albedo = torch.tensor(look.obstacle_color, dtype=torch.float64, device=dirs_w.device).expand(len(t), 3)
    if meshes:
        t_mesh, mesh_normals, mesh_albedo = meshes.hits(origins_w, dirs_w)
        nearer = (t_mesh < t)[:, None]
        t = torch.minimum(t, t_mesh)
        normals, albedo = torch.where(nearer, mesh_normals, normals), torch.where(nearer, mesh_albedo, albedo)
    return t, normals, albedo


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
