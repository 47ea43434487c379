"""Reproducibility of the cage builder: rebuild an asset's cage N times with the same settings.

Each run builds the cage from the asset's shells (:func:`~shellsim.tetcage.build.build_cage`, default settings
unless given) and prints its tet count, seconds, whether it succeeded and a sha256 of the cage (vertices,
tets and the embedding); the last line says whether every successful run gave the same cage. CPU-heavy
(about 45 s a run for the LEGO on 2 busy cores): run it alone.

    python bench/cage_repro.py                      # 20 rebuilds of assets/lego
    python bench/cage_repro.py --asset lego --runs 5 --tets 3000
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import time

import numpy as np

from neural.asset import load_asset
from neural.device import configure_process
from neural.errors import InputError
from shellsim.tetcage.build import CageConfig, build_cage


def cage_hash(cage) -> str:
    """sha256 of the cage's arrays (vertices, tets, embedding of both shells), first 16 hex digits."""
    h = hashlib.sha256()
    for key in ("vertices", "tets", "outer_tet", "outer_bary", "inner_tet", "inner_bary"):
        h.update(np.ascontiguousarray(getattr(cage, key)).tobytes())
    return h.hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--asset", default="lego", help="asset directory or shipped name (default lego)")
    parser.add_argument("--runs", type=int, default=20, help="number of rebuilds (default 20)")
    parser.add_argument("--tets", type=int, help="target tet count (default: CageConfig's)")
    parser.add_argument("-v", "--verbose", action="store_true", help="log the builder's steps")
    args = parser.parse_args()
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(name)s: %(message)s"
    )
    asset = load_asset(args.asset)
    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    config = CageConfig(target_tets=args.tets) if args.tets else CageConfig()
    print(f"{args.runs} rebuilds of the cage of {asset.name} ({asset.root}), {config}")
    hashes, counts, seconds = [], [], []
    for run in range(args.runs):
        start = time.perf_counter()
        try:
            cage = build_cage(outer, inner, config, what=asset.name)
        except InputError as err:
            seconds.append(time.perf_counter() - start)
            print(f"run {run + 1:2d}: FAILED after {seconds[-1]:.1f} s: {err}", flush=True)
            continue
        seconds.append(time.perf_counter() - start)
        hashes.append(cage_hash(cage))
        counts.append(len(cage.tets))
        print(
            f"run {run + 1:2d}: {len(cage.tets)} tets, {len(cage.vertices)} vertices, {seconds[-1]:.1f} s, "
            f"ok, sha256 {hashes[-1]}",
            flush=True,
        )
    verdict = "all identical" if len(set(hashes)) == 1 else "NOT identical"
    print(
        f"{len(hashes)} of {args.runs} succeeded; tets {min(counts, default=0)}..{max(counts, default=0)}; "
        f"{np.mean(seconds):.1f} s a run (min {min(seconds):.1f}, max {max(seconds):.1f}); "
        f"{len(set(hashes))} distinct cage(s): {verdict}"
    )


if __name__ == "__main__":
    configure_process()
    main()
