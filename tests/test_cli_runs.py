"""Command runs under faults: unwritable outputs fail at once in one line, SIGTERM saves what was made like
Ctrl-C, and Warp prints nothing on stdout unless --verbose."""

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid, save_collision_surface, save_embedded_cage, write_asset_dir

from shellsim.cli import main as cli
from shellsim.cli.main import Terminated, main
from shellsim.io.outputs import check_writable_dir, check_writable_file
from shellsim.motion.read import load_motion
from shellsim.motion.writer import motion_exists

REPO = Path(__file__).resolve().parents[1]


def rod_asset(root: Path, with_cage: bool = True) -> Path:
    """A minimal z-up asset (cylinder shells, placeholder field), with a hand-made Kuhn-box cage.npz and M- as
    its collision surface."""
    from neural.asset import load_asset

    outer = trimesh.creation.cylinder(radius=0.15, height=1.0, sections=24)
    outer.apply_translation([0.0, 0.0, 0.5])
    inner = trimesh.creation.cylinder(radius=0.1, height=0.9, sections=24)
    inner.apply_translation([0.0, 0.0, 0.5])
    asset = load_asset(write_asset_dir(root, outer, inner, "rod", center=(0, 0, 0.5), up=(0, 0, 1)))
    if with_cage:
        verts, tets, _ = kuhn_grid(0.0, (0.4, 0.4, 1.1), (2, 2, 6))
        cage = save_embedded_cage(asset, verts - [0.2, 0.2, 0.05], tets)
        save_collision_surface(asset, cage, inner)
    return asset.root


@pytest.fixture
def blocker(tmp_path) -> Path:
    """A regular file: nothing can be written under it, not even by root (chmod does not stop root)."""
    path = tmp_path / "plain.txt"
    path.write_text("not a directory")
    return path


def test_helper_accepts_new_directories_and_leaves_nothing_behind(tmp_path):
    assert check_writable_dir(tmp_path / "a" / "b", "--out") == tmp_path / "a" / "b"
    assert check_writable_file(tmp_path / "c" / "m.npz", "--out") == tmp_path / "c" / "m.npz"
    assert list(tmp_path.iterdir()) == []


def test_helper_refuses_paths_under_a_file_and_names_taken_by_directories(tmp_path, blocker):
    expected = r"^--out .*plain.txt/x/m.npz: cannot write here \(.*plain.txt is a file, not a directory"
    with pytest.raises(ValueError, match=expected):
        check_writable_file(blocker / "x" / "m.npz", "--out")
    with pytest.raises(ValueError, match="--video .*: cannot write here .a directory has this name"):
        check_writable_file(tmp_path, "--video")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root ignores permission bits")
def test_helper_refuses_a_read_only_directory(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        with pytest.raises(ValueError, match="not writable"):
            check_writable_dir(locked / "frames", "--out")
    finally:
        locked.chmod(0o755)


def _fails_in_one_line(argv, capsys, path) -> None:
    start = time.perf_counter()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("shellsim:")]
    assert len(lines) == 1 and "cannot write here" in lines[0] and str(path) in lines[0], err
    assert time.perf_counter() - start < 20  # before the work, not after it


def test_every_command_checks_its_outputs_first(tmp_path, blocker, capsys):
    asset = str(rod_asset(tmp_path / "rod"))
    bad = blocker / "out"
    motion = tmp_path / "wind.npz"
    assert main(["wind", "--asset", asset, "--frames", "2", "--out", str(motion), "--anchor", "z<0.1"]) == 0
    capsys.readouterr()
    cases = [
        ["simulate", "--asset", asset, "--frames", "400", "--out", str(bad / "m.npz")],
        ["simulate", "--asset", asset, "--frames", "400", "--out", str(tmp_path / "m.npz"),
         "--video", str(bad / "m.mp4")],
        ["wind", "--asset", asset, "--frames", "400", "--out", str(bad / "w.npz")],
        ["render", "--asset", asset, "--motion", str(motion), "--out", str(bad / "frames")],
        ["render", "--asset", asset, "--motion", str(motion), "--out", str(tmp_path / "frames"),
         "--video", str(bad / "v.mp4")],
        ["inspect", "--asset", asset, "--screenshot", str(bad / "s.png")],
        ["train", "--data", str(tmp_path / "no_data"), "--out", str(bad / "asset")],
        ["eval", "--asset", asset, "--data", str(tmp_path / "no_data"), "--json", str(bad / "e.json")],
    ]  # fmt: skip
    for argv in cases:
        _fails_in_one_line(argv, capsys, bad)
    assert not (tmp_path / "m.npz").exists() and not (tmp_path / "frames").exists()


def test_a_cage_that_cannot_be_saved_is_not_built(tmp_path, capsys):
    """Without cage.npz the cage is built into the asset; where it cannot be saved the command stops first
    (today: fTetWild runs, then a traceback). A directory named cage.npz blocks the save even for root."""
    asset = rod_asset(tmp_path / "rod", with_cage=False)
    (asset / "cage.npz").mkdir()
    wind = ["wind", "--asset", str(asset), "--out", str(tmp_path / "w.npz")]
    for argv in (["cage", "--asset", str(asset)], wind):
        _fails_in_one_line(argv, capsys, asset / "cage.npz")


def _cli(logs: Path, *args: str) -> subprocess.Popen:
    """``python -m shellsim.cli.main ARGS`` in the background, its stdout and stderr going to files in
    (pipes that nobody reads would fill up with the progress bar and block the command)."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "PYTHONFAULTHANDLER": "1"}
    with open(logs / "stdout.txt", "w") as stdout, open(logs / "stderr.txt", "w") as stderr:
        return subprocess.Popen(
            [sys.executable, "-m", "shellsim.cli.main", *args], env=env, stdout=stdout, stderr=stderr
        )


def _outputs(logs: Path) -> tuple[str, str]:
    return (logs / "stdout.txt").read_text(), (logs / "stderr.txt").read_text()


def _frames_shown(logs: Path) -> int:
    """Frames in the motion file once the simulate bar on stderr reads ``k/N``: frame 0 and k steps."""
    counts = re.findall(r"(\d+)/\d+ \[", _outputs(logs)[1])
    return int(counts[-1]) + 1 if counts else 0


@pytest.mark.slow
def test_sigterm_keeps_the_frames_made_and_warp_is_quiet(tmp_path):
    """A simulation killed by SIGTERM after its first flush, once its progress bar shows two frames more
    than the file holds, exits 143 with one line, and its motion file holds every frame the bar showed:
    the writer closed as on Ctrl-C. Warp's banner and module-load lines stay off stdout."""
    asset = rod_asset(tmp_path / "rod")
    out = tmp_path / "m.npz"
    proc = _cli(
        tmp_path, "simulate", "--asset", str(asset), "--frames", "10000", "--pin", "z<20%", "--out", str(out)
    )
    try:
        deadline = time.monotonic() + 120
        while not motion_exists(out) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert motion_exists(out), _outputs(tmp_path)[1][-2000:]
        first = load_motion(out).n_frames
        while (made := _frames_shown(tmp_path)) < first + 2 and proc.poll() is None:
            assert time.monotonic() < deadline, _outputs(tmp_path)[1][-2000:]
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)  # faulthandler prints where it hangs
            proc.wait(timeout=30)
            pytest.fail(f"no exit 120 s after SIGTERM:\n{_outputs(tmp_path)[1][-4000:]}")
    finally:
        proc.kill()
    stdout, stderr = _outputs(tmp_path)
    assert proc.returncode == 128 + signal.SIGTERM, stderr[-2000:]
    assert stderr.splitlines()[-1] == "shellsim: terminated; what was written so far is kept"
    motion = load_motion(out)
    assert motion.n_frames >= made > first + 1
    assert np.isfinite(motion.positions).all()
    assert "Warp" not in stdout and "Module" not in stdout, stdout
    assert "Warp" not in stderr, stderr  # not even the CUDA probe's line on a machine without a GPU


@pytest.mark.parametrize(
    ("signum", "raised"), [(signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)]
)
def test_a_signal_that_lands_in_a_finalizer_is_not_lost(signum, raised):
    """A signal whose handler runs inside ``__del__`` (Warp frees arrays there) would raise where Python drops
    the exception; the command's handler sends it again instead, and it then interrupts the program."""
    handled = []

    class Freed:
        def __del__(self):
            os.kill(os.getpid(), signum)  # the handler runs at the next instruction, still in __del__
            handled.append("in __del__")

    previous = signal.signal(signum, cli._interrupt)
    try:
        with pytest.raises(raised):
            Freed()  # dropped at once: __del__ runs here
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                time.sleep(0.001)
        assert handled == ["in __del__"]  # the first delivery did not break the finalizer
    finally:
        signal.signal(signum, previous)


@pytest.mark.slow
def test_verbose_shows_warp_messages(tmp_path):
    asset = rod_asset(tmp_path / "rod")
    proc = _cli(
        tmp_path, "-v", "simulate", "--asset", str(asset), "--frames", "2", "--out", str(tmp_path / "m.npz")
    )
    proc.wait(timeout=120)
    stdout, stderr = _outputs(tmp_path)
    assert proc.returncode == 0, stderr[-2000:]
    assert "Warp" in stdout and "Module" in stdout


@pytest.mark.slow
def test_ctrl_c_still_interrupts_after_a_cage_build(tmp_path):
    """fTetWild resets the SIGINT handler; after a cage build, Ctrl-C must still raise KeyboardInterrupt (so
    writers save) instead of killing the process."""
    code = (
        "import os, signal, time, trimesh\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"  # as in a terminal, whatever started us
        "from shellsim.tetcage.build import build_cage\n"
        "m = trimesh.creation.icosphere(subdivisions=2)\n"
        "build_cage(m, m.copy())\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(5)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted')\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "interrupted", (
        done.returncode,
        done.stderr[-2000:],
    )
