"""``shellsim view``: a shot in the browser (:class:`shellsim.view.viewer.Viewer`, built on viser)."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="show a scene, a motion or an asset in the browser: scrub, play, simulate in place",
        description="Serves a page (viser) that shows TARGET at once as meshes (the ground, the colliders, "
        "every body, the scene's cameras as frustums), with a timeline over its motion, the neural picture "
        "of the current view and, for a scene file, a Simulate button that runs 'shellsim scene' on it in "
        "the background (the same files, resume and lock). TARGET is a scene file (.toml; its motion in "
        "the scene's output directory is shown when there is one), a scene's output directory, a motion "
        "file (.npz) or an asset (a shipped name or a directory). Ctrl-C stops it.",
    )
    p.add_argument(
        "target", metavar="TARGET", help="scene file, scene output directory, motion file or asset"
    )
    p.add_argument("--port", type=int, default=8080, help="port of the page (the next free one if taken)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on; another than 127.0.0.1 or localhost lets anyone who reaches the port "
        "drive the viewer",
    )
    p.add_argument("--out", default=None, help="a scene's output directory (default: the file without .toml)")
    p.add_argument("--device", default="auto", help="auto, cpu or cuda")
    p.add_argument("--no-browser", action="store_true", help="do not open the page in the web browser")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from shellsim.view.state import check_target
    from shellsim.view.viewer import Viewer, import_viser, serve

    check_target(args.target)  # every error of the target, before anything heavy or a server starts
    import_viser()
    viewer = Viewer(host=args.host, port=args.port, device=args.device)
    try:
        viewer.open(args.target, out=args.out)
    except BaseException:
        viewer.close()
        raise
    log.info("serving %s at %s (Ctrl-C stops)", args.target, viewer.url)
    print(f"view: {viewer.url}")
    try:
        serve(viewer, browser=not args.no_browser)
    except KeyboardInterrupt:
        log.info("viewer stopped")
