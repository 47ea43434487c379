"""shellsim.world: placements of bodies in the world (metres, z up, ground at z = 0) against closed forms;
shellsim.film.world: the look of a scene file's ``[look]`` and the world options laid over it."""

import dataclasses
import json

import numpy as np
import pytest

from neural.errors import InputError
from shellsim.film.world import WorldSettings, look_of
from shellsim.shot.spec import LookSpec
from shellsim.world import Placement, WorldLook, describe_placement, place_on_ground, up_rotation

LOOK = LookSpec(
    ground_colors=((0.9, 0.9, 0.9), (0.1, 0.2, 0.3)),
    square=0.5,
    light=(0.0, -1.0, 1.0),
    ambient=0.1,
    diffuse=0.9,
    shadows=False,
    sky=((0.2, 0.3, 0.4),),
    collider_color=(0.5, 0.5, 0.0),
)


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@pytest.mark.parametrize("up", [(0, 0, 1), (0, 1, 0), (1, 0, 0), (0, 0, -1), (0.3, -0.4, 0.2)])
def test_up_rotation_turns_up_onto_z(up):
    r = up_rotation(up)
    u = np.asarray(up, float) / np.linalg.norm(up)
    np.testing.assert_allclose(r @ u, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_placement_round_trip_and_distances():
    """to_asset inverts to_world; distances scale by the scale (a similarity), angles are kept."""
    rng = np.random.default_rng(0)
    p = Placement(0.37, random_rotation(rng), rng.normal(size=3))
    x = rng.normal(size=(50, 3))
    w = p.to_world(x)
    np.testing.assert_allclose(p.to_asset(w), x, atol=1e-12)
    np.testing.assert_allclose(
        np.linalg.norm(w[1:] - w[:-1], axis=1), 0.37 * np.linalg.norm(x[1:] - x[:-1], axis=1), rtol=1e-12
    )


def test_place_on_ground_closed_form():
    """A 2 x 4 x 1 box with y up: y turned onto z, the 4-unit side scaled to 0.5 m, lowest point at 0.1 m,
    centred over the origin."""
    corners = np.array([[x, y, z] for x in (1, 3) for y in (-2, 2) for z in (5, 6)], float)
    p = place_on_ground(corners, up=(0, 1, 0), size=0.5, height=0.1)
    assert p.scale == pytest.approx(0.125)
    w = p.to_world(corners)
    lo, hi = w.min(0), w.max(0)
    np.testing.assert_allclose(lo[2], 0.1, atol=1e-12)
    np.testing.assert_allclose(hi - lo, [0.25, 0.125, 0.5], atol=1e-12)  # x: 2, y: 1 (was z), z: 4 (was y)
    np.testing.assert_allclose((lo + hi)[:2] / 2, 0, atol=1e-12)
    # the asset's up (y) points up in the world
    np.testing.assert_allclose(p.rotation @ [0, 1, 0], [0, 0, 1], atol=1e-12)


def test_place_on_ground_by_units_keeps_size():
    """A mesh in millimetres: 1 mm per unit, no rescaling."""
    v = np.array([[0, 0, 0], [200, 0, 0], [0, 100, 0], [0, 0, 50]], float)
    p = place_on_ground(v, size=None, scale=0.001, height=0.0)
    w = p.to_world(v)
    np.testing.assert_allclose(np.ptp(w, axis=0), [0.2, 0.1, 0.05], atol=1e-15)
    assert w[:, 2].min() == pytest.approx(0.0)


def test_placement_json_round_trip_and_malformed():
    rng = np.random.default_rng(1)
    p = Placement(2.0, random_rotation(rng), [1.0, 2.0, 3.0])
    q = Placement.from_dict(json.loads(json.dumps(p.as_dict())), "m.npz")
    x = rng.normal(size=(5, 3))
    np.testing.assert_allclose(q.to_world(x), p.to_world(x), atol=1e-12)
    assert Placement.from_dict({}, "old.npz").scale == 1.0  # motions made before metres: the identity
    for bad in (
        {"scale": -1, "rotation": np.eye(3).tolist(), "translation": [0, 0, 0]},
        {"scale": 1, "rotation": (2 * np.eye(3)).tolist(), "translation": [0, 0, 0]},
        {"scale": 1, "rotation": np.eye(3).tolist()},
    ):
        with pytest.raises(InputError, match="m.npz: malformed placement"):
            Placement.from_dict(bad, "m.npz")


def test_describe_placement_states_extent_lowest_point_and_ground():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]], float)
    p = place_on_ground(v, size=0.3, height=0.05)
    line = describe_placement("cube", p, p.to_world(v))
    assert "extent 0.100 x 0.200 x 0.300 m" in line
    assert "lowest point at z = 0.050" in line and "ground at z = 0" in line


def test_a_look_tables_defaults_are_world_looks():
    assert look_of(LookSpec(), True) == WorldLook()
    assert look_of(LookSpec(), False) == WorldLook(ground=False)


def test_look_of_sets_every_key_and_a_one_colour_sky_is_plain():
    assert look_of(LOOK, False) == WorldLook(
        ground=False,
        square=0.5,
        ground_colors=((0.9, 0.9, 0.9), (0.1, 0.2, 0.3)),
        light=(0.0, -1.0, 1.0),
        ambient=0.1,
        diffuse=0.9,
        shadows=False,
        zenith=(0.2, 0.3, 0.4),
        horizon=(0.2, 0.3, 0.4),
        obstacle_color=(0.5, 0.5, 0.0),
    )
    two = look_of(dataclasses.replace(LOOK, sky=((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))), True)
    assert (two.zenith, two.horizon, two.ground) == ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), True)


def test_world_options_over_a_look_replace_only_the_options_changed():
    look = look_of(LOOK, False)
    default = WorldLook()
    assert WorldSettings().over(look) == look
    # set to their defaults: unchanged, so the look's own stay
    same = WorldSettings(
        ground_colors=default.ground_colors[0] + default.ground_colors[1], light=default.light
    )
    assert same.over(look) == look
    assert WorldSettings(light=(1.0, 0.0, 1.0)).over(look) == dataclasses.replace(look, light=(1.0, 0.0, 1.0))
    both = WorldSettings(ground_colors=(0.0, 0.0, 0.0, 1.0, 1.0, 1.0), sky=(1.0, 0.0, 0.0, 0.0, 1.0, 0.0))
    assert both.over(look) == dataclasses.replace(
        look,
        ground_colors=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
        zenith=(1.0, 0.0, 0.0),
        horizon=(0.0, 1.0, 0.0),
    )
