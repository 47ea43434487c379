"""`shellsim export`: USD, VTU series and PLY files read back by pxr, pyvista and trimesh, against an affine
motion whose deformed shells and volume ratios are known in closed form; the USD colours of M+ against a
field of one known colour, and the PLY colours against the USD ones."""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import trimesh
from meshes import kuhn_grid, save_embedded_cage, write_asset_dir

from shellsim.cage.embed import embed_points
from shellsim.cli.main import main
from shellsim.io.export import AnimatedMesh, up_rotation, write_ply_sequence
from shellsim.motion.format import Motion, Surface, save_motion

FRAMES = 4
FPS = 24.0


def affine(k: int) -> tuple[np.ndarray, np.ndarray]:
    """The map of frame ``k``: x -> A x + b with det A = (1 + 0.1 k)^3 (a scale and a shear)."""
    a = (1.0 + 0.1 * k) * np.array([[1.0, 0.05 * k, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    return a, np.array([0.01 * k, -0.02 * k, 0.03 * k])


def moved(points: np.ndarray, k: int) -> np.ndarray:
    a, b = affine(k)
    return points @ a.T + b


def small_field(center, color=None, inv_s: float = 20.0):
    """An untrained ``ShellField`` (a sphere SDF about ``center``, unit scale) with a small hash grid; with
    ``color`` (3,) its radiance is that colour everywhere."""
    from neural.field import FieldConfig, ShellField
    from neural.field.hashgrid import HashGridConfig

    torch.manual_seed(0)
    hashgrid = HashGridConfig(n_levels=2, log2_table_size=8, max_resolution=16)
    field = ShellField(FieldConfig(hashgrid=hashgrid, init_inv_s=inv_s), center=center)
    if color is not None:
        with torch.no_grad():
            field.rad[-1].weight.zero_()
            field.rad[-1].bias.copy_(torch.logit(torch.tensor(color)))
    return field


@pytest.fixture
def rod(tmp_path):
    """(asset directory, its cage) : cylinder shells in a hand-made Kuhn-box cage, z up."""
    from neural.asset import load_asset

    outer = trimesh.creation.cylinder(radius=0.15, height=1.0, sections=16)
    outer.apply_translation([0.0, 0.0, 0.5])
    inner = trimesh.creation.cylinder(radius=0.1, height=0.9, sections=16)
    inner.apply_translation([0.0, 0.0, 0.5])
    field = small_field((0.0, 0.0, 0.5))
    root = write_asset_dir(
        tmp_path / "rod", outer, inner, "rod", center=(0, 0, 0.5), up=(0, 0, 1), field=field
    )
    verts, tets, _ = kuhn_grid(0.0, (0.4, 0.4, 1.1), (2, 2, 4))
    cage = save_embedded_cage(load_asset(root), verts - [0.2, 0.2, 0.05], tets)
    return root, cage


def write_motion(path, cage, meta=None, surface=None):
    positions = np.stack([moved(cage.vertices, k) for k in range(FRAMES)]).astype(np.float32)
    save_motion(
        path, Motion(cage.vertices, cage.tets, positions, np.arange(FRAMES) / FPS, meta or {}, surface)
    )
    return positions


def test_usd_holds_the_deformed_shell_and_cage_per_time_code(rod, tmp_path):
    from pxr import Usd, UsdGeom

    root, cage = rod
    motion = tmp_path / "m.npz"
    positions = write_motion(motion, cage, {"fps": FPS, "world": {"scale": 0.25}})
    out = tmp_path / "rod.usd"
    assert main(["export", "--asset", str(root), "--motion", str(motion), "--out", str(out)]) == 0
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.25)
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, FRAMES - 1)
    shell = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/outer_shell"))
    rest_outer = trimesh.load(root / "shell_outer.ply", process=False)
    assert np.array_equal(np.asarray(shell.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), rest_outer.faces)
    assert shell.GetPointsAttr().GetTimeSamples() == list(range(FRAMES))
    for k in range(FRAMES):
        points = np.asarray(shell.GetPointsAttr().Get(k))
        assert (
            np.abs(points - moved(rest_outer.vertices, k)).max() < 1e-5
        )  # barycentric maps keep affine maps
    cage_prim = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/cage"))
    cage_points = np.asarray(cage_prim.GetPointsAttr().Get(2))
    faces = np.asarray(cage_prim.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    boundary = trimesh.Trimesh(cage_points, faces, process=False)
    assert boundary.is_watertight and boundary.volume == pytest.approx(1.2**3 * 0.4 * 0.4 * 1.1, rel=1e-5)
    assert np.abs(cage_points[:, None] - positions[2][None]).sum(-1).min(1).max() < 1e-6
    assert cage_prim.GetPurposeAttr().Get() == UsdGeom.Tokens.guide  # not rendered: it would hide M+
    assert shell.GetPurposeAttr().Get() == UsdGeom.Tokens.default_
    colors = np.asarray(shell.GetDisplayColorPrimvar().Get())
    assert shell.GetDisplayColorPrimvar().GetInterpolation() == UsdGeom.Tokens.vertex
    assert colors.shape == rest_outer.vertices.shape and colors.min() >= 0 and colors.max() <= 1


def test_usd_and_ply_colours_of_a_one_colour_field_are_that_colour(tmp_path):
    """A sphere field of one colour, sharp enough (kernel 1/500) to be opaque within its band: every M+
    vertex's colour in the stage and in a PLY frame is that colour, not the white background."""
    from pxr import Usd, UsdGeom

    from neural.asset import load_asset

    color = (0.2, 0.6, 0.9)
    center = np.array([0.1, -0.2, 0.3])
    field = small_field(tuple(center), color, inv_s=500.0)
    radius = field.config.init_radius
    outer = trimesh.creation.icosphere(subdivisions=2, radius=radius + 0.05).apply_translation(center)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=radius - 0.05).apply_translation(center)
    root = write_asset_dir(tmp_path / "ball", outer, inner, "ball", center=tuple(center), field=field)
    verts, tets, _ = kuhn_grid(center - radius - 0.1, center + radius + 0.1, 2)
    cage = save_embedded_cage(load_asset(root), verts, tets)
    write_motion(tmp_path / "m.npz", cage)
    out = tmp_path / "ball.usda"
    assert main(["export", "--asset", str(root), "--motion", str(tmp_path / "m.npz"), "--out", str(out)]) == 0
    stage = Usd.Stage.Open(str(out))  # held: its prims are valid while it lives
    shell = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/outer_shell"))
    colors = np.asarray(shell.GetDisplayColorPrimvar().Get())
    assert colors.shape == (len(outer.vertices), 3)
    np.testing.assert_allclose(colors, np.broadcast_to(color, colors.shape), atol=0.01)
    ply = tmp_path / "ply"
    args = ["export", "--asset", str(root), "--motion", str(tmp_path / "m.npz"), "--out", str(ply)]
    assert main([*args, "--format", "ply", "--frames", "2"]) == 0
    rgba = trimesh.load(ply / "outer_shell_00002.ply", process=False).visual.vertex_colors
    np.testing.assert_allclose(rgba / 255, np.broadcast_to((*color, 1.0), rgba.shape), atol=0.01 + 1 / 255)


def test_ply_frames_carry_the_usd_colours_of_m_plus(rod, tmp_path):
    """Every PLY frame of M+ holds the USD stage's per-vertex colours (uint8 RGBA, opaque, to 1/255); the
    colours leave the points as a PLY without colours has them."""
    from pxr import Usd, UsdGeom

    root, cage = rod
    motion = tmp_path / "m.npz"
    write_motion(motion, cage)
    usd, ply = tmp_path / "rod.usda", tmp_path / "ply"
    args = ["export", "--asset", str(root), "--motion", str(motion)]
    for out, format in ((usd, "usd"), (ply, "ply")):
        assert main([*args, "--out", str(out), "--format", format]) == 0
    stage = Usd.Stage.Open(str(usd))
    shell = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/outer_shell"))
    usd_colors = np.asarray(shell.GetDisplayColorPrimvar().Get())
    rest_outer = trimesh.load(root / "shell_outer.ply", process=False)
    files = sorted(ply.glob("*.ply"))
    assert [f.name for f in files] == [f"outer_shell_{k:05d}.ply" for k in range(FRAMES)]
    for k, f in enumerate(files):
        mesh = trimesh.load(f, process=False)
        assert mesh.visual.kind == "vertex"
        colors = mesh.visual.vertex_colors
        assert colors.dtype == np.uint8 and colors.shape == (len(rest_outer.vertices), 4)
        assert (colors[:, 3] == 255).all()
        np.testing.assert_allclose(colors[:, :3] / 255, usd_colors, atol=1 / 255)
        assert np.array_equal(mesh.faces, rest_outer.faces)
        assert np.abs(mesh.vertices - moved(rest_outer.vertices, k)).max() < 1e-5

    def sequence(name, colors):
        mesh = AnimatedMesh("m", rest_outer.faces, lambda k: moved(rest_outer.vertices, k), colors)
        return [trimesh.load(f, process=False) for f in write_ply_sequence(tmp_path / name, mesh, [1, 3])]

    for coloured, bare in zip(sequence("coloured", usd_colors), sequence("bare", None), strict=True):
        assert bare.visual.kind is None and coloured.visual.kind == "vertex"
        assert np.array_equal(coloured.vertices, bare.vertices) and np.array_equal(coloured.faces, bare.faces)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"purpose": "render"}, "purpose: expected one of default, guide, got 'render'"),
        (
            {"colors": np.full((3, 4), 0.5)},
            r"colors: expected \(V, 3\) numbers in \[0, 1\], got shape \(3, 4\)",
        ),
        ({"colors": np.full((3, 3), 1.5)}, r"colors: expected \(V, 3\)"),
    ],
)
def test_a_mesh_refuses_an_unknown_purpose_or_bad_colours(options, message):
    with pytest.raises(ValueError, match=message):
        AnimatedMesh("m", np.zeros((1, 3), int), lambda k: np.zeros((3, 3)), **options)


def test_vtu_series_carries_displacement_and_det_f(rod, tmp_path):
    import pyvista as pv

    _, cage = rod
    motion = tmp_path / "m.npz"
    write_motion(motion, cage)
    out = tmp_path / "series.pvd"
    assert (
        main(["export", "--format", "vtu", "--motion", str(motion), "--out", str(out), "--frames", "1:4"])
        == 0
    )
    entries = ET.parse(out).getroot().find("Collection").findall("DataSet")
    assert [float(e.get("timestep")) for e in entries] == pytest.approx([1 / FPS, 2 / FPS, 3 / FPS])
    for k, entry in zip(range(1, 4), entries, strict=True):
        grid = pv.read(out.parent / entry.get("file"))
        assert np.abs(grid.points - moved(cage.vertices, k)).max() < 1e-5
        assert (
            np.abs(grid.point_data["displacement"] - (moved(cage.vertices, k) - cage.vertices)).max() < 1e-5
        )
        assert grid.cell_data["volume_ratio"] == pytest.approx(
            np.full(len(cage.tets), (1 + 0.1 * k) ** 3), 1e-5
        )


def mesh_motion(path, meta=None) -> trimesh.Trimesh:
    """A 'simulate --mesh'-like motion at ``path``: a sphere carried by a Kuhn-box cage under the affine
    motion; returns the sphere at rest."""
    verts, tets, _ = kuhn_grid(0.0, 1.0, 2)
    sphere = trimesh.creation.icosphere(1, radius=0.3)
    sphere.apply_translation([0.5, 0.5, 0.5])
    surface = Surface(*embed_points(verts, tets, sphere.vertices), np.asarray(sphere.faces))
    write_motion(path, SimpleNamespace(vertices=verts, tets=tets), meta, surface)
    return sphere


def test_ply_sequence_of_a_simulated_mesh_surface(tmp_path):
    motion = tmp_path / "m.npz"
    sphere = mesh_motion(motion)
    out = tmp_path / "ply"
    assert main(["export", "--format", "ply", "--motion", str(motion), "--out", str(out)]) == 0
    files = sorted(out.glob("*.ply"))
    assert [f.name for f in files] == [f"surface_{k:05d}.ply" for k in range(FRAMES)]
    for k, f in enumerate(files):
        mesh = trimesh.load(f, process=False)
        assert np.array_equal(mesh.faces, sphere.faces)
        assert np.abs(mesh.vertices - moved(sphere.vertices, k)).max() < 1e-5
    assert main(["export", "--format", "ply", "--motion", str(motion), "--out", str(out)]) == 2  # kept


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--format", "vtu", "--out", "x.usd"], "--out: a vtu export is written to .pvd, got 'x.usd'"),
        (["--out", "x.usd", "--frames", "9"], "--frames '9': "),
        (["--out", "x.usd"], "needs --asset to export its shell"),
    ],
)
def test_errors_are_one_line(rod, tmp_path, capsys, args, message):
    _, cage = rod
    write_motion(tmp_path / "m.npz", cage)
    assert main(["export", "--motion", str(tmp_path / "m.npz"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


@pytest.mark.parametrize("up", [(0, 1, 0), (0, 0, 1), (1, 0, 0), (0, 0, -1), (0.3, -0.5, 0.8)])
def test_up_rotation_is_a_rotation_taking_up_to_the_usd_axis(up):
    r, axis = up_rotation(up)
    u = np.asarray(up, float) / np.linalg.norm(up)
    assert np.allclose(r @ r.T, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)
    assert np.allclose(r @ u, (0, 1, 0) if axis == "Y" else (0, 0, 1))


def test_a_missing_usd_extra_is_one_line_naming_it(rod, tmp_path, capsys, monkeypatch):
    root, cage = rod
    write_motion(tmp_path / "m.npz", cage)
    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr raises ImportError
    args = [
        "export",
        "--asset",
        str(root),
        "--motion",
        str(tmp_path / "m.npz"),
        "--out",
        str(tmp_path / "a.usd"),
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.endswith("pip install 'shellsim[usd]'\n") and err.count("\n") == 1
    assert not (tmp_path / "a.usd").exists()


def test_usd_of_a_mesh_motion_takes_the_motion_up_axis(tmp_path):
    from pxr import Usd, UsdGeom

    motion = tmp_path / "m.npz"
    sphere = mesh_motion(motion, {"up": [0.0, 1.0, 0.0]})
    out = tmp_path / "mesh.usda"
    assert main(["export", "--motion", str(motion), "--out", str(out)]) == 0
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    points = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/Root/surface")).GetPointsAttr().Get(3))
    assert np.abs(points - moved(sphere.vertices, 3)).max() < 1e-5
