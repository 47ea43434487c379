"""Motion files (shellsim.motion): format 3 a plain npz, the log of a run in progress, formats 2 and 1 read
(and 2 continued), lazy reads of the header and of frame ranges, interruption, append-only logs."""

import hashlib
import io
import json
import logging
import os
import signal
import subprocess
import sys
import time
import types
import zipfile
from pathlib import Path

import numpy as np
import pytest

from neural.errors import InputError
from shellsim.cli.main import main
from shellsim.motion.format import Motion, Surface, save_motion
from shellsim.motion.log import MAGIC, partial_path
from shellsim.motion.read import frame_bounds, iter_frames, load_motion, read_frames, read_motion_info
from shellsim.motion.writer import MotionWriter, motion_exists
from shellsim.tetcage.geometry import cage_digest


def _cage(n=5):
    rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])[:n]
    return rest, np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def _frames(rest, n, seed=0):
    rng = np.random.default_rng(seed)
    return (rest + rng.normal(scale=0.1, size=(n, *rest.shape))).astype(np.float32)


def _state(rest, k):
    return {"velocities": np.full(rest.shape, float(k)), "step": np.int64(k)}


def _write(path, n, close=True, **kwargs):
    """A motion of ``n`` frames written one chunk per frame, with a state after each; closed (published as
    a format-3 npz) or left as a killed writer leaves it (its log only)."""
    rest, tets = _cage()
    frames = _frames(rest, n)
    writer = MotionWriter(path, rest, tets, {"fps": 10.0}, flush_seconds=0.0, **kwargs)
    for k, frame in enumerate(frames):
        writer.motion.meta["stats"] = {"frames": k + 1}
        writer.append(frame, k / 10.0, _state(rest, k))
    if close:
        writer.close()
    return rest, tets, frames


def _assert_same(a, b):
    """Two motions equal bit for bit: arrays, header and state."""
    for name in ("rest_vertices", "tets", "positions", "times"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
    for name in ("meta", "producer", "settings", "asset", "placement", "cage_digest"):
        assert getattr(a, name) == getattr(b, name), name
    assert a.state.keys() == b.state.keys()
    for k in a.state:
        assert a.state[k].tobytes() == b.state[k].tobytes() and a.state[k].dtype == b.state[k].dtype


@pytest.mark.parametrize("close", [True, False])
def test_round_trip_of_frames_header_meta_and_state(tmp_path, close):
    path = tmp_path / "m.npz"
    surface = Surface(np.array([0, 1]), np.full((2, 4), 0.25), np.array([[0, 1, 0]]))
    asset = {"name": "rod", "digest": "ab" * 32}
    placement = {"scale": 0.5, "rotation": np.eye(3).tolist(), "translation": [0.0, 0.0, 0.1]}
    rest, tets, frames = _write(
        path,
        7,
        close,
        surface=surface,
        producer="test",
        settings={"fps": 10.0, "pin": ["z<1"]},
        asset=asset,
        placement=placement,
    )
    if close:  # the finished file alone
        assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]
    else:  # the log alone: its header and the chunks
        assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz.partial"]
        assert len(_records(partial_path(path).read_bytes())) == 8
    m = load_motion(path)
    np.testing.assert_array_equal(m.positions, frames)  # exactly: float32 in, float32 out
    np.testing.assert_array_equal(m.times, np.arange(7) / 10.0)
    np.testing.assert_array_equal(m.rest_vertices, rest)
    np.testing.assert_array_equal(m.tets, tets)
    assert (m.producer, m.settings, m.asset, m.placement, m.format_version) == (
        "test",
        {"fps": 10.0, "pin": ["z<1"]},
        asset,
        placement,
        3,
    )
    assert m.meta == {"fps": 10.0, "stats": {"frames": 7}}  # the last chunk's
    np.testing.assert_array_equal(m.state["velocities"], np.full(rest.shape, 6.0))  # after the last frame
    assert m.state["step"] == 6 and m.state["velocities"].dtype == np.float64
    np.testing.assert_array_equal(m.surface.bary, surface.bary)
    # save_motion writes the same content
    save_motion(tmp_path / "copy.npz", m)
    copy = load_motion(tmp_path / "copy.npz")
    _assert_same(copy, m)


def test_a_finished_motion_is_a_plain_uncompressed_npz(tmp_path):
    path = tmp_path / "m.npz"
    surface = Surface(np.array([0, 1]), np.full((2, 4), 0.25), np.array([[0, 1, 0]]))
    rest, tets, frames = _write(
        path, 6, surface=surface, producer="test", settings={"fps": 10.0}, placement={"scale": 2.0}
    )
    with np.load(path) as data:  # no allow_pickle
        arrays = {k: data[k] for k in data.files}
    assert set(arrays) == {
        "header",
        "rest_vertices",
        "tets",
        "positions",
        "times",
        "surface_tet",
        "surface_bary",
        "surface_faces",
        "state_velocities",
        "state_step",
    }
    assert arrays["rest_vertices"].dtype == np.float64 and arrays["rest_vertices"].shape == (5, 3)
    assert arrays["tets"].dtype == np.int64 and arrays["tets"].shape == (2, 4)
    assert arrays["positions"].dtype == np.float32 and arrays["positions"].tobytes() == frames.tobytes()
    assert arrays["times"].dtype == np.float64 and arrays["times"].tolist() == [k / 10.0 for k in range(6)]
    np.testing.assert_array_equal(arrays["state_velocities"], np.full(rest.shape, 5.0))
    assert arrays["header"].shape == () and arrays["header"].dtype.kind == "U"
    header = json.loads(str(arrays["header"]))
    assert header == {
        "format": "shellsim-motion",
        "format_version": 3,
        "producer": "test",
        "settings": {"fps": 10.0},
        "asset": {},
        "cage": cage_digest(rest, tets),
        "placement": {"scale": 2.0},
        "meta": {"fps": 10.0, "stats": {"frames": 6}},
        "units": "m",
    }
    with zipfile.ZipFile(path) as z:
        assert sorted(z.namelist()) == sorted(f"{k}.npy" for k in arrays)
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
        assert z.testzip() is None
    # what shellsim reads is what numpy reads, bit for bit
    m = load_motion(path)
    for name in ("rest_vertices", "tets", "positions", "times"):
        assert getattr(m, name).tobytes() == arrays[name].tobytes()


def test_the_cage_digest_is_of_the_arrays():
    rest, tets = _cage()
    rest = rest + 0.1  # not a float32
    # sha256 of the shapes and the raw float64 / int64 bytes, computed here by hand
    h = hashlib.sha256()
    for a in (rest.astype(np.float64), tets.astype(np.int64)):
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    assert cage_digest(rest.astype(np.float32), tets.astype(np.int32)) != h.hexdigest()  # float32 rounds
    assert cage_digest(rest, tets.astype(np.int32)) == h.hexdigest()


def test_check_against_accepts_its_cage_and_refuses_another_in_one_line(tmp_path):
    path = tmp_path / "m.npz"
    rest, tets, _ = _write(path, 2)
    motion = load_motion(path)
    motion.check_against(types.SimpleNamespace(vertices=rest.copy(), tets=tets.copy()))
    moved = rest.copy()
    moved[4, 0] += 1e-3  # same size, other digest
    with pytest.raises(InputError) as err:
        motion.check_against(types.SimpleNamespace(vertices=moved, tets=tets))
    message = str(err.value)
    assert message.startswith(f"{path}: the motion's rest cage differs from the asset's cage")
    assert cage_digest(moved, tets)[:12] in message and "\n" not in message
    with pytest.raises(InputError, match="moves 5 cage vertices but the asset's cage has 4"):
        motion.check_against(types.SimpleNamespace(vertices=rest[:4], tets=tets[:1]))


def test_a_placed_motion_is_identified_by_its_cage_in_the_asset_frame(tmp_path):
    """World-placed rest vertices, the digest of the asset-frame cage in the header: the motion moves the
    asset's cage, not a cage at its world position; nothing compares the digest with the rest vertices."""
    rest, tets = _cage()
    world = 0.3 * rest + [0.0, 0.0, 0.1]
    placement = {"scale": 0.3, "rotation": np.eye(3).tolist(), "translation": [0.0, 0.0, 0.1]}
    path = tmp_path / "m.npz"
    with MotionWriter(path, world, tets, placement=placement, cage_digest=cage_digest(rest, tets)) as w:
        for k in range(3):
            w.append(world + 0.01 * k, k / 10.0)
    for motion in (load_motion(path), read_motion_info(path)):
        assert motion.cage_digest == cage_digest(rest, tets) and motion.placement == placement
        np.testing.assert_array_equal(motion.rest_vertices, world)
        motion.check_against(types.SimpleNamespace(vertices=rest, tets=tets))
        with pytest.raises(InputError, match="rest cage differs"):
            motion.check_against(types.SimpleNamespace(vertices=world, tets=tets))
    # continued, the digest and the placement stay
    with MotionWriter.resume(path, flush_seconds=0.0) as w:
        assert w.motion.cage_digest == cage_digest(rest, tets) and w.motion.placement == placement
        w.append(world, 0.3)
    assert load_motion(path).cage_digest == cage_digest(rest, tets)
    # without an explicit digest: that of the rest cage, as before
    assert Motion(world, tets, world[None], np.zeros(1)).cage_digest == cage_digest(world, tets)


def _format1(path, rest, tets, frames):
    """A motion file as shellsim wrote it before format 2: one npz, state as base64 in the meta."""
    meta = {"producer": "shellsim simulate", "params": {"up": [0, 0, 1]}, "state": {"velocities": "AAAA"}}
    np.savez(
        path,
        rest_vertices=rest,
        tets=tets,
        positions=frames,
        times=np.arange(len(frames)) / 30.0,
        meta=np.array(json.dumps(meta)),
    )


def _record(**arrays) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return _frame(buffer.getvalue())


def _format2(path, rest, tets, frames, chunk=3, producer="shellsim wind"):
    """A format-2 file as shellsim wrote it before format 3, built by hand: the magic line, a header record
    and chunks of ``chunk`` frames, each with its meta and the state after its last frame."""
    header = {"producer": producer, "settings": {"fps": 10.0}, "asset": {}, "cage": cage_digest(rest, tets)}
    data = MAGIC + _record(
        format=np.array("shellsim-motion"),
        format_version=np.array(2),
        rest_vertices=rest,
        tets=tets,
        header=np.array(json.dumps(header)),
    )
    for start in range(0, len(frames), chunk):
        end = min(start + chunk, len(frames))
        data += _record(
            positions=frames[start:end],
            times=np.arange(start, end) / 10.0,
            meta=np.array(json.dumps({"fps": 10.0, "stats": {"frames": end}})),
            **{f"state/{k}": v for k, v in _state(rest, end - 1).items()},
        )
    path.write_bytes(data)


@pytest.mark.slow
def test_format_1_is_read_but_never_continued(tmp_path, capsys):
    rest, tets = _cage()
    frames = _frames(rest, 3)
    old = tmp_path / "old.npz"
    _format1(old, rest, tets, frames)
    motion = load_motion(old)
    assert motion.format_version == 1 and motion.producer == "shellsim simulate" and motion.state == {}
    np.testing.assert_array_equal(motion.positions, frames)
    motion.check_against(types.SimpleNamespace(vertices=rest, tets=tets))  # its cage by the same digest
    assert read_motion_info(old).n_frames == 3
    np.testing.assert_array_equal(read_frames(old, [2, 0]), frames[[2, 0]])
    with pytest.raises(
        InputError, match=r"old.npz: motion format 1 \(written by an older shellsim\) cannot be "
    ):
        MotionWriter.resume(old)
    # at the command line: one line, and the file is left alone
    before = old.read_bytes()
    from test_wind import _write_asset

    argv = ["wind", "--asset", str(_write_asset(tmp_path / "rod")), "--out", str(old), "--frames", "2"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"shellsim: error: {old}: motion format 1 (written by an older shellsim) cannot be " + (
        "continued; make it again"
    )
    assert old.read_bytes() == before


def test_format_2_is_read_and_continued_into_format_3(tmp_path):
    rest, tets = _cage()
    frames = _frames(rest, 10)
    old = tmp_path / "old.npz"
    _format2(old, rest, tets, frames[:7])
    motion = load_motion(old)
    assert motion.format_version == 2 and motion.producer == "shellsim wind" and motion.placement == {}
    assert motion.positions.tobytes() == frames[:7].tobytes()
    np.testing.assert_array_equal(motion.times, np.arange(7) / 10.0)
    assert motion.meta == {"fps": 10.0, "stats": {"frames": 7}}
    np.testing.assert_array_equal(motion.state["velocities"], np.full(rest.shape, 6.0))
    assert motion.cage_digest == cage_digest(rest, tets)
    motion.check_against(types.SimpleNamespace(vertices=rest, tets=tets))
    info = read_motion_info(old)
    assert (info.n_frames, info.format_version, info.meta) == (7, 2, motion.meta)

    before = old.read_bytes()
    writer = MotionWriter.resume(old, flush_seconds=0.0)
    assert writer.n_frames == 7 and writer.last_time == pytest.approx(0.6)
    assert writer.last_positions.tobytes() == frames[6].tobytes()
    assert old.read_bytes() == before and not partial_path(old).exists()  # nothing written before a frame
    for k in range(7, 10):
        writer.motion.meta["stats"] = {"frames": k + 1}
        writer.append(frames[k], k / 10.0, _state(rest, k))
    assert old.read_bytes() == before  # the log beside it holds the copy and the new frames
    assert load_motion(partial_path(old)).positions.tobytes() == frames.tobytes()
    writer.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.npz"]
    continued = load_motion(old)
    assert continued.format_version == 3 and continued.positions.tobytes() == frames.tobytes()
    np.testing.assert_array_equal(continued.times, np.arange(10) / 10.0)
    np.testing.assert_array_equal(continued.state["velocities"], np.full(rest.shape, 9.0))
    assert continued.settings == {"fps": 10.0} and continued.cage_digest == cage_digest(rest, tets)


def test_a_cut_short_last_record_is_dropped_and_resume_continues_to_the_same_motion(tmp_path, caplog):
    path, straight = tmp_path / "m.npz", tmp_path / "straight.npz"
    _write(straight, 5)  # the same motion, never interrupted
    rest, tets, frames = _write(path, 5, close=False)
    log = partial_path(path)
    whole = log.read_bytes()
    log.write_bytes(whole[:-40])  # the last chunk's write was cut short
    with caplog.at_level("WARNING"):
        motion = load_motion(path)
    assert "incomplete last record" in caplog.text
    assert motion.n_frames == 4
    np.testing.assert_array_equal(motion.positions, frames[:4])
    np.testing.assert_array_equal(motion.state["velocities"], np.full(rest.shape, 3.0))  # of frame 3
    writer = MotionWriter.resume(path, flush_seconds=0.0)
    assert writer.n_frames == 4 and writer.last_time == pytest.approx(0.3)
    writer.motion.meta["stats"] = {"frames": 5}
    writer.append(frames[4], 0.4, _state(rest, 4))
    data = log.read_bytes()  # the torn bytes were cut off, not kept before the new chunk:
    assert len(data) == len(whole) and len(_records(data)) == 6  # the header and 5 whole chunks
    writer.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz", "straight.npz"]
    _assert_same(load_motion(path), load_motion(straight))


def test_resume_prefers_the_log_to_the_finished_file(tmp_path, monkeypatch):
    """A finished file continued and killed: its log (newer, holding the file's frames too) is continued."""
    monkeypatch.setattr("shellsim.motion.writer._COPY_BATCH", 2)  # the file's frames copied 2 at a time
    path = tmp_path / "m.npz"
    rest, tets, frames = _write(path, 3)
    finished = path.read_bytes()
    writer = MotionWriter.resume(path, flush_seconds=0.0)
    more = _frames(rest, 2, seed=1)
    for k, frame in enumerate(more):
        writer.append(frame, (3 + k) / 10.0, _state(rest, 3 + k))
    del writer  # killed: the log and the old file
    assert path.read_bytes() == finished and partial_path(path).is_file()
    assert len(_records(partial_path(path).read_bytes())) == 5  # header, 2 + 1 frames copied, 2 new
    assert load_motion(path).n_frames == 3  # the finished file, as long as it is there
    writer = MotionWriter.resume(path, flush_seconds=0.0)
    assert writer.n_frames == 5 and writer.last_positions.tobytes() == more[-1].tobytes()
    np.testing.assert_array_equal(writer.motion.state["velocities"], np.full(rest.shape, 4.0))
    writer.close()
    motion = load_motion(path)
    np.testing.assert_array_equal(motion.positions, np.concatenate([frames, more]))
    np.testing.assert_array_equal(motion.times, np.arange(5) / 10.0)


def test_a_finished_file_continued_without_a_frame_is_left_as_it_was(tmp_path):
    path = tmp_path / "m.npz"
    _write(path, 3)
    before, stat = path.read_bytes(), path.stat()
    with MotionWriter.resume(path) as writer:
        assert writer.n_frames == 3
    assert path.read_bytes() == before and path.stat().st_mtime_ns == stat.st_mtime_ns
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_a_new_motion_replaces_the_file_from_its_first_chunk_and_only_its_log_is_read(tmp_path, caplog):
    path = tmp_path / "m.npz"
    _write(path, 6)
    assert motion_exists(path)
    rest, tets = _cage()
    writer = MotionWriter(path, rest, tets, flush_seconds=1e9, producer="new")
    writer.append(rest, 0.0)
    assert path.is_file()  # nothing written yet
    writer.flush()
    assert not path.exists() and motion_exists(path)  # the old motion is gone; the new one's log is there
    with caplog.at_level(logging.INFO, logger="shellsim.motion.read"):
        motion = load_motion(path)
    assert motion.producer == "new" and motion.n_frames == 1 and motion.path == str(partial_path(path))
    assert caplog.text.count("reading m.npz.partial, the log of a run in progress") == 1
    writer.close()
    assert load_motion(path).producer == "new"


def test_chunks_are_appended_never_rewritten(tmp_path):
    """Writing N frames costs O(N): after the first flush each flush appends to the same log, leaving
    every byte already written as it was."""
    path = tmp_path / "m.npz"
    rest, tets = _cage()
    writer = MotionWriter(path, rest, tets, flush_seconds=1e9)
    sizes, inodes, previous = [], set(), b""
    for k, frame in enumerate(_frames(rest, 20)):
        writer.append(frame, k)
        writer.flush()
        data = partial_path(path).read_bytes()
        assert data.startswith(previous)
        previous = data
        sizes.append(len(data))
        inodes.add(partial_path(path).stat().st_ino)
    assert len(inodes) == 1
    assert len(set(np.diff(sizes))) == 1  # each chunk of one frame costs the same
    writer.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]  # no temporary file, no log


WRITER = """
import sys, numpy as np
from shellsim.motion.writer import MotionWriter
rest = np.random.default_rng(0).normal(size=(2000, 3))
tets = np.array([[0, 1, 2, 3]])
with MotionWriter(sys.argv[1], rest, tets, flush_seconds=0.0) as w:
    for k in range(100000):
        w.append(rest + k, k / 30.0)
"""


def test_a_killed_writer_leaves_its_frames_readable_and_continued(tmp_path):
    path = tmp_path / "m.npz"
    log = partial_path(path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], env=env)
    try:
        deadline = time.monotonic() + 30
        while (not log.exists() or log.stat().st_size < 2_000_000) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert not path.exists()
    motion = load_motion(path)
    assert motion.n_frames > 10
    k = np.arange(motion.n_frames)
    np.testing.assert_array_equal(motion.times, k / 30.0)
    np.testing.assert_allclose(motion.positions[:, 0, 0] - motion.rest_vertices[0, 0], k, atol=1e-3)
    n = motion.n_frames
    with MotionWriter.resume(path) as writer:
        writer.append(motion.rest_vertices + n, n / 30.0)
    assert load_motion(path).n_frames == n + 1 and not log.exists()


def _indices(rng, n_frames):
    """Index sets: random, unsorted with repeats, a range, one frame, the last, none."""
    return [
        rng.choice(n_frames, size=7, replace=False),
        rng.integers(0, n_frames, size=12),
        np.arange(3, 9),
        [0],
        [n_frames - 1],
        [],
    ]


@pytest.mark.parametrize("kind", ["format 3", "log", "format 2", "format 1", "compressed"])
def test_read_frames_equals_slicing_the_full_load(tmp_path, kind, rng):
    path = tmp_path / "m.npz"
    rest, tets = _cage()
    frames = _frames(rest, 23)
    if kind in ("format 3", "log"):
        writer = MotionWriter(path, rest, tets, flush_seconds=1e9)
        for k, frame in enumerate(frames):
            writer.append(frame, k / 10.0)
            if k % 4 == 3:
                writer.flush()  # chunks of 4 frames
        writer.close() if kind == "format 3" else writer.flush()
    elif kind == "format 2":
        _format2(path, rest, tets, frames, chunk=5)
    elif kind == "format 1":
        _format1(path, rest, tets, frames)
    else:  # a format-3 file someone compressed: read through the zip, not by offset
        save_motion(tmp_path / "plain.npz", Motion(rest, tets, frames, np.arange(23) / 10.0))
        with np.load(tmp_path / "plain.npz") as data:
            np.savez_compressed(path, **{k: data[k] for k in data.files})
    full = load_motion(path).positions
    assert full.tobytes() == frames.tobytes()
    for indices in _indices(rng, 23):
        got = read_frames(path, indices)
        assert got.dtype == np.float32 and got.shape == (len(indices), 5, 3)
        assert got.tobytes() == full[np.asarray(indices, int)].tobytes()
    batches = list(iter_frames(path, range(23), batch=10))
    assert [len(b) for b in batches] == [10, 10, 3] and np.concatenate(batches).tobytes() == frames.tobytes()
    np.testing.assert_array_equal(frame_bounds(path), [full.min(axis=(0, 1)), full.max(axis=(0, 1))])
    np.testing.assert_array_equal(frame_bounds(path, lambda p: -p), [-full.max((0, 1)), -full.min((0, 1))])
    info = read_motion_info(path)
    assert info.n_frames == 23 and info.times.tolist() == load_motion(path).times.tolist()
    with pytest.raises(ValueError, match=r"indices: .*m.npz.* has frames 0..22, got \[23\]"):
        read_frames(path, [3, 23])
    with pytest.raises(ValueError, match=r"got \[-1\]"):
        read_frames(path, [-1])


def _bytes_read() -> int:
    """Bytes this process has read from files (and pipes) so far: Linux's ``rchar``."""
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("rchar:"):
            return int(line.split()[1])
    raise AssertionError("no rchar in /proc/self/io")


@pytest.mark.skipif(not Path("/proc/self/io").exists(), reason="counts bytes read with Linux's /proc/self/io")
@pytest.mark.parametrize("finished", [True, False])
def test_a_frame_range_or_the_header_reads_a_small_part_of_the_file(tmp_path, finished):
    """Reading 10 of 1000 frames (or the header) reads a small part of the file's bytes, counted by the
    kernel; reading them all reads it all."""
    path = tmp_path / "m.npz"
    rest = np.random.default_rng(0).normal(size=(300, 3))
    writer = MotionWriter(path, rest, np.array([[0, 1, 2, 3]]), flush_seconds=1e9)
    for k in range(1000):
        writer.append(rest + k, k / 30.0, {"velocities": np.zeros_like(rest)})
        if k % 10 == 9:
            writer.flush()  # chunks of 10 frames
    writer.close() if finished else writer.flush()
    size = (path if finished else partial_path(path)).stat().st_size
    assert size > 1000 * 300 * 12

    read_frames(path, [0])  # the modules a first read imports are not the file's bytes

    def read(what):
        before = _bytes_read()
        result = what()
        return result, _bytes_read() - before

    frames, spent = read(lambda: read_frames(path, np.arange(200, 210)))
    np.testing.assert_allclose(frames[:, 0], rest[0] + np.arange(200, 210)[:, None], atol=1e-3)
    assert spent < (0.02 if finished else 0.1) * size, (spent, size)  # 1%; the log: the headers of each chunk
    info, spent = read(lambda: read_motion_info(path))
    assert info.n_frames == 1000 and spent < (0.015 if finished else 0.1) * size, (spent, size)
    _, spent = read(lambda: load_motion(path))
    assert spent > 1000 * 300 * 12  # every frame


def _frame(npz: bytes) -> bytes:
    return b"SSMR" + len(npz).to_bytes(8, "little") + npz


def _records(data: bytes) -> list[bytes]:
    """The records of a log (or format-2 file), split by hand: tag, uint64 little-endian length, npz."""
    assert data.startswith(MAGIC)
    out, pos = [], len(MAGIC)
    while pos < len(data):
        assert data[pos : pos + 4] == b"SSMR"
        n = int.from_bytes(data[pos + 4 : pos + 12], "little")
        out.append(data[pos + 12 : pos + 12 + n])
        pos += 12 + n
    return out


def test_a_damaged_middle_chunk_or_a_pickled_array_is_one_line(tmp_path):
    from test_npz_files import Unpickled

    path = tmp_path / "m.npz"
    log = partial_path(path)
    _write(path, 3, close=False)
    header, *chunks = _records(log.read_bytes())
    assert len(chunks) == 3
    bad = bytearray(chunks[1])
    bad[250] ^= 0xFF  # inside the positions: its CRC no longer matches
    log.write_bytes(MAGIC + _frame(header) + _frame(chunks[0]) + _frame(bytes(bad)) + _frame(chunks[2]))
    with pytest.raises(InputError, match=r"m.npz.partial: not a shellsim motion file \(damaged archive: Bad"):
        load_motion(path)

    marker = tmp_path / "unpickled"
    obj = Unpickled()
    obj.marker = marker
    buffer = io.BytesIO()
    rest, _ = _cage()
    np.savez(buffer, positions=rest[None], times=np.zeros(1), meta=np.array([obj], dtype=object))
    pickled = _frame(buffer.getvalue())
    log.write_bytes(MAGIC + _frame(header) + _frame(chunks[0]) + pickled + _frame(chunks[2]))
    for read in (load_motion, read_motion_info, lambda p: read_frames(p, [0])):
        with pytest.raises(InputError, match=r"not a shellsim motion file \('meta' holds Python objects"):
            read(path)
    assert not marker.exists()


def _cut(path, size):
    path.write_bytes(path.read_bytes()[:size])


def _truncated_npz(path):
    _write(path, 20)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _bad_header(path, **changes):
    m = Motion(*_cage(), _frames(_cage()[0], 2), np.arange(2) / 10.0)
    save_motion(path, m)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    header = {**json.loads(str(arrays["header"])), **changes}
    arrays["header"] = np.array(json.dumps(header))
    np.savez(path, **arrays)


CORRUPT = {
    "truncated npz": (_truncated_npz, "m.npz", "damaged archive"),
    "log cut in its header": (
        lambda p: _write(p, 3, close=False) and _cut(partial_path(p), 300),
        "m.npz.partial",
        "no complete chunk of frames",
    ),
    "log of junk": (
        lambda p: partial_path(p).write_bytes(MAGIC + 2 * (b"SSMR" + (20).to_bytes(8, "little") + b"x" * 20)),
        "m.npz.partial",
        "damaged archive",
    ),
    "log without its magic": (lambda p: partial_path(p).write_bytes(b"SSMR" * 10), "m.npz.partial", ".npz"),
    "format 4": (lambda p: _bad_header(p, format_version=4), "m.npz", "motion format 4; this shellsim reads"),
    "another format": (lambda p: _bad_header(p, format="other"), "m.npz", "header is not that of a"),
    "no cage digest": (lambda p: _bad_header(p, cage=None), "m.npz", "its header has no cage digest"),
    "placement a list": (lambda p: _bad_header(p, placement=[1]), "m.npz", "header.placement must be a JSON"),
}


@pytest.mark.parametrize("kind", CORRUPT)
def test_corrupt_files_are_one_error_naming_the_file(tmp_path, kind):
    path = tmp_path / "m.npz"
    make, name, reason = CORRUPT[kind]
    make(path)
    for read in (load_motion, read_motion_info, MotionWriter.resume):
        with pytest.raises(InputError) as err:
            read(path)
        message = str(err.value)
        assert message.startswith(f"{tmp_path / name}: not a shellsim motion file (") and reason in message
        assert "\n" not in message and "pickle" not in message
    with pytest.raises(InputError, match=f"^{tmp_path / name}: "):
        read_frames(path, [0])
