"""The prior for what no training camera saw (neural.visibility), on a block photographed only from above:
trained with it, the field invents nothing below the block's true bottom (without it, the same training grew a
bulge 0.25 below it), its underside takes the colours of the walls beside it rather than the background, and
the asset records the share of its surface that no camera saw."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from configs import SMALL
from scenes import BLOCK, trace_block, write_block_scene

from neural.asset import load_asset, load_field
from neural.pipeline import train_asset
from neural.shell.extract import marching_cubes_mesh, sample_grid

pytestmark = pytest.mark.slow
SIZE = 96  # pixels of the photos: one is 0.022 world units at the block


@pytest.fixture(scope="module")  # trains for about 70 s on 2 cores
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("block")
    data = write_block_scene(root / "data", n_views=24, size=SIZE)
    config = dataclasses.replace(SMALL, stage1=dataclasses.replace(SMALL.stage1, visibility_every=100))
    torch.manual_seed(0)
    asset = load_asset(train_asset(data, root / "asset", config, "cpu", name="block"))
    return asset, load_field(asset)


def _zero_level(field, resolution: int = 96) -> np.ndarray:
    """(V, 3) vertices of the field's zero level over its box."""
    f, _ = sample_grid(lambda u: (field.sdf(u), torch.ones(len(u))), [-1] * 3, [1] * 3, resolution)
    return np.asarray(marching_cubes_mesh(f.numpy(), [-1] * 3, 2.0 / (resolution - 1)).vertices)


def _underside(vertices: np.ndarray) -> np.ndarray:
    """The zero level's vertices below the middle of the block, inside its footprint by 0.1."""
    half = np.asarray(BLOCK.half)
    inner = (np.abs(vertices[:, :2]) < half[:2] - 0.1).all(1) & (vertices[:, 2] < 0)
    return vertices[inner]


def test_the_unseen_underside_invents_no_geometry_below_the_block(block):
    _, field = block
    under = _underside(_zero_level(field))
    bottom = -BLOCK.half[2]
    assert len(under) > 100  # the field closes under the block...
    assert under[:, 2].min() > bottom - 3 * 2.2 / SIZE  # ...no more than three photo pixels below it
    with torch.no_grad():
        inside, below = field.sdf(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, bottom - 0.1]])).tolist()
    assert inside < 0 < below


def test_the_unseen_underside_takes_the_colours_of_the_walls_beside_it(block):
    """Seen from straight below, each underside point has the colour of the nearest wall as the photos show
    it (its shaded albedo), not the white of the training background."""
    _, field = block
    under = torch.tensor(_underside(_zero_level(field)), dtype=torch.float32)
    with torch.no_grad():
        color = field.radiance(
            under, torch.tensor([[0.0, 0.0, 1.0]]).expand(len(under), 3), field.geometry(under)
        )
    half = np.asarray(BLOCK.half)
    p = under.double().numpy()
    # the nearest wall's colour: trace a ray into it horizontally from just outside it
    gap = half[:2] - np.abs(p[:, :2])
    axis = gap.argmin(1)
    origin = p.copy()
    origin[np.arange(len(p)), axis] = np.sign(p[np.arange(len(p)), axis]) * (half[axis] + 1.0)
    origin[:, 2] = -half[2] + 0.02
    direction = np.zeros_like(p)
    direction[np.arange(len(p)), axis] = -np.sign(p[np.arange(len(p)), axis])
    hit, wall = trace_block(origin, direction)
    assert hit.all()
    error = np.abs(color.double().numpy() - wall).mean(1)
    white = (color > 0.85).all(1)
    assert not white.any()
    assert np.median(error) < 0.12, np.median(error)


def test_the_asset_records_the_share_of_its_surface_no_camera_saw(block):
    asset, _ = block
    half = np.asarray(BLOCK.half)
    areas = 4 * np.array([half[0] * half[1], half[1] * half[2], half[0] * half[2]])
    bottom_share = areas[0] / (2 * areas.sum())  # the bottom face: 0.25
    record = asset.meta["visibility"]
    assert record["unseen_surface_share"] == pytest.approx(bottom_share, abs=0.04)
    assert asset.visibility().unseen_surface_share == record["unseen_surface_share"]
    assert -half[2] - 0.07 < record["support_height"] + asset.visibility().lo[2] <= -half[2] + 0.02
