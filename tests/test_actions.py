"""shellsim.shot.actions: the timed pins, grabs, pushes and wind of a scene as the solver's inputs per
substep, checked against closed forms on tiny hand-made vertex sets."""

import math

import numpy as np
import pytest

from shellsim.shot.actions import AIR_DENSITY, Actions, BodyInfo
from shellsim.shot.spec import ActionSpec, Keyframe, SceneError

REST = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
MASSES = np.array([1.0, 2, 3, 4, 5])
NO_FACES = np.zeros((0, 3), np.int64)
BODY = BodyInfo("b", REST, MASSES, NO_FACES)
WHERE = "scene.toml: [[action]] #1"


def run(actions, bodies, h, steps, moving=lambda t: REST, t0=0.0):
    """The inputs of substeps k = 0 .. steps - 1 starting at t0 + k h, the body at ``moving(t)``."""
    out = []
    for k in range(steps):
        t = t0 + k * h
        pos = {b.name: moving(t) for b in bodies}
        out.append((t, actions.inputs(t, h, pos, {b.name: np.zeros_like(b.rest) for b in bodies})))
    return out


def rz(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rx(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


@pytest.mark.parametrize("start, end", [(0.2, 0.5), (0.033, 0.171), (0.0, 0.01), (0.2049, 0.2051)])
def test_velocity_push_gives_exactly_m_dv(start, end):
    dv = np.array([0.5, -1.0, 2.0])
    push = ActionSpec("push", start, end, body="b", region=("z<0.5",), velocity=tuple(dv))
    h = 0.01
    steps = run(Actions([push], [BODY]), [BODY], h, 80)
    impulse = sum(inp["b"].forces * h for _, inp in steps)
    np.testing.assert_allclose(impulse[:3], MASSES[:3, None] * dv, rtol=1e-12, atol=1e-15)
    assert not impulse[3:].any()  # outside the region
    inside = [inp["b"].forces for t, inp in steps if start <= t and t + h <= end]
    for f in inside:  # spread evenly: m_i dv / (end - start)
        np.testing.assert_allclose(f[:3], MASSES[:3, None] * dv / (end - start), rtol=1e-12)


def test_velocity_push_with_times_summed_step_by_step():
    push = ActionSpec("push", 0.1, 0.3, body="b", velocity=(0.0, 0.0, 1.0))
    actions, h, t, impulse = Actions([push], [BODY]), 0.1 / 3, 0.0, np.zeros((5, 3))
    for _ in range(20):
        impulse += actions.inputs(t, h, {}, {})["b"].forces * h
        t += h
    np.testing.assert_allclose(impulse[:, 2], MASSES, rtol=1e-12)


@pytest.mark.parametrize("start", [0.123, 0.2])
def test_impulse_acts_in_the_one_substep_containing_start(start):
    push = ActionSpec("push", start, start, body="b", velocity=(0.0, 3.0, 0.0))
    h = 0.01
    actions, t, hits = Actions([push], [BODY]), 0.0, []
    for _ in range(40):  # times summed step by step: t lands within rounding of 0.2
        f = actions.inputs(t, h, {}, {})["b"].forces
        if f.any():
            hits.append(t)
            np.testing.assert_allclose(f, np.outer(MASSES, (0, 3.0, 0)) / h, rtol=1e-12)
        t += h
    assert len(hits) == 1 and hits[0] - 1e-9 <= start < hits[0] + h - 1e-9


def test_force_push_is_shared_by_mass():
    F = np.array([0.0, 0.0, 6.0])
    push = ActionSpec("push", 0.05, 0.3, body="b", region=("x<0.5",), force=tuple(F))  # vertices 0, 2, 3
    h = 0.1
    steps = run(Actions([push], [BODY]), [BODY], h, 5)
    full = steps[1][1]["b"].forces  # [0.1, 0.2]: wholly inside
    np.testing.assert_allclose(full[[0, 2, 3]], np.outer([1, 3, 4], F) / 8)
    assert not full[[1, 4]].any()
    np.testing.assert_allclose(full.sum(0), F)
    impulse = sum(inp["b"].forces * h for _, inp in steps)
    np.testing.assert_allclose(impulse.sum(0), F * 0.25, rtol=1e-12)  # F times the window's length


def test_pin_holds_where_the_region_was_at_start_and_releases_at_end():
    pin = ActionSpec("pin", 0.25, 0.5, body="b", region=("z<0.5",))
    h = 0.1
    drift = np.array([1.0, 0.0, 0.0])
    actions = Actions([pin], [BODY])
    assert actions.active(0.3) == ["pin b (z<0.5)"] and actions.active(0.5) == []
    steps = run(actions, [BODY], h, 8, moving=lambda t: REST + t * drift)
    for t, inp in steps:
        held = 0.2 - 1e-9 < t < 0.5 - 1e-9  # the substeps overlapping [0.25, 0.5)
        assert inp["b"].pinned.tolist() == [held] * 3 + [False] * 2
        if held:  # captured at the first one, [0.2, 0.3]
            np.testing.assert_allclose(inp["b"].targets[:3], REST[:3] + 0.2 * drift)


def test_pin_aligned_with_substeps_starts_and_ends_on_them():
    pin = ActionSpec("pin", 0.5, 1.0, body="b")
    pinned = [(t, inp["b"].pinned.all()) for t, inp in run(Actions([pin], [BODY]), [BODY], 0.1, 12)]
    assert [t for t, p in pinned if p] == pytest.approx([0.5, 0.6, 0.7, 0.8, 0.9])


GRAB = ActionSpec(
    "grab",
    0.0,
    3.0,
    body="b",
    keyframes=(
        Keyframe(1.0, (1.0, 0.0, 0.0), (0.0, 0.0, 90.0)),
        Keyframe(2.0, (1.0, 2.0, 0.0), (90.0, 0.0, 90.0)),
    ),
    where=WHERE,
)


def test_grab_follows_the_keyframes_rigidly():
    """Targets at t + h: the identity at start; 90 degrees about z and (1, 0, 0) at 1 s; about world x then
    z, Rz(90) Rx(90), and (1, 2, 0) at 2 s; linear offsets and half-angle rotations midway; held after."""
    h = 0.125
    p0 = REST + np.array([0.1, 0.2, 0.3])  # where the body is when the grab begins, not its rest
    steps = run(Actions([GRAB], [BODY]), [BODY], h, 28, moving=lambda t: p0 + t)
    c0 = p0.mean(0)
    expected = {
        0.5: (rz(45), (0.5, 0, 0)),
        1.0: (rz(90), (1, 0, 0)),
        1.5: (rz(90) @ rx(45), (1, 1, 0)),
        2.0: (rz(90) @ rx(90), (1, 2, 0)),
        2.75: (rz(90) @ rx(90), (1, 2, 0)),
        3.0: (rz(90) @ rx(90), (1, 2, 0)),
    }
    by_end = {t + h: inp["b"] for t, inp in steps}
    for end, (turn, offset) in expected.items():
        np.testing.assert_allclose(by_end[end].targets, c0 + (p0 - c0) @ turn.T + offset, atol=1e-12)
    rest_distances = np.linalg.norm(p0[:, None] - p0[None], axis=-1)
    for t, inp in steps:
        assert inp["b"].pinned.all() == (t < 3.0)
        if t < 3.0:
            x = inp["b"].targets
            np.testing.assert_allclose(
                np.linalg.norm(x[:, None] - x[None], axis=-1), rest_distances, atol=1e-12
            )


def test_the_later_action_holds_a_vertex_two_hold():
    pin = ActionSpec("pin", 0.0, 1.0, body="b", region=("z<0.5",))
    grab = ActionSpec("grab", 0.0, 1.0, body="b", keyframes=(Keyframe(0.5, (0.0, 0.0, 1.0)),))
    [(_, pin_last)] = run(Actions([grab, pin], [BODY]), [BODY], 0.5, 1)
    [(_, grab_last)] = run(Actions([pin, grab], [BODY]), [BODY], 0.5, 1)
    np.testing.assert_allclose(pin_last["b"].targets, REST + np.array([[0, 0, 0]] * 3 + [[0, 0, 1]] * 2))
    np.testing.assert_allclose(grab_last["b"].targets, REST + [0, 0, 1])


def plate(name, normal_axis, flip=False):
    """A 2 m x 2 m square (area 4) through the origin, normal along ``normal_axis``."""
    a, b = [i for i in range(3) if i != normal_axis]
    v = np.zeros((4, 3))
    v[:, a], v[:, b] = [-1, 1, 1, -1], [-1, -1, 1, 1]
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return BodyInfo(name, v, np.ones(4), faces[:, ::-1] if flip else faces)


def wind(**kw):
    args = dict(speed=3.0, direction=(1.0, 0.0, 0.0), gust=0.0, turbulence=0.0, drag_coefficient=1.3)
    return ActionSpec("wind", 0.0, 2.0, **{**args, **kw})


def total_drag(action, body, t, h=0.01, velocity=0.0):
    inp = Actions([action], [body]).inputs(
        t, h, {body.name: body.rest}, {body.name: np.full_like(body.rest, velocity)}
    )
    return inp[body.name].forces.sum(0)


def test_wind_on_a_plate_facing_it_is_half_rho_cd_a_u2_and_nothing_on_its_back():
    facing = plate("p", 0, flip=True)  # its normal points into the wind (-x)
    expected = 0.5 * AIR_DENSITY * 1.3 * 4.0 * 3.0**2
    np.testing.assert_allclose(total_drag(wind(), facing, 1.0), (expected, 0, 0), atol=1e-12)
    np.testing.assert_allclose(
        total_drag(wind(), facing, 0.12), (expected / 4, 0, 0), atol=1e-12
    )  # half ramp
    np.testing.assert_allclose(total_drag(wind(), facing, 1.0, velocity=1.0), (expected * 4 / 9, 0, 0))
    assert not total_drag(wind(), facing, 2.0).any()  # after the window
    assert not total_drag(wind(), plate("b", 0), 1.0).any()  # the air blows on its back: no pressure there
    edge_on = plate("q", 1)
    both = Actions([wind()], [facing, edge_on]).inputs(
        1.0, 0.01, {"p": facing.rest, "q": edge_on.rest}, {"p": np.zeros((4, 3)), "q": np.zeros((4, 3))}
    )
    np.testing.assert_allclose(both["p"].forces.sum(0), (expected, 0, 0), atol=1e-12)
    assert np.abs(both["q"].forces).max() < 1e-12


def test_wind_on_a_closed_cube_is_the_drag_equation_on_its_front_face():
    import trimesh

    cube = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    body = BodyInfo("c", np.asarray(cube.vertices), np.ones(8), np.asarray(cube.faces))
    expected = 0.5 * AIR_DENSITY * 1.3 * 4.0 * 3.0**2  # front face 2 m x 2 m
    np.testing.assert_allclose(total_drag(wind(), body, 1.0), (expected, 0, 0), atol=1e-9)


def test_gusts_and_turbulence_stay_within_their_bounds():
    facing = plate("p", 0, flip=True)
    calm = 0.5 * AIR_DENSITY * 1.3 * 4.0 * 3.0**2
    gusty = wind(gust=0.3, turbulence=0.5, gust_frequency=2.0)
    totals = np.array([total_drag(gusty, facing, t) for t in np.linspace(0.3, 1.7, 50)])
    assert (totals[:, 0] <= calm * (1 + 0.3 + 0.5) ** 2).all() and (totals[:, 0] >= 0).all()
    assert totals[:, 0].std() > 0.05 * calm  # it does blow in gusts


def test_state_restores_the_captured_anchors():
    pin = ActionSpec("pin", 0.2, 0.9, body="b", region=("z<0.5",))
    actions = [pin, GRAB]
    h = 0.1

    def moving(t):
        return REST + np.array([t, t * t, -t])

    first = Actions(actions, [BODY])
    run(first, [BODY], h, 4, moving)  # both captured by t = 0.3
    saved = first.state()
    assert set(saved) == {"anchor_0", "anchor_1"}
    continued = run(first, [BODY], h, 10, moving, t0=0.4)
    fresh = Actions(actions, [BODY])
    fresh.restore(saved)
    resumed = run(fresh, [BODY], h, 10, moving, t0=0.4)
    for (_, a), (_, b) in zip(continued, resumed, strict=True):
        assert np.array_equal(a["b"].pinned, b["b"].pinned)
        np.testing.assert_array_equal(a["b"].targets, b["b"].targets)
    with pytest.raises(ValueError, match="anchor_2"):
        fresh.restore({"anchor_2": np.zeros((5, 3))})


def test_region_is_every_rule_and_one_selecting_nothing_names_the_action():
    push = ActionSpec("push", 0.0, 0.1, body="b", region=("x>0.5", "z<0.5"), velocity=(1.0, 0, 0))
    [(_, inp)] = run(Actions([push], [BODY]), [BODY], 0.1, 1)
    assert np.flatnonzero(inp["b"].forces[:, 0]).tolist() == [1]  # both rules hold only at vertex 1
    with pytest.raises(SceneError) as err:
        Actions([ActionSpec("pin", 0.0, 1.0, body="b", region=("z<0.5", "z>2"), where=WHERE)], [BODY])
    assert str(err.value).startswith(f"{WHERE} region: 'z>2'") and "(its vertices span z 0 .. 1 m)" in str(
        err.value
    )
    assert "--" not in str(err.value)
    with pytest.raises(SceneError) as err:
        Actions(
            [ActionSpec("pin", 0.0, 1.0, body="b", region=("x>0.5", "y>0.5", "z<0.5"), where=WHERE)], [BODY]
        )
    assert str(err.value) == (
        f"{WHERE} region: 'x>0.5', 'y>0.5', 'z<0.5' together select no vertex of 'b' "
        "(its vertices span x 0 .. 1, y 0 .. 1, z 0 .. 1 m)"
    )
