"""neural.config: every config checks its values and names the field and what it takes (ConfigError); the
job settings that set a config's field refuse a bad value with the config's own bound, from the command
line as from the library."""

from __future__ import annotations

import pytest

from neural.config import (
    ConfigError,
    FieldConfig,
    HashGridConfig,
    NarrowBandConfig,
    PipelineConfig,
    ShellConfig,
    Stage1Config,
    Stage2Config,
)
from shellsim.cli.main import main

TRAIN = ["train", "--data", "d", "--out", "o"]

#: (command line, the config built with the same value, the field): each value is out of the bound.
REFUSED = [
    ([*TRAIN, "--kernel-grid", "600"], lambda: FieldConfig(kernel_grid=600), "kernel_grid"),
    ([*TRAIN, "--kernel-grid", "1"], lambda: FieldConfig(kernel_grid=1), "kernel_grid"),
    ([*TRAIN, "--table-size", "31"], lambda: HashGridConfig(log2_table_size=31), "log2_table_size"),
    ([*TRAIN, "--shell-resolution", "4"], lambda: ShellConfig(resolution=4), "resolution"),
    ([*TRAIN, "--steps", "0"], lambda: Stage1Config(steps=0), "steps"),
    ([*TRAIN, "--stage2-steps", "0"], lambda: Stage2Config(steps=0), "steps"),
    ([*TRAIN, "--eval-every", "0"], lambda: Stage1Config(eval_every=0), "eval_every"),
    ([*TRAIN, "--eval-views", "-1"], lambda: Stage1Config(eval_views=-1), "eval_views"),
    ([*TRAIN, "--sharpness", "-1"], lambda: Stage1Config(lambda_k=-1.0), "lambda_k"),
    ([*TRAIN, "--seed", "-1"], lambda: Stage1Config(seed=-1), "seed"),
    ([*TRAIN, "--seed", str(2**31)], lambda: Stage1Config(seed=2**31), "seed"),
    (
        [*TRAIN, "--checkpoint-minutes", "-1"],
        lambda: Stage1Config(checkpoint_seconds=-60.0),
        "checkpoint_seconds",
    ),
    ([*TRAIN, "--downscale", "0"], lambda: PipelineConfig(downscale=0), "downscale"),
    ([*TRAIN, "--bound", "0"], lambda: PipelineConfig(bound=0.0), "bound"),
    ([*TRAIN, "--background", "2,0,0"], lambda: PipelineConfig(background=(2.0, 0.0, 0.0)), "background"),
    (["extract", "--asset", "a", "--v-max", "-1"], lambda: ShellConfig(v_max=-1.0), "v_max"),
    (["extract", "--asset", "a", "--resolution", "4"], lambda: ShellConfig(resolution=4), "resolution"),
    (["extract", "--asset", "a", "--max-peel", "0"], lambda: NarrowBandConfig(max_peel=0), "max_peel"),
    (
        ["eval", "--asset", "a", "--data", "d", "--downscale", "0"],
        lambda: PipelineConfig(downscale=0),
        "downscale",
    ),
]


@pytest.mark.parametrize(
    ("argv", "build", "field"), REFUSED, ids=[f"{r[0][0]} {r[0][-2]}={r[0][-1]}" for r in REFUSED]
)
def test_the_command_line_and_the_library_refuse_with_one_bound(capsys, argv, build, field):
    """The option's one-line error states what the config's ConfigError states it expects."""
    with pytest.raises(ConfigError) as raised:
        build()
    assert raised.value.field == field
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"shellsim: error: {argv[-2]}: expected {raised.value.expected}, got {argv[-1]}"]
    assert str(raised.value).startswith(f"{raised.value.config.__name__}.{field}: expected ")


def test_a_stage_two_seed_follows_the_largest_seed():
    """Stage 2 draws from the seed after stage 1's, within the configs' bound."""
    from shellsim.jobs.train import TrainSettings

    config = TrainSettings("d", "o", seed=2**31 - 1).pipeline_config()
    assert (config.stage1.seed, config.stage2.seed) == (2**31 - 1, 0)


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: Stage1Config(steps=1.5), "Stage1Config.steps: expected an integer >= 1, got 1.5"),
        (
            lambda: Stage1Config(random_background="yes"),
            "Stage1Config.random_background: expected true or false",
        ),
        (lambda: Stage1Config(reg_fraction=0.0), r"Stage1Config.reg_fraction: expected a number in \(0, 1\]"),
        (lambda: Stage2Config(rays=0), "Stage2Config.rays: expected an integer >= 1, got 0"),
        (lambda: ShellConfig(dt=float("nan")), "ShellConfig.dt: expected a number > 0, got nan"),
        (
            lambda: ShellConfig(min_part_fraction=2.0),
            r"ShellConfig.min_part_fraction: expected a number in \[0, 1\]",
        ),
        (lambda: FieldConfig(init_inv_s=0.5), r"FieldConfig.init_inv_s: expected a number in \[1, 100000\]"),
        (lambda: FieldConfig(kernel_grid=True), "FieldConfig.kernel_grid: expected 0 or an integer in"),
        (
            lambda: HashGridConfig(max_resolution=8),
            "HashGridConfig.max_resolution: expected an integer >= 16",
        ),
        (lambda: NarrowBandConfig(delta_s=0.0), "NarrowBandConfig.delta_s: expected a number > 0, got 0"),
        (lambda: PipelineConfig(bound=float("inf")), "PipelineConfig.bound: expected a number > 0, got inf"),
    ],
)
def test_configs_refuse_values_out_of_their_domain(build, message):
    with pytest.raises(ConfigError, match=f"^{message}"):
        build()


def test_the_defaults_are_valid_and_configs_are_value_errors():
    for config in (FieldConfig, HashGridConfig, NarrowBandConfig, PipelineConfig, ShellConfig):
        config()
    assert issubclass(ConfigError, ValueError)
