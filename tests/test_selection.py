"""shellsim.physics.selection: the one vertex-selection grammar of ``simulate --pin`` and
``wind --anchor``."""

import numpy as np
import pytest
from meshes import kuhn_grid

from neural.errors import InputError
from shellsim.physics.selection import parse_selection, select_vertices
from shellsim.physics.wind import WindField, heights, wind_displacement


@pytest.mark.parametrize(
    "text, axis, op, value, percent",
    [
        ("z<0.1", 2, "<", 0.1, False),
        ("x >= -2", 0, ">=", -2.0, False),
        (" Y>1e-3 ", 1, ">", 1e-3, False),
        ("z<=5%", 2, "<=", 5.0, True),
        ("x>.5", 0, ">", 0.5, False),
    ],
)
def test_rules_parse(text, axis, op, value, percent):
    rule = parse_selection(text)
    assert (rule.axis, rule.op, rule.value, rule.percent, rule.text) == (axis, op, value, percent, text)
    assert rule.sign == (1.0 if op in ("<", "<=") else -1.0)  # +1: the selection lies below the threshold


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os')",
        "z<",
        "q<1",
        "z<1; x>2",
        "z=1",
        "z<nan",
        "z<inf",
        "",
        "1<z",
        "z<1e999",
        "z<<1",
        "z",
        "<1",
        "z<1<2",
        "z<0.1; import os",
        "z < 1 + 1",
        None,
        3,
    ],
)
def test_junk_is_rejected_quoting_the_value_not_an_option(text):
    with pytest.raises(InputError, match="expected AXIS OP VALUE") as err:
        parse_selection(text)
    assert str(err.value).startswith(repr(text)) and "--" not in str(err.value)
    with pytest.raises(InputError) as err:
        parse_selection(text, "anchor")
    assert str(err.value).startswith(f"anchor {text!r}: expected AXIS OP VALUE")


def test_select_vertices_is_the_union_and_refuses_an_empty_rule():
    v = np.array([[0.0, 0, 0], [0, 0, 1], [0, 0, 2], [5, 0, 10]])
    rules = [parse_selection("z<0.5"), parse_selection("x>4")]
    assert select_vertices(rules, v, "--pin").tolist() == [True, False, False, True]
    with pytest.raises(InputError) as err:
        select_vertices([*rules, parse_selection("y > 3")], v, "--pin")
    assert str(err.value) == "--pin: 'y > 3' selects no cage vertex (y spans 0 .. 0)"


def test_selection_in_world_units_and_percent():
    v = np.array([[0.0, 0, 0], [0, 0, 1], [0, 0, 2], [0, 0, 10]])
    assert parse_selection("z<1.5").select(v).tolist() == [True, True, False, False]
    assert parse_selection("z>=15%").select(v).tolist() == [False, False, True, True]  # 15% of 0..10: 1.5
    assert parse_selection("z<=10%").select(v).tolist() == [True, True, False, False]
    assert parse_selection("z<10%").select(v).tolist() == [True, False, False, False]


def test_wind_anchor_takes_the_pin_grammar():
    """``z<5%`` anchors the lowest 5 % of the cage: the same as the default anchor (base_fraction 0.05
    along up = z), so the displacements agree exactly; ``<=`` and ``>=`` are accepted too."""
    verts = kuhn_grid(0.0, (0.2, 0.2, 1.0), (2, 2, 10))[0]
    default = WindField(strength=0.2, turbulence=0.5)
    percent = WindField(strength=0.2, turbulence=0.5, anchor="z<5%")
    np.testing.assert_array_equal(heights(verts, percent), heights(verts, default))
    for t in (0.0, 0.7, 2.3):
        np.testing.assert_array_equal(
            wind_displacement(verts, t, percent), wind_displacement(verts, t, default)
        )
    # '<=' fixes the same vertices as '<': those on the threshold have height 0 and never move
    for a, b in (("z<=0.3", "z<0.3"), ("z>=0.7", "z>0.7")):
        u, w = (wind_displacement(verts, 1.3, WindField(strength=0.2, anchor=s)) for s in (a, b))
        np.testing.assert_array_equal(u, w)
        assert np.abs(u).max() > 0
    hanging = WindField(strength=0.2, anchor="z>=90%")  # hangs from its top 10 %
    fixed = verts[:, 2] >= 0.9
    u = wind_displacement(verts, 1.3, hanging)
    assert fixed.any() and np.array_equal(u[fixed], np.zeros_like(u[fixed])) and np.abs(u[~fixed]).max() > 0


def test_cli_names_the_option(tmp_path, capsys):
    from shellsim.cli.main import main

    for argv, flag in (
        (["wind", "--asset", str(tmp_path / "none"), "--anchor", "z<<1"], "--anchor"),
        (["simulate", "--mesh", str(tmp_path / "none.ply"), "--pin", "z=1", "--device", "cpu"], "--pin"),
    ):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert (
            err.startswith(f"shellsim: error: {flag}: ")
            and "expected AXIS OP VALUE" in err
            and "\n" not in err
        )
