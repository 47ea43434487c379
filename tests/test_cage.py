"""shellsim.cage and ``shellsim cage`` on procedural shells (spheres, a torus, two far-apart spheres)."""

import shutil

import numpy as np
import pytest
import trimesh
from meshes import write_asset_dir

import shellsim.cage as cage_module
from neural.asset import load_asset
from neural.errors import InputError
from shellsim.cage import (
    Cage,
    CageConfig,
    boundary_faces,
    build_cage,
    cage_summary,
    load_cage,
    load_or_build_cage,
    save_cage,
    shell_digest,
    tet_quality,
    tet_volumes,
)
from shellsim.cli import main
from shellsim.embed import interpolate, outside_distance

#: Small, quick cages: a coarse dilation grid, one fTetWild run, any count within a factor 3 of 1000.
QUICK = CageConfig(margin=0.05, target_tets=1000, surface_faces=1000, tolerance=3.0, max_attempts=1)


def enclosed_volume(vertices, faces):
    """Divergence theorem: volume enclosed by an outward-oriented closed surface."""
    v = vertices[faces]
    return np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0


@pytest.fixture(scope="module")
def sphere_asset(tmp_path_factory):
    outer = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    return write_asset_dir(tmp_path_factory.mktemp("assets") / "ball", outer, inner, "ball")


@pytest.fixture(scope="module")
def sphere_cage(sphere_asset):
    """Built through load_or_build_cage, which also writes ball/cage.npz."""
    return load_or_build_cage(load_asset(sphere_asset), QUICK)


def check_cage(cage, outer, inner):
    """Invariants every cage satisfies; returns the boundary surface."""
    volumes = tet_volumes(cage.vertices, cage.tets)
    assert (volumes > 0).all()
    assert tet_quality(cage.vertices, cage.tets).min() > 0.01
    faces = boundary_faces(cage.tets)
    surface = trimesh.Trimesh(cage.vertices, faces, process=False)
    assert surface.is_watertight and surface.is_winding_consistent
    assert volumes.sum() == pytest.approx(enclosed_volume(cage.vertices, faces), rel=1e-9)
    for mesh, tet_index, bary in (
        (outer, cage.outer_tet, cage.outer_bary),
        (inner, cage.inner_tet, cage.inner_bary),
    ):
        assert tet_index.shape == (len(mesh.vertices),) and bary.shape == (len(mesh.vertices), 4)
        assert np.allclose(bary.sum(axis=1), 1.0, rtol=0, atol=1e-12)
        assert np.abs(interpolate(cage.vertices, cage.tets, tet_index, bary) - mesh.vertices).max() < 1e-9
        # the cage contains the shells: their vertices and points all over M+
        assert (bary >= -1e-9).all()
        assert outside_distance(cage.vertices, cage.tets, mesh.vertices).max() == 0.0
    assert outside_distance(cage.vertices, cage.tets, outer.sample(5000, seed=1)).max() == 0.0
    return surface


def test_sphere_cage(sphere_asset, sphere_cage):
    asset = load_asset(sphere_asset)
    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    surface = check_cage(sphere_cage, outer, inner)
    assert surface.euler_number == 2  # one ball: boundary is a sphere
    # the cage is M+ dilated by the margin, up to fTetWild's envelope and the polygonisation
    radius = 1.0 + QUICK.margin * np.linalg.norm(np.ptp(outer.vertices, axis=0))
    assert tet_volumes(sphere_cage.vertices, sphere_cage.tets).sum() == pytest.approx(
        4 / 3 * np.pi * radius**3, rel=0.05
    )
    assert QUICK.target_tets / 3 <= len(sphere_cage.tets) <= QUICK.target_tets * 3
    assert sphere_cage.shell_digest == shell_digest(outer, inner)
    summary = cage_summary(sphere_cage)
    assert summary["outside"] == 0 and summary["max_outside_distance"] == 0.0
    assert summary["tets"] == len(sphere_cage.tets) and summary["min_quality"] > 0.01


def test_affine_map_of_cage_maps_shells(sphere_asset, sphere_cage, rng):
    outer = load_asset(sphere_asset).outer_mesh()
    a, b = rng.normal(size=(3, 3)) + 3 * np.eye(3), rng.normal(size=3)
    moved = interpolate(
        sphere_cage.vertices @ a.T + b, sphere_cage.tets, sphere_cage.outer_tet, sphere_cage.outer_bary
    )
    assert np.abs(moved - (outer.vertices @ a.T + b)).max() < 1e-9


def test_torus_cage_keeps_the_hole():
    outer, inner = trimesh.creation.torus(1.0, 0.35), trimesh.creation.torus(1.0, 0.2)
    cage = build_cage(outer, inner, QUICK)
    assert check_cage(cage, outer, inner).euler_number == 0  # genus 1


def test_far_apart_parts_are_an_input_error():
    ball = trimesh.creation.icosphere(subdivisions=2)
    two = trimesh.util.concatenate([ball, ball.copy().apply_translation([4.0, 0, 0])])
    with pytest.raises(
        InputError, match=r"twins\.ply: the cage falls apart into 2 separate solids.*--margin"
    ):
        build_cage(two, two, QUICK, what="twins.ply")


def test_save_load_round_trip(sphere_cage, tmp_path):
    path = tmp_path / "sub" / "cage.npz"
    save_cage(path, sphere_cage)
    loaded = load_cage(path)
    for key in ("vertices", "tets", "outer_tet", "outer_bary", "inner_tet", "inner_bary"):
        assert np.array_equal(getattr(loaded, key), getattr(sphere_cage, key)), key
        assert getattr(loaded, key).dtype == getattr(sphere_cage, key).dtype
    assert loaded.shell_digest == sphere_cage.shell_digest and loaded.config == sphere_cage.config
    assert [p.name for p in path.parent.iterdir()] == ["cage.npz"]  # no temporary left behind


def corrupt(cage, **changes):
    fields = {k: getattr(cage, k) for k in Cage.__dataclass_fields__}
    fields.update(changes)
    return Cage(**fields)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda path, cage: path.write_bytes(b"not a zip file"), r"not a shellsim cage file \(not an \.npz"),
        (lambda path, cage: np.savez(path, vertices=cage.vertices), "missing"),
        (lambda path, cage: save_cage(path, corrupt(cage, tets=cage.tets[:, [1, 0, 2, 3]])), "inverted"),
        (lambda path, cage: save_cage(path, corrupt(cage, tets=cage.tets + 10**6)), "outside"),
        (lambda path, cage: save_cage(path, corrupt(cage, outer_bary=cage.outer_bary * 2)), "sum to 1"),
        (lambda path, cage: save_cage(path, corrupt(cage, inner_tet=cage.inner_tet[:-1])), "inner_tet"),
    ],
)
def test_corrupt_cage_file_is_input_error(sphere_cage, tmp_path, damage, message):
    path = tmp_path / "cage.npz"
    damage(path, sphere_cage)
    with pytest.raises(InputError, match=message) as err:
        load_cage(path)
    assert str(err.value).startswith(str(path))


def test_load_or_build_reuses_and_rebuilds(sphere_asset, sphere_cage, tmp_path, monkeypatch):
    root = tmp_path / "ball"
    shutil.copytree(sphere_asset, root)
    asset = load_asset(root)
    calls = []
    monkeypatch.setattr(
        cage_module, "build_cage", lambda outer, inner, config, what: calls.append(config) or sphere_cage
    )
    assert np.array_equal(load_or_build_cage(asset, QUICK).tets, sphere_cage.tets)
    assert np.array_equal(load_or_build_cage(asset).tets, sphere_cage.tets)  # any settings will do
    assert calls == []
    load_or_build_cage(asset, QUICK, rebuild=True)
    load_or_build_cage(asset, CageConfig(target_tets=3000))  # other settings
    assert calls == [QUICK, CageConfig(target_tets=3000)]
    trimesh.creation.icosphere(subdivisions=3, radius=1.1).export(root / "shell_outer.ply")
    load_or_build_cage(asset)  # the shells changed
    assert len(calls) == 3
    (root / "cage.npz").write_bytes(b"garbage")
    load_or_build_cage(asset, QUICK)  # unreadable cache: rebuilt, not an error
    assert len(calls) == 4


def test_cli_summary(sphere_asset, sphere_cage, tmp_path, capsys):
    root = tmp_path / "ball"
    shutil.copytree(sphere_asset, root)
    assert main(["cage", "--asset", str(root)]) == 0
    out = capsys.readouterr().out
    assert f"{len(sphere_cage.vertices)} vertices, {len(sphere_cage.tets)} tets" in out
    assert "0 outside the cage" in out


def test_cli_passes_settings(sphere_asset, sphere_cage, tmp_path, capsys, monkeypatch):
    root = tmp_path / "ball"
    shutil.copytree(sphere_asset, root)
    calls = []
    monkeypatch.setattr(
        cage_module, "build_cage", lambda outer, inner, config, what: calls.append(config) or sphere_cage
    )
    assert main(["cage", "--asset", str(root), "--tets", "1500", "--margin", "0.03"]) == 0
    assert calls == [CageConfig(target_tets=1500, margin=0.03)]
    assert main(["cage", "--asset", str(root), "--rebuild"]) == 0
    assert calls[1:] == [None]
    assert "outside the cage" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, message",
    [
        (["--asset", "{missing}"], "no such directory"),
        (["--asset", "{asset}", "--margin", "-1"], "--margin: margin must be a positive number"),
        (["--asset", "{asset}", "--tets", "0"], "--tets: target_tets must be at least 10"),
    ],
)
def test_cli_errors_are_one_line(sphere_asset, tmp_path, capsys, args, message):
    args = [a.format(missing=tmp_path / "nope", asset=sphere_asset) for a in args]
    assert main(["cage", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("shellsim: error: ") and message in err and err.count("\n") == 1
