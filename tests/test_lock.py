"""One writer per output (``neural.lock``): another process's lock refuses, a killed owner's is taken over,
every command that writes refuses an output being written, and two real ``simulate`` runs on one file."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from neural.lock import OutputBusy, hold_output, lock_path
from shellsim.cli.main import main
from shellsim.motion.read import load_motion

#: A process that locks ``argv[1]``, says so, and holds it until its stdin closes.
HOLDER = """
import sys
from neural.lock import hold_output
with hold_output(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()
"""


@contextlib.contextmanager
def held_elsewhere(path):
    """Another process holding the lock of ``path`` for the ``with`` block; yields its Popen."""
    child = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout.readline().strip() == "held"
        yield child
    finally:
        child.stdin.close()
        child.wait(30)


def test_a_lock_held_by_another_process_is_refused_naming_it(tmp_path):
    out = tmp_path / "motion.npz"
    with held_elsewhere(out) as child:
        with pytest.raises(OutputBusy) as caught:
            with hold_output(out):
                pass
        assert caught.value.pid == child.pid
        assert caught.value.command == f"shellsim {out}"  # the holder's arguments, as run
        assert str(caught.value).startswith(f"{out}: being written by another shellsim (pid {child.pid}: ")
    assert not lock_path(out).exists()  # released by its owner, removed
    with hold_output(out):  # free again
        assert json.loads(lock_path(out).read_text())["pid"] == os.getpid()


def test_the_lock_of_a_killed_process_is_taken_over(tmp_path):
    out = tmp_path / "frames"
    with held_elsewhere(out) as child:
        child.kill()
        child.wait(30)
    assert json.loads(lock_path(out).read_text())["pid"] == child.pid  # left behind by the killed owner
    with hold_output(out):
        assert json.loads(lock_path(out).read_text())["pid"] == os.getpid()
    assert not lock_path(out).exists()


def test_a_lock_is_reentrant_within_a_process_and_released_at_the_outermost_exit(tmp_path):
    out = tmp_path / "asset"
    with hold_output(out):
        with hold_output(tmp_path / ".." / tmp_path.name / "asset"):  # the same output spelled otherwise
            pass
        assert lock_path(out).exists()
        probe = subprocess.run(
            [sys.executable, "-c", HOLDER, str(out)], input="", capture_output=True, text=True
        )
        assert probe.returncode == 1 and "being written by another shellsim" in probe.stderr
    assert not lock_path(out).exists()


def _commands(tmp_path):
    """(argv, the output it writes) of every command that writes, each refused before it reads its inputs."""
    images = tmp_path / "images"
    images.mkdir()
    motion, out = tmp_path / "m.npz", tmp_path / "out"
    return [
        (["simulate", "--asset", "lego", "--out", str(motion), "--overwrite"], motion),
        (
            ["simulate", "--asset", "lego", "--out", str(motion), "--video", str(tmp_path / "v.mp4")],
            tmp_path / "v.mp4",
        ),
        (
            ["simulate", "--asset", "lego", "--out", str(motion), "--video", str(tmp_path / "v.mp4")],
            tmp_path / "v_frames",
        ),
        (["wind", "--asset", "lego", "--out", str(motion)], motion),
        (["render", "--asset", "lego", "--motion", str(motion), "--camera", "orbit", "--out", str(out)], out),
        (["export", "--motion", str(motion), "--format", "ply", "--out", str(out)], out),
        (
            ["sweep", "--asset", "lego", "--material", "rubber", "--drop-height", "0.1", "--out", str(out)],
            out,
        ),
        (["train", "--data", str(tmp_path / "data"), "--out", str(out)], out),
        (["eval", "--asset", "lego", "--data", str(tmp_path / "data"), "--json", str(motion)], motion),
        (["poses", "--images", str(images), "--out", str(out)], out),
    ]


def test_every_command_refuses_an_output_being_written_in_one_line(tmp_path, capsys):
    for argv, output in _commands(tmp_path):
        with held_elsewhere(output) as child:
            capsys.readouterr()
            assert main(argv) == 2, argv
            err = capsys.readouterr().err.strip()
        assert err.startswith(
            f"shellsim: error: {output}: being written by another shellsim (pid {child.pid}: "
        )
        assert "\n" not in err and "; wait for it or choose another --" in err, err
        assert not any(p.name.endswith(".lock") for p in tmp_path.iterdir()), argv  # all released


def test_a_cage_being_built_by_another_process_is_refused(capsys):
    from neural.asset import load_asset
    from shellsim.tetcage.build import CageConfig, shell_digest
    from shellsim.tetcage.store import cached_cage_path

    lego = load_asset("lego")
    entry = cached_cage_path(shell_digest(lego.outer_mesh(), lego.inner_mesh()), CageConfig(target_tets=3000))
    with held_elsewhere(entry) as child:
        capsys.readouterr()
        assert main(["cage", "--asset", "lego", "--tets", "3000"]) == 2
        err = capsys.readouterr().err.strip()
    assert err.startswith(f"shellsim: error: {entry}: being written by another shellsim (pid {child.pid}: ")
    assert err.endswith("; wait for it or choose another output") and not entry.exists()


def _simulate(out, *more):
    argv = ["shellsim", "simulate", "--asset", "lego", "--frames", "40", "--out", str(out), *more]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(path, seconds=60.0):
    deadline = time.monotonic() + seconds
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.05)


@pytest.mark.slow
def test_two_simulations_of_one_motion_the_second_refused_and_sigterm_releases(tmp_path):
    out = tmp_path / "lego_sim.npz"
    first = _simulate(out)
    _wait_for(lock_path(out))
    second = _simulate(out, "--overwrite")
    _, err = second.communicate(timeout=120)
    assert second.returncode == 2
    line = err.strip().splitlines()[-1]
    assert line.startswith(
        f"shellsim: error: {out}: being written by another shellsim (pid {first.pid}: shellsim "
    )
    assert first.wait(120) == 0  # not disturbed
    assert load_motion(out).n_frames == 40 and not lock_path(out).exists()

    third = _simulate(tmp_path / "other.npz")
    _wait_for(tmp_path / "other.npz.partial")
    third.send_signal(signal.SIGTERM)
    assert third.wait(120) == 128 + signal.SIGTERM
    assert not lock_path(tmp_path / "other.npz").exists()  # released on SIGTERM


def test_the_holder_removes_temporaries_of_writers_killed_mid_write(tmp_path):
    """A writer killed between creating its temporary and the rename leaves
    ``.NAME.<pid>-<hex>.partial.SUFFIX`` behind; the next holder of the output's lock removes those of dead
    processes, beside a file and inside a directory, and leaves a live process's and other files alone."""
    from neural.files import temporary_name

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    dead = int(gone.stdout)
    out, frames = tmp_path / "m.npz", tmp_path / "frames"
    frames.mkdir()
    mine = f".{os.getpid()}-"
    left = [
        p.with_name(p.name.replace(mine, f".{dead}-"))
        for p in (temporary_name(out), temporary_name(frames / "00003.png"))
    ]
    other = tmp_path / ".other.123-0000abcd.partial.npz"
    keep = [temporary_name(out), tmp_path / "m.npz.partial", frames / "00002.png", other]  # ours is in use
    for p in [*left, *keep]:
        p.write_bytes(b"x")
    with hold_output(out), hold_output(frames):
        pass
    assert not any(p.exists() for p in left)
    assert all(p.exists() for p in keep)
