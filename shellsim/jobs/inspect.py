"""View an asset's shells and cage (and a motion's frames) with pyvista, or render the view to a PNG.

Without an asset, a motion that carries its own surface (``simulate --mesh``) shows that surface (else its
cage's boundary). pyvista is imported only when the view is made.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from neural.errors import ShellsimError
from shellsim.errors import SettingError
from shellsim.io.outputs import check_writable_file
from shellsim.settings import check_choice, option, pixels, show_pixels
from shellsim.viz.inspect import DEFAULT_SIZE, SCALARS

COLORS = tuple(SCALARS)


@dataclass(frozen=True)
class InspectSettings:
    """What ``shellsim inspect`` takes; ``quiet`` keeps VTK's warnings off stderr."""

    asset: str | None = option(help="asset directory or shipped asset name")
    motion: str | None = option(help="motion file (.npz) of the asset's cage, or of a mesh without --asset")
    frame: int = option(0, help="frame of the motion to show first (negative counts from the end)")
    color: str = option(
        COLORS[0],
        choices=COLORS,
        help="colour M+ by the shell width (distance to M-) or the field's kernel size s",
    )
    screenshot: str | None = option(metavar="OUT.png", help="render off-screen to this PNG and exit")
    size: tuple[int, int] = option(
        DEFAULT_SIZE,
        parse=pixels,
        metavar="WxH",
        help="window or image size",
        shown_default=show_pixels(DEFAULT_SIZE),
    )
    quiet: bool = True

    def __post_init__(self):
        if self.asset is None and self.motion is None:
            raise SettingError(
                "asset", "needed (its shells and cage), unless {motion} shows a motion's surface"
            )
        if self.motion is None and self.frame != 0:
            raise SettingError("frame", "needs {motion}")
        check_choice("color", self.color, COLORS)
        if self.asset is None and self.color != COLORS[0]:
            raise SettingError("color", "colours an asset's shell; it needs {asset}")
        if self.screenshot is not None and Path(self.screenshot).suffix.lower() != ".png":
            raise SettingError(
                "screenshot", "screenshots are written as PNG; give a name ending .png", value=self.screenshot
            )


def inspect(settings: InspectSettings) -> Path | None:
    """Open the interactive view (returns None when its window is closed) or, with ``settings.screenshot``,
    write the PNG and return its path. Files and frames are checked before the asset loads."""
    from shellsim.motion.read import load_motion

    shot = settings.screenshot
    if shot is not None:
        check_writable_file(shot, "screenshot")
        if not Path(shot).parent.is_dir():
            raise SettingError("screenshot", f"directory {Path(shot).parent} does not exist", value=shot)
    motion = load_motion(settings.motion) if settings.motion else None
    frame = settings.frame
    if motion is not None and not -motion.n_frames <= frame < motion.n_frames:
        raise SettingError("frame", f"{settings.motion} has frames 0..{motion.n_frames - 1}, got {frame}")

    from shellsim.viz import inspect as viewer

    if settings.quiet:
        viewer.quiet_vtk()
    if shot is None:
        try:
            viewer.check_display()
        except ShellsimError as err:
            raise SettingError("screenshot", f"needed: {err}") from None
    if settings.asset is None:
        from shellsim.viz.surface import surface_plotter

        def plotter(off_screen, slider):
            return surface_plotter(motion, frame, settings.size, off_screen=off_screen, slider=slider)
    else:
        from neural.asset import load_asset
        from shellsim.tetcage.store import cage_for_motion, load_or_build_cage

        asset = load_asset(settings.asset)
        cage = (
            load_or_build_cage(asset) if motion is None else cage_for_motion(asset, motion, settings.motion)
        )

        def plotter(off_screen, slider):
            color, size = settings.color, settings.size
            return viewer.make_plotter(asset, cage, motion, frame, color, size, off_screen, slider=slider)

    if shot is not None:
        return viewer.save_screenshot(plotter(True, False), shot)
    viewer.show_plotter(plotter(None, True))
    return None
