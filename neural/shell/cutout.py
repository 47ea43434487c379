"""The object cut out of a capture (issue 43): a region of the field's world (a box, optionally above the
plane the object rests on) whose content becomes a **body** with its own shells, and whose complement is the
**backdrop**, the rest of the field, drawn around it and never moved.

- :class:`Cut`: the region, ``contains`` (which samples belong to the body) and ``distance`` (a bound of the
  distance to it, positive outside: the body's SDF is ``max(f, distance)``, the field's content cut off at
  the region's faces);
- :func:`propose_cut`: the region the cameras look at when the user names none: the field's surface
  near their focus point, the supporting plane found there by RANSAC (a table, normal within
  :data:`PLANE_TILT_DEGREES` of up; else the wall the object hangs on), and the connected part of the
  surface above it nearest the focus;
- :func:`cut_shells`: Procedure 2 on the cut field over a grid around the region (so the body's shells are
  as fine as the extraction's resolution over the object, not over the whole room);
- :class:`RegionMask`: a map of samples (:class:`neural.render.view.RestMap`) that keeps those inside (the
  body) or outside (the backdrop) the region: the two together at rest show exactly the samples of one
  field, each from its own shells.

Units: world units of the asset's frame. The body's shells are extracted on a world grid (a contracted
field evaluated at the contracted points): inside the contraction's unit ball, where an object sits, the
two spaces are one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from .extract import ShellConfig, extract_shells, sample_grid, shell_width_stats
from .from_field import FieldShells

#: The supporting plane's normal is at most this far from the capture's up (degrees).
PLANE_TILT_DEGREES = 30.0
#: Grid nodes per axis over the proposal's ball when looking for the surface, and RANSAC's tries.
PROPOSAL_GRID = 96
PLANE_TRIES = 256
#: A proposed box reaches this many proposal voxels past the surface it holds.
BOX_MARGIN_VOXELS = 3
#: The cut's floor lies this many proposal voxels above (in front of) the supporting plane, so that the
#: table's or wall's own surface, its kernel's width, stays whole with the backdrop when the body moves.
FLOOR_VOXELS = 2


@dataclass(frozen=True)
class Cut:
    """Inside the box ``lo``..``hi`` (3,) and, with a plane, on the side its unit ``normal`` (3,) points to
    from ``point`` (3,) (the object above its table), world units of the asset's frame."""

    lo: np.ndarray
    hi: np.ndarray
    point: np.ndarray | None = None
    normal: np.ndarray | None = None

    def __post_init__(self):
        lo, hi = (np.asarray(v, np.float64).reshape(3) for v in (self.lo, self.hi))
        if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi > lo).all()):
            raise InputError(f"cut box: expected finite corners lo < hi, got {lo.tolist()} {hi.tolist()}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        if (self.point is None) != (self.normal is None):
            raise InputError("cut plane: needs both a point and a normal")
        if self.normal is not None:
            normal = np.asarray(self.normal, np.float64).reshape(3)
            if not (np.isfinite(normal).all() and np.linalg.norm(normal) > 0):
                raise InputError(f"cut plane: the normal {normal.tolist()} has no direction")
            object.__setattr__(self, "normal", normal / np.linalg.norm(normal))
            object.__setattr__(self, "point", np.asarray(self.point, np.float64).reshape(3))

    def distance(self, x: torch.Tensor) -> torch.Tensor:
        """(N,) a lower bound of the distance of points ``x`` (N, 3) to the region, positive outside and
        negative inside (the box's SDF, intersected with the plane's half-space)."""
        lo, hi = (torch.as_tensor(v).to(x) for v in (self.lo, self.hi))
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        q = (x - centre).abs() - half
        box = q.clamp_min(0.0).norm(dim=1) + q.amax(dim=1).clamp_max(0.0)
        if self.normal is None:
            return box
        point, normal = (torch.as_tensor(v).to(x) for v in (self.point, self.normal))
        return torch.maximum(box, -((x - point) @ normal))

    def contains(self, x: torch.Tensor) -> torch.Tensor:
        """(N,) bool: points ``x`` (N, 3) inside the region."""
        return self.distance(x) <= 0

    def to_dict(self) -> dict:
        """JSON-ready: ``box`` [[lo], [hi]] and ``plane`` {point, normal} or None."""
        plane = None
        if self.normal is not None:
            plane = {"point": self.point.tolist(), "normal": self.normal.tolist()}
        return {"box": [self.lo.tolist(), self.hi.tolist()], "plane": plane}

    @classmethod
    def from_dict(cls, data, where: str) -> Cut:
        """Inverse of :meth:`to_dict`; an :class:`InputError` naming ``where`` when malformed."""
        try:
            plane = data.get("plane") or {}
            lo, hi = data["box"]
            return cls(lo, hi, plane.get("point"), plane.get("normal"))
        except InputError as err:
            raise InputError(f"{where}: {err}") from None
        except (AttributeError, KeyError, TypeError, ValueError) as err:
            raise InputError(f"{where}: expected {{box: [[x, y, z], [x, y, z]], plane}} ({err})") from None


class RegionMask:
    """Keeps the samples inside ``cut`` (``inside`` true: the body) or outside it (the backdrop): a map of
    samples that moves nothing (stretch 1) and drops the others."""

    def __init__(self, cut: Cut, inside: bool):
        self.cut, self.inside = cut, inside

    def map_rays(self, points: torch.Tensor, unit_dirs: torch.Tensor):
        kept = self.cut.contains(points)
        return points, unit_dirs, torch.ones_like(points[:, 0]), kept if self.inside else ~kept


def _unit_ball(field) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius of the part of the world where the field's space is the world's: a contracted
    field's unit ball, else its whole box (half its side)."""
    contraction = getattr(field, "contraction", None)
    center = field.center.detach().double().cpu().numpy()
    if contraction is None:
        return center, 1.0 / float(field.scale)
    return center, contraction.radius


@torch.no_grad()
def propose_cut(
    field, up, center=None, radius: float | None = None, box: Cut | None = None, device: str = "cpu"
) -> Cut:
    """The cut of the object the cameras look at: the field's surface (``|f| <`` a voxel) on a
    :data:`PROPOSAL_GRID`^3 grid over the ball ``center``, ``radius`` (defaults: the field's centre, the
    cameras' focus, and its unit ball), the supporting plane among those points by RANSAC (the plane with
    most points within a voxel whose normal is within :data:`PLANE_TILT_DEGREES` of ``up`` (3,), a table;
    else the wall the object hangs on, :func:`_object_floor`; none when fewer than a tenth of the points
    lie on one), and the connected part of the surface above (in front of) that plane, from
    :data:`FLOOR_VOXELS` over it (the cut's floor), nearest the centre, boxed with
    :data:`BOX_MARGIN_VOXELS` to spare; a box without plane when there is no plane. With ``box`` (a
    :class:`Cut` the user named) the box is that one, and only the floor is found, among the surface inside
    it. An :class:`InputError` when no surface lies there."""
    from scipy import ndimage

    ball_center, ball_radius = _unit_ball(field)
    if box is not None:
        center, radius = 0.5 * (box.lo + box.hi), 0.5 * float(np.linalg.norm(box.hi - box.lo))
    center = ball_center if center is None else np.asarray(center, np.float64).reshape(3)
    radius = ball_radius if radius is None else float(radius)
    n = PROPOSAL_GRID
    voxel = 2.0 * radius / (n - 1)
    f, _ = sample_grid(
        lambda x: world_sdf_and_kernel(field, x),
        center - radius,
        center + radius,
        n,
        device=device,
    )
    f = f.cpu().numpy()
    ijk = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), -1)
    nodes = center - radius + voxel * ijk
    in_ball = np.linalg.norm(nodes - center, axis=-1) <= radius
    surface = (np.abs(f) < voxel) & in_ball
    points = nodes[surface]
    if len(points) < 16:
        raise InputError(f"cut: the field has no surface within {radius:.3g} of {center.round(4).tolist()}")
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    if box is not None:
        inside = box.contains(torch.as_tensor(points)).numpy()
        floor = _object_floor(points[inside], up, voxel) if inside.sum() >= 16 else None
        return box if floor is None else Cut(box.lo, box.hi, *floor)
    floor = _object_floor(points, up, voxel)
    keep = surface.copy()
    if floor is not None:
        keep &= (nodes - floor[0]) @ floor[1] > 0.0
    labels, count = ndimage.label(ndimage.binary_dilation(keep, iterations=1), structure=np.ones((3, 3, 3)))
    labels = np.where(keep, labels, 0)
    if count == 0 or not labels.any():
        raise InputError(f"cut: no object above the table within {radius:.3g} of {center.round(4).tolist()}")
    marked = np.nonzero(labels)
    nearest = np.argmin(np.linalg.norm(nodes[marked] - center, axis=1))
    part = nodes[labels == labels[tuple(a[nearest] for a in marked)]]
    lo, hi = part.min(0) - BOX_MARGIN_VOXELS * voxel, part.max(0) + BOX_MARGIN_VOXELS * voxel
    return Cut(lo, hi) if floor is None else Cut(lo, hi, *floor)


def _object_floor(points: np.ndarray, up: np.ndarray, voxel: float):
    """The cut's floor among surface ``points`` (N, 3) of a proposal grid of ``voxel`` spacing: ``(point
    (3,), unit normal (3,))`` of the plane the object rests on, raised :data:`FLOOR_VOXELS` along its
    normal. The plane is the table it stands on (:func:`_supporting_plane`) or else the wall it hangs on
    (the plane through most points, of any tilt; its normal towards the side where more of the other points
    lie, the object's: behind a wall the cameras see little); None when neither holds a tenth of the
    points."""
    plane = _supporting_plane(points, up, voxel)
    if plane is None:
        plane = _supporting_plane(points, up, voxel, table=False)
        if plane is None:
            return None
        height = (points - plane[0]) @ plane[1]
        if (height > voxel).sum() < (height < -voxel).sum():
            plane = (plane[0], -plane[1])
    point, normal = plane
    return point + FLOOR_VOXELS * voxel * normal, normal


def world_sdf_and_kernel(field, x: torch.Tensor):
    """``field.sdf_and_kernel`` at world points ``x`` (N, 3): a contracted field's at their contracted
    points (the identity in its unit ball; beyond it, values in contracted units)."""
    contraction = getattr(field, "contraction", None)
    x = x.to(field.center.device)
    return field.sdf_and_kernel(x if contraction is None else contraction.to_field(x))


def is_table(normal, up) -> bool:
    """Whether a plane of unit ``normal`` (3,) is one an object stands on: within :data:`PLANE_TILT_DEGREES`
    of the unit ``up`` (3,)."""
    return float(np.dot(normal, up)) >= math.cos(math.radians(PLANE_TILT_DEGREES))


def region_sdf_and_kernel(field, x: torch.Tensor, cut: Cut | None = None):
    """:func:`world_sdf_and_kernel` at world points ``x`` (N, 3), with the SDF cut to ``cut``'s region
    (``max(f, distance)``: nothing outside it) when one is given."""
    sdf, s = world_sdf_and_kernel(field, x)
    if cut is not None:
        sdf = torch.maximum(sdf, cut.distance(x.double()).to(sdf))
    return sdf, s


def _supporting_plane(points: np.ndarray, up: np.ndarray, tolerance: float, table: bool = True):
    """``(point (3,), unit normal (3,) towards up)`` of the plane through most ``points`` (N, 3) within
    ``tolerance``, refitted by least squares to its inliers, among planes whose normal is within
    :data:`PLANE_TILT_DEGREES` of ``up`` (``table``) or of any tilt; None when it holds fewer than a tenth
    of the points."""
    rng = np.random.default_rng(0)
    best, best_count = None, 0
    for _ in range(PLANE_TRIES):
        a, b, c = points[rng.choice(len(points), 3, replace=False)]
        normal = np.cross(b - a, c - a)
        if not np.linalg.norm(normal) > 0:
            continue
        normal /= np.linalg.norm(normal)
        normal = normal if normal @ up >= 0 else -normal
        if table and not is_table(normal, up):
            continue
        count = int((np.abs((points - a) @ normal) < tolerance).sum())
        if count > best_count:
            best, best_count = (a, normal), count
    if best is None or best_count < len(points) / 10:
        return None
    inliers = points[np.abs((points - best[0]) @ best[1]) < tolerance]
    point = inliers.mean(0)
    normal = np.linalg.svd(inliers - point)[2][-1]
    return point, normal if normal @ up >= 0 else -normal


def cut_shells(field, cut: Cut, config: ShellConfig, device: str = "cpu") -> FieldShells:
    """Procedure 2 on the field cut to ``cut`` (``f_cut = max(f, distance)``, nothing outside the region) on
    a ``config.resolution``^3 grid over the cube around the region's box (``config``'s lengths in the
    field's unit space, as for the whole field; a contracted field at the contracted points,
    :func:`world_sdf_and_kernel`): the body's M+ and M- in world units, closed, inside the region up to the
    dilation's reach."""
    scale = float(field.scale)
    centre = 0.5 * (cut.lo + cut.hi)
    half = 0.5 * float((cut.hi - cut.lo).max()) * 1.1  # room for the dilation beyond the faces
    lo_u = (centre - half - field.center.detach().double().cpu().numpy()) * scale
    hi_u = lo_u + 2.0 * half * scale

    def unit_fn(u: torch.Tensor):
        sdf, s = region_sdf_and_kernel(field, field.center + u / scale, cut)
        return sdf * scale, s * scale

    with torch.no_grad():
        f, s = sample_grid(unit_fn, lo_u, hi_u, config.resolution, device=device)
    spacing = float(hi_u[0] - lo_u[0]) / (config.resolution - 1)
    result = extract_shells(f, s, lo_u, spacing, config)
    center = field.center.detach().double().cpu().numpy()
    for mesh in (result.outer, result.inner):
        mesh.vertices = mesh.vertices / scale + center
    stats = {f"width_{k}": float(v) for k, v in shell_width_stats(result.outer, result.inner).items()}
    stats.update(outer_faces=int(len(result.outer.faces)), inner_faces=int(len(result.inner.faces)))
    return FieldShells(result.outer, result.inner, stats)
