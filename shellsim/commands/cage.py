"""``shellsim cage``: build (or load) the tetrahedral cage of an asset and print a summary (paper Sec. 5)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "cage",
        help="build or load the tetrahedral cage of an asset (ASSET/cage.npz or the cache)",
        description="Dilate the outer shell M+, tetrahedralize it with fTetWild and embed the vertices of "
        "both shells (barycentric coordinates). An asset's own cage is ASSET/cage.npz (built when missing "
        "or when the shells changed). Cages with other settings (--tets/--margin; those not given take "
        "their defaults), --rebuild next to a good own cage, and every cage of a shipped asset that it "
        "does not ship go to the cache directory (shellsim --cache-dir), keyed by the shells and the "
        "settings: a shipped asset is never written to, and a cage that motions were made with is never "
        "replaced.",
    )
    p.add_argument("--asset", required=True, help="asset directory, or the name of a shipped asset")
    p.add_argument("--tets", type=int, default=None, help="target number of tets (default 5000)")
    p.add_argument(
        "--margin",
        type=float,
        default=None,
        help="dilation of M+, relative to its bounding-box diagonal (default 0.02)",
    )
    p.add_argument("--rebuild", action="store_true", help="rebuild even if a matching cage.npz exists")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import time

    from neural.asset import load_asset
    from neural.errors import InputError
    from shellsim.cage import CageConfig, cage_summary, load_or_build_cage

    settings = {}
    for flag, key, value in (("--tets", "target_tets", args.tets), ("--margin", "margin", args.margin)):
        if value is not None:
            try:
                CageConfig(**{key: value})
            except ValueError as err:
                raise InputError(f"{flag}: {err}") from None
            settings[key] = value
    config = CageConfig(**settings) if settings else None
    asset = load_asset(args.asset)
    start = time.perf_counter()
    cage = load_or_build_cage(asset, config, rebuild=args.rebuild)
    seconds = time.perf_counter() - start
    s = cage_summary(cage)
    print(f"cage of {asset.name}: {cage.path}")
    print(f"  {s['vertices']} vertices, {s['tets']} tets, volume {s['volume']:.6g}")
    print(f"  tet quality: min {s['min_quality']:.3f}, median {s['median_quality']:.3f} (1 = regular)")
    print(
        f"  embedded: {s['outer_vertices']} outer-shell + {s['inner_vertices']} inner-shell vertices; "
        f"{s['outside']} outside the cage (max distance {s['max_outside_distance']:.3g})"
    )
    print(
        f"  margin {cage.config.margin:g} of the diagonal, target {cage.config.target_tets} tets; "
        f"{seconds:.1f} s"
    )
