"""Recording a motion, shared by every job that writes one (``simulate``, ``scene``, ``wind``).

:func:`resume_or_refuse` decides what an existing output becomes: continued when it was made by the same
producer with the same settings, refused in one line (naming each setting that changed) otherwise, unless
``overwrite``. :func:`record_frames` appends frames with a progress bar, keeps the motion's per-frame
statistics, flushes on every exit (an error or an interrupt keeps every frame made before) and words a
simulation that leaves its valid regime as one line naming the frames kept.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from shellsim.errors import SettingError

log = logging.getLogger(__name__)

#: What a refusal tells the user to do.
REPLACE = "give {overwrite} to start it anew, or another {out}"


class FrameFigures(Protocol):
    """What a step reports of its frame (:class:`shellsim.physics.driver.FrameStats`, a wind frame)."""

    def figures(self) -> dict[str, float]:
        """Numbers the motion's statistics add up; ``min_*`` and ``max_*`` ones keep their extremes."""


def resume_or_refuse(
    out: Path,
    producer: str,
    record: dict,
    overwrite: bool,
    resume: bool = False,
    names: dict[str, str] | None = None,
    compared: Callable[[dict], dict] = dict,
    changed: str = "made with other settings",
):
    """The :class:`shellsim.motion.writer.MotionWriter` continuing ``out`` when it holds a motion of
    ``producer`` made with the settings ``record`` (as far as ``compared`` of both tells), None when there
    is nothing to continue (no motion there, or ``overwrite``); a :class:`SettingError` naming each setting
    that changed (``names``: how a setting is shown when it is not its field; ``changed`` what the refusal
    calls the difference) otherwise. A file that is not a motion is refused as it is, never replaced."""
    from shellsim.motion.changes import describe_changes
    from shellsim.motion.writer import MotionWriter, motion_exists

    if overwrite or not motion_exists(out):
        if out.exists():
            log.info("replacing %s", out)
        elif resume:
            log.info("%s does not exist: nothing to resume, starting it", out)
        return None
    writer = MotionWriter.resume(out)
    if writer.motion.producer != producer:
        raise SettingError("out", f"not a '{producer}' motion file; {REPLACE}", out)
    changes = describe_changes(compared(writer.motion.settings), compared(record), names or {})
    if changes:
        raise SettingError("out", f"{changed} ({'; '.join(changes)}); {REPLACE}", out)
    log.info("continuing %s after frame %d", out, writer.n_frames - 1)
    return writer


def record_frames(
    writer,
    frames: int,
    advance: Callable[[], FrameFigures],
    snapshot: Callable[[], tuple[np.ndarray, float, dict | None]],
    *,
    advice: Callable[[object], str],
    desc: str,
    progress: bool = True,
    initial: bool = True,
) -> list:
    """Append frames to ``writer`` until it holds ``frames``; returns what ``advance`` reported of each.

    ``advance()`` makes the next frame and reports it; ``snapshot()`` is (positions (V, 3), time [s],
    state to resume from or None) of the frame made last. With ``initial`` an empty writer first gets the
    snapshot as frame 0 (a simulation's initial state); without it ``advance`` makes every frame. Every frame
    adds its :meth:`FrameFigures.figures` and wall time to ``writer.motion.meta["stats"]``. A
    :class:`shellsim.physics.driver.SimulationError` gets the frame's index and becomes one
    :class:`SettingError` naming the frames kept and ``advice(err)``; the writer is flushed on every exit.
    """
    from tqdm.auto import tqdm

    from shellsim.physics.driver import SimulationError

    stats = writer.motion.meta.setdefault("stats", {})
    history = []
    try:
        if initial and writer.n_frames == 0:
            writer.append(*snapshot())
        with tqdm(
            total=max(frames - writer.n_frames, 0), disable=not progress, unit="frame", desc=desc
        ) as bar:
            while writer.n_frames < frames:
                start = time.perf_counter()
                try:
                    made = advance()
                except SimulationError as err:
                    err.frame = writer.n_frames
                    kept = f"frames 0-{err.frame - 1} are kept in {writer.path}"
                    raise SettingError(None, f"{err}; {kept}; {advice(err)}") from None
                writer.append(*snapshot())
                figures = made.figures()
                _tally(stats, {**figures, "frames": 1, "seconds": time.perf_counter() - start})
                history.append(made)
                bar.set_postfix({k: figures[k] for k in ("newton_iterations", "retries") if k in figures})
                bar.update()
    finally:
        writer.flush()
    return history


def _tally(stats: dict, figures: dict[str, float]) -> None:
    """Add a frame's ``figures`` into the running ``stats``: sums, or extremes for ``min_*`` / ``max_*``."""
    for key, value in figures.items():
        value = float(value) if isinstance(value, float | np.floating) else int(value)
        if key.startswith("min_"):
            stats[key] = min(stats.get(key, value), value)
        elif key.startswith("max_"):
            stats[key] = max(stats.get(key, value), value)
        else:
            stats[key] = stats.get(key, 0) + value
