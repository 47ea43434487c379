"""The scene file (:mod:`shellsim.shot.file`): a full file read into the spec's dataclasses, the defaults,
paths relative to the file, and one line ``FILE: [table] key: problem`` for each kind of mistake."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest

from shellsim.shot.file import problem, read_scene
from shellsim.shot.spec import (
    ActionSpec,
    BodySpec,
    CageSpec,
    CameraKeyframe,
    CameraSpec,
    ColliderSpec,
    Keyframe,
    LookSpec,
    SceneError,
    SceneSpec,
    WorldSpec,
)

FULL = """
[world]
fps = 24
duration = 2.5
substeps = 4
gravity = 9.8
ground = true
ground_friction = 0.8
damping = 0.001
drag = 0.1
contact_gap = 0.002
friction_velocity = 0.02
settle = 0.5

[[body]]
name = "brick"
asset = "lego"
size = 0.25
position = [0, 0, 0.5]
rotation = [0, 0, 45]
material = "foam"
youngs = 2e5
poisson = 0.3
density = 50
damping = 0.01
friction = 0.7
velocity = [1, 0, 0]
spin = [0, 0, 3]
color = [1, 0.5, 0]
[body.cage]
target_tets = 3000
margin = 0.01

[[body]]
mesh = "parts/ball.obj"
units = "cm"
position = [0.5, 0, 0]
color = [0.1, 0.2, 0.3]

[[body]]
name = "toy"
asset = "assets/toy"

[[collider]]
name = "ramp"
shape = "box"
position = [1, 0, 0.1]
rotation = [0, 20, 0]
half_extents = [0.5, 0.3, 0.1]
friction = 0.2
color = [0, 1, 0.25]

[[collider]]
shape = "sphere"
position = [0, 1, 0.2]
radius = 0.2

[[collider]]
name = "rock"
shape = "mesh"
mesh = "parts/rock.stl"
units = "mm"
scale = 2

[[action]]
kind = "pin"
body = "brick"
region = "z<10%"
end = 1.0

[[action]]
kind = "grab"
body = "body2"
region = ["x>90%", "z >= 0.05"]
start = 0.5
end = 2
keyframes = [
  {time = 1.0, position = [0.05, 0, 0]},
  {time = 1.5, position = [0.1, 0, 0.1], rotation = [0, 0, 10]},
]

[[action]]
kind = "push"
body = "toy"
start = 0.2
end = 0.2
velocity = [0, 1, 0]

[[action]]
kind = "push"
body = "toy"
start = 1
end = 1.5
force = [0, 0, 5]

[[action]]
kind = "wind"
start = 0.5
speed = 8
direction = [0, 1, 0]
gust = 0.5
gust_frequency = 2
turbulence = 0.1
drag_coefficient = 1.2

[[camera]]
name = "wide"
target = [0, 0, 0.2]
distance = 3
elevation = 15
azimuth = -45
degrees = 90
fov = 50

[[camera]]
kind = "fixed"
position = [2, -2, 1]
target = [0, 0, 0.1]

[[camera]]
name = "chase"
kind = "follow"
position = [1, 1, 1]
body = "brick"
fov = 30

[[camera]]
name = "flyby"
kind = "path"
fov = 35
keyframes = [
  {time = 0, position = [2, -2, 1], target = [0, 0, 0.2]},
  {time = 2.5, position = [2, 2, 1.5], target = [0, 0, 0.3]},
]

[[camera]]
name = "high"
kind = "three-quarter"
elevation = 40
fov = 45

[[camera]]
kind = "top"

[look]
ground_colors = [[0.9, 0.9, 0.9], [0.2, 0.2, 0.25]]
square = 0.25
light = [1, 0, 2]
ambient = 0.2
diffuse = 0.8
shadows = false
sky = [0.5, 0.6, 0.7]
collider_color = [0.3, 0.3, 1]
"""


def _files(root):
    """What the scenes of these tests refer to: two mesh files, an asset directory and a non-asset one."""
    (root / "parts").mkdir(exist_ok=True)
    (root / "parts" / "ball.obj").write_text("v 0 0 0\n")
    (root / "parts" / "rock.stl").write_text("solid rock\nendsolid rock\n")
    (root / "assets" / "toy").mkdir(parents=True, exist_ok=True)
    (root / "assets" / "toy" / "asset.json").write_text("{}")
    (root / "empty").mkdir(exist_ok=True)


def _write(path, text: str):
    path.write_text(textwrap.dedent(text))
    return path


def test_a_full_file_reads_into_the_spec(tmp_path):
    _files(tmp_path)
    path = _write(tmp_path / "scene.toml", FULL)
    spec = read_scene(path)
    toy = str(tmp_path.resolve() / "assets" / "toy")
    f = str(path)
    assert spec.world == WorldSpec(
        fps=24.0,
        frames=60,
        substeps=4,
        gravity=9.8,
        ground=True,
        ground_friction=0.8,
        damping=0.001,
        drag=0.1,
        contact_gap=0.002,
        friction_velocity=0.02,
        settle=0.5,
    )
    assert spec.bodies == (
        BodySpec(
            name="brick",
            asset="lego",
            size=0.25,
            position=(0.0, 0.0, 0.5),
            rotation=(0.0, 0.0, 45.0),
            material="foam",
            youngs=2e5,
            poisson=0.3,
            density=50.0,
            damping=0.01,
            friction=0.7,
            velocity=(1.0, 0.0, 0.0),
            spin=(0.0, 0.0, 3.0),
            color=(1.0, 0.5, 0.0),
            cage=CageSpec(target_tets=3000, margin=0.01),
            where=f"{f}: [[body]] #1 (brick)",
        ),
        BodySpec(
            name="body2",
            mesh=str(tmp_path.resolve() / "parts" / "ball.obj"),
            units="cm",
            position=(0.5, 0.0, 0.0),
            color=(0.1, 0.2, 0.3),
            where=f"{f}: [[body]] #2 (body2)",
        ),
        BodySpec(name="toy", asset=toy, where=f"{f}: [[body]] #3 (toy)"),
    )
    assert spec.colliders == (
        ColliderSpec(
            name="ramp",
            shape="box",
            position=(1.0, 0.0, 0.1),
            rotation=(0.0, 20.0, 0.0),
            half_extents=(0.5, 0.3, 0.1),
            friction=0.2,
            color=(0.0, 1.0, 0.25),
            where=f"{f}: [[collider]] #1 (ramp)",
        ),
        ColliderSpec(
            name="collider2",
            shape="sphere",
            position=(0.0, 1.0, 0.2),
            radius=0.2,
            where=f"{f}: [[collider]] #2 (collider2)",
        ),
        ColliderSpec(
            name="rock",
            shape="mesh",
            mesh=str(tmp_path.resolve() / "parts" / "rock.stl"),
            units="mm",
            scale=2.0,
            where=f"{f}: [[collider]] #3 (rock)",
        ),
    )
    assert spec.actions == (
        ActionSpec(
            kind="pin", start=0.0, end=1.0, body="brick", region=("z<10%",), where=f"{f}: [[action]] #1 (pin)"
        ),
        ActionSpec(
            kind="grab",
            start=0.5,
            end=2.0,
            body="body2",
            region=("x>90%", "z >= 0.05"),
            keyframes=(
                Keyframe(1.0, (0.05, 0.0, 0.0)),
                Keyframe(1.5, (0.1, 0.0, 0.1), (0.0, 0.0, 10.0)),
            ),
            where=f"{f}: [[action]] #2 (grab)",
        ),
        ActionSpec(
            kind="push",
            start=0.2,
            end=0.2,
            body="toy",
            velocity=(0.0, 1.0, 0.0),
            where=f"{f}: [[action]] #3 (push)",
        ),
        ActionSpec(
            kind="push",
            start=1.0,
            end=1.5,
            body="toy",
            force=(0.0, 0.0, 5.0),
            where=f"{f}: [[action]] #4 (push)",
        ),
        ActionSpec(
            kind="wind",
            start=0.5,
            end=2.5,
            speed=8.0,
            direction=(0.0, 1.0, 0.0),
            gust=0.5,
            gust_frequency=2.0,
            turbulence=0.1,
            drag_coefficient=1.2,
            where=f"{f}: [[action]] #5 (wind)",
        ),
    )
    assert spec.cameras == (
        CameraSpec(
            name="wide",
            kind="orbit",
            target=(0.0, 0.0, 0.2),
            distance=3.0,
            elevation=15.0,
            azimuth=-45.0,
            degrees=90.0,
            fov=50.0,
            where=f"{f}: [[camera]] #1 (wide)",
        ),
        CameraSpec(
            name="camera2",
            kind="fixed",
            position=(2.0, -2.0, 1.0),
            target=(0.0, 0.0, 0.1),
            where=f"{f}: [[camera]] #2 (camera2)",
        ),
        CameraSpec(
            name="chase",
            kind="follow",
            position=(1.0, 1.0, 1.0),
            body="brick",
            fov=30.0,
            where=f"{f}: [[camera]] #3 (chase)",
        ),
        CameraSpec(
            name="flyby",
            kind="path",
            fov=35.0,
            keyframes=(
                CameraKeyframe(0.0, (2.0, -2.0, 1.0), (0.0, 0.0, 0.2)),
                CameraKeyframe(2.5, (2.0, 2.0, 1.5), (0.0, 0.0, 0.3)),
            ),
            where=f"{f}: [[camera]] #4 (flyby)",
        ),
        CameraSpec(
            name="high", kind="three-quarter", elevation=40.0, fov=45.0, where=f"{f}: [[camera]] #5 (high)"
        ),
        CameraSpec(name="camera6", kind="top", where=f"{f}: [[camera]] #6 (camera6)"),
    )
    assert spec.look == LookSpec(
        ground_colors=((0.9, 0.9, 0.9), (0.2, 0.2, 0.25)),
        square=0.25,
        light=(1.0, 0.0, 2.0),
        ambient=0.2,
        diffuse=0.8,
        shadows=False,
        sky=((0.5, 0.6, 0.7),),
        collider_color=(0.3, 0.3, 1.0),
    )
    assert type(spec.look.collider_color[2]) is float and type(spec.look.light[0]) is float
    assert type(spec.bodies[0].color[1]) is float and type(spec.colliders[0].color[0]) is float
    assert spec.path == str(path.resolve())
    assert spec.body("toy").asset == toy


def test_defaults(tmp_path):
    path = _write(
        tmp_path / "s.toml",
        """
        [[body]]
        asset = "lego"
        [[collider]]
        shape = "sphere"
        radius = 1
        [[action]]
        kind = "pin"
        body = "body1"
        [[action]]
        kind = "wind"
        speed = 3
        [[camera]]
        """,
    )
    spec = read_scene(path)
    f = str(path)
    assert spec == SceneSpec(
        path=str(path.resolve()),
        world=WorldSpec(
            fps=30.0,
            frames=60,
            substeps=8,
            gravity=9.81,
            ground=True,
            ground_friction=0.5,
            damping=0.0,
            drag=0.0,
            contact_gap=0.001,
            friction_velocity=0.01,
        ),
        bodies=(
            BodySpec(
                name="body1",
                asset="lego",
                mesh=None,
                units="m",
                size=None,
                position=(0.0, 0.0, 0.0),
                rotation=(0.0, 0.0, 0.0),
                material="rubber",
                youngs=None,
                poisson=None,
                density=None,
                damping=None,
                friction=0.5,
                velocity=(0.0, 0.0, 0.0),
                spin=(0.0, 0.0, 0.0),
                cage=CageSpec(target_tets=None, margin=None),
                where=f"{f}: [[body]] #1 (body1)",
            ),
        ),
        colliders=(
            ColliderSpec(
                name="collider1",
                shape="sphere",
                position=(0.0, 0.0, 0.0),
                rotation=(0.0, 0.0, 0.0),
                half_extents=None,
                radius=1.0,
                mesh=None,
                units="m",
                scale=1.0,
                friction=0.5,
                where=f"{f}: [[collider]] #1 (collider1)",
            ),
        ),
        actions=(
            ActionSpec(kind="pin", start=0.0, end=2.0, body="body1", where=f"{f}: [[action]] #1 (pin)"),
            ActionSpec(
                kind="wind",
                start=0.0,
                end=2.0,
                body=None,
                speed=3.0,
                direction=(1.0, 0.0, 0.0),
                gust=0.3,
                gust_frequency=1.0,
                turbulence=0.3,
                drag_coefficient=1.0,
                where=f"{f}: [[action]] #2 (wind)",
            ),
        ),
        cameras=(
            CameraSpec(
                name="camera1",
                kind="orbit",
                position=None,
                target=None,
                distance=None,
                elevation=20.0,
                azimuth=30.0,
                degrees=30.0,
                fov=40.0,
                body=None,
                where=f"{f}: [[camera]] #1 (camera1)",
            ),
        ),
        look=LookSpec(
            ground_colors=((0.82, 0.82, 0.8), (0.62, 0.63, 0.62)),
            square=0.1,
            light=(0.35, 0.5, 1.0),
            ambient=0.35,
            diffuse=0.65,
            shadows=True,
            sky=((0.62, 0.74, 0.9), (0.93, 0.94, 0.96)),
            collider_color=(0.78, 0.52, 0.36),
        ),
    )


def test_a_sky_is_one_colour_or_two(tmp_path):
    path = _write(tmp_path / "s.toml", BODY + "[look]\nsky = [[1, 1, 1], [0, 0, 0.5]]\n")
    assert read_scene(path).look.sky == ((1.0, 1.0, 1.0), (0.0, 0.0, 0.5))
    path.write_text(BODY + "[look]\nsky = [1, 1, 1]\n")
    assert read_scene(path).look.sky == ((1.0, 1.0, 1.0),)


def test_frames_from_a_duration_and_ints_for_floats(tmp_path):
    path = _write(tmp_path / "s.toml", '[world]\nfps = 24\nframes = 7\n[[body]]\nasset = "lego"\nsize = 1\n')
    spec = read_scene(path)
    assert (spec.world.fps, spec.world.frames, spec.bodies[0].size) == (24.0, 7, 1.0)
    assert type(spec.world.fps) is float and type(spec.bodies[0].size) is float
    path.write_text('[world]\nfps = 25\nduration = 1.5\n[[body]]\nasset = "lego"\n')
    assert read_scene(path).world.frames == 38  # round(37.5), to even


def test_paths_are_relative_to_the_scene_file(tmp_path, monkeypatch):
    _files(tmp_path)
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "toy").mkdir()
    (tmp_path / "scenes" / "toy" / "asset.json").write_text("{}")
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "lego").mkdir(
        parents=True
    )  # a directory named like a shipped asset in the working directory
    (elsewhere / "assets" / "toy").mkdir(parents=True)
    monkeypatch.chdir(elsewhere)
    path = _write(
        tmp_path / "scenes" / "s.toml",
        """
        [[body]]
        asset = "toy"
        [[body]]
        asset = "../assets/toy"
        [[body]]
        asset = "lego"
        [[body]]
        mesh = "../parts/ball.obj"
        [[collider]]
        shape = "mesh"
        mesh = "../parts/rock.stl"
        """,
    )
    spec = read_scene("../scenes/s.toml")
    root = tmp_path.resolve()
    assert [b.asset for b in spec.bodies[:3]] == [
        str(root / "scenes" / "toy"),
        str(root / "assets" / "toy"),
        "lego",
    ]
    assert spec.bodies[3].mesh == str(root / "parts" / "ball.obj")
    assert spec.colliders[0].mesh == str(root / "parts" / "rock.stl")
    assert spec.path == str(path.resolve())
    assert spec.bodies[0].where == "../scenes/s.toml: [[body]] #1 (body1)"


BODY = '[[body]]\nname = "lego"\nasset = "lego"\n'
PIN = BODY + '[[action]]\nkind = "pin"\nbody = "lego"\n'
GRAB = BODY + '[[action]]\nkind = "grab"\nbody = "lego"\nend = 1\n'
PUSH = BODY + '[[action]]\nkind = "push"\nbody = "lego"\nend = 1\n'
WIND = BODY + '[[action]]\nkind = "wind"\n'
PATH = BODY + '[[camera]]\nname = "p"\nkind = "path"\n'
KEY0 = "{time = 0, position = [1, 0, 0], target = [0, 0, 0]}"
RAMP = '[[collider]]\nname = "ramp"\nshape = "sphere"\nradius = 1\n'
LOOK = BODY + "[look]\n"


MALFORMED = [
    ("[world]\nfps = \n" + BODY, "not valid TOML: Invalid value (at line 2, column 7)"),
    ("[wrld]\nfps = 30\n" + BODY, ": [wrld]: unknown table; did you mean [world]?"),
    ("[[bodies]]\nasset = 'lego'\n", ": [[bodies]]: unknown table; did you mean [[body]]?"),
    ("fps = 30\n" + BODY, ": fps: unknown key outside any table (expected [world], [[body]]"),
    ("[body]\nasset = 'lego'\n", ": [[body]]: expected an array of tables [[body]], got a table"),
    ("[[world]]\n" + BODY, ": [world]: expected a table [world], got [a table]"),
    ("[world]\nfsp = 30\n" + BODY, "[world] fsp: unknown key; did you mean fps?"),
    ('[world]\n"two words" = 1\n' + BODY, "[world] 'two words': unknown key (expected fps, duration"),
    ("[world]\ngravity = true\n" + BODY, "[world] gravity: expected a number, got true"),
    ("[world]\ngravity = -1\n" + BODY, "[world] gravity: must be >= 0, got -1"),
    ("[world]\nfps = 0\n" + BODY, "[world] fps: must be in (0, 1000], got 0"),
    ("[world]\nfps = inf\n" + BODY, "[world] fps: expected a finite number, got inf"),
    ("[world]\nduration = 1\nframes = 30\n" + BODY, "[world] frames: give duration or frames, not both"),
    (
        "[world]\nduration = 0.001\n" + BODY,
        "[world] duration: 0.001 s at 30 fps is 0 frames, not in [1, 10000]",
    ),
    ("[world]\nframes = 0\n" + BODY, "[world] frames: must be in [1, 10000], got 0"),
    ("[world]\nframes = 60.0\n" + BODY, "[world] frames: expected an integer, got 60.0"),
    ("[world]\nsubsteps = 1001\n" + BODY, "[world] substeps: must be in [1, 1000], got 1001"),
    ("[world]\nground = 'yes'\n" + BODY, "[world] ground: expected true or false, got 'yes'"),
    ("[world]\ncontact_gap = 0.5\n" + BODY, "[world] contact_gap: must be in (0, 0.1], got 0.5"),
    ("[world]\nground_friction = 11\n" + BODY, "[world] ground_friction: must be in [0, 10], got 11"),
    ("[world]\nfps = 30\n", ": [[body]]: missing; a scene needs at least one body"),
    ("[[body]]\nname = 'b'\n", "[[body]] #1 (b) asset: missing (or give a mesh)"),
    (
        "[[body]]\nasset = 'lego'\nmesh = 'parts/ball.obj'\n",
        "[[body]] #1 (body1) asset: give asset or mesh, not both",
    ),
    ("[[body]]\nname = 'ghost'\nasset = 'ghost'\n", "[[body]] #1 (ghost) asset: asset '"),
    ("[[body]]\nasset = 'empty'\n", "[[body]] #1 (body1) asset: "),
    ("[[body]]\nmesh = 'parts/none.obj'\n", "[[body]] #1 (body1) mesh: no such file "),
    (BODY + "units = 'cm'\n", "[[body]] #1 (lego) units: not a key of an asset body, only of a mesh body"),
    (
        "[[body]]\nmesh = 'parts/ball.obj'\nunits = 'km'\n",
        "(body1) units: 'km' is not one of m, cm, mm, in, ft",
    ),
    (BODY + "material = 'rubbr'\n", "(lego) material: 'rubbr' is not one of jelly, foam, rubber"),
    (BODY + "poisson = 0.5\n", "[[body]] #1 (lego) poisson: must be in (-1, 0.5), got 0.5"),
    (BODY + "density = 0\n", "[[body]] #1 (lego) density: must be in [1, 100000], got 0"),
    (BODY + "youngs = -1e5\n", "[[body]] #1 (lego) youngs: must be in [100, 2e+12], got -100000.0"),
    (BODY + "size = 0\n", "[[body]] #1 (lego) size: must be > 0, got 0"),
    (BODY + "friction = -0.1\n", "[[body]] #1 (lego) friction: must be in [0, 10], got -0.1"),
    (BODY + "position = [0, 0]\n", "[[body]] #1 (lego) position: expected 3 numbers [x, y, z], got [0, 0]"),
    (
        BODY + "velocity = [0, nan, 0]\n",
        "(lego) velocity: expected 3 finite numbers [x, y, z], got [0, nan, 0]",
    ),
    (BODY + "spin = [0, true, 0]\n", "[[body]] #1 (lego) spin: expected 3 finite numbers"),
    (
        BODY + "position = [0, 0, -0.1]\n",
        "[[body]] #1 (lego) position: z = -0.1 m puts the body's bottom below the ground (z = 0)",
    ),
    (
        BODY + "[body.cage]\ntarget_tet = 900\n",
        "(lego) cage.target_tet: unknown key; did you mean target_tets?",
    ),
    (BODY + "[body.cage]\ntarget_tets = 5\n", "[[body]] #1 (lego) cage.target_tets: must be >= 10, got 5"),
    (BODY + "cage = 3\n", "[[body]] #1 (lego) cage: expected a table [body.cage], got 3"),
    (BODY + "name2 = 'x'\n", "[[body]] #1 (lego) name2: unknown key; did you mean name?"),
    ("[[body]]\nname = ''\nasset = 'lego'\n", "[[body]] #1 name: expected a non-empty string of printable"),
    ('[[body]]\nname = "a\\nb"\nasset = "lego"\n', "[[body]] #1 name: expected a non-empty string"),
    (BODY + BODY, "[[body]] #2 (lego) name: 'lego' is already the name of [[body]] #1"),
    (BODY + "[[collider]]\nname = 'lego'\nshape = 'box'\n", "[[collider]] #1 (lego) name: 'lego' is already"),
    (BODY + "[[collider]]\nshape = 'box'\n", "[[collider]] #1 (collider1) half_extents: missing"),
    (
        BODY + "[[collider]]\nshape = 'box'\nhalf_extents = [1, 0, 1]\n",
        "(collider1) half_extents: must all be > 0, got [1, 0, 1]",
    ),
    (
        BODY + "[[collider]]\nshape = 'sphere'\nradius = -1\n",
        "[[collider]] #1 (collider1) radius: must be > 0",
    ),
    (
        BODY + "[[collider]]\nshape = 'box'\nhalf_extents = [1, 1, 1]\nradius = 1\n",
        "[[collider]] #1 (collider1) radius: not a key of a box collider, only of a sphere collider",
    ),
    (BODY + "[[collider]]\nshape = 'cone'\n", "[[collider]] #1 (collider1) shape: 'cone' is not one of box"),
    (BODY + "[[collider]]\nradius = 1\n", "[[collider]] #1 (collider1) shape: missing"),
    (
        BODY + "[[collider]]\nshape = 'mesh'\nmesh = 'no.obj'\n",
        "[[collider]] #1 (collider1) mesh: no such file",
    ),
    (BODY + "[[action]]\nbody = 'lego'\n", "[[action]] #1 kind: missing"),
    (BODY + "[[action]]\nkind = 'pinn'\n", "[[action]] #1 kind: 'pinn' is not one of pin, grab, push, wind"),
    (BODY + "[[action]]\nkind = 'pin'\n", "[[action]] #1 (pin) body: missing"),
    (
        BODY + "[[action]]\nkind = 'pin'\nbody = 'lgo'\n",
        "(pin) body: no body named 'lgo'; did you mean 'lego'?",
    ),
    (
        BODY + RAMP + "[[action]]\nkind = 'pin'\nbody = 'ramp'\n",
        "[[action]] #1 (pin) body: 'ramp' is [[collider]] #1, not a body",
    ),
    (PIN + "start = 1\nend = 0.5\n", "[[action]] #1 (pin) end: 0.5 s must be after start (1 s)"),
    (PIN + "start = 2\n", "[[action]] #1 (pin) start: 2 s is not before the end of the shot (2 s)"),
    (PIN + "start = -1\n", "[[action]] #1 (pin) start: must be >= 0, got -1"),
    (PIN + "region = 'q<1'\n", "[[action]] #1 (pin) region: 'q<1': expected AXIS OP VALUE"),
    (PIN + "region = [1]\n", "[[action]] #1 (pin) region: expected a rule such as 'z<10%'"),
    (PIN + "speed = 3\n", "[[action]] #1 (pin) speed: not a key of a pin action, only of a wind action"),
    (GRAB, "[[action]] #1 (grab) keyframes: missing (a grab moves along its keyframes)"),
    (GRAB + "keyframes = []\n", "[[action]] #1 (grab) keyframes: expected an array of tables"),
    (
        GRAB + "keyframes = [{time = 2}]\n",
        "[[action]] #1 (grab) keyframes #1 time: 2 s must be after start (0 s) and at most end (1 s)",
    ),
    (
        GRAB + "keyframes = [{time = 0.5}, {time = 0.2}]\n",
        "(grab) keyframes #2 time: 0.2 s must be after keyframe #1 (0.5 s)",
    ),
    (
        GRAB + "keyframes = [{time = 0.5, positon = [0, 0, 1]}]\n",
        "keyframes #1 positon: unknown key; did you mean position?",
    ),
    (GRAB + "keyframes = [{position = [0, 0, 1]}]\n", "[[action]] #1 (grab) keyframes #1 time: missing"),
    (PUSH + "velocity = [1, 0, 0]\nforce = [1, 0, 0]\n", "(push) velocity: give velocity or force, not both"),
    (PUSH, "[[action]] #1 (push) velocity: missing (or give a force)"),
    (
        PUSH + "velocity = [1, 0, 0]\nkeyframes = [{time = 0.5}]\n",
        "[[action]] #1 (push) keyframes: not a key of a push action, only of a grab action",
    ),
    (PUSH + "start = 1\nforce = [0, 0, 1]\n", "[[action]] #1 (push) end: 1 s must be after start (1 s)"),
    (BODY + "[[action]]\nkind = 'push'\nbody = 'lego'\nforce = [1, 0, 0]\n", "(push) end: missing"),
    (WIND, "[[action]] #1 (wind) speed: missing"),
    (
        WIND + "speed = 5\ndirection = [0, 0, 1]\n",
        "[[action]] #1 (wind) direction: must be horizontal and not zero, [x, y, 0], got [0, 0, 1]",
    ),
    (WIND + "speed = 5\ngust = 2\n", "[[action]] #1 (wind) gust: must be in [0, 1], got 2"),
    (
        WIND + "speed = 5\nregion = 'z<1'\n",
        "[[action]] #1 (wind) region: not a key of a wind action, only of a pin/grab/push action",
    ),
    (
        BODY + "[[camera]]\nname = 'c'\nkind = 'follow'\nposition = [1, 1, 1]\nbody = 'x'\n",
        "(c) body: no body named 'x'",
    ),
    (BODY + "[[camera]]\nkind = 'follow'\nposition = [1, 1, 1]\n", "[[camera]] #1 (camera1) body: missing"),
    (BODY + "[[camera]]\nkind = 'fixed'\n", "[[camera]] #1 (camera1) position: missing"),
    (BODY + "[[camera]]\nkind = 'fixed'\nposition = [1, 1, 1]\ntarget = [1, 1, 1]\n", "target: must differ"),
    (BODY + "[[camera]]\nfov = 180\n", "[[camera]] #1 (camera1) fov: must be in (0, 180), got 180"),
    (
        BODY + "[[camera]]\nelevation = 91\n",
        "[[camera]] #1 (camera1) elevation: must be in [-90, 90], got 91",
    ),
    (
        BODY + "[[camera]]\nposition = [1, 1, 1]\n",
        "[[camera]] #1 (camera1) position: not a key of an orbit camera, only of a fixed/follow camera",
    ),
    (BODY + "[[camera]]\nname = 'c'\n[[camera]]\nname = 'c'\n", "[[camera]] #2 (c) name: 'c' is already"),
    (BODY + "[[camera]]\nkind = 'pth'\n", "(camera1) kind: 'pth' is not one of orbit, fixed, follow, path"),
    (PATH, "[[camera]] #1 (p) keyframes: missing (a path camera moves along its keyframes)"),
    (
        PATH + f"keyframes = [{KEY0}]\n",
        "[[camera]] #1 (p) keyframes: expected an array of at least 2 tables {time = .., position = [..], "
        "target = [..]}, got [a table]",
    ),
    (PATH + "keyframes = 3\n", "[[camera]] #1 (p) keyframes: expected an array of at least 2 tables"),
    (
        PATH + f"keyframes = [{KEY0}, {KEY0}]\n",
        "[[camera]] #1 (p) keyframes #2 time: 0 s must be after keyframe #1 (0 s)",
    ),
    (
        PATH + f"keyframes = [{{time = -1, position = [1, 0, 0], target = [0, 0, 0]}}, {KEY0}]\n",
        "[[camera]] #1 (p) keyframes #1 time: must be >= 0, got -1",
    ),
    (
        PATH + f"keyframes = [{KEY0}, {{time = 1, position = [1, 0, 0]}}]\n",
        "[[camera]] #1 (p) keyframes #2 target: missing",
    ),
    (
        PATH + f"keyframes = [{{position = [1, 0, 0], target = [0, 0, 0]}}, {KEY0}]\n",
        "[[camera]] #1 (p) keyframes #1 time: missing",
    ),
    (
        PATH + f"keyframes = [{KEY0}, {{time = 1, position = [0, 1, 0], target = [0, 1, 0]}}]\n",
        "[[camera]] #1 (p) keyframes #2 target: must differ from position",
    ),
    (
        PATH + f"keyframes = [{KEY0}, {{time = 1, position = [0, 1], target = [0, 0, 0]}}]\n",
        "[[camera]] #1 (p) keyframes #2 position: expected 3 numbers [x, y, z], got [0, 1]",
    ),
    (
        PATH + f"keyframes = [{KEY0}, {{time = 1, position = [0, 1, 0], targte = [0, 0, 0]}}]\n",
        "[[camera]] #1 (p) keyframes #2 targte: unknown key; did you mean target?",
    ),
    (
        PATH + f"keyframes = [{KEY0}, {{time = 1, position = [0, 1, 0], target = [0, 0, 0], fov = 30}}]\n",
        "[[camera]] #1 (p) keyframes #2 fov: unknown key (expected time, position, target)",
    ),
    (
        PATH + "position = [1, 1, 1]\n",
        "[[camera]] #1 (p) position: not a key of a path camera, only of a fixed/follow camera",
    ),
    (
        BODY + f"[[camera]]\nkeyframes = [{KEY0}, {KEY0}]\n",
        "[[camera]] #1 (camera1) keyframes: not a key of an orbit camera, only of a path camera",
    ),
    (
        BODY + "[[camera]]\nkind = 'front'\nposition = [1, 1, 1]\n",
        "[[camera]] #1 (camera1) position: not a key of a front camera, only of a fixed/follow camera",
    ),
    (
        BODY + "[[camera]]\nkind = 'top'\ntarget = [0, 0, 0]\n",
        "[[camera]] #1 (camera1) target: not a key of a top camera, only of an orbit/fixed camera",
    ),
    (
        BODY + "[[camera]]\nkind = 'side'\nelevation = 10\n",
        "(camera1) elevation: not a key of a side camera, only of an orbit/three-quarter camera",
    ),
    (
        BODY + "[[camera]]\nkind = 'three-quarter'\nelevation = -91\n",
        "[[camera]] #1 (camera1) elevation: must be in [-90, 90], got -91",
    ),
    (
        BODY + "[[camera]]\nkind = 'three-quartr'\n",
        "(camera1) kind: 'three-quartr' is not one of orbit, fixed, follow, path, capture, front, side, top, "
        "three-quarter; did you mean 'three-quarter'?",
    ),
    ("[[look]]\nsquare = 1\n" + BODY, ": [look]: expected a table [look], got [a table]"),
    (
        LOOK + "obstacle_color = [1, 0, 0]\n",
        "[look] obstacle_color: unknown key; did you mean collider_color?",
    ),
    (
        LOOK + "ground_colors = [[0.5, 0.5, 0.5]]\n",
        "[look] ground_colors: expected [[r, g, b], [r, g, b]], got [[0.5, 0.5, 0.5]]",
    ),
    (
        LOOK + "ground_colors = [[0.5, 0.5], [0.5, 0.5, 0.5]]\n",
        "[look] ground_colors: expected [[r, g, b], [r, g, b]], got [[0.5, 0.5], [0.5, 0.5, 0.5]]",
    ),
    (
        LOOK + "ground_colors = [[0.5, 0.5, 0.5], [1.5, 0, 0]]\n",
        "[look] ground_colors: must all be in [0, 1], got [[0.5, 0.5, 0.5], [1.5, 0, 0]]",
    ),
    (LOOK + "sky = [0.5, 0.5]\n", "[look] sky: expected [r, g, b] or [[r, g, b], [r, g, b]], got [0.5, 0.5]"),
    (LOOK + "sky = [[1, 1, 1], [1, 1, 1], [1, 1, 1]]\n", "[look] sky: expected [r, g, b] or [[r, g, b]"),
    (
        LOOK + "sky = [1, true, 1]\n",
        "[look] sky: expected [r, g, b] or [[r, g, b], [r, g, b]], got [1, true, 1]",
    ),
    (LOOK + "sky = [0, 0, nan]\n", "[look] sky: must all be in [0, 1], got [0, 0, nan]"),
    (
        LOOK + "collider_color = [0, 0, -0.1]\n",
        "[look] collider_color: must all be in [0, 1], got [0, 0, -0.1]",
    ),
    (LOOK + "collider_color = [[0, 0, 0]]\n", "[look] collider_color: expected [r, g, b], got [[0, 0, 0]]"),
    (LOOK + "light = [0, 0, 0]\n", "[look] light: must not be zero, got [0, 0, 0]"),
    (LOOK + "light = [0, 1]\n", "[look] light: expected 3 numbers [x, y, z], got [0, 1]"),
    (LOOK + "ambient = -0.1\n", "[look] ambient: must be >= 0, got -0.1"),
    (LOOK + "diffuse = 'high'\n", "[look] diffuse: expected a number, got 'high'"),
    (LOOK + "square = 0\n", "[look] square: must be > 0, got 0"),
    ("[world]\nsettle = -0.5\n" + BODY, "[world] settle: must be in [0, 60], got -0.5"),
    ("[world]\nsettle = '1 s'\n" + BODY, "[world] settle: expected a number, got '1 s'"),
    (BODY + "color = [1, 1.5, 0]\n", "[[body]] #1 (lego) color: must all be in [0, 1], got [1, 1.5, 0]"),
    (BODY + "color = [-0.1, 0, 0]\n", "[[body]] #1 (lego) color: must all be in [0, 1], got [-0.1, 0, 0]"),
    (BODY + "color = [1, 1]\n", "[[body]] #1 (lego) color: expected [r, g, b], got [1, 1]"),
    (BODY + "color = [1, 1, 1, 1]\n", "[[body]] #1 (lego) color: expected [r, g, b], got [1, 1, 1, 1]"),
    (BODY + "color = 'red'\n", "[[body]] #1 (lego) color: expected [r, g, b], got 'red'"),
    (BODY + "colour = [1, 1, 1]\n", "[[body]] #1 (lego) colour: unknown key; did you mean color?"),
    (
        BODY + RAMP + "color = [2, 0, 0]\n",
        "[[collider]] #1 (ramp) color: must all be in [0, 1], got [2, 0, 0]",
    ),
    (
        BODY + RAMP + "color = [0, true, 0]\n",
        "[[collider]] #1 (ramp) color: expected [r, g, b], got [0, true, 0]",
    ),
    (LOOK + "shadows = 1\n", "[look] shadows: expected true or false, got 1"),
]


@pytest.mark.parametrize(("text", "expected"), MALFORMED)
def test_a_malformed_file_is_one_line_naming_the_table_and_key(tmp_path, text, expected):
    _files(tmp_path)
    path = _write(tmp_path / "scene.toml", text)
    assert expected in _one_line_error(path)


def _one_line_error(path) -> str:
    """The message of the :class:`SceneError` reading the scene file ``path`` raises, checked to be one line
    that starts with the file's name."""
    with pytest.raises(SceneError) as caught:
        read_scene(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    return message


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "cannot read the scene file (No such file or directory)"),
        ("dir", "cannot read the scene file (Is a directory)"),
        (b'[[body]]\nasset = "l\xe9go"\n', "not UTF-8 text (byte 0xe9 at offset 19)"),
    ],
)
def test_a_file_that_cannot_be_read(tmp_path, content, expected):
    path = tmp_path / "scene.toml"
    if content == "dir":
        path.mkdir()
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(SceneError, match="^" + str(path) + ": ") as caught:
        read_scene(path)
    assert str(caught.value) == f"{path}: {expected}"


def test_an_unknown_asset_names_the_shipped_ones(tmp_path):
    path = _write(tmp_path / "s.toml", "[[body]]\nasset = 'ghost'\n")
    with pytest.raises(SceneError) as caught:
        read_scene(path)
    assert "no shipped asset of that name" in str(caught.value) and "lego" in str(caught.value)
    _files(tmp_path)
    path.write_text("[[body]]\nasset = 'empty'\n")
    with pytest.raises(SceneError, match="is not an asset"):
        read_scene(path)


def test_a_utf8_bom_is_accepted(tmp_path):
    path = tmp_path / "s.toml"
    path.write_bytes(b"\xef\xbb\xbf" + BODY.encode())
    assert read_scene(path).bodies[0].asset == "lego"


def test_problem_formats_later_checks_the_same_way(tmp_path):
    path = _write(tmp_path / "s.toml", BODY + "[[action]]\nkind = 'pin'\nbody = 'lego'\nregion = 'z<-5'\n")
    action = read_scene(path).actions[0]
    error = problem(action.where, "region", "'z<-5' selects no cage vertex")
    assert isinstance(error, SceneError)
    assert str(error) == f"{path}: [[action]] #1 (pin) region: 'z<-5' selects no cage vertex"
    body = read_scene(path).bodies[0]
    assert str(problem(body.where, None, "overlaps body2")) == f"{path}: [[body]] #1 (lego): overlaps body2"


def _capture(path: Path, cameras: int = 3) -> Path:
    """A NeRF-synthetic camera file at ``path`` listing ``cameras`` cameras one unit apart, without images."""
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = [
        {
            "file_path": f"./r_{k}",
            "transform_matrix": [[1, 0, 0, k], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]],
        }
        for k in range(cameras)
    ]
    path.write_text(json.dumps({"camera_angle_x": 0.7, "w": 8, "h": 6, "frames": frames}))
    return path


def test_a_capture_camera_reads_its_file_relative_to_the_scene(tmp_path):
    _files(tmp_path)
    _capture(tmp_path / "captures" / "walk.json")
    _capture(tmp_path / "captures" / "lego" / "transforms_train.json", cameras=2)
    (tmp_path / "scenes").mkdir()
    path = _write(
        tmp_path / "scenes" / "s.toml",
        """
        [[body]]
        name = "ball"
        mesh = "../parts/ball.obj"
        [[body]]
        name = "lego"
        asset = "lego"
        [[camera]]
        name = "walk"
        kind = "capture"
        path = "../captures/walk.json"
        [[camera]]
        name = "exact"
        kind = "capture"
        path = "../captures/lego"
        body = "lego"
        smooth = 0
        fov = 50
        """,
    )
    captures, f = tmp_path.resolve() / "captures", str(path)
    assert read_scene(path).cameras == (
        CameraSpec(
            name="walk",
            kind="capture",
            fov=None,
            body="lego",  # the first asset body
            path=str(captures / "walk.json"),
            smooth=2.0,
            where=f"{f}: [[camera]] #1 (walk)",
        ),
        CameraSpec(
            name="exact",
            kind="capture",
            fov=50.0,
            body="lego",
            path=str(captures / "lego"),
            smooth=0.0,
            where=f"{f}: [[camera]] #2 (exact)",
        ),
    )


CAPTURE = '[[camera]]\nname = "walk"\nkind = "capture"\n'
MESH = '[[body]]\nname = "ball"\nmesh = "parts/ball.obj"\n'
WALK = MESH + BODY + CAPTURE + "path = 'walk.json'\n"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (BODY + CAPTURE, "[[camera]] #1 (walk) path: missing"),
        (BODY + CAPTURE + "path = 'nope.json'\n", "(walk) path: no such file or directory {root}/nope.json"),
        (
            BODY + CAPTURE + "path = 'one.json'\n",
            "(walk) path: {root}/one.json: lists 1 camera; a capture camera moves along at least 2",
        ),
        (BODY + CAPTURE + "path = 'bad.json'\n", "(walk) path: {root}/bad.json: malformed JSON"),
        (BODY + CAPTURE + "path = 'parts'\n", "(walk) path: {root}/parts: is a directory, not a camera file"),
        (WALK + "smooth = -1\n", "[[camera]] #1 (walk) smooth: must be >= 0, got -1"),
        (WALK + "smooth = 'more'\n", "[[camera]] #1 (walk) smooth: expected a number, got 'more'"),
        (
            WALK + "body = 'ball'\n",
            "(walk) body: 'ball' is a mesh body; a capture's cameras are in an asset's",
        ),
        (WALK + "body = 'lgo'\n", "[[camera]] #1 (walk) body: no body named 'lgo'; did you mean 'lego'?"),
        (MESH + CAPTURE + "path = 'walk.json'\n", "(walk) body: missing: no [[body]] is an asset"),
        (WALK + "keyframes = []\n", "(walk) keyframes: not a key of a capture camera, only of a path camera"),
        (BODY + "[[camera]]\nsmooth = 1\n", "smooth: not a key of an orbit camera, only of a capture camera"),
        (
            BODY + "[[camera]]\nkind = 'fixed'\npath = 'walk.json'\n",
            "(camera1) path: not a key of a fixed camera, only of a capture camera",
        ),
    ],
)
def test_a_wrong_capture_camera_is_one_line_naming_the_key(tmp_path, text, expected):
    _files(tmp_path)
    _capture(tmp_path / "walk.json")
    _capture(tmp_path / "one.json", cameras=1)
    (tmp_path / "bad.json").write_text("{frames: []")
    path = _write(tmp_path / "scene.toml", text)
    assert expected.format(root=tmp_path.resolve()) in _one_line_error(path)


EXAMPLE_SCENES = sorted((Path(__file__).parent.parent / "examples" / "scenes").glob("*.toml"))


@pytest.mark.parametrize("path", EXAMPLE_SCENES, ids=[p.stem for p in EXAMPLE_SCENES])
def test_every_example_scene_reads(path):
    """The shipped example scenes stay valid as the schema changes (their runs: bench/scene_bench.py)."""
    spec = read_scene(path)
    assert spec.bodies and spec.world.frames >= 1
    for body in spec.bodies:
        assert body.mesh is None or Path(body.mesh).is_file()
