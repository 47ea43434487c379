"""Every writer as a fault-injection scenario (:mod:`faults`): ``scenario(root, fault, k) -> bool`` sets up
the old state in a fresh directory, runs the write with the ``k``-th call failing, checks that what is on
disk reads back as the old complete state or the new one (no temporary left after an error), runs the same
write again without faults, checks the new state, and returns whether the faulty run finished before its
``k``-th call. The truths are the arrays, bytes and dicts handed to the writers, read back with numpy, PIL,
json, trimesh and safetensors' loader (the motion with :func:`shellsim.motion.read.load_motion`, against
frames computed here).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from faults import Killed, injected

from neural.errors import WriteError

#: Frames of the motion scenarios and frames per chunk.
N_FRAMES, CHUNK = 12, 3


def _run(write, fault: str, k: int) -> tuple[bool, bool]:
    """``write()`` under the fault; (whether it finished before the k-th call, whether it was killed). An
    injected I/O error must reach the caller as a :class:`WriteError`."""
    with injected(fault, k) as counter:
        try:
            write()
        except Killed:
            return False, True
        except WriteError:
            assert counter.calls >= k, "a WriteError without an injected fault"
            return False, False
        except OSError as err:
            raise AssertionError(f"a raw OSError reached the caller: {err!r}") from None
    return counter.calls < k, False


def _temporaries(directory: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name not in keep)


def atomic_case(make_old, write_new, read, name: str):
    """A scenario for a writer through :func:`neural.files.write_atomically`: ``make_old(path)`` (or None),
    ``write_new(path)``, ``read(path)`` -> a comparable value."""

    def scenario(root: Path, fault: str, k: int) -> bool:
        folder = root / f"{fault}-{k}"
        folder.mkdir(parents=True)
        path = folder / name
        old = None
        if make_old is not None:
            make_old(path)
            old = read(path)
        finished, killed = _run(lambda: write_new(path), fault, k)
        now = read(path) if path.exists() else None
        new = _reference(write_new, root, name, read)
        assert _equal(now, old) or _equal(now, new), f"{name} is neither the old nor the new content"
        if not killed:
            assert not _temporaries(folder, {name}), f"temporaries left: {_temporaries(folder, {name})}"
        write_new(path)  # the same command again
        assert _equal(read(path), new), f"{name}: the second run did not write the new content"
        return finished

    return scenario


def _reference(write_new, root: Path, name: str, read):
    path = root / "reference" / name
    if not path.exists():
        path.parent.mkdir(exist_ok=True)
        write_new(path)
    return read(path)


def _equal(a, b) -> bool:
    if a is None or b is None:
        return a is b
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_equal(a[key], b[key]) for key in a)
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a, b))
    return a == b


def _bytes_case():
    from neural.files import write_bytes_atomically

    return atomic_case(
        lambda p: write_bytes_atomically(p, b"old" * 100),
        lambda p: write_bytes_atomically(p, bytes(range(256)) * 40),
        Path.read_bytes,
        "blob.bin",
    )


def _json_case():
    from neural.asset import write_meta

    old, new = {"name": "old", "metrics": {}}, {"name": "new", "values": list(range(500))}
    return atomic_case(
        lambda p: write_meta(p.parent, old),
        lambda p: write_meta(p.parent, new),
        lambda p: json.loads(p.read_text()),
        "asset.json",
    )


def _npz_case():
    from shellsim.io.npz import save_npz

    rng = np.random.default_rng(0)
    old = {"vertices": rng.random((10, 3)), "tets": np.arange(8).reshape(2, 4)}
    new = {"vertices": rng.random((400, 3)), "tets": np.arange(400).reshape(100, 4), "tag": np.array("new")}

    def read(path):
        with np.load(path) as data:
            return {key: data[key] for key in data.files}

    return atomic_case(lambda p: save_npz(p, **old), lambda p: save_npz(p, **new), read, "cage.npz")


def _png_case():
    from PIL import Image

    from shellsim.io.png import RECORD_CHUNK, save_png

    ramp = np.linspace(0, 1, 24 * 32 * 3).reshape(24, 32, 3)

    def read(path):
        with Image.open(path) as image:
            return {"pixels": np.asarray(image), "record": image.text.get(RECORD_CHUNK)}

    return atomic_case(
        lambda p: save_png(p, np.zeros((4, 4, 3)), {"frame": 0}),
        lambda p: save_png(p, ramp, {"frame": 1}),
        read,
        "00001.png",
    )


def _checkpoint_case():
    import torch

    from neural.checkpoint import load_checkpoint, save_checkpoint

    def model(value: float) -> torch.nn.Module:
        layer = torch.nn.Linear(16, 8)
        with torch.no_grad():
            layer.weight.fill_(value)
            layer.bias.fill_(-value)
        return layer

    def read(path):
        layer = torch.nn.Linear(16, 8)
        meta, _ = load_checkpoint(path, layer)
        return {"weight": layer.weight.detach().numpy().copy(), "step": meta["step"]}

    return atomic_case(
        lambda p: save_checkpoint(p, model(1.0), None, meta={"step": 1}),
        lambda p: save_checkpoint(p, model(2.0), None, meta={"step": 2}),
        read,
        "stage1.safetensors",
    )


def _ply_case():
    import trimesh

    from neural.files import write_atomically

    def write(path, size):
        mesh = trimesh.creation.icosphere(subdivisions=size)
        write_atomically(path, lambda tmp: mesh.export(tmp))

    def read(path):
        return np.asarray(trimesh.load(path, force="mesh", process=False).vertices)

    return atomic_case(lambda p: write(p, 1), lambda p: write(p, 3), read, "shell_outer.ply")


def _video_case():
    import tempfile

    from PIL import Image

    from shellsim.io.video import write_video

    folder = Path(tempfile.mkdtemp(prefix="shellsim-stills-"))
    stills = [folder / f"{i}.png" for i in range(5)]
    for i, still in enumerate(stills):  # the input frames, written before any fault is injected
        Image.fromarray(np.full((16, 16, 3), 40 * i, np.uint8)).save(still)

    def write(path, frames):
        write_video(stills[:frames], path, 10)

    def read(path):
        import imageio.v2 as imageio

        return len(imageio.mimread(path))

    return atomic_case(lambda p: write(p, 2), lambda p: write(p, 5), read, "clip.mp4")


# --- the motion writer ---------------------------------------------------------------------------------


def _cage():
    rest = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], np.float64)
    return rest, np.array([[0, 1, 2, 3], [1, 2, 3, 4]], np.int64)


def _frame(i: int, scale: float = 0.01) -> np.ndarray:
    return (_cage()[0] + scale * i * np.array([1.0, 2.0, 3.0])).astype(np.float32)


def _state(i: int) -> dict:
    return {"velocities": np.full((5, 3), float(i))}


def _produce(path: Path, writer, upto: int, confirmed: list[int], scale: float = 0.01) -> None:
    """Append frames ``writer.n_frames .. upto - 1`` as a simulation does (a flush every :data:`CHUNK`
    frames, a flush in ``finally``, ``close`` by ``with``); ``confirmed`` gets the frames on disk after each
    flush that returned."""
    with writer:
        try:
            for i in range(writer.n_frames, upto):
                writer.append(_frame(i, scale), 0.1 * i, _state(i))
                if (i + 1) % CHUNK == 0:
                    writer.flush()
                    confirmed.append(writer.n_frames)
        finally:
            writer.flush()


def _new_writer(path: Path):
    from shellsim.motion.writer import MotionWriter

    rest, tets = _cage()
    return MotionWriter(path, rest, tets, {"fps": 10}, flush_seconds=float("inf"), producer="fault test")


def _resume_or_new(path: Path):
    from shellsim.motion.writer import MotionWriter, motion_exists

    return MotionWriter.resume(path, float("inf")) if motion_exists(path) else _new_writer(path)


def _motion(path: Path) -> dict:
    from shellsim.motion.read import load_motion

    motion = load_motion(path)
    return {
        "positions": motion.positions,
        "times": np.round(motion.times, 9),
        "velocities": motion.state["velocities"],
        "meta": motion.meta,
    }


def _truth(n: int, scale: float = 0.01) -> dict:
    return {
        "positions": np.stack([_frame(i, scale) for i in range(n)]),
        "times": np.round(0.1 * np.arange(n), 9),
        "velocities": _state(n - 1)["velocities"],
        "meta": {"fps": 10},
    }


def motion_case(setup: str):
    """A :class:`~shellsim.motion.writer.MotionWriter` scenario: ``setup`` "new" (nothing there), "log" (a
    killed run's log of 6 frames), "file" (a finished file of 6 frames) or "overwrite" (a finished file of
    another motion, replaced by a new one); the run writes frames up to :data:`N_FRAMES` and closes."""

    def scenario(root: Path, fault: str, k: int) -> bool:
        from shellsim.motion.log import partial_path

        folder = root / f"{fault}-{k}"
        folder.mkdir(parents=True)
        path = folder / "motion.npz"
        log = partial_path(path)
        names = {path.name, log.name}
        old = None
        if setup in ("log", "file"):
            writer = _new_writer(path)
            for i in range(6):
                writer.append(_frame(i), 0.1 * i, _state(i))
            writer.flush()
            if setup == "file":
                writer.close()
            old = _truth(6)
        elif setup == "overwrite":
            _produce(path, _new_writer(path), 4, [], scale=0.5)
            old = _truth(4, 0.5)
        command = _new_writer if setup == "overwrite" else _resume_or_new
        confirmed = [0]
        finished, killed = _run(lambda: _produce(path, command(path), N_FRAMES, confirmed), fault, k)
        if not killed:
            assert not _temporaries(folder, names), f"temporaries left: {_temporaries(folder, names)}"
        if log.exists():  # what the next run continues
            now = _motion(log)
            n = len(now["positions"])
            assert n >= confirmed[-1], f"the log holds {n} frames, {confirmed[-1]} were flushed"
            assert _equal(now, _truth(n)), f"the log's {n} frames are not the first {n} of the motion"
        elif path.exists():  # the old motion, or the new one as far as it got (closed after the error)
            now = _motion(path)
            n = len(now["positions"])
            least = max(confirmed[-1], 0 if old is None or setup == "overwrite" else len(old["positions"]))
            new = n >= least and _equal(now, _truth(n))
            assert _equal(now, old) or new, f"the motion ({n} frames) is neither the old one nor the new one"
        else:
            assert old is None and confirmed[-1] == 0, "the motion and its log are gone"
        _produce(path, command(path), N_FRAMES, [])  # the same command again
        assert not log.exists(), "the log is left after a finished run"
        final = _motion(path)
        assert _equal(final, _truth(N_FRAMES)), "the continued motion differs from an uninterrupted one"
        return finished

    return scenario


def writers() -> dict:
    """Scenario of each writer, by name."""
    return {
        "write_atomically (bytes)": _bytes_case(),
        "asset.json / sweep index (JSON)": _json_case(),
        "npz (cage, save_npz)": _npz_case(),
        "png (rendered frame)": _png_case(),
        "checkpoint (safetensors)": _checkpoint_case(),
        "ply (shells, export)": _ply_case(),
        "video (mp4)": _video_case(),
        "motion: new": motion_case("new"),
        "motion: resume log": motion_case("log"),
        "motion: resume file": motion_case("file"),
        "motion: overwrite": motion_case("overwrite"),
    }
