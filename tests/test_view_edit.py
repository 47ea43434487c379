"""The viewer's scene editor (shellsim.view.edit): edits written back with the file's comments and key order
kept, reading back to the original spec but for the edited fields; only its own file written; names that
are not the file's refused."""

from __future__ import annotations

import dataclasses

import pytest
import trimesh

from shellsim.shot.file import read_scene
from shellsim.shot.spec import ActionSpec, CameraSpec, SceneError
from shellsim.view.edit import SceneEditor, action_keys

SCENE = """\
# A cube on a cube, for the editor's tests.

[world]
duration = 1.0   # seconds
substeps = 2

[[body]]
name = "base"
mesh = "cube.stl"
size = 0.2
position = [0, 0, 0]   # on the ground
material = "foam"

[body.cage]
target_tets = 50   # coarse

# the unnamed one is body2
[[body]]
mesh = "cube.stl"
size = 0.1
rotation = [0, 0, 10]
position = [0, 0, 0.3]

[[collider]]
shape = "box"
position = [0.5, 0, 0.05]
half_extents = [0.05, 0.05, 0.05]

[[camera]]
name = "front"
kind = "fixed"
position = [0.6, -0.65, 0.55]
target = [0, 0, 0.2]

[look]
square = 0.2
"""


@pytest.fixture
def scene(tmp_path):
    trimesh.creation.box((1, 1, 1)).export(tmp_path / "cube.stl")
    path = tmp_path / "shot.toml"
    path.write_text(SCENE)
    return path


def test_poses_are_saved_with_comments_and_key_order_kept_and_the_rest_unchanged(scene):
    before = read_scene(scene)
    editor = SceneEditor(scene)
    editor.set_pose("base", position=(0.1, -0.2, 0.0))
    editor.set_pose("body2", position=[0.0, 0.05, 0.25], rotation=[5, 0, 45])
    editor.set_pose("collider1", rotation=(0, 0, 30))
    saved = editor.save()

    text = scene.read_text()
    for comment in ("# A cube on a cube", "# seconds", "# on the ground", "# coarse", "# the unnamed one"):
        assert comment in text
    # the keys stay where they were: position before material in base, rotation before position in body2
    first, second = text.split("[[body]]")[1:3]
    assert first.index("position = [0.1, -0.2, 0.0]") < first.index("material")
    assert second.index("rotation = [5.0, 0.0, 45.0]") < second.index("position = [0.0, 0.05, 0.25]")
    assert "rotation" in text.split("[[collider]]")[1]

    after = read_scene(scene)
    assert after == saved
    expected = dataclasses.replace(
        before,
        bodies=(
            dataclasses.replace(before.bodies[0], position=(0.1, -0.2, 0.0)),
            dataclasses.replace(before.bodies[1], position=(0.0, 0.05, 0.25), rotation=(5.0, 0.0, 45.0)),
        ),
        colliders=(dataclasses.replace(before.colliders[0], rotation=(0.0, 0.0, 30.0)),),
    )
    assert after == expected


def test_a_push_and_a_camera_are_appended_and_read_back(scene):
    before = read_scene(scene)
    editor = SceneEditor(scene)
    push = ActionSpec(
        kind="push",
        start=0.1,
        end=0.4,
        body="body2",
        region=("x >= -0.0100", "x <= 0.0100", "z >= 0.3500"),
        force=(0.5, 0.0, 1.25),
    )
    editor.add_action(push)
    assert editor.add_camera(None, (1.0, -1.0, 0.5), (0.0, 0.0, 0.1), fov=35.0) == "camera2"
    editor.add_camera("top view", (0.0, 0.0, 2.0), (0.0, 0.01, 0.0))
    editor.save()

    after = read_scene(scene)
    where = f"{after.path}: [[action]] #1 (push)"
    assert after.actions == (dataclasses.replace(push, where=where),)
    cameras = [
        CameraSpec(
            name="camera2",
            kind="fixed",
            position=(1.0, -1.0, 0.5),
            target=(0.0, 0.0, 0.1),
            fov=35.0,
            where=f"{after.path}: [[camera]] #2 (camera2)",
        ),
        CameraSpec(
            name="top view",
            kind="fixed",
            position=(0.0, 0.0, 2.0),
            target=(0.0, 0.01, 0.0),
            fov=40.0,
            where=f"{after.path}: [[camera]] #3 (top view)",
        ),
    ]
    assert after == dataclasses.replace(before, actions=after.actions, cameras=(*before.cameras, *cameras))
    assert "# A cube on a cube" in scene.read_text()
    # the keys of a push are those its kind takes
    assert action_keys(push) == {
        "kind": "push",
        "start": 0.1,
        "end": 0.4,
        "body": "body2",
        "region": list(push.region),
        "force": [0.5, 0.0, 1.25],
    }


def test_only_the_scene_file_is_written(scene, tmp_path):
    editor = SceneEditor(scene)
    assert editor.path == scene.resolve()
    editor.set_pose("base", position=(0, 0, 0.01))
    listing = {p: p.read_bytes() for p in tmp_path.iterdir() if p != scene}
    editor.save()
    assert {p: p.read_bytes() for p in tmp_path.iterdir() if p != scene} == listing  # nothing else, no temp
    with pytest.raises(TypeError):
        editor.save(tmp_path / "elsewhere.toml")  # the editor has no other path
    assert not hasattr(editor, "save_as")


@pytest.mark.parametrize("name", ["ghost", "front", "../etc/passwd", "", None, 3])
def test_a_name_that_is_not_a_body_or_collider_of_the_file_is_refused(scene, name):
    editor = SceneEditor(scene)
    with pytest.raises(ValueError, match="name: " + repr(name).replace("(", r"\(").replace(".", r"\.")):
        editor.set_pose(name, position=(0, 0, 0))


def test_bad_values_and_actions_on_unknown_bodies_are_refused(scene):
    editor = SceneEditor(scene)
    with pytest.raises(ValueError, match="position"):
        editor.set_pose("base", position=(0, float("nan"), 0))
    with pytest.raises(ValueError, match="rotation"):
        editor.set_pose("base", rotation=(0, 0))
    with pytest.raises(ValueError, match="'collider1'"):
        editor.add_action({"kind": "push", "body": "collider1", "end": 0.5, "force": [0, 0, 1]})
    with pytest.raises(ValueError, match="'front' is already"):
        editor.add_camera("front", (1, 1, 1), (0, 0, 0))
    with pytest.raises(ValueError, match="fov"):
        editor.add_camera("wide", (1, 1, 1), (0, 0, 0), fov=180)


def test_a_text_that_does_not_read_back_is_refused_in_one_line_and_the_file_kept(scene):
    editor = SceneEditor(scene)
    editor.set_pose("base", position=(0, 0, -0.5))  # below the ground: read_scene refuses it
    with pytest.raises(SceneError) as caught:
        editor.save()
    message = str(caught.value)
    assert "\n" not in message and message.startswith(str(scene.resolve()))
    assert "[[body]] #1 (base) position" in message and "not saved" in message and ".partial" not in message
    assert scene.read_text() == SCENE
    assert sorted(p.name for p in scene.parent.iterdir()) == ["cube.stl", "shot.toml"]


def test_a_file_changed_on_disk_since_it_was_opened_is_not_overwritten(scene):
    editor = SceneEditor(scene)
    editor.set_pose("base", position=(0, 0, 0.01))
    scene.write_text(SCENE.replace("substeps = 2", "substeps = 3"))
    with pytest.raises(SceneError, match="changed on disk"):
        editor.save()
    assert "substeps = 3" in scene.read_text()
