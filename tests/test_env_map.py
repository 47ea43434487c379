"""The environment map of fields trained on photos without alpha (real captures such as the fox): rays that
leave the field's box see a learnt colour per direction instead of a constant background."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
import trimesh

from neural.asset import load_asset, load_field, save_asset
from neural.data import Normalisation
from neural.field import FieldConfig, HashGridConfig, ShellField
from neural.pipeline import build_field
from neural.render.fullray import render_rays
from neural.render.samples import RaySamples

SMALL = HashGridConfig(n_levels=4, log2_table_size=12, max_resolution=64)


def _no_samples(n: int) -> RaySamples:
    empty = torch.zeros(0)
    return RaySamples(torch.zeros(0, dtype=torch.long), empty, empty, n)


def _dirs(n: int, seed: int = 0) -> torch.Tensor:
    d = torch.randn(n, 3, generator=torch.Generator().manual_seed(seed))
    return d / d.norm(dim=1, keepdim=True)


def _sky(d: torch.Tensor) -> torch.Tensor:
    """A room-like background: bright above, dark brown below, bluish towards +x (R, 3) in [0, 1]."""
    z, x = d[:, 2], d[:, 0]
    return torch.stack([0.5 + 0.3 * z - 0.1 * x, 0.45 + 0.35 * z, 0.4 + 0.2 * z + 0.25 * x], dim=1)


@pytest.mark.parametrize("alphas, expected", [(None, True), (np.ones((1, 2, 2), np.float32), False)])
def test_photos_without_alpha_get_an_environment_map(alphas, expected):
    data = SimpleNamespace(normalisation=Normalisation(np.zeros(3), 1.0), alphas=alphas)
    field = build_field(data, FieldConfig(hashgrid=SMALL), "cpu")
    assert field.config.env_map is expected and (field.env is not None) is expected


def test_rays_leaving_the_box_show_the_environment_not_the_background():
    dirs = _dirs(64)
    plain = ShellField(FieldConfig(hashgrid=SMALL))
    white = torch.ones(3)
    out = render_rays(plain, torch.zeros(64, 3), dirs, _no_samples(64), white)
    torch.testing.assert_close(out["color"], white.expand(64, 3))  # unchanged without an environment map

    field = ShellField(FieldConfig(hashgrid=SMALL, env_map=True))
    out = render_rays(field, torch.zeros(64, 3), dirs, _no_samples(64), white)
    torch.testing.assert_close(out["color"], field.environment(dirs))
    assert not torch.allclose(out["color"], white.expand(64, 3), atol=0.05)


@pytest.mark.slow
def test_the_environment_map_learns_a_background_through_the_renderer():
    torch.manual_seed(0)
    field = ShellField(FieldConfig(hashgrid=SMALL, env_map=True))
    optimizer = torch.optim.Adam(field.parameters(), lr=1e-2)
    for step in range(300):
        dirs = _dirs(512, seed=step)
        out = render_rays(field, torch.zeros(512, 3), dirs, _no_samples(512), torch.ones(3))
        loss = (out["color"] - _sky(dirs)).abs().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    held_out = _dirs(2000, seed=10**6)
    with torch.no_grad():
        error = (field.environment(held_out) - _sky(held_out)).abs().max()
    assert error < 0.03


def test_an_asset_keeps_its_environment_map(tmp_path):
    torch.manual_seed(1)
    field = ShellField(FieldConfig(hashgrid=SMALL, env_map=True), center=(0.1, 0.2, 0.3), scale=2.0)
    with torch.no_grad():
        field.env[-1].bias.copy_(torch.tensor([0.5, -1.0, 2.0]))
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    save_asset(
        tmp_path,
        field,
        ball,
        ball,
        {"name": "env", "normalisation": {"center": [0.1, 0.2, 0.3], "scale": 2.0}},
    )
    loaded = load_field(load_asset(tmp_path))
    dirs = _dirs(32)
    torch.testing.assert_close(loaded.environment(dirs), field.environment(dirs))
