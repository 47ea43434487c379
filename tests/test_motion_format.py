"""Motion file format 2 (shellsim.motion.format): round trip, identities, format 1, interruption, append-only."""

import json
import os
import signal
import subprocess
import sys
import time
import types

import numpy as np
import pytest

from neural.errors import InputError
from shellsim.cli.main import main
from shellsim.motion.format import MAGIC, MotionWriter, Surface, cage_digest, load_motion, save_motion


def _cage(n=5):
    rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])[:n]
    return rest, np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def _frames(rest, n, seed=0):
    rng = np.random.default_rng(seed)
    return (rest + rng.normal(scale=0.1, size=(n, *rest.shape))).astype(np.float32)


def _write(path, n, close=True, **kwargs):
    """A motion of ``n`` frames written one chunk per frame, with a state after each; closed (its chunks
    merged into one) or left as a killed writer leaves it."""
    rest, tets = _cage()
    frames = _frames(rest, n)
    writer = MotionWriter(path, rest, tets, {"fps": 10.0}, flush_seconds=0.0, **kwargs)
    for k, frame in enumerate(frames):
        writer.motion.meta["stats"] = {"frames": k + 1}
        writer.append(frame, k / 10.0, {"velocities": np.full(rest.shape, float(k)), "step": np.int64(k)})
    if close:
        writer.close()
    return rest, tets, frames


@pytest.mark.parametrize("close", [True, False])
def test_round_trip_of_frames_header_meta_and_state(tmp_path, close):
    path = tmp_path / "m.npz"
    surface = Surface(np.array([0, 1]), np.full((2, 4), 0.25), np.array([[0, 1, 0]]))
    asset = {"name": "rod", "digest": "ab" * 32}
    rest, tets, frames = _write(
        path, 7, close, surface=surface, producer="test", settings={"fps": 10.0, "pin": ["z<1"]}, asset=asset
    )
    assert len(_records(path.read_bytes())) == (2 if close else 8)  # the header and the chunks
    m = load_motion(path)
    np.testing.assert_array_equal(m.positions, frames)  # exactly: float32 in, float32 out
    np.testing.assert_array_equal(m.times, np.arange(7) / 10.0)
    np.testing.assert_array_equal(m.rest_vertices, rest)
    np.testing.assert_array_equal(m.tets, tets)
    assert (m.producer, m.settings, m.asset, m.format_version) == (
        "test",
        {"fps": 10.0, "pin": ["z<1"]},
        asset,
        2,
    )
    assert m.meta == {"fps": 10.0, "stats": {"frames": 7}}  # the last chunk's
    np.testing.assert_array_equal(m.state["velocities"], np.full(rest.shape, 6.0))  # after the last frame
    assert m.state["step"] == 6 and m.state["velocities"].dtype == np.float64
    np.testing.assert_array_equal(m.surface.bary, surface.bary)
    # save_motion writes the same content in one chunk
    save_motion(tmp_path / "copy.npz", m)
    copy = load_motion(tmp_path / "copy.npz")
    np.testing.assert_array_equal(copy.positions, frames)
    assert (copy.settings, copy.asset, copy.meta) == (m.settings, m.asset, m.meta)
    np.testing.assert_array_equal(copy.state["velocities"], m.state["velocities"])


def test_the_cage_digest_is_of_the_arrays():
    rest, tets = _cage()
    rest = rest + 0.1  # not a float32
    # sha256 of the shapes and the raw float64 / int64 bytes, computed here by hand
    import hashlib

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


def test_format_1_is_read_but_never_continued(tmp_path, capsys):
    rest, tets = _cage()
    frames = _frames(rest, 3)
    old = tmp_path / "old.npz"
    _format1(old, rest, tets, frames)
    motion = load_motion(old)
    assert motion.format_version == 1 and motion.producer == "shellsim simulate" and motion.state == {}
    np.testing.assert_array_equal(motion.positions, frames)
    motion.check_against(types.SimpleNamespace(vertices=rest, tets=tets))  # its cage by the same digest
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


def test_a_cut_short_last_record_is_dropped_and_resume_writes_after_the_good_ones(tmp_path, caplog):
    path = tmp_path / "m.npz"
    rest, tets, frames = _write(path, 5, close=False)
    whole = path.read_bytes()
    path.write_bytes(whole[:-40])  # the last chunk's write was cut short
    with caplog.at_level("WARNING"):
        motion = load_motion(path)
    assert "incomplete last record" in caplog.text
    assert motion.n_frames == 4
    np.testing.assert_array_equal(motion.positions, frames[:4])
    np.testing.assert_array_equal(motion.state["velocities"], np.full(rest.shape, 3.0))  # of frame 3
    writer = MotionWriter.resume(path, flush_seconds=0.0)
    assert writer.n_frames == 4 and writer.last_time == pytest.approx(0.3)
    writer.append(frames[4], 0.4, {"velocities": np.full(rest.shape, 4.0), "step": np.int64(4)})
    data = path.read_bytes()  # the torn bytes were cut off, not kept before the new chunk:
    assert len(data) == len(whole) and len(_records(data)) == 6  # the header and 5 whole chunks
    writer.close()
    again = load_motion(path)
    np.testing.assert_array_equal(again.positions, frames)
    assert len(_records(path.read_bytes())) == 2  # merged on closing


def test_chunks_are_appended_never_rewritten(tmp_path):
    """Writing N frames costs O(N): after the first flush each flush appends to the same file, leaving
    every byte already written as it was."""
    path = tmp_path / "m.npz"
    rest, tets = _cage()
    writer = MotionWriter(path, rest, tets, flush_seconds=1e9)
    sizes, inodes, previous = [], set(), b""
    for k, frame in enumerate(_frames(rest, 20)):
        writer.append(frame, k)
        writer.flush()
        data = path.read_bytes()
        assert data.startswith(previous)
        previous = data
        sizes.append(len(data))
        inodes.add(path.stat().st_ino)
    assert len(inodes) == 1
    assert len(set(np.diff(sizes))) == 1  # each chunk of one frame costs the same


WRITER = """
import sys, numpy as np
from shellsim.motion.format import MotionWriter
rest = np.random.default_rng(0).normal(size=(2000, 3))
tets = np.array([[0, 1, 2, 3]])
with MotionWriter(sys.argv[1], rest, tets, flush_seconds=0.0) as w:
    for k in range(100000):
        w.append(rest + k, k / 30.0)
"""


def test_a_killed_writer_leaves_its_frames_readable(tmp_path):
    path = tmp_path / "m.npz"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], env=env)
    try:
        deadline = time.monotonic() + 30
        while (not path.exists() or path.stat().st_size < 2_000_000) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    motion = load_motion(path)
    assert motion.n_frames > 10
    k = np.arange(motion.n_frames)
    np.testing.assert_array_equal(motion.times, k / 30.0)
    np.testing.assert_allclose(motion.positions[:, 0, 0] - motion.rest_vertices[0, 0], k, atol=1e-3)


def _records(data: bytes) -> list[bytes]:
    """The records of a format-2 file, split by hand: tag, uint64 little-endian length, npz."""
    assert data.startswith(MAGIC)
    out, pos = [], len(MAGIC)
    while pos < len(data):
        assert data[pos : pos + 4] == b"SSMR"
        n = int.from_bytes(data[pos + 4 : pos + 12], "little")
        out.append(data[pos + 12 : pos + 12 + n])
        pos += 12 + n
    return out


def _frame(npz: bytes) -> bytes:
    return b"SSMR" + len(npz).to_bytes(8, "little") + npz


def test_a_damaged_middle_chunk_or_a_pickled_array_is_one_line(tmp_path):
    import io

    from test_npz_files import Unpickled

    path = tmp_path / "m.npz"
    _write(path, 3, close=False)
    header, *chunks = _records(path.read_bytes())
    assert len(chunks) == 3
    bad = bytearray(chunks[1])
    bad[100] ^= 0xFF  # inside the positions: its CRC no longer matches
    path.write_bytes(MAGIC + _frame(header) + _frame(chunks[0]) + _frame(bytes(bad)) + _frame(chunks[2]))
    with pytest.raises(InputError, match=r"m.npz: not a shellsim motion file \(damaged archive: Bad CRC-32"):
        load_motion(path)

    marker = tmp_path / "unpickled"
    obj = Unpickled()
    obj.marker = marker
    buffer = io.BytesIO()
    rest, _ = _cage()
    np.savez(buffer, positions=rest[None], times=np.zeros(1), meta=np.array([obj], dtype=object))
    path.write_bytes(
        MAGIC + _frame(header) + _frame(chunks[0]) + _frame(buffer.getvalue()) + _frame(chunks[2])
    )
    with pytest.raises(InputError, match=r"not a shellsim motion file \('meta' holds Python objects"):
        load_motion(path)
    assert not marker.exists()
