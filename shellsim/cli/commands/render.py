"""``shellsim render``: PNG frames (and an MP4) of an asset, at rest or moved by a motion file."""

from __future__ import annotations

import argparse

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.render import RenderSettings, render


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render an asset at rest (every camera of a camera file) or a motion file (PNG frames, MP4)",
        description="Without --motion: render every camera of a transforms*.json-style camera file (its "
        "images may be absent) to OUT/<frame name>.png with narrow-band rendering (paper Sec. 3.4). With "
        "--motion: render each motion frame k, seen by the first camera of --cameras or by a camera "
        "orbiting the asset (--orbit), to OUT/<k:05d>.png, deforming the shells with the cage and mapping "
        "every sample back to rest space (paper Sec. 5). Each PNG records what made it (motion frame, "
        "camera, size, asset, renderer settings): one already in OUT is kept only when all of these match, "
        "so an interrupted render resumes, and rendered again otherwise; --overwrite renders all again.",
    )
    add_options(p, RenderSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(RenderSettings):
        _report(render(from_args(RenderSettings, args, quiet=not args.verbose)))


def _report(summary: dict) -> None:
    line = f"{summary['rendered']} frames rendered to {summary['out']} ({summary['skipped']} already there"
    line += f", {summary['replaced']} replaced)" if summary["replaced"] else ")"
    if summary["rendered"] and "field_ms" in summary:
        line += (
            f": {summary['ms']:.0f} ms/frame (deform + build {summary['build_ms']:.0f}, cast "
            f"{summary['cast_ms']:.0f}, inverse map {summary['map_ms']:.0f}, field {summary['field_ms']:.0f})"
        )
    elif summary["rendered"]:
        line += f": {summary['ms']:.0f} ms/frame"
    print(line)
    if "video" in summary:
        print(f"video: {summary['video']}")
