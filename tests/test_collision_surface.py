"""shellsim.tetcage.collision: the collision surface of an asset whose field is the exact SDF of a sphere lies
on that sphere (within half a grid cell and the decimation's chord error), is closed and outward oriented
with the ball's volume; its embedding weights reproduce it exactly and carry affine maps of the cage
exactly; a real field is read in the asset's frame; a mesh body in a cage of its own tets keeps its
vertices; a decimation that breaks the surface is retried with more faces, and an open, self-intersecting
or uncaged mesh refused; the cache is read, and rebuilt when corrupt."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid, save_embedded_cage, write_asset_dir
from scenes import SphereField

from neural.asset import load_asset
from neural.errors import InputError
from shellsim.tetcage.collision import surface_of_asset, surface_of_mesh
from shellsim.tetcage.store import load_or_build_cage

CENTER = np.array([0.1, -0.2, 0.3])
RADIUS = 0.5
HALF = 0.7  # the cage is the cube CENTER +- HALF
RESOLUTION = 96  # grid cells along the cage's bounding-box diagonal
MAX_FACES = 800


@pytest.fixture
def ball(tmp_path, monkeypatch):
    """(asset, cage) : an asset whose field is the exact SDF of the sphere (CENTER, RADIUS) (``load_field``
    returns a :class:`SphereField`), its cage the cube of 2^3 Kuhn cells around it; a cache of its own."""
    monkeypatch.setenv("SHELLSIM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(
        "neural.asset.load_field", lambda asset, device="cpu": SphereField(RADIUS, center=CENTER)
    )
    outer = trimesh.creation.icosphere(subdivisions=2, radius=RADIUS + 0.1).apply_translation(CENTER)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=RADIUS - 0.1).apply_translation(CENTER)
    asset = load_asset(write_asset_dir(tmp_path / "ball", outer, inner, "ball", center=tuple(CENTER)))
    save_embedded_cage(asset, *kuhn_grid(CENTER - HALF, CENTER + HALF, 2)[:2])
    return asset, load_or_build_cage(asset)


def max_chord_error(surface) -> float:
    """How far inside a sphere of RADIUS the midpoint of the longest edge of ``surface`` lies when its ends
    lie on it: the sagitta ``R - sqrt(R^2 - (e/2)^2)``."""
    f = surface.faces
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    longest = np.linalg.norm(np.diff(surface.vertices[edges], axis=1), axis=2).max()
    return RADIUS - math.sqrt(RADIUS**2 - (longest / 2) ** 2)


def test_the_surface_of_a_sphere_field_is_that_sphere_closed_and_outward(ball):
    asset, cage = ball
    surface = surface_of_asset(asset, cage, max_faces=MAX_FACES, resolution=RESOLUTION)
    cell = np.linalg.norm(np.full(3, 2 * HALF)) / RESOLUTION
    assert MAX_FACES / 2 < len(surface.faces) <= MAX_FACES
    radius = np.linalg.norm(surface.vertices - CENTER, axis=1)
    assert np.abs(radius - RADIUS).max() < cell / 2 + max_chord_error(surface)
    mesh = trimesh.Trimesh(surface.vertices, surface.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(4 / 3 * math.pi * RADIUS**3, rel=0.03)  # positive: outward
    assert surface.tet.shape == (len(surface.vertices),) and surface.bary.shape == (len(surface.vertices), 4)
    assert surface.bary.min() >= -1e-9  # every vertex in or on its tet


def test_weights_reproduce_the_surface_and_carry_affine_maps_of_the_cage(ball):
    asset, cage = ball
    surface = surface_of_asset(asset, cage, max_faces=MAX_FACES, resolution=RESOLUTION)
    w = surface.weights(len(cage.vertices))
    assert w.shape == (len(surface.vertices), len(cage.vertices))
    np.testing.assert_allclose(w @ cage.vertices, surface.vertices, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(w.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-12)
    a = np.array([[1.2, 0.3, -0.1], [0.0, 0.8, 0.2], [0.1, -0.2, 1.1]])  # stretch, shear and turn
    b = np.array([0.5, -1.0, 2.0])
    np.testing.assert_allclose(w @ (cage.vertices @ a.T + b), surface.vertices @ a.T + b, rtol=0, atol=1e-9)


def test_a_trained_field_is_read_in_the_asset_frame(tmp_path, monkeypatch):
    """A real (untrained, sphere-initialised) ``ShellField`` about CENTER through ``load_field``: every vertex
    of the undecimated level set lies on the field's zero set, to a small fraction of a cell."""
    import torch

    from neural.field import FieldConfig, HashGridConfig, ShellField

    monkeypatch.setenv("SHELLSIM_CACHE", str(tmp_path / "cache"))
    torch.manual_seed(0)
    hashgrid = HashGridConfig(n_levels=2, log2_table_size=8, max_resolution=16)
    field = ShellField(FieldConfig(hashgrid=hashgrid), center=tuple(CENTER))
    r = field.config.init_radius
    outer = trimesh.creation.icosphere(subdivisions=2, radius=r + 0.1).apply_translation(CENTER)
    root = write_asset_dir(tmp_path / "ball", outer, outer, "ball", center=tuple(CENTER), field=field)
    asset = load_asset(root)
    cage = save_embedded_cage(asset, *kuhn_grid(CENTER - r - 0.2, CENTER + r + 0.2, 2)[:2])
    surface = surface_of_asset(asset, cage, max_faces=10**6, resolution=64)
    cell = np.linalg.norm(np.full(3, 2 * r + 0.4)) / 64
    with torch.no_grad():
        sdf = field.geometry(torch.as_tensor(surface.vertices, dtype=torch.float32)).sdf.numpy()
    assert np.abs(sdf).max() < 0.05 * cell
    assert np.linalg.norm(surface.vertices - CENTER, axis=1).max() < r + cell


def test_a_mesh_body_in_a_cage_of_its_own_tets_keeps_its_vertices():
    lo, hi = np.array([-0.5, 0.0, 1.0]), np.array([0.5, 2.0, 1.5])
    box = trimesh.creation.box(bounds=[lo, hi])
    verts, tets, _ = kuhn_grid(lo, hi, (2, 3, 1))
    surface = surface_of_mesh(box.vertices, box.faces, verts, tets)
    np.testing.assert_allclose(surface.vertices, box.vertices, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(surface.faces, box.faces)
    np.testing.assert_allclose(surface.weights(len(verts)) @ verts, box.vertices, rtol=0, atol=1e-12)
    turned = surface_of_mesh(box.vertices, box.faces[:, ::-1], verts, tets)  # inside out: turned over
    np.testing.assert_array_equal(turned.faces, box.faces)


def test_a_finer_mesh_body_is_decimated_and_stays_closed():
    ball = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)  # 1280 faces
    verts, tets, _ = kuhn_grid(-HALF, HALF, 2)
    surface = surface_of_mesh(ball.vertices, ball.faces, verts, tets, max_faces=300)
    assert len(surface.faces) <= 300
    mesh = trimesh.Trimesh(surface.vertices, surface.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(ball.volume, rel=0.05)


def test_a_decimation_that_breaks_the_surface_is_retried_with_more_faces(monkeypatch):
    import igl

    ball = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)
    verts, tets, _ = kuhn_grid(-HALF, HALF, 2)
    qslim, targets = igl.qslim, []

    def first_one_flipped(v, f, max_m, block_intersections):
        targets.append(max_m)
        out = qslim(v, f, max_m, block_intersections)
        if len(targets) == 1:
            out[1][0] = out[1][0, ::-1]  # one face turned over: not consistently oriented
        return out

    monkeypatch.setattr(igl, "qslim", first_one_flipped)
    surface = surface_of_mesh(ball.vertices, ball.faces, verts, tets, max_faces=300)
    assert targets == [300, 450] and len(surface.faces) <= 450
    assert trimesh.Trimesh(surface.vertices, surface.faces, process=False).is_winding_consistent


def test_an_open_self_intersecting_or_uncaged_mesh_is_refused():
    box = trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    verts, tets, _ = kuhn_grid(0.0, 1.0, 1)
    with pytest.raises(InputError, match="brick: a collision surface needs a closed"):
        surface_of_mesh(box.vertices, box.faces[1:], verts, tets, what="brick")
    with pytest.raises(InputError, match="brick: the surface reaches .* outside its cage"):
        surface_of_mesh(box.vertices + [0.0, 0.0, 0.1], box.faces, verts, tets, what="brick")
    small = trimesh.creation.box(bounds=[[0.2, 0.2, 0.2], [0.6, 0.6, 0.6]])
    two = trimesh.util.concatenate([small, small.copy().apply_translation([0.2, 0.2, 0.2])])
    with pytest.raises(InputError, match=r"brick: .* \(the last try, 24 faces, is self-intersecting\)"):
        surface_of_mesh(two.vertices, two.faces, verts, tets, what="brick")


def test_the_cache_is_read_and_a_corrupt_one_rebuilt(ball, tmp_path, monkeypatch):
    asset, cage = ball
    first = surface_of_asset(asset, cage, max_faces=MAX_FACES, resolution=RESOLUTION)
    (cached,) = (tmp_path / "cache" / "collision").glob("*.npz")

    def refuse(asset, device="cpu"):
        raise AssertionError("the field was loaded: the cache was not read")

    with monkeypatch.context() as patch:
        patch.setattr("neural.asset.load_field", refuse)
        again = surface_of_asset(asset, cage, max_faces=MAX_FACES, resolution=RESOLUTION)
        for name in ("vertices", "faces", "tet", "bary"):
            np.testing.assert_array_equal(getattr(again, name), getattr(first, name))
        with pytest.raises(AssertionError, match="field was loaded"):  # other settings: another entry
            surface_of_asset(asset, cage, max_faces=MAX_FACES + 1, resolution=RESOLUTION)
    cached.write_bytes(cached.read_bytes()[:100])  # torn
    rebuilt = surface_of_asset(asset, cage, max_faces=MAX_FACES, resolution=RESOLUTION)
    np.testing.assert_array_equal(rebuilt.vertices, first.vertices)
    with monkeypatch.context() as patch:
        patch.setattr("neural.asset.load_field", refuse)
        surface_of_asset(asset, cage, max_faces=MAX_FACES, resolution=RESOLUTION)  # cached again


def test_the_surface_of_a_cut_asset_is_that_of_its_region(ball):
    """A body cut out of a capture collides as the field inside its cut: the half ball above a plane."""
    from neural.shell.cutout import Cut

    asset, cage = ball
    cut = Cut(CENTER - HALF, CENTER + HALF, point=CENTER, normal=[0.0, 0.0, 1.0])
    asset.meta["cut"] = cut.to_dict()
    surface = surface_of_asset(asset, cage, max_faces=MAX_FACES, resolution=RESOLUTION)
    cell = np.linalg.norm(np.full(3, 2 * HALF)) / RESOLUTION
    assert surface.vertices[:, 2].min() > CENTER[2] - cell
    mesh = trimesh.Trimesh(surface.vertices, surface.faces, process=False)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(2 / 3 * math.pi * RADIUS**3, rel=0.04)
