"""neural.asset round trip: a tiny asset saved with save_asset and loaded back gives every weight (the hash
table rounded to float16, as stored), every shell array (as float32, the PLY's type), the field configuration
and every metadata entry exactly."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import torch
import trimesh

from neural.asset import FORMAT, FORMAT_VERSION, HALF_PRECISION, load_asset, load_field, save_asset
from neural.config import NarrowBandConfig
from neural.field import FieldConfig, HashGridConfig, ShellField

#: Every field setting away from its default, so that a setting dropped on the way reads back different.
CONFIG = FieldConfig(
    hashgrid=HashGridConfig(n_levels=3, n_features_per_level=4, log2_table_size=9, base_resolution=4,
                            max_resolution=40),
    geo_hidden=16,
    rad_hidden=24,
    geo_feature_dim=7,
    init_radius=0.3,
    init_inv_s=33.0,
    inv_s_min=2.0,
    inv_s_max=5e4,
    backend="torch",
    cpu_threads=1,
    env_map=True,
    contract=True,
    view_encoding="direction",
    kernel_grid=5,
)  # fmt: skip
META = {
    "name": "tiny",
    "normalisation": {"center": [0.125, -0.3, 2.0], "scale": 1.75},
    "up": [0.0, 1.0, 0.0],
    "background": [0.25, 0.5, 0.0],
    "training": {"downscale": 2, "stage1_steps": 7},
    "narrowband": {"delta_s": 0.02, "w_s": 0.05},
    "shell": {"resolution": 64},
    "metrics": {"psnr": 31.25},
}


def test_an_asset_reads_back_exactly(tmp_path):
    assert all(
        getattr(CONFIG, f.name) != f.default for f in dataclasses.fields(FieldConfig) if f.name != "hashgrid"
    )
    torch.manual_seed(0)
    field = ShellField(CONFIG, center=tuple(META["normalisation"]["center"]), scale=1.75)
    with torch.no_grad():  # weights unlike any initialisation
        for p in field.parameters():
            p.copy_(torch.randn_like(p))
    outer = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    inner = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
    outer.vertices += [0.1, 0.0, -0.3]

    root = save_asset(tmp_path / "tiny", field, outer, inner, META)
    asset = load_asset(root)

    written = json.loads((root / "asset.json").read_text())
    assert asset.meta == written
    assert {k: v for k, v in asset.meta.items() if k in META} == META
    assert (asset.meta["format"], asset.meta["format_version"]) == (FORMAT, FORMAT_VERSION)
    assert (asset.name, asset.scale, asset.training_downscale) == ("tiny", 1.75, 2)
    np.testing.assert_array_equal(asset.center, META["normalisation"]["center"])
    np.testing.assert_array_equal(asset.up, META["up"])
    assert asset.background == tuple(META["background"])
    assert asset.narrowband_config() == NarrowBandConfig(**META["narrowband"])

    loaded = load_field(asset)
    assert loaded.config == CONFIG
    state, back = field.state_dict(), loaded.state_dict()
    assert state.keys() == back.keys()
    for name, value in state.items():
        # the hash table is stored in half precision: exactly its values rounded to float16, back as float32
        expected = value.half().float() if name in HALF_PRECISION else value
        assert back[name].dtype == value.dtype and torch.equal(back[name], expected), name
    table = field.encoding.table
    assert (back["encoding.table"] - table).abs().max() <= table.abs().max() * 2.0**-11  # float16's rounding

    for mesh, read in ((outer, asset.outer_mesh()), (inner, asset.inner_mesh())):
        # the PLY files hold float32 vertices: exactly the shells' vertices rounded to float32
        np.testing.assert_array_equal(read.vertices, mesh.vertices.astype(np.float32))
        np.testing.assert_array_equal(read.faces, mesh.faces)
