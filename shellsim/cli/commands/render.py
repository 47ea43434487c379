"""``shellsim render``: PNG frames (and an MP4) of an asset, at rest or moved by a motion file."""

from __future__ import annotations

import argparse

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.film.result import RenderResult
from shellsim.jobs.render import RenderSettings, render


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render an asset at rest (every camera of a camera file) or a motion file (PNG frames, MP4)",
        description="Without --motion: render every camera of a transforms*.json-style camera file (its "
        "images may be absent) to OUT/<frame name>.png with narrow-band rendering (paper Sec. 3.4). With "
        "--motion: render each motion frame k, seen by the first camera of --cameras or by --camera (world "
        "metres: an orbit of --orbit-degrees, a fixed or preset view, or one following the body), to "
        "OUT/<k:05d>.png, deforming the shells with the cage and mapping "
        "every sample back to rest space (paper Sec. 5). Each PNG records what made it (motion frame, "
        "camera, size, asset, renderer settings): one already in OUT is kept only when all of these match, "
        "so an interrupted render resumes, and rendered again otherwise; --overwrite renders all again.",
    )
    add_options(p, RenderSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(RenderSettings):
        _report(render(from_args(RenderSettings, args, quiet=not args.verbose)))


def _report(result: RenderResult) -> None:
    line = f"{result.rendered} frames rendered to {result.out} ({result.skipped} already there"
    line += f", {result.replaced} replaced)" if result.replaced else ")"
    if result.rendered:
        stages = ", ".join(f"{stage} {ms:.0f}" for stage, ms in result.stage_ms.items())
        line += f": {result.ms:.0f} ms/frame" + (f" ({stages})" if stages else "")
    print(line)
    if result.video is not None:
        print(f"video: {result.video}")
