"""Rendering an asset at rest and deformed by a motion of its cage (paper Sec. 5, DESIGN.md step 7).

Images are made by the one pipeline of :mod:`neural.render.view` (sample, optional map to rest space,
shade); this module supplies, for one frame with cage vertices ``p`` (V, 3), the deformed sampler and the map
to rest space. :class:`DeformedRenderer`

1. **deforms the shells**: every ``M+`` / ``M-`` vertex is the barycentric interpolation of ``p`` in its
   rest tet (:func:`shellsim.deform.inverse_map.deform_points`, as :meth:`~neural.render.raycast.WarpCaster.refit_blended`
   computes it in a Warp kernel); the BVHs of their Warp meshes, built once from the rest shells, are
   refitted, and meanwhile the inverse map (:class:`shellsim.deform.inverse_map.InverseMap`) is updated to the frame;
2. **samples**: casts the camera rays against the deformed shells and places samples in the deformed narrow
   band (Procedure 3, the asset's ``NarrowBandConfig`` in world units);
3. **maps** every sample back to rest space: ``x_rest = Phi^-1(x)``, the ray direction by finite
   differences ``d_rest = normalize(Phi^-1(x + eps d) - Phi^-1(x))`` and the local stretch
   ``|Phi^-1(x + eps d) - Phi^-1(x)| / eps``, which turns a deformed section of length ``delta`` into a
   rest-space one of length ``stretch * delta`` (:meth:`InverseMap.map_rays`). Samples outside the deformed
   cage (``inside = False``) are dropped: the cage contains everything the field shows;
4. **shades** the rest-space samples with the field and composites them along the deformed rays (Eq. 2-3),
   over the asset's background.

With no cage positions it renders the rest shells directly (plain narrow-band rendering, Sec. 3.4): the
pipeline without a map, with the asset's rest sampler, exactly what ``shellsim eval`` measures.

:func:`render_motion` renders a motion file frame by frame to ``DIR/00000.png ...`` (frame ``k`` of the
motion is ``k:05d.png``) and optionally assembles an MP4; :func:`render_views` renders every camera of a
camera file at rest. Every PNG records what made it (:func:`frame_record`: the motion frame, camera, size,
asset and renderer settings, as JSON in a PNG text chunk); a PNG already on disk is kept only when its record
matches, so an interrupted render resumes and frames of another motion, camera or size are rendered again.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

#: PNG text chunk of a rendered frame holding its :func:`frame_record` as JSON.
RECORD_CHUNK = "shellsim-frame"


def save_png(path: Path, image: np.ndarray, record: dict | None = None) -> None:
    """Write an (H, W, 3) float image in [0, 1] as an 8-bit PNG atomically (temporary file + rename), so a
    PNG on disk is always complete; ``record`` (see :func:`frame_record`) goes into its text chunk
    ``RECORD_CHUNK`` as JSON."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    if record is not None:
        info.add_text(RECORD_CHUNK, json.dumps(record, sort_keys=True))
    tmp = path.with_name(path.stem + ".tmp.png")
    Image.fromarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8), "RGB").save(tmp, pnginfo=info)
    os.replace(tmp, path)


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
    shells and the rest ``cage`` (:class:`shellsim.cage.build.Cage`, when it deforms them) by content."""
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


def renderer_identity(asset) -> str:
    """Digest of the narrow-band renderer's settings for ``asset`` (its sampling and background)."""
    from dataclasses import asdict

    settings = {"narrowband": asdict(asset.narrowband_config()), "background": list(asset.background)}
    return digest("narrow band", json.dumps(settings, sort_keys=True))
