"""Training settings the tests train their small synthetic scenes with."""

from __future__ import annotations

from neural.config import FieldConfig, HashGridConfig, PipelineConfig
from neural.shell import ShellConfig
from neural.train import Stage1Config, Stage2Config

#: 300 stage-1 and 40 stage-2 steps on a small hash grid: a 32-96 pixel scene trains in about a minute on
#: 2 cores, without periodic evaluations or checkpoints.
SMALL = PipelineConfig(
    field=FieldConfig(hashgrid=HashGridConfig(log2_table_size=14, max_resolution=256)),
    stage1=Stage1Config(
        steps=300,
        target_samples=8192,
        initial_rays=256,
        eval_every=10**6,
        checkpoint_every=10**6,
        occupancy_resolution=32,
        warmup_steps=20,
        eval_views=3,
    ),
    shell=ShellConfig(resolution=96),
    stage2=Stage2Config(steps=40, rays=1024, eval_every=10**6, checkpoint_every=10**6),
    bound=1.0,
)
