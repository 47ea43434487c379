"""Live mode (shellsim.view.live): a poke pulls a body its way and it springs back when released; the
spring's force is capped; a recorded poke is a push whose impulse is the momentum it gave, and it reads back
through the scene file after the editor writes it. Mesh bodies on a Kuhn-grid cage (no fTetWild)."""

from __future__ import annotations

import dataclasses
import math
import types

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid

from shellsim.physics.selection import parse_selection
from shellsim.shot.file import read_scene
from shellsim.view.edit import SceneEditor
from shellsim.view.live import (
    STANDARD_GRAVITY,
    LiveShot,
    PokeSettings,
    live_spec,
    spring_force,
    strain_cap,
)

WORLD = """\
[world]
duration = 2.0
substeps = 2
gravity = 0
ground = false
drag = {drag}

[[body]]
name = "block"
mesh = "cube.stl"
size = 0.1
material = "jelly"
"""
PIN = """
[[action]]
kind = "pin"
body = "block"
region = "x < 1%"
end = 0.5

[[action]]
kind = "push"
body = "block"
start = 0.1
end = 0.2
velocity = [0, 0, 1]
"""


@pytest.fixture
def scene(tmp_path, monkeypatch):
    """A scene file writer: a 10 cm jelly cube, no gravity, no ground; its cage a 162-tet Kuhn grid."""
    trimesh.creation.box((1, 1, 1)).export(tmp_path / "cube.stl")

    def build_cage(outer, inner, config=None, what=""):
        v, t, _ = kuhn_grid(0.0, 1.0, 3)
        return types.SimpleNamespace(vertices=v + outer.bounds[0], tets=t)

    monkeypatch.setattr("shellsim.tetcage.build.build_cage", build_cage)

    def write(extra: str = "", drag: float = 0.0):
        path = tmp_path / "shot.toml"
        path.write_text(WORLD.format(drag=drag) + extra)
        return path

    return write


def top_corner(shot):
    """The +x, +z edge's middle of the block, on its surface, where it is now."""
    v = shot.display_positions("block")
    return np.array([v[:, 0].max(), 0.5 * (v[:, 1].min() + v[:, 1].max()), v[:, 2].max()])


def test_live_spec_coarsens_the_cages_and_keeps_only_the_pins_held_for_ever(scene):
    spec = read_scene(scene(PIN))
    live = live_spec(spec, target_tets=1000, margin=0.05, substeps=1)
    assert live.world.substeps == 1 and live.bodies[0].cage.target_tets == 1000
    assert live.bodies[0].cage.margin == 0.05
    assert [(a.kind, a.start, a.end) for a in live.actions] == [("pin", 0.0, math.inf)]
    assert live_spec(spec, actions="all").actions == spec.actions
    assert live_spec(spec, actions="none").actions == ()
    with pytest.raises(ValueError, match="actions"):
        live_spec(spec, actions="some")


def test_a_poke_pulls_the_body_its_way_and_it_springs_back_when_released(scene):
    shot = LiveShot(read_scene(scene(PIN, drag=3.0)), device="cpu")
    assert shot.names == ["block"]
    rest_vertices, faces = shot.display_mesh("block")
    assert len(faces) == 12
    np.testing.assert_allclose(shot.display_positions("block"), rest_vertices, atol=1e-12)

    point = top_corner(shot)
    pull = np.array([0.0, 0.0, 0.05])
    shot.poke("block", point, point + pull)
    for _ in range(15):
        shot.step()
    now, target = shot.spring()
    moved = now - point
    assert moved @ pull > 0.2 * (pull @ pull)  # at least a centimetre of the 5 cm pull, its way
    assert np.linalg.norm(moved - (moved @ pull) / (pull @ pull) * pull) < 0.5 * np.linalg.norm(moved)
    np.testing.assert_array_equal(target, point + pull)
    rest = shot.simulation.bodies[0].rest
    held = rest[:, 0] < rest[:, 0].min() + 1e-9  # the pin's face stays put
    np.testing.assert_allclose(shot.positions()[0][held], rest[held], atol=1e-12)

    record = shot.release()
    assert shot.spring() is None and record is not None
    for _ in range(45):
        shot.step()
    back = np.linalg.norm(top_corner(shot) - point)
    assert back < 0.25 * np.linalg.norm(moved)  # back toward rest


def test_the_force_is_capped_by_the_body_mass_and_by_the_material():
    settings = PokeSettings(stiffness=50.0, damping=5.0, max_acceleration=2.0)
    # a small pull: k M d exactly, against the velocity by d M v
    force = spring_force(np.zeros(3), [0.0, 0.1, 0.0], [0.01, 0.0, 0.0], 3.0, settings)
    np.testing.assert_allclose(force, [50 * 3 * 0.01, -5 * 3 * 0.1, 0.0])
    # a far cursor: |F| = max_acceleration g M, along the pull
    far = spring_force(np.zeros(3), np.zeros(3), [0.0, 0.0, 100.0], 3.0, settings)
    np.testing.assert_allclose(far, [0.0, 0.0, 2.0 * STANDARD_GRAVITY * 3.0])
    tight = spring_force(np.zeros(3), np.zeros(3), [0.0, 100.0, 0.0], 3.0, settings, max_force=1.5)
    np.testing.assert_allclose(tight, [0.0, 1.5, 0.0])
    # a regular tet of edge a has volume a^3 / (6 sqrt 2): the cap is max_strain E a^2
    assert strain_cap(1e4, 0.02**3 / (6 * math.sqrt(2)), 0.5) == pytest.approx(0.5 * 1e4 * 0.02**2)
    with pytest.raises(ValueError, match="stiffness"):
        PokeSettings(stiffness=-1.0)


def test_a_poke_far_away_is_held_to_its_cap(scene):
    settings = PokeSettings(max_acceleration=0.5)
    shot = LiveShot(read_scene(scene()), poke=settings, device="cpu")
    point = top_corner(shot)
    shot.poke("block", point, point + (0.0, 10.0, 0.0))  # ten metres away
    shot.step()
    mass = shot.masses[0]
    assert mass == pytest.approx(1050 * 0.1**3, rel=1e-6)  # jelly's density times the cube's volume
    force = shot.spring_force()
    assert np.linalg.norm(force) <= 0.5 * STANDARD_GRAVITY * mass * (1 + 1e-9)
    assert force[1] > 0.99 * np.linalg.norm(force)


def test_a_recorded_poke_is_the_push_of_its_impulse_and_reads_back_from_the_file(scene):
    path = scene()
    shot = LiveShot(read_scene(path), device="cpu")
    point = top_corner(shot)
    shot.poke("block", point, point + (0.03, 0.0, 0.02))
    for _ in range(6):
        shot.step()
    record = shot.release()
    assert record.body == "block" and record.start == 0.0 and record.end == pytest.approx(6 / 30)
    # a free body without gravity: its momentum is the poke's impulse, mean force times duration
    model = shot.simulation.driver.solver.models[0]
    momentum = model.masses @ shot.simulation.states[0].velocities.numpy()
    np.testing.assert_allclose(momentum, np.multiply(record.force, record.end - record.start), rtol=1e-6)

    push = shot.push_action(record)
    assert (
        push.kind == "push" and push.body == "block" and push.force == pytest.approx(record.force, abs=1e-6)
    )
    rest = shot.simulation.bodies[0].rest
    chosen = np.ones(len(rest), bool)
    for rule in push.region:
        chosen &= parse_selection(rule).select(rest)
    assert chosen[np.argmin(np.linalg.norm(rest - record.point, axis=1))]  # around the picked point
    assert chosen.sum() >= 4 and not chosen.all()

    editor = SceneEditor(path)
    editor.add_action(push)
    editor.save()
    saved = read_scene(path)
    assert saved.actions == (dataclasses.replace(push, where=f"{saved.path}: [[action]] #1 (push)"),)

    late = dataclasses.replace(record, start=2.5, end=2.6)
    with pytest.raises(ValueError, match="after the shot's end"):
        shot.push_action(late)


def test_a_body_that_is_not_the_scenes_is_refused(scene):
    shot = LiveShot(read_scene(scene()), device="cpu")
    with pytest.raises(ValueError, match="'ghost'"):
        shot.poke("ghost", (0, 0, 0), (0, 0, 1))
    with pytest.raises(ValueError, match="target"):
        shot.poke("block", (0, 0, 0), (0, float("inf"), 1))
