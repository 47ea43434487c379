"""The job layer (:mod:`shellsim.jobs`): the CLI's options, defaults and help come from the settings, and the
settings' defaults from the library's configs (that library errors name no option: tests/test_layers.py)."""

import argparse
import dataclasses
import re

import pytest

from neural.errors import InputError
from shellsim.cli.main import build_parser, main
from shellsim.cli.options import options_named
from shellsim.errors import SettingError

CONVERTED = ("train", "extract", "cage", "poses", "inspect", "eval", "render")


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def _shown(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


@pytest.mark.parametrize("command", CONVERTED)
def test_help_states_the_default_the_parser_applies(command):
    """Each option with a default says it, as applied; an option without one (None: the asset's, the file's,
    ...) never claims a bare number (extract --resolution said 'default 256' and kept the asset's)."""
    for action in _subparsers()[command]._actions:
        if not action.option_strings or isinstance(action, argparse._HelpAction):
            continue
        stated = re.search(r"\(default:? ([^()]*)\)$", action.help or "")
        default = action.default
        if default is None or isinstance(default, bool):
            assert not (stated and re.fullmatch(r"[-+0-9.e,x ]+", stated[1])), (command, action.help)
        elif isinstance(default, tuple | list):  # parsed values (a colour, a size) show as written
            assert stated, (command, action.option_strings)
        else:
            assert stated and stated[1] == _shown(default), (command, action.option_strings, action.help)


def test_train_defaults_are_the_pipelines():
    """With only data and output given, train trains exactly the library's default pipeline."""
    from neural.pipeline import PipelineConfig
    from shellsim.jobs.train import TrainSettings

    args = build_parser().parse_args(["train", "--data", "d", "--out", "o"])
    from shellsim.cli.options import from_args

    assert from_args(TrainSettings, args).pipeline_config() == PipelineConfig()
    quick = TrainSettings("d", "o", steps=200).pipeline_config()
    assert (quick.stage2.steps, quick.shell.resolution, quick.stage1.target_samples) == (34, 128, 16384)
    gentle = TrainSettings("d", "o", stage2_rate=0.1).pipeline_config()
    assert gentle.stage2.lr_encoding == pytest.approx(0.1 * PipelineConfig().stage1.lr_encoding)
    assert gentle.stage2.lr_network == pytest.approx(0.1 * PipelineConfig().stage1.lr_network)
    with pytest.raises(SettingError, match="^stage2_rate"):
        TrainSettings("d", "o", stage2_rate=0.0)


def test_cage_defaults_are_the_cage_configs(tmp_path):
    from shellsim.jobs.cage import CageSettings
    from shellsim.tetcage.build import CageConfig

    assert CageSettings("a").cage_config() is None  # the asset's own cage, whatever its settings
    assert CageSettings("a", margin=0.05).cage_config() == CageConfig(margin=0.05)
    text = " ".join(_subparsers()["cage"].format_help().split())
    assert f"else {CageConfig.target_tets})" in text and f"else {CageConfig.margin:g})" in text


def test_settings_errors_name_fields_and_the_cli_names_options():
    from shellsim.jobs.poses import PosesSettings
    from shellsim.jobs.render import RenderSettings

    with pytest.raises(SettingError, match=r"^min_registered: expected a fraction in \[0, 1\], got 2$"):
        PosesSettings("i", "o", min_registered=2.0)
    with pytest.raises(SettingError, match=r"^video: needs motion \(without it"):
        RenderSettings(asset="a", cameras="c", out="o", video="v.mp4")
    err = SettingError("out", "/x/t.json already exists; give {overwrite} to replace it", value="/x")
    assert str(err) == "out /x: /x/t.json already exists; give overwrite to replace it"
    with pytest.raises(InputError) as raised, options_named(PosesSettings):
        raise err
    assert str(raised.value) == "--out /x: /x/t.json already exists; give --overwrite to replace it"
    with pytest.raises(SettingError), options_named(PosesSettings):  # not a field of these settings
        raise SettingError("margin", "expected a number")


def test_a_job_time_error_names_the_option(tmp_path, capsys):
    """Errors found while the job runs (a missing directory) name the option too, with the value."""
    assert main(["poses", "--images", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    assert (
        capsys.readouterr().err.strip() == f"shellsim: error: --images {tmp_path / 'none'}: no such directory"
    )


def test_settings_are_frozen_dataclasses_of_options():
    from shellsim.jobs import cage, eval, extract, inspect, poses, render, train

    for settings in (
        train.TrainSettings,
        extract.ExtractSettings,
        cage.CageSettings,
        poses.PosesSettings,
        inspect.InspectSettings,
        eval.EvalSettings,
        render.RenderSettings,
    ):
        assert dataclasses.is_dataclass(settings) and settings.__dataclass_params__.frozen
