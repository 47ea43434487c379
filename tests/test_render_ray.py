"""Frames of a motion rendered as Ray tasks on a local instance: the same PNGs bit for bit as the serial
path, and frames already on disk are kept."""

from __future__ import annotations

import pytest

from shellsim.cli import main
from shellsim.render import render_motion

pytestmark = pytest.mark.slow


def test_ray_frames_equal_serial_frames_and_resume(tmp_path):
    motion = tmp_path / "w.npz"
    assert main(["wind", "--asset", "lego", "--frames", "3", "--out", str(motion)]) == 0
    serial = render_motion("lego", motion, tmp_path / "serial", orbit=True, size=(24, 24), progress=False)
    orbit = ["render", "--asset", "lego", "--motion", str(motion), "--orbit", "--width", "24"]
    assert main([*orbit, "--out", str(tmp_path / "ray"), "--ray"]) == 0  # a local Ray instance
    assert serial["rendered"] == 3
    for k in range(3):
        name = f"{k:05d}.png"
        assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "serial" / name).read_bytes(), name
    (tmp_path / "ray" / "00001.png").unlink()  # an interrupted run: one frame missing
    again = render_motion(
        "lego", motion, tmp_path / "ray", orbit=True, size=(24, 24), progress=False, ray="local"
    )
    assert (again["rendered"], again["skipped"]) == (1, 2)
    assert (tmp_path / "ray" / "00001.png").read_bytes() == (tmp_path / "serial" / "00001.png").read_bytes()
