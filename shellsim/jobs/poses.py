"""Camera poses for plain photos by structure from motion (COLMAP via pycolmap) -> ``transforms.json``."""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from neural.files import write_text_atomically
from shellsim.errors import SettingError
from shellsim.io.outputs import check_writable_dir, holds_outputs, lock_output
from shellsim.settings import check_choice, check_range, check_required, option

log = logging.getLogger(__name__)

MATCHINGS = ("exhaustive", "sequential")


@dataclass(frozen=True)
class PosesSettings:
    """What ``shellsim poses`` takes."""

    images: str = option(help="directory of photos (jpg, png, tif, bmp) of one size", required=True)
    out: str = option(help="directory to write transforms.json and colmap/ to", required=True)
    matching: str = option(
        MATCHINGS[0],
        choices=MATCHINGS,
        help="match every pair of photos (exhaustive), or each with the next 10 in name order, wrapping "
        "round (sequential: videos and orbits; much faster for hundreds of photos)",
    )
    max_features: int = option(4096, help="SIFT features per photo")
    min_registered: float = option(0.5, help="fail unless this fraction of the photos is posed")
    threads: int | None = option(help="CPU threads", shown_default="every core")
    overwrite: bool = option(False, help="replace an existing OUT/transforms.json")

    def __post_init__(self):
        check_required(self)
        check_range("min_registered", self.min_registered, 0.0, 1.0, "a fraction")
        check_range("max_features", self.max_features, 64, 1_000_000, "a number of features")
        if self.threads is not None:
            check_range("threads", self.threads, 1, 1024, "a number of threads")
        check_choice("matching", self.matching, MATCHINGS)


@dataclass(frozen=True)
class PosesResult:
    """What :func:`poses` wrote: ``transforms`` the path of ``transforms.json``, ``posed`` of ``photos``
    photos posed, ``unregistered`` the paths (relative to the output directory, as in the file) of those
    that could not be used or posed."""

    transforms: Path
    posed: int
    photos: int
    unregistered: list[str]


@holds_outputs
def poses(settings: PosesSettings) -> PosesResult:
    """Pose the photos in ``settings.images``; writes ``OUT/transforms.json`` (instant-ngp format, the
    photos that could not be posed under ``unregistered``) and COLMAP's files in ``OUT/colmap`` (rebuilt
    each time)."""
    from neural.data.colmap import require_pycolmap, run_sfm, transforms_from_reconstruction

    images, out = Path(settings.images), Path(settings.out)
    if not images.is_dir():
        raise SettingError("images", "no such directory", value=images)
    lock_output(check_writable_dir(out, "out"), "out")
    target, work = out / "transforms.json", out / "colmap"
    if target.exists() and not settings.overwrite:
        raise SettingError("out", f"{target} already exists; give {{overwrite}} to replace it", value=out)
    require_pycolmap()  # before any file is touched
    if work.exists():
        shutil.rmtree(work)

    result = run_sfm(images, work, settings.matching, settings.max_features, settings.threads)
    n_images = len(result.names) + len(result.skipped)
    registered = len(result.names) - len(result.unregistered)
    log.info(
        "%s: %d of %d photos posed (features %.0f s, matching %.0f s, mapping %.0f s)",
        images,
        registered,
        n_images,
        *(result.seconds[k] for k in ("features", "matching", "mapping")),
    )
    needed = max(3, math.ceil(settings.min_registered * n_images))
    if registered < needed:
        raise SettingError(
            "images",
            f"only {registered} of {n_images} photos could be posed (needs {needed}, {{min_registered}} "
            f"{settings.min_registered:g}): photos need texture and overlap with each other",
            value=images,
        )
    meta = transforms_from_reconstruction(result.reconstruction, images, out)
    reasons = {
        **result.skipped,
        **{name: "not posed by structure from motion" for name in result.unregistered},
    }
    meta["unregistered"] = [
        {"file_path": Path(os.path.relpath(images / name, out)).as_posix(), "reason": reasons[name]}
        for name in sorted(reasons)
    ]
    write_text_atomically(target, json.dumps(meta, indent=2) + "\n")
    log.info(
        "%s: %d posed frames, %s camera %dx%d fl %.1f, %.1f, k1 %.3g k2 %.3g, aabb_scale %s; "
        "train with: shellsim train --data %s --out ASSET",
        target,
        len(meta["frames"]),
        meta["camera_model"],
        meta["w"],
        meta["h"],
        meta["fl_x"],
        meta["fl_y"],
        meta["k1"],
        meta["k2"],
        meta.get("aabb_scale", 1),
        out,
    )
    return PosesResult(target, registered, n_images, [u["file_path"] for u in meta["unregistered"]])
