"""Deformed space: transfer a cage deformation to the shells and map deformed points back to rest space.

Paper Sec. 5: the cage's deformation is transferred to ``M+`` / ``M-`` by barycentric interpolation
(:func:`deform_points`); to render, every sample ``x`` of a camera ray in deformed space is mapped back
to the rest space of the field through its containing deformed tet, ``x_rest = Phi^-1(x)``
(:meth:`InverseMap.map_points`), and the ray direction by finite differences,
``d_rest ~ normalize(Phi^-1(x + eps d) - Phi^-1(x))`` (:meth:`InverseMap.map_directions`); the length of
that difference over ``eps`` is the local stretch that turns a deformed ray section's length into its
rest-space length (:meth:`InverseMap.map_rays`).

``Phi^-1`` is piecewise affine: inside deformed tet ``t`` with vertices ``v0..v3`` (rest ``r0..r3``),
``b = D_t^-1 (x - v0)`` with ``D_t = [v1 - v0, v2 - v0, v3 - v0]`` and ``x_rest = r0 + R_t b`` with
``R_t = [r1 - r0, r2 - r0, r3 - r0]``. :class:`InverseMap` finds the tet by walking from the previous
point's tet across the faces the point lies beyond, else with a Warp BVH over the deformed tets' bounding
boxes (built once, refitted for every further frame by :meth:`InverseMap.update`), and runs the
point-in-tet test in a Warp kernel (CPU or CUDA) in float64.
:func:`map_points_reference` and :func:`map_directions_reference` are its brute-force numpy twins.

Points in no deformed tet (outside the cage) get ``inside = False`` and ``x_rest = nan``; the cage
contains all content, so a renderer drops those samples.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from neural.device import cpu_threads as default_cpu_threads
from neural.device import run_in_chunks
from shellsim.tetcage.embed import interpolate
from shellsim.tetcage.geometry import check_points, check_tets, tet_neighbors

#: Barycentric tolerance of the point-in-tet test: a point whose smallest barycentric coordinate is
#: at least ``-BARY_TOL`` is inside (points on shared and boundary faces are found).
BARY_TOL = 1e-6
#: Default finite-difference step of :meth:`InverseMap.map_directions`, relative to the cage's diagonal.
EPS_REL = 1e-4
#: Fewest points per CPU thread of a query.
_MIN_CHUNK = 16384
#: Most tets a point's search walks through from its hint before it queries the BVH.
_WALK_STEPS = wp.constant(8)
#: Consecutive points a CPU kernel thread maps, each first tried in its predecessor's tet (one per thread
#: on CUDA).
_CPU_SPAN = 256


def deform_points(cage_positions, tets, tet_index, bary) -> np.ndarray:
    """Barycentric interpolation of deformed cage vertices: the deformed ``M+`` / ``M-`` vertices.

    cage_positions : (V, 3) float, cage vertices of one frame
    tets : (T, 4) int
    tet_index : (P,) int, containing tet of each embedded point (from :mod:`shellsim.tetcage.embed`)
    bary : (P, 4) float, its barycentric coordinates in that tet
    returns : (P, 3) float64, ``sum_k bary[p, k] * cage_positions[tets[tet_index[p], k]]``
        (:func:`shellsim.tetcage.embed.interpolate` for one frame)
    """
    return interpolate(check_points("cage_positions", cage_positions), tets, tet_index, bary)


# --------------------------------------------------------------------------- Warp kernels


@wp.struct
class _Tets:
    """Per deformed tet ``t`` of one frame: ``origin`` v0, ``to_bary`` D_t^-1 (``valid`` 0 where D_t is
    degenerate), ``rest_origin`` r0, ``rest_edges`` R_t and ``neighbors`` (:func:`tet_neighbors`); ``bvh``
    the Warp BVH over their boxes."""

    bvh: wp.uint64
    origin: wp.array(dtype=wp.vec3d)
    to_bary: wp.array(dtype=wp.mat33d)
    rest_origin: wp.array(dtype=wp.vec3d)
    rest_edges: wp.array(dtype=wp.mat33d)
    valid: wp.array(dtype=wp.int32)
    neighbors: wp.array2d(dtype=wp.int32)


@wp.kernel
def _prepare_tets(
    deformed: wp.array(dtype=wp.vec3d),
    rest: wp.array(dtype=wp.vec3d),
    tets: wp.array2d(dtype=wp.int32),
    pad: wp.float64,
    min_det: wp.float64,
    lowers: wp.array(dtype=wp.vec3),
    uppers: wp.array(dtype=wp.vec3),
    out: _Tets,
):
    t = wp.tid()
    v0 = deformed[tets[t, 0]]
    v1 = deformed[tets[t, 1]]
    v2 = deformed[tets[t, 2]]
    v3 = deformed[tets[t, 3]]
    lo = wp.min(wp.min(v0, v1), wp.min(v2, v3))
    hi = wp.max(wp.max(v0, v1), wp.max(v2, v3))
    lowers[t] = wp.vec3(wp.float32(lo[0] - pad), wp.float32(lo[1] - pad), wp.float32(lo[2] - pad))
    uppers[t] = wp.vec3(wp.float32(hi[0] + pad), wp.float32(hi[1] + pad), wp.float32(hi[2] + pad))
    d = wp.matrix_from_cols(v1 - v0, v2 - v0, v3 - v0)
    out.origin[t] = v0
    r0 = rest[tets[t, 0]]
    out.rest_origin[t] = r0
    out.rest_edges[t] = wp.matrix_from_cols(
        rest[tets[t, 1]] - r0, rest[tets[t, 2]] - r0, rest[tets[t, 3]] - r0
    )
    if wp.abs(wp.determinant(d)) > min_det:
        out.to_bary[t] = wp.inverse(d)
        out.valid[t] = 1
    else:
        out.valid[t] = 0


@wp.func
def _locate(tets: _Tets, p: wp.vec3d):
    """The candidate tet whose smallest barycentric coordinate of ``p`` is largest (first one >= 0)."""
    pf = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
    query = wp.bvh_query_aabb(tets.bvh, pf, pf)
    t = int(0)  # noqa: UP018 (a Warp dynamic variable, not a constant)
    best = int(-1)  # noqa: UP018
    best_min = wp.float64(-1.0e300)
    best_b = wp.vec3d()
    while wp.bvh_query_next(query, t):
        if tets.valid[t] == 1:
            b = tets.to_bary[t] * (p - tets.origin[t])
            m = wp.min(wp.min(b[0], b[1]), wp.min(b[2], wp.float64(1.0) - b[0] - b[1] - b[2]))
            if m > best_min:
                best = t
                best_min = m
                best_b = b
                if m >= wp.float64(0.0):
                    break
    return best, best_min, best_b


@wp.func
def _locate_near(tets: _Tets, p: wp.vec3d, hint: int):
    """:func:`_locate`, walking from tet ``hint`` (-1: none) first: across the face of the most negative
    barycentric coordinate of ``p``, at most ``_WALK_STEPS`` tets; a tet that contains ``p`` (smallest
    coordinate >= 0) is taken without a search (where tets share a face, a point on it maps to the same
    rest point through either). A walk that leaves the cage, meets a degenerate tet or runs out of steps
    ends in the search."""
    t = hint
    m = wp.float64(-1.0e300)
    b = wp.vec3d()
    for _ in range(_WALK_STEPS):
        if t < 0:
            break
        if tets.valid[t] == 0:
            break
        b = tets.to_bary[t] * (p - tets.origin[t])
        b0 = wp.float64(1.0) - b[0] - b[1] - b[2]
        m = wp.min(wp.min(b0, b[0]), wp.min(b[1], b[2]))
        if m >= wp.float64(0.0):
            break
        k = int(0)  # noqa: UP018 (a Warp dynamic variable, not a constant)
        if b[0] == m:
            k = 1
        elif b[1] == m:
            k = 2
        elif b[2] == m:
            k = 3
        t = tets.neighbors[t, k]
    if m < wp.float64(0.0):
        t, m, b = _locate(tets, p)
    return t, m, b


@wp.func
def _to_rest(tets: _Tets, t: int, b: wp.vec3d):
    """``Phi^-1`` inside tet ``t`` of the point with barycentric coordinates ``b`` (b1, b2, b3)."""
    return tets.rest_origin[t] + tets.rest_edges[t] * b


@wp.kernel
def _map_kernel(
    tets: _Tets,
    points: wp.array(dtype=wp.vec3d),
    dirs: wp.array(dtype=wp.vec3d),
    with_dirs: int,
    eps: wp.float64,
    tol: wp.float64,
    span: int,
    out_points: wp.array(dtype=wp.vec3d),
    out_dirs: wp.array(dtype=wp.vec3d),
    out_stretch: wp.array(dtype=wp.float64),
    out_inside: wp.array(dtype=wp.bool),
):
    # thread i maps points [i span, (i + 1) span) in order, each first tried in its predecessor's tet (the
    # samples of a ray come one after the other, mostly a few in a tet)
    i = wp.tid()
    nan = wp.float64(wp.nan)
    hint = int(-1)  # noqa: UP018 (a Warp dynamic variable, not a constant)
    for j in range(i * span, wp.min((i + 1) * span, points.shape[0])):
        p = points[j]
        t, m, b = _locate_near(tets, p, hint)
        if t < 0 or m < -tol:
            out_inside[j] = False
            out_points[j] = wp.vec3d(nan, nan, nan)
            if with_dirs == 1:
                out_dirs[j] = wp.vec3d(nan, nan, nan)
                out_stretch[j] = nan
            continue
        hint = t
        x_rest = _to_rest(tets, t, b)
        out_inside[j] = True
        out_points[j] = x_rest
        if with_dirs == 1:
            d = dirs[j]
            # forward difference; backward where x + eps d leaves the cage; the containing tet's Jacobian
            # R_t D_t^-1 d (the eps -> 0 limit of both) where the cage is thinner than eps around x
            # (diff is the rest-space image of the step eps d, or of d itself for the Jacobian); x +- eps d
            # is nearly always in x's own tet
            step = eps
            t1, m1, b1 = _locate_near(tets, p + eps * d, t)
            if t1 >= 0 and m1 >= -tol:
                diff = _to_rest(tets, t1, b1) - x_rest
            else:
                t2, m2, b2 = _locate_near(tets, p - eps * d, t)
                if t2 >= 0 and m2 >= -tol:
                    diff = x_rest - _to_rest(tets, t2, b2)
                else:
                    diff = tets.rest_edges[t] * (tets.to_bary[t] * d)
                    step = wp.float64(1.0)
            out_dirs[j] = wp.normalize(diff)
            out_stretch[j] = wp.length(diff) / (step * wp.length(d))


# --------------------------------------------------------------------------- the inverse map


def _is_torch(x) -> bool:
    return type(x).__module__.split(".")[0] == "torch"


class InverseMap:
    """``Phi^-1`` of one frame: deformed space -> rest space through the deformed cage.

    deformed_vertices : (V, 3) float, cage vertices of this frame
    tets : (T, 4) int, cage tets (orientation not required; inverted tets are searched too, and where
        deformed tets overlap a point maps through one of those containing it)
    rest_vertices : (V, 3) float, the rest cage
    device : Warp device ("cpu", "cuda:0"); None picks Warp's preferred device (CUDA when present)
    tol : barycentric tolerance of the point-in-tet test
    cpu_threads : threads sharing a query on the CPU (None: :func:`neural.device.cpu_threads`)
    neighbors : (T, 4) int, the tet across each face as :func:`shellsim.tetcage.geometry.tet_neighbors` gives
        it;
        None computes it (-1 everywhere ends every walk at once, so each point searches the BVH)

    Building costs one Warp kernel over the tets and one BVH build (a few ms for 10k tets on a CPU), and
    the tets' neighbours unless given; :meth:`update` takes the map to another frame of the cage with a
    refit of the BVH instead of a build.
    Queries accept numpy arrays (answered as float64 numpy) or torch tensors (answered as tensors of
    the input's dtype and device).
    """

    def __init__(
        self,
        deformed_vertices,
        tets,
        rest_vertices,
        device: str | None = None,
        tol: float = BARY_TOL,
        cpu_threads: int | None = None,
        neighbors=None,
    ):
        deformed = check_points("deformed_vertices", deformed_vertices)
        rest = check_points("rest_vertices", rest_vertices)
        if rest.shape != deformed.shape:
            raise ValueError(
                f"rest_vertices: expected {deformed.shape} like deformed_vertices, got {rest.shape}"
            )
        tets = check_tets(tets, len(deformed))
        if not tol >= 0:
            raise ValueError(f"tol: expected >= 0, got {tol}")
        if cpu_threads is not None and not (isinstance(cpu_threads, int) and cpu_threads >= 1):
            raise ValueError(f"cpu_threads: expected a positive int or None, got {cpu_threads!r}")
        self.device = wp.get_device(device)
        self.tol = float(tol)
        self.cpu_threads = cpu_threads or default_cpu_threads()
        n = len(tets)
        dev = self.device
        neighbors = tet_neighbors(tets) if neighbors is None else np.asarray(neighbors)
        if neighbors.shape != tets.shape or not ((neighbors >= -1) & (neighbors < n)).all():
            raise ValueError(f"neighbors: expected shape {tets.shape} of tet indices or -1")
        self._tet_vertices = tets  # (T, 4) int64, for the mean edge of a frame
        self._shape = rest.shape
        self._rest = wp.array(rest, dtype=wp.vec3d, device=dev)
        self._corners = wp.array(tets.astype(np.int32), dtype=wp.int32, device=dev)
        self._lowers = wp.empty(n, dtype=wp.vec3, device=dev)
        self._uppers = wp.empty(n, dtype=wp.vec3, device=dev)
        self._tets = _Tets()
        self._tets.origin = wp.empty(n, dtype=wp.vec3d, device=dev)
        self._tets.to_bary = wp.zeros(n, dtype=wp.mat33d, device=dev)
        self._tets.rest_origin = wp.empty(n, dtype=wp.vec3d, device=dev)
        self._tets.rest_edges = wp.empty(n, dtype=wp.mat33d, device=dev)
        self._tets.valid = wp.empty(n, dtype=wp.int32, device=dev)
        self._tets.neighbors = wp.array(neighbors.astype(np.int32), dtype=wp.int32, device=dev)
        self._bvh = None
        self.update(deformed)

    def update(self, deformed_vertices) -> None:
        """Make this the map of another frame of the same cage, deformed to ``deformed_vertices`` (V, 3): the
        tets' matrices afresh and the BVH refitted to their boxes instead of rebuilt (0.2 against 6.8 ms
        for lego's 7,966 tets on a CPU; the boxes of a large deformation overlap more, and walks from
        the previous sample's tet avoid most queries)."""
        deformed = check_points("deformed_vertices", deformed_vertices)
        if deformed.shape != self._shape:
            raise ValueError(
                f"deformed_vertices: expected {self._shape} like the rest cage, got {deformed.shape}"
            )
        if not np.isfinite(deformed).all():
            raise ValueError("deformed_vertices: contain NaN or infinity")
        lo, hi = deformed.min(0), deformed.max(0)
        #: (float) diagonal of the deformed cage's bounding box
        self.diagonal = float(np.linalg.norm(hi - lo))
        # boxes padded for the float32 BVH and the barycentric tolerance; degenerate tets (|det D_t| below
        # 1e-12 mean edge^3) are never entered
        pad = 1e-5 * self.diagonal + 1e-6 * float(np.abs(deformed).max())
        tets = self._tet_vertices
        edge = np.linalg.norm(deformed[tets[:, 1]] - deformed[tets[:, 0]], axis=1).mean()
        dev = self.device
        wp.launch(
            _prepare_tets,
            dim=len(tets),
            inputs=[
                wp.array(deformed, dtype=wp.vec3d, device=dev),
                self._rest,
                self._corners,
                pad,
                1e-12 * edge**3,
            ],
            outputs=[self._lowers, self._uppers, self._tets],
            device=dev,
        )
        if self._bvh is None:
            self._bvh = wp.Bvh(self._lowers, self._uppers)  # kept alive with the map: kernels query it by id
            self._tets.bvh = self._bvh.id
        else:
            self._bvh.refit()
        if dev.is_cuda:  # queries on torch's stream must see the finished build
            wp.synchronize_device(dev)

    def map_points(self, x):
        """``Phi^-1`` of deformed points.

        x : (N, 3) deformed points, numpy or torch
        returns : x_rest (N, 3) rest points (nan outside the cage), inside (N,) bool
        """
        x_rest, _, _, inside = self._run(x, None, None)
        return x_rest, inside

    def map_directions(self, x, d, eps: float | None = None):
        """Rest-space directions of deformed rays by finite differences (paper Sec. 5).

        x : (N, 3) deformed points; d : (N, 3) deformed unit directions (numpy or torch)
        eps : step length; None uses ``EPS_REL`` times the deformed cage's diagonal
        returns : d_rest (N, 3) unit vectors, ``normalize(Phi^-1(x + eps d) - Phi^-1(x))``; the backward
            difference where ``x + eps d`` leaves the cage, the containing tet's Jacobian ``R_t D_t^-1 d``
            where both steps leave it; nan where ``x`` is outside the cage
        """
        return self._run(x, d, eps)[1]

    def map_samples(self, x, d, eps: float | None = None):
        """:meth:`map_points` and :meth:`map_directions` in one pass.

        returns : x_rest (N, 3), d_rest (N, 3), inside (N,)
        """
        x_rest, d_rest, _, inside = self._run(x, d, eps)
        return x_rest, d_rest, inside

    def map_rays(self, x, d, eps: float | None = None):
        """:meth:`map_samples` plus the local stretch along the ray (what a renderer wants).

        returns : x_rest (N, 3), d_rest (N, 3), stretch (N,), inside (N,). ``stretch`` is the rest-space
            length of a unit deformed length along ``d``: ``|Phi^-1(x + eps d) - Phi^-1(x)| / (eps |d|)``
            from the same difference as ``d_rest`` (``|R_t D_t^-1 d| / |d|`` for the Jacobian); a deformed
            ray section of length ``delta`` around ``x`` spans ``stretch * delta`` in rest space. nan outside.
        """
        return self._run(x, d, eps)

    def _run(self, x, d, eps):
        eps = EPS_REL * self.diagonal if eps is None else float(eps)
        if not eps > 0:
            raise ValueError(f"eps: expected > 0, got {eps}")
        torch_in, with_dirs = _is_torch(x), d is not None
        if with_dirs and _is_torch(d) != torch_in:
            raise TypeError("x and d: pass both as numpy arrays or both as torch tensors")
        # without directions the kernel never touches d, out_d and out_s (d and out_d alias x and out_x)
        if torch_in:
            import torch

            device = "cpu" if self.device.is_cpu else f"cuda:{self.device.ordinal}"
            xs = _torch_points("x", x, device)
            ds = _torch_points("d", d, device) if with_dirs else xs
            out_x = torch.empty_like(xs)
            out_d = torch.empty_like(xs) if with_dirs else out_x
            out_s = torch.empty(len(xs), dtype=torch.float64, device=device)
            out_in = torch.empty(len(xs), dtype=torch.bool, device=device)
            arrays = [wp.from_torch(a, dtype=wp.vec3d) for a in (xs, ds, out_x, out_d)]
            arrays += [wp.from_torch(out_s, dtype=wp.float64), wp.from_torch(out_in, dtype=wp.bool)]
            stream = None if self.device.is_cpu else wp.stream_from_torch(device)
        else:
            xs = wp.array(check_points("x", x), dtype=wp.vec3d, device=self.device)
            ds = wp.array(check_points("d", d), dtype=wp.vec3d, device=self.device) if with_dirs else xs
            out_x = wp.empty(len(xs), dtype=wp.vec3d, device=self.device)
            out_d = wp.empty(len(xs), dtype=wp.vec3d, device=self.device) if with_dirs else out_x
            out_s = wp.empty(len(xs), dtype=wp.float64, device=self.device)
            arrays = [xs, ds, out_x, out_d, out_s, wp.empty(len(xs), dtype=wp.bool, device=self.device)]
            stream = None
        if len(ds) != len(xs):
            raise ValueError(f"d: expected shape ({len(xs)}, 3) like x, got {tuple(d.shape)}")
        self._launch(arrays, int(with_dirs), eps, stream)
        if torch_in:
            dtype = x.dtype if x.is_floating_point() else None  # float64 for integer input
            x_rest, d_rest, stretch = (a.to(device=x.device, dtype=dtype) for a in (out_x, out_d, out_s))
            inside = out_in.to(x.device)
        else:
            x_rest, d_rest, stretch, inside = (a.numpy() for a in arrays[2:])
        if not with_dirs:
            d_rest = stretch = None
        return x_rest, d_rest, stretch, inside

    def _launch(self, arrays: list, with_dirs: int, eps: float, stream) -> None:
        """Run the map kernel on ``arrays`` = [x, d, out_x, out_d, out_stretch, out_inside]; on the CPU,
        split the points into chunks over ``cpu_threads`` Python threads (Warp releases the GIL during a
        CPU launch; the chunks write disjoint outputs)."""
        n = arrays[0].shape[0]

        span = 1 if self.device.is_cuda else _CPU_SPAN

        def launch(lo: int, hi: int) -> None:
            x, d, out_x, out_d, out_s, out_in = (a[lo:hi] for a in arrays)
            inputs = [self._tets, x, d, with_dirs, eps, self.tol, span]
            wp.launch(
                _map_kernel,
                dim=(hi - lo + span - 1) // span,
                inputs=inputs,
                outputs=[out_x, out_d, out_s, out_in],
                device=self.device,
                stream=stream,
            )

        wp.load_module(_map_kernel.module, device=self.device)
        run_in_chunks(n, launch, 1 if self.device.is_cuda else self.cpu_threads, _MIN_CHUNK)


def _torch_points(name: str, a, device: str):
    """(N, 3) tensor -> contiguous float64 tensor on ``device``."""
    import torch

    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {tuple(a.shape)}")
    return a.detach().to(device=device, dtype=torch.float64).contiguous()


# --------------------------------------------------------------------------- slow reference twins


def _barycentrics_all(deformed: np.ndarray, tets: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(N, T, 4) barycentric coordinates of every point in every tet (degenerate tets: -inf)."""
    v = deformed[tets]  # (T, 4, 3)
    edges = np.transpose(v[:, 1:] - v[:, :1], (0, 2, 1))  # (T, 3, 3), columns are edges
    det = np.linalg.det(edges)
    ok = np.abs(det) > 1e-12 * np.linalg.norm(v[:, 1] - v[:, 0], axis=1).mean() ** 3
    inv = np.linalg.inv(np.where(ok[:, None, None], edges, np.eye(3)))
    b = np.einsum("tij,ntj->nti", inv, x[:, None, :] - v[None, :, 0])  # (N, T, 3)
    bary = np.concatenate([1.0 - b.sum(-1, keepdims=True), b], axis=-1)
    bary[:, ~ok] = -np.inf
    return bary


def _locate_reference(deformed, tets, x, tol):
    """Containing tet (N,), its barycentrics (N, 4) and inside (N,) by brute force."""
    bary = _barycentrics_all(deformed, tets, x)
    depth = bary.min(-1)  # (N, T)
    best = depth.argmax(1)
    rows = np.arange(len(x))
    return best, bary[rows, best], depth[rows, best] >= -tol


def map_points_reference(deformed_vertices, tets, rest_vertices, x, tol: float = BARY_TOL):
    """Brute-force twin of :meth:`InverseMap.map_points`: every point against every tet (O(N T)).

    returns : x_rest (N, 3) float64 (nan outside), inside (N,) bool
    """
    deformed = check_points("deformed_vertices", deformed_vertices)
    rest = check_points("rest_vertices", rest_vertices)
    tets = check_tets(tets, len(deformed))
    best, bary, inside = _locate_reference(deformed, tets, check_points("x", x), tol)
    x_rest = np.einsum("nk,nkc->nc", bary, rest[tets[best]])
    x_rest[~inside] = np.nan
    return x_rest, inside


def map_directions_reference(deformed_vertices, tets, rest_vertices, x, d, eps: float, tol: float = BARY_TOL):
    """Brute-force twin of :meth:`InverseMap.map_directions`: forward difference, else backward, else
    the containing tet's Jacobian ``R_t D_t^-1 d``; nan outside. Returns (N, 3) float64."""
    deformed = check_points("deformed_vertices", deformed_vertices)
    rest = check_points("rest_vertices", rest_vertices)
    tets = check_tets(tets, len(deformed))
    x = check_points("x", x)
    d = check_points("d", d)
    best, _, inside = _locate_reference(deformed, tets, x, tol)
    x0, _ = map_points_reference(deformed, tets, rest, x, tol)
    xf, inside_f = map_points_reference(deformed, tets, rest, x + eps * d, tol)
    xb, inside_b = map_points_reference(deformed, tets, rest, x - eps * d, tol)
    v, r = deformed[tets[best]], rest[tets[best]]
    edges_def = np.transpose(v[:, 1:] - v[:, :1], (0, 2, 1))
    edges_rest = np.transpose(r[:, 1:] - r[:, :1], (0, 2, 1))
    jac = np.einsum("nij,nj->ni", edges_rest, np.linalg.solve(edges_def, d[..., None])[..., 0])
    diff = np.where(inside_f[:, None], xf - x0, np.where(inside_b[:, None], x0 - xb, jac))
    diff[~inside] = np.nan
    return diff / np.linalg.norm(diff, axis=1, keepdims=True)
