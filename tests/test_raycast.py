"""Ray casting against the shells (neural.render.raycast): the Embree and Warp backends against each other,
against a brute-force float64 ray-triangle test of every face, and against closed forms (a box: the slab
method, exact; a sphere: the chord, up to the icosphere's facets)."""

import numpy as np
import pytest
import trimesh

from neural.render.raycast import EmbreeCaster, ShellCaster, WarpCaster, ray_triangle_hits

BACKENDS = {
    "embree": EmbreeCaster,
    "warp": lambda outer, inner: WarpCaster(outer, inner, device="cpu", cpu_threads=2),
}


def icospheres():
    return (
        trimesh.creation.icosphere(subdivisions=3, radius=1.0),
        trimesh.creation.icosphere(subdivisions=2, radius=0.6),
    )


def tori():
    def torus(minor):
        return trimesh.creation.torus(
            major_radius=1.0, minor_radius=minor, major_sections=40, minor_sections=20
        )

    return torus(0.45), torus(0.2)


def rays(rng, n, distance, spread):
    """``n`` rays from a sphere of radius ``distance`` towards random points of a box of half-size
    ``spread``, with directions of random lengths (distances come back in units of them)."""
    origins = rng.normal(size=(n, 3))
    origins *= distance / np.linalg.norm(origins, axis=1, keepdims=True)
    dirs = rng.uniform(-1, 1, size=(n, 3)) * np.asarray(spread) - origins
    dirs *= rng.uniform(0.5, 2.0, size=(n, 1)) / np.linalg.norm(dirs, axis=1, keepdims=True)
    return origins, dirs


def brute_force(mesh, origins, dirs):
    """Per ray: (t (K,) in units of its dir, face (K,), entering (K,)) of every hit, in order."""
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    normals = np.asarray(mesh.face_normals)
    out = []
    for o, d in zip(origins, dirs, strict=True):
        norm = np.linalg.norm(d)
        t, faces = ray_triangle_hits(triangles, o, d / norm)
        out.append((t / norm, faces, normals[faces] @ d < 0))
    return out


def clean(truth, min_gap=1e-3):
    """(R,) bool: rays whose hits are all at least ``min_gap`` apart (no edge, vertex or grazing double hit
    that float32 casting may merge or split)."""
    return np.array([np.all(np.diff(np.r_[0.0, t]) > min_gap) for t, _, _ in truth])


@pytest.mark.parametrize("shells", [icospheres, tori])
@pytest.mark.parametrize("backend", BACKENDS)
def test_hits_match_brute_force(rng, shells, backend):
    outer, inner = shells()
    caster = BACKENDS[backend](outer, inner)
    origins, dirs = rays(rng, 400, 3.0, (1.4, 1.4, 0.6))
    truth = {"outer": brute_force(outer, origins, dirs), "inner": brute_force(inner, origins, dirs)}
    ok = clean(truth["outer"]) & clean(truth["inner"])
    assert ok.mean() > 0.95

    t, face = caster.first_hit("inner", origins, dirs)
    first_t = np.array([h[0][0] if len(h[0]) else np.inf for h in truth["inner"]])
    first_face = np.array([h[1][0] if len(h[1]) else -1 for h in truth["inner"]])
    assert np.isfinite(first_t[ok]).mean() > 0.2 and np.isinf(first_t[ok]).mean() > 0.1
    np.testing.assert_array_equal(face[ok], first_face[ok])
    np.testing.assert_allclose(t[ok], first_t[ok], atol=1e-5)

    ray_idx, t, entering = caster.all_hits("outer", origins, dirs, max_hits=16)
    true_rays = np.concatenate([np.full(len(h[0]), i) for i, h in enumerate(truth["outer"])])
    true_t, _, true_entering = (np.concatenate(x) for x in zip(*truth["outer"], strict=True))
    keep, true_keep = ok[ray_idx], ok[true_rays]
    np.testing.assert_array_equal(ray_idx[keep], true_rays[true_keep])
    np.testing.assert_allclose(t[keep], true_t[true_keep], atol=1e-5)
    np.testing.assert_array_equal(entering[keep], true_entering[true_keep])
    if shells is tori:
        assert np.bincount(true_rays).max() == 4  # some rays cross both sides of the ring


def test_backends_agree_after_a_refit(rng):
    """Warp meshes built on the rest torus and refitted to a sheared one cast like Embree built on the
    sheared one, and the cap ``max_hits`` and ``t_stop`` cut both alike."""
    outer, inner = tori()
    shear = np.array([[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.2, 0.0, 0.8]])
    moved = [trimesh.Trimesh(m.vertices @ shear.T, m.faces, process=False) for m in (outer, inner)]
    warp = WarpCaster(outer, inner, device="cpu", cpu_threads=2)
    warp.refit(moved[0].vertices, moved[1].vertices)
    embree = EmbreeCaster(*moved)
    origins, dirs = rays(rng, 2000, 3.0, (1.4, 1.4, 0.6))
    ok = clean(brute_force(moved[0], origins, dirs)) & clean(brute_force(moved[1], origins, dirs))
    t_e, face_e = embree.first_hit("inner", origins, dirs)
    t_w, face_w = warp.first_hit("inner", origins, dirs)
    np.testing.assert_array_equal(face_w[ok], face_e[ok])
    np.testing.assert_allclose(t_w[ok], t_e[ok], atol=1e-5, rtol=1e-5)
    for max_hits, t_stop in ((16, None), (3, None), (16, t_e)):
        e = embree.all_hits("outer", origins, dirs, max_hits, t_stop=t_stop)
        w = warp.all_hits("outer", origins, dirs, max_hits, t_stop=t_stop)
        e_ok, w_ok = ok[e[0]], ok[w[0]]
        np.testing.assert_array_equal(w[0][w_ok], e[0][e_ok])
        np.testing.assert_allclose(w[1][w_ok], e[1][e_ok], atol=1e-5, rtol=1e-5)  # float32 casts
        np.testing.assert_array_equal(w[2][w_ok], e[2][e_ok])


def test_blended_refit_moves_the_shells_like_a_refit_to_the_blends(rng):
    """Shell vertices as weighted sums of four control points each: refit_blended gives the Warp meshes the
    points (and so the hits) that refit gives them with the sums made in numpy; bad blends are refused."""
    outer, inner = tori()
    control = rng.normal(size=(200, 3)) * 0.05 + rng.uniform(-1.5, 1.5, size=(200, 3))
    blends, moved = {}, {}
    for which, mesh in (("outer", outer), ("inner", inner)):
        corners = rng.integers(0, len(control), size=(len(mesh.vertices), 4))
        weights = rng.dirichlet(np.ones(4), size=len(mesh.vertices))
        blends[which] = corners, weights
        moved[which] = sum(weights[:, k, None] * control[corners[:, k]] for k in range(4))
    blended = WarpCaster(outer, inner, device="cpu", cpu_threads=2)
    with pytest.raises(ValueError, match="no blend"):
        blended.refit_blended(control)
    blended.set_blend(**blends)
    blended.refit_blended(control)
    plain = WarpCaster(outer, inner, device="cpu", cpu_threads=2)
    plain.refit(moved["outer"], moved["inner"])
    for which in blends:
        a, b = blended._scenes[which].points.numpy(), plain._scenes[which].points.numpy()
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    origins, dirs = rays(rng, 500, 4.0, (1.4, 1.4, 0.6))
    units = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    ours, theirs = blended.band_hits(origins, units, 16), plain.band_hits(origins, units, 16)
    assert len(ours[0]) > 10
    np.testing.assert_array_equal(ours[0], theirs[0])  # the same rays meet the blended shells
    with pytest.raises(ValueError, match="control"):
        blended.refit_blended(control[:10])
    with pytest.raises(ValueError, match="control"):
        blended.refit_blended(np.full_like(control, np.nan))
    with pytest.raises(ValueError, match="outer: expected corners and weights"):
        blended.set_blend(outer=(blends["outer"][0][:-1], blends["outer"][1]), inner=blends["inner"])
    with pytest.raises(ValueError, match="inner: corners must be >= 0"):
        blended.set_blend(outer=blends["outer"], inner=(-blends["inner"][0] - 1, blends["inner"][1]))


def test_warp_peels_every_ray_in_one_kernel_like_the_shared_rounds(rng):
    """WarpCaster's one-launch depth peeling finds the hits that the shared round-by-round loop finds with the
    same casts, also for rays through a torus's vertices and edges (repeated faces, stepping off them) and
    under a cap and a stop distance."""
    outer, inner = tori()
    caster = WarpCaster(outer, inner, device="cpu", cpu_threads=2)
    origins, dirs = rays(rng, 1500, 3.0, (1.4, 1.4, 0.6))
    corners = np.asarray(outer.vertices)[rng.choice(len(outer.vertices), 300)]
    edges = np.asarray(outer.vertices)[outer.edges_unique[rng.choice(len(outer.edges_unique), 300)]].mean(1)
    targets = np.concatenate([corners, edges])
    starts = targets + rng.normal(size=targets.shape) * 2.0
    origins, dirs = np.concatenate([origins, starts]), np.concatenate([dirs, targets - starts])
    units = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    stop = np.where(rng.uniform(size=len(units)) < 0.5, rng.uniform(1.0, 4.0, len(units)), np.inf)
    scene = caster._scene("outer")
    for max_hits in (16, 3):
        ours = caster._peel(scene, origins, units, stop, max_hits)
        rounds = ShellCaster._peel(caster, scene, origins, units, stop, max_hits)
        np.testing.assert_array_equal(ours[0], rounds[0])
        np.testing.assert_array_equal(ours[2], rounds[2])
        np.testing.assert_allclose(ours[1], rounds[1], rtol=0, atol=1e-12)
    assert len(ours[0]) > len(units)


def test_warp_band_hits_in_one_kernel_equal_the_generic_casts(rng):
    """WarpCaster's one-launch casts of Procedure 3 (first M+ hit, first M- hit, peeling up to it) equal the
    generic path's separate casts, on a sheared refit and for rays through vertices and edges."""
    outer, inner = tori()
    caster = WarpCaster(outer, inner, device="cpu", cpu_threads=2)
    shear = np.array([[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.2, 0.0, 0.8]])
    caster.refit(outer.vertices @ shear.T, inner.vertices @ shear.T)
    origins, dirs = rays(rng, 9000, 3.0, (1.4, 1.4, 0.6))
    vertices = np.asarray(outer.vertices) @ shear.T
    edges = vertices[outer.edges_unique[rng.choice(len(outer.edges_unique), 300)]].mean(1)
    targets = np.concatenate([vertices[rng.choice(len(vertices), 300)], edges])
    starts = targets + rng.normal(size=targets.shape) * 2.0
    origins, dirs = np.concatenate([origins, starts]), np.concatenate([dirs, targets - starts])
    units = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    for max_hits in (16, 2, 1):
        ours = caster.band_hits(origins, units, max_hits)
        generic = ShellCaster.band_hits(caster, origins, units, max_hits)
        for a, b in zip(ours, generic, strict=True):  # the generic path divides by |unit| = 1 +- 1 ulp
            np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)
    meets, t_inner, ray_idx, _, _ = ours
    assert 0.2 < len(meets) / len(units) < 0.9 and np.isfinite(t_inner).mean() > 0.3
    assert np.array_equal(np.unique(ray_idx), meets)


@pytest.mark.parametrize("backend", BACKENDS)
def test_box_hits_match_the_slab_method(rng, backend):
    """A box is exact: its two hits are the slab method's near and far distances."""
    half = np.array([0.5, 0.8, 0.3])
    center = np.array([0.2, -0.1, 0.4])
    box = trimesh.creation.box(extents=2 * half, transform=trimesh.transformations.translation_matrix(center))
    inner = trimesh.creation.box(extents=half, transform=trimesh.transformations.translation_matrix(center))
    caster = BACKENDS[backend](box, inner)
    origins, dirs = rays(rng, 500, 2.5, 1.3 * half)
    origins += center
    with np.errstate(divide="ignore"):
        a, b = (center - half - origins) / dirs, (center + half - origins) / dirs
    near, far = np.minimum(a, b).max(axis=1), np.maximum(a, b).min(axis=1)
    hit = near < far
    assert 0.3 < hit.mean() < 0.9
    t, face = caster.first_hit("outer", origins, dirs)
    np.testing.assert_allclose(t[hit], near[hit], atol=1e-5)
    assert np.isinf(t[~hit]).all() and (face[~hit] == -1).all()
    ray_idx, t, entering = caster.all_hits("outer", origins, dirs, max_hits=8)
    np.testing.assert_array_equal(ray_idx, np.flatnonzero(hit).repeat(2))
    np.testing.assert_allclose(t, np.column_stack([near, far])[hit].ravel(), atol=1e-5)
    np.testing.assert_array_equal(entering, np.tile([True, False], hit.sum()))


@pytest.mark.parametrize("backend", BACKENDS)
def test_sphere_hits_match_the_chord(rng, backend):
    """Rays with impact parameter ``b`` meet a sphere of radius ``r`` at ``t = s -+ sqrt(r^2 - b^2)`` from the
    foot ``s`` of the centre; an icosphere's facets lie up to ~4e-4 inside it (subdivision 5)."""
    r = 1.0
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=r)
    caster = BACKENDS[backend](sphere, trimesh.creation.icosphere(subdivisions=1, radius=0.5))
    origins, dirs = rays(rng, 300, 3.0, (0.4, 0.4, 0.4))  # impact parameters < 0.7 r
    units = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    s = -np.einsum("ij,ij->i", origins, units)
    b2 = np.einsum("ij,ij->i", origins, origins) - s**2
    chord = np.sqrt(r**2 - b2)
    norms = np.linalg.norm(dirs, axis=1)
    t, _ = caster.first_hit("outer", origins, dirs)
    np.testing.assert_allclose(t * norms, s - chord, atol=2e-3)
    ray_idx, t, entering = caster.all_hits("outer", origins, dirs, max_hits=8)
    np.testing.assert_array_equal(ray_idx, np.arange(len(origins)).repeat(2))
    np.testing.assert_allclose(t * norms[ray_idx], np.column_stack([s - chord, s + chord]).ravel(), atol=2e-3)
    np.testing.assert_array_equal(entering, np.tile([True, False], len(origins)))
