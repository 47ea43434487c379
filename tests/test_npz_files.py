"""Motion and cage files (shellsim.io.npz, shellsim.motion): anything that is not one is one line naming the
file, never a traceback and never numpy's advice to unpickle; npz archives written block by block."""

import json
import re
import zipfile

import numpy as np
import pytest

from neural.errors import InputError
from shellsim.cli.main import main
from shellsim.io.npz import Blocks, load_npz, write_npz
from shellsim.motion.format import FORMAT1_KEYS, KEYS, Motion, save_motion
from shellsim.motion.read import load_motion, read_frames, read_motion_info


def _motion(n_frames=3):
    rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    frames = np.stack([rest + 0.1 * k for k in range(n_frames)])
    return Motion(rest, np.array([[0, 1, 2, 3]]), frames, np.arange(n_frames) / 10.0, {"fps": 10.0})


def _arrays(**changes):
    m = _motion()
    arrays = {
        "rest_vertices": m.rest_vertices,
        "tets": m.tets,
        "positions": m.positions.astype(np.float32),
        "times": m.times,
        "meta": np.array(json.dumps(m.meta)),
    }
    arrays.update(changes)
    return {k: v for k, v in arrays.items() if v is not None}


class Unpickled:
    """Unpickling an instance writes a marker file: the loader must refuse the array before that."""

    marker = None

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def _write_pickled(path, marker):
    obj = Unpickled()
    obj.marker = marker
    np.savez(path, **_arrays(meta=np.array([obj], dtype=object)))


def _truncated(path):
    np.savez(path, **_arrays())  # format 1
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _bit_flipped(path):
    np.savez(path, **_arrays())  # format 1
    data = bytearray(path.read_bytes())
    data[200] ^= 0xFF  # inside the first member's data: its CRC no longer matches
    path.write_bytes(bytes(data))


def _zip_of_other_things(path):
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("readme.txt", "hello")


JUNK = {
    "text": (lambda p: p.write_text("my notes\n"), "not an .npz archive"),
    "empty": (lambda p: p.write_bytes(b""), "the file is empty"),
    "npy": (
        lambda p: np.save(p.with_suffix(".npy"), np.zeros(3)) or p.with_suffix(".npy").rename(p),
        "not an .npz",
    ),
    "json": (lambda p: p.write_text('{"frames": []}'), "not an .npz archive"),
    "truncated": (_truncated, "damaged archive"),
    "bit flipped": (_bit_flipped, "damaged archive: Bad CRC-32"),
    "other zip": (_zip_of_other_things, "missing the arrays rest_vertices, tets, positions, times, header"),
    "missing key": (lambda p: np.savez(p, **_arrays(times=None)), "missing the array times"),
    "positions as text": (
        lambda p: np.savez(p, **_arrays(positions=np.full((3, 4, 3), "x"))),
        "positions must hold floats",
    ),
    "tets as floats": (
        lambda p: np.savez(p, **_arrays(tets=np.zeros((1, 4)))),
        r"tets: expected \(T, 4\) integers",
    ),
    "frames of other vertices": (
        lambda p: np.savez(p, **_arrays(positions=np.zeros((3, 5, 3)))),
        r"\(F, 4, 3\)",
    ),
    "times of other frames": (lambda p: np.savez(p, **_arrays(times=np.zeros(2))), r"times must be \(3,\)"),
    "NaN frame": (
        lambda p: np.savez(
            p, **_arrays(positions=np.where(np.arange(3)[:, None, None] == 2, np.nan, _motion().positions))
        ),
        "frame 2 has NaN or infinite positions",
    ),
    "NaN rest": (
        lambda p: np.savez(p, **_arrays(rest_vertices=np.full((4, 3), np.nan))),
        "rest_vertices contains NaN",
    ),
    "meta not JSON": (lambda p: np.savez(p, **_arrays(meta=np.array("{oops"))), "meta is not valid JSON"),
    "meta a list": (
        lambda p: np.savez(p, **_arrays(meta=np.array("[1, 2]"))),
        "meta must be a JSON object, got list",
    ),
    "meta numbers": (lambda p: np.savez(p, **_arrays(meta=np.zeros(3))), "meta must be one JSON string"),
}


@pytest.mark.parametrize("kind", JUNK)
def test_junk_motion_is_one_line_naming_the_file(tmp_path, kind):
    path = tmp_path / "motion.npz"
    make, reason = JUNK[kind]
    make(path)
    with pytest.raises(InputError) as err:
        load_motion(path)
    message = str(err.value)
    assert message.startswith(f"{path}: not a shellsim motion file (") and message.endswith(")"), message
    assert re.search(reason, message), message
    assert "\n" not in message and "pickle" not in message
    # the header alone: the same error, unless the problem is in the frames it does not read
    if kind != "NaN frame":
        with pytest.raises(InputError, match=f"^{re.escape(message)}$"):
            read_motion_info(path)
    # frames: read, or one line (they check what they read: the frames and the positions' headers)
    try:
        read_frames(path, [2])
    except InputError as lazy:
        assert str(lazy).startswith(f"{path}: not a shellsim motion file (") and "\n" not in str(lazy)


def test_pickled_objects_are_refused_before_they_are_read(tmp_path):
    path, marker = tmp_path / "evil.npz", tmp_path / "unpickled"
    _write_pickled(path, marker)
    for read in (load_motion, read_motion_info):
        with pytest.raises(InputError, match=r"not a shellsim motion file \('meta' holds Python objects"):
            read(path)
    assert not marker.exists()


def test_a_directory_or_a_missing_file_says_so(tmp_path):
    with pytest.raises(InputError, match=f"^{tmp_path}: is a directory, not a cage file$"):
        load_npz(tmp_path, ("vertices",), "cage")
    with pytest.raises(InputError, match="nothing.npz: motion file not found$"):
        load_motion(tmp_path / "nothing.npz")


def test_a_good_motion_round_trips(tmp_path):
    path = tmp_path / "m.npz"
    save_motion(path, _motion())
    loaded = load_motion(path)
    assert set(FORMAT1_KEYS) == {"rest_vertices", "tets", "positions", "times", "meta"}
    assert set(KEYS) == {"rest_vertices", "tets", "positions", "times", "header"}
    np.testing.assert_array_equal(loaded.positions, _motion().positions.astype(np.float32))
    assert loaded.meta == {"fps": 10.0}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]  # no temporary file left


def test_blocks_are_written_as_one_array_numpy_reads(tmp_path):
    rng = np.random.default_rng(0)
    whole = rng.normal(size=(7, 4, 3)).astype(np.float32)
    path = tmp_path / "a.npz"
    blocks = Blocks((7, 4, 3), np.float32, [whole[:2], whole[2:3], whole[3:]])
    write_npz(path, {"a": np.arange(3), "b": blocks})
    with np.load(path) as data:
        assert data.files == ["a", "b"] and data["b"].tobytes() == whole.tobytes()
        np.testing.assert_array_equal(data["a"], np.arange(3))
    with pytest.raises(ValueError, match="blocks of 6 rows in all, expected 7"):
        write_npz(tmp_path / "c.npz", {"b": Blocks((7, 4, 3), np.float32, [whole[:6]])})
    with pytest.raises(ValueError, match=r"expected blocks \(n, \(4, 3\)\)"):
        write_npz(tmp_path / "d.npz", {"b": Blocks((7, 4, 3), np.float32, [whole[:, :2]])})


@pytest.mark.parametrize(
    "argv",
    [
        ["inspect", "--asset", "{asset}", "--motion", "{notes}"],
        pytest.param(  # 3-4 s on 2 cores, the other two well under 1 s
            ["wind", "--asset", "{asset}", "--out", "{notes}", "--resume", "--frames", "2"],
            marks=pytest.mark.slow,
        ),
        [
            "simulate",
            "--asset",
            "{asset}",
            "--out",
            "{notes}",
            "--resume",
            "--frames",
            "2",
            "--device",
            "cpu",
        ],
    ],
)
def test_cli_given_a_text_file_as_a_motion(tmp_path, capsys, argv):
    """The issue's case: a text file as a motion; no advice to load it unsafely."""
    from test_wind import _write_asset

    asset = _write_asset(tmp_path / "rod")
    notes = tmp_path / "notes.txt"
    notes.write_text("these are my notes\n")
    capsys.readouterr()
    assert main([a.format(asset=asset, notes=notes) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"shellsim: error: {notes}: not a shellsim motion file (not an .npz archive)"
