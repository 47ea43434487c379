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

import math
import os
from pathlib import Path

import numpy as np


def write_video(frames: list[Path], path, fps: float) -> Path:
    """Assemble PNG ``frames`` into an H.264 MP4 at ``fps`` with imageio-ffmpeg (odd sizes are padded by
    one edge row / column: H.264's 4:2:0 chroma needs even sizes)."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("frames: nothing to assemble")
    if not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps: expected a positive number, got {fps}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    with imageio.get_writer(
        tmp, fps=fps, codec="libx264", macro_block_size=1, quality=8, pixelformat="yuv420p", format="FFMPEG"
    ) as writer:
        for frame in frames:
            image = np.asarray(imageio.imread(frame))[..., :3]
            h, w = image.shape[:2]
            writer.append_data(np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge"))
    os.replace(tmp, path)
    return path
