"""PNG frames assembled into an H.264 MP4 (imageio-ffmpeg), written atomically and checked: a video that
ffmpeg could not finish (a full disk) never replaces the one there."""

from __future__ import annotations

import errno
import math
import os
import shutil
from pathlib import Path

import numpy as np

from neural.files import write_atomically


def write_video(frames: list[Path], path, fps: float) -> Path:
    """Assemble PNG ``frames`` into an H.264 MP4 at ``fps`` with imageio-ffmpeg (odd sizes are padded by
    one edge row / column: H.264's 4:2:0 chroma needs even sizes)."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("frames: nothing to assemble")
    if not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps: expected a positive number, got {fps}")

    def write(tmp: Path) -> None:
        with imageio.get_writer(
            tmp,
            fps=fps,
            codec="libx264",
            macro_block_size=1,
            quality=8,
            pixelformat="yuv420p",
            format="FFMPEG",
        ) as writer:
            for frame in frames:
                image = np.asarray(imageio.imread(frame))[..., :3]
                h, w = image.shape[:2]
                writer.append_data(np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge"))
        _check_complete(tmp, len(frames))

    return write_atomically(path, write)


def _check_complete(path: Path, n_frames: int) -> None:
    """An ``OSError`` unless the MP4 ``path`` decodes to ``n_frames`` frames: ffmpeg reports a failed write
    (a full disk) only in its log, and imageio does not check its exit status."""
    import imageio_ffmpeg

    try:
        complete = imageio_ffmpeg.count_frames_and_secs(str(path))[0] == n_frames
    except RuntimeError:
        complete = False
    if not complete:
        full = shutil.disk_usage(path.parent).free < 1 << 20
        code = errno.ENOSPC if full else errno.EIO
        raise OSError(code, f"ffmpeg wrote an incomplete video ({os.strerror(code)})", str(path))
