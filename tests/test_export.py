"""`shellsim export`: USD, VTU series and PLY files read back by pxr, pyvista and trimesh, against an affine
motion whose deformed shells and volume ratios are known in closed form; the USD colours of M+ against a
field of one known colour, and the PLY colours against the USD ones; a scene's export (a neural body, two
mesh bodies, a box collider) against the motion's own surfaces and cages and the collider's mesh."""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import trimesh
from meshes import kuhn_grid, save_collision_surface, save_embedded_cage, write_asset_dir
from test_render_deformed import CENTER, make_asset

from shellsim.cli.main import main
from shellsim.io.export import AnimatedMesh, up_rotation, write_ply_sequence
from shellsim.motion.format import Motion, Surface, save_motion
from shellsim.tetcage.embed import embed_points

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
        return [trimesh.load(f, process=False) for f in write_ply_sequence(tmp_path / name, [mesh], [1, 3])]

    for coloured, bare in zip(sequence("coloured", usd_colors), sequence("bare", None), strict=True):
        assert bare.visual.kind is None and coloured.visual.kind == "vertex"
        assert np.array_equal(coloured.vertices, bare.vertices) and np.array_equal(coloured.faces, bare.faces)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"purpose": "render"}, "purpose: expected one of default, guide, got 'render'"),
        (
            {"colors": np.full((3, 4), 0.5)},
            r"colors: expected \(V, 3\) or \(3,\) numbers in \[0, 1\], got shape \(3, 4\)",
        ),
        ({"colors": np.full((3, 3), 1.5)}, r"colors: expected \(V, 3\)"),
        ({"colors": np.full((2, 3, 3), 0.5)}, r"colors: expected \(V, 3\) or \(3,\)"),
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


ORB_TINT = (0.5, 1.0, 0.25)
BALL_COLOR = (0.2, 0.4, 0.6)
TABLE_COLOR = (0.6, 0.0, 1.0)
COLLIDER_COLOR = (0.25, 0.75, 0.5)


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    """(scene output directory, the neural body's asset directory): 3 frames of a scene made by
    ``shellsim scene``: the test asset of test_render_deformed (its collision surface a sphere between its
    shells, so that none is extracted) as the body 'orb' tinted by :data:`ORB_TINT`, a box 'crate' and a ball
    'ball' in :data:`BALL_COLOR` (.obj meshes), a box collider 'table' in :data:`TABLE_COLOR` and a sphere
    collider 'shelf' in the look's :data:`COLLIDER_COLOR`."""
    pytest.importorskip("ipctk")
    from neural.asset import load_asset
    from shellsim.jobs.scene import SceneSettings, scene
    from shellsim.tetcage.store import load_or_build_cage

    tmp = tmp_path_factory.mktemp("shot")
    root = make_asset(tmp / "orb")
    asset = load_asset(root)
    save_collision_surface(
        asset, load_or_build_cage(asset), trimesh.creation.icosphere(2, radius=0.25).apply_translation(CENTER)
    )
    trimesh.creation.box(extents=(0.1, 0.08, 0.06)).export(tmp / "crate.obj")
    trimesh.creation.icosphere(1, radius=0.05).export(tmp / "ball.obj")
    (tmp / "shot.toml").write_text(
        f"""
[world]
frames = 30

[[body]]
name = "orb"
asset = "{root}"
size = 0.2
position = [0, 0, 0.1]
color = {list(ORB_TINT)}

[[body]]
name = "crate"
mesh = "{tmp / "crate.obj"}"
position = [0.3, 0, 0.1]
rotation = [0, 0, 30]

[[body]]
name = "ball"
mesh = "{tmp / "ball.obj"}"
position = [-0.3, 0, 0.1]
color = {list(BALL_COLOR)}

[[collider]]
name = "table"
shape = "box"
position = [0, 0.4, 0.05]
rotation = [0, 0, 20]
half_extents = [0.1, 0.1, 0.05]
color = {list(TABLE_COLOR)}

[[collider]]
name = "shelf"
shape = "sphere"
position = [0, -0.4, 0.05]
radius = 0.05

[look]
collider_color = {list(COLLIDER_COLOR)}
"""
    )
    scene(SceneSettings(scene=str(tmp / "shot.toml"), out=str(tmp / "out"), frames=3), progress=False)
    return tmp / "out", root


def shell_points(motion, record: dict, cage, k: int) -> np.ndarray:
    """(V, 3) M+ of the neural body ``record`` at frame ``k``: barycentric in its cage's world positions
    (a placement is affine, so no round trip through the asset's frame is needed)."""
    lo = record["vertices"][0]
    corners = motion.positions[k].astype(np.float64)[cage.tets[cage.outer_tet] + lo]
    return np.einsum("pk,pki->pi", cage.outer_bary, corners)


def surface_of(motion, record: dict) -> tuple[np.ndarray, np.ndarray]:
    """(indices (S,) of the body ``record``'s vertices in the motion's surface, its faces (F, 3) renumbered
    into them)."""
    t_lo, t_hi = record["tets"]
    mine = (motion.surface.tet >= t_lo) & (motion.surface.tet < t_hi)
    index = np.flatnonzero(mine)
    return index, motion.surface.faces[np.all(mine[motion.surface.faces], axis=1)] - index[0]


def test_usd_of_a_scene_holds_every_body_its_cage_and_the_static_collider(shot, tmp_path):
    from pxr import Usd, UsdGeom

    from neural.asset import load_asset, load_field
    from shellsim.film.shell_colors import shell_colors
    from shellsim.motion.read import load_motion
    from shellsim.shot.bodies import collider_mesh
    from shellsim.shot.recorded import MESH_BODY_COLORS, read_scene_motion
    from shellsim.tetcage.store import load_or_build_cage
    from shellsim.world import Placement

    out, root = shot
    motion = load_motion(out / "motion.npz")
    records = {r["name"]: r for r in motion.asset["bodies"]}
    assert list(records) == ["orb", "crate", "ball"]
    usd = tmp_path / "shot.usda"
    assert main(["export", "--motion", str(out), "--out", str(usd)]) == 0  # the scene's directory
    stage = Usd.Stage.Open(str(usd))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 2)
    names = [p.GetName() for p in stage.GetPrimAtPath("/Root").GetChildren()]
    assert names == ["orb", "crate", "ball", "table", "shelf", "orb_cage", "crate_cage", "ball_cage"]

    def mesh(name):
        prim = UsdGeom.Mesh(stage.GetPrimAtPath(f"/Root/{name}"))
        faces = np.asarray(prim.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        return prim, faces, lambda k: np.asarray(prim.GetPointsAttr().Get(k), np.float64)

    asset = load_asset(root)
    cage = load_or_build_cage(asset)
    orb, faces, points = mesh("orb")
    assert np.array_equal(faces, asset.outer_mesh().faces)
    assert orb.GetPointsAttr().GetTimeSamples() == [0, 1, 2]
    placement = Placement.from_dict(records["orb"]["placement"], "orb")
    assert np.abs(points(0) - placement.to_world(asset.outer_mesh().vertices)).max() < 1e-6  # at rest
    for k in range(3):
        assert np.abs(points(k) - shell_points(motion, records["orb"], cage, k)).max() < 1e-6
    assert orb.GetDisplayColorPrimvar().GetInterpolation() == UsdGeom.Tokens.vertex
    field_colors = shell_colors(asset, load_field(asset, "cpu"))  # (V, 3): what the field shows, untinted
    np.testing.assert_allclose(orb.GetDisplayColorPrimvar().Get(), field_colors * ORB_TINT, atol=1e-6)
    assert np.abs(points(2) - points(0)).max() > 1e-3  # it moved: it falls

    for name, expected_color in (("crate", MESH_BODY_COLORS[1]), ("ball", BALL_COLOR)):
        prim, faces, points = mesh(name)
        index, expected = surface_of(motion, records[name])
        assert np.array_equal(faces, expected)
        for frame in range(3):
            assert np.abs(points(frame) - motion.surface_points(frame)[index]).max() < 1e-6
        color = prim.GetDisplayColorPrimvar()
        assert color.GetInterpolation() == UsdGeom.Tokens.constant
        np.testing.assert_allclose(np.asarray(color.Get()), [expected_color], atol=1e-6)

    for name, record in records.items():
        prim, faces, points = mesh(f"{name}_cage")
        assert prim.GetPurposeAttr().Get() == UsdGeom.Tokens.guide
        lo, hi = record["vertices"]
        boundary = trimesh.Trimesh(points(1), faces, process=False)
        assert boundary.is_watertight and boundary.volume > 0
        assert np.abs(points(1)[:, None] - motion.positions[1][None, lo:hi]).sum(-1).min(1).max() < 1e-6

    specs = read_scene_motion(out, load_assets=False).colliders
    for spec, color in zip(specs, (TABLE_COLOR, COLLIDER_COLOR), strict=True):
        vertices, expected = collider_mesh(spec)
        prim, faces, points = mesh(spec.name)
        assert prim.GetPointsAttr().GetTimeSamples() == []  # written once, not per frame
        assert np.array_equal(faces, expected) and np.abs(points(1) - vertices).max() < 1e-6
        assert prim.GetPurposeAttr().Get() == UsdGeom.Tokens.default_
        np.testing.assert_allclose(prim.GetDisplayColorPrimvar().Get(), [color], atol=1e-6)


def test_ply_of_a_scene_is_every_body_per_frame_and_each_collider_once(shot, tmp_path):
    from neural.asset import load_asset, load_field
    from shellsim.film.shell_colors import shell_colors
    from shellsim.motion.read import load_motion
    from shellsim.shot.bodies import collider_mesh
    from shellsim.shot.recorded import read_scene_motion
    from shellsim.tetcage.store import load_or_build_cage

    out, root = shot
    motion = load_motion(out / "motion.npz")
    records = {r["name"]: r for r in motion.asset["bodies"]}
    ply = tmp_path / "ply"
    assert main(["export", "--format", "ply", "--motion", str(out / "motion.npz"), "--out", str(ply)]) == 0
    names = {f"{b}_{k:05d}.ply" for b in records for k in range(3)} | {"table.ply", "shelf.ply"}
    assert {f.name for f in ply.iterdir()} == names
    asset = load_asset(root)
    cage = load_or_build_cage(asset)
    orb_colors = np.round(shell_colors(asset, load_field(asset, "cpu")) * ORB_TINT * 255)

    def rgb(mesh) -> np.ndarray:
        assert mesh.visual.kind == "vertex" and (mesh.visual.vertex_colors[:, 3] == 255).all()
        return np.asarray(mesh.visual.vertex_colors[:, :3], np.float64)

    for k in range(3):
        orb = trimesh.load(ply / f"orb_{k:05d}.ply", process=False)
        assert np.abs(orb.vertices - shell_points(motion, records["orb"], cage, k)).max() < 1e-6
        assert np.abs(rgb(orb) - orb_colors).max() <= 1
        ball = trimesh.load(ply / f"ball_{k:05d}.ply", process=False)
        index, faces = surface_of(motion, records["ball"])
        assert np.array_equal(ball.faces, faces)
        assert np.abs(ball.vertices - motion.surface_points(k)[index]).max() < 1e-6
        assert (rgb(ball) == np.round(np.multiply(BALL_COLOR, 255))).all()
    specs = read_scene_motion(out, load_assets=False).colliders
    for spec, color in zip(specs, (TABLE_COLOR, COLLIDER_COLOR), strict=True):
        vertices, faces = collider_mesh(spec)
        collider = trimesh.load(ply / f"{spec.name}.ply", process=False)
        assert np.array_equal(collider.faces, faces) and np.abs(collider.vertices - vertices).max() < 1e-6
        assert (rgb(collider) == np.round(np.multiply(color, 255))).all()


def test_vtu_of_a_scene_is_its_concatenated_cage(shot, tmp_path):
    import pyvista as pv

    from shellsim.motion.read import load_motion

    out, _ = shot
    motion = load_motion(out / "motion.npz")
    pvd = tmp_path / "shot.pvd"
    assert main(["export", "--format", "vtu", "--motion", str(out), "--out", str(pvd), "--frames", "2"]) == 0
    (entry,) = ET.parse(pvd).getroot().find("Collection").findall("DataSet")
    grid = pv.read(pvd.parent / entry.get("file"))
    assert grid.n_cells == len(motion.tets)
    assert np.abs(grid.points - motion.positions[2]).max() < 1e-6


def test_an_asset_for_a_scene_motion_is_one_line_naming_it(shot, tmp_path, capsys):
    out, root = shot
    usd = tmp_path / "x.usd"
    capsys.readouterr()
    assert main(["export", "--motion", str(out), "--asset", str(root), "--out", str(usd)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"--asset {root}: {out / 'motion.npz'} is a scene motion" in err and "leave --asset out" in err
    assert not usd.exists()


def test_names_that_would_clash_in_a_scene_export_are_one_line_naming_the_motion(
    shot, tmp_path, capsys, monkeypatch
):
    """A collider named like a body's cage guide ('orb_cage') would make two prims of one path."""
    import dataclasses

    import shellsim.shot.recorded as scene_motion

    read = scene_motion.read_scene_motion

    def renamed(path, load_assets=True):
        scene = read(path, load_assets)
        scene.colliders = [dataclasses.replace(c, name="orb_cage") for c in scene.colliders]
        return scene

    monkeypatch.setattr(scene_motion, "read_scene_motion", renamed)
    out, _ = shot
    usd = tmp_path / "x.usd"
    capsys.readouterr()
    assert main(["export", "--motion", str(out), "--out", str(usd)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out / 'motion.npz'}: " in err and "'orb_cage'" in err
    assert not usd.exists()
