"""Odd input at the command line: one line ``shellsim: error: ...`` naming the file, exit 2, no traceback."""

import json
import math

import numpy as np
import pytest
import trimesh
from meshes import write_asset_dir
from test_render_cli import write_cameras
from test_render_deformed import make_asset

from shellsim.cli.main import main


def _error(capsys, argv) -> str:
    capsys.readouterr()
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("shellsim: error: ") and "\n" not in err, err
    return err[len("shellsim: error: ") :]


def test_render_refuses_a_camera_file_with_an_all_zero_pose(tmp_path, capsys):
    """The issue's case: it ended in 'ValueError: dirs must be finite' (or rendered garbage)."""
    asset = make_asset(tmp_path / "asset")
    cameras = write_cameras(tmp_path / "cams.json", 2)
    meta = json.loads(cameras.read_text())
    meta["frames"][1]["transform_matrix"] = np.zeros((4, 4)).tolist()
    cameras.write_text(json.dumps(meta))
    err = _error(capsys, ["render", "--asset", asset, "--cameras", cameras, "--out", tmp_path / "out"])
    assert err == f"{cameras}: frame 1 (./views/v_1): 'transform_matrix' is all zeros: not a camera pose"
    assert not list((tmp_path / "out").glob("*.png"))

    meta["frames"][1]["transform_matrix"] = np.eye(4).tolist()
    meta["camera_angle_x"] = math.nan
    cameras.write_text(json.dumps(meta))
    err = _error(capsys, ["render", "--asset", asset, "--cameras", cameras, "--out", tmp_path / "out"])
    assert err == f"{cameras}: top-level 'camera_angle_x' must be a finite number, got nan"


@pytest.mark.parametrize(
    "key, value, words",
    [
        ("up", [math.nan, 0, 1], "'up' must be 3 finite numbers, not all 0, got [nan, 0, 1]"),
        ("up", [0, 0, 0], "'up' must be 3 finite numbers, not all 0, got [0, 0, 0]"),
        ("background", "white", "'background' must be 3 numbers in [0, 1], got 'white'"),
        ("name", ["rod"], "'name' must be a string, got ['rod']"),
        ("training", {"downscale": "x"}, "'training.downscale' must be a whole number >= 1, got 'x'"),
    ],
)
def test_an_asset_json_with_a_bad_optional_key(tmp_path, capsys, key, value, words):
    """Each of these gave a traceback in some command (simulate, wind, render, eval)."""
    shell = trimesh.creation.icosphere(subdivisions=1)
    root = write_asset_dir(tmp_path / "rod", shell, shell, "rod")
    meta = json.loads((root / "asset.json").read_text())
    meta[key] = value
    (root / "asset.json").write_text(json.dumps(meta))
    for command in ("simulate", "wind", "cage"):
        assert _error(capsys, [command, "--asset", root]) == f"{root / 'asset.json'}: {words}"
