"""``shellsim cage``: build (or load) the tetrahedral cage of an asset and print a summary (paper Sec. 5)."""

from __future__ import annotations

import argparse

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.cage import CageSettings, cage


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
    add_options(p, CageSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(CageSettings):
        s = cage(from_args(CageSettings, args))
    print(f"cage of {s.name}: {s.path}")
    print(f"  {s.vertices} vertices, {s.tets} tets, volume {s.volume:.6g}")
    print(f"  tet quality: min {s.min_quality:.3f}, median {s.median_quality:.3f} (1 = regular)")
    print(
        f"  embedded: {s.outer_vertices} outer-shell + {s.inner_vertices} inner-shell vertices; "
        f"{s.outside} outside the cage (max distance {s.max_outside_distance:.3g})"
    )
    print(
        f"  margin {s.config.margin:g} of the diagonal, target {s.config.target_tets} tets; {s.seconds:.1f} s"
    )
