"""Crash consistency and one-line errors of every writer under injected faults (issue 44): each writer x
{I/O error, disk full, kill} at every call index up to :data:`BOUND` (``bench/fault_bench.py`` runs them
all), and the messages a user reads."""

import errno

import numpy as np
import pytest
from fault_writers import atomic_case, writers
from faults import FAULTS, injected, sweep

from neural.errors import WriteError

#: Largest call index failed here; the writers but the motion make fewer calls (the bench has no bound).
BOUND = 30

WRITERS = writers()

#: Each writer with each fault; the video's encoder makes each of its cases cost 3-4 s on 2 cores, so they run
#: only in the whole suite (``-m "not slow"`` skips them; ``bench/fault_bench.py`` runs the whole matrix).
CASES = [
    pytest.param(name, fault, marks=pytest.mark.slow) if name == "video (mp4)" else (name, fault)
    for name in WRITERS
    for fault in FAULTS
]


@pytest.mark.parametrize(("name", "fault"), CASES)
def test_writer_survives_every_fault(tmp_path, name, fault):
    tally = sweep(lambda f, k: WRITERS[name](tmp_path, f, k), fault, BOUND)
    assert tally.runs >= 2  # the fault fired at least once
    assert tally.inconsistent == []


def test_the_matrix_sees_a_writer_that_is_not_atomic(tmp_path):
    """A writer that writes its target in place is caught: a torn file is neither old nor new."""

    def in_place(path):
        with open(path, "wb") as f:
            for _ in range(4):
                f.write(b"new" * 100)

    scenario = atomic_case(lambda p: p.write_bytes(b"old"), in_place, lambda p: p.read_bytes(), "x.bin")
    assert sweep(lambda f, k: scenario(tmp_path, f, k), "kill", BOUND).inconsistent


def test_full_disk_in_a_motion_names_file_frames_and_what_was_kept(tmp_path):
    from shellsim.motion.writer import MotionWriter

    rest = np.eye(4, 3)
    writer = MotionWriter(tmp_path / "lego.npz", rest, [[0, 1, 2, 3]], flush_seconds=float("inf"))
    for i in range(9):
        writer.append(rest, 0.1 * i)
        if i in (2, 5):
            writer.flush()
    with injected("enospc", 1), pytest.raises(WriteError) as caught:
        writer.flush()
    assert str(caught.value) == (
        f"{tmp_path / 'lego.npz.partial'}: no space left on device (writing frames 6-8); 6 frames kept; "
        "free space and run the same command to continue"
    )
    assert caught.value.errno == errno.ENOSPC
    writer.close()  # space again: nothing lost
    with np.load(tmp_path / "lego.npz") as motion:
        assert motion["positions"].shape == (9, 4, 3)


def test_a_failing_frame_says_how_many_frames_are_on_disk(tmp_path):
    from shellsim.film.motion_frames import render_frames

    jobs = [(tmp_path / f"{k:05d}.png", {"frame": k}, k) for k in range(5)]
    recipe = lambda: lambda k: (np.full((4, 4, 3), k / 5), {"ms": 1.0})  # noqa: E731
    render_frames(jobs[:2], tmp_path, False, False, recipe)
    with injected("eio", 10**9) as one:  # the calls of one frame
        render_frames([(tmp_path / "scratch" / "0.png", {}, 0)], tmp_path / "scratch", False, False, recipe)
    with injected("eio", one.calls + 1), pytest.raises(WriteError) as caught:  # the second new frame's first
        render_frames(jobs, tmp_path, False, False, recipe)
    message = str(caught.value)
    assert message.startswith(f"{jobs[3][0]}: input/output error (the disk failed); 3 of 5 frames kept in ")
    on_disk = sorted(p.name for p in tmp_path.iterdir() if p.is_file())
    assert on_disk == ["00000.png", "00001.png", "00002.png"]  # no temporary left
