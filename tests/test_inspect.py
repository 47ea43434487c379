"""shellsim.viz.inspect: the shell-width closed form of concentric spheres, the kernel size of an untrained
field,
a motion frame moving the drawn cage and shells exactly, the off-screen PNG (size, not blank, translucent
shell visible), the frame slider, and the CLI's one-line errors."""

import sys

import numpy as np
import pytest
from meshes import kuhn_grid, save_embedded_cage, write_asset_dir

from neural.errors import InputError, ShellsimError
from neural.field import FieldConfig, HashGridConfig, ShellField
from shellsim.cli.main import main  # noqa: E402
from shellsim.motion.format import Motion, save_motion
from shellsim.tetcage.embed import interpolate  # noqa: E402
from shellsim.viz.inspect import SCALARS, build_scene, make_plotter, screenshot, shell_width


def box_cage(n: int = 3, half: float = 1.25):
    """The cube [-half, half]^3 split into n^3 cells of 6 Kuhn tets: vertices (V, 3), tets (T, 4)."""
    return kuhn_grid(-half, half, n)[:2]


def write_asset(root, inner_subdivisions: int = 2, field=None):
    """Asset directory: asset.json, ``field``'s weights (None: a placeholder file), icospheres M+ (radius 1)
    and M- (radius 0.9), and a cage.npz of Kuhn tets around them (no fTetWild)."""
    import trimesh

    from neural.asset import load_asset

    outer = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    inner = trimesh.creation.icosphere(subdivisions=inner_subdivisions, radius=0.9)
    write_asset_dir(root, outer, inner, "ball", scale=0.5, up=(0, 0, 1), field=field)
    asset = load_asset(root)
    return asset, save_embedded_cage(asset, *box_cage())


def twist_motion(cage, n_frames: int = 4, fps: float = 10.0) -> Motion:
    """Cage frames: a growing twist about z plus a shear, frame 0 at rest."""
    frames = []
    for k in range(n_frames):
        a = 0.15 * k
        rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        frames.append(cage.vertices @ rot.T + 0.1 * k * cage.vertices[:, 2:3] * [1.0, 0.0, 0.0])
    return Motion(cage.vertices, cage.tets, np.stack(frames), np.arange(n_frames) / fps, {"made_by": "test"})


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    return write_asset(tmp_path_factory.mktemp("inspect") / "ball")


def test_concentric_spheres_have_width_one_tenth(tmp_path):
    """Same subdivision: every M+ vertex lies radially over an M- vertex, 0.1 away, and the M- polyhedron
    lies in the ball of radius 0.9, so the width is exactly 0.1 (up to the PLY files' float32 coordinates)."""
    asset, cage = write_asset(tmp_path / "same", inner_subdivisions=2)
    width = build_scene(asset, cage)["outer"].point_data[SCALARS["width"]]
    assert width.shape == (len(asset.outer_mesh().vertices),)
    np.testing.assert_allclose(width, 0.1, rtol=0, atol=2e-7)


def test_width_lies_between_the_sphere_gap_and_the_inradius_bound(rng):
    """A coarser M-: its faces cut inside the sphere of radius 0.9, down to its inradius r (closest face plane
    to the centre), so 0.1 <= width <= 1 - r for vertices on the unit sphere."""
    import trimesh

    inner = trimesh.creation.icosphere(subdivisions=1, radius=0.9)
    normals = inner.face_normals
    inradius = np.abs(np.einsum("fi,fi->f", normals, inner.vertices[inner.faces[:, 0]])).min()
    dirs = rng.normal(size=(500, 3))
    points = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    width = shell_width(points, inner.vertices, inner.faces)
    assert width.min() >= 0.1 - 1e-12 and width.max() <= 1 - inradius + 1e-12
    assert width.max() - width.min() > 0.5 * (0.9 - inradius)  # it does see the faces' sag


def test_motion_frame_moves_the_drawn_cage_and_shells_exactly(ball):
    asset, cage = ball
    motion = twist_motion(cage)
    for k in (0, 2, -1):
        scene = build_scene(asset, cage, motion, frame=k)
        np.testing.assert_array_equal(scene["cage"].points, motion.positions[k].astype(np.float64))
        for name in ("outer", "inner"):
            tet, bary = getattr(cage, f"{name}_tet"), getattr(cage, f"{name}_bary")
            expected = interpolate(motion.positions[k], cage.tets, tet, bary)
            np.testing.assert_allclose(scene[name].points, expected, rtol=0, atol=1e-12)
    # frame 0 is the rest state: the drawn shells are the asset's shells
    rest = build_scene(asset, cage, motion, frame=0)
    np.testing.assert_allclose(rest["outer"].points, asset.outer_mesh().vertices, atol=1e-6)
    # the cage is drawn as its closed boundary (6 faces of the cube, n^2 squares each, 2 triangles a square)
    assert rest["cage"].n_cells == 6 * 9 * 2


def test_bad_scene_arguments(ball):
    asset, cage = ball
    motion = twist_motion(cage)
    with pytest.raises(ValueError, match="color"):
        build_scene(asset, cage, color="rainbow")
    with pytest.raises(ValueError, match="frame"):
        build_scene(asset, cage, motion, frame=4)
    with pytest.raises(ValueError, match="frame"):
        build_scene(asset, cage, frame=1)
    short = Motion(cage.vertices[:-1], cage.tets[:1], motion.positions[:, :-1], motion.times)
    with pytest.raises(InputError, match="moves 63 cage vertices but the asset's cage has 64"):
        short.check_against(cage, "short.npz")
    moved = Motion(cage.vertices + 0.1, cage.tets, motion.positions, motion.times)
    with pytest.raises(InputError, match="rest cage differs"):
        moved.check_against(cage)


def test_kernel_colouring_without_a_field_is_a_clear_error(ball, monkeypatch):
    asset, cage = ball
    with pytest.raises(InputError, match="field.safetensors: cannot read"):  # placeholder weights
        build_scene(asset, cage, color="kernel")
    monkeypatch.setitem(sys.modules, "neural.field", None)  # the field package cannot be imported
    with pytest.raises(ShellsimError, match="kernel size needs the neural field"):
        build_scene(asset, cage, color="kernel")


def test_kernel_colouring_reads_the_field(tmp_path):
    """An untrained field has ``log s = -log(init_inv_s)`` in unit space (its kernel output starts at zero),
    so ``s = 1 / (init_inv_s * scale)`` in world units at every point."""
    config = FieldConfig(
        hashgrid=HashGridConfig(n_levels=2, log2_table_size=8, max_resolution=32),
        init_inv_s=40.0,
        backend="torch",
    )
    field = ShellField(config, center=(0.0, 0.0, 0.0), scale=0.5)
    asset, cage = write_asset(tmp_path / "fielded", field=field)
    s = build_scene(asset, cage, color="kernel")["outer"].point_data[SCALARS["kernel"]]
    np.testing.assert_allclose(s, 1.0 / (40.0 * 0.5), rtol=1e-5)


def test_screenshot_is_the_requested_size_and_shows_every_part(ball, tmp_path):
    from PIL import Image

    asset, cage = ball
    motion = twist_motion(cage)
    path = screenshot(asset, cage, tmp_path / "view.png", motion, frame=2, size=(320, 240))
    image = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert image.shape == (240, 320, 3)
    colours = np.unique(image.reshape(-1, 3), axis=0)
    assert len(colours) > 50
    assert (image.min(axis=2) < 60).sum() > 100  # dark pixels: the cage's lines and the text
    # the centre shows both shells: removing either changes it (M+ is drawn and M- shows through it)
    centre = image[100:140, 140:180]
    for hidden in ("outer", "inner"):
        plotter = make_plotter(asset, cage, motion, frame=2, size=(320, 240), off_screen=True)
        plotter.remove_actor(hidden)
        without = plotter.screenshot(return_img=True).astype(int)[100:140, 140:180]
        plotter.close()
        assert np.abs(centre - without).mean() > 10, hidden


def test_frame_slider_moves_cage_and_title(ball):
    asset, cage = ball
    motion = twist_motion(cage)
    plotter = make_plotter(asset, cage, motion, frame=0, size=(160, 120), off_screen=True, slider=True)
    widget = plotter.widgets.slider_widgets[0]
    widget.GetRepresentation().SetValue(3.0)
    widget.InvokeEvent("InteractionEvent")
    actors = plotter.renderer.actors
    np.testing.assert_array_equal(
        actors["cage"].mapper.dataset.points, motion.positions[3].astype(np.float64)
    )
    assert "frame 3 of 0..3, t = 0.300 s" in actors["title"].GetText(2)  # upper left
    plotter.close()


def test_cli_screenshot(ball, tmp_path):
    from PIL import Image

    asset, cage = ball
    save_motion(tmp_path / "m.npz", twist_motion(cage))
    out = tmp_path / "cli.png"
    args = ["inspect", "--asset", str(asset.root), "--motion", str(tmp_path / "m.npz"), "--frame", "-1"]
    assert main([*args, "--screenshot", str(out), "--size", "200x150"]) == 0
    assert Image.open(out).size == (200, 150)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--size", "200by150"], "--size"),
        (["--size", "0x150"], "--size"),
        (["--frame", "1"], "--frame: needs --motion"),
        (["--screenshot", "out.jpg"], "PNG"),
    ],
)
def test_cli_bad_options_are_one_line(ball, tmp_path, capsys, extra, message):
    asset, _ = ball
    args = ["inspect", "--asset", str(asset.root), *extra]
    if "--screenshot" not in extra:
        args += ["--screenshot", str(tmp_path / "x.png")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_cli_needs_an_asset_or_a_motion(capsys):
    assert main(["inspect", "--screenshot", "x.png"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--asset" in err and "--motion" in err and len(err.splitlines()) == 1


def test_cli_mismatching_motion_is_one_line(ball, tmp_path, capsys):
    asset, cage = ball
    verts, tets = box_cage(n=2)
    path = tmp_path / "other.npz"
    save_motion(path, Motion(verts, tets, verts[None], np.zeros(1)))
    assert main(["inspect", "--asset", str(asset.root), "--motion", str(path), "--screenshot", "x.png"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "27 cage vertices" in err[0] and "has 64" in err[0]
    motion = twist_motion(cage)
    path = tmp_path / "m.npz"
    save_motion(path, motion)
    assert main(["inspect", "--asset", str(asset.root), "--motion", str(path), "--frame", "4"]) == 2
    assert "--frame" in capsys.readouterr().err


@pytest.mark.slow
def test_screenshot_prints_nothing_from_vtk(ball, tmp_path):
    """Without a display VTK warns 'bad X server connection' on stderr; inspect keeps it quiet."""
    import os
    import subprocess

    asset, _ = ball
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    shot = tmp_path / "quiet.png"
    argv = [sys.executable, "-m", "shellsim.cli.main", "inspect", "--asset", str(asset.root)]
    result = subprocess.run(
        [*argv, "--screenshot", str(shot), "--size", "64x48"], env=env, capture_output=True, text=True
    )
    assert result.returncode == 0 and shot.is_file()
    assert "WARN" not in result.stderr and "X server" not in result.stderr, result.stderr
    assert result.stdout == ""


def test_colour_bar_title_clears_its_labels(ball):
    """The rows of the title's text and of the labels above the bar are apart (VTK's own title used to
    sit on the middle label). Only the bar and its text are drawn."""
    asset, cage = ball
    plotter = make_plotter(asset, cage, size=(640, 480), off_screen=True)
    for name in ("outer", "inner", "cage", "title"):
        plotter.remove_actor(name)
    image = plotter.screenshot(return_img=True).astype(int)
    plotter.close()
    middle = image[240:, 300:440]  # below the centre, around the bar's middle label
    inked = (middle.min(axis=2) < 128).any(axis=1)
    runs = np.flatnonzero(np.diff(inked.astype(int)) == 1)  # rows where a run of dark text or bar starts
    assert len(runs) >= 3, inked.nonzero()  # title, middle label, bar: three separate runs


@pytest.mark.parametrize("extra", [["--frame", "9"], ["--size", "0x1"], ["--screenshot", "x.jpg"]])
def test_cli_options_are_checked_before_the_asset_loads(ball, tmp_path, capsys, monkeypatch, extra):
    def no_loading(*args, **kwargs):
        raise AssertionError("the asset was loaded before the options were checked")

    monkeypatch.setattr("neural.asset.load_asset", no_loading)
    asset, cage = ball
    save_motion(tmp_path / "m.npz", twist_motion(cage))
    args = ["inspect", "--asset", str(asset.root), "--motion", str(tmp_path / "m.npz")]
    if "--screenshot" not in extra:
        args += ["--screenshot", str(tmp_path / "x.png")]
    assert main([*args, *extra]) == 2
    assert extra[0] in capsys.readouterr().err
