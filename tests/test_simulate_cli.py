"""``shellsim simulate``: bad meshes, a small run, pins and --resume (the pin grammar: test_selection)."""

import types

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid

from shellsim.cli.main import main
from shellsim.motion.read import load_motion
from shellsim.world import Placement


def _fail(argv, capsys):
    capsys.readouterr()
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("shellsim: error:") and "\n" not in err and "Traceback" not in err
    return err


def test_bad_meshes_fail_with_one_line(tmp_path, capsys):
    open_mesh = trimesh.creation.box((1, 1, 1))
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) != 0)  # drop a triangle: a hole
    open_mesh.export(tmp_path / "open.ply")
    (tmp_path / "empty.ply").write_bytes(b"")
    (tmp_path / "garbage.obj").write_bytes(b"\x00\xffnot a mesh at all\x13" * 10)
    for name, words in (("open.ply", "not closed"), ("empty.ply", ""), ("garbage.obj", "")):
        err = _fail(["simulate", "--mesh", str(tmp_path / name), "--out", str(tmp_path / "m.npz")], capsys)
        assert name in err and words in err
        assert not (tmp_path / "m.npz").exists()


@pytest.fixture
def closed_mesh(tmp_path, monkeypatch):
    """A closed box mesh file; tetrahedralising is replaced by a 48-tet box (fTetWild is slow and tested
    with the cage)."""
    path = tmp_path / "cube.stl"
    trimesh.creation.box((1, 1, 1)).export(path)
    calls = []

    def build_cage(outer, inner, config=None, what=""):
        calls.append((outer, inner))
        v, t, _ = kuhn_grid(0.0, 1.0, 2)
        return types.SimpleNamespace(vertices=v + outer.bounds[0], tets=t)

    monkeypatch.setattr("shellsim.tetcage.build.build_cage", build_cage)
    return path, calls


def test_run_writes_a_motion_file_and_resume_extends_it(tmp_path, closed_mesh, capsys):
    mesh, calls = closed_mesh
    base = [
        "simulate",
        "--mesh",
        str(mesh),
        "--material",
        "rubber",
        "--fps",
        "30",
        "--substeps",
        "2",
        "--size",
        "0.1",
        "--drop-height",
        "0.01",
        "--velocity",
        "0.1,0,0",
        "--device",
        "cpu",
    ]
    full, part = tmp_path / "full.npz", tmp_path / "part.npz"
    assert main([*base, "--frames", "5", "--out", str(full)]) == 0
    assert main([*base, "--frames", "3", "--out", str(part)]) == 0
    assert calls[0][0] is calls[0][1]  # no inner shell: inner = outer
    motion = load_motion(part)
    assert motion.n_frames == 3 and np.allclose(motion.times, [0, 1 / 30, 2 / 30])
    v0 = motion.rest_vertices
    np.testing.assert_allclose(motion.positions[0], v0, atol=1e-6)
    # a 1-unit cube placed in the world: 0.1 m wide, its lowest point 0.01 m above the ground, centred
    np.testing.assert_allclose(np.ptp(v0, axis=0), 0.1, rtol=1e-12)
    assert v0[:, 2].min() == pytest.approx(0.01) and np.abs(v0.min(0) + v0.max(0))[:2].max() < 1e-12
    assert motion.placement["scale"] == pytest.approx(0.1) and motion.meta["up"] == [0, 0, 1]
    # it falls (and moves along +x) in world metres
    assert motion.positions[-1][:, 2].mean() < v0[:, 2].mean() - 0.01
    assert motion.positions[-1][:, 0].mean() > v0[:, 0].mean()

    assert main([*base, "--frames", "5", "--out", str(part), "--resume"]) == 0
    resumed, straight = load_motion(part), load_motion(full)
    assert resumed.n_frames == 5
    np.testing.assert_array_equal(resumed.positions[:3], motion.positions)
    # resuming continues the same trajectory, up to the Newton tolerance (newton_tol x size per second:
    # 1.7e-3 m/s, ~3e-5 m per substep) and float32 storage; the frames move ~100x more
    np.testing.assert_allclose(resumed.positions, straight.positions, atol=3e-5)
    assert np.abs(np.diff(straight.positions, axis=0)).max() > 100 * 3e-5
    np.testing.assert_allclose(resumed.times, straight.times)

    err = _fail([*base, "--frames", "6", "--out", str(part), "--resume", "--material", "jelly"], capsys)
    assert "material" in err
    err = _fail([*base, "--frames", "6", "--out", str(part), "--pin", "z<-100", "--overwrite"], capsys)
    assert "selects no vertex" in err
    err = _fail(
        [*base, "--frames", "6", "--out", str(part), "--pin", "__import__('os')", "--overwrite"], capsys
    )
    assert "--pin" in err
    assert load_motion(part).n_frames == 5  # failed commands leave the file alone


def test_pinned_vertices_stay_put(tmp_path, closed_mesh):
    mesh, _ = closed_mesh
    out = tmp_path / "pinned.npz"
    argv = [
        "simulate",
        "--mesh",
        str(mesh),
        "--material",
        "foam",
        "--frames",
        "4",
        "--substeps",
        "2",
        "--no-ground",
        "--pin",
        "x<-0.49",
        "--out",
        str(out),
        "--device",
        "cpu",
    ]
    assert main(argv) == 0
    motion = load_motion(out)
    pinned = motion.rest_vertices[:, 0] < -0.49
    assert pinned.sum() == 9
    np.testing.assert_allclose(
        motion.positions[:, pinned], np.broadcast_to(motion.rest_vertices[pinned], (4, 9, 3)), atol=1e-6
    )
    assert (motion.positions[-1][~pinned, 2] < motion.rest_vertices[~pinned, 2]).all()  # the rest sags


def test_an_existing_motion_is_continued_or_refused_never_replaced_silently(tmp_path, closed_mesh, capsys):
    """Run again: same settings continue the file; other settings are refused naming old and new values;
    --overwrite starts anew."""
    mesh, _ = closed_mesh
    out = tmp_path / "m.npz"
    base = ["simulate", "--mesh", str(mesh), "--substeps", "1", "--size", "0.1", "--out", str(out)]
    base += ["--device", "cpu"]
    assert main([*base, "--frames", "3"]) == 0
    first = load_motion(out)
    assert main([*base, "--frames", "5"]) == 0  # no --resume needed
    grown = load_motion(out)
    assert grown.n_frames == 5
    np.testing.assert_array_equal(grown.positions[:3], first.positions)

    for extra, shown in (
        (["--material", "jelly"], "--material: rubber -> jelly"),
        (["--fps", "24"], "--fps: 30 -> 24"),
        (["--velocity", "1,0,0"], "--velocity: 0,0,0 -> 1,0,0"),
        (["--resume", "--no-ground"], "--drop-height (none: --no-ground): 0.1 -> none"),
    ):
        err = _fail([*base, "--frames", "6", *extra], capsys)
        assert shown in err and str(out) in err and "--overwrite" in err, err
        assert "{" not in err and "np." not in err
    assert load_motion(out).n_frames == 5  # refused runs leave the file alone

    assert main([*base, "--frames", "2", "--fps", "24", "--overwrite"]) == 0
    fresh = load_motion(out)
    assert fresh.n_frames == 2 and fresh.settings["fps"] == 24


@pytest.fixture
def rod(tmp_path):
    """A rod asset whose cage is a column of Kuhn tets (no fTetWild run): (asset, cage vertices, tets)."""
    from meshes import save_embedded_cage
    from test_wind import _write_asset, column

    from neural.asset import load_asset

    asset = load_asset(_write_asset(tmp_path / "rod"))
    verts, tets = column(n_xy=2, n_z=6, width=0.4, height=1.1)
    save_embedded_cage(asset, verts - [0.2, 0.2, 0.05], tets)
    return asset, verts, tets


def _wind_args(asset, out):
    return ["wind", "--asset", str(asset.root), "--fps", "10", "--out", str(out), "--anchor", "z<0.1"]


def test_wind_run_again_continues_or_refuses(tmp_path, capsys, rod):
    asset = rod[0]
    out = tmp_path / "wind.npz"
    args = _wind_args(asset, out)
    assert main([*args, "--frames", "3"]) == 0
    assert main([*args, "--frames", "5"]) == 0
    assert load_motion(out).n_frames == 5
    err = _fail([*args, "--frames", "6", "--strength", "0.2", "--seed", "3"], capsys)
    assert "--strength: 0.05 -> 0.2" in err and "--seed: 0 -> 3" in err and "--overwrite" in err
    assert "{" not in err
    assert load_motion(out).n_frames == 5
    assert main([*args, "--frames", "2", "--strength", "0.2", "--overwrite"]) == 0
    assert load_motion(out).n_frames == 2


def test_mesh_simulation_video_shows_the_mesh_moving(tmp_path, closed_mesh):
    """simulate --mesh --video: the motion carries the mesh's surface (frame 0: the mesh file's own
    vertices) and its frames show it moving."""
    from PIL import Image

    mesh, _ = closed_mesh
    out, video = tmp_path / "cube.npz", tmp_path / "cube.mp4"
    argv = [
        "simulate",
        "--mesh",
        str(mesh),
        "--frames",
        "3",
        "--substeps",
        "2",
        "--no-ground",
        "--out",
        str(out),
    ]
    argv += ["--velocity", "20,0,0", "--video", str(video), "--video-size", "32x24", "--device", "cpu"]
    assert main(argv) == 0
    motion = load_motion(out)
    placed = Placement.from_dict(motion.placement, str(out)).to_world(trimesh.load(mesh).vertices)
    np.testing.assert_allclose(motion.surface_points(0), placed, atol=1e-9)  # in metres, on the ground
    assert len(motion.surface.faces) == 12
    frames = [np.asarray(Image.open(tmp_path / "cube_frames" / f"{k:05d}.png")) for k in range(3)]
    assert all(f.shape == (24, 32, 3) and (f.min(axis=2) < 200).sum() > 20 for f in frames)
    assert (np.abs(frames[2].astype(int) - frames[0]).max(axis=2) > 50).sum() > 20
    assert video.is_file()


def test_a_motion_is_continued_only_with_the_cage_and_mesh_it_was_made_from(
    tmp_path, closed_mesh, capsys, caplog, rod
):
    """The motion records its asset, cage and mesh by content digest: another field is logged, a rebuilt
    cage (wind) or an edited mesh (simulate --mesh) refuses to continue it, in one line."""
    from meshes import save_embedded_cage

    asset, verts, tets = rod
    out = tmp_path / "wind.npz"
    args = _wind_args(asset, out)
    assert main([*args, "--frames", "3"]) == 0
    from shellsim.tetcage.store import cage_for_motion

    (asset.root / "field.safetensors").write_bytes(b"retrained")  # same shells and cage, another field
    with caplog.at_level("WARNING"):
        cage = cage_for_motion(asset, load_motion(out))
    np.testing.assert_array_equal(cage.vertices, verts - [0.2, 0.2, 0.05])
    assert f"{out} was made for another version of the asset 'rod'" in caplog.text
    save_embedded_cage(asset, verts - [0.2, 0.2, 0.06], tets)  # the cage rebuilt: 1 cm lower
    err = _fail([*args, "--frames", "5"], capsys)
    assert err.startswith(f"shellsim: error: {out}: the motion's rest cage differs from the asset's cage")
    assert load_motion(out).n_frames == 3

    mesh, _ = closed_mesh
    out = tmp_path / "m.npz"
    base = ["simulate", "--mesh", str(mesh), "--substeps", "1", "--out", str(out), "--device", "cpu"]
    assert main([*base, "--frames", "2"]) == 0
    trimesh.creation.box((1, 1, 1.5)).export(mesh)
    err = _fail([*base, "--frames", "3"], capsys)
    assert f"{out}: made from another content of {mesh} (changed since)" in err
    assert load_motion(out).n_frames == 2


def _cube(mesh, *options):
    """A 0.1 m rubber cube (the 1-unit mesh at --size 0.1), its lowest point 0.1 m above the ground."""
    return ["simulate", "--mesh", str(mesh), "--size", "0.1", "--substeps", "4", "--device", "cpu", *options]


def test_an_obstacle_overlapping_the_body_at_frame_0_is_named(tmp_path, closed_mesh, capsys):
    """The cube spans z 0.1..0.2 m and x, y -0.05..0.05 m: a box reaching up to z = 0.11 cuts its surface; a
    small sphere inside it touches no face, but lies inside the body: both are named as they were given."""
    mesh, _ = closed_mesh
    out = tmp_path / "cube.npz"
    err = _fail(_cube(mesh, "--box", "0,0,0.05,0.2,0.2,0.06", "--out", str(out)), capsys)
    assert "the body overlaps the collider 'box 1 (0,0,0.05,0.2,0.2,0.06)' at t = 0" in err
    err = _fail(
        _cube(mesh, "--sphere", "0.3,0,0.1,0.05", "--sphere", "0.02,0.02,0.13,0.005", "--out", str(out)),
        capsys,
    )
    assert "the body overlaps the collider 'sphere 2 (0.02,0.02,0.13,0.005)' at t = 0" in err
    assert not out.exists()  # refused before anything is written


def test_a_box_placed_in_metres_catches_the_body(tmp_path, closed_mesh):
    """Without a ground, the cube (lowest point at z = 0.1 m) falls onto a box whose top is at z = 0.05 m
    and rests on it: the lowest point of its surface (what contact acts on; the cage's face centres between
    the surface's corners may sag a little lower) ends within the barrier's reach (1 mm) above 0.05 m, never
    below."""
    mesh, _ = closed_mesh
    out = tmp_path / "cube.npz"
    argv = _cube(mesh, "--no-ground", "--box", "0,0,0,0.2,0.2,0.05", "--frames", "20", "--out", str(out))
    assert main([*argv, "--damping", "0.01"]) == 0
    motion = load_motion(out)
    assert motion.rest_vertices[:, 2].min() == pytest.approx(0.1)
    lowest = np.array([motion.surface_points(k)[:, 2].min() for k in range(motion.n_frames)])
    assert 0.05 < lowest[-1] <= 0.05 + 1e-3
    assert lowest.min() > 0.05  # never through the box


def test_the_saved_scene_is_the_run_and_the_scene_job_makes_the_same_motion(tmp_path, closed_mesh):
    """``simulate --save-scene`` writes the one-body shot it runs (pins as pin actions, the obstacles as
    colliders, one friction): read back it is the same spec, and ``shellsim scene`` on it makes a motion
    with equal positions, frame for frame."""
    import argparse
    import dataclasses

    from shellsim.cli.options import add_options, from_args
    from shellsim.jobs.simulate import SimulateSettings, scene_of
    from shellsim.shot.file import read_scene

    mesh, _ = closed_mesh
    toml = tmp_path / "shot.toml"
    options = ["--pin", "z>0.195", "--pin", "x<-0.049", "--box", "0.2,0,0.02,0.05,0.05,0.02"]
    options += ["--material", "jelly", "--friction", "0.3", "--damping", "0.002"]
    argv = _cube(
        mesh, *options, "--frames", "4", "--out", str(tmp_path / "cube.npz"), "--save-scene", str(toml)
    )
    assert main(argv) == 0

    def plain(spec):
        strip = {"where": ""}
        return dataclasses.replace(
            spec,
            path="",
            bodies=tuple(dataclasses.replace(b, **strip) for b in spec.bodies),
            colliders=tuple(dataclasses.replace(c, **strip) for c in spec.colliders),
            actions=tuple(dataclasses.replace(a, **strip) for a in spec.actions),
        )

    parser = argparse.ArgumentParser()
    add_options(parser, SimulateSettings)
    settings = from_args(SimulateSettings, parser.parse_args(argv[1:]))
    assert plain(read_scene(toml)) == plain(scene_of(settings))
    assert main(["scene", str(toml), "--out", str(tmp_path / "shot"), "--device", "cpu"]) == 0
    one, shot = load_motion(tmp_path / "cube.npz"), load_motion(tmp_path / "shot" / "motion.npz")
    assert one.n_frames == shot.n_frames == 4
    np.testing.assert_array_equal(one.rest_vertices, shot.rest_vertices)
    np.testing.assert_array_equal(one.positions, shot.positions)
    assert np.abs(one.positions[-1] - one.positions[0]).max() > 1e-3  # it moved
