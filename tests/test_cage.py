"""shellsim.tetcage and ``shellsim cage`` on procedural shells (spheres, a torus, two far-apart spheres)."""

import shutil

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid, write_asset_dir

import shellsim.tetcage.build as cage_build
import shellsim.tetcage.store as cage_store
from neural.asset import load_asset
from neural.errors import InputError
from shellsim.cli.main import main
from shellsim.motion.format import Motion
from shellsim.tetcage.build import Cage, CageConfig, build_cage, shell_digest
from shellsim.tetcage.embed import interpolate, outside_distance
from shellsim.tetcage.geometry import boundary_faces, tet_quality, tet_volumes
from shellsim.tetcage.store import (
    cache_dir,
    cached_cage_path,
    cage_for_motion,
    cage_summary,
    load_cage,
    load_or_build_cage,
    save_cage,
)

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
        InputError, match=r"twins\.ply: the cage falls apart into 2 separate solids.*a larger margin"
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
    """The asset's own cage is reused whatever its settings; other settings and rebuilds go to the cache
    (the own cage, which motions were made with, is never replaced by another) and are reused from there;
    new shells or an unreadable own cage are rebuilt in place."""
    monkeypatch.setenv("SHELLSIM_CACHE", str(tmp_path / "cache"))
    root = tmp_path / "ball"
    shutil.copytree(sphere_asset, root)
    asset = load_asset(root)
    calls = []
    monkeypatch.setattr(
        cage_build, "build_cage", lambda outer, inner, config, what: calls.append(config) or sphere_cage
    )
    own = (root / "cage.npz").read_bytes()
    assert np.array_equal(load_or_build_cage(asset, QUICK).tets, sphere_cage.tets)
    assert np.array_equal(load_or_build_cage(asset).tets, sphere_cage.tets)  # any settings will do
    assert calls == []
    assert load_or_build_cage(asset, QUICK, rebuild=True).path != str(root / "cage.npz")
    other = CageConfig(target_tets=3000)
    load_or_build_cage(asset, other)
    assert calls == [QUICK, other]
    assert (root / "cage.npz").read_bytes() == own
    digest = shell_digest(asset.outer_mesh(), asset.inner_mesh())
    assert cached_cage_path(digest, other).is_file() and cached_cage_path(digest, QUICK).is_file()
    assert len(set(cached_cage_path(digest, c) for c in (QUICK, other, CageConfig()))) == 3
    load_or_build_cage(asset, other)  # from the cache now
    assert len(calls) == 2
    trimesh.creation.icosphere(subdivisions=3, radius=1.1).export(root / "shell_outer.ply")
    assert load_or_build_cage(asset).path == str(root / "cage.npz")  # the shells changed: rebuilt in place
    assert len(calls) == 3
    (root / "cage.npz").write_bytes(b"garbage")
    load_or_build_cage(asset, QUICK)  # unreadable own cage: rebuilt, not an error
    assert len(calls) == 4


def test_shipped_assets_are_never_written_to(sphere_asset, sphere_cage, tmp_path, monkeypatch, capsys):
    """An asset found by name among the shipped ones: its cages go to the cache, extract and eval --record
    refuse it in one line, and a motion made with a cached cage finds that cage again."""
    monkeypatch.setenv("SHELLSIM_CACHE", str(tmp_path / "cache"))
    shipped = tmp_path / "shipped"
    shutil.copytree(sphere_asset, shipped / "ball")
    (shipped / "ball" / "cage.npz").unlink(missing_ok=True)
    monkeypatch.setenv("SHELLSIM_ASSETS", str(shipped))
    before = sorted(p.name for p in (shipped / "ball").iterdir())
    monkeypatch.setattr(cage_build, "build_cage", lambda outer, inner, config, what: sphere_cage)
    asset = load_asset("ball")
    assert asset.shipped and not load_asset(shipped / "ball").shipped
    cage = load_or_build_cage(asset, QUICK)
    assert sorted(p.name for p in (shipped / "ball").iterdir()) == before
    assert len(list((tmp_path / "cache" / "cages").glob("*.npz"))) == 1
    motion = Motion(cage.vertices, cage.tets, cage.vertices[None].astype(np.float32), np.zeros(1))
    assert np.array_equal(cage_for_motion(asset, motion, "m.npz").vertices, cage.vertices)
    moved = Motion(cage.vertices * 1.1, cage.tets, motion.positions, motion.times)
    with pytest.raises(InputError, match="m.npz: the motion's rest cage differs"):
        cage_for_motion(asset, moved, "m.npz")
    for argv in (["extract", "--asset", "ball"], ["eval", "--asset", "ball", "--data", ".", "--record"]):
        assert main(argv) == 2
        assert "'ball' is shipped with shellsim and is never modified" in capsys.readouterr().err
    assert sorted(p.name for p in (shipped / "ball").iterdir()) == before


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
        cage_build, "build_cage", lambda outer, inner, config, what: calls.append(config) or sphere_cage
    )
    assert main(["cage", "--asset", str(root), "--tets", "1500", "--margin", "0.03"]) == 0
    assert calls == [CageConfig(target_tets=1500, margin=0.03)]
    assert main(["cage", "--asset", str(root), "--rebuild"]) == 0
    assert calls[1:] == [QUICK]  # the settings of the asset's own cage
    assert "outside the cage" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, message",
    [
        (["--asset", "{missing}"], "no such directory"),
        (["--asset", "{asset}", "--margin", "-1"], "--margin: margin must be a number >= 0"),
        (["--asset", "{asset}", "--tets", "0"], "--tets: target_tets must be at least 10"),
    ],
)
def test_cli_errors_are_one_line(sphere_asset, tmp_path, capsys, args, message):
    args = [a.format(missing=tmp_path / "nope", asset=sphere_asset) for a in args]
    assert main(["cage", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("shellsim: error: ") and message in err and err.count("\n") == 1


def test_rebuilds_are_identical_and_leave_the_cwd_clean(tmp_path, monkeypatch):
    """fTetWild shuffles its input with std::random_device and keeps a static generator between runs: two
    builds in one process differed (and one in three LEGO rebuilds had a stray tet). Seeded, one thread, a
    process per run: the same cage twice, and its __tracked_surface.stl stays out of the cwd."""
    monkeypatch.chdir(tmp_path)
    outer = trimesh.creation.icosphere(subdivisions=2)
    first, second = (build_cage(outer, outer, QUICK) for _ in range(2))
    for key in ("vertices", "tets", "outer_tet", "outer_bary"):
        np.testing.assert_array_equal(getattr(first, key), getattr(second, key), err_msg=key)
    assert list(tmp_path.iterdir()) == []


def test_stray_parts_without_shell_vertices_are_dropped(monkeypatch, caplog):
    """A tet mesh with a stray tet far from the shell (as fTetWild sometimes leaves one): the tet is dropped
    with a log line, and the embedding still reproduces the shells."""
    outer = trimesh.creation.icosphere(subdivisions=2)
    inner = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    grid_v, grid_t, _ = kuhn_grid(-1.5, 1.5, 3)
    stray_v = np.array([[5.0, 0, 0], [6.0, 0, 0], [5.0, 1.0, 0], [5.0, 0, 1.0]])
    vertices = np.concatenate([stray_v, grid_v])  # the stray first: every index moves when it goes
    tets = np.concatenate([[[0, 1, 2, 3]], grid_t + 4])
    monkeypatch.setattr(cage_build, "tetrahedralize", lambda *args: (vertices, tets, True))
    with caplog.at_level("INFO", logger="shellsim.tetcage.build"):
        cage = build_cage(outer, inner, QUICK)
    assert "dropped 1 stray part(s) of the tet mesh that hold no shell vertex (1 tets)" in caplog.text
    np.testing.assert_array_equal(cage.vertices, grid_v)
    np.testing.assert_array_equal(cage.tets, grid_t)
    check_cage(cage, outer, inner)


def test_an_undilated_mesh_in_pieces_is_not_told_to_raise_the_margin():
    ball = trimesh.creation.icosphere(subdivisions=2)
    two = trimesh.util.concatenate([ball, ball.copy().apply_translation([4.0, 0, 0])])
    undilated = CageConfig(margin=0.0, target_tets=1000, tolerance=3.0, max_attempts=1)
    with pytest.raises(InputError, match="one connected solid") as err:
        build_cage(two, two, undilated, what="twins.ply")
    assert "--margin" not in str(err.value)


@pytest.mark.parametrize("command", ["simulate", "wind"])
def test_commands_that_build_cages_take_margin(sphere_asset, monkeypatch, tmp_path, command):
    """The advice of a cage in pieces is 'Raise --margin': every command that builds a cage has one."""
    configs = []

    def record(asset, config=None, rebuild=False):
        configs.append(config)
        raise InputError("recorded")

    monkeypatch.setattr(cage_store, "load_or_build_cage", record)
    out = str(tmp_path / "m.npz")
    assert main([command, "--asset", str(sphere_asset), "--margin", "0.07", "--out", out]) == 2
    assert configs == [CageConfig(margin=0.07)]


def test_shipped_lego_cage_is_loaded_not_built(monkeypatch):
    """The shipped asset ships its cage (a few MB at most): the README's main command never runs fTetWild."""
    asset = load_asset("lego")
    assert asset.cage_path.is_file() and asset.cage_path.stat().st_size < 3e6

    def no_build(*args, **kwargs):
        raise AssertionError("the shipped cage was rebuilt")

    monkeypatch.setattr(cage_build, "build_cage", no_build)
    cage = load_or_build_cage(asset)
    assert cage.config == CageConfig()
    summary = cage_summary(cage)
    assert summary["outside"] == 0 and summary["outer_vertices"] == len(asset.outer_mesh().vertices)


@pytest.mark.slow
def test_shipped_lego_cage_is_what_the_builder_makes():
    """Rebuilding the shipped cage with its settings gives it again, bit for bit (about a minute)."""
    asset = load_asset("lego")
    shipped = load_cage(asset.cage_path, (asset.outer_mesh(), asset.inner_mesh()))
    rebuilt = build_cage(asset.outer_mesh(), asset.inner_mesh(), shipped.config)
    for key in ("vertices", "tets", "outer_tet", "outer_bary", "inner_tet", "inner_bary"):
        np.testing.assert_array_equal(getattr(rebuilt, key), getattr(shipped, key), err_msg=key)


def test_cache_directory_follows_the_environment(tmp_path, monkeypatch):
    """$SHELLSIM_CACHE (what --cache-dir sets), else $XDG_CACHE_HOME/shellsim, else ~/.cache/shellsim."""
    monkeypatch.delenv("SHELLSIM_CACHE")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    assert cache_dir() == tmp_path / "home" / ".cache" / "shellsim"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "shellsim"
    monkeypatch.setenv("SHELLSIM_CACHE", str(tmp_path / "mine"))
    assert cache_dir() == tmp_path / "mine"
    assert main(["--cache-dir", str(tmp_path / "flag"), "cage", "--asset", str(tmp_path / "none")]) == 2
    assert cache_dir() == tmp_path / "flag"
