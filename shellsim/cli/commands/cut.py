"""``shellsim cut``: cut the object out of a captured asset, as a body with the rest as its backdrop."""

from __future__ import annotations

import argparse

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.cut import CutSettings, cut


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "cut",
        help="cut the object out of a captured asset: a body to simulate, the room as its backdrop",
        description="Writes a new asset whose shells hold only the object (named by --box, by --center and "
        "--radius, or proposed: the surface the cameras look at, above the supporting plane found in the "
        "field, a table or else the wall it hangs on) and which keeps the rest of the field as a static "
        "backdrop drawn around every frame. A table becomes the asset's up, so the body stands on the "
        "ground of a shot as on its own table.",
    )
    add_options(p, CutSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(CutSettings):
        result = cut(from_args(CutSettings, args))
    faces = f"body M+ {result.outer_faces} faces, M- {result.inner_faces} faces"
    print(f"{result.asset}: {faces}; cut {result.cut.to_dict()}")
