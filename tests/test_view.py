"""``shellsim view``: targets told apart and refused in one line before a server starts, the displayed
meshes of a motion frame against barycentric interpolation of its cage, the page served, a stale motion
marked, and "Simulate in place" streaming frames into the timeline."""

from __future__ import annotations

import logging
import time
import urllib.request

import numpy as np
import pytest
from test_cli_runs import rod_asset

from shellsim.cli.main import main
from shellsim.motion.read import read_frames
from shellsim.tetcage.embed import interpolate

pytest.importorskip("viser")
pytest.importorskip("ipctk")

SCENE = """
[world]
frames = {frames}
substeps = 2

[[body]]
name = "r"
asset = "{asset}"
size = 0.3
material = "{material}"
position = [0, 0, 0.05]
velocity = [0.5, 0, 0]

[[collider]]
name = "wall"
shape = "box"
position = [1, 0, 0.2]
half_extents = [0.05, 0.5, 0.2]

[[camera]]
name = "side"
kind = "fixed"
position = [0, -2, 0.5]
"""


@pytest.fixture
def shot(tmp_path):
    """A scene file of the rod asset (hand-made cage and collision surface: nothing is built) and a box."""
    asset = rod_asset(tmp_path / "rod")
    path = tmp_path / "shot.toml"

    def write(frames: int = 3, material: str = "rubber"):
        path.write_text(SCENE.format(asset=asset, frames=frames, material=material))
        return path

    write()
    return write


@pytest.fixture
def viewer():
    from shellsim.view.viewer import Viewer

    v = Viewer(port=0, colors=False, picture=False)
    yield v
    v.close()


def expected(motion_path, k: int, asset_root) -> np.ndarray:
    """M+ of the rod at frame ``k``: the cage's own embedding of M+ interpolated in the frame's positions."""
    from neural.asset import load_asset
    from shellsim.tetcage.store import load_or_build_cage

    cage = load_or_build_cage(load_asset(asset_root))
    positions = read_frames(motion_path, [k])[0].astype(np.float64)
    return interpolate(positions, cage.tets, cage.outer_tet, cage.outer_bary)


def test_the_targets_are_told_apart(tmp_path, shot):
    from shellsim.view.state import target_kind

    path = shot()
    assert main(["scene", str(path)]) == 0
    assert target_kind(path) == "scene"
    assert target_kind(path.with_suffix("")) == "motion"
    assert target_kind(path.with_suffix("") / "motion.npz") == "motion"
    assert target_kind(tmp_path / "rod") == "asset"
    assert target_kind("lego") == "asset"


@pytest.mark.parametrize(
    "text, words",
    [
        ("[world\nfps = 30", "not valid TOML"),
        ('[[body]]\nasset = "no_such_asset_here"\n', "no_such_asset_here"),
    ],
)
def test_a_malformed_scene_file_is_one_line_exit_2_and_no_server(tmp_path, capsys, monkeypatch, text, words):
    import viser

    started = []
    monkeypatch.setattr(viser, "ViserServer", lambda *a, **k: started.append(a) or pytest.fail("started"))
    path = tmp_path / "bad.toml"
    path.write_text(text)
    capsys.readouterr()
    assert main(["view", str(path), "--no-browser", "--port", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"shellsim: error: {path}") and "\n" not in err and "Traceback" not in err
    assert words in err and not started


@pytest.mark.parametrize("target", ["missing.toml", "missing.npz", "no_such_asset", "a/b/missing"])
def test_a_missing_target_is_one_line_exit_2(tmp_path, capsys, target):
    capsys.readouterr()
    assert main(["view", str(tmp_path / target) if "/" in target else target, "--no-browser"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("shellsim: error:") and "\n" not in err and "Traceback" not in err


def test_a_missing_viser_is_one_line(tmp_path, shot, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "viser", None)  # import viser raises ImportError
    capsys.readouterr()
    assert main(["view", str(shot()), "--no-browser"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == 'shellsim: error: shellsim view needs viser: pip install -e ".[view]"'


def test_a_scene_without_motion_shows_its_bodies_at_rest_colliders_ground_and_cameras(shot):
    from shellsim.shot.file import read_scene
    from shellsim.view.state import load_state

    state = load_state(shot())
    assert state.kind == "scene" and state.n_frames == 1 and not state.shows_motion
    (body,) = state.bodies
    (shown,) = state.displayed(0)
    # the rest pose: M+ placed in the world by the body's placement
    np.testing.assert_allclose(shown, body.placement.to_world(body.asset.outer_mesh().vertices), atol=1e-9)
    assert state.built[0].surface_world[:, 2].min() == pytest.approx(0.05)  # placed by its visible surface
    (wall,) = state.colliders
    assert wall[0] == "wall" and np.allclose(wall[1].max(0), [1.05, 0.5, 0.4])
    (camera,) = state.cameras
    assert camera.name == "side" and np.allclose(camera.c2w[:3, 3], [0, -2, 0.5])
    spec = read_scene(shot())
    a, b = state.ground()
    assert len(a[1]) == len(b[1])  # as many squares of each colour (an even number a side)
    side = np.ptp(a[0][:4], axis=0)  # the four corners of one square
    np.testing.assert_allclose(side[:2], [spec.look.square] * 2)


def test_frame_k_moves_the_meshes_as_barycentric_interpolation_of_the_frame(shot, viewer, tmp_path):
    path = shot()
    assert main(["scene", str(path)]) == 0
    motion = path.with_suffix("") / "motion.npz"
    for target in (path, path.with_suffix(""), motion):
        viewer.open(target)
        assert viewer.n_frames == 3 and viewer.state.stale == ""
        for k in (2, 0, 1):
            viewer.frame(k)
            want = expected(motion, k, tmp_path / "rod")
            np.testing.assert_allclose(viewer.displayed("r"), want, atol=1e-5)  # float32 as sent
            np.testing.assert_allclose(viewer.state.displayed(k)[0], want, atol=1e-12)
        assert not np.allclose(expected(motion, 2, tmp_path / "rod"), expected(motion, 0, tmp_path / "rod"))
        with pytest.raises(ValueError, match="k: the timeline has frames 0..2"):
            viewer.frame(3)


def test_the_server_serves_the_page_on_a_free_port(shot, viewer):
    viewer.open(shot())
    assert viewer.url.startswith("http://127.0.0.1:") and not viewer.url.endswith(":0")
    with urllib.request.urlopen(viewer.url, timeout=10) as response:
        page = response.read().decode()
    assert "<html" in page.lower() and "viser" in page.lower()


def test_an_asset_alone_stands_on_the_ground_as_simulate_places_it(tmp_path, shot, viewer):
    viewer.open(tmp_path / "rod")
    state = viewer.state
    assert state.kind == "asset" and viewer.n_frames == 1 and state.motion is None
    (shown,) = state.displayed(0)
    assert np.ptp(shown, axis=0).max() > 0
    assert "simulate" not in viewer._gui  # only a scene file is simulated in place


def test_a_motion_of_another_version_of_the_scene_is_marked_stale(shot):
    from shellsim.view.state import load_state

    assert main(["scene", str(shot())]) == 0
    assert load_state(shot()).stale == ""
    state = load_state(shot(material="jelly"))
    assert "material: rubber -> jelly" in state.stale and state.shows_motion  # same cages: frames shown


@pytest.mark.slow
def test_simulate_streams_frames_into_the_timeline(shot, viewer):
    path = shot(frames=1000)  # several seconds (about 6 ms a frame): the run's log gets a chunk every 2 s
    viewer.open(path)
    assert viewer.n_frames == 1
    sim = viewer.simulate()
    seen, deadline = set(), time.monotonic() + 180
    while time.monotonic() < deadline:
        seen.add(viewer.n_frames)
        if sim.poll() is not None and viewer.n_frames == 1000:
            break
        time.sleep(0.1)
    assert sim.poll() == ("done", 1000), sim.poll()
    assert any(1 < n < 1000 for n in seen), sorted(seen)  # frames shown while the run wrote its log
    assert viewer.n_frames == 1000 and viewer._gui["frame"].max == 999
    assert (path.with_suffix("") / "motion.npz").is_file()
    viewer.frame(239)


@pytest.mark.slow
def test_an_error_of_the_simulation_is_shown_on_the_page(shot, viewer):
    path = shot()
    assert main(["scene", str(path)]) == 0
    viewer.open(shot(material="jelly"))  # a changed scene: the job refuses to continue its motion
    sim = viewer.simulate()
    sim.join(120)
    deadline = time.monotonic() + 10
    while "Simulation failed" not in viewer._gui["status"].content and time.monotonic() < deadline:
        time.sleep(0.1)
    assert sim.error is not None and "made from another scene" in sim.error
    assert "Simulation failed" in viewer._gui["status"].content
    assert "anew" in viewer._gui  # the stale motion may be replaced, on purpose only


@pytest.mark.slow
@pytest.mark.parametrize("host, warned", [("127.0.0.1", False), ("0.0.0.0", True)])
def test_the_command_serves_until_sigterm_and_exits_0(shot, host, warned):
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    command = [sys.executable, "-m", "shellsim.cli.main", "view", str(shot()), "--no-browser", "--port", "0"]
    process = subprocess.Popen(
        [*command, "--host", host],
        cwd=repo,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(repo)},
    )
    try:
        line = process.stdout.readline()
        assert line.startswith("view: http://127.0.0.1:"), line  # the first line on stdout
        with urllib.request.urlopen(line.split()[1], timeout=10) as response:
            assert "<html" in response.read().decode().lower()
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == 0, err
    assert ("anyone who can reach port" in err) == warned


def test_moving_a_collider_and_a_body_edits_only_their_poses_and_save_reopens_the_file(viewer, shot):
    """What "Move" does when its arrows are let go: the file's position and rotation of the wall and the rod
    change, nothing else; the page's meshes move at once, and after Save the reopened file shows them
    there."""
    import dataclasses

    from shellsim.shot.file import read_scene

    path = shot()
    before = read_scene(path)
    viewer.open(path)
    rod = viewer.displayed("r").copy()
    viewer.move("wall", (1.2, 0.1, 0.2), (0.0, 0.0, 30.0))
    viewer.move("r", (0.0, 0.3, 0.05), (0.0, 0.0, 0.0))
    np.testing.assert_allclose(viewer.displayed("r"), rod + [0.0, 0.3, 0.0], atol=1e-6)
    after = viewer.save()
    assert after == read_scene(path)
    wall = dataclasses.replace(before.colliders[0], position=(1.2, 0.1, 0.2), rotation=(0.0, 0.0, 30.0))
    body = dataclasses.replace(before.bodies[0], position=(0.0, 0.3, 0.05))
    assert after.colliders == (wall,) and after.bodies == (body,)
    assert after.actions == before.actions and after.cameras == before.cameras and after.world == before.world
    name, vertices, _ = viewer.state.colliders[0]
    assert name == "wall"
    np.testing.assert_allclose(0.5 * (vertices.min(0) + vertices.max(0)), (1.2, 0.1, 0.2), atol=1e-9)
    np.testing.assert_allclose(viewer.displayed("r").mean(0), rod.mean(0) + [0.0, 0.3, 0.0], atol=1e-3)


def test_a_hostile_message_from_a_page_is_dropped_with_a_log_line_and_the_server_goes_on(
    shot, viewer, caplog
):
    """Messages the page's controls deliver (through the callbacks viser holds for them) carrying what no
    honest page sends: a frame number that is not a number, a body to move that the scene does not have.
    Each is dropped with one warning, and the viewer still serves its page and shows frames."""
    from types import SimpleNamespace

    viewer.open(shot())
    for key, value, what in (("frame", float("nan"), "timeline"), ("move", "../../etc/passwd", "move")):
        handle = viewer._gui[key]
        handle._impl.value = value  # what a page's malformed update leaves in the handle
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="shellsim.view.viewer"):
            for callback in handle._impl.update_cb:
                callback(SimpleNamespace(client=None, target=handle))
        dropped = [
            r.getMessage() for r in caplog.records if "dropped a message from a page" in r.getMessage()
        ]
        assert len(dropped) == 1 and f"({what})" in dropped[0]
    viewer._gui["frame"]._impl.value = 0
    viewer.frame(0)
    with urllib.request.urlopen(viewer.url, timeout=10) as response:
        assert "<html" in response.read().decode().lower()
