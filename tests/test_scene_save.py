"""A scene written back (shellsim.shot.save) reads to the same spec (shellsim.shot.file): every example
scene, and one that uses every kind of table and key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from shellsim.shot.file import read_scene
from shellsim.shot.save import scene_toml

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples" / "scenes").glob("*.toml"))


def plain(spec) -> dict:
    """The spec as a dict, without the file's path and the ``where`` of each part (both name the file)."""

    def strip(value):
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in ("where", "path")}
        if isinstance(value, list | tuple):
            return [strip(v) for v in value]
        return value

    return strip(dataclasses.asdict(spec))


def round_trip(spec, tmp_path):
    path = tmp_path / "saved.toml"
    path.write_text(scene_toml(spec))
    return read_scene(path)


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda p: p.stem)
def test_every_example_scene_reads_back_the_same(example, tmp_path):
    spec = read_scene(example)
    assert plain(round_trip(spec, tmp_path)) == plain(spec)


def test_every_kind_of_table_and_key_reads_back_the_same(tmp_path):
    import trimesh

    trimesh.creation.box((1, 1, 1)).export(tmp_path / "cube.stl")
    text = """
[world]
duration = 0.5
fps = 24
gravity = 3.5
ground_friction = 0.25
damping = 0.001
settle = 0.35

[[body]]
name = "lego"
asset = "lego"
up = [0, 1, 0]
size = 0.2
position = [0.1, -0.2, 0.03]
rotation = [10, 20, 30]
material = "jelly"
youngs = 20000.0
velocity = [0, 0, -1]
spin = [0, 0, 2]
color = [0.9, 0.8, 0.7]
[body.cage]
margin = 0.03

[[body]]
name = "cube"
mesh = "cube.stl"
units = "cm"
position = [0.5, 0.5, 0]
friction = 0.7
color = [0.1, 0.25, 1]

[[collider]]
name = "tray"
shape = "box"
position = [1, 0, 0.05]
half_extents = [0.2, 0.2, 0.05]

[[collider]]
shape = "sphere"
position = [-1, 0, 0.2]
radius = 0.1
color = [0, 0.5, 0.125]

[[collider]]
shape = "mesh"
mesh = "cube.stl"
scale = 0.2
position = [0, 2, 0.1]

[[action]]
kind = "pin"
body = "lego"
region = ["z<10%", "x>0"]
end = 0.2

[[action]]
kind = "grab"
body = "cube"
region = "z>50%"
start = 0.1
end = 0.4
keyframes = [{time = 0.2, position = [0, 0, 0.1]}, {time = 0.3, rotation = [0, 0, 45]}]

[[action]]
kind = "push"
body = "cube"
start = 0.2
end = 0.2
velocity = [1, 0, 0]

[[action]]
kind = "wind"
speed = 4
direction = [0, 1, 0]
gust = 0.5

[[camera]]
name = "orbit"
distance = 2

[[camera]]
name = "path"
kind = "path"
keyframes = [
    {time = 0, position = [1, 1, 1], target = [0, 0, 0]},
    {time = 0.5, position = [2, 1, 1], target = [0, 0, 0]},
]

[[camera]]
name = "follow"
kind = "follow"
body = "cube"
position = [1, 0, 0.5]

[look]
sky = [0.5, 0.6, 0.7]
shadows = false
collider_color = [0.2, 0.3, 0.4]
"""
    path = tmp_path / "every.toml"
    path.write_text(text)
    spec = read_scene(path)
    assert spec.bodies[0].up == (0.0, 1.0, 0.0) and spec.bodies[1].up is None
    assert spec.world.settle == 0.35 and spec.bodies[1].color == (0.1, 0.25, 1.0)
    assert spec.colliders[1].color == (0.0, 0.5, 0.125) and spec.colliders[0].color is None
    saved = scene_toml(spec)
    assert "settle = 0.35\n" in saved and "color = [0.9, 0.8, 0.7]\n" in saved
    assert plain(round_trip(spec, tmp_path)) == plain(spec)


def test_an_up_axis_of_zero_is_refused_naming_the_key(tmp_path):
    from shellsim.shot.spec import SceneError

    path = tmp_path / "zero.toml"
    path.write_text('[[body]]\nasset = "lego"\nup = [0, 0, 0]\n')
    with pytest.raises(
        SceneError, match=r"zero.toml: \[\[body\]\] #1 \(body1\) up: must be a non-zero vector"
    ):
        read_scene(path)
