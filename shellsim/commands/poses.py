"""``shellsim poses``: camera poses for plain photos by structure from motion (COLMAP via pycolmap)."""

from __future__ import annotations

import argparse
import math

MIN_REGISTERED = 0.5


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "poses",
        help="recover camera poses of plain photos (structure from motion) -> transforms.json",
        description="Runs COLMAP (pycolmap, on the CPU): SIFT features, matching with two-view geometric "
        "verification, incremental mapping with one OPENCV camera (fx fy cx cy k1 k2 p1 p2) shared by all "
        "photos. Writes OUT/transforms.json (instant-ngp / nerfstudio format, OpenGL camera axes, file_path "
        "relative to OUT, the scene centred on the point the cameras look at, mean up along +z, mean camera "
        "distance 4) for `shellsim train --data OUT`, and the COLMAP database and model in OUT/colmap (this "
        "command's working folder, rebuilt on every run). "
        "Photos that could not be posed are listed in the log and under 'unregistered' in the JSON. "
        'Needs pycolmap: pip install -e ".[sfm]".',
    )
    p.add_argument("--images", required=True, help="directory of photos (jpg, png, tif, bmp) of one size")
    p.add_argument("--out", required=True, help="directory to write transforms.json and colmap/ to")
    p.add_argument(
        "--matching",
        choices=("exhaustive", "sequential"),
        default="exhaustive",
        help="match every pair of photos (default), or each with the next 10 in name order, wrapping "
        "round (videos and orbits; much faster for hundreds of photos)",
    )
    p.add_argument("--max-features", type=int, default=4096, help="SIFT features per photo (default 4096)")
    p.add_argument(
        "--min-registered",
        type=float,
        default=MIN_REGISTERED,
        help=f"fail unless this fraction of the photos is posed (default {MIN_REGISTERED})",
    )
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: every core)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT/transforms.json")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import json
    import logging
    import os
    import shutil
    from pathlib import Path

    from neural.data.colmap import require_pycolmap, run_sfm, transforms_from_reconstruction
    from neural.errors import InputError
    from shellsim.commands.args import check_range
    from shellsim.outputs import check_writable_dir

    log = logging.getLogger("shellsim")
    images, out = Path(args.images), Path(args.out)
    check_range("--min-registered", args.min_registered, 0.0, 1.0, "a fraction")
    check_range("--max-features", args.max_features, 64, 1_000_000, "a number of features")
    if args.threads is not None:
        check_range("--threads", args.threads, 1, 1024, "a number of threads")
    if not images.is_dir():
        raise InputError(f"--images {images}: no such directory")
    check_writable_dir(out, "--out")
    target, work = out / "transforms.json", out / "colmap"
    if target.exists() and not args.overwrite:
        raise InputError(f"--out {out}: {target} already exists; give --overwrite to replace it")
    require_pycolmap()  # before any file is touched
    if work.exists():
        shutil.rmtree(work)

    result = run_sfm(images, work, args.matching, args.max_features, args.threads)
    n_images = len(result.names) + len(result.skipped)
    registered = len(result.names) - len(result.unregistered)
    log.info(
        "%s: %d of %d photos posed (features %.0f s, matching %.0f s, mapping %.0f s)",
        images,
        registered,
        n_images,
        *(result.seconds[k] for k in ("features", "matching", "mapping")),
    )
    needed = max(3, math.ceil(args.min_registered * n_images))
    if registered < needed:
        raise InputError(
            f"--images {images}: only {registered} of {n_images} photos could be posed (needs {needed}, "
            f"--min-registered {args.min_registered:g}): photos need texture and overlap with each other"
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
    tmp = target.with_name(target.name + ".tmp")
    tmp.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    tmp.replace(target)
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
