"""The tetrahedral cage of an asset (paper Sec. 5; docs/architecture.md, "cages and where they are kept").

"We first dilate and tetrahedralize the outer mesh M+ with Fast-TetWild to produce a tetrahedral mesh that
encapsulates the scene [...] any deformation is transferred to M+ and M- via barycentric interpolation,
using precomputed barycentric coordinates generated as a pre-process."

:func:`build_cage`:

1. **dilate** ``M+`` by ``margin`` (relative to its bounding-box diagonal): marching cubes of its signed
   distance on a grid of cell ``margin / 2`` at the level ``+margin`` (``igl.offset_surface``), which is a
   closed surface by construction, then quadric-error decimation to ``surface_faces`` triangles, since
   fTetWild's time grows with its input;
   ``margin=0`` skips this: a closed mesh that is the body itself is tetrahedralised as it is;
2. **tetrahedralize** it with fTetWild (:func:`shellsim.tetcage.tetwild.tetrahedralize`: seeded, one thread, a
   fresh process per run, so the same shells and settings give the same cage), steering the ideal edge
   length until the tet count is within a factor ``tolerance`` of ``target_tets`` (at most
   ``max_attempts`` runs; the closest is kept). fTetWild's envelope (how far its boundary may stray from the
   dilated surface) is ``envelope * margin`` (:data:`UNDILATED_EPSILON` of the diagonal when undilated);
3. **embed** every ``M+`` and ``M-`` vertex (:func:`shellsim.tetcage.embed.embed_points`) and drop the
   connected parts of the tet mesh that hold none of them (fTetWild's stray tets), with a log line;
4. **validate** (:func:`check_tet_mesh`): every tet positively oriented and not degenerate, and one solid
   connected through shared faces. A shell whose parts lie farther apart than twice the margin gives a
   cage in pieces, which is an :class:`~neural.errors.InputError` (raise the margin, or remove the floaters).

``cage.npz`` (format version 1, no pickle): ``vertices`` (V, 3) float64, ``tets`` (T, 4) int64,
optionally ``outer_tet`` (Vo,) int64, ``outer_bary`` (Vo, 4) float64, ``inner_tet`` (Vi,), ``inner_bary``
(Vi, 4) (:func:`load_or_build_cage` leaves them out: for the 250k shell vertices of the LEGO they are 10
MB against 0.3 MB for the cage, and embedding again takes half a second), ``shell_digest`` (sha256 of the
shells' vertex and face arrays as loaded), ``config`` (JSON of :class:`CageConfig`), ``format``,
``format_version``.
"""

from __future__ import annotations

import hashlib
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from neural.errors import InputError
from shellsim.tetcage.embed import embed_points
from shellsim.tetcage.geometry import cage_digest, connected_parts, tet_quality
from shellsim.tetcage.tetwild import tetrahedralize

logger = logging.getLogger(__name__)


#: Tets with :func:`tet_quality` below this are degenerate (1 is a regular tet).
DEGENERATE_QUALITY = 1e-6


#: Cells of the dilation's signed-distance grid per margin, and the grid's limits along the longest side.
GRID_CELLS_PER_MARGIN = 2


GRID_MIN, GRID_MAX = 16, 160


#: fTetWild's tet count at ideal edge length ``L`` is about ``TETS_PER_VOLUME * volume / L**3 +
#: TETS_PER_AREA * area / L**2`` (least squares on a bumpy sphere, a box, a torus, a capsule and a plant-like
#: shape at the default envelope; within -30%/+25% on them). Only the first guess of ``L`` depends on it.
TETS_PER_VOLUME, TETS_PER_AREA = 4.8, 7.6


#: fTetWild's envelope relative to the bounding-box diagonal when the surface is not dilated (its default).
UNDILATED_EPSILON = 1e-3


#: What a cage in pieces asks for: a dilated shell, an undilated mesh.
APART_DILATED = (
    "parts of the outer shell lie farther apart than twice the margin. Build the cage with a larger margin "
    "(the cage, simulate and wind commands set one; the others use the stored cage) until they merge, or "
    "remove the floating parts from the shell"
)


APART_UNDILATED = "the mesh must be one connected solid: simulate its parts one at a time, or join them"


@dataclass
class CageConfig:
    """Settings of :func:`build_cage`.

    margin : dilation of ``M+`` before tetrahedralising, relative to its bounding-box diagonal; 0 for none
        (a mesh that is the body itself)
    target_tets : the tet count to aim for; the result lies within a factor ``tolerance`` when fTetWild
        can resolve the surface with that few (a thin, detailed shell needs more)
    tolerance : accepted ratio between the tet count and ``target_tets``
    max_attempts : fTetWild runs at most, steering the edge length between them
    surface_faces : triangles of the dilated surface handed to fTetWild
    envelope : fTetWild's envelope (largest distance of the cage boundary from the dilated surface),
        as a fraction of the margin
    """

    margin: float = 0.02
    target_tets: int = 5000
    tolerance: float = 1.5
    max_attempts: int = 3
    surface_faces: int = 4000
    envelope: float = 0.25

    def __post_init__(self):
        if not (math.isfinite(self.margin) and self.margin >= 0):
            raise ValueError(f"margin must be a number >= 0, got {self.margin}")
        if self.target_tets < 10:
            raise ValueError(f"target_tets must be at least 10, got {self.target_tets}")
        if not self.tolerance > 1:
            raise ValueError(f"tolerance must be > 1, got {self.tolerance}")
        if self.max_attempts < 1:
            raise ValueError(f"max_attempts must be >= 1, got {self.max_attempts}")
        if self.surface_faces < 100:
            raise ValueError(f"surface_faces must be >= 100, got {self.surface_faces}")
        if not 0 < self.envelope < 1:
            raise ValueError(f"envelope must lie in (0, 1), got {self.envelope}")


@dataclass
class Cage:
    """A rest cage and the embedding of the shells' vertices in it.

    vertices : (V, 3) float64, tets : (T, 4) int64 (positive volumes),
    outer_tet : (Vo,) int64 and outer_bary : (Vo, 4) float64 for the vertices of ``M+``,
    inner_tet : (Vi,) int64 and inner_bary : (Vi, 4) float64 for those of ``M-``,
    shell_digest : :func:`shell_digest` of the shells embedded, config : the settings it was built with,
    path : the file it was read from or saved to ("" for one only in memory).
    """

    vertices: np.ndarray
    tets: np.ndarray
    outer_tet: np.ndarray
    outer_bary: np.ndarray
    inner_tet: np.ndarray
    inner_bary: np.ndarray
    shell_digest: str
    config: CageConfig = field(default_factory=CageConfig)
    path: str = ""

    @property
    def digest(self) -> str:
        """:func:`shellsim.tetcage.geometry.cage_digest` of the rest cage: the identity a motion records."""
        return cage_digest(self.vertices, self.tets)


def check_tet_mesh(vertices: np.ndarray, tets: np.ndarray, what: str, apart: str = APART_DILATED) -> None:
    """Raise :class:`InputError` (``what: problem``) unless the tets form one solid of well-shaped,
    positively oriented tets; ``apart`` is the advice when they form several. vertices (V, 3), tets (T, 4)."""
    if len(tets) == 0:
        raise InputError(f"{what}: the cage has no tetrahedra")
    if not np.isfinite(vertices).all():
        raise InputError(f"{what}: cage vertices contain NaN or infinity")
    quality = tet_quality(vertices, tets)
    if (quality <= 0).any():
        raise InputError(f"{what}: {int((quality <= 0).sum())} of {len(tets)} cage tets are inverted or flat")
    if (quality < DEGENERATE_QUALITY).any():
        raise InputError(
            f"{what}: {int((quality < DEGENERATE_QUALITY).sum())} of {len(tets)} cage tets are "
            f"degenerate (quality below {DEGENERATE_QUALITY:g})"
        )
    parts = connected_parts(tets)
    n_parts = int(parts.max()) + 1
    if n_parts > 1:
        sizes = np.sort(np.bincount(parts))[::-1]
        raise InputError(
            f"{what}: the cage falls apart into {n_parts} separate solids ({', '.join(map(str, sizes[:5]))} "
            f"tets); {apart}"
        )


def holding_parts(tets: np.ndarray, held: np.ndarray) -> np.ndarray:
    """(T,) bool: the tets of the connected parts (:func:`connected_parts`) that hold at least one of the
    tets ``held`` (P,) int (those of the shell vertices). The others are fTetWild's strays: logged. When no
    part holds any, all are kept (the check of the cage then reports the pieces)."""
    parts = connected_parts(tets)
    holding = np.zeros(int(parts.max()) + 1, bool)
    holding[parts[held]] = True
    keep = holding[parts]
    if not holding.any():
        return np.ones(len(tets), bool)
    if not keep.all():
        sizes = np.bincount(parts[~keep])
        logger.info(
            "dropped %d stray part(s) of the tet mesh that hold no shell vertex (%s tets)",
            int((~holding).sum()),
            ", ".join(str(n) for n in sorted(sizes[sizes > 0], reverse=True)),
        )
    return keep


def drop_tets(vertices: np.ndarray, tets: np.ndarray, keep: np.ndarray):
    """The tets (T, 4) where ``keep`` (T,) bool, with their vertices (V, 3) renumbered -> (V', 3), (T', 4),
    and (T,) int64 the new index of each kept tet (-1 for a dropped one)."""
    used, new_tets = np.unique(tets[keep], return_inverse=True)
    new_index = np.full(len(tets), -1, np.int64)
    new_index[keep] = np.arange(int(keep.sum()))
    return vertices[used], new_tets.reshape(-1, 4).astype(np.int64), new_index


def shell_digest(outer, inner) -> str:
    """sha256 of the shells' vertex (float64) and face (int64) arrays: the cage is rebuilt when it changes."""
    h = hashlib.sha256()
    for mesh in (outer, inner):
        for array in (np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)):
            h.update(str(array.shape).encode())
            h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()


def dilate_surface(
    vertices: np.ndarray, faces: np.ndarray, offset: float, max_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """The closed surface at signed distance ``+offset`` outside a closed triangle mesh.

    vertices (N, 3) float, faces (M, 3) int, offset > 0 in world units -> (N', 3) float64, (M', 3) int64 with
    ``M' <= max_faces``: marching cubes on a signed-distance grid with cells ``offset / 2`` (fast winding
    number sign), decimated by quadric-error edge collapse (which keeps ~90% of the offset at sharp corners,
    where midpoint collapse cuts them).
    """
    import igl

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    longest = float(np.ptp(vertices, axis=0).max()) + 2 * offset
    wanted = math.ceil(longest / offset * GRID_CELLS_PER_MARGIN)
    cells = int(np.clip(wanted, GRID_MIN, GRID_MAX))
    if wanted > GRID_MAX:
        logger.warning(
            "margin %.3g is small for a %d-cell dilation grid: the cage may not contain every shell "
            "vertex (those outside get extrapolated coordinates)",
            offset,
            GRID_MAX,
        )
    out_v, out_f, *_ = igl.offset_surface(
        vertices, faces, offset, cells, igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER
    )
    logger.debug("dilated surface: %d triangles on a grid of %d cells", len(out_f), cells)
    if len(out_f) > max_faces:
        out_v, out_f, _, _ = igl.qslim(
            np.asfortranarray(out_v), np.asfortranarray(out_f, dtype=np.int32), max_faces, False
        )
    return np.ascontiguousarray(out_v, dtype=np.float64), np.ascontiguousarray(out_f, dtype=np.int64)


def tetrahedralize_to_count(
    vertices: np.ndarray, faces: np.ndarray, config: CageConfig, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """fTetWild on a closed surface with about ``config.target_tets`` tets.

    vertices (N, 3), faces (M, 3) of the dilated surface, margin in world units (0: undilated) -> (V, 3)
    float64, (T, 4) int64. The edge length starts from the model of :data:`TETS_PER_VOLUME` and
    :data:`TETS_PER_AREA`, then follows a secant on log(count) against log(edge length), changing by a
    factor 2 at most per run.
    """
    import trimesh

    surface = trimesh.Trimesh(vertices, faces, process=False)
    diag = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    epsilon = config.envelope * margin / diag if margin > 0 else UNDILATED_EPSILON
    target = config.target_tets
    # positive root u = 1 / L of TETS_PER_VOLUME * volume * u^3 + TETS_PER_AREA * area * u^2 = target
    roots = np.roots([TETS_PER_VOLUME * abs(surface.volume), TETS_PER_AREA * surface.area, 0.0, -target])
    edge = 1.0 / float(max(r.real for r in roots if abs(r.imag) < 1e-9 * abs(r)))

    def off(tets: np.ndarray) -> float:  # how far a tet count is from the target, as a log ratio
        return abs(math.log(max(len(tets), 1) / target))

    tried: list[tuple[float, np.ndarray, np.ndarray]] = []
    for attempt in range(config.max_attempts):
        start = time.perf_counter()
        tet_v, tets, seeded = tetrahedralize(vertices, faces, edge, epsilon)
        if not seeded and attempt == 0:
            logger.warning("fTetWild cannot be seeded on this platform: rebuilding this cage may differ")
        logger.info(
            "fTetWild run %d: edge %.4g -> %d tets (%.1f s)",
            attempt + 1,
            edge,
            len(tets),
            time.perf_counter() - start,
        )
        tried.append((edge, tet_v, tets))
        if off(tets) <= math.log(config.tolerance):
            break
        slope = -3.0  # count ~ edge^-3 in the bulk, ~ edge^-2 near the surface
        if len(tried) > 1 and tried[-2][0] != edge and len(tried[-2][2]) and len(tets):
            slope = math.log(len(tets) / len(tried[-2][2])) / math.log(edge / tried[-2][0])
            slope = float(np.clip(slope, -6.0, -0.5))
        edge *= float(np.clip((max(len(tets), 1) / target) ** (-1 / slope), 0.5, 2.0))
    _, tet_v, tets = min(tried, key=lambda t: off(t[2]))
    if off(tets) > math.log(config.tolerance):
        logger.warning(
            "cage has %d tets, target %d: fTetWild could not get closer in %d runs",
            len(tets),
            target,
            config.max_attempts,
        )
    return tet_v, tets


def build_cage(outer, inner, config: CageConfig | None = None, what: str = "outer shell") -> Cage:
    """Dilate, tetrahedralize, validate and embed (module docstring). ``outer`` (M+) and ``inner`` (M-) are
    closed ``trimesh.Trimesh`` in world coordinates; ``what`` names the source in error messages."""
    config = config or CageConfig()
    for name, mesh in (("outer", outer), ("inner", inner)):
        if not hasattr(mesh, "vertices") or not hasattr(mesh, "faces") or len(mesh.faces) == 0:
            raise ValueError(f"{name}: expected a non-empty trimesh.Trimesh, got {type(mesh).__name__}")
    start = time.perf_counter()
    outer_v = np.asarray(outer.vertices, dtype=np.float64)
    inner_v = np.asarray(inner.vertices, dtype=np.float64)
    margin = config.margin * float(np.linalg.norm(np.ptp(outer_v, axis=0)))
    if margin > 0:
        surf_v, surf_f = dilate_surface(outer_v, outer.faces, margin, config.surface_faces)
        logger.info(
            "dilated M+ by %.4g: %d triangles (%.1f s)", margin, len(surf_f), time.perf_counter() - start
        )
    else:
        surf_v, surf_f = outer_v, np.asarray(outer.faces, np.int64)
    try:
        vertices, tets = tetrahedralize_to_count(surf_v, surf_f, config, margin)
    except RuntimeError as err:  # fTetWild crashed or refused the surface
        raise InputError(f"{what}: {err}") from None
    outer_tet, outer_bary = embed_points(vertices, tets, outer_v)
    inner_tet, inner_bary = embed_points(vertices, tets, inner_v)
    keep = holding_parts(tets, np.concatenate([outer_tet, inner_tet]))
    if not keep.all():
        vertices, tets, new_index = drop_tets(vertices, tets, keep)
        outer_tet, inner_tet = new_index[outer_tet], new_index[inner_tet]
    check_tet_mesh(vertices, tets, what, APART_DILATED if margin > 0 else APART_UNDILATED)
    logger.info("cage: %d vertices, %d tets (%.1f s)", len(vertices), len(tets), time.perf_counter() - start)
    return Cage(
        vertices, tets, outer_tet, outer_bary, inner_tet, inner_bary, shell_digest(outer, inner), config
    )
