"""``[world] settle`` and the sag said before simulating: the standing column's estimate against closed forms
(a prism, a pyramid) and against a settled soft column; a body set down that settles stays put while one that
does not settle sinks; a settled shot resumes, and a changed ``settle`` is refused; the warning of a body
that will not hold its shape."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid
from scipy.spatial import Delaunay

from shellsim.cli.main import main
from shellsim.motion.read import load_motion
from shellsim.physics.sag import column_sag, holding_youngs

RHO, G, E = 1050.0, 9.81, 1.0e4  # the jelly preset under gravity

COLUMN = (0.05, 0.05, 0.1)  # [m] the soft column's extents
SCENE = """
[world]
frames = 10
substeps = 4
settle = {settle}
ground_friction = 0

[[body]]
name = "column"
mesh = "{mesh}"
material = "jelly"
poisson = 0.2
friction = 0
[body.cage]
target_tets = 2000
"""


def test_a_prism_sags_by_its_base_strain_times_half_its_height():
    """A prism of height H under its own weight: every slice carries the prism above it, ``delta = rho g H^2 /
    (2 E)``; the part under ``base`` carries nothing."""
    vertices, tets, _ = kuhn_grid((0.0, 0.0, 0.0), (0.05, 0.05, 0.2), (3, 3, 12))
    assert column_sag(vertices, tets, RHO, E, G) == pytest.approx(RHO * G * 0.2**2 / (2 * E), rel=0.03)
    half = column_sag(vertices, tets, RHO, E, G, base=0.1)
    assert half == pytest.approx(RHO * G * 0.1**2 / (2 * E), rel=0.03)
    assert column_sag(vertices, tets, RHO, E, 0.0) == 0.0


def test_a_pyramid_sags_a_third_as_much_as_a_prism():
    """A square pyramid standing on its base carries a third of a prism's weight per area at every height:
    ``delta = rho g H^2 / (6 E)``, whatever its tets."""
    grid = np.stack(
        np.meshgrid(*[np.linspace(-0.1, 0.1, 21)] * 2, np.linspace(0, 0.2, 41), indexing="ij"), -1
    )
    points = grid.reshape(-1, 3)
    points = points[np.abs(points[:, :2]).max(1) <= 0.1 * (1 - points[:, 2] / 0.2) + 1e-9]
    tets = Delaunay(points).simplices
    e = points[tets[:, 1:]] - points[tets[:, :1]]
    tets = tets[np.abs(np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2]))) > 1e-12]
    assert column_sag(points, tets, RHO, E, G) == pytest.approx(RHO * G * 0.2**2 / (6 * E), rel=0.03)


def test_the_holding_youngs_holds_the_estimate_to_five_percent():
    vertices, tets, _ = kuhn_grid((0.0, 0.0, 0.0), (0.05, 0.05, 0.3), (2, 2, 12))
    sag = column_sag(vertices, tets, RHO, E, G)
    stiff = holding_youngs(E, sag, 0.3)
    assert float(f"{stiff:.2g}") == stiff  # two significant figures
    held = column_sag(vertices, tets, RHO, stiff, G)
    assert 0.049 * 0.3 <= held <= 0.05 * 0.3


@pytest.fixture
def column(tmp_path):
    """A closed box mesh of :data:`COLUMN` (metres), its faces subdivided to 1 cm so the ground's contact
    spreads over its base."""
    box = trimesh.creation.box(COLUMN)
    vertices, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.01)
    path = tmp_path / "column.ply"
    trimesh.Trimesh(vertices, faces).export(path)
    return path


def run(tmp_path, mesh, settle: float, *extra, name: str = "shot"):
    scene = tmp_path / f"{name}.toml"
    scene.write_text(SCENE.format(settle=settle, mesh=mesh))
    out = tmp_path / name
    assert main(["scene", str(scene), "--out", str(out), *extra]) == 0
    return scene, out, load_motion(out / "motion.npz")


def visible_height(motion, k: int | None = None) -> float:
    """The height [m] of the body's visible surface at frame ``k`` (None: at rest)."""
    if k is not None:
        points = motion.surface_points(k)
    else:
        s = motion.surface
        points = np.einsum("sk,skd->sd", s.bary, motion.rest_vertices[motion.tets[s.tet]])
    return float(np.ptp(points[:, 2]))


@pytest.mark.slow
def test_a_settled_column_stays_put_and_sags_as_the_estimate_says(tmp_path, column, caplog):
    """A soft column set down on a frictionless ground: settled for 0.5 s, frame 0 is the column shortened by
    its weight as linear elasticity says exactly for a prism on a frictionless base (uniaxial stress ``rho g
    (H - z)``: ``rho g H^2 / (2 E)``, 5.2 mm; within 10%: linear tets and the Neo-Hookean's stiffening in
    compression make it 6% stiffer), and its vertices then move less than 1 mm over 10 frames with nothing
    still moving at the end; without settling, the column starts at rest, sinks and rebounds, more than
    1 mm."""
    caplog.set_level(logging.INFO)
    _, _, settled = run(tmp_path, column, 0.5, name="settled")
    record = settled.meta["settle"]
    assert record["seconds"] == 0.5 and record["frames"] == 15 and record["substeps"] == 4
    height = COLUMN[2]
    expected = RHO * G * height**2 / (2 * E)
    sag = visible_height(settled) - visible_height(settled, 0)
    assert sag == pytest.approx(expected, rel=0.1)
    moved = np.abs(settled.positions - settled.positions[0]).max()
    assert moved < 1e-3
    assert "still moving" not in caplog.text
    _, _, dropped = run(tmp_path, column, 0.0, name="dropped")
    assert "settle" not in dropped.meta
    assert np.abs(dropped.positions - dropped.positions[0]).max() > 1e-3


@pytest.mark.slow
def test_a_settled_shot_resumes_and_a_changed_settle_is_refused(tmp_path, capsys):
    """Interrupted after 3 frames, the shot continues from its stored state without settling again, to the
    motion made in one run; a changed ``settle`` is refused like any changed setting."""
    ball = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=2, radius=0.05).export(ball)
    text = SCENE.replace('material = "jelly"', 'material = "rubber"').replace("frames = 10", "frames = 6")
    scene, out = tmp_path / "shot.toml", tmp_path / "shot"
    scene.write_text(text.format(settle=0.1, mesh=ball))
    assert main(["scene", str(scene), "--out", str(out)]) == 0
    whole = load_motion(out / "motion.npz")
    (out / "motion.npz").unlink()
    assert main(["scene", str(scene), "--out", str(out), "--frames", "3"]) == 0
    assert load_motion(out / "motion.npz").n_frames == 3
    assert main(["scene", str(scene), "--out", str(out)]) == 0
    continued = load_motion(out / "motion.npz")
    np.testing.assert_allclose(continued.positions, whole.positions, atol=1e-6)
    assert continued.meta["settle"] == whole.meta["settle"] and whole.meta["settle"]["frames"] == 3
    before = (out / "motion.npz").read_bytes()
    scene.write_text(text.format(settle=0.2, mesh=ball))
    capsys.readouterr()
    assert main(["scene", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "another scene" in err and "settle: 0.1 -> 0.2" in err
    assert (out / "motion.npz").read_bytes() == before


def test_the_end_of_a_shot_names_the_fastest_body_still_moving(tmp_path, caplog):
    """A ball falling freely for 3 frames at 30 fps ends at g t = 0.981 m/s, which the log names; a resting
    one is not named."""
    ball = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=1, radius=0.05).export(ball)
    scene = tmp_path / "fall.toml"
    body = f'[[body]]\nname = "ball"\nmesh = "{ball}"\nposition = [0, 0, 1]\n'
    scene.write_text("[world]\nframes = 4\nsubsteps = 2\nground = false\n" + body)
    with caplog.at_level(logging.INFO):
        assert main(["scene", str(scene), "--out", str(tmp_path / "fall")]) == 0
    assert "still moving at the end: body ball at 0.981 m/s" in caplog.text
    caplog.clear()
    scene.write_text("[world]\nframes = 4\nsubsteps = 2\ngravity = 0\nground = false\n" + body)
    with caplog.at_level(logging.INFO):
        assert main(["scene", str(scene), "--out", str(tmp_path / "still")]) == 0
    assert "still moving" not in caplog.text


def test_a_body_too_soft_for_its_size_is_warned_about_before_simulating(caplog):
    """The furry bunny 0.3 m tall: as jelly (10 kPa) its standing column sags past 10% of its height, which
    one warning names with a Young's modulus that holds it to 5%; at 20 kPa it is silent."""
    pytest.importorskip("ipctk")
    from shellsim.shot.bodies import build_body
    from shellsim.shot.simulation import warn_sagging
    from shellsim.shot.spec import BodySpec

    for youngs, warned in ((1.0e4, True), (2.0e4, False)):
        spec = BodySpec("bunny", asset="furry_bunny", material="jelly", youngs=youngs, where="s.toml: bunny")
        body = build_body(spec, 5e-4)
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            warn_sagging([body], G)
        if not warned:
            assert not caplog.records
            continue
        (record,) = caplog.records
        message = record.getMessage()
        assert message.startswith("s.toml: bunny: as jelly (youngs 10000 Pa")
        assert "sag about 13% of its 0.3 m height" in message and "youngs = 27000 holds it to 5%" in message


@pytest.mark.slow
def test_while_settling_pins_hold_and_other_actions_wait_for_the_shot(tmp_path):
    """Settling with a pin from t = 0 on one ball and a push at t = 0 on another, no ground: the pinned
    region is where it was at rest at frame 0 and the ball hangs from it (a free ball settling 0.1 s under
    the settling drag falls about 3 cm); the push has not acted yet (the pushed ball has not moved along x at
    frame 0) and acts once the shot starts, changing the momentum by the ball's mass times its velocity."""
    from test_scene_job import RUBBER_DENSITY, lumped_masses

    ball = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=1, radius=0.05).export(ball)
    scene = tmp_path / "held.toml"
    scene.write_text(
        f"""
[world]
frames = 4
substeps = 2
ground = false
settle = 0.1

[[body]]
name = "held"
mesh = "{ball}"

[[body]]
name = "pushed"
mesh = "{ball}"
position = [0.2, 0, 0]

[[action]]
kind = "pin"
body = "held"
region = "z>80%"

[[action]]
kind = "push"
body = "pushed"
start = 0
end = 0
velocity = [0.5, 0, 0]
"""
    )
    assert main(["scene", str(scene), "--out", str(tmp_path / "held")]) == 0
    motion = load_motion(tmp_path / "held" / "motion.npz")
    (held, pushed) = (slice(*r["vertices"]) for r in motion.asset["bodies"])
    rest = motion.rest_vertices
    z = rest[held, 2]
    pinned = np.flatnonzero(z > z.min() + 0.8 * np.ptp(z))
    np.testing.assert_allclose(motion.positions[0][held][pinned], rest[held][pinned], atol=1e-6)
    assert np.abs(motion.positions[0][held] - rest[held]).max() < 1e-4  # unheld it would fall 3 cm
    masses = lumped_masses(
        rest[pushed], motion.tets[motion.tets[:, 0] >= pushed.start] - pushed.start, RUBBER_DENSITY
    )
    velocities = motion.state["velocities"][pushed]
    assert masses @ velocities[:, 0] == pytest.approx(0.5 * masses.sum(), rel=0.02)
    assert abs(masses @ (motion.positions[0][pushed] - rest[pushed])[:, 0]) < 1e-9 * masses.sum()
