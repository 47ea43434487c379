"""Frames of a motion rendered as Ray tasks on a local instance: the same PNGs bit for bit as the serial
path, and frames already on disk are kept."""

from __future__ import annotations

import pytest

from shellsim.cli.main import main
from shellsim.film.motion_frames import render_motion


@pytest.mark.slow
def test_ray_frames_equal_serial_frames_and_resume(tmp_path):
    motion = tmp_path / "w.npz"
    assert main(["wind", "--asset", "lego", "--frames", "3", "--out", str(motion)]) == 0
    serial = render_motion("lego", motion, tmp_path / "serial", size=(24, 24), progress=False)
    orbit = ["render", "--asset", "lego", "--motion", str(motion), "--camera", "orbit", "--width", "24"]
    assert main([*orbit, "--out", str(tmp_path / "ray"), "--ray"]) == 0  # a local Ray instance
    assert serial.rendered == 3
    for k in range(3):
        name = f"{k:05d}.png"
        assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "serial" / name).read_bytes(), name
    (tmp_path / "ray" / "00001.png").unlink()  # an interrupted run: one frame missing
    again = render_motion("lego", motion, tmp_path / "ray", size=(24, 24), progress=False, ray="local")
    assert (again.rendered, again.skipped) == (1, 2)
    assert (tmp_path / "ray" / "00001.png").read_bytes() == (tmp_path / "serial" / "00001.png").read_bytes()


@pytest.mark.slow
def test_a_worker_killed_mid_render_loses_no_frame(tmp_path, monkeypatch):
    import os
    import signal
    import subprocess

    import shellsim.film.motion_frames as render

    motion = tmp_path / "w.npz"
    assert main(["wind", "--asset", "lego", "--frames", "6", "--out", str(motion)]) == 0
    killed, save = [], render.save_png

    def save_then_kill(path, image, record=None):
        save(path, image, record)
        if not killed:  # after the first frame: kill a worker that is rendering the next one
            found = subprocess.run(
                ["pgrep", "-f", "ray::_run"], capture_output=True, text=True
            ).stdout.split()
            if found:
                os.kill(int(found[0]), signal.SIGKILL)
                killed.append(int(found[0]))

    monkeypatch.setattr(render, "save_png", save_then_kill)
    summary = render_motion("lego", motion, tmp_path / "ray", size=(24, 24), progress=False, ray="local")
    assert killed and summary.rendered == 6
    monkeypatch.setattr(render, "save_png", save)
    serial = render_motion("lego", motion, tmp_path / "serial", size=(24, 24), progress=False)
    assert serial.rendered == 6
    for k in range(6):
        name = f"{k:05d}.png"
        assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "serial" / name).read_bytes(), name


@pytest.mark.parametrize(
    "command", [["render", "--asset", "lego", "--cameras", "none.json"], ["sweep", "--asset", "lego"]]
)
def test_a_missing_cluster_extra_is_one_line_naming_it(tmp_path, capsys, monkeypatch, command):
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    assert main([*command, "--out", str(tmp_path / "out"), "--ray"]) == 2
    err = capsys.readouterr().err
    assert err.endswith("pip install 'shellsim[cluster]'\n") and err.count("\n") == 1
    assert not (tmp_path / "out").exists()
