"""The examples run on a tiny setting (the shipped LEGO, 2 frames of 16x16 pixels), write what they say and
print none of Warp's lines (its banner, CUDA probe and module loads)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_device import WARP_NOISE

from shellsim.motion.read import load_motion

ROOT = Path(__file__).resolve().parents[1]


def _run(script: str, *argv: str) -> str:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    done = subprocess.run(
        [sys.executable, str(ROOT / "examples" / script), *argv, "--device", "cpu"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    noise = WARP_NOISE.search(done.stdout + done.stderr)
    assert noise is None, noise
    return done.stdout


@pytest.mark.slow
@pytest.mark.parametrize(
    "script, motion, frames",
    [("drop_on_ground.py", "drop.npz", "drop_frames"), ("wind_animation.py", "wind.npz", "frames")],
)
def test_example_runs_tiny(tmp_path, script, motion, frames):
    out = tmp_path / "out"
    printed = _run(script, "--frames", "2", "--size", "16x12", "--out", str(out))
    assert "2 frames in" in printed
    m = load_motion(out / motion)
    assert m.n_frames == 2 and m.asset["name"] == "lego" and len(m.asset["digest"]) == 64
    assert np.abs(m.positions[1] - m.positions[0]).max() > 0  # it moved
    images = sorted((out / frames).glob("*.png"))
    assert [Image.open(p).size for p in images] == [(16, 12)] * 2
    assert (out / motion.replace(".npz", ".mp4")).stat().st_size > 0


@pytest.mark.parametrize(
    "normal, pin, grab, aside",
    [
        ((0.0, 0.0, 1.0), "z<10%", "z>75%", (1, 0, 0)),  # on its table
        ((1.0, 0.0, 0.0), "x<40%", "x>75%", (0, 1, 0)),  # on a wall behind it, facing +x
        ((0.0, -1.0, 0.0), "y>60%", "y<25%", (1, 0, 0)),  # on a wall facing -y
    ],
)
def test_the_real_capture_shot_pins_the_body_where_it_rests(normal, pin, grab, aside):
    import importlib.util
    from types import SimpleNamespace

    from neural.shell.cutout import Cut

    spec = importlib.util.spec_from_file_location("real_capture", ROOT / "examples" / "real_capture.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    body = SimpleNamespace(cut=Cut([-1, -1, -1], [1, 1, 1], [0, 0, 0], normal), up=np.array([0.0, 0.0, 1.0]))
    got_pin, got_grab, got_aside = example.holds(body)
    assert (got_pin, got_grab) == (pin, grab)
    np.testing.assert_allclose(got_aside, aside)
