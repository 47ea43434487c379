"""``shellsim scene``: the shot's timed actions against closed forms (a grab's path, a push's impulse, free
fall after a release), refusals of the first instant, malformed scene files at the command line, resuming."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from shellsim.cli.main import main
from shellsim.motion.read import load_motion

pytest.importorskip("ipctk")

RUBBER_DENSITY = 1100.0  # kg/m^3, the preset (shellsim.physics.materials)


@pytest.fixture
def ball(tmp_path):
    """A closed icosphere of radius 5 cm, in metres."""
    path = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=2, radius=0.05).export(path)
    return path


def write_scene(tmp_path, text: str, name: str = "shot.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def run_scene(path, *extra) -> object:
    out = path.with_suffix("")
    assert main(["scene", str(path), "--out", str(out), *extra]) == 0
    return load_motion(out / "motion.npz")


def lumped_masses(rest: np.ndarray, tets: np.ndarray, density: float) -> np.ndarray:
    """(V,) a quarter of each tet's mass on each of its vertices (computed here, not by the solver)."""
    e = rest[tets[:, 1:]] - rest[tets[:, :1]]
    volume = np.abs(np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2]))) / 6.0
    return np.bincount(tets.ravel(), np.repeat(density * volume / 4.0, 4), minlength=len(rest))


def test_a_grab_follows_its_keyframes_within_a_millimetre_then_the_body_falls_freely(tmp_path, ball):
    scene = write_scene(
        tmp_path,
        f"""
[world]
fps = 30
frames = 19
substeps = 4
ground = false

[[body]]
name = "ball"
mesh = "{ball}"
position = [0, 0, 0.5]

[[action]]
kind = "grab"
body = "ball"
region = ["z>70%"]
start = 0.0
end = 0.4
keyframes = [{{ time = 0.2, position = [0.05, 0, 0.02], rotation = [0, 0, 90] }}, {{ time = 0.3 }}]
""",
    )
    motion = run_scene(scene)
    rest, times = motion.rest_vertices, motion.times
    z = rest[:, 2]
    region = z > z.min() + 0.7 * (z.max() - z.min())
    p0 = rest[region]
    c0 = p0.mean(0)
    quarter = Rotation.from_euler("z", 90, degrees=True)
    for k, t in enumerate(times):
        if not 0 < t < 0.4 - 1e-9:
            continue
        if t <= 0.2:  # the first leg: offset and angle grow linearly from the identity at start
            s = t / 0.2
            offset, turn = s * np.array([0.05, 0, 0.02]), Rotation.from_euler("z", 90 * s, degrees=True)
        elif t <= 0.3:  # back to where it began, turning back
            s = (t - 0.2) / 0.1
            offset = (1 - s) * np.array([0.05, 0, 0.02])
            turn = Rotation.from_euler("z", 90 * (1 - s), degrees=True)
        else:  # held at the last keyframe: the pose at start
            offset, turn = np.zeros(3), Rotation.identity()
        expected = c0 + turn.apply(p0 - c0) + offset
        assert np.abs(motion.positions[k][region] - expected).max() <= 1e-3, (t, quarter)
    # released at 0.4 s: from then on only gravity acts, so the momentum grows by M g per second
    masses = lumped_masses(rest, motion.tets, RUBBER_DENSITY)
    velocity = np.diff(motion.positions, axis=0) * 30.0  # mean velocity over each frame
    momentum = masses @ velocity  # (F - 1, 3)
    late = np.nonzero(times[:-1] >= 0.45)[0]
    a, b = late[0], late[-1]
    change = momentum[b] - momentum[a]
    expected = masses.sum() * np.array([0, 0, -9.81]) * (times[b] - times[a])
    assert np.linalg.norm(change - expected) <= 0.01 * np.linalg.norm(expected)


def test_a_push_changes_the_momentum_by_the_region_mass_times_dv(tmp_path, ball):
    scene = write_scene(
        tmp_path,
        f"""
[world]
fps = 30
frames = 10
substeps = 4
gravity = 0
ground = false

[[body]]
name = "ball"
mesh = "{ball}"
position = [0, 0, 0.5]

[[action]]
kind = "push"
body = "ball"
region = ["x<30%"]
start = 0.05
end = 0.15
velocity = [0.4, 0, 0.2]
""",
    )
    motion = run_scene(scene)
    rest = motion.rest_vertices
    x = rest[:, 0]
    region = x < x.min() + 0.3 * (x.max() - x.min())
    masses = lumped_masses(rest, motion.tets, RUBBER_DENSITY)
    momentum = masses @ ((motion.positions[-1] - motion.positions[-2]) * 30.0)
    expected = masses[region].sum() * np.array([0.4, 0, 0.2])
    assert np.linalg.norm(momentum - expected) <= 0.02 * np.linalg.norm(expected)


def test_a_scene_runs_again_continues_and_a_changed_scene_is_refused(tmp_path, ball, capsys):
    text = f"""
[world]
frames = 6
substeps = 2

[[body]]
name = "ball"
mesh = "{ball}"
position = [0, 0, 0.02]
"""
    scene = write_scene(tmp_path, text)
    whole = run_scene(scene)
    out = scene.with_suffix("")
    (out / "motion.npz").unlink()
    assert main(["scene", str(scene), "--out", str(out), "--frames", "3"]) == 0
    assert load_motion(out / "motion.npz").n_frames == 3
    continued = run_scene(scene)  # the rest of the shot, from the stored state
    np.testing.assert_allclose(continued.positions, whole.positions, atol=1e-6)
    before = (out / "motion.npz").read_bytes()
    write_scene(tmp_path, text.replace("frames = 6", "frames = 6\ngravity = 3"))
    capsys.readouterr()
    assert main(["scene", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "another scene" in err and "gravity" in err and "--overwrite" in err
    assert (out / "motion.npz").read_bytes() == before


def test_a_resting_ball_touches_the_ground_with_its_surface(tmp_path, ball):
    motion = run_scene(
        write_scene(
            tmp_path,
            f"""
[world]
frames = 25
substeps = 4
damping = 0.02

[[body]]
name = "ball"
mesh = "{ball}"
position = [0, 0, 0.01]
""",
        )
    )
    lowest = np.array([motion.surface_points(k)[:, 2].min() for k in range(motion.n_frames)])
    assert (lowest > 0).all()
    assert lowest[-1] <= 1e-3


BODY = """
[[body]]
name = "{name}"
mesh = "{mesh}"
position = {position}
"""


@pytest.mark.parametrize(
    "bodies, extra, words",
    [
        ([("a", "[0, 0, 0]"), ("b", "[0.03, 0, 0]")], "", "bodies 'a' and 'b' overlap at t = 0"),
        (
            [("a", "[0, 0, 0]")],
            '[[collider]]\nshape = "box"\nposition = [0, 0, 0.05]\nhalf_extents = [0.2, 0.2, 0.01]',
            "overlaps the collider",
        ),
        (
            [("a", "[0, 0, 0]")],
            '[[action]]\nkind = "pin"\nbody = "a"\nregion = ["z>5"]',
            "region: 'z>5' selects no vertex",
        ),
    ],
)
def test_the_first_instant_is_checked_before_anything_is_written(
    tmp_path, ball, capsys, bodies, extra, words
):
    text = "".join(BODY.format(name=n, mesh=ball, position=p) for n, p in bodies) + extra
    scene = write_scene(tmp_path, text)
    capsys.readouterr()
    assert main(["scene", str(scene), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("shellsim: error:") and "\n" not in err and "Traceback" not in err
    assert str(scene) in err and words in err
    assert not (tmp_path / "out" / "motion.npz").exists()


MALFORMED = [
    ("[world\nfps = 30", "not valid TOML"),
    ('[world]\nfps = 0\n[[body]]\nmesh = "{ball}"\n', "[world] fps"),
    ('[world]\nfps = true\n[[body]]\nmesh = "{ball}"\n', "[world] fps"),
    ('[world]\nframes = 0\n[[body]]\nmesh = "{ball}"\n', "[world] frames"),
    ('[world]\nsubsteps = 2.5\n[[body]]\nmesh = "{ball}"\n', "[world] substeps"),
    ('[world]\ngravity = -1\n[[body]]\nmesh = "{ball}"\n', "[world] gravity"),
    ('[world]\ncontact_gap = 0\n[[body]]\nmesh = "{ball}"\n', "[world] contact_gap"),
    ('[world]\nsettle = -1\n[[body]]\nmesh = "{ball}"\n', "[world] settle: must be in [0, 60], got -1"),
    ('[world]\nduration = 1\nframes = 30\n[[body]]\nmesh = "{ball}"\n', "[world]"),
    ("[wrld]\n", "wrld"),
    ('[world]\nfsp = 30\n[[body]]\nmesh = "{ball}"\n', "fsp"),
    ('[[body]]\nname = "x"\n', "[[body]] #1 (x)"),
    ('[[body]]\nasset = "no_such_asset_here"\n', "no_such_asset_here"),
    ('[[body]]\nmesh = "missing.obj"\n', "missing.obj"),
    ('[[body]]\nmesh = "{ball}"\ndensity = -3\n', "density"),
    ('[[body]]\nmesh = "{ball}"\nmaterial = "cheese"\n', "material"),
    ('[[body]]\nmesh = "{ball}"\nposition = [0, 0]\n', "position"),
    ('[[body]]\nmesh = "{ball}"\nposition = [0, 0, -0.5]\n', "position"),
    ('[[body]]\nmesh = "{ball}"\nunits = "furlong"\n', "units"),
    ('[[body]]\nmesh = "{ball}"\ncolor = [1, 0, 1.5]\n', "(body1) color: must all be in [0, 1]"),
    ('[[body]]\nmesh = "{ball}"\ncolor = [1, 0]\n', "(body1) color: expected [r, g, b], got [1, 0]"),
    ('[[body]]\nmesh = "{ball}"\n[[collider]]\nshape = "sphere"\nradius = 1\ncolor = [-1, 0, 0]\n', "color"),
    ('[[body]]\nmesh = "{ball}"\n[[collider]]\nshape = "cone"\n', "shape"),
    ('[[body]]\nmesh = "{ball}"\n[[collider]]\nshape = "sphere"\nradius = -1\n', "radius"),
    ('[[body]]\nmesh = "{ball}"\n[[action]]\nkind = "pin"\nbody = "nobody"\nstart = 0\nend = 1\n', "nobody"),
    ('[[body]]\nmesh = "{ball}"\n[[action]]\nkind = "pin"\nbody = "body1"\nstart = 1\nend = 0.5\n', "end"),
    (
        '[[body]]\nmesh = "{ball}"\n[[action]]\nkind = "grab"\nbody = "body1"\nstart = 0\nend = 1\n',
        "keyframes",
    ),
    (
        '[[body]]\nmesh = "{ball}"\n[[action]]\nkind = "push"\nbody = "body1"\nstart = 0\nend = 1\n',
        "velocity",
    ),
    ('[[body]]\nmesh = "{ball}"\n[[action]]\nkind = "pin"\nbody = "body1"\nregion = ["q<1"]\n', "region"),
    ('[[body]]\nmesh = "{ball}"\n[[action]]\nkind = "wiggle"\n', "kind"),
    ('[[body]]\nmesh = "{ball}"\n[[camera]]\nkind = "follow"\nposition = [1, 1, 1]\nbody = "x"\n', "x"),
]


@pytest.mark.parametrize("text, words", MALFORMED)
def test_a_malformed_scene_file_is_one_line_exit_2_and_writes_nothing(tmp_path, ball, capsys, text, words):
    scene = write_scene(tmp_path, text.format(ball=ball))
    capsys.readouterr()
    out = tmp_path / "out"
    assert main(["scene", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"shellsim: error: {scene}") and "\n" not in err and "Traceback" not in err
    assert words in err
    assert not out.exists()


def test_a_shipped_asset_body_is_placed_by_its_visible_surface_and_recorded_under_its_own_name(tmp_path):
    """The shipped LEGO (its cage and collision surface ship with it: nothing is built) as the body 'dozer',
    its visible bottom 5 cm up: frame 0's lowest surface point is at 0.05 m, the cage reaches lower."""
    motion = run_scene(
        write_scene(
            tmp_path,
            """
[world]
frames = 2
substeps = 2

[[body]]
name = "dozer"
asset = "lego"
size = 0.2
position = [0.1, -0.2, 0.05]
""",
        )
    )
    (body,) = motion.asset["bodies"]
    assert body["name"] == "dozer" and body["source"]["name"] == "lego"
    assert body["vertices"] == [0, len(motion.rest_vertices)] and body["tets"] == [0, len(motion.tets)]
    surface = motion.surface_points(0)
    lo, hi = surface.min(0), surface.max(0)
    assert lo[2] == pytest.approx(0.05, abs=1e-6)  # positions are stored as float32
    assert (hi - lo).max() == pytest.approx(0.2, abs=1e-6)
    np.testing.assert_allclose(0.5 * (lo[:2] + hi[:2]), [0.1, -0.2], atol=1e-6)
    assert motion.rest_vertices[:, 2].min() < 0.05 - 1e-3  # the cage is dilated past the visible surface
