"""Settings dataclasses as options: the parser is derived from the dataclass, errors name the option."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from neural.errors import InputError
from shellsim.cli.options import add_options, from_args
from shellsim.errors import SettingError
from shellsim.settings import check_range, float_list, floats, name_list, option


@dataclasses.dataclass(frozen=True)
class Toy:
    name: str = option(help="what to call it", required=True, group="source")
    mesh: str | None = option(help="a mesh file", group="source")
    frames: int = option(90, help="number of frames")
    fps: float = option(30.0, help="frames per second")
    size: float | None = option(help="largest extent in metres", shown_default="the asset's")
    velocity: tuple[float, ...] = option((0.0, 0.0, 0.0), help="initial velocity", parse=floats(3))
    pin: tuple[str, ...] = option(help="a rule", repeat=True, metavar="RULE")
    ground: bool = option(True, help="no ground plane", flag="--no-ground", negate=True)
    mode: str = option("fast", help="how", choices=("fast", "slow"))
    copies: int = option(1, help="copies")
    offset: float = option(0.0, help="offset")
    wait: float = option(0.0, help="how long it waits")
    internal: int = 7

    def __post_init__(self):
        check_range("frames", self.frames, 1, 100, "an integer")


def _parse(argv):
    parser = argparse.ArgumentParser()
    add_options(parser, Toy)
    return parser, parser.parse_args(argv)


def test_defaults_types_and_values_come_from_the_dataclass():
    _, args = _parse(["--name", "a"])
    toy = from_args(Toy, args)
    assert toy == Toy(name="a")
    _, args = _parse(
        ["--mesh", "m.ply", "--frames", "5", "--velocity", "1,2,3", "--pin", "z<1", "--pin", "x>2"]
    )
    toy = from_args(Toy, args, internal=3)
    assert (toy.mesh, toy.frames, toy.velocity, toy.pin, toy.internal) == (
        "m.ply",
        5,
        (1.0, 2.0, 3.0),
        ("z<1", "x>2"),
        3,
    )
    _, args = _parse(["--name", "a", "--no-ground", "--mode", "slow"])
    assert from_args(Toy, args).ground is False and from_args(Toy, args).mode == "slow"


def test_help_shows_each_default_once_and_the_group_is_exclusive_and_required():
    parser, _ = _parse(["--name", "a"])
    text = " ".join(parser.format_help().split())
    assert "number of frames (default 90)" in text
    assert "frames per second (default 30)" in text
    assert "how long it waits (default 0)" in text  # a zero default is shown (0 == False in Python)
    assert "(default the asset's)" in text and "(default 0,0,0)" in text
    assert "copies (default 1)" in text and "offset (default 0)" in text  # 1 == True, 0 == False
    assert "internal" not in text
    with pytest.raises(SystemExit):
        parser.parse_args(["--name", "a", "--mesh", "b"])
    with pytest.raises(SystemExit):
        parser.parse_args([])


def test_errors_name_the_option_at_the_command_line_and_the_field_in_the_library():
    _, args = _parse(["--name", "a", "--frames", "0"])
    with pytest.raises(InputError, match=r"^--frames: expected an integer in \[1, 100\], got 0$"):
        from_args(Toy, args)
    with pytest.raises(SettingError, match=r"^frames: expected an integer"):
        Toy(name="a", frames=0)
    _, args = _parse(["--name", "a", "--velocity", "1,2"])
    with pytest.raises(InputError, match=r"^--velocity: expected 3 comma-separated numbers, got '1,2'$"):
        from_args(Toy, args)


def test_an_option_with_const_takes_an_optional_value_and_lists_parse():
    @dataclasses.dataclass(frozen=True)
    class Job:
        ray: str | None = option(help="Ray address", const="local")
        heights: tuple[float, ...] = option((0.1,), help="heights", parse=float_list)
        names: tuple[str, ...] = option(("a",), help="names", parse=name_list)

    parser = argparse.ArgumentParser()
    add_options(parser, Job)
    assert from_args(Job, parser.parse_args([])) == Job(None, (0.1,), ("a",))
    assert from_args(Job, parser.parse_args(["--ray"])).ray == "local"
    job = from_args(
        Job, parser.parse_args(["--ray", "10.0.0.1:6379", "--heights", "0.1,0.3", "--names", "x, y"])
    )
    assert job == Job("10.0.0.1:6379", (0.1, 0.3), ("x", "y"))
    for argv, message in (
        (["--heights", "0.1,,"], "--heights: expected comma-separated numbers, got '0.1,,'"),
        (["--names", "x,"], "--names: expected comma-separated names, got 'x,'"),
    ):
        with pytest.raises(InputError, match=f"^{message}$"):
            from_args(Job, parser.parse_args(argv))


def test_an_error_of_the_whole_job_names_settings_as_options_at_the_command_line():
    from shellsim.cli.options import options_named

    err = SettingError(None, "frame 3 failed; use more {frames} or a lower {fps}")
    assert str(err) == "frame 3 failed; use more frames or a lower fps"
    with pytest.raises(InputError) as raised, options_named(Toy):
        raise err
    assert str(raised.value) == "frame 3 failed; use more --frames or a lower --fps"


def test_an_option_that_takes_one_value_refuses_a_second():
    """Given twice it used to keep the last value silently; a group's option too. A flag given twice changes
    nothing and a repeat option collects its values."""
    for argv, message in (
        (["--name", "a", "--frames", "5", "--frames", "6"], "--frames given twice (5, then 6)"),
        (["--mesh", "m.ply", "--mesh", "n.ply"], "--mesh given twice (m.ply, then n.ply)"),
        (
            ["--name", "a", "--fps", "1", "--fps", "2.5", "--fps", "3"],
            "--fps given 3 times (1, then 2.5, then 3)",
        ),
    ):
        _, args = _parse(argv)
        with pytest.raises(InputError) as raised:
            from_args(Toy, args)
        assert str(raised.value) == f"{message}; it takes one value"
    _, args = _parse(["--name", "a", "--no-ground", "--no-ground", "--pin", "z<1", "--pin", "x>2"])
    toy = from_args(Toy, args)
    assert toy.ground is False and toy.pin == ("z<1", "x>2")


def test_the_command_refuses_an_option_given_twice_in_one_line(capsys):
    from shellsim.cli.main import main

    assert main(["cage", "--asset", "lego", "--asset", "furry_bunny"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "shellsim: error: --asset given twice (lego, then furry_bunny); it takes one value"
    ]


def test_repeat_options_say_so_in_their_help():
    """Every option of every command that may be repeated says so, and no other one does."""
    from shellsim.cli.main import build_parser

    parser, _ = _parse(["--name", "a"])
    assert "a rule (repeat for several)" in " ".join(parser.format_help().split())
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    repeated = []
    for name, command in commands.items():
        for action in command._actions:
            says = "(repeat for several)" in (action.help or "")
            assert says == isinstance(action, argparse._AppendAction), (name, action.option_strings)
            repeated += action.option_strings[:1] * says
    assert {"--pin", "--sphere", "--box"} <= set(repeated)
