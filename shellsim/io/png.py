"""Rendered frames as PNG files that record what made them.

:func:`save_png` writes an (H, W, 3) image atomically with its :func:`frame_record` (the motion frame, camera,
size, asset and renderer settings, as JSON in the PNG text chunk :data:`RECORD_CHUNK`); :func:`stale_reason`
says whether a PNG on disk was made as a record says, so an interrupted render resumes and frames of another
motion, camera or size are rendered again. :func:`asset_identity` and :func:`renderer_identity` are the
digests the records hold.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from neural.files import write_atomically

#: PNG text chunk of a rendered frame holding its :func:`frame_record` as JSON.
RECORD_CHUNK = "shellsim-frame"


def save_png(path: Path, image: np.ndarray, record: dict | None = None) -> None:
    """Write an (H, W, 3) float image in [0, 1] as an 8-bit PNG atomically (:mod:`neural.files`), so a
    PNG on disk is always complete; ``record`` (see :func:`frame_record`) goes into its text chunk
    ``RECORD_CHUNK`` as JSON."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    if record is not None:
        info.add_text(RECORD_CHUNK, json.dumps(record, sort_keys=True))
    pixels = Image.fromarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8), "RGB")
    write_atomically(path, lambda tmp: pixels.save(tmp, pnginfo=info))


def digest(*parts) -> str:
    """Short SHA-256 of ``parts``: arrays (their dtype, shape and bytes), strings, bytes or files (Path)."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, Path):
            with open(part, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        elif isinstance(part, bytes | str):
            h.update(part.encode() if isinstance(part, str) else part)
        else:
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        h.update(b"|")
    return h.hexdigest()[:16]


def asset_identity(asset, cage=None) -> str:
    """Digest of what an asset's images depend on: its field weights and configuration, normalisation,
    shells and the rest ``cage`` (:class:`shellsim.tetcage.build.Cage`, when it deforms them) by content."""
    meta = {k: asset.meta.get(k) for k in ("normalisation", "field")}
    files = [asset.file("field"), asset.file("shell_outer"), asset.file("shell_inner")]
    return digest(json.dumps(meta, sort_keys=True), *files, *([cage.vertices, cage.tets] if cage else []))


def frame_record(motion: str, camera, asset: str, renderer: str) -> dict:
    """What makes a frame, stored in its PNG: ``motion`` (digest of the cage frame, "rest" without one),
    ``camera`` (digest of the one camera of the ``Cameras`` ``camera``), ``size`` ("WxH"), ``asset``
    (:func:`asset_identity` or another digest of what is drawn) and ``renderer`` (digest of its settings)."""
    c = camera
    return {
        "motion": motion,
        "camera": digest(c.c2w, c.fx, c.fy, c.cx, c.cy, c.distortion),
        "size": f"{int(c.width[0])}x{int(c.height[0])}",
        "asset": asset,
        "renderer": renderer,
    }


#: How a record field that differs is named in the log.
_RECORD_NAMES = {
    "motion": "motion frame",
    "camera": "camera",
    "size": "size",
    "asset": "asset",
    "renderer": "renderer settings",
}


def stale_reason(path: Path, record: dict) -> str | None:
    """None when the PNG ``path`` exists and was made as ``record`` says; else why it must be rendered:
    "" (no such file) or what differs, e.g. "another size (32x32, now 48x48)"."""
    from PIL import Image

    if not path.is_file():
        return ""
    try:
        with Image.open(path) as image:
            stored = json.loads(image.info[RECORD_CHUNK])
    except (OSError, KeyError, ValueError):
        return "no record of what made it"
    if not isinstance(stored, dict):
        return "no record of what made it"
    differ = [k for k in record if stored.get(k) != record[k]]
    if not differ:
        return None
    parts = [f"another {_RECORD_NAMES[k]}" for k in differ]
    if "size" in differ:
        parts[differ.index("size")] += f" ({stored.get('size')}, now {record['size']})"
    return ", ".join(parts)


def renderer_identity(
    asset, antialias: int = 1, world: dict | None = None, adaptive: float | None = None
) -> str:
    """Digest of the narrow-band renderer's settings for ``asset`` (its sampling and background), the
    jittered rays per pixel ``antialias`` (:func:`shellsim.film.antialias.antialiased`; 1, one ray through
    each pixel's centre, leaves the digest as it was before antialiasing, so those PNGs stay valid), given
    only where a pixel's neighbourhood spans more than ``adaptive`` (:func:`shellsim.film.antialias.adaptive`;
    None: everywhere), and the ``world`` around the body (JSON: its look, the body's placement and the static
    obstacles, :func:`shellsim.film.motion_frames.world_record`; None, the asset's background, leaves the
    digest as it was)."""
    from dataclasses import asdict

    settings = {"narrowband": asdict(asset.narrowband_config()), "background": list(asset.background)}
    if antialias != 1:
        settings["antialias"] = antialias
        if adaptive is not None:
            settings["adaptive"] = adaptive
    if world is not None:
        settings["world"] = world
    return digest("narrow band", json.dumps(settings, sort_keys=True))
