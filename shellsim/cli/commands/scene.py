"""``shellsim scene``: the command line of :mod:`shellsim.jobs.scene`."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    from shellsim.cli.options import add_options
    from shellsim.jobs.scene import SceneSettings  # numpy only; warp and ipctk are imported when it runs

    p = sub.add_parser(
        "scene",
        help="simulate a shot of several bodies, colliders and timed actions from a scene file",
        description="Reads SCENE.toml (schema in docs/scene-file.md: world, bodies, colliders, timed pins, "
        "grabs, pushes and wind, cameras; SI units, z up, ground at z = 0), checks it, then simulates every "
        "body in one implicit solve with incremental potential contact between their visible surfaces, the "
        "colliders and the ground. Writes OUT/motion.npz, and with --video its frames (OUT/frames) and an "
        "MP4. Interrupt at any time: run again, and a motion of the same scene is continued (its cameras may "
        "change); one of another scene is refused unless --overwrite.",
    )
    p.add_argument("scene", metavar="SCENE.toml", help="the scene file")
    add_options(p, SceneSettings, skip=("scene",))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from shellsim.cli.options import from_args, options_named
    from shellsim.jobs.scene import SceneSettings, scene

    settings = from_args(SceneSettings, args)
    with options_named(SceneSettings):
        result = scene(settings)
    log.info("motion of %s written to %s (%d frames)", ", ".join(result.bodies), result.out, result.frames)
    if result.history:
        from shellsim.physics.driver import summary

        log.info("%s", summary(result.history))
    if result.video is not None:
        v = result.video
        log.info(
            "%d frames rendered to %s (%d already there): %.0f ms/frame", v.rendered, v.out, v.skipped, v.ms
        )
        print(f"video: {v.video}")
